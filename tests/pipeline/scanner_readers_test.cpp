// Scanner-format readers (issue 12): LAS 1.0–1.4 (point formats 0–10), PTX and PTS, on the
// shared real samples (data/scans/scanner_samples/) and small synthetic files, and the imperial
// units. Every expected value is computed here independently of the readers: LAS header fields
// and records by byte arithmetic on the file, PTX/PTS text with std::istringstream.

#include "hc/common/error.hpp"
#include "hc/common/units.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/mesh_raster.hpp"
#include "error_of.hpp"
#include "test_paths.hpp"
#include "file_bytes.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iomanip>
#include <sstream>
#include <string>
#include <vector>

namespace hp = hc::pipeline;
namespace fs = std::filesystem;

namespace {

using hc::test::le;

using hc::test::read_bytes;
using hc::test::write_bytes;

using hc::test::error_of;

bool has_note(const hp::StageReport& r, const std::string& text) {
  return std::any_of(r.notes.begin(), r.notes.end(), [&](const std::string& n) { return n.find(text) != std::string::npos; });
}

// ---------------------------------------------------------------------------------------------
// LAS oracle: little-endian field reads at the offsets of the LAS 1.4 R15 header table.

struct LasHeader {
  int minor = 0;
  std::size_t offset = 0, record_length = 0;
  int format = 0;
  std::uint64_t count = 0;
  double scale[3]{}, shift[3]{}, max[3]{}, min[3]{};
};

LasHeader las_header(const std::string& b) {
  LasHeader h;
  h.minor = static_cast<unsigned char>(b[25]);
  h.offset = le<std::uint32_t>(b, 96);
  h.format = static_cast<unsigned char>(b[104]);
  h.record_length = le<std::uint16_t>(b, 105);
  h.count = le<std::uint32_t>(b, 107);
  if (h.minor >= 4) h.count = le<std::uint64_t>(b, 247);
  for (int a = 0; a < 3; ++a) {
    h.scale[a] = le<double>(b, 131 + 8 * a);
    h.shift[a] = le<double>(b, 155 + 8 * a);
    h.max[a] = le<double>(b, 179 + 16 * a);
    h.min[a] = le<double>(b, 187 + 16 * a);
  }
  return h;
}

struct LasPoint {
  double xyz[3];
  std::uint16_t intensity;
  int cls;
  std::uint16_t rgb[3];
};

LasPoint las_point(const std::string& b, const LasHeader& h, std::size_t i) {
  const std::size_t at = h.offset + i * h.record_length;
  LasPoint p{};
  for (int a = 0; a < 3; ++a) p.xyz[a] = le<std::int32_t>(b, at + 4 * a) * h.scale[a] + h.shift[a];
  p.intensity = le<std::uint16_t>(b, at + 12);
  p.cls = h.format <= 5 ? (static_cast<unsigned char>(b[at + 15]) & 31) : static_cast<unsigned char>(b[at + 16]);
  const std::size_t c = h.format == 2 ? 20 : (h.format == 3 || h.format == 5) ? 28 : (h.format >= 7 && h.format != 9) ? 30 : 0;
  if (c) {
    for (int k = 0; k < 3; ++k) p.rgb[k] = le<std::uint16_t>(b, at + c + 2 * k);
  }
  return p;
}

bool las_has_rgb(int format) { return format == 2 || format == 3 || format == 5 || format == 7 || format == 8 || format == 10; }

struct LasSample {
  const char* file;
  std::uint64_t points;  // from the samples' README
  int format;
};

class LasSamples : public ::testing::TestWithParam<LasSample> {};

TEST_P(LasSamples, MatchesTheHeaderAndTheRecordsReadByteByByte) {
  const LasSample s = GetParam();
  const fs::path path = hc::test::scan_path(std::string("scanner_samples/las/") + s.file);
  const std::string b = read_bytes(path);
  const LasHeader h = las_header(b);
  ASSERT_EQ(h.count, s.points);
  ASSERT_EQ(h.format, s.format);

  // Keep every class: every record comes back.
  const auto r = hp::load_cloud(path, hp::LoadOptions{{}});
  const hp::Cloud& c = r.value;
  ASSERT_EQ(c.size(), h.count);
  ASSERT_EQ(c.intensity.size(), c.size());
  EXPECT_EQ(c.has_rgb(), las_has_rgb(h.format));
  EXPECT_FALSE(c.has_grid_index());

  // Bounding box against the header's (which writers round to the scale or better).
  for (int a = 0; a < 3; ++a) {
    const double tol = h.scale[a] * 0.51 + 1e-9 * std::abs(h.max[a]);
    EXPECT_NEAR(c.xyz.row(a).minCoeff(), h.min[a], tol) << "axis " << a;
    EXPECT_NEAR(c.xyz.row(a).maxCoeff(), h.max[a], tol) << "axis " << a;
  }

  // Colour: 16-bit scaled to 8 bit unless every stored value is already <= 255.
  std::uint16_t rgb_max = 0;
  std::vector<std::size_t> class_count(256, 0);
  for (std::size_t i = 0; i < h.count; ++i) {
    const LasPoint p = las_point(b, h, i);
    ++class_count[static_cast<std::size_t>(p.cls)];
    for (int k = 0; k < 3; ++k) rgb_max = std::max(rgb_max, p.rgb[k]);
  }
  for (const std::size_t i : {std::size_t{0}, static_cast<std::size_t>(h.count / 2), static_cast<std::size_t>(h.count - 1)}) {
    const LasPoint p = las_point(b, h, i);
    for (int a = 0; a < 3; ++a) EXPECT_DOUBLE_EQ(c.xyz(a, static_cast<Eigen::Index>(i)), p.xyz[a]) << "point " << i;
    EXPECT_EQ(c.intensity[i], static_cast<float>(p.intensity)) << "point " << i;
    if (las_has_rgb(h.format)) {
      for (int k = 0; k < 3; ++k) {
        const int want = rgb_max <= 255 ? p.rgb[k] : p.rgb[k] >> 8;
        EXPECT_EQ(c.rgb[3 * i + static_cast<std::size_t>(k)], want) << "point " << i << " channel " << k;
      }
    }
  }
  if (las_has_rgb(h.format)) {
    EXPECT_TRUE(has_note(r.report, rgb_max <= 255 ? "at most 255" : "16-bit scaled to 8-bit"));
  }

  // Default: classes 7 and 18 (noise) dropped.
  const auto d = hp::load_cloud(path);
  EXPECT_EQ(d.value.size(), h.count - class_count[7] - class_count[18]);
  EXPECT_TRUE(has_note(d.report, "dropped " + std::to_string(class_count[7] + class_count[18]) + " points"));

  // Dropping the most common class leaves exactly the others, in order.
  const auto most = static_cast<int>(std::max_element(class_count.begin(), class_count.end()) - class_count.begin());
  if (class_count[static_cast<std::size_t>(most)] < h.count) {
    const auto k = hp::load_cloud(path, hp::LoadOptions{{most}});
    ASSERT_EQ(k.value.size(), h.count - class_count[static_cast<std::size_t>(most)]);
    std::size_t first_kept = 0;
    while (las_point(b, h, first_kept).cls == most) ++first_kept;
    const LasPoint p = las_point(b, h, first_kept);
    for (int a = 0; a < 3; ++a) EXPECT_DOUBLE_EQ(k.value.xyz(a, 0), p.xyz[a]);
    EXPECT_TRUE(has_note(k.report, "class " + std::to_string(most) + ": " +
                                       std::to_string(class_count[static_cast<std::size_t>(most)])));
  }
}

INSTANTIATE_TEST_SUITE_P(SharedSamples, LasSamples,
                         ::testing::Values(LasSample{"laspy-vegetation_1_3.las", 10683, 1},
                                           LasSample{"pdal-autzen_trim_7.las", 110000, 7},
                                           LasSample{"pdal-permutations_1.2_2.las", 1, 2},
                                           LasSample{"pdal-sample_c.las", 14408, 3},
                                           LasSample{"pdal-simple.las", 1065, 3},
                                           LasSample{"pdal-test1_4.las", 1000, 6}),
                         [](const auto& param_info) {
                           std::string n = param_info.param.file;
                           for (auto& ch : n) {
                             if (!std::isalnum(static_cast<unsigned char>(ch))) ch = '_';
                           }
                           return n;
                         });

TEST(LasReader, CarriesTheCrsIntoTheReport) {
  const auto wkt = hp::load_cloud(hc::test::scan_path("scanner_samples/las/pdal-autzen_trim_7.las"));
  EXPECT_TRUE(has_note(wkt.report, "CRS (OGC WKT, VLR 2112): PROJCS[\"NAD_1983_HARN_Lambert_Conformal_Conic\""));
  EXPECT_TRUE(has_note(wkt.report, "last UNIT in the WKT: \"foot\",0.3048"));
  const auto keys = hp::load_cloud(hc::test::scan_path("scanner_samples/las/pdal-permutations_1.2_2.las"));
  EXPECT_TRUE(has_note(keys.report, "CRS (GeoTIFF keys, VLR 34735)"));
  EXPECT_TRUE(has_note(keys.report, "NAD83 / UTM zone 15N"));
  const auto none = hp::load_cloud(hc::test::scan_path("scanner_samples/las/pdal-simple.las"));
  EXPECT_TRUE(has_note(none.report, "no CRS record"));
  EXPECT_TRUE(has_note(none.report, "LAS 1.2, point data format 3 (34-byte records), 1065 point records"));
}

// A minimal LAS writer for synthetic files (header, no VLRs, records of `record_length` bytes).
struct SynthPoint {
  std::int32_t X, Y, Z;
  std::uint16_t intensity;
  std::uint8_t cls;
  std::uint16_t r, g, b;
};

std::string synth_las(int minor, int format, std::size_t record_length, const std::vector<SynthPoint>& pts,
                      const double scale[3], const double shift[3]) {
  const std::size_t header = minor <= 2 ? 227 : minor == 3 ? 235 : 375;
  std::string b(header + pts.size() * record_length, '\0');
  auto put = [&](std::size_t at, auto v) { std::memcpy(b.data() + at, &v, sizeof v); };
  std::memcpy(b.data(), "LASF", 4);
  b[24] = 1;
  b[25] = static_cast<char>(minor);
  put(94, static_cast<std::uint16_t>(header));
  put(96, static_cast<std::uint32_t>(header));
  b[104] = static_cast<char>(format);
  put(105, static_cast<std::uint16_t>(record_length));
  put(107, static_cast<std::uint32_t>(format <= 5 ? pts.size() : 0));
  for (int a = 0; a < 3; ++a) {
    put(131 + 8 * static_cast<std::size_t>(a), scale[a]);
    put(155 + 8 * static_cast<std::size_t>(a), shift[a]);
  }
  if (minor >= 4) put(247, static_cast<std::uint64_t>(pts.size()));
  const std::size_t rgb_at = format == 2 ? 20 : (format == 3 || format == 5) ? 28 : (format == 7 || format == 8 || format == 10) ? 30 : 0;
  for (std::size_t i = 0; i < pts.size(); ++i) {
    const std::size_t at = header + i * record_length;
    put(at, pts[i].X);
    put(at + 4, pts[i].Y);
    put(at + 8, pts[i].Z);
    put(at + 12, pts[i].intensity);
    if (format <= 5) {
      b[at + 15] = static_cast<char>(pts[i].cls | 0xE0);  // flag bits 5–7 set: must be masked off
    } else {
      b[at + 15] = static_cast<char>(0xFF);  // classification flags etc.: not the class
      b[at + 16] = static_cast<char>(pts[i].cls);
    }
    if (rgb_at) {
      put(at + rgb_at, pts[i].r);
      put(at + rgb_at + 2, pts[i].g);
      put(at + rgb_at + 4, pts[i].b);
    }
    const std::size_t base[] = {20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67};
    for (std::size_t x = at + base[format]; x < at + record_length; ++x) b[x] = '\x5a';  // extra bytes
  }
  return b;
}

TEST(LasReader, ReadsEveryPointFormatAndVersionWithExtraBytes) {
  const std::size_t base[] = {20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67};
  const double scale[3] = {0.001, 0.01, 0.0025}, shift[3] = {1000.5, -2000.25, 10.0};
  const std::vector<SynthPoint> pts = {{1000, -2000, 300, 17, 2, 0x1200, 0x3400, 0xFF00},
                                       {-5, 7, -9, 65535, 7, 0, 0, 0},
                                       {2147483647, -2147483647, 0, 0, 18, 0xFFFF, 0x0100, 0x00FF},
                                       {42, 43, 44, 100, 31, 0x8000, 0x8080, 0x7FFF}};
  const fs::path dir = hc::test::temp_dir("las");
  for (int format = 0; format <= 10; ++format) {
    for (const std::size_t extra : {std::size_t{0}, std::size_t{5}}) {
      const int minor = format >= 6 ? 4 : format % 5;  // 1.0 .. 1.4
      const std::size_t len = base[format] + extra;
      std::string file_name = "f";  // built by appending: GCC 12 -O3 flags "f" + str (-Wrestrict)
      file_name += std::to_string(format);
      file_name += '_';
      file_name += std::to_string(extra);
      file_name += ".las";
      const fs::path f = dir / file_name;
      write_bytes(f, synth_las(minor, format, len, pts, scale, shift));
      SCOPED_TRACE(f.filename().string());
      const auto r = hp::load_cloud(f);
      const hp::Cloud& c = r.value;
      // Classes 7 and 18 dropped by default; class 31 kept (format 0-5: 5 bits).
      ASSERT_EQ(c.size(), 2u);
      const SynthPoint* kept[] = {&pts[0], &pts[3]};
      for (std::size_t i = 0; i < 2; ++i) {
        EXPECT_DOUBLE_EQ(c.xyz(0, static_cast<Eigen::Index>(i)), kept[i]->X * scale[0] + shift[0]);
        EXPECT_DOUBLE_EQ(c.xyz(1, static_cast<Eigen::Index>(i)), kept[i]->Y * scale[1] + shift[1]);
        EXPECT_DOUBLE_EQ(c.xyz(2, static_cast<Eigen::Index>(i)), kept[i]->Z * scale[2] + shift[2]);
        EXPECT_EQ(c.intensity[i], static_cast<float>(kept[i]->intensity));
      }
      EXPECT_TRUE(has_note(r.report, "dropped 2 points"));
      EXPECT_TRUE(has_note(r.report, "class 7: 1, class 18: 1"));
      EXPECT_EQ(has_note(r.report, "5 extra bytes per record"), extra == 5);
      if (las_has_rgb(format)) {
        ASSERT_EQ(c.rgb.size(), 6u);
        EXPECT_EQ(c.rgb[0], 0x12);
        EXPECT_EQ(c.rgb[1], 0x34);
        EXPECT_EQ(c.rgb[2], 0xFF);
        EXPECT_EQ(c.rgb[3], 0x80);
        EXPECT_EQ(c.rgb[5], 0x7F);
      } else {
        EXPECT_FALSE(c.has_rgb());
      }
      // All classes kept: the extreme int32 coordinates come back exactly.
      const auto all = hp::load_cloud(f, hp::LoadOptions{{}});
      ASSERT_EQ(all.value.size(), 4u);
      EXPECT_DOUBLE_EQ(all.value.xyz(0, 2), 2147483647.0 * scale[0] + shift[0]);
      EXPECT_DOUBLE_EQ(all.value.xyz(1, 2), -2147483647.0 * scale[1] + shift[1]);
    }
  }
}

TEST(LasReader, EightBitColourIsDetectedAndKeptAsIs) {
  const double scale[3] = {1, 1, 1}, shift[3] = {0, 0, 0};
  const fs::path f = hc::test::temp_dir("las8") / "rgb8.las";
  write_bytes(f, synth_las(2, 2, 26, {{1, 2, 3, 0, 2, 200, 100, 255}, {4, 5, 6, 0, 2, 0, 1, 2}}, scale, shift));
  const auto r = hp::load_cloud(f);
  ASSERT_EQ(r.value.rgb.size(), 6u);
  EXPECT_EQ(r.value.rgb[0], 200);
  EXPECT_EQ(r.value.rgb[1], 100);
  EXPECT_EQ(r.value.rgb[2], 255);
  EXPECT_EQ(r.value.rgb[5], 2);
  EXPECT_TRUE(has_note(r.report, "at most 255"));
}

TEST(LasReader, BadHeadersAreClearErrors) {
  const fs::path dir = hc::test::temp_dir("lasbad");
  const std::string good = read_bytes(hc::test::scan_path("scanner_samples/las/pdal-simple.las"));
  ASSERT_EQ(le<std::uint32_t>(good, 107), 1065u);

  // Counts that exceed the file.
  std::string more = good;
  const std::uint32_t n = 1066;
  std::memcpy(more.data() + 107, &n, 4);
  write_bytes(dir / "more.las", more);
  std::string msg = error_of([&] { hp::load_cloud(dir / "more.las"); });
  EXPECT_NE(msg.find("load_cloud: '"), std::string::npos) << msg;
  EXPECT_NE(msg.find("more.las"), std::string::npos) << msg;
  EXPECT_NE(msg.find("declares 1066 point records"), std::string::npos) << msg;
  EXPECT_NE(msg.find("room for only 1065"), std::string::npos) << msg;

  // A truncated file (the header still says 1065).
  write_bytes(dir / "cut.las", good.substr(0, good.size() - 10));
  msg = error_of([&] { hp::load_cloud(dir / "cut.las"); });
  EXPECT_NE(msg.find("room for only 1064"), std::string::npos) << msg;

  // An unknown point format.
  std::string fmt = good;
  fmt[104] = 11;
  write_bytes(dir / "fmt.las", fmt);
  msg = error_of([&] { hp::load_cloud(dir / "fmt.las"); });
  EXPECT_NE(msg.find("point data format 11: expected 0 to 10"), std::string::npos) << msg;

  // The LAZ compression bit.
  fmt[104] = static_cast<char>(0x83);
  write_bytes(dir / "laz.las", fmt);
  msg = error_of([&] { hp::load_cloud(dir / "laz.las"); });
  EXPECT_NE(msg.find("compressed LAZ"), std::string::npos) << msg;

  // A record length shorter than the format's.
  std::string shortrec = good;
  const std::uint16_t len = 30;
  std::memcpy(shortrec.data() + 105, &len, 2);
  write_bytes(dir / "short.las", shortrec);
  msg = error_of([&] { hp::load_cloud(dir / "short.las"); });
  EXPECT_NE(msg.find("records of 30 bytes: point data format 3 needs at least 34"), std::string::npos) << msg;

  // Not a LAS file; a version beyond 1.4.
  write_bytes(dir / "text.las", std::string(300, 'x'));
  EXPECT_NE(error_of([&] { hp::load_cloud(dir / "text.las"); }).find("signature 'LASF'"), std::string::npos);
  std::string v15 = good;
  v15[25] = 5;
  write_bytes(dir / "v15.las", v15);
  EXPECT_NE(error_of([&] { hp::load_cloud(dir / "v15.las"); }).find("LAS version 1.5: expected 1.0 to 1.4"),
            std::string::npos);
  // Every point dropped.
  const fs::path simple = hc::test::scan_path("scanner_samples/las/pdal-simple.las");
  msg = error_of([&] { hp::load_cloud(simple, hp::LoadOptions{{1, 2}}); });
  EXPECT_NE(msg.find("all of a classification in input.las.drop_classes"), std::string::npos) << msg;
}

// ---------------------------------------------------------------------------------------------
// Units and config keys.

TEST(ImperialUnits, FactorsAreTheExactDefinitions) {
  EXPECT_EQ(hc::metres_per_unit("ft"), 0.3048);
  EXPECT_EQ(hc::metres_per_unit("in"), 0.0254);
  EXPECT_EQ(hc::metres_per_unit("us-ft"), 1200.0 / 3937.0);
  EXPECT_NEAR(hc::metres_per_unit("us-ft") / hc::metres_per_unit("ft"), 1.000002, 1e-6);  // 2 ppm longer
  EXPECT_DOUBLE_EQ(hc::metres_per_unit("ft"), 12 * hc::metres_per_unit("in"));
  EXPECT_THROW(hc::metres_per_unit("yd"), hc::ConfigError);
}

std::string config_error(const std::string& yaml) {
  try {
    hp::parse_run_config(yaml, "configs/test.yaml");
  } catch (const hc::ConfigError& e) {
    return e.what();
  }
  return "NO EXCEPTION";
}

TEST(ScannerConfig, UnitsAndLasDropClasses) {
  const auto def = hp::parse_run_config("input:\n  files: [a.las]\n", "configs/test.yaml");
  EXPECT_EQ(def.input.las_drop_classes, (std::vector<int>{7, 18}));
  for (const char* u : {"ft", "us-ft", "in", "m", "cm", "mm"}) {
    EXPECT_EQ(hp::parse_run_config(std::string("input:\n  files: [a.las]\n  units: ") + u + "\n", "configs/test.yaml")
                  .input.units,
              u);
  }
  const auto c = hp::parse_run_config("input:\n  files: [a.las]\n  las:\n    drop_classes: [7, 18, 0]\n",
                                      "configs/test.yaml");
  EXPECT_EQ(c.input.las_drop_classes, (std::vector<int>{7, 18, 0}));
  const auto none = hp::parse_run_config("input:\n  files: [a.las]\n  las: {drop_classes: []}\n", "configs/test.yaml");
  EXPECT_TRUE(none.input.las_drop_classes.empty());
  std::string msg = config_error("input:\n  files: [a.las]\n  las: {drop_classes: [7, 256]}\n");
  EXPECT_NE(msg.find("configs/test.yaml:3: input.las.drop_classes has the element 256: expected a list of LAS "
                     "classification codes, integers in [0, 255]"),
            std::string::npos)
      << msg;
  msg = config_error("input:\n  files: [a.las]\n  las: {drop_classes: 7}\n");
  EXPECT_NE(msg.find("input.las.drop_classes = '7': expected a list"), std::string::npos) << msg;
  msg = config_error("input:\n  files: [a.las]\n  las: {drop_classes: [noise]}\n");
  EXPECT_NE(msg.find("has the element 'noise'"), std::string::npos) << msg;
  msg = config_error("input:\n  files: [a.las]\n  las: {drop: [7]}\n");
  EXPECT_NE(msg.find("input.las.drop"), std::string::npos) << msg;
  msg = config_error("input:\n  files: [a.las]\n  units: yd\n");
  EXPECT_NE(msg.find("input.units = 'yd': expected one of: m, cm, mm, ft, us-ft, in"), std::string::npos) << msg;
}

// ---------------------------------------------------------------------------------------------
// PTX: oracle with std::istringstream; the pose from the scanner position and axis lines
// (p = position + x·axisX + y·axisY + z·axisZ), which never reads the 4×4 block.

struct TextPoint {
  Eigen::Vector3d p;
  double intensity = 0;
  int rgb[3] = {-1, -1, -1};
  int row = -1, col = -1;
};

struct PtxOracle {
  std::vector<TextPoint> points;
  std::size_t scans = 0, zeros = 0;
  std::vector<Eigen::Vector3d> positions;
  std::vector<Eigen::Matrix3d> axes;       // rows: the axis lines
  std::vector<Eigen::Matrix4d> transforms;  // as written
};

PtxOracle ptx_oracle(const std::string& text) {
  PtxOracle o;
  std::istringstream in(text);
  std::string line;
  auto next = [&](std::istringstream& ls) {
    while (std::getline(in, line)) {
      if (line.find_first_not_of(" \t\r") != std::string::npos) {
        ls.clear();  // reuse the stream (move-assigning one trips GCC 12's -Wstringop-overflow under ASan)
        ls.str(line);
        return true;
      }
    }
    return false;
  };
  std::istringstream ls;
  while (next(ls)) {
    std::size_t cols = 0, rows = 0;
    ls >> cols;
    next(ls);
    ls >> rows;
    Eigen::Vector3d pos;
    Eigen::Matrix3d ax;
    Eigen::Matrix4d m;
    next(ls);
    ls >> pos.x() >> pos.y() >> pos.z();
    for (int r = 0; r < 3; ++r) {
      next(ls);
      ls >> ax(r, 0) >> ax(r, 1) >> ax(r, 2);
    }
    for (int r = 0; r < 4; ++r) {
      next(ls);
      ls >> m(r, 0) >> m(r, 1) >> m(r, 2) >> m(r, 3);
    }
    o.positions.push_back(pos);
    o.axes.push_back(ax);
    o.transforms.push_back(m);
    ++o.scans;
    for (std::size_t i = 0; i < cols * rows; ++i) {
      EXPECT_TRUE(next(ls));
      double x, y, z;
      TextPoint t;
      ls >> x >> y >> z >> t.intensity;
      if (int r, g, b; ls >> r >> g >> b) {
        t.rgb[0] = r;
        t.rgb[1] = g;
        t.rgb[2] = b;
      }
      if (x == 0 && y == 0 && z == 0) {
        ++o.zeros;
        continue;
      }
      t.p = pos + x * ax.row(0).transpose() + y * ax.row(1).transpose() + z * ax.row(2).transpose();
      t.row = static_cast<int>(i % rows);
      t.col = static_cast<int>(i / rows);
      o.points.push_back(t);
    }
  }
  return o;
}

void expect_matches(const hp::Cloud& c, const std::vector<TextPoint>& want, double tol, bool grid) {
  ASSERT_EQ(c.size(), want.size());
  const bool rgb = want.front().rgb[0] >= 0;
  EXPECT_EQ(c.has_rgb(), rgb);
  ASSERT_EQ(c.intensity.size(), c.size());
  EXPECT_EQ(c.has_grid_index(), grid);
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e300), hi = -lo;
  for (std::size_t i = 0; i < want.size(); ++i) {
    const auto j = static_cast<Eigen::Index>(i);
    EXPECT_NEAR((c.xyz.col(j) - want[i].p).norm(), 0.0, tol) << "point " << i;
    EXPECT_FLOAT_EQ(c.intensity[i], static_cast<float>(want[i].intensity)) << "point " << i;
    if (rgb) {
      for (int k = 0; k < 3; ++k) EXPECT_EQ(c.rgb[3 * i + static_cast<std::size_t>(k)], want[i].rgb[k]) << "point " << i;
    }
    if (grid) {
      EXPECT_EQ(c.row[i], want[i].row) << "point " << i;
      EXPECT_EQ(c.col[i], want[i].col) << "point " << i;
    }
    lo = lo.cwiseMin(want[i].p);
    hi = hi.cwiseMax(want[i].p);
  }
  EXPECT_NEAR((c.xyz.rowwise().minCoeff() - lo).norm(), 0.0, tol);
  EXPECT_NEAR((c.xyz.rowwise().maxCoeff() - hi).norm(), 0.0, tol);
}

