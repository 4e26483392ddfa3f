// Reading scans in chunks (point_stream.hpp, issue 14): every chunking gives back exactly the
// points load_cloud reads whole, for the layouts streamed natively and for those read whole.

#include "hc/common/error.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/point_stream.hpp"
#include "hc/tools/relief.hpp"

#include "error_of.hpp"
#include "file_bytes.hpp"
#include "pcl_pcd_writer.hpp"
#include "test_paths.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <initializer_list>
#include <iterator>
#include <limits>
#include <random>
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

// Every chunk with its intensity, concatenated (the LAS stream gives intensity too).
Cloud read_with_intensity(hc::pipeline::PointStream& s, std::size_t chunk_points) {
  Cloud all, c;
  std::vector<double> xyz;
  while (s.next(c, chunk_points)) {
    EXPECT_GT(c.size(), 0U) << "a chunk handed out empty";
    EXPECT_LE(c.size(), chunk_points);
    xyz.insert(xyz.end(), c.xyz.data(), c.xyz.data() + c.xyz.size());
    all.rgb.insert(all.rgb.end(), c.rgb.begin(), c.rgb.end());
    all.intensity.insert(all.intensity.end(), c.intensity.begin(), c.intensity.end());
  }
  all.xyz = Eigen::Map<Eigen::Matrix3Xd>(xyz.data(), 3, static_cast<Eigen::Index>(xyz.size() / 3));
  return all;
}

// Whether a and b hold the same coordinates: equal values, or NaNs of the same bits (a PCD's
// "nan").
bool same_xyz(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) {
  if (a.cols() != b.cols()) return false;
  for (Eigen::Index i = 0; i < a.size(); ++i) {
    const double x = a.data()[i], y = b.data()[i];
    if (!(x == y) && !(std::isnan(x) && std::bit_cast<std::uint64_t>(x) == std::bit_cast<std::uint64_t>(y))) return false;
  }
  return true;
}

// `p` streamed natively in chunks of `chunk` points: `whole`'s points, colour and intensity,
// and a point count of at least its size. Returns the stream, read to its end.
std::unique_ptr<hc::pipeline::PointStream> expect_chunks_equal(const fs::path& p, const Cloud& whole, std::size_t chunk) {
  auto s = hc::pipeline::open_point_stream(p);
  EXPECT_TRUE(s->streamed());
  EXPECT_GE(s->total_points(), whole.size());
  const Cloud got = read_with_intensity(*s, chunk);
  EXPECT_EQ(got.size(), whole.size()) << "chunk " << chunk;
  if (got.size() != whole.size()) return s;
  EXPECT_TRUE(same_xyz(got.xyz, whole.xyz)) << "chunk " << chunk;
  EXPECT_EQ(got.rgb, whole.rgb) << "chunk " << chunk;
  EXPECT_EQ(got.intensity, whole.intensity) << "chunk " << chunk;
  return s;
}

// Reading `p` in chunks of `chunk` points fails with load_cloud's own message, which names the
// file, and every later call fails too (the stream's failure is sticky). Returns the message.
std::string expect_stream_fails_as_whole_read(const fs::path& p, std::size_t chunk) {
  const std::string whole_error = hc::test::error_of([&] { hc::pipeline::load_cloud(p); });
  EXPECT_NE(whole_error.find(p.filename().string()), std::string::npos) << whole_error;
  auto s = hc::pipeline::open_point_stream(p);
  EXPECT_TRUE(s->streamed());
  Cloud c;
  EXPECT_EQ(hc::test::error_of([&] {
              while (s->next(c, chunk)) {
              }
            }),
            whole_error);
  const std::string again = hc::test::error_of([&] { s->next(c, 10); });
  EXPECT_NE(again.find("failed earlier"), std::string::npos) << again;
  return whole_error;
}

// The real LAS samples (1.0–1.4, formats with and without colour, 8- and 16-bit colour, WKT
// and GeoTIFF-key CRS, classes dropped by default): streamed natively, every chunking gives
// load_cloud's points, colour, intensity and CRS.
// A natively streamed file read in chunks of 7, 1000 and 2^20 points: load_cloud's points,
// colour, intensity and CRS, and its notes in its order followed by `how_read`.
void expect_stream_equals_load_cloud(const fs::path& p, const std::string& how_read) {
  const auto whole_read = hc::pipeline::load_cloud(p);
  const Cloud& whole = whole_read.value;
  for (const std::size_t chunk : {std::size_t{7}, std::size_t{1000}, std::size_t{1} << 20}) {
    const auto s = expect_chunks_equal(p, whole, chunk);
    EXPECT_EQ(s->crs(), whole.crs);
    std::vector<std::string> notes = s->notes();
    ASSERT_FALSE(notes.empty());
    EXPECT_EQ(notes.back(), how_read);
    notes.pop_back();
    const std::vector<std::string>& all = whole_read.report.notes;
    EXPECT_NE(std::search(all.begin(), all.end(), notes.begin(), notes.end()), all.end())
        << "the stream's notes are not load_cloud's, in order";
  }
}

TEST(PointStream, LasStreamsTheSamePointsColourIntensityAndCrsInAnyChunking) {
  std::size_t with_rgb = 0, with_crs = 0;
  for (const char* name : {"laspy-vegetation_1_3.las", "pdal-autzen_trim_7.las", "pdal-permutations_1.2_2.las",
                           "pdal-sample_c.las", "pdal-simple.las", "pdal-test1_4.las"}) {
    SCOPED_TRACE(name);
    const fs::path p = hc::test::scan_path(std::string("scanner_samples/las/") + name);
    const Cloud whole = hc::pipeline::load_cloud(p).value;
    with_rgb += whole.has_rgb() ? 1U : 0U;
    with_crs += whole.crs.empty() ? 0U : 1U;
    expect_stream_equals_load_cloud(p, "point records streamed in chunks");
  }
  EXPECT_GE(with_rgb, 2U) << "the samples cover colour";
  EXPECT_GE(with_crs, 1U) << "the samples cover a CRS";
}

// A generated wall with 16-bit colour, one point at a time (chunks of 1) and in chunks; a LAS
// whose every class is dropped fails at the end of the stream as load_cloud fails; a truncated
// one fails when it is opened, as load_cloud does.
TEST(PointStream, LasChunkOfOneDropsAndTruncationBehaveAsTheWholeRead) {
  const fs::path dir = hc::test::temp_dir("las");
  hc::tools::ReliefSpec spec;
  spec.points = 3000;
  spec.rgb = true;
  hc::tools::write_relief(spec, dir / "w.las");
  const Cloud whole = hc::pipeline::load_cloud(dir / "w.las").value;
  ASSERT_EQ(whole.size(), 3000U);
  for (const std::size_t chunk : {std::size_t{1}, std::size_t{999}}) {
    auto s = hc::pipeline::open_point_stream(dir / "w.las");
    const Cloud got = read_with_intensity(*s, chunk);
    EXPECT_TRUE(got.xyz == whole.xyz);
    EXPECT_EQ(got.rgb, whole.rgb);
    EXPECT_EQ(got.intensity, whole.intensity);
  }
  hc::pipeline::LoadOptions all_dropped;
  all_dropped.las_drop_classes.clear();
  for (int c = 0; c < 256; ++c) all_dropped.las_drop_classes.push_back(c);
  const std::string whole_error = hc::test::error_of([&] { hc::pipeline::load_cloud(dir / "w.las", all_dropped); });
  EXPECT_NE(whole_error.find("drop_classes"), std::string::npos) << whole_error;
  EXPECT_EQ(hc::test::error_of([&] {
              auto s = hc::pipeline::open_point_stream(dir / "w.las", all_dropped);
              read_with_intensity(*s, 1000);
            }),
            whole_error);
  // A file that shrinks after it was opened: the read fails, and so does every later call.
  fs::copy_file(dir / "w.las", dir / "shrinks.las");
  {
    auto s = hc::pipeline::open_point_stream(dir / "shrinks.las");
    fs::resize_file(dir / "shrinks.las", fs::file_size(dir / "shrinks.las") - 1000);
    Cloud c;
    EXPECT_THROW(s->next(c, 100), hc::InputError);
    const std::string again = hc::test::error_of([&] { s->next(c, 100); });
    EXPECT_NE(again.find("failed earlier"), std::string::npos) << again;
  }
  fs::resize_file(dir / "w.las", fs::file_size(dir / "w.las") - 10);
  const std::string truncated = hc::test::error_of([&] { hc::pipeline::load_cloud(dir / "w.las"); });
  EXPECT_NE(truncated.find("truncated"), std::string::npos) << truncated;
  EXPECT_EQ(hc::test::error_of([&] { hc::pipeline::open_point_stream(dir / "w.las"); }), truncated);
}

// Files opened together (open_point_streams) are probed once a process and the probe kept by
// the file's identity and the load options: a LAS file under gzip is read whole, and its point
// count is what input.las.drop_classes leaves. Half of a generated LAS file's points are turned
// to class 7 (low noise): opened with the default options, then keeping every class, then with
// the defaults again, each time the count load_cloud gives with those options (the oracle). Until
// 2026-11-27 the probe was kept by the file alone, and the second opening gave the first's count.
TEST(PointStream, FilesOpenedTogetherCountWhatTheirOwnLoadOptionsKeep) {
  const fs::path dir = hc::test::temp_dir("probe_options");
  hc::tools::ReliefSpec spec;
  spec.points = 3000;
  hc::tools::write_relief(spec, dir / "w.las");
  std::string las = hc::test::read_bytes(dir / "w.las");
  // LAS 1.2 header: offset to the point records (uint32 at byte 96), record length (uint16 at
  // 105); point format 0: classification in the low 5 bits of byte 15 of a record.
  std::uint32_t first = 0;
  std::uint16_t length = 0;
  std::memcpy(&first, las.data() + 96, 4);
  std::memcpy(&length, las.data() + 105, 2);
  ASSERT_EQ(las.size(), first + 3000U * length);
  for (std::size_t i = 0; i < 3000; i += 2) las[first + i * length + 15] = static_cast<char>(7);
  hc::test::write_gzip(dir / "w.las.gz", las);
  hc::tools::ReliefSpec other = spec;
  other.seed = 2;
  hc::tools::write_relief(other, dir / "other.las");
  const std::vector<fs::path> files = {dir / "w.las.gz", dir / "other.las"};
  hc::pipeline::LoadOptions defaults, keep_all;
  keep_all.las_drop_classes.clear();
  for (const auto* o : {&defaults, &keep_all, &defaults}) {
    const std::uint64_t expected = hc::pipeline::load_cloud(files[0], *o).value.size() + hc::pipeline::load_cloud(files[1], *o).value.size();
    auto s = hc::pipeline::open_point_streams(files, *o);
    EXPECT_EQ(s->total_points(), expected) << (o == &keep_all ? "every class kept" : "classes 7 and 18 dropped");
    std::uint64_t got = 0;
    Cloud c;
    while (s->next(c, 1000)) got += c.size();
    EXPECT_EQ(got, expected);
  }
  EXPECT_EQ(hc::pipeline::load_cloud(files[0], defaults).value.size(), 1500U);
}

// LAZ, decompressed chunk by chunk: the real samples (point-wise chunked, and a layered COPC
// file with colour) give load_cloud's points, colour, intensity, CRS and notes in any chunking.
TEST(PointStream, LazStreamsTheSamePointsAsTheWholeReadInAnyChunking) {
  std::size_t with_rgb = 0;
  for (const char* name : {"pdal-simple.laz", "pdal-autzen_trim.laz", "pdal-1.2-with-color.copc.laz"}) {
    SCOPED_TRACE(name);
    const fs::path p = hc::test::scan_path(std::string("scanner_samples/laz/") + name);
    with_rgb += hc::pipeline::load_cloud(p).value.has_rgb() ? 1U : 0U;
    expect_stream_equals_load_cloud(p, "point records streamed in chunks");
  }
  EXPECT_GE(with_rgb, 1U) << "the samples cover colour";
}

// A LAZ file cut short fails when the stream is opened with load_cloud's own message (its chunk
// table is gone); one that shrinks after opening fails in next(), and every later call fails.
TEST(PointStream, LazTruncationFailsAsTheWholeReadAndStaysFailed) {
  const fs::path dir = hc::test::temp_dir("laz");
  const fs::path src = hc::test::scan_path("scanner_samples/laz/pdal-autzen_trim.laz");
  fs::copy_file(src, dir / "cut.laz");
  fs::resize_file(dir / "cut.laz", fs::file_size(src) / 2);
  const std::string whole_error = hc::test::error_of([&] { hc::pipeline::load_cloud(dir / "cut.laz"); });
  ASSERT_FALSE(whole_error.empty());
  EXPECT_NE(whole_error.find("cut.laz"), std::string::npos) << whole_error;
  EXPECT_EQ(hc::test::error_of([&] { hc::pipeline::open_point_stream(dir / "cut.laz"); }), whole_error);

  fs::copy_file(src, dir / "shrinks.laz");
  auto s = hc::pipeline::open_point_stream(dir / "shrinks.laz");
  fs::resize_file(dir / "shrinks.laz", 4096);
  Cloud c;
  const std::string first = hc::test::error_of([&] {
    while (s->next(c, 1000)) {
    }
  });
  EXPECT_NE(first.find("truncated or unreadable in LAZ chunk"), std::string::npos) << first;
  const std::string again = hc::test::error_of([&] { s->next(c, 100); });
  EXPECT_NE(again.find("failed earlier"), std::string::npos) << again;
}

