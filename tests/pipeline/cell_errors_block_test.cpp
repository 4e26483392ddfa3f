// detail::cell_errors_in_block (run_internal.hpp), the tiled cross-check's cell errors of a
// window's interior, against detail::cross_check_cell_errors over the whole window (the bucket
// search, itself tested against brute force in cross_check_test.cpp): every sample of the block
// must get the same float bit for bit, by each of the three ways the function settles a sample
// (the four cells about it, a scan of every point, the bucket search), which the counts show.
// The clouds hold what moves a nearest point across a cell: points on grid lines and on the
// samples themselves, a steep step (the nearest in 3-D lies in another cell than the nearest in
// x-y), a filled hole (samples far from every point), non-finite points and no-data samples.

#include "run_internal.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/cross_check.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

namespace {

using hc::GridGeometry;
using hc::HeightField;
using hc::pipeline::Cloud;
namespace detail = hc::pipeline::detail;

GridGeometry geometry(int cols, int rows) {
  GridGeometry g;
  g.cols = cols;
  g.rows = rows;
  g.cell_size_m = 0.00049;
  g.x0_m = -0.0731;
  g.y0_m = 0.0217;
  return g;
}

// Height of the test surface: a gentle slope and a 4 mm step along x = x_step.
double surface_z(double x, double y, double x_step) { return 0.001 * std::sin(400.0 * x) + 0.02 * y + (x > x_step ? 0.004 : 0.0); }

struct Case {
  HeightField grid;
  Cloud points;
};

// `per_cell` points a cell on average, none in the hole [hole_c0, hole_c1) × [hole_r0, hole_r1)
// of samples (which keep their surface height, as hole filling gives them), a few points on
// grid lines and on samples, non-finite points; no-data samples in a strip.
Case make_case(int cols, int rows, double per_cell, std::array<int, 4> hole, std::uint64_t seed) {
  Case k{HeightField(geometry(cols, rows)), Cloud{}};
  const GridGeometry& g = k.grid.geometry();
  const double x_step = g.x_of_col(cols * 0.6);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) k.grid.at(r, c) = static_cast<float>(surface_z(g.x_of_col(c), g.y_of_row(r), x_step));
  for (int r = 2; r < rows - 2; ++r) k.grid.at(r, 3) = std::numeric_limits<float>::quiet_NaN();  // no data
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0), noise(-0.0002, 0.0002);
  const auto n = static_cast<std::size_t>(per_cell * cols * rows);
  std::vector<double> xyz;
  auto add = [&](double x, double y, double z) { xyz.insert(xyz.end(), {x, y, z}); };
  for (std::size_t i = 0; i < n; ++i) {
    const double cx = u(rng) * (cols - 1), cy = u(rng) * (rows - 1);
    if (cx >= hole[2] - 0.5 && cx < hole[3] - 0.5 && cy >= hole[0] - 0.5 && cy < hole[1] - 0.5) continue;
    const double x = g.x_of_col(cx), y = g.y_of_row(cy);
    add(x, y, surface_z(x, y, x_step) + noise(rng));
  }
  for (int i = 0; i < 200; ++i) {  // on grid lines and on samples
    const int c = 1 + static_cast<int>(u(rng) * (cols - 2)), r = 1 + static_cast<int>(u(rng) * (rows - 2));
    if (c >= hole[2] - 1 && c <= hole[3] && r >= hole[0] - 1 && r <= hole[1]) continue;
    add(g.x_of_col(c), g.y_of_row(r + u(rng)), surface_z(g.x_of_col(c), g.y_of_row(r), x_step));
    add(g.x_of_col(c), g.y_of_row(r), static_cast<double>(k.grid.at(r, c)) + 0.0001);
  }
  const double nan = std::numeric_limits<double>::quiet_NaN(), inf = std::numeric_limits<double>::infinity();
  add(nan, g.y0_m, 0.0);
  add(g.x0_m, inf, 0.0);
  add(g.x0_m, g.y0_m, -inf);
  k.points.xyz = Eigen::Map<Eigen::Matrix3Xd>(xyz.data(), 3, static_cast<Eigen::Index>(xyz.size() / 3));
  return k;
}