TEST(PtxReader, SharedSamplesMatchAnIndependentParse) {
  struct S {
    const char* file;
    std::size_t points, zeros;
  };
  for (const S s : {S{"pdal-1.2-with-color.ptx", 1065, 0}, S{"pdal-complex-transform.ptx", 4, 8},
                    S{"pdal-no-color.ptx", 15, 0}}) {
    SCOPED_TRACE(s.file);
    const fs::path path = hc::test::scan_path(std::string("scanner_samples/ptx/") + s.file);
    const PtxOracle o = ptx_oracle(read_bytes(path));
    ASSERT_EQ(o.points.size(), s.points);
    EXPECT_EQ(o.zeros, s.zeros);
    const auto r = hp::load_cloud(path);
    expect_matches(r.value, o.points, 1e-9 * (1 + o.points.front().p.norm()), true);
    EXPECT_TRUE(has_note(r.report, std::to_string(s.zeros) + " no-return points"));
  }
}

TEST(PtxReader, TransformIsRowVectorConventionAsTheComplexTransformSampleShows) {
  // The sample's 4×4 block: rows 0–2 equal the scanner axis lines, row 3 the scanner position,
  // column 3 is 0 0 0 1. So [x y z 1]·M = position + x·axisX + y·axisY + z·axisZ.
  const PtxOracle o = ptx_oracle(read_bytes(hc::test::scan_path("scanner_samples/ptx/pdal-complex-transform.ptx")));
  ASSERT_EQ(o.scans, 1u);
  const Eigen::Matrix4d& m = o.transforms[0];
  const Eigen::Matrix3d rot = m.topLeftCorner<3, 3>();
  const Eigen::Vector3d translation = m.block<1, 3>(3, 0).transpose();
  EXPECT_TRUE(rot.isApprox(o.axes[0], 1e-12));
  EXPECT_TRUE(translation.isApprox(o.positions[0], 1e-12));
  EXPECT_EQ(m.col(3), Eigen::Vector4d(0, 0, 0, 1));
  EXPECT_FALSE(o.axes[0].isIdentity(1e-3));  // a real rotation: R and Rᵀ differ
  // First kept point by hand: x = -0.005630, y = 0.645218, z = -0.440506.
  const Eigen::Vector3d want = o.positions[0] + Eigen::Vector3d(-0.005630 * 0.999979 + 0.645218 * 0.003613 + -0.440506 * 0.005359,
                                                                -0.005630 * -0.003604 + 0.645218 * 0.999992 + -0.440506 * -0.001650,
                                                                -0.005630 * -0.005365 + 0.645218 * 0.001630 + -0.440506 * 0.999984);
  const auto c = hp::load_cloud(hc::test::scan_path("scanner_samples/ptx/pdal-complex-transform.ptx")).value;
  EXPECT_NEAR((c.xyz.col(0) - want).norm(), 0.0, 1e-12);
  EXPECT_EQ(c.row[0], 4);
  EXPECT_EQ(c.col[0], 0);
}