// A PTX file of two scans, 8 MB of text (more than one 4 MiB read block, so lines are carried
// across blocks): scan 1 with colour and a transform, no-returns and blank lines, CRLF ends;
// scan 2 without colour (so neither read keeps RGB). `bad_line`: a point line of scan 2 that
// is replaced by text, 0 = none.
fs::path write_ptx(const fs::path& p, std::size_t bad_line = 0) {
  std::ofstream out(p, std::ios::binary);
  const int cols = 300, rows = 300;
  for (int scan = 0; scan < 2; ++scan) {
    out << cols << "\r\n" << rows << "\r\n";
    out << "1 2 3\r\n1 0 0\r\n0 1 0\r\n0 0 1\r\n";
    if (scan == 0) {
      out << "0 1 0 0\r\n-1 0 0 0\r\n0 0 1 0\r\n1 2 3 1\r\n";  // 90° about z, then moved
    } else {
      out << "1 0 0 0\r\n0 1 0 0\r\n0 0 1 0\r\n0 0 0 1\r\n";
    }
    for (int k = 0; k < cols * rows; ++k) {
      if (scan == 1 && bad_line != 0 && static_cast<std::size_t>(k) + 1 == bad_line) {
        out << "0.1 0.2 not-a-number 0.5\r\n";
        continue;
      }
      if (k % 997 == 0) out << "\r\n";  // a blank line now and then
      if (k % 101 == 0) {
        out << (scan == 0 ? "0 0 0 0 0 0 0" : "0 0 0 0") << "\r\n";  // no return
        continue;
      }
      out << 0.001 * (k % cols) + 0.1 * scan << ' ' << -0.002 * (k / cols) << ' ' << 0.5 + 1e-4 * (k % 17) << ' '
          << 0.25 + 0.5 * ((k % 7) / 7.0);
      if (scan == 0) out << ' ' << k % 256 << ' ' << (3 * k) % 256 << ' ' << 255 - k % 256;
      out << "\r\n";
    }
  }
  return p;
}

TEST(PointStream, PtxStreamsTheSamePointsAndNotesAsTheWholeRead) {
  const fs::path dir = hc::test::temp_dir("ptx");
  std::vector<fs::path> files = {write_ptx(dir / "two_scans.ptx")};
  for (const char* name : {"pdal-1.2-with-color.ptx", "pdal-complex-transform.ptx", "pdal-no-color.ptx"}) {
    files.push_back(hc::test::scan_path(std::string("scanner_samples/ptx/") + name));
  }
  for (const fs::path& p : files) {
    SCOPED_TRACE(p.filename().string());
    const auto whole_read = hc::pipeline::load_cloud(p);
    const Cloud& whole = whole_read.value;
    for (const std::size_t chunk : {std::size_t{1}, std::size_t{7}, std::size_t{5000}, std::size_t{1} << 20}) {
      if (chunk == 1 && whole.size() > 10000) continue;  // one point at a time: the small samples
      const auto s = expect_chunks_equal(p, whole, chunk);
      std::vector<std::string> notes = s->notes();
      ASSERT_FALSE(notes.empty());
      EXPECT_EQ(notes.back(), "point lines streamed in chunks");
      notes.pop_back();
      EXPECT_EQ(notes, whole_read.report.notes) << "chunk " << chunk;
    }
  }
  // The generated file: both scans' measured points, colour dropped (scan 2 has none).
  const Cloud two = hc::pipeline::load_cloud(files[0]).value;
  EXPECT_EQ(two.size(), 2U * (90000U - 892U));
  EXPECT_FALSE(two.has_rgb());
}

// A bad point line fails in next() with load_cloud's message, and every later call fails; a file
// that ends inside a scan fails when the stream is opened, with load_cloud's message.
TEST(PointStream, PtxErrorsAreTheWholeReadsAndStick) {
  const fs::path dir = hc::test::temp_dir("ptx_bad");
  const fs::path bad = write_ptx(dir / "bad.ptx", 4321);
  const std::string whole_error = expect_stream_fails_as_whole_read(bad, 10000);
  EXPECT_NE(whole_error.find("not-a-number"), std::string::npos) << whole_error;

  const fs::path cut = write_ptx(dir / "cut.ptx");
  {  // cut at the end of a line, 100 kB before the end
    std::ifstream in(cut, std::ios::binary);
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    fs::resize_file(cut, text.rfind('\n', text.size() - 100000) + 1);
  }
  const std::string cut_error = hc::test::error_of([&] { hc::pipeline::load_cloud(cut); });
  EXPECT_NE(cut_error.find("the file ends after"), std::string::npos) << cut_error;
  EXPECT_EQ(hc::test::error_of([&] { hc::pipeline::open_point_stream(cut); }), cut_error);
}

// A PTX file of 64 MiB or more: its first look is kept for later streams of the unchanged file
// (a tiled run opens it once per pass); those give the same points and count, and a file that
// grew is looked at again.
TEST(PointStream, ALargePtxFilesFirstLookIsReusedWhileTheFileIsUnchanged) {
  const fs::path dir = hc::test::temp_dir("ptx_large");
  const fs::path p = dir / "large.ptx";
  const auto write_scan = [](std::ofstream& out, int cols, int salt) {
    out << cols << "\n1000\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
    std::string block;
    for (int k = 0; k < cols * 1000; ++k) {
      block += std::to_string(0.001 * (k % 997) + salt) + " " + std::to_string(0.002 * (k / 997)) + " 0.5 0.25 10 20 30\n";
      if (block.size() > (1U << 20)) {
        out << block;
        block.clear();
      }
    }
    out << block;
  };
  {
    std::ofstream out(p, std::ios::binary);
    write_scan(out, 2000, 0);
  }
  ASSERT_GE(fs::file_size(p), std::uintmax_t{64} << 20);
  const auto count = [&](std::uint64_t* total) {
    auto s = hc::pipeline::open_point_stream(p);
    *total = s->total_points();
    Cloud c;
    std::size_t n = 0, rgb = 0;
    double sum = 0;
    while (s->next(c, 1 << 16)) {
      n += c.size();
      rgb += c.rgb.size();
      for (Eigen::Index i = 0; i < c.xyz.cols(); ++i) sum += c.xyz(0, i);
    }
    EXPECT_EQ(rgb, 3 * n);
    return std::pair{n, sum};
  };
  std::uint64_t first_total = 0, second_total = 0, grown_total = 0;
  const auto first = count(&first_total);
  const auto second = count(&second_total);  // the look comes from the cache
  EXPECT_EQ(first_total, 2000U * 1000U);
  EXPECT_EQ(second_total, first_total);
  EXPECT_EQ(second, first);
  {
    std::ofstream out(p, std::ios::binary | std::ios::app);
    write_scan(out, 3, 7);  // a second scan: size and time change, so the file is looked at again
  }
  const auto grown = count(&grown_total);
  EXPECT_EQ(grown_total, first_total + 3000U);
  EXPECT_EQ(grown.first, first.first + 3000U);
}

