// Reading scans in chunks (point_stream.hpp, issue 14): every chunking gives back exactly the
// points load_cloud reads whole, for the layouts streamed natively and for those read whole.

#include "hc/common/error.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/point_stream.hpp"

#include "error_of.hpp"
#include "test_paths.hpp"

#include <gtest/gtest.h>

#include <bit>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using hc::pipeline::Cloud;

// A PLY file with `n` vertices: a uchar "tag" before x (so the coordinates sit at an offset),
// x y z of `type` (float or double), optional rgb, and an element "junk" of fixed records
// before the vertex element. Values: x = i·0.001 + 1/3, y = −i, z = i²·1e-6.
fs::path write_ply(const fs::path& dir, const std::string& stem, std::size_t n, const std::string& type, bool big_endian,
                   bool rgb, bool ascii = false) {
  const fs::path p = dir / (stem + ".ply");
  std::ofstream out(p, std::ios::binary);
  out << "ply\nformat " << (ascii ? "ascii" : big_endian ? "binary_big_endian" : "binary_little_endian") << " 1.0\n";
  out << "element junk 3\nproperty short a\n";
  out << "element vertex " << n << "\nproperty uchar tag\nproperty " << type << " x\nproperty " << type << " y\nproperty "
      << type << " z\n";
  if (rgb) out << "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  out << "end_header\n";
  auto put = [&](auto v) {
    if (big_endian) {
      char b[sizeof v];
      std::memcpy(b, &v, sizeof v);
      for (std::size_t k = 0; k < sizeof v / 2; ++k) std::swap(b[k], b[sizeof v - 1 - k]);
      out.write(b, sizeof v);
    } else {
      out.write(reinterpret_cast<const char*>(&v), sizeof v);
    }
  };
  for (int j = 0; j < 3; ++j) {
    if (ascii) {
      out << j << "\n";
    } else {
      put(static_cast<std::int16_t>(j));
    }
  }
  for (std::size_t i = 0; i < n; ++i) {
    const double v[3] = {static_cast<double>(i) * 0.001 + 1.0 / 3.0, -static_cast<double>(i), static_cast<double>(i * i) * 1e-6};
    if (ascii) {
      out << 7 << " " << v[0] << " " << v[1] << " " << v[2];
      if (rgb) out << " " << i % 256 << " " << (i * 7) % 256 << " " << 255 - i % 256;
      out << "\n";
      continue;
    }
    put(static_cast<std::uint8_t>(7));
    for (double c : v) {
      if (type == "float") {
        put(static_cast<float>(c));
      } else {
        put(c);
      }
    }
    if (rgb) {
      put(static_cast<std::uint8_t>(i % 256));
      put(static_cast<std::uint8_t>((i * 7) % 256));
      put(static_cast<std::uint8_t>(255 - i % 256));
    }
  }
  return p;
}

// Every chunk, concatenated.
Cloud read_in_chunks(hc::pipeline::PointStream& s, std::size_t chunk_points, std::size_t* chunks) {
  Cloud all, c;
  std::vector<double> xyz;
  *chunks = 0;
  while (s.next(c, chunk_points)) {
    ++*chunks;
    EXPECT_LE(c.size(), chunk_points);
    xyz.insert(xyz.end(), c.xyz.data(), c.xyz.data() + c.xyz.size());
    all.rgb.insert(all.rgb.end(), c.rgb.begin(), c.rgb.end());
    all.float32_xyz = c.float32_xyz;
  }
  EXPECT_EQ(c.size(), 0U);
  all.xyz = Eigen::Map<Eigen::Matrix3Xd>(xyz.data(), 3, static_cast<Eigen::Index>(xyz.size() / 3));
  return all;
}

TEST(PointStream, BinaryPlyStreamsTheSamePointsInAnyChunking) {
  const fs::path dir = hc::test::temp_dir("ply");
  struct Case {
    const char* type;
    bool big, rgb;
  };
  for (const Case k : {Case{"float", false, false}, Case{"double", false, true}, Case{"float", true, true}, Case{"double", true, false}}) {
    const fs::path p = write_ply(dir, std::string(k.type) + (k.big ? "_be" : "_le") + (k.rgb ? "_rgb" : ""), 1001, k.type, k.big, k.rgb);
    const Cloud whole = hc::pipeline::load_cloud(p).value;
    for (const std::size_t chunk : {std::size_t{1}, std::size_t{7}, std::size_t{1000}, std::size_t{1001}, std::size_t{5000}}) {
      auto s = hc::pipeline::open_point_stream(p);
      ASSERT_TRUE(s->streamed()) << p;
      EXPECT_EQ(s->total_points(), 1001U);
      std::size_t chunks = 0;
      const Cloud got = read_in_chunks(*s, chunk, &chunks);
      EXPECT_EQ(chunks, (1001 + chunk - 1) / chunk);
      ASSERT_EQ(got.size(), whole.size());
      EXPECT_TRUE(got.xyz == whole.xyz) << p << " chunk " << chunk;
      EXPECT_EQ(got.rgb, whole.rgb) << p;
      EXPECT_EQ(got.float32_xyz, whole.float32_xyz) << p;
    }
    // And against the values written (independent of load_cloud): float32 or exact doubles.
    const double tol = std::string(k.type) == "float" ? 1e-7 * 1001 : 0.0;
    EXPECT_NEAR(whole.xyz(0, 500), 0.5 + 1.0 / 3.0, tol);
    EXPECT_NEAR(whole.xyz(1, 1000), -1000.0, tol);
  }
}

TEST(PointStream, OtherLayoutsAreReadWholeAndHandedOutInChunks) {
  const fs::path dir = hc::test::temp_dir("whole");
  const fs::path p = write_ply(dir, "ascii", 50, "float", false, true, /*ascii=*/true);
  auto s = hc::pipeline::open_point_stream(p);
  EXPECT_FALSE(s->streamed());
  std::size_t chunks = 0;
  const Cloud got = read_in_chunks(*s, 16, &chunks);
  EXPECT_EQ(chunks, 4U);
  const Cloud whole = hc::pipeline::load_cloud(p).value;
  EXPECT_TRUE(got.xyz == whole.xyz);
  EXPECT_EQ(got.rgb, whole.rgb);
  bool said = false;
  for (const std::string& n : s->notes()) said = said || n.find("read whole") != std::string::npos;
  EXPECT_TRUE(said);
}

TEST(PointStream, ATruncatedPlyIsRefusedWhenOpened) {
  const fs::path dir = hc::test::temp_dir("truncated");
  const fs::path p = write_ply(dir, "t", 100, "float", false, false);
  fs::resize_file(p, fs::file_size(p) - 5);
  const std::string e = hc::test::error_of([&] { hc::pipeline::open_point_stream(p); });
  EXPECT_NE(e.find("t.ply"), std::string::npos) << e;
  EXPECT_NE(e.find("truncated"), std::string::npos) << e;
  // load_cloud says the same.
  EXPECT_EQ(e, hc::test::error_of([&] { hc::pipeline::load_cloud(p); }));
  EXPECT_NE(hc::test::error_of([&] { hc::pipeline::open_point_stream(dir / "missing.ply"); }).find("does not exist"),
            std::string::npos);
}

}  // namespace
