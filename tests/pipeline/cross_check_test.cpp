#include "hc/pipeline/cross_check.hpp"

#include "hc/common/bilinear_surface.hpp"
#include "hc/common/error.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/synthetic.hpp"

#include "cloud_fixtures.hpp"
#include "run_internal.hpp"
#include "stage_figure.hpp"
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cstdint>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

namespace hc::pipeline {
namespace {

using hc::test::figure;

using hc::test::cloud_of;

// Nearest-rank percentile of a fully sorted copy (the oracle for error_stats_mm).
double rank_of_sorted(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  const auto k = static_cast<std::size_t>(std::ceil(q * static_cast<double>(v.size())));
  return v[std::clamp<std::size_t>(k, 1, v.size()) - 1];
}

void expect_stats_equal(const ErrorStats& s, std::vector<double> abs_m) {
  ASSERT_EQ(s.count, abs_m.size());
  double sum_sq = 0.0;
  for (double v : abs_m) sum_sq += v * v;
  EXPECT_NEAR(s.rms_mm, std::sqrt(sum_sq / static_cast<double>(abs_m.size())) * 1e3, 1e-9);
  EXPECT_NEAR(s.p50_mm, rank_of_sorted(abs_m, 0.50) * 1e3, 1e-9);
  EXPECT_NEAR(s.p95_mm, rank_of_sorted(abs_m, 0.95) * 1e3, 1e-9);
  EXPECT_NEAR(s.p99_mm, rank_of_sorted(abs_m, 0.99) * 1e3, 1e-9);
  EXPECT_NEAR(s.max_mm, *std::max_element(abs_m.begin(), abs_m.end()) * 1e3, 1e-9);
}

TEST(ErrorStats, MatchesAFullSortAndTakesAbsoluteValues) {
  std::mt19937_64 rng(1);
  std::normal_distribution<double> n(0.0, 1e-3);
  for (std::size_t size : {1u, 2u, 3u, 99u, 100u, 101u, 12345u}) {
    std::vector<double> v(size);
    for (double& x : v) x = n(rng);
    std::vector<double> a(v);
    for (double& x : a) x = std::abs(x);
    expect_stats_equal(error_stats_mm(v), a);
  }
  // Known answer: 1..100 mm → p50 = 50, p95 = 95, p99 = 99, max = 100.
  std::vector<double> k;
  for (int i = 100; i >= 1; --i) k.push_back(-1e-3 * i);
  const ErrorStats s = error_stats_mm(k);
  EXPECT_DOUBLE_EQ(s.p50_mm, 50.0);
  EXPECT_DOUBLE_EQ(s.p95_mm, 95.0);
  EXPECT_DOUBLE_EQ(s.p99_mm, 99.0);
  EXPECT_DOUBLE_EQ(s.max_mm, 100.0);
}

TEST(ErrorStats, FloatValuesGiveTheStatsOfTheirDoubles) {
  // error_stats_mm_of_floats (the tiled cross-check's cells) against a full sort of the same
  // values as doubles, exactly: the floats convert without rounding.
  std::mt19937_64 rng(3);
  std::exponential_distribution<float> e(800.0f);
  for (std::size_t size : {1u, 7u, 1000u, 54321u}) {
    std::vector<float> v(size);
    for (float& x : v) x = (rng() & 1U) != 0U ? e(rng) : -e(rng);
    std::vector<double> a;
    for (float x : v) a.push_back(std::abs(static_cast<double>(x)));
    const ErrorStats s = hc::pipeline::error_stats_mm_of_floats(v);
    ASSERT_EQ(s.count, a.size());
    EXPECT_EQ(s.p50_mm, rank_of_sorted(a, 0.50) * 1e3);
    EXPECT_EQ(s.p95_mm, rank_of_sorted(a, 0.95) * 1e3);
    EXPECT_EQ(s.p99_mm, rank_of_sorted(a, 0.99) * 1e3);
    EXPECT_EQ(s.max_mm, *std::max_element(a.begin(), a.end()) * 1e3);
    double sum_sq = 0.0;
    for (double x : a) sum_sq += x * x;
    EXPECT_EQ(s.rms_mm, std::sqrt(sum_sq / static_cast<double>(a.size())) * 1e3);
  }
  EXPECT_THROW(hc::pipeline::error_stats_mm_of_floats({1e-3f, std::numeric_limits<float>::infinity()}), InputError);
}

TEST(ErrorStats, EmptyGivesZerosAndNaNIsAnError) {
  const ErrorStats s = error_stats_mm({});
  EXPECT_EQ(s.count, 0u);
  EXPECT_EQ(s.rms_mm, 0.0);
  EXPECT_EQ(s.max_mm, 0.0);
  EXPECT_THROW(error_stats_mm({1e-3, std::nan("")}), InputError);
}

// Cell → point distances (b) against exhaustive nearest neighbours, on a fully valid grid (so
// that many queries sit next to the threads' row split) and on a reprojected noisy sinusoid
// with see-through and filled cells.
void expect_cells_match_brute_force(const Cloud& cloud, const HeightField& grid, double tol_m) {
  const auto r = cross_check(cloud, grid, tol_m);
  const CrossCheck& cc = r.value;
  const GridGeometry& g = grid.geometry();
  ASSERT_EQ(cc.cell_error_m.geometry(), g);
  std::vector<double> expected;
  std::size_t supported = 0;
  for (int row = 0; row < g.rows; ++row) {
    for (int c = 0; c < g.cols; ++c) {
      if (!grid.valid(row, c)) {
        EXPECT_TRUE(std::isnan(cc.cell_error_m.at(row, c)));
        continue;
      }
      const Eigen::Vector3d q(g.x_of_col(c), g.y_of_row(row), grid.at(row, c));
      double best = std::numeric_limits<double>::infinity();
      for (Eigen::Index i = 0; i < cloud.xyz.cols(); ++i) {
        const Eigen::Vector3d p = cloud.xyz.col(i);
        if (!p.allFinite()) continue;
        best = std::min(best, (p - q).norm());
      }
      expected.push_back(best);
      supported += best <= tol_m ? 1U : 0U;
      ASSERT_NEAR(cc.cell_error_m.at(row, c), best, 1e-6 * best + 1e-9) << row << "," << c;
    }
  }
  ASSERT_EQ(cc.cell_to_point.count, expected.size());
  // The kd-tree works in float (local frame): agreement to 1e-6 relative + 1 nm.
  const ErrorStats want = error_stats_mm(expected);
  EXPECT_NEAR(cc.cell_to_point.rms_mm, want.rms_mm, 1e-6 * want.rms_mm + 1e-6);
  EXPECT_NEAR(cc.cell_to_point.p50_mm, want.p50_mm, 1e-6 * want.p50_mm + 1e-6);
  EXPECT_NEAR(cc.cell_to_point.p95_mm, want.p95_mm, 1e-6 * want.p95_mm + 1e-6);
  EXPECT_NEAR(cc.cell_to_point.p99_mm, want.p99_mm, 1e-6 * want.p99_mm + 1e-6);
  EXPECT_NEAR(cc.cell_to_point.max_mm, want.max_mm, 1e-6 * want.max_mm + 1e-6);
  EXPECT_DOUBLE_EQ(cc.supported_fraction, static_cast<double>(supported) / static_cast<double>(expected.size()));
  // The levels table's support without distances (each point marks the samples near it).
  EXPECT_DOUBLE_EQ(supported_fraction(cloud, grid, tol_m),
                   static_cast<double>(supported) / static_cast<double>(expected.size()));
}

TEST(CrossCheck, CellDistancesEqualBruteForceOnAFullGrid) {
  std::mt19937_64 rng(21);
  std::uniform_real_distribution<double> u(-0.01, 0.01), uz(-0.004, 0.004);
  for (int trial = 0; trial < 3; ++trial) {
    std::vector<Eigen::Vector3d> pts;
    for (int i = 0; i < 300 + 400 * trial; ++i) pts.emplace_back(u(rng), u(rng), uz(rng));
    GridGeometry g{37, 29, -0.011, -0.0105, 0.0007};
    HeightField h(g);
    for (float& v : h.values()) v = static_cast<float>(uz(rng));
    expect_cells_match_brute_force(cloud_of(pts), h, 0.001);
  }
}

TEST(CrossCheck, FarSamplesEqualBruteForceThroughTheKdTrees) {
  // Points only in one corner of a large grid: most samples are many cells from any point, so
  // their searches finish through kd-trees over all points.
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(0.0, 0.002), uz(-0.001, 0.001);
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 400; ++i) pts.emplace_back(u(rng), u(rng), uz(rng));
  GridGeometry g{120, 150, 0.0, 0.0, 2e-4};
  HeightField h(g);
  for (float& v : h.values()) v = static_cast<float>(uz(rng));
  const auto r = cross_check(cloud_of(pts), h, 1e-3);
  EXPECT_GT(figure(r.report, "samples_far_by_full_tree"), 1000.0);
  expect_cells_match_brute_force(cloud_of(pts), h, 1e-3);
}

TEST(CrossCheck, AFewFarSamplesEqualBruteForceThroughRings) {
  // A dense patch of samples over the points plus three samples 30+ cells away.
  std::mt19937_64 rng(6);
  std::uniform_real_distribution<double> u(0.0, 0.002), uz(-0.001, 0.001);
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 400; ++i) pts.emplace_back(u(rng), u(rng), uz(rng));
  GridGeometry g{60, 60, 0.0, 0.0, 2e-4};
  HeightField h(g);
  for (int r = 0; r < 10; ++r) {
    for (int c = 0; c < 10; ++c) h.at(r, c) = static_cast<float>(uz(rng));
  }
  h.at(45, 50) = 0.0f;
  h.at(59, 0) = 0.003f;
  h.at(30, 59) = -0.002f;
  const auto r = cross_check(cloud_of(pts), h, 1e-3);
  EXPECT_EQ(figure(r.report, "samples_far"), 3.0);
  EXPECT_EQ(figure(r.report, "samples_far_by_full_tree"), 0.0);
  expect_cells_match_brute_force(cloud_of(pts), h, 1e-3);
}