// A coloured LAS file of 64 MiB or more: the colour pass's result (8- or 16-bit) is kept for
// later streams of the unchanged file; every stream gives load_cloud's colour.
TEST(PointStream, ALargeLasFilesColourPassIsReusedAndGivesTheWholeReadsColour) {
  const fs::path dir = hc::test::temp_dir("las_large");
  hc::tools::ReliefSpec spec;
  spec.points = 2'700'000;
  spec.rgb = true;
  hc::tools::write_relief(spec, dir / "large.las");
  ASSERT_GE(fs::file_size(dir / "large.las"), std::uintmax_t{64} << 20);
  {  // colour whose low bytes differ from its high bytes (the generator writes v·257): zero them,
     // so that taking the wrong byte would show (LAS 1.2 header: point offset at byte 96, record
     // length at 105; format 2 keeps R G B as u16 at bytes 20–25 of a record)
    std::fstream f(dir / "large.las", std::ios::in | std::ios::out | std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    std::uint32_t offset = 0;
    std::uint16_t length = 0;
    std::memcpy(&offset, bytes.data() + 96, 4);
    std::memcpy(&length, bytes.data() + 105, 2);
    ASSERT_EQ(length, 26U);
    for (std::size_t at = offset; at + length <= bytes.size(); at += length)
      for (int c = 0; c < 3; ++c) bytes[at + 20 + 2 * static_cast<std::size_t>(c)] = 0;
    f.seekp(0);
    f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  }
  const Cloud whole = hc::pipeline::load_cloud(dir / "large.las").value;
  ASSERT_TRUE(whole.has_rgb());
  ASSERT_NE(*std::max_element(whole.rgb.begin(), whole.rgb.end()), 0) << "the high bytes carry the colour";
  for (int pass = 0; pass < 2; ++pass) {  // the second takes the colour decision from the first
    auto s = hc::pipeline::open_point_stream(dir / "large.las");
    const Cloud got = read_with_intensity(*s, 1 << 18);
    EXPECT_EQ(got.rgb, whole.rgb) << "pass " << pass;
    EXPECT_TRUE(got.xyz == whole.xyz) << "pass " << pass;
  }
}

// A PTS file of two blocks, about 6 MB of text (more than one 4 MiB read block, so lines are
// carried across blocks): X Y Z intensity R G B with Leica's integer intensities, CRLF ends,
// blank lines now and then. `count_off`: added to block 2's count line; `bad_line`: a point
// line of block 2 replaced by text (0 = none).
fs::path write_pts(const fs::path& p, long count_off = 0, std::size_t bad_line = 0) {
  std::ofstream out(p, std::ios::binary);
  const std::size_t n[2] = {60000, 90001};
  for (int b = 0; b < 2; ++b) {
    out << static_cast<long>(n[b]) + (b == 1 ? count_off : 0) << "\r\n";
    for (std::size_t k = 0; k < n[b]; ++k) {
      if (k % 991 == 0) out << "  \r\n";  // a blank line now and then
      if (b == 1 && k + 1 == bad_line) {
        out << "0.1 0.2 0.3 12 n/a 4 5\r\n";
        continue;
      }
      out << 0.001 * static_cast<double>(k % 300) + 0.5 * b << ' ' << -0.002 * static_cast<double>(k / 300) << ' '
          << 0.25 + 1e-4 * static_cast<double>(k % 17) << ' ' << static_cast<long>(k % 4096) - 2048 << ' ' << k % 256 << ' '
          << (3 * k) % 256 << ' ' << 255 - k % 256 << "\r\n";
    }
  }
  return p;
}

// The real PTS samples and the generated file: every chunking gives load_cloud's points,
// intensity and colour, and its notes; the generated file's first look counts its points.
TEST(PointStream, PtsStreamsTheSamePointsIntensityColourAndNotesAsTheWholeRead) {
  const fs::path dir = hc::test::temp_dir("pts");
  const fs::path two = write_pts(dir / "two_blocks.pts");
  std::vector<fs::path> files = {two};
  for (const char* name : {"pdal-test.pts", "pdal-site_56_8.pts"}) {
    files.push_back(hc::test::scan_path(std::string("scanner_samples/pts/") + name));
  }
  for (const fs::path& p : files) {
    SCOPED_TRACE(p.filename().string());
    expect_stream_equals_load_cloud(p, "point lines streamed in chunks");
  }
  const Cloud whole = hc::pipeline::load_cloud(two).value;
  ASSERT_EQ(whole.size(), 150001U);
  EXPECT_EQ(whole.intensity.size(), whole.size());
  EXPECT_EQ(whole.rgb.size(), 3 * whole.size());
  EXPECT_EQ(hc::pipeline::open_point_stream(two)->total_points(), 150001U);
}

// A bad point line, and a count its point lines do not match (generated, and the shared
// bunny_8.pts, whose count line says 8 where 9 point lines follow): next() fails with
// load_cloud's message, and every later call fails.
TEST(PointStream, PtsErrorsAreTheWholeReadsAndStick) {
  const fs::path dir = hc::test::temp_dir("pts_bad");
  const fs::path bad = write_pts(dir / "bad.pts", 0, 4321);
  const fs::path more = write_pts(dir / "more.pts", 5);
  const fs::path fewer = write_pts(dir / "fewer.pts", -3);
  const fs::path lying = hc::test::scan_path("scanner_samples/pts/pdal-bunny_8.pts");
  for (const fs::path& p : {bad, more, fewer, lying}) {
    SCOPED_TRACE(p.filename().string());
    (void)expect_stream_fails_as_whole_read(p, 10000);
  }
  EXPECT_NE(hc::test::error_of([&] { hc::pipeline::load_cloud(bad); }).find("'n/a' is not a number"), std::string::npos);
  EXPECT_NE(hc::test::error_of([&] { hc::pipeline::load_cloud(more); }).find("says 90006 points but 90001"), std::string::npos);
  // Block 2 says 89998: its last 3 point lines run on, where a count line should come.
  EXPECT_NE(hc::test::error_of([&] { hc::pipeline::load_cloud(fewer); }).find("says 89998 points but 90001"), std::string::npos);
}

// An XYZ file of about 5 MB: '#' comments (whole lines and after points), blank lines, commas
// and tabs, extra columns, CRLF ends. `bad_line`: the point line replaced by text (0 = none).
fs::path write_xyz(const fs::path& p, std::size_t bad_line = 0) {
  std::ofstream out(p, std::ios::binary);
  out << "# x y z r g b, from a test\r\n";
  for (std::size_t k = 0; k < 200000; ++k) {
    if (k % 1009 == 0) out << "\r\n   # a comment line\r\n";
    if (k + 1 == bad_line) {
      out << "1.5 2.5 z=3\r\n";
      continue;
    }
    const double x = 0.001 * static_cast<double>(k % 400), y = -0.001 * static_cast<double>(k / 400), z = 1e-5 * static_cast<double>(k % 31);
    if (k % 3 == 0) {
      out << x << ',' << y << ',' << z << ",10,20,30\r\n";
    } else {
      out << x << '\t' << y << ' ' << z << (k % 5 == 0 ? " # trailing\r\n" : "\r\n");
    }
  }
  return p;
}

TEST(PointStream, XyzStreamsTheSamePointsAsTheWholeReadAndItsErrors) {
  const fs::path dir = hc::test::temp_dir("xyz");
  const fs::path p = write_xyz(dir / "points.xyz");
  expect_stream_equals_load_cloud(p, "lines streamed in chunks");
  EXPECT_EQ(hc::pipeline::load_cloud(p).value.size(), 200000U);
  EXPECT_EQ(hc::pipeline::open_point_stream(p)->total_points(), 200000U);
  // .txt is the same reader.
  fs::copy_file(p, dir / "points.txt");
  expect_stream_equals_load_cloud(dir / "points.txt", "lines streamed in chunks");
  const fs::path bad = write_xyz(dir / "bad.xyz", 150000);
  const std::string whole_error = expect_stream_fails_as_whole_read(bad, 7777);
  EXPECT_NE(whole_error.find("'z=3' is not a number"), std::string::npos) << whole_error;
  Cloud c;
  // Comments and blank lines only: no point, as the whole read says.
  {
    std::ofstream(dir / "none.xyz") << "# nothing\n\n  # here\n";
  }
  const std::string none = hc::test::error_of([&] { hc::pipeline::load_cloud(dir / "none.xyz"); });
  EXPECT_NE(none.find("holds no points"), std::string::npos) << none;
  auto empty = hc::pipeline::open_point_stream(dir / "none.xyz");
  EXPECT_EQ(empty->total_points(), 0U);
  EXPECT_EQ(hc::test::error_of([&] { empty->next(c, 10); }), none);
}

// A text line longer than 64 MiB (2^26 bytes without its '\n') is refused by the whole read and
// by the stream with the same words, naming the file and the line; one of exactly 2^26 bytes is
// read by both. The limit is the test's own figure, and both lengths are written here: "1 2 3"
// padded with blanks (separators, so the line is still a point), between two short lines. Until
// 2026-11-28 only the stream refused long lines, and at a length that depended on where its
// 4 MiB blocks fell: both of these lines were read. The same for an OBJ of vertices and an ascii
// PCD.
TEST(PointStream, ATextLineLongerThan64MiBIsRefusedWholeAndStreamedInTheSameWords) {
  const fs::path dir = hc::test::temp_dir("long_line");
  constexpr std::size_t kLimit = std::size_t{1} << 26;
  // `head`, then the point line "<tag>1 2 3" padded with blanks to `line_bytes`, then the point
  // line "<tag>4 5 6".
  auto write = [&](const fs::path& p, const std::string& head, const std::string& tag, std::size_t line_bytes) {
    std::string line = tag + "1 2 3";
    line.resize(line_bytes, ' ');
    std::ofstream(p, std::ios::binary) << head << line << "\n" << tag << "4 5 6\n";
    return p;
  };
  // Read whole and streamed: three points, the long line's (1, 2, 3) the second.
  auto expect_read_alike = [&](const fs::path& p) {
    SCOPED_TRACE(p.filename().string());
    const Cloud whole = hc::pipeline::load_cloud(p).value;
    ASSERT_EQ(whole.size(), 3U);
    EXPECT_EQ(whole.xyz(0, 1), 1.0);
    EXPECT_EQ(whole.xyz(1, 1), 2.0);
    EXPECT_EQ(whole.xyz(2, 1), 3.0);
    auto s = hc::pipeline::open_point_stream(p);
    EXPECT_TRUE(s->streamed());
    const Cloud got = read_with_intensity(*s, 2);
    ASSERT_EQ(got.size(), 3U);
    EXPECT_TRUE(same_xyz(got.xyz, whole.xyz));
    fs::remove(p);
  };
  // Refused whole and streamed in the same words, naming the file and line `line_no`.
  auto expect_refused_alike = [&](const fs::path& p, int line_no) {
    SCOPED_TRACE(p.filename().string());
    const std::string whole_error = hc::test::error_of([&] { hc::pipeline::load_cloud(p); });
    EXPECT_NE(whole_error.find(p.filename().string()), std::string::npos) << whole_error;
    EXPECT_NE(whole_error.find("line " + std::to_string(line_no) + " is longer than 64 MiB"), std::string::npos) << whole_error;
    Cloud c;
    const std::string stream_error = hc::test::error_of([&] {
      auto s = hc::pipeline::open_point_stream(p);
      while (s->next(c, 2)) {
      }
    });
    EXPECT_EQ(stream_error, whole_error);
    fs::remove(p);
  };
  expect_read_alike(write(dir / "at_limit.xyz", "0 0 0\n", "", kLimit));
  expect_refused_alike(write(dir / "past_limit.xyz", "0 0 0\n", "", kLimit + 1), 2);
  // An OBJ of vertices (its whole read walks its lines on its own).
  expect_refused_alike(write(dir / "past_limit.obj", "v 0 0 0\n", "v ", kLimit + 1), 2);
  // An ascii PCD (its whole read walks its data lines on its own; its stream starts after the
  // header): the line named by its number in the file, 10 header lines and one data line before.
  const std::string pcd_head =
      "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
      "POINTS 3\nDATA ascii\n0 0 0\n";
  expect_read_alike(write(dir / "at_limit.pcd", pcd_head, "", kLimit));
  expect_refused_alike(write(dir / "past_limit.pcd", pcd_head, "", kLimit + 1), 12);
}

// An ASCII PLY (an element of its own before the vertex element, float or double x y z, with
// and without colour; 200 000 vertices, about 6 MB, more than one read block): streamed in blocks
// of lines, every chunking gives load_cloud's points, colour and float32 flag; a bad token and a
// cut file fail as the whole read does, and stay failed.
TEST(PointStream, AsciiPlyStreamsTheSamePointsAndErrorsAsTheWholeRead) {
  const fs::path dir = hc::test::temp_dir("ascii_ply");
  for (const bool rgb : {true, false}) {
    const fs::path p = write_ply(dir, rgb ? "rgb" : "plain", 200000, rgb ? "float" : "double", false, rgb, /*ascii=*/true);
    SCOPED_TRACE(p.filename().string());
    const Cloud whole = hc::pipeline::load_cloud(p).value;
    ASSERT_EQ(whole.size(), 200000U);
    for (const std::size_t chunk : {std::size_t{7}, std::size_t{1000}, std::size_t{1} << 20}) {
      auto s = hc::pipeline::open_point_stream(p);
      ASSERT_TRUE(s->streamed());
      EXPECT_EQ(s->total_points(), 200000U);
      std::size_t chunks = 0;
      const Cloud got = read_in_chunks(*s, chunk, &chunks);
      EXPECT_TRUE(got.xyz == whole.xyz) << "chunk " << chunk;
      EXPECT_EQ(got.rgb, whole.rgb) << "chunk " << chunk;
      EXPECT_EQ(got.float32_xyz, whole.float32_xyz) << "chunk " << chunk;
      EXPECT_EQ(s->notes().front(), "PLY ascii, 200000 vertices (lines streamed in chunks)");
    }
  }
  const fs::path p = write_ply(dir, "bad", 200000, "float", false, true, /*ascii=*/true);
  {
    std::fstream io(p, std::ios::in | std::ios::out | std::ios::binary);
    const std::string text((std::istreambuf_iterator<char>(io)), std::istreambuf_iterator<char>());
    // The line of vertex 150 000: after the header's last line and the 3 lines of "junk".
    std::size_t at = text.find('\n', text.find("end_header"));
    for (int k = 0; k < 3 + 150000; ++k) at = text.find('\n', at + 1);
    io.seekp(static_cast<std::streamoff>(text.find(' ', at + 1) + 1));
    io << "q";  // its x (after the tag) begins with a letter now
  }
  fs::path cut = dir / "cut.ply";
  fs::copy_file(write_ply(dir, "whole", 200000, "float", false, true, true), cut);
  {  // cut at the end of a line, about 1 kB before the end
    std::ifstream in(cut, std::ios::binary);
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    fs::resize_file(cut, text.rfind('\n', text.size() - 1000) + 1);
  }
  for (const fs::path& f : {p, cut}) (void)expect_stream_fails_as_whole_read(f, 9999);
  EXPECT_NE(hc::test::error_of([&] { hc::pipeline::load_cloud(p); }).find("is not a number"), std::string::npos);
  EXPECT_NE(hc::test::error_of([&] { hc::pipeline::load_cloud(cut); }).find("truncated"), std::string::npos);
}

// Gzip-compressed PLY (binary and ASCII), PTX, PTS and XYZ stream too, decompressed as they are
// read (zlib): every chunking gives load_cloud's points, colour and intensity from the same
// .gz (which it inflates whole with libdeflate), for one gzip member and for several
// concatenated; the real Buddha's merged .ply.gz as well. A cut .gz fails naming the file, and a
// file named .gz that is not gzip is refused as load_cloud refuses it.
TEST(PointStream, GzipFilesStreamDecompressedAsTheWholeReadInflatesThem) {
  const fs::path dir = hc::test::temp_dir("gz_stream");
  const std::vector<fs::path> plain = {write_ply(dir, "bin", 100000, "float", false, true),
                                       write_ply(dir, "asc", 100000, "double", false, true, /*ascii=*/true), write_ptx(dir / "scans.ptx"),
                                       write_pts(dir / "blocks.pts"), write_xyz(dir / "points.xyz")};
  for (const fs::path& p : plain) {
    for (const int members : {1, 3}) {
      const fs::path gz = dir / (p.filename().string() + ".gz");
      hc::test::write_gzip(gz, hc::test::read_bytes(p), members);
      SCOPED_TRACE(gz.filename().string() + ", members " + std::to_string(members));
      const auto whole_read = hc::pipeline::load_cloud(gz);
      const Cloud& whole = whole_read.value;
      ASSERT_GT(whole.size(), 50000U);
      for (const std::size_t chunk : {std::size_t{1000}, std::size_t{1} << 20}) (void)expect_chunks_equal(gz, whole, chunk);
    }
  }
  {
    const fs::path buddha = hc::test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz");
    const Cloud whole = hc::pipeline::load_cloud(buddha).value;
    auto s = hc::pipeline::open_point_stream(buddha);
    ASSERT_TRUE(s->streamed());
    EXPECT_EQ(s->total_points(), 1099005U);
    std::size_t chunks = 0;
    const Cloud got = read_in_chunks(*s, 250000, &chunks);
    EXPECT_EQ(chunks, 5U);
    EXPECT_TRUE(got.xyz == whole.xyz);
    EXPECT_EQ(got.float32_xyz, whole.float32_xyz);
  }
  // Bad gzip data fail as the whole read fails, in its words: cut inside a member, four zero
  // bytes after the last member, a plain file named .gz, an empty file, a gzip of nothing.
  const auto stream_error = [](const fs::path& p) {
    return hc::test::error_of([&] {
      auto s = hc::pipeline::open_point_stream(p);
      Cloud c;
      while (s->next(c, 5000)) {
      }
    });
  };
  for (const fs::path& p : {plain[0], plain[3]}) {
    const std::string packed = hc::test::read_bytes(dir / (p.filename().string() + ".gz"));
    const std::string stem = p.filename().string();
    // Sound gzip data of a file 5 bytes short (a binary PLY's vertices: its size is known only
    // at the end).
    const std::string bytes = hc::test::read_bytes(p);
    hc::test::write_gzip(dir / ("short_" + stem + ".gz"), bytes.substr(0, bytes.size() - 5));
    hc::test::write_bytes(dir / ("cut_" + stem + ".gz"), packed.substr(0, packed.size() / 2));
    hc::test::write_bytes(dir / ("tail_" + stem + ".gz"), packed + std::string(4, '\0'));
    hc::test::write_bytes(dir / ("plain_" + stem + ".gz"), hc::test::read_bytes(p));
    hc::test::write_bytes(dir / ("empty_" + stem + ".gz"), "");
    hc::test::write_gzip(dir / ("nothing_" + stem + ".gz"), "");
    for (const char* what : {"cut_", "tail_", "plain_", "empty_", "nothing_", "short_"}) {
      const fs::path bad = dir / (what + stem + ".gz");
      const std::string whole_error = hc::test::error_of([&] { hc::pipeline::load_cloud(bad); });
      EXPECT_NE(whole_error.find(bad.filename().string()), std::string::npos) << whole_error;
      EXPECT_EQ(stream_error(bad), whole_error);
    }
  }
  // zlib's own format (RFC 1950) under a .gz name, which the whole read's inflate also takes.
  {
    const std::string text = hc::test::read_bytes(plain[4]);
    uLongf size = compressBound(static_cast<uLong>(text.size()));
    std::string packed(size, '\0');
    ASSERT_EQ(compress(reinterpret_cast<Bytef*>(packed.data()), &size, reinterpret_cast<const Bytef*>(text.data()),
                       static_cast<uLong>(text.size())),
              Z_OK);
    packed.resize(size);
    hc::test::write_bytes(dir / "zlib.xyz.gz", packed);
    (void)expect_chunks_equal(dir / "zlib.xyz.gz", hc::pipeline::load_cloud(dir / "zlib.xyz.gz").value, 4096);
  }
}

// The header of a streamed PLY ends at its "end_header" line, not at the word in a comment; and a
// header whose element sizes overflow is left to the whole read, which says what is wrong.
TEST(PointStream, PlyHeaderEdgesAreTheWholeReads) {
  const fs::path dir = hc::test::temp_dir("ply_header");
  const std::string body = [] {
    std::string b;
    for (int i = 0; i < 3; ++i) {
      const float v[3] = {0.5f * static_cast<float>(i), 1.0f, -2.0f};
      b.append(reinterpret_cast<const char*>(v), sizeof v);
    }
    return b;
  }();
  hc::test::write_bytes(dir / "comment.ply",
                        "ply\nformat binary_little_endian 1.0\ncomment written before end_header\nelement vertex 3\n"
                        "property float x\nproperty float y\nproperty float z\nend_header\n" + body);
  const Cloud whole = hc::pipeline::load_cloud(dir / "comment.ply").value;
  ASSERT_EQ(whole.size(), 3U);
  (void)expect_chunks_equal(dir / "comment.ply", whole, 2);
  hc::test::write_bytes(dir / "overflow.ply",
                        "ply\nformat binary_little_endian 1.0\nelement junk 4611686018427387904\nproperty float a\n"
                        "element vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n" + body.substr(0, 12));
  const std::string whole_error = hc::test::error_of([&] { hc::pipeline::load_cloud(dir / "overflow.ply"); });
  EXPECT_NE(whole_error.find("overflow.ply"), std::string::npos) << whole_error;
  EXPECT_EQ(hc::test::error_of([&] {
              auto s = hc::pipeline::open_point_stream(dir / "overflow.ply");
              Cloud c;
              while (s->next(c, 10)) {
              }
            }),
            whole_error);
}

// Each of `names` in `dir`: the whole read fails naming the file, and opening the stream or
// reading it to the end in chunks of 5000 fails with the same message (when opened or later).
void expect_stream_fails_as_whole_read_at_any_point(const fs::path& dir, std::initializer_list<const char*> names) {
  for (const char* name : names) {
    SCOPED_TRACE(name);
    const fs::path p = dir / name;
    const std::string whole_error = hc::test::error_of([&] { hc::pipeline::load_cloud(p); });
    EXPECT_NE(whole_error.find(name), std::string::npos) << whole_error;
    EXPECT_EQ(hc::test::error_of([&] {
                auto s = hc::pipeline::open_point_stream(p);
                Cloud c;
                while (s->next(c, 5000)) {
                }
              }),
              whole_error);
  }
}

// A binary PCD of n points: x as float64, y as float32, z as int32, with a packed rgb (U4) before
// them and a pair of int16 after, so the axes sit at offsets 4, 12 and 16 of a 24-byte record;
// or, with floats, x y z all float32 (and no other field). The header as PCL writes it.
fs::path write_binary_pcd(const fs::path& p, std::size_t n, bool floats) {
  std::ofstream out(p, std::ios::binary);
  out << "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n";
  out << (floats ? "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                 : "FIELDS rgb x y z pad\nSIZE 4 8 4 4 2\nTYPE U F F I I\nCOUNT 1 1 1 1 2\n");
  out << "WIDTH " << n << "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " << n << "\nDATA binary\n";
  auto put = [&](auto v) { out.write(reinterpret_cast<const char*>(&v), sizeof v); };
  for (std::size_t i = 0; i < n; ++i) {
    const double x = static_cast<double>(i) * 0.001 + 1.0 / 3.0;
    const auto y = static_cast<float>(-static_cast<double>(i) / 7.0);
    const auto z = static_cast<std::int32_t>(i * 37 % 100003) - 50000;
    if (floats) {
      put(static_cast<float>(x));
      put(y);
      put(static_cast<float>(z) * 1e-3f);
    } else {
      put(static_cast<std::uint32_t>(0x00FF8000u + i % 256));
      put(x);
      put(y);
      put(z);
      put(static_cast<std::int16_t>(i % 7));
      put(static_cast<std::int16_t>(-1));
    }
  }
  return p;
}

// A DATA binary PCD streams natively: load_cloud's points and notes in any chunking, plain and
// under gzip, with its float32 flag; its errors are load_cloud's.
TEST(PointStream, BinaryPcdStreamsTheSamePointsAndErrorsAsTheWholeRead) {
  const fs::path dir = hc::test::temp_dir("pcd_stream");
  const fs::path mixed = write_binary_pcd(dir / "mixed.pcd", 100000, false);
  const fs::path floats = write_binary_pcd(dir / "floats.pcd", 70001, true);
  expect_stream_equals_load_cloud(mixed, "PCD binary, 100000 points (fixed-size records streamed in chunks)");
  expect_stream_equals_load_cloud(floats, "PCD binary, 70001 points (fixed-size records streamed in chunks)");
  for (const fs::path& p : {mixed, floats}) {
    const Cloud whole = hc::pipeline::load_cloud(p).value;
    EXPECT_EQ(hc::pipeline::open_point_stream(p)->total_points(), whole.size());
    Cloud c;
    ASSERT_TRUE(hc::pipeline::open_point_stream(p)->next(c, 10));
    EXPECT_EQ(c.float32_xyz, whole.float32_xyz);
    EXPECT_EQ(c.float32_xyz, p == floats);
    for (const int members : {1, 3}) {
      const fs::path gz = dir / (p.filename().string() + ".gz");
      hc::test::write_gzip(gz, hc::test::read_bytes(p), members);
      SCOPED_TRACE(gz.filename().string() + ", members " + std::to_string(members));
      (void)expect_chunks_equal(gz, hc::pipeline::load_cloud(gz).value, 4096);
    }
  }
  // The whole read's errors, when the stream is opened or read: a body 5 bytes short (plain and
  // under gzip), a header without WIDTH, a count larger than the file, a cut gzip member.
  const std::string packed = hc::test::read_bytes(dir / "mixed.pcd.gz");
  const std::string bytes = hc::test::read_bytes(mixed);
  hc::test::write_bytes(dir / "short.pcd", bytes.substr(0, bytes.size() - 5));
  hc::test::write_gzip(dir / "short.pcd.gz", bytes.substr(0, bytes.size() - 5));
  std::string no_width = bytes;
  no_width.replace(no_width.find("WIDTH 100000\n"), 13, "");
  hc::test::write_bytes(dir / "nowidth.pcd", no_width);
  std::string huge = bytes.substr(0, bytes.find("DATA binary\n") + 12);
  for (const char* key : {"WIDTH ", "POINTS "}) huge.replace(huge.find(std::string(key) + "100000"), std::strlen(key) + 6, std::string(key) + "900000000");
  hc::test::write_bytes(dir / "huge.pcd", huge);
  hc::test::write_bytes(dir / "cut.pcd.gz", packed.substr(0, packed.size() / 2));
  expect_stream_fails_as_whole_read_at_any_point(dir, {"short.pcd", "short.pcd.gz", "nowidth.pcd", "huge.pcd", "cut.pcd.gz"});
  EXPECT_NE(hc::test::error_of([&] { hc::pipeline::load_cloud(dir / "short.pcd"); }).find("truncated"), std::string::npos);
}

// A DATA binary_compressed PCD written by PCL's own writer (its LZF compressor), or DATA binary
// with compressed false: x y z float32, a packed rgb, a normal, a curvature and a uint16
// intensity (7 × the point's number mod 65536), n points as `height` rows. With repeats, x
// cycles over 1000 values, z holds runs of 300 equal values and the normal is constant (so the
// block holds long, overlapping back references); y is NaN now and then.
fs::path write_compressed_normals_pcd(const fs::path& p, std::uint32_t width, std::uint32_t height, bool compressed = true) {
  std::string rec;
  auto put = [&](auto v) { rec.append(reinterpret_cast<const char*>(&v), sizeof v); };
  const std::size_t n = static_cast<std::size_t>(width) * height;
  for (std::size_t i = 0; i < n; ++i) {
    put(static_cast<float>(i % 1000) * 0.01f);
    put(i % 97 == 5 ? std::numeric_limits<float>::quiet_NaN() : static_cast<float>(i) * -3.7e-4f);
    put((i / 300) % 2 == 0 ? 0.25f : 0.5f);
    put(static_cast<std::uint32_t>(0x00808080u));
    put(0.0f);
    put(0.0f);
    put(1.0f);
    put(static_cast<float>(i) * 1e-6f);
    put(static_cast<std::uint16_t>(7 * i % 65536));
  }
  hc::test::write_pcl_compressed_pcd(p,
                                     {{"x", 'F', 4, 1}, {"y", 'F', 4, 1}, {"z", 'F', 4, 1}, {"rgb", 'U', 4, 1}, {"normal_x", 'F', 4, 1},
                                      {"normal_y", 'F', 4, 1}, {"normal_z", 'F', 4, 1}, {"curvature", 'F', 4, 1}, {"intensity", 'U', 2, 1}},
                                     rec, width, height, compressed);
  return p;
}

// Where a PCD's binary_compressed block starts in `bytes`, and its two sizes (compressed, unpacked).
std::size_t compressed_block(const std::string& bytes, std::uint32_t sizes[2]) {
  const std::size_t pos = bytes.find("DATA binary_compressed\n") + 23;
  std::memcpy(sizes, bytes.data() + pos, 8);
  return pos;
}

// load_cloud's points, colours and intensities of the PCD `p` are those PCL's own reader gives
// (hc::test::read_pcl_pcd, the oracle). Returns load_cloud's cloud.
Cloud expect_whole_read_is_pcls(const fs::path& p) {
  std::vector<double> xyz;
  std::vector<std::uint8_t> rgb;
  std::vector<float> intensity;
  hc::test::read_pcl_pcd(p, xyz, rgb, intensity);
  Cloud whole = hc::pipeline::load_cloud(p).value;
  EXPECT_TRUE(same_xyz(whole.xyz, Eigen::Map<const Eigen::Matrix3Xd>(xyz.data(), 3, static_cast<Eigen::Index>(xyz.size() / 3))));
  EXPECT_EQ(whole.rgb, rgb);
  EXPECT_EQ(whole.intensity, intensity);
  return whole;
}

// A DATA binary_compressed PCD streams natively (an LZF decoder per column read): the points,
// colours and intensities of the whole read, which are PCL's own reader's, in any chunking,
// plain and under gzip. The files are
// PCL's own: mixed field types with the axes after a packed colour (float64 x, int32 z), and
// float32 axes before a colour, a normal and a curvature, organised, with NaN and a block of
// mostly back references.
TEST(PointStream, CompressedPcdStreamsThePointsPclReads) {
  const fs::path dir = hc::test::temp_dir("pcd_compressed_stream");
  const fs::path binary = write_binary_pcd(dir / "mixed_binary.pcd", 100000, false);
  const std::string binary_bytes = hc::test::read_bytes(binary);
  const fs::path mixed = dir / "mixed.pcd";
  hc::test::write_pcl_compressed_pcd(mixed, {{"rgb", 'U', 4, 1}, {"x", 'F', 8, 1}, {"y", 'F', 4, 1}, {"z", 'I', 4, 1}, {"pad", 'I', 2, 2}},
                                     binary_bytes.substr(binary_bytes.find("DATA binary\n") + 12), 100000);
  const fs::path normals = write_compressed_normals_pcd(dir / "normals.pcd", 1001, 70);
  const fs::path normals_binary = write_compressed_normals_pcd(dir / "normals_binary.pcd", 1001, 70, false);
  // The whole read gives PCL's own reader's points, colours and intensities (the oracle), and
  // the values written: for the mixed file the binary file's points (read directly) and R 0xFF,
  // G 0x80, B the point's number mod 256; for the normals file grey 128 and 7 × the point's
  // number mod 65536, binary or compressed.
  for (const fs::path& p : {mixed, normals, normals_binary}) {
    SCOPED_TRACE(p.filename().string());
    const Cloud whole = expect_whole_read_is_pcls(p);
    ASSERT_EQ(whole.rgb.size(), 3 * whole.size());
    ASSERT_EQ(whole.intensity.size(), p == mixed ? 0U : whole.size());
    for (std::size_t i = 0; i < whole.size(); ++i) {
      const std::array<std::uint8_t, 3> want = p == mixed ? std::array<std::uint8_t, 3>{0xFF, 0x80, static_cast<std::uint8_t>(i % 256)}
                                                          : std::array<std::uint8_t, 3>{128, 128, 128};
      if (!std::equal(want.begin(), want.end(), whole.rgb.begin() + static_cast<std::ptrdiff_t>(3 * i)) ||
          (p != mixed && whole.intensity[i] != static_cast<float>(7 * i % 65536))) {
        ADD_FAILURE() << "point " << i << ": colour or intensity not as written";
        break;
      }
    }
  }
  // An axis of COUNT 2 (its first value; the column's stride is both), a float64 y, an rgba and a
  // float64 intensity, binary and compressed: PCL's points, colours and intensities.
  {
    std::string rec;
    auto put = [&](auto v) { rec.append(reinterpret_cast<const char*>(&v), sizeof v); };
    for (std::uint32_t i = 0; i < 3000; ++i) {
      put(static_cast<float>(i) * 0.25f);
      put(-1.0f);
      put(static_cast<double>(i) / 3.0);
      put(static_cast<float>(i % 17));
      put(0xFF000000u | (i * 2654435761u >> 8));
      put(static_cast<double>(i) * 1e-3);
    }
    const std::vector<hc::test::PcdField> fields = {{"x", 'F', 4, 2}, {"y", 'F', 8, 1}, {"z", 'F', 4, 1}, {"rgba", 'U', 4, 1}, {"intensity", 'F', 8, 1}};
    for (const bool compressed : {true, false}) {
      const fs::path p = dir / (compressed ? "count2.pcd" : "count2_binary.pcd");
      SCOPED_TRACE(p.filename().string());
      hc::test::write_pcl_compressed_pcd(p, fields, rec, 3000, 1, compressed);
      const Cloud whole = expect_whole_read_is_pcls(p);
      EXPECT_EQ(whole.rgb.size(), 9000U);
      EXPECT_EQ(whole.intensity.size(), 3000U);
      (void)expect_chunks_equal(p, whole, 7);
    }
  }
  EXPECT_TRUE(same_xyz(hc::pipeline::load_cloud(normals_binary).value.xyz, hc::pipeline::load_cloud(normals).value.xyz));
  expect_stream_equals_load_cloud(normals_binary, "PCD binary, 70070 points (fixed-size records streamed in chunks)");
  const Cloud from_binary = hc::pipeline::load_cloud(binary).value;
  EXPECT_TRUE(same_xyz(hc::pipeline::load_cloud(mixed).value.xyz, from_binary.xyz));
  EXPECT_EQ(hc::pipeline::load_cloud(mixed).value.rgb, from_binary.rgb);
  // The repeats pack 34 bytes a point into fewer than 12: most of the block is back references.
  std::uint32_t sizes[2];
  (void)compressed_block(hc::test::read_bytes(normals), sizes);
  EXPECT_EQ(sizes[1], 70070U * 34U);
  EXPECT_LT(sizes[0], 70070U * 12U);
  expect_stream_equals_load_cloud(mixed, "PCD binary_compressed, 100000 points (one LZF block decoded as it is read, a decoder per column)");
  expect_stream_equals_load_cloud(normals, "PCD binary_compressed, 70070 points (one LZF block decoded as it is read, a decoder per column)");
  for (const fs::path& p : {mixed, normals}) {
    SCOPED_TRACE(p.filename().string());
    const Cloud whole = hc::pipeline::load_cloud(p).value;
    EXPECT_EQ(hc::pipeline::open_point_stream(p)->total_points(), whole.size());
    (void)expect_chunks_equal(p, whole, 1);
    Cloud c;
    ASSERT_TRUE(hc::pipeline::open_point_stream(p)->next(c, 10));
    EXPECT_EQ(c.float32_xyz, whole.float32_xyz);
    EXPECT_EQ(c.float32_xyz, p == normals);
    for (const int members : {1, 3}) {
      const fs::path gz = dir / (p.filename().string() + ".gz");
      hc::test::write_gzip(gz, hc::test::read_bytes(p), members);
      SCOPED_TRACE("members " + std::to_string(members));
      (void)expect_chunks_equal(gz, hc::pipeline::load_cloud(gz).value, 4096);
    }
  }
}

// A bad binary_compressed block fails the stream (when opened or read) as it fails the whole
// read, in the same words, which say what is wrong and where: a back reference before the data's
// start, a block declared one byte short (its last instruction cut), a block that unpacks past
// the size its header declares, a wrong unpacked size, a file cut inside the block, a cut gzip.
TEST(PointStream, CompressedPcdErrorsAreTheWholeReadsAndSayWhere) {
  const fs::path dir = hc::test::temp_dir("pcd_compressed_errors");
  const std::string bytes = hc::test::read_bytes(write_compressed_normals_pcd(dir / "good.pcd", 5000, 1));
  std::uint32_t sizes[2];
  const std::size_t pos = compressed_block(bytes, sizes);
  ASSERT_LT(static_cast<unsigned char>(bytes[pos + 8]), 32U);  // PCL's block starts with a literal run
  std::string start = bytes;
  start[pos + 8] = static_cast<char>(0x20);  // a reference of 3 bytes, 1 + the next byte back, at output byte 0
  hc::test::write_bytes(dir / "start.pcd", start);
  const auto with_sizes = [&](std::uint32_t packed, std::uint32_t unpacked, const std::string& from) {
    std::string b = from;
    const std::uint32_t v[2] = {packed, unpacked};
    std::memcpy(b.data() + pos, v, 8);
    return b;
  };
  hc::test::write_bytes(dir / "short_block.pcd", with_sizes(sizes[0] - 1, sizes[1], bytes));
  // 4999 points declared (the header as long as before): the block unpacks 34 bytes past them.
  std::string fewer = with_sizes(sizes[0], sizes[1] - 34, bytes);
  for (const char* key : {"WIDTH 5000", "POINTS 5000"}) fewer.replace(fewer.find(key), std::strlen(key), std::string(key, std::strlen(key) - 4) + "4999");
  hc::test::write_bytes(dir / "overrun.pcd", fewer);
  hc::test::write_bytes(dir / "unpacked.pcd", with_sizes(sizes[0], sizes[1] + 34, bytes));
  hc::test::write_bytes(dir / "cut.pcd", bytes.substr(0, pos + 8 + sizes[0] - 10));  // PCL pads its file to whole pages
  hc::test::write_gzip(dir / "good.pcd.gz", bytes);
  const std::string packed = hc::test::read_bytes(dir / "good.pcd.gz");
  hc::test::write_bytes(dir / "cut.pcd.gz", packed.substr(0, packed.size() / 2));
  const auto error = [&](const char* name) { return hc::test::error_of([&] { hc::pipeline::load_cloud(dir / name); }); };
  // A COUNT whose record passes 2^32 − 1 bytes (it wrapped the sizes, and a read ran past the
  // body), and a block declaring far more bytes than LZF can unpack from it (4 GB asked of a
  // 1-byte block, allocated before anything was decoded): both refused from the header.
  const std::string head = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 8\nTYPE F F U\nCOUNT 1 1 2305843009213693952\n"
                           "WIDTH 10\nHEIGHT 1\nPOINTS 10\nDATA binary_compressed\n";
  const std::uint32_t wrapped[2] = {81, 80};
  hc::test::write_bytes(dir / "count.pcd", head + std::string(reinterpret_cast<const char*>(wrapped), 8) + std::string(81, '\x00'));
  const std::uint32_t bomb[2] = {1, 4000000008U};
  hc::test::write_bytes(dir / "bomb.pcd", "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1000000000 1 1\n"
                                          "WIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA binary_compressed\n" +
                                              std::string(reinterpret_cast<const char*>(bomb), 8) + std::string(1, '\x00'));
  expect_stream_fails_as_whole_read_at_any_point(
      dir, {"start.pcd", "short_block.pcd", "overrun.pcd", "unpacked.pcd", "cut.pcd", "cut.pcd.gz", "count.pcd", "bomb.pcd"});
  EXPECT_NE(error("count.pcd").find("field 'z' has SIZE 8 and COUNT 2305843009213693952: a point record of more than 4294967295 bytes"),
            std::string::npos)
      << error("count.pcd");
  EXPECT_NE(error("bomb.pcd").find("the compressed block of 1 bytes cannot unpack to 4000000008"), std::string::npos) << error("bomb.pcd");
  EXPECT_NE(error("start.pcd").find("start.pcd': the binary_compressed body (LZF): corrupt at compressed byte 0 (output byte 0): a back reference"),
            std::string::npos)
      << error("start.pcd");
  EXPECT_NE(error("short_block.pcd").find("the " + std::to_string(sizes[0] - 1) + " compressed bytes"), std::string::npos) << error("short_block.pcd");
  EXPECT_NE(error("overrun.pcd").find("past the " + std::to_string(sizes[1] - 34) + " bytes the header declares"), std::string::npos)
      << error("overrun.pcd");
  EXPECT_NE(error("unpacked.pcd").find("unpacks to"), std::string::npos) << error("unpacked.pcd");
  EXPECT_NE(error("cut.pcd").find("truncated: the compressed block needs"), std::string::npos) << error("cut.pcd");
}

// An ascii PCD of n points as PCL's writer lays it out (one point a line, blanks between
// values): with mixed, a packed rgb (U4), x as float64 (17 digits), y as float32 written with 12
// digits (so that the float rounding of the decimal matters), a 3-value field, z as float64 and
// a uint8 label, organised as 2 rows (HEIGHT 2); y "nan", "NaN", beyond float's range (1e39)
// or subnormal (1e-40) now and then, and a blank line now and then; else x y z float32 only;
// with int_z, z an int32 field.
fs::path write_ascii_pcd(const fs::path& p, std::size_t n, bool mixed, bool int_z = false) {
  std::ofstream out(p, std::ios::binary);
  out << "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n";
  out << (mixed ? "FIELDS rgb x y normal z label\nSIZE 4 8 4 4 8 1\nTYPE U F F F F U\nCOUNT 1 1 1 3 1 1\n"
                : int_z ? "FIELDS x y z\nSIZE 4 4 4\nTYPE F F I\nCOUNT 1 1 1\n" : "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n");
  out << "WIDTH " << (mixed ? n / 2 : n) << "\nHEIGHT " << (mixed ? 2 : 1) << "\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " << n
      << "\nDATA ascii\n";
  std::mt19937 rng(20261126);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  char buf[96];
  for (std::size_t i = 0; i < n; ++i) {
    const double x = u(rng), y = u(rng) * 1e-3, z = u(rng);
    if (mixed) {
      std::snprintf(buf, sizeof buf, "%.17g", x);
      out << (0x00FF8000u + i % 256) << ' ' << buf << ' ';
      if (i % 97 == 0) {
        out << (i % 2 == 0 ? "nan" : "NaN");
      } else if (i % 1001 == 5) {
        out << (i % 2 == 0 ? "1e39" : "-1e-40");
      } else {
        std::snprintf(buf, sizeof buf, "%.12g", y);
        out << buf;
      }
      std::snprintf(buf, sizeof buf, "%.17g", z);
      out << " 0.1 -0.2 0.97 " << buf << ' ' << i % 256 << "\n";
      if (i % 1000 == 999) out << "\n";
    } else if (int_z) {
      std::snprintf(buf, sizeof buf, "%.9g %.9g %ld\n", x, y, std::lround(z * 1e5));
      out << buf;
    } else {
      std::snprintf(buf, sizeof buf, "%.12g %.12g %.12g\n", x, y, z);
      out << buf;
    }
  }
  return p;
}

// A DATA ascii PCD streams in blocks of lines: the points, colours and intensities of PCL's own
// reader (the oracle, hc::test::read_pcl_pcd) bit for bit in any chunking, whole or streamed,
// plain and under gzip, float32 flag included, on generated files of float32 and float64 axes
// among fields of every type, an integer axis and the shared bunny; its errors are the whole read's.
TEST(PointStream, AsciiPcdStreamsThePointsPclReads) {
  const fs::path dir = hc::test::temp_dir("pcd_ascii_stream");
  const fs::path mixed = write_ascii_pcd(dir / "mixed.pcd", 60000, true);
  const fs::path floats = write_ascii_pcd(dir / "floats.pcd", 50001, false);
  const fs::path bunny = hc::test::scan_path("bunny/pcl_bunny.pcd");
  const fs::path int_z = write_ascii_pcd(dir / "int_z.pcd", 3000, false, true);
  for (const fs::path& p : {mixed, floats, bunny, int_z}) {
    SCOPED_TRACE(p.filename().string());
    const Cloud whole = expect_whole_read_is_pcls(p);
    EXPECT_EQ(whole.rgb.size(), p == mixed ? 3 * whole.size() : 0U);  // the mixed file's packed colour
  }
  expect_stream_equals_load_cloud(mixed, "PCD ascii, 60000 points (lines streamed in chunks)");
  expect_stream_equals_load_cloud(floats, "PCD ascii, 50001 points (lines streamed in chunks)");
  expect_stream_equals_load_cloud(bunny, "PCD ascii, 397 points (lines streamed in chunks)");
  // An integer z field (int32) streams too (until the forty-second session, 2026-11-27, PCL read it whole at every pass).
  expect_stream_equals_load_cloud(int_z, "PCD ascii, 3000 points (lines streamed in chunks)");
  {
    const Cloud whole = hc::pipeline::load_cloud(mixed).value;
    std::size_t nan_y = 0, inf_y = 0, tiny_y = 0;
    for (Eigen::Index i = 0; i < whole.xyz.cols(); ++i) {
      const double y = whole.xyz(1, i);
      nan_y += std::isnan(y) ? 1U : 0U;
      inf_y += std::isinf(y) ? 1U : 0U;
      tiny_y += y != 0.0 && std::abs(y) < static_cast<double>(std::numeric_limits<float>::min()) ? 1U : 0U;
    }
    EXPECT_EQ(nan_y, (60000U + 96U) / 97U) << "the nan values came through";
    EXPECT_GT(inf_y, 0U) << "1e39 is beyond float's range: inf, as PCL stores it";
    EXPECT_GT(tiny_y, 0U) << "1e-40 is a float subnormal";
  }
  for (const fs::path& p : {mixed, floats}) {
    const Cloud whole = hc::pipeline::load_cloud(p).value;
    const auto s = hc::pipeline::open_point_stream(p);
    EXPECT_TRUE(s->streamed());
    EXPECT_EQ(s->total_points(), whole.size());
    Cloud c;
    ASSERT_TRUE(s->next(c, 10));
    EXPECT_EQ(c.float32_xyz, whole.float32_xyz);
    EXPECT_EQ(c.float32_xyz, p == floats);
    const fs::path gz = dir / (p.filename().string() + ".gz");
    hc::test::write_gzip(gz, hc::test::read_bytes(p), 2);
    SCOPED_TRACE(gz.filename().string());
    (void)expect_chunks_equal(gz, hc::pipeline::load_cloud(gz).value, 4096);
  }
  // The whole read's errors: a token that is no number on data line 1234, a line of 7 values,
  // a body short of 10 lines (plain and under gzip).
  const std::string bytes = hc::test::read_bytes(mixed);
  const std::size_t body = bytes.find("DATA ascii\n") + 11;
  const auto line_at = [&](std::size_t k) {  // the offset of data line k (from 1; blank lines skipped)
    std::size_t at = body;
    for (std::size_t seen = 0;;) {
      if (bytes[at] != '\n' && ++seen == k) return at;
      at = bytes.find('\n', at) + 1;
    }
  };
  std::string word = bytes;
  word.replace(line_at(1234), bytes.find(' ', line_at(1234)) - line_at(1234), "0x1F");
  hc::test::write_bytes(dir / "word.pcd", word);
  std::string seven = bytes;
  seven.erase(bytes.rfind(' ', bytes.find('\n', line_at(777))), bytes.find('\n', line_at(777)) - bytes.rfind(' ', bytes.find('\n', line_at(777))));
  hc::test::write_bytes(dir / "seven.pcd", seven);
  std::string comma = bytes;  // PCL would read "1 2 ,3" as 1 2 0: refused by both
  comma.insert(bytes.find(' ', line_at(4321)) + 1, ",");
  hc::test::write_bytes(dir / "comma.pcd", comma);
  const std::string short_body = bytes.substr(0, line_at(59991));
  hc::test::write_bytes(dir / "short.pcd", short_body);
  hc::test::write_gzip(dir / "short.pcd.gz", short_body);
  expect_stream_fails_as_whole_read_at_any_point(dir, {"word.pcd", "seven.pcd", "comma.pcd", "short.pcd", "short.pcd.gz"});
  EXPECT_NE(hc::test::error_of([&] { hc::pipeline::load_cloud(dir / "word.pcd"); }).find("data line 1234: '0x1F' is not a number"), std::string::npos);
  EXPECT_NE(hc::test::error_of([&] { hc::pipeline::load_cloud(dir / "seven.pcd"); }).find("data line 777: 7 values"), std::string::npos);
  EXPECT_NE(hc::test::error_of([&] { hc::pipeline::load_cloud(dir / "short.pcd"); }).find("only 59990 data lines"), std::string::npos);
  EXPECT_NE(hc::test::error_of([&] { hc::pipeline::load_cloud(dir / "comma.pcd"); }).find("data line 4321: ',' between values"), std::string::npos);
}

// A PCD of an unknown DATA type is refused naming it, streamed or whole, before any buffer of its
// records is sized (a fuzzed header declaring 4 GB records once had the stream allocate them).
TEST(PointStream, PcdOfUnknownDataTypeIsRefusedBeforeItsRecordsAreSized) {
  const fs::path dir = hc::test::temp_dir("pcd_unknown_data");
  hc::test::write_bytes(dir / "odd.pcd", std::string("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1000000001 1 1\nWIDTH 1\n"
                                                     "HEIGHT 1\nPOINTS 1\nDATA bincry_compressed\n") + std::string(12, '\x01'));
  const std::string whole = hc::test::error_of([&] { hc::pipeline::load_cloud(dir / "odd.pcd"); });
  EXPECT_NE(whole.find("odd.pcd': unknown PCD DATA type 'bincry_compressed' (expected ascii, binary or binary_compressed)"), std::string::npos)
      << whole;
  const std::string streamed = hc::test::error_of([&] {
    Cloud c;
    const auto s = hc::pipeline::open_point_stream(dir / "odd.pcd");
    while (s->next(c, 1000)) {
    }
  });
  EXPECT_EQ(streamed, whole);
}

// A field named rgb of a SIZE other than 4 holds no packed colour: not read as colour, and a
// note says so, in the whole read and the stream, for an ascii and a binary body (the points
// PCL's).
TEST(PointStream, PcdColourFieldOfAnotherSizeIsNotReadAndANoteSaysSo) {
  const fs::path dir = hc::test::temp_dir("pcd_rgb_size");
  std::string rec;
  for (std::uint8_t i = 0; i < 40; ++i) {
    const float xyz[3] = {static_cast<float>(i), 0.5f, -1.0f};
    rec.append(reinterpret_cast<const char*>(xyz), sizeof xyz);
    rec.push_back(static_cast<char>(i));
  }
  const std::vector<hc::test::PcdField> fields = {{"x", 'F', 4, 1}, {"y", 'F', 4, 1}, {"z", 'F', 4, 1}, {"rgb", 'U', 1, 1}};
  hc::test::write_pcl_compressed_pcd(dir / "binary.pcd", fields, rec, 40, 1, false);
  hc::test::write_pcl_ascii_pcd(dir / "ascii.pcd", fields, rec, 40);
  const std::string note = "PCD: field 'rgb' has SIZE 1, not a packed colour's 4 bytes: not read as colour";
  for (const char* name : {"binary.pcd", "ascii.pcd"}) {
    SCOPED_TRACE(name);
    const auto whole = hc::pipeline::load_cloud(dir / name);
    EXPECT_TRUE(whole.value.rgb.empty());
    EXPECT_NE(std::find(whole.report.notes.begin(), whole.report.notes.end(), note), whole.report.notes.end());
    std::vector<double> xyz;
    std::vector<std::uint8_t> rgb;
    std::vector<float> intensity;
    hc::test::read_pcl_pcd(dir / name, xyz, rgb, intensity);
    EXPECT_TRUE(same_xyz(whole.value.xyz, Eigen::Map<const Eigen::Matrix3Xd>(xyz.data(), 3, 40)));
    const auto s = hc::pipeline::open_point_stream(dir / name);
    EXPECT_NE(std::find(s->notes().begin(), s->notes().end(), note), s->notes().end());
    (void)expect_chunks_equal(dir / name, whole.value, 7);
  }
}

// An ascii PCD's colour and intensity (until the forty-second session, 2026-11-27, only x y z were read from an ascii body):
// files written by PCL's own ascii writer give PCL's own reader's colours and intensities, and
// the values written, whole and streamed; a packed colour declared TYPE F (older PCL's layout)
// is the float's bits; an integer field holds an integer of its range or the file is refused,
// naming the line, the field and the value, streamed or whole.
TEST(PointStream, AsciiPcdColourAndIntensityAreReadAndIntegersChecked) {
  const fs::path dir = hc::test::temp_dir("pcd_ascii_colour");
  // PCL's writer: float32 axes before rgb (U4), a curvature and a uint16 intensity (7·i mod
  // 65536, grey 128), 200 × 100; and an x of COUNT 2, a float64 y, an rgba (U4) and a float64
  // intensity (i / 1000), 17 digits.
  std::string normals, count2;
  auto put = [](std::string& rec, auto v) { rec.append(reinterpret_cast<const char*>(&v), sizeof v); };
  for (std::uint32_t i = 0; i < 20000; ++i) {
    put(normals, static_cast<float>(i % 1000) * 0.01f);
    put(normals, i % 97 == 5 ? std::numeric_limits<float>::quiet_NaN() : static_cast<float>(i) * -3.7e-4f);
    put(normals, 0.25f);
    put(normals, static_cast<std::uint32_t>(0x00808080u));
    put(normals, 0.0f);
    put(normals, static_cast<std::uint16_t>(7 * i % 65536));
    put(count2, static_cast<float>(i) * 0.25f);
    put(count2, -1.0f);
    put(count2, static_cast<double>(i) / 3.0);
    put(count2, static_cast<float>(i % 17));
    put(count2, 0xFF000000u | (i * 2654435761u >> 8));
    put(count2, static_cast<double>(i) * 1e-3);
  }
  hc::test::write_pcl_ascii_pcd(dir / "normals.pcd",
                                {{"x", 'F', 4, 1}, {"y", 'F', 4, 1}, {"z", 'F', 4, 1}, {"rgb", 'U', 4, 1}, {"curvature", 'F', 4, 1}, {"intensity", 'U', 2, 1}},
                                normals, 200, 100);
  hc::test::write_pcl_ascii_pcd(dir / "count2.pcd",
                                {{"x", 'F', 4, 2}, {"y", 'F', 8, 1}, {"z", 'F', 4, 1}, {"rgba", 'U', 4, 1}, {"intensity", 'F', 8, 1}}, count2, 20000,
                                1, 17);
  for (const char* name : {"normals.pcd", "count2.pcd"}) {
    SCOPED_TRACE(name);
    const fs::path p = dir / name;
    const Cloud whole = expect_whole_read_is_pcls(p);
    ASSERT_EQ(whole.rgb.size(), 60000U);
    ASSERT_EQ(whole.intensity.size(), 20000U);
    const bool n = std::string(name) == "normals.pcd";
    for (std::uint32_t i = 0; i < 20000; ++i) {
      const std::uint32_t c = n ? 0x808080u : (i * 2654435761u >> 8) & 0xFFFFFFu;
      const std::array<std::uint8_t, 3> want{static_cast<std::uint8_t>(c >> 16), static_cast<std::uint8_t>(c >> 8), static_cast<std::uint8_t>(c)};
      const float level = n ? static_cast<float>(7 * i % 65536) : static_cast<float>(static_cast<double>(i) * 1e-3);
      if (!std::equal(want.begin(), want.end(), whole.rgb.begin() + 3 * static_cast<std::ptrdiff_t>(i)) || whole.intensity[i] != level) {
        ADD_FAILURE() << "point " << i << ": colour or intensity not as written";
        break;
      }
    }
    expect_stream_equals_load_cloud(p, "PCD ascii, 20000 points (lines streamed in chunks)");
    const fs::path gz = dir / (std::string(name) + ".gz");
    hc::test::write_gzip(gz, hc::test::read_bytes(p), 2);
    (void)expect_chunks_equal(gz, whole, 4096);
  }
  // A colour declared TYPE F, written as the float whose bits pack it (0x00RRGGBB: a subnormal
  // float), 9 significant digits: the colour is those bits, as PCL reads them.
  {
    std::ostringstream out;
    out << "VERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 300\nHEIGHT 1\nPOINTS 300\nDATA ascii\n";
    std::vector<std::uint8_t> want;
    char buf[64];
    for (std::uint32_t i = 0; i < 300; ++i) {
      const std::uint32_t c = (i * 40503u) & 0xFFFFFFu;
      float f = 0.0f;
      std::memcpy(&f, &c, 4);
      std::snprintf(buf, sizeof buf, "%u 0 1 %.9g\n", i, static_cast<double>(f));
      out << buf;
      want.insert(want.end(), {static_cast<std::uint8_t>(c >> 16), static_cast<std::uint8_t>(c >> 8), static_cast<std::uint8_t>(c)});
    }
    hc::test::write_bytes(dir / "float_rgb.pcd", out.str());
    const Cloud whole = expect_whole_read_is_pcls(dir / "float_rgb.pcd");
    EXPECT_EQ(whole.rgb, want);
    (void)expect_chunks_equal(dir / "float_rgb.pcd", whole, 7);
  }
  // Integer fields: int8 x, int16 y, int32 z, a U4 rgb and a uint16 intensity, the extremes of
  // each range read (PCL's reader the oracle); int64 and uint64 against the values written (PCL
  // 1.13 reads them through a double, wrong at the ends of their ranges); decimals whose values
  // are integers ("255.000000", "1e3", "-0") against the values written (PCL's stream parse
  // reads "1e3" as 1); one value past a range, a fraction, a minus sign on an unsigned field, "nan"
  // or "+-1" refuses the file on its line, whole and streamed, and so does a header declaring more
  // points than its body's bytes can hold (before anything is sized for them).
  const std::string head =
      "VERSION 0.7\nFIELDS x y z rgb intensity\nSIZE 1 2 4 4 2\nTYPE I I I U U\nCOUNT 1 1 1 1 1\nWIDTH 4\nHEIGHT 1\nPOINTS 4\nDATA ascii\n";
  const std::string two = "-128 32767 -2147483648 4294967295 65535\n127 -32768 2147483647 0 0\n";
  hc::test::write_bytes(dir / "ints.pcd", head + two + "+5 0 1 16777215 1\n0 0 0 255 7\n");
  {
    const Cloud whole = expect_whole_read_is_pcls(dir / "ints.pcd");
    EXPECT_EQ(whole.xyz(0, 0), -128.0);
    EXPECT_EQ(whole.xyz(1, 1), -32768.0);
    EXPECT_EQ(whole.xyz(2, 1), 2147483647.0);
    EXPECT_EQ(whole.xyz(0, 2), 5.0);
    EXPECT_EQ(whole.rgb, (std::vector<std::uint8_t>{255, 255, 255, 0, 0, 0, 255, 255, 255, 0, 0, 255}));
    EXPECT_EQ(whole.intensity, (std::vector<float>{65535.0f, 0.0f, 1.0f, 7.0f}));
    (void)expect_chunks_equal(dir / "ints.pcd", whole, 1);
  }
  hc::test::write_bytes(dir / "ints64.pcd", "VERSION 0.7\nFIELDS x y z\nSIZE 8 8 4\nTYPE I U F\nWIDTH 2\nPOINTS 2\nDATA ascii\n"
                                            "-9223372036854775808 18446744073709551615 1\n9007199254740993 9007199254740993 2\n");
  {
    const Cloud whole = hc::pipeline::load_cloud(dir / "ints64.pcd").value;
    ASSERT_EQ(whole.size(), 2U);
    EXPECT_EQ(whole.xyz(0, 0), -9223372036854775808.0);
    EXPECT_EQ(whole.xyz(1, 0), 18446744073709551615.0);
    EXPECT_EQ(whole.xyz(0, 1), 9007199254740992.0);  // 2^53 + 1 rounds to even as a double
    EXPECT_EQ(whole.xyz(1, 1), 9007199254740992.0);
    (void)expect_chunks_equal(dir / "ints64.pcd", whole, 1);
  }
  hc::test::write_bytes(dir / "decimals.pcd", "VERSION 0.7\nFIELDS x y z rgb intensity\nSIZE 4 2 8 4 2\nTYPE I U I U U\nWIDTH 2\nPOINTS 2\n"
                                              "DATA ascii\n1.0 -0 1e3 255.000000 7.0\n-2.5e1 +0 -0.0 1.6777215e7 65535.0\n");
  {
    const Cloud whole = hc::pipeline::load_cloud(dir / "decimals.pcd").value;
    ASSERT_EQ(whole.size(), 2U);
    EXPECT_EQ(whole.xyz.col(0), Eigen::Vector3d(1.0, 0.0, 1000.0));
    EXPECT_EQ(whole.xyz.col(1), Eigen::Vector3d(-25.0, 0.0, 0.0));
    EXPECT_EQ(whole.rgb, (std::vector<std::uint8_t>{0, 0, 255, 255, 255, 255}));
    EXPECT_EQ(whole.intensity, (std::vector<float>{7.0f, 65535.0f}));
    (void)expect_chunks_equal(dir / "decimals.pcd", whole, 1);
  }
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"x_past.pcd", "128 0 0 0 0"},        {"y_fraction.pcd", "0 1.5 0 0 0"}, {"rgb_sign.pcd", "0 0 0 -5 0"},
      {"intensity_past.pcd", "0 0 0 0 70000"}, {"z_nan.pcd", "0 0 nan 0 0"},    {"z_past.pcd", "0 0 2147483648 0 0"},
      {"plus_minus.pcd", "0 0 +-1 0 0"},    {"rgb_minus_decimal.pcd", "0 0 0 -1.0 0"}};
  for (const auto& [name, line] : bad) hc::test::write_bytes(dir / name, head + two + line + "\n0 0 0 0 0\n");
  // 3·10^6 points declared, one data line and 3·10^6 line ends; a DATA line the file ends in.
  const std::string bomb = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 3000000\nPOINTS 3000000\nDATA ascii\n1 2 3\n" + std::string(3000000, '\n');
  hc::test::write_bytes(dir / "bomb.pcd", bomb);
  hc::test::write_gzip(dir / "bomb.pcd.gz", bomb);
  const std::string bare = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nPOINTS 1\nDATA ascii";
  hc::test::write_bytes(dir / "bare.pcd", bare);
  hc::test::write_gzip(dir / "bare.pcd.gz", bare);
  expect_stream_fails_as_whole_read_at_any_point(dir, {"x_past.pcd", "y_fraction.pcd", "rgb_sign.pcd", "intensity_past.pcd", "z_nan.pcd", "z_past.pcd",
                                                       "plus_minus.pcd", "rgb_minus_decimal.pcd", "bomb.pcd", "bomb.pcd.gz", "bare.pcd", "bare.pcd.gz"});
  const auto says = [&](const std::string& name, const std::string& text) {
    const std::string what = hc::test::error_of([&] { hc::pipeline::load_cloud(dir / name); });
    EXPECT_NE(what.find(text), std::string::npos) << what;
  };
  says("x_past.pcd", "x_past.pcd': data line 3: field 'x' (TYPE I SIZE 1) holds '128': expected an integer from -128 to 127");
  says("y_fraction.pcd", "data line 3: field 'y' (TYPE I SIZE 2) holds '1.5': expected an integer from -32768 to 32767");
  says("rgb_sign.pcd", "data line 3: field 'rgb' (TYPE U SIZE 4) holds '-5': expected an integer from 0 to 4294967295");
  says("intensity_past.pcd", "field 'intensity' (TYPE U SIZE 2) holds '70000': expected an integer from 0 to 65535");
  says("z_nan.pcd", "field 'z' (TYPE I SIZE 4) holds 'nan'");
  says("z_past.pcd", "holds '2147483648': expected an integer from -2147483648 to 2147483647");
  says("plus_minus.pcd", "data line 3: '+-1' is not a number");
  says("rgb_minus_decimal.pcd", "field 'rgb' (TYPE U SIZE 4) holds '-1.0': expected an integer from 0 to 4294967295");
  for (const char* name : {"bomb.pcd", "bomb.pcd.gz"}) {
    says(name, "truncated: the header declares 3000000 points of 3 values, but the 3000006 bytes after it hold at most 500001 data lines");
  }
  for (const char* name : {"bare.pcd", "bare.pcd.gz"}) says(name, "truncated: the header declares 1 points of 3 values, but the 0 bytes after it hold at most 0 data lines");
}

