// LAZ reader (issue "Scanner data in", LAZ part): every decoded point of a LAZ sample equals
// the same file's uncompressed LAS twin (data/scans/scanner_samples/, PDAL test data), read by
// the independent LAS reader; header counts and bounds are read from the LAZ file's own header
// bytes here; damaged files (truncated, unsupported compressor, unknown item) are clear
// hc::InputErrors.

#include "hc/common/error.hpp"
#include "hc/pipeline/ingest.hpp"
#include "error_of.hpp"
#include "test_paths.hpp"
#include "file_bytes.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

namespace hp = hc::pipeline;
namespace fs = std::filesystem;

namespace {

using hc::test::le;

using hc::test::read_bytes;
using hc::test::write_bytes;

using hc::test::error_of;

/// Keep every point (no classification dropped), so both files give all their records.
const hp::LoadOptions kKeepAll{{}};

/// One point as the Cloud holds it: x y z, intensity, r g b.
using Row = std::tuple<double, double, double, float, int, int, int>;

std::vector<Row> rows(const hp::Cloud& c) {
  std::vector<Row> out;
  for (std::size_t i = 0; i < c.size(); ++i) {
    const auto k = static_cast<Eigen::Index>(i);
    out.emplace_back(c.xyz(0, k), c.xyz(1, k), c.xyz(2, k), c.has_intensity() ? c.intensity[i] : -1.0f,
                     c.has_rgb() ? c.rgb[3 * i] : -1, c.has_rgb() ? c.rgb[3 * i + 1] : -1,
                     c.has_rgb() ? c.rgb[3 * i + 2] : -1);
  }
  return out;
}

/// One point on the integer grid of a scale (x y z in steps of `scale`, rounded), intensity,
/// r g b: for files whose offsets differ (a COPC file re-centres them), so that the doubles
/// X·scale + offset differ in the last bits while the points are the same.
using GridRow = std::tuple<long long, long long, long long, float, int, int, int>;

std::vector<GridRow> grid_rows(const hp::Cloud& c, double scale) {
  std::vector<GridRow> out;
  for (const Row& r : rows(c)) {
    out.emplace_back(std::llround(std::get<0>(r) / scale), std::llround(std::get<1>(r) / scale),
                     std::llround(std::get<2>(r) / scale), std::get<3>(r), std::get<4>(r), std::get<5>(r),
                     std::get<6>(r));
  }
  return out;
}

/// Offset of the LASzip VLR's payload (user id "laszip encoded", record 22204) in a LAZ file,
/// found by walking the VLR headers (54 bytes each) from the header size.
std::size_t laszip_payload(const std::string& b) {
  std::size_t at = le<std::uint16_t>(b, 94);
  const std::uint32_t n = le<std::uint32_t>(b, 100);
  for (std::uint32_t i = 0; i < n; ++i) {
    const std::string user(b.data() + at + 2, 14);
    const std::uint16_t id = le<std::uint16_t>(b, at + 18);
    if (user == "laszip encoded" && id == 22204) return at + 54;
    at += 54 + le<std::uint16_t>(b, at + 20);
  }
  ADD_FAILURE() << "no LASzip VLR";
  return 0;
}

}  // namespace

TEST(LazReader, PointWiseEqualsItsLasTwinPointByPoint) {
  const fs::path laz = hc::test::scan_path("scanner_samples/laz/pdal-simple.laz");
  const fs::path las = hc::test::scan_path("scanner_samples/las/pdal-simple.las");
  const std::string head = read_bytes(laz);
  ASSERT_GE(head.size(), 227u);
  EXPECT_EQ(static_cast<unsigned char>(head[104]), 0x80u | 3u);  // compressed point format 3
  const std::uint32_t count = le<std::uint32_t>(head, 107);
  ASSERT_EQ(count, 1065u);

  const auto z = hp::load_cloud(laz, kKeepAll);
  const auto s = hp::load_cloud(las, kKeepAll);
  ASSERT_EQ(z.value.size(), count);
  ASSERT_EQ(s.value.size(), count);
  ASSERT_TRUE(z.value.has_intensity());
  ASSERT_TRUE(z.value.has_rgb());
  const std::vector<Row> a = rows(z.value), b = rows(s.value);
  for (std::size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a[i], b[i]) << "point " << i;
  }
  // The classification decodes too: the default drop classes keep the same points in both.
  EXPECT_EQ(hp::load_cloud(laz).value.size(), hp::load_cloud(las).value.size());
  const auto& notes = z.report.notes;
  EXPECT_TRUE(std::any_of(notes.begin(), notes.end(), [](const std::string& n) {
    return n.find("compressor 2 (point-wise chunked)") != std::string::npos &&
           n.find("POINT10 v2, GPSTIME11 v2, RGB12 v2") != std::string::npos;
  }));
}

