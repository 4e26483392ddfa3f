// detail::InlineBilinear and detail::InlineResidual (inline_bilinear.hpp) against the functions
// they stand in for: BilinearSurface::sample (hc/common) and point_residual (cross_check.hpp).
// The cross-check's figures and the honest check's classes must not move when a loop takes the
// inline copy, so the oracle is bit equality of every double and float over the cases where
// the arithmetic branches: inside, on cell edges and grid lines, on and past each border (the
// clamp and the zero slope), cells with a NaN corner, NaN and infinite coordinates, and a
// geometry whose origin and cell size are not round numbers. A changed association in the
// copy ((1 − u)·((1 − v)·z00) for ((1 − u)·(1 − v))·z00) or a multiplication by 1/cell for the
// division fails the first test on some of the random points (checked by hand, 2026-11-27; the
// second, whose residuals are floats, does not always see a last-bit change of f).

#include "inline_bilinear.hpp"

#include "hc/common/bilinear_surface.hpp"
#include "hc/pipeline/cross_check.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

namespace {

using hc::BilinearSurface;
using hc::GridGeometry;
using hc::HeightField;
using hc::HeightFieldView;
using hc::SurfaceSample;
using hc::pipeline::PointResidual;
using hc::pipeline::point_residual;

bool same_bits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }
bool same_bits(float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; }

// A 37 × 23 grid, origin and cell not representable exactly, a carved-looking field and a few
// no-data samples (one in the interior, one on the border, one in a corner).
HeightField test_field() {
  GridGeometry g;
  g.cols = 37;
  g.rows = 23;
  g.cell_size_m = 0.0013;
  g.x0_m = -0.0241;
  g.y0_m = 0.3337;
  HeightField f(g);
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c) f.at(r, c) = static_cast<float>(0.01 * std::sin(0.7 * r) * std::cos(0.45 * c) + 0.002 * r);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  f.at(11, 17) = nan;
  f.at(0, 5) = nan;
  f.at(g.rows - 1, g.cols - 1) = nan;
  return f;
}

// Query points: random inside and up to two cells past each border, exact node and edge
// positions, and non-finite coordinates.
std::vector<std::array<double, 3>> queries(const GridGeometry& g) {
  std::vector<std::array<double, 3>> q;
  std::mt19937_64 rng(20261127);
  const double w = g.cell_size_m * (g.cols - 1), h = g.cell_size_m * (g.rows - 1);
  std::uniform_real_distribution<double> ux(g.x0_m - 2 * g.cell_size_m, g.x0_m + w + 2 * g.cell_size_m);
  std::uniform_real_distribution<double> uy(g.y0_m - 2 * g.cell_size_m, g.y0_m + h + 2 * g.cell_size_m);
  std::uniform_real_distribution<double> uz(-0.03, 0.03);
  for (int i = 0; i < 20000; ++i) q.push_back({ux(rng), uy(rng), uz(rng)});
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c) {
      q.push_back({g.x_of_col(c), g.y_of_row(r), 0.0});
      q.push_back({g.x_of_col(c + 0.5), g.y_of_row(r), 0.001});
      q.push_back({g.x_of_col(c), g.y_of_row(r + 0.5), -0.001});
    }
  const double inf = std::numeric_limits<double>::infinity(), nan = std::numeric_limits<double>::quiet_NaN();
  for (const double bad : {inf, -inf, nan}) {
    q.push_back({bad, g.y0_m, 0.0});
    q.push_back({g.x0_m, bad, 0.0});
    q.push_back({g.x0_m + 0.01, g.y0_m + 0.01, bad});
  }
  return q;
}

TEST(InlineBilinear, EqualsBilinearSurfaceBitForBit) {
  const HeightField f = test_field();
  const BilinearSurface reference(HeightFieldView::of(f));
  const hc::pipeline::detail::InlineBilinear copy(HeightFieldView::of(f));
  std::size_t valid = 0, invalid = 0, clamped = 0;
  for (const auto& p : queries(f.geometry())) {
    const SurfaceSample a = reference.sample(p[0], p[1]);
    const SurfaceSample b = copy.at<true>(p[0], p[1]);
    const SurfaceSample z = copy.at<false>(p[0], p[1]);
    ASSERT_EQ(a.valid, b.valid) << p[0] << " " << p[1];
    ASSERT_EQ(a.valid, z.valid) << p[0] << " " << p[1];
    ASSERT_TRUE(same_bits(a.z_m, b.z_m)) << p[0] << " " << p[1] << ": " << a.z_m << " vs " << b.z_m;
    ASSERT_TRUE(same_bits(a.z_m, z.z_m)) << p[0] << " " << p[1];
    ASSERT_TRUE(same_bits(a.dz_dx, b.dz_dx)) << p[0] << " " << p[1] << ": " << a.dz_dx << " vs " << b.dz_dx;
    ASSERT_TRUE(same_bits(a.dz_dy, b.dz_dy)) << p[0] << " " << p[1] << ": " << a.dz_dy << " vs " << b.dz_dy;
    valid += a.valid ? 1U : 0U;
    invalid += a.valid ? 0U : 1U;
    clamped += a.valid && (a.dz_dx == 0.0 || a.dz_dy == 0.0) ? 1U : 0U;
  }
  // The cases were reached: valid samples, no-data ones, and clamped borders with zero slope.
  EXPECT_GT(valid, 15000U);
  EXPECT_GT(invalid, 100U);
  EXPECT_GT(clamped, 100U);
}

TEST(InlineResidual, EqualsPointResidualBitForBit) {
  const HeightField f = test_field();
  const BilinearSurface surface(HeightFieldView::of(f));
  const hc::pipeline::detail::InlineResidual copy(HeightFieldView::of(f));
  std::size_t by_kind[4] = {0, 0, 0, 0};
  for (const double band : {0.004, 0.02}) {
    for (const auto& p : queries(f.geometry())) {
      const PointResidual a = point_residual(surface, f.geometry(), p[0], p[1], p[2], band);
      const PointResidual b = copy(p[0], p[1], p[2], band);
      ASSERT_EQ(a.kind, b.kind) << p[0] << " " << p[1] << " " << p[2];
      ASSERT_TRUE(same_bits(a.vertical_m, b.vertical_m)) << p[0] << " " << p[1] << " " << p[2];
      ASSERT_TRUE(same_bits(a.normal_m, b.normal_m)) << p[0] << " " << p[1] << " " << p[2];
      ++by_kind[a.kind];
    }
  }
  for (int k = 0; k < 4; ++k) EXPECT_GT(by_kind[k], 50U) << "kind " << k << " was reached";
}

}  // namespace