// A binary PLY whose vertex element holds list properties (records of their own lengths) among
// its scalars: x float, a list of r mod 6 ints (count type `count`), y double, red green blue,
// a list of r mod 3 floats (ushort count), z float; then an element "extra" of 3 bytes. Vertex r
// has x = r/1000 + 1/3, y = −r, z = r²·10⁻⁶, colour (r, 2r, 3r) mod 256.
// negative_at: the vertex whose first list count is −1 (a char count), or none.
fs::path write_ply_vertex_lists(const fs::path& p, std::size_t n, bool big_endian, const std::string& count = "uchar",
                                std::size_t negative_at = std::numeric_limits<std::size_t>::max()) {
  std::ofstream out(p, std::ios::binary);
  out << "ply\nformat " << (big_endian ? "binary_big_endian" : "binary_little_endian") << " 1.0\n";
  out << "element vertex " << n << "\nproperty float x\nproperty list " << count << " int ids\nproperty double y\n"
      << "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty list ushort float w\nproperty float z\n"
      << "element extra 3\nproperty uchar k\nend_header\n";
  auto put = [&](auto v) {
    char b[sizeof v];
    std::memcpy(b, &v, sizeof v);
    if (big_endian) std::reverse(b, b + sizeof v);
    out.write(b, sizeof v);
  };
  for (std::size_t r = 0; r < n; ++r) {
    put(static_cast<float>(static_cast<double>(r) * 0.001 + 1.0 / 3.0));
    const int items = r == negative_at ? -1 : static_cast<int>(r % 6);
    if (count == "char") {
      put(static_cast<std::int8_t>(items));
    } else {
      put(static_cast<std::uint8_t>(items));
    }
    for (int k = 0; k < items; ++k) put(static_cast<std::int32_t>(r + static_cast<std::size_t>(k)));
    put(-static_cast<double>(r));
    put(static_cast<std::uint8_t>(r % 256));
    put(static_cast<std::uint8_t>((2 * r) % 256));
    put(static_cast<std::uint8_t>((3 * r) % 256));
    put(static_cast<std::uint16_t>(r % 3));
    for (std::size_t k = 0; k < r % 3; ++k) put(static_cast<float>(k) + 0.5f);
    put(static_cast<float>(static_cast<double>(r * r) * 1e-6));
  }
  for (int k = 0; k < 3; ++k) put(static_cast<std::uint8_t>(k));
  return p;
}