TEST(LazReader, AutzenHeaderCountBoundsAndLas14Twin) {
  const fs::path laz = hc::test::scan_path("scanner_samples/laz/pdal-autzen_trim.laz");
  const std::string b = read_bytes(laz);
  ASSERT_GE(b.size(), 227u);
  const std::uint32_t count = le<std::uint32_t>(b, 107);
  EXPECT_EQ(count, 110000u);
  double scale[3], hi[3], lo[3];
  for (int a = 0; a < 3; ++a) {
    scale[a] = le<double>(b, 131 + 8 * a);
    hi[a] = le<double>(b, 179 + 16 * a);
    lo[a] = le<double>(b, 187 + 16 * a);
  }
  const auto z = hp::load_cloud(laz, kKeepAll).value;
  ASSERT_EQ(z.size(), count);
  for (int a = 0; a < 3; ++a) {
    const double mn = z.xyz.row(a).minCoeff(), mx = z.xyz.row(a).maxCoeff();
    // The header bounds are the extremes of the scaled coordinates (to within half a step).
    EXPECT_NEAR(mn, lo[a], 0.5 * scale[a] + 1e-9) << "axis " << a;
    EXPECT_NEAR(mx, hi[a], 0.5 * scale[a] + 1e-9) << "axis " << a;
    EXPECT_GT(scale[a], 0.0);
  }

  // The LAS 1.4 point format 7 twin holds the same Autzen points: compare point by point when
  // the order matches, else as sorted sets.
  const auto s = hp::load_cloud(hc::test::scan_path("scanner_samples/las/pdal-autzen_trim_7.las"), kKeepAll).value;
  ASSERT_EQ(s.size(), z.size());
  std::vector<Row> a = rows(z), c = rows(s);
  if (a != c) {
    std::sort(a.begin(), a.end());
    std::sort(c.begin(), c.end());
  }
  EXPECT_TRUE(a == c);
}

TEST(LazReader, CopcLayeredEqualsLasTwinAsASet) {
  const fs::path copc = hc::test::scan_path("scanner_samples/laz/pdal-1.2-with-color.copc.laz");
  const std::string b = read_bytes(copc);
  ASSERT_GE(b.size(), 375u);
  EXPECT_EQ(static_cast<unsigned char>(b[104]), 0x80u | 7u);  // compressed point format 7
  const std::uint64_t count = le<std::uint64_t>(b, 247);
  EXPECT_EQ(count, 1065u);
  const auto z = hp::load_cloud(copc, kKeepAll);
  const auto s = hp::load_cloud(hc::test::scan_path("scanner_samples/las/pdal-simple.las"), kKeepAll);
  ASSERT_EQ(z.value.size(), count);
  // Both files store coordinates in steps of 0.01 (their headers); the offsets differ.
  const std::string twin = read_bytes(hc::test::scan_path("scanner_samples/las/pdal-simple.las"));
  const double step = le<double>(b, 131);
  for (int a = 0; a < 3; ++a) {
    ASSERT_EQ(le<double>(b, 131 + 8 * a), step);
    ASSERT_EQ(le<double>(twin, 131 + 8 * a), step);
  }
  std::vector<GridRow> a = grid_rows(z.value, step), c = grid_rows(s.value, step);
  ASSERT_EQ(a.size(), c.size());
  std::sort(a.begin(), a.end());
  std::sort(c.begin(), c.end());
  for (std::size_t i = 0; i < a.size(); ++i) ASSERT_EQ(a[i], c[i]) << "sorted point " << i;
  EXPECT_EQ(hp::load_cloud(copc).value.size(), hp::load_cloud(hc::test::scan_path("scanner_samples/las/pdal-simple.las")).value.size());
  const auto& notes = z.report.notes;
  EXPECT_TRUE(std::any_of(notes.begin(), notes.end(),
                          [](const std::string& n) { return n.find("COPC file: read as plain LAZ") != std::string::npos; }));
}