TEST(CrossCheck, CellDistancesEqualBruteForceOnAReprojectedScan) {
  SyntheticSpec s;
  s.kind = SurfaceKind::kSinusoid;
  s.half_extent_m = 0.01;
  s.density_per_m2 = 1.5e7;  // 6000 points
  s.noise_sigma_m = 5e-5;
  Cloud front = generate_surface(s);
  s.seed = 2;
  s.density_per_m2 = 5e6;
  Cloud back = generate_surface(s);
  back.xyz.row(2).array() -= 0.01;  // a back layer 10 mm behind
  Cloud both;
  both.xyz.resize(3, front.xyz.cols() + back.xyz.cols());
  both.xyz << front.xyz, back.xyz;
  ReprojectOptions o;
  o.grid.n_long_side = 60;
  o.see_through_depth_m = 0.002;
  const auto grid = fill_holes(reproject(both, o).value, 20).value;
  expect_cells_match_brute_force(both, grid.depth, 2e-4);
}

// The supported fraction is the share of valid cells whose error map value (a float) is within
// the tolerance, so that the scene's cell_error layer gives the figure back and a tiled run,
// which counts from its merged map, counts alike. Each tolerance is set to one cell's stored
// error exactly: before 2026-11-30 the double distance before its rounding to float was
// compared, and a cell whose double lay above its float then counted as unsupported (about
// half of the tolerances below; the oracle is a count over the map).
TEST(CrossCheck, TheSupportedFractionIsTheErrorMapsShareWithinTheTolerance) {
  SyntheticSpec s;
  s.kind = SurfaceKind::kSinusoid;
  s.half_extent_m = 0.01;
  s.density_per_m2 = 1.5e7;
  s.noise_sigma_m = 5e-5;
  const Cloud cloud = generate_surface(s);
  ReprojectOptions o;
  o.grid.n_long_side = 60;
  const auto grid = reproject(cloud, o).value;
  const auto first = cross_check(cloud, grid.depth, 1e-4).value;
  std::vector<float> errors;
  for (const float e : first.cell_error_m.values()) {
    if (!std::isnan(e) && e > 0.0f) errors.push_back(e);
  }
  ASSERT_GT(errors.size(), 100U);
  int checked = 0;
  for (std::size_t i = 0; i < errors.size(); i += errors.size() / 40) {
    const double tol = static_cast<double>(errors[i]);
    const auto r = cross_check(cloud, grid.depth, tol).value;
    std::size_t valid = 0, within = 0;
    for (std::size_t c = 0; c < r.cell_error_m.values().size(); ++c) {
      if (std::isnan(grid.depth.values()[c])) continue;
      ++valid;
      const float e = r.cell_error_m.values()[c];
      within += !std::isnan(e) && static_cast<double>(e) <= tol ? 1U : 0U;
    }
    EXPECT_EQ(r.supported_fraction, static_cast<double>(within) / static_cast<double>(valid)) << "tolerance " << tol << " m";
    ++checked;
  }
  EXPECT_GE(checked, 40);
}