// Until 2026-11-27 a binary PLY with list properties in its vertex element was read whole at
// every pass of a tiled run. Now its records are walked from blocks of 1 MiB or more as they
// are read (here about 4.3 MB of them), little and big endian and under gzip. Oracles: the whole
// read (load_cloud), bit for bit with colour, and the values written; its errors, word for word,
// sticky, where the read reaches them: a negative list count at vertex 90 000 and data that end
// inside vertex 100 000.
TEST(PointStream, BinaryPlyWithListsInItsVerticesStreamsAsTheWholeRead) {
  const fs::path dir = hc::test::temp_dir("ply_vertex_lists");
  for (const bool big : {false, true}) {
    const fs::path p = write_ply_vertex_lists(dir / (big ? "be.ply" : "le.ply"), 120001, big);
    const fs::path gz = dir / (p.filename().string() + ".gz");
    hc::test::write_gzip(gz, hc::test::read_bytes(p), 2);
    for (const fs::path& f : {p, gz}) {
      SCOPED_TRACE(f.filename().string());
      const Cloud whole = hc::pipeline::load_cloud(f).value;
      ASSERT_EQ(whole.size(), 120001U);
      EXPECT_EQ(whole.xyz(0, 120000), static_cast<double>(static_cast<float>(120.0 + 1.0 / 3.0)));
      EXPECT_EQ(whole.xyz(1, 12345), -12345.0);
      EXPECT_EQ(whole.xyz(2, 1000), static_cast<double>(static_cast<float>(1.0)));
      ASSERT_TRUE(whole.has_rgb());
      EXPECT_EQ(whole.rgb[3 * 300 + 1], 600 % 256);
      for (const std::size_t chunk : {std::size_t{7}, std::size_t{1000}, std::size_t{1} << 20}) {
        const auto s = expect_chunks_equal(f, whole, chunk);
        EXPECT_EQ(s->total_points(), 120001U);
        bool said = false;
        for (const std::string& n : s->notes()) said = said || n.find("records with list properties streamed in chunks") != std::string::npos;
        EXPECT_TRUE(said);
      }
    }
  }
  // All axes float (float32_xyz as the whole read says), and one vertex whose list of 300 000
  // ints (1.2 MB) is larger than the stream's block.
  {
    const fs::path p = dir / "floats_long_list.ply";
    std::ofstream out(p, std::ios::binary);
    out << "ply\nformat binary_little_endian 1.0\nelement vertex 5000\nproperty float x\nproperty float y\n"
        << "property list uint int ids\nproperty float z\nend_header\n";
    for (std::uint32_t r = 0; r < 5000; ++r) {
      const float xy[2] = {0.5f * static_cast<float>(r), -static_cast<float>(r)};
      const std::uint32_t items = r == 2500 ? 300000 : r % 4;
      out.write(reinterpret_cast<const char*>(xy), sizeof xy);
      out.write(reinterpret_cast<const char*>(&items), sizeof items);
      for (std::uint32_t k = 0; k < items; ++k) out.write(reinterpret_cast<const char*>(&k), sizeof k);
      const float z = 0.25f * static_cast<float>(r % 7);
      out.write(reinterpret_cast<const char*>(&z), sizeof z);
    }
    out.close();
    const Cloud whole = hc::pipeline::load_cloud(p).value;
    ASSERT_EQ(whole.size(), 5000U);
    EXPECT_TRUE(whole.float32_xyz);
    EXPECT_EQ(whole.xyz(0, 2501), 1250.5);
    EXPECT_EQ(whole.xyz(2, 2501), 0.25 * (2501 % 7));
    for (const std::size_t chunk : {std::size_t{3}, std::size_t{2600}, std::size_t{1} << 20}) {
      (void)expect_chunks_equal(p, whole, chunk);
      auto s = hc::pipeline::open_point_stream(p);
      Cloud c;
      ASSERT_TRUE(s->next(c, chunk));
      EXPECT_TRUE(c.float32_xyz);
    }
  }
  const fs::path negative = write_ply_vertex_lists(dir / "negative.ply", 120001, false, "char", 90000);
  EXPECT_NE(expect_stream_fails_as_whole_read(negative, 5000).find("vertex 90000: list property 'ids' has the negative item count -1"),
            std::string::npos);
  const std::string bytes = hc::test::read_bytes(write_ply_vertex_lists(dir / "whole.ply", 120001, false));
  // Vertex r's record: 4 + 1 + 4·(r mod 6) + 8 + 3 + 2 + 4·(r mod 3) + 4 = 22 + … bytes.
  std::size_t at = bytes.find("end_header\n") + 11;
  for (std::size_t r = 0; r < 100000; ++r) at += 22 + 4 * (r % 6) + 4 * (r % 3);
  std::ofstream(dir / "cut.ply", std::ios::binary) << bytes.substr(0, at + 10);
  hc::test::write_gzip(dir / "cut.ply.gz", bytes.substr(0, at + 10));
  for (const char* cut : {"cut.ply", "cut.ply.gz"}) {
    SCOPED_TRACE(cut);
    EXPECT_NE(expect_stream_fails_as_whole_read(dir / cut, 5000).find("the data ends inside vertex 100000 (100000 whole vertices)"),
              std::string::npos);
  }
  // Under gzip the data's size is known only at its end: a header declaring more vertices than
  // bytes follow it (here 120 001 vertices and 1 000 bytes) gets the whole read's header words
  // there, and so does a fixed-stride element before the vertices that the data end inside
  // (plain and gzip); a plain file's header check runs when it opens.
  const std::size_t header = bytes.find("end_header\n") + 11;
  hc::test::write_gzip(dir / "few.ply.gz", bytes.substr(0, header + 1000));
  EXPECT_NE(expect_stream_fails_as_whole_read(dir / "few.ply.gz", 5000).find("the header declares 120001 vertices but only 1000 bytes follow it"),
            std::string::npos);
  {
    std::string before = bytes.substr(0, header);
    before.replace(before.find("element vertex 120001"), 21, "element junk 1000\nproperty double a\nelement vertex 10");
    const std::string cut_junk = before + std::string(4000, '\0');
    std::ofstream(dir / "in_junk.ply", std::ios::binary) << cut_junk;
    hc::test::write_gzip(dir / "in_junk.ply.gz", cut_junk);
    for (const char* f : {"in_junk.ply", "in_junk.ply.gz"}) {
      SCOPED_TRACE(f);
      const std::string whole = hc::test::error_of([&] { hc::pipeline::load_cloud(dir / f); });
      EXPECT_NE(whole.find("the data ends inside element 'junk' (500 of 1000 records)"), std::string::npos) << whole;
      EXPECT_EQ(hc::test::error_of([&] {
                  auto s = hc::pipeline::open_point_stream(dir / f);
                  Cloud c;
                  while (s->next(c, 5000)) {
                  }
                }),
                whole);
    }
  }
}

