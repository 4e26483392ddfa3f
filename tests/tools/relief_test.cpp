// The generated relief scans of issue 14 (tools/relief): the surface against heights derived by
// hand, the classes against binomial bounds, the files against what the pipeline's own PLY and
// LAS readers read back, chunk and thread independence, the error policy, and a whole run whose
// grid must follow the analytic wall.

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/point_stream.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/tools/relief.hpp"

#include "error_of.hpp"
#include "file_bytes.hpp"
#include "test_paths.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <numbers>
#include <string>
#include <vector>

namespace {

using hc::tools::ReliefPointKind;
using hc::tools::ReliefSpec;
namespace fs = std::filesystem;

std::vector<char> read_all(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

ReliefSpec small_spec(std::uint64_t points) {
  ReliefSpec s;
  s.points = points;
  s.seed = 7;
  return s;
}

// Heights derived by hand for the default wall (2 m × 1 m, courses 0.25 m, blocks 0.5 m, odd
// courses shifted by 0.25 m), chisel marks off so that each term can be checked alone.
TEST(Relief, HeightFollowsTheCarvingDerivedByHand) {
  ReliefSpec s;
  s.chisel_amplitude_m = 0.0;
  // Centre of block 0 of course 0: u = 0.25, v = 0.125 → x = −0.75, y = −0.375: the rosette's
  // crown (joints 0.125 m away: exp(−31²) is 0).
  EXPECT_NEAR(hc::tools::relief_height_m(s, -0.75, -0.375), 0.03, 1e-12);
  // On the horizontal joint v = 0.25 (y = −0.25) at u = 0.1, far from any rosette: −joint depth.
  EXPECT_NEAR(hc::tools::relief_height_m(s, -0.9, -0.25), -0.006, 1e-12);
  // Course 1 is shifted: its vertical joint lies at u = 0.75 (x = −0.25), where course 0 has a
  // block's middle. At v = 0.375 (course 1, y = −0.125): the joint.
  EXPECT_NEAR(hc::tools::relief_height_m(s, -0.25, -0.125), -0.006, 1e-12);
  // Course 0 at u = 0.75, v = 0.18 (x = −0.25, y = −0.32): 0.055 m above its block's centre,
  // θ = 90°, so the petal radius is 0.35·0.25·(1 + 0.15·cos 540°) = 0.074375 m and the height
  // 0.03·cos²(π/2 · 0.055/0.074375); the nearest joint is 0.07 m away.
  const double c = std::cos(0.5 * std::numbers::pi * 0.055 / 0.074375);
  EXPECT_NEAR(hc::tools::relief_height_m(s, -0.25, -0.32), 0.03 * c * c, 1e-12);
  // Flat ashlar between rosette and joints: 0.2 m right of block 0's centre on course 0.
  EXPECT_NEAR(hc::tools::relief_height_m(s, -0.55, -0.375), 0.0, 1e-12);
  // The chisel marks add A·sin(2π(x + y/2)/λ): at x = 0.001, y = 0 a quarter wavelength.
  ReliefSpec t = s;
  t.chisel_amplitude_m = 0.0003;
  EXPECT_NEAR(hc::tools::relief_height_m(t, 0.001, 0.0) - hc::tools::relief_height_m(s, 0.001, 0.0), 0.0003, 1e-12);
}

TEST(Relief, ClassesAndPositionsFollowTheSpec) {
  ReliefSpec s = small_spec(200'000);
  s.back_fraction = 0.1;
  s.outlier_fraction = 0.01;
  std::uint64_t back = 0, outliers = 0, front_on_face = 0, front = 0;
  for (std::uint64_t i = 0; i < s.points; ++i) {
    const hc::tools::ReliefPoint p = hc::tools::relief_point(s, i);
    ASSERT_LE(std::fabs(p.x_m), 1.0);
    ASSERT_LE(std::fabs(p.y_m), 0.5);
    if (p.kind == ReliefPointKind::kBack) {
      ++back;
      EXPECT_LT(std::fabs(p.z_m + s.thickness_m), 6.0 * s.noise_sigma_m);
    } else if (p.kind == ReliefPointKind::kOutlier) {
      ++outliers;
      EXPECT_GE(p.z_m, -s.thickness_m);
      EXPECT_LE(p.z_m, s.outlier_reach_m);
    } else {
      ++front;
      front_on_face += std::fabs(p.z_m - hc::tools::relief_height_m(s, p.x_m, p.y_m)) <= 4.0 * s.noise_sigma_m ? 1U : 0U;
    }
  }
  // Binomial: 5 standard deviations.
  const auto within = [&](std::uint64_t count, double p) {
    const double n = static_cast<double>(s.points);
    return std::fabs(static_cast<double>(count) - n * p) <= 5.0 * std::sqrt(n * p * (1.0 - p));
  };
  EXPECT_TRUE(within(back, 0.1)) << back;
  EXPECT_TRUE(within(outliers, 0.01)) << outliers;
  // |N(0,1)| ≤ 4 with probability 0.999937.
  EXPECT_GE(static_cast<double>(front_on_face) / static_cast<double>(front), 0.9995);
  // The same index gives the same point; another seed another one.
  EXPECT_EQ(hc::tools::relief_point(s, 123).z_m, hc::tools::relief_point(s, 123).z_m);
  ReliefSpec other = s;
  other.seed = 8;
  EXPECT_NE(hc::tools::relief_point(s, 123).x_m, hc::tools::relief_point(other, 123).x_m);
}

// Scan order: 20 000 points on the 2 m × 1 m wall make a raster of round(√10 000) = 100 rows
// and 200 columns (by hand); point i lies in column i / 100, row i mod 100, each cell 10 mm
// square; every cell holds one point; the classes come out as in the default order. 20 001
// points: 100 rows, 201 columns, the last holding one point at the bottom.
TEST(Relief, ScanOrderWalksVerticalProfilesLeftToRight) {
  ReliefSpec s = small_spec(20'000);
  s.scan_order = true;
  s.back_fraction = 0.1;
  s.outlier_fraction = 0.01;
  const hc::tools::ScanRaster ras = hc::tools::scan_raster(s);
  EXPECT_EQ(ras.rows, 100U);
  EXPECT_EQ(ras.cols, 200U);
  std::vector<int> hits(20'000, 0);
  std::uint64_t back = 0, outliers = 0;
  for (std::uint64_t i = 0; i < s.points; ++i) {
    const hc::tools::ReliefPoint p = hc::tools::relief_point(s, i);
    const double col = (p.x_m + 1.0) / 0.01, row = (p.y_m + 0.5) / 0.01;
    ASSERT_EQ(static_cast<std::uint64_t>(col), i / 100) << "point " << i << " x " << p.x_m;
    ASSERT_EQ(static_cast<std::uint64_t>(row), i % 100) << "point " << i << " y " << p.y_m;
    ++hits[static_cast<std::size_t>(col) * 100 + static_cast<std::size_t>(row)];
    back += p.kind == ReliefPointKind::kBack ? 1U : 0U;
    outliers += p.kind == ReliefPointKind::kOutlier ? 1U : 0U;
    if (p.kind == ReliefPointKind::kFront) {
      EXPECT_LE(std::fabs(p.z_m - hc::tools::relief_height_m(s, p.x_m, p.y_m)), 6.0 * s.noise_sigma_m);
    }
    // Consecutive points within a profile are at most two cells apart.
    if (i % 100 != 0) {
      const hc::tools::ReliefPoint q = hc::tools::relief_point(s, i - 1);
      EXPECT_LE(std::hypot(p.x_m - q.x_m, p.y_m - q.y_m), 0.02 * std::sqrt(2.0) + 1e-12) << "point " << i;
    }
  }
  EXPECT_TRUE(std::all_of(hits.begin(), hits.end(), [](int h) { return h == 1; }));
  // The class of a point is drawn as in the default order: the same counts.
  ReliefSpec random = s;
  random.scan_order = false;
  std::uint64_t back_r = 0, outliers_r = 0;
  for (std::uint64_t i = 0; i < s.points; ++i) {
    const auto k = hc::tools::relief_point(random, i).kind;
    back_r += k == ReliefPointKind::kBack ? 1U : 0U;
    outliers_r += k == ReliefPointKind::kOutlier ? 1U : 0U;
  }
  EXPECT_EQ(back, back_r);
  EXPECT_EQ(outliers, outliers_r);
  ReliefSpec odd = s;
  odd.points = 20'001;
  EXPECT_EQ(hc::tools::scan_raster(odd).rows, 100U);
  EXPECT_EQ(hc::tools::scan_raster(odd).cols, 201U);
  const hc::tools::ReliefPoint last = hc::tools::relief_point(odd, 20'000);
  EXPECT_GE(last.x_m, -1.0 + 200.0 * 2.0 / 201.0);
  EXPECT_LT(last.y_m, -0.5 + 0.01);
  // One point, and a wall far taller than wide: at least one row, at most one a point.
  ReliefSpec one = s;
  one.points = 1;
  EXPECT_EQ(hc::tools::scan_raster(one).rows, 1U);
  EXPECT_EQ(hc::tools::scan_raster(one).cols, 1U);
  ReliefSpec tall = s;
  tall.points = 10;
  tall.height_m = 1000.0;
  EXPECT_EQ(hc::tools::scan_raster(tall).rows, 10U);
  EXPECT_EQ(hc::tools::scan_raster(tall).cols, 1U);
}

// Sorted: the default order's points, written column by column of the scan raster (by x) and
// up each column (by y). The file read back holds the same points (as a multiset, against
// relief_point of every index) in that order, checked pair by pair; the scan order and sorted
// together are refused.
TEST(Relief, SortedWritesTheDefaultPointsInAScannersOrder) {
  const fs::path dir = hc::test::temp_dir("sorted");
  ReliefSpec s = small_spec(20'001);
  s.rgb = true;
  s.sorted = true;
  const auto stats = hc::tools::write_relief(s, dir / "w.ply", 3000, 2);
  const hc::pipeline::Cloud c = hc::pipeline::load_cloud(dir / "w.ply").value;
  ASSERT_EQ(c.size(), s.points);
  // 100 rows, 201 columns of 2 m / 201 each (by hand: round(√(20001 / 2)) = 100).
  const double col_w = 2.0 / 201.0;
  std::vector<std::array<float, 3>> want, got;
  std::uint64_t back = 0;
  for (std::uint64_t i = 0; i < s.points; ++i) {
    const hc::tools::ReliefPoint p = hc::tools::relief_point(s, i);
    want.push_back({static_cast<float>(p.x_m), static_cast<float>(p.y_m), static_cast<float>(p.z_m)});
    back += p.kind == ReliefPointKind::kBack ? 1U : 0U;
  }
  // A point's column from its float x: the lowest and highest it can be (a float x within a
  // rounding step of a column's edge, up to 2^-25 m, 3·10^-6 of a column, may sit on either side).
  const auto col_range = [&](double x) {
    return std::array<double, 2>{std::floor((x + 1.0) / col_w - 1e-5), std::floor((x + 1.0) / col_w + 1e-5)};
  };
  for (std::size_t i = 0; i < c.size(); ++i) {
    const auto e = static_cast<Eigen::Index>(i);
    got.push_back({static_cast<float>(c.xyz(0, e)), static_cast<float>(c.xyz(1, e)), static_cast<float>(c.xyz(2, e))});
    if (i == 0) continue;
    const auto prev = col_range(c.xyz(0, e - 1)), now = col_range(c.xyz(0, e));
    ASSERT_GE(now[1], prev[0]) << "point " << i << ": its column lies before the one of the point before it";
    if (prev[0] == prev[1] && now[0] == now[1] && now[0] == prev[0]) {
      ASSERT_GE(c.xyz(1, e), c.xyz(1, e - 1)) << "point " << i << ": lower than the point before it in its column";
    }
  }
  std::sort(want.begin(), want.end());
  std::sort(got.begin(), got.end());
  EXPECT_EQ(want, got);
  EXPECT_EQ(stats.back, back);
  // The default file holds the same points in index order: not the sorted one's.
  ReliefSpec plain = s;
  plain.sorted = false;
  hc::tools::write_relief(plain, dir / "plain.ply", 3000, 2);
  const std::vector<char> plain_bytes = read_all(dir / "plain.ply"), sorted_bytes = read_all(dir / "w.ply");
  const std::string end = "end_header\n";
  const auto body = [&](const std::vector<char>& b) {
    return std::vector<char>(std::search(b.begin(), b.end(), end.begin(), end.end()) + static_cast<std::ptrdiff_t>(end.size()), b.end());
  };
  EXPECT_EQ(body(plain_bytes).size(), body(sorted_bytes).size());
  EXPECT_NE(body(plain_bytes), body(sorted_bytes));
  ReliefSpec both = s;
  both.scan_order = true;
  try {
    hc::tools::write_relief(both, dir / "both.ply");
    ADD_FAILURE() << "no error";
  } catch (const hc::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("sorted"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(dir / "both.ply"));
}

TEST(Relief, FilesDoNotDependOnChunksOrThreads) {
  const fs::path dir = hc::test::temp_dir("chunks");
  ReliefSpec s = small_spec(50'001);
  s.rgb = true;
  for (const char* ext : {".ply", ".las", ".e57"}) {
    const auto a = hc::tools::write_relief(s, dir / (std::string("a") + ext), 1000, 1);
    const auto b = hc::tools::write_relief(s, dir / (std::string("b") + ext), 65536, 2);
    EXPECT_EQ(read_all(dir / (std::string("a") + ext)), read_all(dir / (std::string("b") + ext))) << ext;
    EXPECT_EQ(a.front + a.back + a.outliers, s.points);
    EXPECT_EQ(a.front, b.front);
    EXPECT_EQ(a.outliers, b.outliers);
    EXPECT_EQ(a.bytes, fs::file_size(dir / (std::string("a") + ext)));
    EXPECT_EQ(a.buffer_bytes, 1000U * (std::string(ext) == ".las" ? 26U : 15U));
  }
}

TEST(Relief, ThePipelineReadersReadBackEveryPoint) {
  const fs::path dir = hc::test::temp_dir("read");
  ReliefSpec s = small_spec(30'000);
  s.rgb = true;
  s.outlier_fraction = 0.01;
  hc::tools::write_relief(s, dir / "w.ply", 4096, 2);
  hc::tools::write_relief(s, dir / "w.las", 4096, 2);
  const hc::pipeline::Cloud ply = hc::pipeline::load_cloud(dir / "w.ply").value;
  const hc::pipeline::Cloud las = hc::pipeline::load_cloud(dir / "w.las").value;
  ASSERT_EQ(ply.size(), s.points);
  ASSERT_EQ(las.size(), s.points);
  ASSERT_TRUE(ply.has_rgb());
  ASSERT_TRUE(las.has_rgb());
  double lo[3] = {1e9, 1e9, 1e9}, hi[3] = {-1e9, -1e9, -1e9};
  for (std::size_t i = 0; i < s.points; ++i) {
    const hc::tools::ReliefPoint p = hc::tools::relief_point(s, i);
    const double want[3] = {p.x_m, p.y_m, p.z_m};
    for (int a = 0; a < 3; ++a) {
      // PLY: float32 (relative 2⁻²⁴); LAS: 0.1 mm steps, so half a step.
      ASSERT_NEAR(ply.xyz(a, static_cast<Eigen::Index>(i)), want[a], 1e-7) << "point " << i;
      ASSERT_NEAR(las.xyz(a, static_cast<Eigen::Index>(i)), want[a], 0.5e-4 + 1e-12) << "point " << i;
      lo[a] = std::min(lo[a], las.xyz(a, static_cast<Eigen::Index>(i)));
      hi[a] = std::max(hi[a], las.xyz(a, static_cast<Eigen::Index>(i)));
    }
    const std::uint8_t rgb[3] = {p.r, p.g, p.b};
    for (int c = 0; c < 3; ++c) {
      ASSERT_EQ(ply.rgb[3 * i + c], rgb[c]);
      ASSERT_EQ(las.rgb[3 * i + c], rgb[c]);  // 16-bit LAS colour v·257 reads back as v
    }
  }
  // The LAS header's bounds (LAS 1.2 Table 4: max X, min X, max Y, ... at byte 179) are the
  // stored points' own.
  const std::vector<char> bytes = read_all(dir / "w.las");
  for (int a = 0; a < 3; ++a) {
    double mx = 0.0, mn = 0.0;
    std::memcpy(&mx, bytes.data() + 179 + 16 * a, 8);
    std::memcpy(&mn, bytes.data() + 187 + 16 * a, 8);
    EXPECT_NEAR(mx, hi[a], 1e-9);
    EXPECT_NEAR(mn, lo[a], 1e-9);
  }
}

// The E57 output (one scan, float coordinates, 8-bit colour, 8 packets of up to 4096 records)
// read by the pipeline's E57 reader gives the PLY output's points and colours exactly (both store
// floats), whole and streamed in chunks; every page's CRC-32C, computed here bit by bit, is the
// one stored big-endian after its 1020 bytes (E2807 § 7.3); the file is whole pages.
TEST(Relief, TheE57OutputIsThePlysPointsInCheckedPages) {
  const fs::path dir = hc::test::temp_dir("e57");
  ReliefSpec s = small_spec(30'000);
  s.rgb = true;
  const auto stats = hc::tools::write_relief(s, dir / "w.e57", 7000, 2);
  hc::tools::write_relief(s, dir / "w.ply", 7000, 2);
  const std::vector<char> bytes = read_all(dir / "w.e57");
  ASSERT_EQ(bytes.size() % 1024, 0U);
  EXPECT_EQ(stats.bytes, bytes.size());
  for (std::size_t page = 0; page < bytes.size() / 1024; ++page) {
    std::uint32_t c = 0xFFFFFFFFU;
    for (std::size_t i = 0; i < 1020; ++i) {
      c ^= static_cast<unsigned char>(bytes[page * 1024 + i]);
      for (int k = 0; k < 8; ++k) c = (c & 1U) ? (c >> 1) ^ 0x82F63B78U : c >> 1;
    }
    c = ~c;
    const auto* q = reinterpret_cast<const unsigned char*>(bytes.data() + page * 1024 + 1020);
    ASSERT_EQ((std::uint32_t{q[0]} << 24) | (std::uint32_t{q[1]} << 16) | (std::uint32_t{q[2]} << 8) | q[3], c) << "page " << page;
  }
  const hc::pipeline::Cloud ply = hc::pipeline::load_cloud(dir / "w.ply").value;
  const auto e57 = hc::pipeline::load_cloud(dir / "w.e57");
  ASSERT_EQ(e57.value.size(), s.points);
  EXPECT_TRUE(e57.value.xyz == ply.xyz);
  EXPECT_EQ(e57.value.rgb, ply.rgb);
  EXPECT_TRUE(e57.value.float32_xyz);
  for (const std::size_t chunk : {std::size_t{7}, std::size_t{5000}}) {
    auto stream = hc::pipeline::open_point_stream(dir / "w.e57");
    ASSERT_TRUE(stream->streamed());
    EXPECT_EQ(stream->total_points(), s.points);
    std::vector<double> xyz;
    std::vector<std::uint8_t> rgb;
    hc::pipeline::Cloud c;
    while (stream->next(c, chunk)) {
      ASSERT_LE(c.size(), chunk);
      xyz.insert(xyz.end(), c.xyz.data(), c.xyz.data() + c.xyz.size());
      rgb.insert(rgb.end(), c.rgb.begin(), c.rgb.end());
    }
    ASSERT_EQ(xyz.size(), 3 * s.points) << "chunk " << chunk;
    EXPECT_TRUE(std::equal(xyz.begin(), xyz.end(), ply.xyz.data())) << "chunk " << chunk;
    EXPECT_EQ(rgb, ply.rgb) << "chunk " << chunk;
  }
}

TEST(Relief, BadSpecsAndExistingFilesAreRefusedAndNothingIsLeft) {
  const fs::path dir = hc::test::temp_dir("errors");
  ReliefSpec s = small_spec(100);
  {
    std::ofstream(dir / "mine.ply") << "the user's file";
  }
  EXPECT_NE(hc::test::error_of([&] { hc::tools::write_relief(s, dir / "mine.ply"); }).find("mine.ply exists"),
            std::string::npos);
  std::ifstream in(dir / "mine.ply");
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), {}), "the user's file");
  EXPECT_NE(hc::test::error_of([&] { hc::tools::write_relief(s, dir / "missing" / "w.ply"); }).find("w.ply"),
            std::string::npos);
  ReliefSpec bad = s;
  bad.back_fraction = 0.7;
  bad.outlier_fraction = 0.4;
  try {
    hc::tools::write_relief(bad, dir / "w.ply");
    ADD_FAILURE() << "no error";
  } catch (const hc::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("back_fraction + outlier_fraction"), std::string::npos) << e.what();
  }
  bad = s;
  bad.width_m = std::nan("");
  EXPECT_THROW(hc::tools::write_relief(bad, dir / "w.ply"), hc::ConfigError);
  EXPECT_THROW(hc::tools::write_relief(s, dir / "w.xyz"), hc::ConfigError);
  EXPECT_THROW(hc::tools::write_relief(s, dir / "w.ply", 0), hc::ConfigError);
  bad = s;
  bad.width_m = 1e6;  // ±500 km does not fit LAS's int32 at 0.1 mm
  EXPECT_THROW(hc::tools::write_relief(bad, dir / "w.las"), hc::ConfigError);
  EXPECT_FALSE(hc::test::has_entry_named_with(dir, ".part-"));
  EXPECT_FALSE(fs::exists(dir / "w.ply"));
  EXPECT_FALSE(fs::exists(dir / "w.las"));
}

// The whole run on a generated wall: the back face is hidden, the outliers go, and the grid
// follows the analytic front face. 5 mm cells resolve the rosettes (0.09 m) but not the joints
// (0.008 m wide grooves), which cover about (2·0.008/0.25 + 2·0.008/0.5) ≈ 10 % of the wall; the
// 0.5 mm range noise is averaged over about 40 points per cell by the plane splats.
TEST(Relief, ARunFollowsTheAnalyticWall) {
  const fs::path dir = hc::test::temp_dir("run");
  ReliefSpec s = small_spec(400'000);
  s.chisel_amplitude_m = 0.0;  // below a 5 mm cell
  hc::tools::write_relief(s, dir / "wall.ply");
  const std::string yaml =
      "name: wall\ninput: {files: [wall.ply], units: m}\n"
      "grid: {n: 400, splat_radius_cells: 1.2, splat_mode: plane, see_through_depth_m: 0.02, hole_fill_max_cells: 64}\n"
      "cross_check: {tolerance_m: 0.003}\n";
  const hc::pipeline::RunConfig config = hc::pipeline::parse_run_config(yaml, dir / "wall.yaml");
  const hc::pipeline::BuiltScene built = hc::pipeline::build_scene(config);
  const hc::HeightField& depth = built.scene.layers.depth;
  const hc::GridGeometry& g = depth.geometry();
  ASSERT_EQ(g.cols, 400);
  const Eigen::Affine3d grid_to_model = built.scene.model_to_grid.inverse();
  std::size_t cells = 0, within_1mm = 0, far = 0;
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      const double z = depth.at(r, c);
      if (!std::isfinite(z)) continue;
      const Eigen::Vector3d m = grid_to_model * Eigen::Vector3d(g.x_of_col(c), g.y_of_row(r), z);
      const double err = std::fabs(m.z() - hc::tools::relief_height_m(s, m.x(), m.y()));
      ++cells;
      within_1mm += err <= 1e-3 ? 1U : 0U;
      far += err > 0.02 ? 1U : 0U;  // the back face (0.3 m) or an outlier spike would show here
    }
  }
  EXPECT_GE(static_cast<double>(cells), 0.98 * g.rows * g.cols);
  EXPECT_GE(static_cast<double>(within_1mm) / static_cast<double>(cells), 0.85);
  EXPECT_EQ(far, 0U);
}

}  // namespace