// detail::cross_check_cell_errors with a query box (the tiled run's tile interior inside its
// window) searches only the samples inside it: each gives the whole search's distance bit for
// bit (the oracle: the same call without a box, itself checked against brute force above), the
// others are NaN, and the figures cover the searched samples. Boxes: an inner block, one
// reaching past the grid (clamped), one over no valid sample, and samples far from every point
// (deferred searches) inside the box.
TEST(CrossCheck, AQueryBoxSearchesItsSamplesAsTheWholeSearchDoes) {
  std::mt19937_64 rng(31);
  std::uniform_real_distribution<double> u(-0.01, 0.01), uz(-0.004, 0.004);
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 900; ++i) pts.emplace_back(u(rng), u(rng), uz(rng));
  GridGeometry g{61, 47, -0.012, -0.011, 0.0004};
  HeightField h(g);
  for (float& v : h.values()) v = static_cast<float>(uz(rng));
  for (int r = 40; r < 47; ++r)  // a block of no data, and a corner far from every point
    for (int c = 0; c < 8; ++c) h.at(r, c) = std::numeric_limits<float>::quiet_NaN();
  h.at(0, 60) = 0.02f;
  const Cloud cloud = cloud_of(pts);
  const CrossCheck whole = detail::cross_check_cell_errors(cloud, h, 0.001, 0.01).value;
  for (const std::array<int, 4> box : {std::array<int, 4>{5, 30, 7, 50}, std::array<int, 4>{-3, 2, 55, 99},
                                       std::array<int, 4>{41, 47, 0, 8}}) {
    SCOPED_TRACE(::testing::Message() << box[0] << " " << box[1] << " " << box[2] << " " << box[3]);
    const CrossCheck part = detail::cross_check_cell_errors(cloud, h, 0.001, 0.01, box).value;
    std::vector<double> inside;
    std::size_t supported = 0;
    for (int r = 0; r < g.rows; ++r) {
      for (int c = 0; c < g.cols; ++c) {
        const bool in = r >= box[0] && r < box[1] && c >= box[2] && c < box[3] && !std::isnan(h.at(r, c));
        if (!in) {
          EXPECT_TRUE(std::isnan(part.cell_error_m.at(r, c))) << r << "," << c;
          continue;
        }
        ASSERT_EQ(std::bit_cast<std::uint32_t>(part.cell_error_m.at(r, c)), std::bit_cast<std::uint32_t>(whole.cell_error_m.at(r, c)))
            << r << "," << c;
        inside.push_back(whole.cell_error_m.at(r, c));
        supported += whole.cell_error_m.at(r, c) <= 0.001 ? 1U : 0U;
      }
    }
    EXPECT_EQ(part.cell_to_point.count, inside.size());
    EXPECT_DOUBLE_EQ(part.supported_fraction,
                     inside.empty() ? 0.0 : static_cast<double>(supported) / static_cast<double>(inside.size()));
  }
}