// An OBJ of about 9 MB (more than one read block): 120 000 vertices with colour (v x y z r g b,
// values outside [0, 1] among them), texture coordinates, normals, groups, materials, comments,
// CRLF ends, faces in every corner form with absolute and relative indices, polygons, plain and
// gzip-compressed. With input.as_points the vertices stream: every chunking gives load_cloud's points and colour,
// and total_points counts them; without it the file is a mesh, refused by open_point_stream as
// before. A vertex without colour drops the colour of all, as read_obj does. A bad vertex, a
// bad texture coordinate and a bad face corner past the first read block fail as load_cloud
// fails, and stay failed; a file without a vertex fails with load_cloud's words.
fs::path write_obj(const fs::path& p, std::size_t vertices, bool colour_all = true, const std::string& bad = "",
                   std::size_t bad_at = 0) {
  std::ofstream out(p, std::ios::binary);
  out << "# generated by point_stream_test\r\nmtllib none.mtl\r\no wall\r\n";
  for (std::size_t k = 0; k < vertices; ++k) {
    if (bad_at != 0 && k == bad_at) out << bad << "\r\n";
    const double x = 0.001 * static_cast<double>(k % 300), y = -0.001 * static_cast<double>(k / 300), z = 1e-5 * static_cast<double>(k % 37);
    out << "v " << x << ' ' << y << ' ' << z;
    if (colour_all || k != vertices / 2) out << ' ' << 0.003 * static_cast<double>(k % 400) - 0.1 << " 0.5 1";
    out << "\r\n";
    if (k % 4 == 3) {
      out << "vt 0." << k % 10 << " 0.5\r\nvn 0 0 1\r\n";
      if (k % 1000 == 3) out << "usemtl stone\r\ng part\r\n";
      out << "f " << k - 2 << "/1 " << k - 1 << "/2/1 " << k << "//1\r\n";  // absolute (1-based)
      out << "f -1 -2 -3 -4\r\n";                                          // relative: a quad
    }
  }
  return p;
}