// Compares the block's errors with the bucket search's over the whole grid, bit for bit.
detail::CellErrorsInBlock expect_same(const Case& k, std::array<int, 4> block) {
  const hc::pipeline::CrossCheck all = detail::cross_check_cell_errors(k.points, k.grid, 0.002, 0.02).value;
  const detail::CellErrorsInBlock b = detail::cell_errors_in_block(k.points, k.grid, block, 0.002, 0.02);
  const int bw = block[3] - block[2];
  EXPECT_EQ(b.error_m.size(), static_cast<std::size_t>(bw) * static_cast<std::size_t>(block[1] - block[0]));
  std::size_t valid = 0, differing = 0;
  for (int r = block[0]; r < block[1]; ++r)
    for (int c = block[2]; c < block[3]; ++c) {
      const float want = all.cell_error_m.at(r, c);
      const float got = b.error_m[static_cast<std::size_t>(r - block[0]) * static_cast<std::size_t>(bw) + static_cast<std::size_t>(c - block[2])];
      valid += std::isnan(want) ? 0U : 1U;
      if (std::memcmp(&want, &got, sizeof want) != 0) {
        if (++differing <= 5) ADD_FAILURE() << "sample (" << r << ", " << c << "): " << got << " m, the bucket search " << want << " m";
      }
    }
  EXPECT_EQ(differing, 0U);
  EXPECT_EQ(b.by_corners + b.by_scan + b.by_buckets, valid);
  return b;
}

TEST(CellErrorsInBlock, DenseWindowsAreSettledByTheirCellsAndEqualTheBucketSearch) {
  const Case k = make_case(120, 90, 6.0, {0, 0, 0, 0}, 1);
  for (const std::array<int, 4> block : {std::array<int, 4>{0, 90, 0, 120}, std::array<int, 4>{10, 70, 20, 100},
                                         std::array<int, 4>{0, 1, 0, 1}, std::array<int, 4>{89, 90, 119, 120}}) {
    const detail::CellErrorsInBlock b = expect_same(k, block);
    EXPECT_GT(b.by_corners, 0U);
  }
  // An empty block is allowed and gives nothing.
  EXPECT_TRUE(detail::cell_errors_in_block(k.points, k.grid, {5, 5, 7, 9}, 0.002, 0.02).error_m.empty());
}

TEST(CellErrorsInBlock, AFilledHoleIsFoundByAScanOfThePoints) {
  // A hole of 6 × 5 samples: their nearest points lie cells away, past their own cells.
  const Case k = make_case(120, 90, 6.0, {40, 45, 60, 66}, 2);
  const detail::CellErrorsInBlock b = expect_same(k, {20, 70, 30, 100});
  EXPECT_GT(b.by_scan, 10U);
  EXPECT_EQ(b.by_buckets, 0U);
}

TEST(CellErrorsInBlock, ALargeHoleInAManyPointWindowFallsBackToTheBucketSearch) {
  // open samples × points above kBruteForceBudget: 40 × 30 open samples, about 4.3e5 points.
  const Case k = make_case(300, 240, 6.0, {100, 130, 100, 140}, 3);
  ASSERT_GT(1200.0 * static_cast<double>(k.points.size()), detail::kBruteForceBudget);
  const detail::CellErrorsInBlock b = expect_same(k, {80, 160, 80, 170});
  EXPECT_GT(b.by_buckets, 500U);
  EXPECT_EQ(b.by_scan, 0U);
}

TEST(CellErrorsInBlock, ASparseWindowEqualsTheBucketSearchToo) {
  // Under a point a cell: many samples have no point in their four cells.
  const Case k = make_case(80, 60, 0.4, {0, 0, 0, 0}, 4);
  const detail::CellErrorsInBlock b = expect_same(k, {5, 55, 5, 75});
  EXPECT_GT(b.by_scan + b.by_buckets, 50U);
}

TEST(CellErrorsInBlock, ErrorsNameTheProblem) {
  Case k = make_case(20, 20, 2.0, {0, 0, 0, 0}, 5);
  EXPECT_THROW(detail::cell_errors_in_block(k.points, k.grid, {0, 21, 0, 20}, 0.002, 0.02), std::invalid_argument);
  EXPECT_THROW(detail::cell_errors_in_block(k.points, k.grid, {5, 4, 0, 20}, 0.002, 0.02), std::invalid_argument);
  EXPECT_THROW(detail::cell_errors_in_block(k.points, k.grid, {0, 20, 0, 20}, 0.0, 0.02), hc::ConfigError);
  k.points.xyz.setConstant(std::numeric_limits<double>::quiet_NaN());
  try {
    (void)detail::cell_errors_in_block(k.points, k.grid, {0, 20, 0, 20}, 0.002, 0.02);
    ADD_FAILURE() << "no error for a cloud without a finite point";
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("none of the"), std::string::npos) << e.what();
  }
}

}  // namespace