TEST(CrossCheck, SupportedFractionIgnoresNonFiniteAndFarPointsAndChecksItsArguments) {
  // Two samples; one point on each, one point 1e30 m away, one NaN, one just outside the
  // tolerance of the first sample diagonally (in x-y and z together).
  GridGeometry g{2, 3, 0.0, 0.0, 0.001};
  HeightField h(g);
  h.at(0, 0) = 0.0f;
  h.at(1, 2) = 0.002f;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double t = 3e-4, off = 1.01 * t / std::sqrt(3.0);
  EXPECT_DOUBLE_EQ(supported_fraction(cloud_of({{0.0, 0.0, 1e-4}, {1e30, -1e30, 0.0}, {nan, 0.0, 0.0}}), h, t), 0.5);
  EXPECT_DOUBLE_EQ(supported_fraction(cloud_of({{off, off, off}, {0.002, 0.001, 0.002 + 0.99 * t}}), h, t), 0.5);
  EXPECT_DOUBLE_EQ(supported_fraction(cloud_of({{-off, off, -off}, {0.002, 0.001, 0.002}}), h, t), 0.5);
  EXPECT_DOUBLE_EQ(supported_fraction(cloud_of({{0.0, 0.0, 0.0}, {0.002, 0.001, 0.002}}), h, t), 1.0);
  EXPECT_THROW(supported_fraction(cloud_of({{0.0, 0.0, 0.0}}), h, 0.0), ConfigError);
  EXPECT_THROW(supported_fraction(cloud_of({{0.0, 0.0, 0.0}}), h, nan), ConfigError);
  EXPECT_THROW(supported_fraction(cloud_of({{0.0, 0.0, 0.0}}), HeightField(g), t), InputError);
}