TEST(PointStream, ObjVerticesStreamWithInputAsPointsAsTheWholeReadGivesThem) {
  const fs::path dir = hc::test::temp_dir("obj");
  hc::pipeline::LoadOptions points;
  points.as_points = true;
  const fs::path p = write_obj(dir / "wall.obj", 120000);
  const fs::path plain = write_obj(dir / "plain.obj", 120000, false);
  const fs::path gz = dir / "wall.obj.gz";
  hc::test::write_gzip(gz, hc::test::read_bytes(p), 2);
  for (const fs::path& f : {p, plain, gz}) {
    SCOPED_TRACE(f.filename().string());
    const auto whole_read = hc::pipeline::load_cloud(f, points);
    const Cloud& whole = whole_read.value;
    ASSERT_EQ(whole.size(), 120000U);
    EXPECT_FALSE(whole.has_mesh());
    EXPECT_EQ(whole.has_rgb(), f != plain);
    for (const std::size_t chunk : {std::size_t{7}, std::size_t{1000}, std::size_t{1} << 20}) {
      auto s = hc::pipeline::open_point_stream(f, points);
      EXPECT_TRUE(s->streamed());
      EXPECT_EQ(s->total_points(), 120000U);
      const Cloud got = read_with_intensity(*s, chunk);
      ASSERT_EQ(got.size(), whole.size()) << "chunk " << chunk;
      EXPECT_TRUE(same_xyz(got.xyz, whole.xyz)) << "chunk " << chunk;
      EXPECT_EQ(got.rgb, whole.rgb) << "chunk " << chunk;
      EXPECT_EQ(s->notes().back(), "lines streamed in chunks");
    }
  }
  // Colour clamped to [0, 1] as read_obj clamps it: vertex 0 has r = -0.1, vertex 399 r = 1.097.
  const Cloud coloured = hc::pipeline::load_cloud(p, points).value;
  EXPECT_EQ(coloured.rgb[0], 0);
  EXPECT_EQ(coloured.rgb[3 * 399], 255);
  EXPECT_EQ(coloured.rgb[3 * 100], static_cast<std::uint8_t>(std::lround(0.2f * 255.0f)));
  // Without input.as_points the file is a mesh: not streamed, refused as before.
  const std::string mesh = hc::test::error_of([&] { hc::pipeline::open_point_stream(p); });
  EXPECT_NE(mesh.find("is a mesh"), std::string::npos) << mesh;
  // A vertex-only OBJ streams without input.as_points.
  {
    std::ofstream out(dir / "cloud.obj");
    for (int i = 0; i < 5000; ++i) out << "v " << i << " 0.5 " << -i << "\n";
  }
  EXPECT_TRUE(hc::pipeline::open_point_stream(dir / "cloud.obj")->streamed());
  expect_stream_equals_load_cloud(dir / "cloud.obj", "lines streamed in chunks");
}