/// A PTX scan of `world` points seen from a scanner with rotation r (scanner axes as columns,
/// in the common frame) and position t: local = rᵀ·(world − t); one 0 0 0 no-return point first.
std::string ptx_scan(const std::vector<Eigen::Vector3d>& world, const Eigen::Matrix3d& r, const Eigen::Vector3d& t) {
  std::ostringstream os;
  os << std::setprecision(17);
  os << 1 << "\n" << world.size() + 1 << "\n" << t.x() << " " << t.y() << " " << t.z() << "\n";
  for (int a = 0; a < 3; ++a) os << r(0, a) << " " << r(1, a) << " " << r(2, a) << "\n";
  for (int a = 0; a < 3; ++a) os << r(0, a) << " " << r(1, a) << " " << r(2, a) << " 0\n";
  os << t.x() << " " << t.y() << " " << t.z() << " 1\n";
  os << "0 0 0 0.5 0 0 0\n";
  for (std::size_t i = 0; i < world.size(); ++i) {
    const Eigen::Vector3d l = r.transpose() * (world[i] - t);
    os << l.x() << " " << l.y() << " " << l.z() << " 0." << i + 1 << " " << 10 * i << " " << 20 << " " << 30 << "\n";
  }
  return os.str();
}

TEST(PtxReader, TwoScansWithKnownPosesMergeIntoTheCommonFrame) {
  const std::vector<Eigen::Vector3d> world = {{1.0, 2.0, 3.0}, {-4.5, 0.25, 7.0}, {100.0, -50.0, 0.125}, {0.0, 0.0, 1.0}};
  const Eigen::Matrix3d ra = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::Matrix3d rb = Eigen::AngleAxisd(-2.1, Eigen::Vector3d(0, -1, 0.3).normalized()).toRotationMatrix();
  const std::string text = ptx_scan(world, ra, {10, -5, 2}) + ptx_scan(world, rb, {-300, 40, 12.5}) +
                           ptx_scan(world, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
  const fs::path f = hc::test::temp_dir("ptx2") / "two.ptx";
  write_bytes(f, text);
  const auto r = hp::load_cloud(f);
  ASSERT_EQ(r.value.size(), 3 * world.size());
  ASSERT_EQ(r.value.scan_id.size(), r.value.size());
  for (std::size_t s = 0; s < 3; ++s) {
    for (std::size_t i = 0; i < world.size(); ++i) {
      const auto j = static_cast<Eigen::Index>(s * world.size() + i);
      EXPECT_NEAR((r.value.xyz.col(j) - world[i]).norm(), 0.0, 1e-9) << "scan " << s << " point " << i;
      EXPECT_EQ(r.value.row[static_cast<std::size_t>(j)], static_cast<int>(i + 1));
      EXPECT_EQ(r.value.rgb[3 * static_cast<std::size_t>(j)], 10 * i);
      EXPECT_EQ(r.value.scan_id[static_cast<std::size_t>(j)], s) << "each point carries its scan";
    }
  }
  EXPECT_TRUE(has_note(r.report, "3 scan(s), 3 no-return points"));
}

// Rows and columns are per scan, so an organised mesh of a file of two scans is the two scans'
// meshes side by side: as many triangles as the two files of one scan each give. (Before the
// reader kept scan ids, both scans' points shared one row/column grid.)
TEST(PtxReader, TwoScansOfOneFileAreMeshedEachOnItsOwn) {
  const auto scan = [](double x0) {
    std::ostringstream out;
    out << std::setprecision(17);
    const int cols = 12, rows = 9;
    out << cols << "\n" << rows << "\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
    for (int c = 0; c < cols; ++c) {
      for (int r = 0; r < rows; ++r) {
        const double x = x0 + 0.01 * c, y = 0.01 * r;
        out << x << ' ' << y << ' ' << 1.0 + 0.002 * std::sin(40 * x + 30 * y) << " 0.5\n";
      }
    }
    return out.str();
  };
  const fs::path dir = hc::test::temp_dir("ptx_mesh");
  write_bytes(dir / "a.ptx", scan(0.0));
  write_bytes(dir / "b.ptx", scan(0.003));  // the same area, shifted by a third of a column
  write_bytes(dir / "ab.ptx", scan(0.0) + scan(0.003));
  const auto triangles = [&](const char* f) { return hp::mesh_organised_scans(hp::load_cloud(dir / f).value, 4.0).value.mesh.triangles.size(); };
  const std::size_t a = triangles("a.ptx"), b = triangles("b.ptx");
  EXPECT_EQ(a, 2U * 11U * 8U) << "every cell of a smooth 12 x 9 grid gives two triangles";
  EXPECT_EQ(b, a);
  EXPECT_EQ(triangles("ab.ptx"), a + b);
}

TEST(PtxReader, RowCountThatDoesNotMatchIsAnError) {
  const fs::path dir = hc::test::temp_dir("ptxbad");
  const std::string header = "2\n3\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";
  std::string pts;
  for (int i = 0; i < 7; ++i) pts += std::to_string(i + 1) + " 2 3 0.5\n";
  // Too few: 5 point lines for 3 rows x 2 columns.
  write_bytes(dir / "few.ptx", header + pts.substr(0, pts.size() / 7 * 5));
  std::string msg = error_of([&] { hp::load_cloud(dir / "few.ptx"); });
  EXPECT_NE(msg.find("few.ptx' scan 1 (header at line 1) declares 3 rows x 2 columns = 6 points, but the file ends "
                     "after 5 point lines (line 15)"),
            std::string::npos)
      << msg;
  // Too many: the 7th point line stands where the next scan's column count should be.
  write_bytes(dir / "many.ptx", header + pts);
  msg = error_of([&] { hp::load_cloud(dir / "many.ptx"); });
  EXPECT_NE(msg.find("many.ptx' line 17: scan 2: expected the column count"), std::string::npos) << msg;
  EXPECT_NE(msg.find("more point lines than scan 1's rows"), std::string::npos) << msg;
  // A second scan cut short.
  write_bytes(dir / "second.ptx", header + pts.substr(0, pts.size() / 7 * 6) + header + pts.substr(0, pts.size() / 7 * 2));
  msg = error_of([&] { hp::load_cloud(dir / "second.ptx"); });
  EXPECT_NE(msg.find("scan 2 (header at line 17) declares 3 rows x 2 columns = 6 points, but the file ends after 2"),
            std::string::npos)
      << msg;
  // A header line that is not numbers.
  write_bytes(dir / "hdr.ptx", "2\n3\n0 0 0\n1 0 0\nzero 1 0\n");
  msg = error_of([&] { hp::load_cloud(dir / "hdr.ptx"); });
  EXPECT_NE(msg.find("line 5: scan 1: expected scanner axis Y"), std::string::npos) << msg;
}

// ---------------------------------------------------------------------------------------------
// PTS

std::vector<TextPoint> pts_oracle(const std::string& text, std::size_t& stated) {
  std::istringstream in(text);
  std::string line;
  std::getline(in, line);
  stated = std::stoul(line);
  std::vector<TextPoint> out;
  while (std::getline(in, line)) {
    std::istringstream ls(line);
    std::vector<double> v;
    for (double x; ls >> x;) v.push_back(x);
    if (v.empty()) continue;
    TextPoint t;
    t.p = {v[0], v[1], v[2]};
    if (v.size() == 4 || v.size() == 7) t.intensity = v[3];
    if (v.size() >= 6) {
      for (int k = 0; k < 3; ++k) t.rgb[k] = static_cast<int>(v[v.size() - 3 + static_cast<std::size_t>(k)]);
    }
    out.push_back(t);
  }
  return out;
}

TEST(PtsReader, SharedSamplesMatchAnIndependentParse) {
  struct S {
    const char* file;
    std::size_t points;
    bool intensity;
  };
  for (const S s : {S{"pdal-site_56_8.pts", 8, true}, S{"pdal-test.pts", 19, true}}) {
    SCOPED_TRACE(s.file);
    const fs::path path = hc::test::scan_path(std::string("scanner_samples/pts/") + s.file);
    std::size_t stated = 0;
    const auto want = pts_oracle(read_bytes(path), stated);
    ASSERT_EQ(stated, s.points);
    ASSERT_EQ(want.size(), s.points);
    const auto r = hp::load_cloud(path);
    const hp::Cloud& c = r.value;
    ASSERT_EQ(c.size(), want.size());
    EXPECT_EQ(c.has_intensity(), s.intensity);
    EXPECT_FALSE(c.has_grid_index());
    for (std::size_t i = 0; i < want.size(); ++i) {
      const auto j = static_cast<Eigen::Index>(i);
      for (int a = 0; a < 3; ++a) EXPECT_DOUBLE_EQ(c.xyz(a, j), want[i].p[a]) << "point " << i;
      if (s.intensity) {
        EXPECT_EQ(c.intensity[i], static_cast<float>(want[i].intensity));
      }
      if (want[i].rgb[0] >= 0) {
        ASSERT_TRUE(c.has_rgb());
        for (int k = 0; k < 3; ++k) EXPECT_EQ(c.rgb[3 * i + static_cast<std::size_t>(k)], want[i].rgb[k]);
      }
    }
    EXPECT_EQ(has_note(r.report, "Leica's integer range -2048..2047"), s.intensity);
  }
}

// The shared bunny_8.pts is itself a lying file: its count line says 8 and 9 point lines follow
// (the oracle counts them). It is refused, naming both numbers, rather than read in part.
TEST(PtsReader, SharedBunnySampleHasACountLineThatLies) {
  const fs::path path = hc::test::scan_path("scanner_samples/pts/pdal-bunny_8.pts");
  std::size_t stated = 0;
  const auto lines = pts_oracle(read_bytes(path), stated);
  ASSERT_EQ(stated, 8u);
  ASSERT_EQ(lines.size(), 9u);
  const std::string msg = error_of([&] { hp::load_cloud(path); });
  EXPECT_NE(msg.find("pdal-bunny_8.pts' line 1: the count line says 8 points but 9 point lines follow it"),
            std::string::npos)
      << msg;
}

TEST(PtsReader, CountLineThatLiesIsAnError) {
  const fs::path dir = hc::test::temp_dir("ptsbad");
  std::string body;
  for (int i = 0; i < 9; ++i) body += std::to_string(i) + ".5 1 2 -100 1 2 3\n";
  const std::size_t line_len = body.size() / 9;
  write_bytes(dir / "fewer.pts", "8\n" + body.substr(0, 7 * line_len));
  std::string msg = error_of([&] { hp::load_cloud(dir / "fewer.pts"); });
  EXPECT_NE(msg.find("fewer.pts' line 1: the count line says 8 points but 7 point lines follow it"), std::string::npos)
      << msg;
  write_bytes(dir / "more.pts", "8\n" + body);
  msg = error_of([&] { hp::load_cloud(dir / "more.pts"); });
  EXPECT_NE(msg.find("the count line says 8 points but 9 point lines follow it"), std::string::npos) << msg;
  // Two blocks, the first one short.
  write_bytes(dir / "blocks.pts", "3\n" + body.substr(0, 2 * line_len) + "2\n" + body.substr(0, 2 * line_len));
  msg = error_of([&] { hp::load_cloud(dir / "blocks.pts"); });
  EXPECT_NE(msg.find("the count line says 3 points but 2 point lines follow it (up to line 3)"), std::string::npos)
      << msg;
  // Two honest blocks are read whole.
  write_bytes(dir / "ok.pts", "2\n" + body.substr(0, 2 * line_len) + "3\n" + body.substr(0, 3 * line_len));
  EXPECT_EQ(hp::load_cloud(dir / "ok.pts").value.size(), 5u);
  write_bytes(dir / "nocount.pts", body);
  EXPECT_NE(error_of([&] { hp::load_cloud(dir / "nocount.pts"); }).find("expected the point count line first"),
            std::string::npos);
}

// ---------------------------------------------------------------------------------------------
// End to end: configs/las_sample.yaml (pdal-simple.las, feet) through every stage of `run`.

TEST(LasEndToEnd, SampleConfigGivesAValidGridInMetres) {
  const fs::path config_path = fs::path(HC_SOURCE_DIR) / "configs" / "las_sample.yaml";
  const hp::RunConfig config = hp::load_run_config(config_path);
  EXPECT_EQ(config.input.units, "ft");
  const std::string b = read_bytes(hc::test::scan_path("scanner_samples/las/pdal-simple.las"));
  const LasHeader h = las_header(b);
  const hp::BuiltScene built = hp::build_scene(config, /*keep_cloud=*/true);
  const auto& g = built.summary.grid;
  ASSERT_GT(g.rows, 0);
  ASSERT_GT(g.cols, 0);
  const double cells = static_cast<double>(g.rows) * g.cols;
  EXPECT_GT(static_cast<double>(built.summary.valid_cells) / cells, 0.8);
  // The grid spans the header's x-y extent converted from feet (0.3048 m), within two cells
  // (the outlier filter may trim a few edge points).
  const double x_m = (h.max[0] - h.min[0]) * 0.3048, y_m = (h.max[1] - h.min[1]) * 0.3048;
  EXPECT_NEAR(g.cols * g.cell_size_m, x_m, 2 * g.cell_size_m);
  EXPECT_NEAR(g.rows * g.cell_size_m, y_m, 2 * g.cell_size_m);
  ASSERT_TRUE(built.cloud.has_value());
  const Eigen::Vector3d extent = built.cloud->xyz.rowwise().maxCoeff() - built.cloud->xyz.rowwise().minCoeff();
  EXPECT_NEAR(extent.z(), (h.max[2] - h.min[2]) * 0.3048, 0.5 * (h.max[2] - h.min[2]) * 0.3048);
  const auto& ingest = built.summary.stages.front();
  EXPECT_TRUE(has_note(ingest, "LAS 1.2, point data format 3"));
  EXPECT_EQ(ingest.count_out, h.count);
}

}  // namespace