TEST(CrossCheck, GeoreferencedXYOffsetsKeepFullPrecision) {
  // The same scene 10^5 m away in x and y: the kd-tree's local frame keeps the figures equal.
  SyntheticSpec s;
  s.half_extent_m = 0.01;
  s.density_per_m2 = 1e7;
  s.noise_sigma_m = 2e-5;
  const Cloud near = generate_surface(s);
  ReprojectOptions o;
  o.grid.n_long_side = 40;
  const HeightField grid = reproject(near, o).value.depth;
  Cloud far = near;
  far.xyz.row(0).array() += 123456.0;
  far.xyz.row(1).array() -= 654321.0;
  HeightField far_grid = grid;
  GridGeometry fg = grid.geometry();
  fg.x0_m += 123456.0;
  fg.y0_m -= 654321.0;
  far_grid = HeightField(fg);
  far_grid.values() = grid.values();
  const CrossCheck a = cross_check(near, grid, 1e-4).value;
  const CrossCheck b = cross_check(far, far_grid, 1e-4).value;
  EXPECT_NEAR(a.cell_to_point.rms_mm, b.cell_to_point.rms_mm, 1e-5);
  EXPECT_NEAR(a.cell_to_point.max_mm, b.cell_to_point.max_mm, 1e-5);
  EXPECT_NEAR(a.point_vertical.rms_mm, b.point_vertical.rms_mm, 1e-5);
  EXPECT_EQ(a.points_on_surface, b.points_on_surface);
}