TEST(PointStream, ObjErrorsAreTheWholeReadsAndStick) {
  const fs::path dir = hc::test::temp_dir("obj_bad");
  hc::pipeline::LoadOptions points;
  points.as_points = true;
  const struct {
    const char* line;
    const char* says;
  } bad[] = {{"v 1.0 2.0 zz", "'zz' is not a number"},
             {"vt north", "malformed texture coordinate line"},
             {"f 1/2 3/x 4", "malformed face corner '3/x'"},
             {"f 1 0 2", "malformed face corner '0'"}};
  for (const auto& b : bad) {
    SCOPED_TRACE(b.line);
    const fs::path f = write_obj(dir / "bad.obj", 100000, true, b.line, 90000);
    const std::string whole = hc::test::error_of([&] { hc::pipeline::load_cloud(f, points); });
    EXPECT_NE(whole.find(b.says), std::string::npos) << whole;
    EXPECT_NE(whole.find("bad.obj"), std::string::npos) << whole;
    auto s = hc::pipeline::open_point_stream(f, points);
    ASSERT_TRUE(s->streamed());
    Cloud c;
    std::size_t given = 0;
    EXPECT_EQ(hc::test::error_of([&] {
                while (s->next(c, 4096)) given += c.size();
              }),
              whole);
    EXPECT_LE(given, 90000U);
    const std::string again = hc::test::error_of([&] { s->next(c, 10); });
    EXPECT_NE(again.find("failed earlier"), std::string::npos) << again;
  }
  {
    std::ofstream(dir / "none.obj") << "# no vertex\nvt 0 0\ng empty\n";
  }
  const std::string none = hc::test::error_of([&] { hc::pipeline::load_cloud(dir / "none.obj", points); });
  EXPECT_NE(none.find("holds no vertices"), std::string::npos) << none;
  auto empty = hc::pipeline::open_point_stream(dir / "none.obj", points);
  EXPECT_EQ(empty->total_points(), 0U);
  Cloud c;
  EXPECT_EQ(hc::test::error_of([&] { empty->next(c, 10); }), none);
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

// A binary PLY whose element with a list property comes before its vertices: an element "junk"
// of `junk` shorts, then "camera" (`cameras` records: float f, a list of r mod 7 ints with a
// `count` count type, a short), then `n` float x y z vertices with the values write_ply writes.
// negative_at: the record whose list count is −1 (a char count), or none.
fs::path write_ply_lists_first(const fs::path& dir, const std::string& stem, std::size_t n, std::size_t cameras, bool big_endian,
                               const std::string& count = "uchar", std::size_t junk = 1000,
                               std::size_t negative_at = std::numeric_limits<std::size_t>::max()) {
  const fs::path p = dir / (stem + ".ply");
  std::ofstream out(p, std::ios::binary);
  out << "ply\nformat " << (big_endian ? "binary_big_endian" : "binary_little_endian") << " 1.0\n";
  out << "element junk " << junk << "\nproperty short a\n";
  out << "element camera " << cameras << "\nproperty float f\nproperty list " << count << " int ids\nproperty short s\n";
  out << "element vertex " << n << "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  auto put = [&](auto v) {
    char b[sizeof v];
    std::memcpy(b, &v, sizeof v);
    if (big_endian) std::reverse(b, b + sizeof v);
    out.write(b, sizeof v);
  };
  for (std::size_t j = 0; j < junk; ++j) put(static_cast<std::int16_t>(j));
  for (std::size_t r = 0; r < cameras; ++r) {
    put(static_cast<float>(r) * 0.5f);
    const int items = r == negative_at ? -1 : static_cast<int>(r % 7);
    if (count == "char") {
      put(static_cast<std::int8_t>(items));
    } else {
      put(static_cast<std::uint8_t>(items));
    }
    for (int k = 0; k < items; ++k) put(static_cast<std::int32_t>(r * 10 + static_cast<std::size_t>(k)));
    put(static_cast<std::int16_t>(-static_cast<int>(r % 1000)));
  }
  for (std::size_t i = 0; i < n; ++i) {
    put(static_cast<float>(static_cast<double>(i) * 0.001 + 1.0 / 3.0));
    put(static_cast<float>(-static_cast<double>(i)));
    put(static_cast<float>(static_cast<double>(i * i) * 1e-6));
  }
  return p;
}

// Until 2026-11-26 a binary PLY with list properties before its vertices was read whole at every
// pass of a tiled run. Now the elements before the vertices are walked from the source at each
// pass (about 3.8 MB of camera records here, more than the walk's 1 MiB blocks), and the
// vertices stream. Oracles: the whole read (load_cloud), bit for bit, and the values written;
// its errors, word for word.
TEST(PointStream, BinaryPlyWithListsBeforeItsVerticesStreamsAsTheWholeRead) {
  const fs::path dir = hc::test::temp_dir("ply_lists_first");
  for (const bool big : {false, true}) {
    const fs::path p = write_ply_lists_first(dir, big ? "be" : "le", 30001, 200000, big);
    const fs::path gz = dir / (p.filename().string() + ".gz");
    hc::test::write_gzip(gz, hc::test::read_bytes(p), 2);
    for (const fs::path& f : {p, gz}) {
      SCOPED_TRACE(f.filename().string());
      const Cloud whole = hc::pipeline::load_cloud(f).value;
      ASSERT_EQ(whole.size(), 30001U);
      EXPECT_NEAR(whole.xyz(0, 30000), 30.0 + 1.0 / 3.0, 1e-5);
      EXPECT_EQ(whole.xyz(1, 12345), -12345.0);
      for (const std::size_t chunk : {std::size_t{7}, std::size_t{30001}, std::size_t{1} << 20}) {
        const auto s = expect_chunks_equal(f, whole, chunk);
        EXPECT_EQ(s->total_points(), 30001U);
      }
    }
  }
  // Errors: a negative list count (record 150000, past the first block), a file that ends inside
  // the camera element, one that ends inside the fixed-stride element before it, and a camera
  // element that leaves too few bytes for the vertices: each refused when the stream opens, with
  // load_cloud's words.
  const fs::path negative = write_ply_lists_first(dir, "negative", 100, 200000, false, "char", 1000, 150000);
  const fs::path cut = write_ply_lists_first(dir, "cut", 100, 200000, false);
  const std::string bytes = hc::test::read_bytes(cut);
  const std::size_t header = bytes.find("end_header\n") + 11;
  {
    std::ofstream(dir / "in_cameras.ply", std::ios::binary) << bytes.substr(0, header + 2000 + 2'000'000);
    std::ofstream(dir / "in_junk.ply", std::ios::binary) << bytes.substr(0, header + 1001);
    std::ofstream(dir / "in_vertices.ply", std::ios::binary) << bytes.substr(0, bytes.size() - 5);
  }
  hc::test::write_gzip(dir / "in_cameras.ply.gz", bytes.substr(0, header + 2000 + 2'000'000));
  const struct {
    fs::path file;
    const char* says;
  } bad[] = {{negative, "camera 150000: list property 'ids' has the negative item count -1"},
             {dir / "in_cameras.ply", "truncated: the data ends inside element 'camera'"},
             {dir / "in_cameras.ply.gz", "truncated: the data ends inside element 'camera'"},
             {dir / "in_junk.ply", "truncated: the data ends inside element 'junk' (500 of 1000 records)"},
             {dir / "in_vertices.ply", "truncated"}};
  for (const auto& b : bad) {
    SCOPED_TRACE(b.file.filename().string());
    const std::string whole = hc::test::error_of([&] { hc::pipeline::load_cloud(b.file); });
    EXPECT_NE(whole.find(b.says), std::string::npos) << whole;
    EXPECT_EQ(hc::test::error_of([&] { hc::pipeline::open_point_stream(b.file); }), whole);
  }
}

}  // namespace