TEST(LazReader, TruncatedFilesAreClearErrors) {
  const fs::path dir = hc::test::temp_dir("lazcut");
  for (const char* name : {"pdal-simple.laz", "pdal-1.2-with-color.copc.laz"}) {
    const std::string good = read_bytes(hc::test::scan_path(std::string("scanner_samples/laz/") + name));
    ASSERT_GT(good.size(), 2000u);
    const std::size_t data = le<std::uint32_t>(good, 96);
    for (std::size_t cut : {std::size_t{100}, std::size_t{300}, data, data + 8, data + 200, good.size() / 2,
                            good.size() - 9, good.size() - 1}) {
      write_bytes(dir / "cut.laz", good.substr(0, cut));
      const std::string msg = error_of([&] { hp::load_cloud(dir / "cut.laz"); });
      EXPECT_NE(msg.find("load_cloud: '"), std::string::npos) << name << " cut at " << cut << ": " << msg;
      EXPECT_NE(msg.find("cut.laz"), std::string::npos) << name << " cut at " << cut << ": " << msg;
    }
  }
}

TEST(LazReader, UnsupportedCompressorAndItemsAreClearErrors) {
  const fs::path dir = hc::test::temp_dir("lazbad");
  const std::string good = read_bytes(hc::test::scan_path("scanner_samples/laz/pdal-simple.laz"));
  const std::size_t vlr = laszip_payload(good);
  ASSERT_GT(vlr, 0u);
  ASSERT_EQ(le<std::uint16_t>(good, vlr), 2u);       // compressor: point-wise chunked
  ASSERT_EQ(le<std::uint16_t>(good, vlr + 32), 3u);  // items: POINT10, GPSTIME11, RGB12
  ASSERT_EQ(le<std::uint16_t>(good, vlr + 34), 6u);

  std::string bad = good;
  bad[vlr] = 9;  // compressor 9
  write_bytes(dir / "comp.laz", bad);
  std::string msg = error_of([&] { hp::load_cloud(dir / "comp.laz"); });
  EXPECT_NE(msg.find("comp.laz"), std::string::npos) << msg;
  EXPECT_NE(msg.find("LASzip compressor 9"), std::string::npos) << msg;

  bad = good;
  bad[vlr + 2] = 1;  // coder 1
  write_bytes(dir / "coder.laz", bad);
  EXPECT_NE(error_of([&] { hp::load_cloud(dir / "coder.laz"); }).find("LASzip coder 1"), std::string::npos);

  bad = good;
  bad[vlr + 34] = 99;  // first item: type 99
  write_bytes(dir / "item.laz", bad);
  msg = error_of([&] { hp::load_cloud(dir / "item.laz"); });
  EXPECT_NE(msg.find("item type 99 version 2"), std::string::npos) << msg;

  bad = good;
  bad[vlr + 34 + 6 + 4] = 1;  // GPSTIME11 version 1
  write_bytes(dir / "version.laz", bad);
  msg = error_of([&] { hp::load_cloud(dir / "version.laz"); });
  EXPECT_NE(msg.find("GPSTIME11 version 1"), std::string::npos) << msg;

  bad = good;
  bad[vlr + 34 + 2] = 22;  // POINT10 of 22 bytes: items no longer sum to the record length
  write_bytes(dir / "size.laz", bad);
  msg = error_of([&] { hp::load_cloud(dir / "size.laz"); });
  EXPECT_NE(msg.find("expected 34 bytes"), std::string::npos) << msg;

  // GPSTIME11 declared 10 bytes and RGB12 4 (the sum still the record length): the item
  // decoders write 8 and 6 bytes (LAZ specification), so the file is refused, not misread.
  bad = good;
  bad[vlr + 34 + 6 + 2] = 10;
  bad[vlr + 34 + 12 + 2] = 4;
  write_bytes(dir / "itemsize.laz", bad);
  msg = error_of([&] { hp::load_cloud(dir / "itemsize.laz"); });
  EXPECT_NE(msg.find("itemsize.laz"), std::string::npos) << msg;
  EXPECT_NE(msg.find("GPSTIME11 version 2 (10 bytes)"), std::string::npos) << msg;

  // A plain LAS file named .laz has no LASzip VLR.
  write_bytes(dir / "plain.laz", read_bytes(hc::test::scan_path("scanner_samples/las/pdal-simple.las")));
  EXPECT_NE(error_of([&] { hp::load_cloud(dir / "plain.laz"); }).find("no LASzip VLR"), std::string::npos);
}