TEST(CrossCheck, PointResidualsHaveKnownAnswers) {
  // Grid: the plane z = 0.5·x over 11 × 11 nodes, 1 mm apart, one no-data node at (5, 5).
  GridGeometry g{11, 11, 0.0, 0.0, 1e-3};
  HeightField h(g);
  for (int r = 0; r < 11; ++r) {
    for (int c = 0; c < 11; ++c) h.at(r, c) = static_cast<float>(0.5 * g.x_of_col(c));
  }
  h.at(5, 5) = kNoData;
  const double n_z = 1.0 / std::sqrt(1.0 + 0.25);
  const std::vector<Eigen::Vector3d> pts = {
      {0.0021, 0.0012, 0.5 * 0.0021 + 3e-4},   // 0.3 mm above
      {0.0082, 0.0087, 0.5 * 0.0082 - 1e-4},   // 0.1 mm below (within the band)
      {0.0071, 0.0023, 0.5 * 0.0071 - 5e-3},   // 5 mm below: hidden
      {0.0052, 0.0049, 0.5 * 0.0052},          // next to the no-data node: off surface
      {0.0120, 0.0050, 0.0},                   // outside the grid
      {std::nan(""), 0.0, 0.0},                // not finite: ignored
  };
  const auto r = cross_check(cloud_of(pts), h, 5e-4, 2e-3);
  const CrossCheck& cc = r.value;
  EXPECT_EQ(cc.points_on_surface, 2u);
  EXPECT_EQ(cc.points_hidden, 1u);
  EXPECT_EQ(cc.points_off_surface, 1u);
  EXPECT_EQ(cc.points_outside, 1u);
  EXPECT_EQ(cc.hidden_band_m, 2e-3);
  EXPECT_NEAR(cc.point_vertical.max_mm, 0.3, 1e-5);
  EXPECT_NEAR(cc.point_vertical.p50_mm, 0.1, 1e-5);
  EXPECT_NEAR(cc.point_normal.max_mm, 0.3 * n_z, 1e-5);
  EXPECT_NEAR(cc.point_normal.p50_mm, 0.1 * n_z, 1e-5);
  EXPECT_NEAR(cc.point_vertical.rms_mm, std::sqrt((0.09 + 0.01) / 2.0), 1e-5);
  EXPECT_EQ(cc.cell_to_point.count, 120u);
  EXPECT_EQ(r.report.count_out, 120u);
}

TEST(CrossCheck, ExactSurfaceSamplesAreFullySupported) {
  // Points exactly at the nodes of a tilted plane: zero residuals and zero cell distances.
  GridGeometry g{20, 30, -0.01, 0.02, 5e-4};
  HeightField h(g);
  std::vector<Eigen::Vector3d> pts;
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      const float z = static_cast<float>(0.1 * g.x_of_col(c) - 0.2 * g.y_of_row(r));
      h.at(r, c) = z;
      pts.emplace_back(static_cast<float>(g.x_of_col(c)), static_cast<float>(g.y_of_row(r)), z);
    }
  }
  const auto r = cross_check(cloud_of(pts), h, 1e-6);
  EXPECT_EQ(r.value.supported_fraction, 1.0);
  EXPECT_LT(r.value.cell_to_point.max_mm, 1e-5);  // float rounding in the kd-tree's local frame
  EXPECT_LT(r.value.point_vertical.max_mm, 1e-6);
  EXPECT_EQ(r.value.points_hidden, 0u);
}

TEST(CrossCheck, BadInputsAreErrors) {
  GridGeometry g{4, 4, 0.0, 0.0, 1e-3};
  HeightField h(g, 0.0f);
  const Cloud c = cloud_of({{0.001, 0.001, 0.0}});
  EXPECT_THROW(cross_check(Cloud{}, h, 1e-3), InputError);
  EXPECT_THROW(cross_check(cloud_of({{std::nan(""), 0.0, 0.0}}), h, 1e-3), InputError);
  EXPECT_THROW(cross_check(c, HeightField(g), 1e-3), InputError);  // no valid cell
  EXPECT_THROW(cross_check(c, HeightField(GridGeometry{1, 4, 0.0, 0.0, 1e-3}, 0.0f), 1e-3), InputError);
  EXPECT_THROW(cross_check(c, h, 0.0), ConfigError);
  EXPECT_THROW(cross_check(c, h, 1e-3, -1.0), ConfigError);
}

}  // namespace
}  // namespace hc::pipeline
