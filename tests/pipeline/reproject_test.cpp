#include "hc/pipeline/reproject.hpp"

#include "hc/common/bilinear_surface.hpp"
#include "hc/common/error.hpp"
#include "hc/pipeline/synthetic.hpp"

#include "cloud_fixtures.hpp"
#include "stage_figure.hpp"
#include <Eigen/Eigenvalues>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <tuple>
#include <vector>

namespace hc::pipeline {
namespace {

using hc::test::figure;

using hc::test::cloud_of;

ReprojectOptions with_n(int n) {
  ReprojectOptions o;
  o.grid.n_long_side = n;
  return o;
}

ReprojectOptions with_cell(double cell_m) {
  ReprojectOptions o;
  o.grid.cell_size_m = cell_m;
  return o;
}

std::size_t count_flag(const DepthGrid& g, CellFlag f) {
  return static_cast<std::size_t>(std::count(g.flags.begin(), g.flags.end(), static_cast<std::uint8_t>(f)));
}

// ---------------------------------------------------------------------------------------------
// Geometry and known answers

TEST(Reproject, GeometryFollowsTheLongerSideAndCentresTheShorterOne) {
  // x extent 0.10 m, y extent 0.043 m, N = 11 → cell 0.01 m, cols 11, rows round(4.3) + 1 = 5.
  const Cloud c = cloud_of({{0.0, 0.0, 0.0}, {0.1, 0.043, 1.0}, {0.05, 0.02, 2.0}});
  const auto r = reproject(c, with_n(11));
  const GridGeometry& g = r.value.depth.geometry();
  EXPECT_EQ(g.cols, 11);
  EXPECT_EQ(g.rows, 5);
  EXPECT_DOUBLE_EQ(g.cell_size_m, 0.01);
  EXPECT_DOUBLE_EQ(g.x0_m, 0.0);
  EXPECT_NEAR(g.y0_m, 0.0215 - 0.02, 1e-15);  // centred: middle row at the box centre
  EXPECT_EQ(r.value.flags.size(), g.cell_count());
  EXPECT_EQ(r.report.count_in, 3u);
  EXPECT_EQ(r.report.count_out, 3u);
  EXPECT_EQ(count_flag(r.value, kCellMeasured), 3u);

  // Cell size given: both sides from the extent.
  const auto r2 = reproject(c, with_cell(0.02));
  EXPECT_EQ(r2.value.depth.cols(), 6);
  EXPECT_EQ(r2.value.depth.rows(), 3);
}

class FrontMostOracle : public ::testing::TestWithParam<std::tuple<int, bool>> {};

// Small clouds take the one-thread path, large ones (≥ 2^18 points) the two-thread path; clouds
// with a non-finite point the careful path, others the fast path.
TEST_P(FrontMostOracle, FrontMostRuleMatchesABruteForceOracle) {
  const auto [size, with_non_finite] = GetParam();
  std::mt19937_64 rng(42);
  std::uniform_real_distribution<double> ux(-0.3, 0.7), uy(0.1, 0.5), uz(-1.0, 1.0);
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < size; ++i) pts.emplace_back(ux(rng), uy(rng), uz(rng));
  const double nan = std::numeric_limits<double>::quiet_NaN();
  if (with_non_finite) {
    pts.insert(pts.begin() + 3, Eigen::Vector3d(nan, 0.2, 5.0));  // skipped, in both halves
    pts.emplace_back(0.2, 0.3, std::numeric_limits<double>::infinity());
  }
  const Cloud cloud = cloud_of(pts);
  const auto r = reproject(cloud, with_n(41));
  const HeightField& h = r.value.depth;
  const GridGeometry& g = h.geometry();
  EXPECT_EQ(std::max(g.rows, g.cols), 41);
  EXPECT_EQ(figure(r.report, "points_non_finite"), with_non_finite ? 2.0 : 0.0);

  // Oracle: each finite point to its nearest node by exhaustive search over the nodes' x and y,
  // then the largest z per node.
  std::vector<double> best(g.cell_count(), -std::numeric_limits<double>::infinity());
  for (const auto& p : pts) {
    if (!p.allFinite()) continue;
    int bc = 0, br = 0;
    for (int c = 1; c < g.cols; ++c) {
      if (std::abs(p.x() - g.x_of_col(c)) < std::abs(p.x() - g.x_of_col(bc))) bc = c;
    }
    for (int rr = 1; rr < g.rows; ++rr) {
      if (std::abs(p.y() - g.y_of_row(rr)) < std::abs(p.y() - g.y_of_row(br))) br = rr;
    }
    auto& b = best[static_cast<std::size_t>(br * g.cols + bc)];
    b = std::max(b, p.z());
  }
  std::size_t valid = 0;
  for (int rr = 0; rr < g.rows; ++rr) {
    for (int c = 0; c < g.cols; ++c) {
      const double b = best[static_cast<std::size_t>(rr * g.cols + c)];
      if (std::isinf(b)) {
        EXPECT_TRUE(std::isnan(h.at(rr, c))) << rr << "," << c;
        EXPECT_EQ(r.value.flags[static_cast<std::size_t>(rr * g.cols + c)], kCellEmpty);
      } else {
        ++valid;
        EXPECT_EQ(h.at(rr, c), static_cast<float>(b)) << rr << "," << c;
        EXPECT_EQ(r.value.flags[static_cast<std::size_t>(rr * g.cols + c)], kCellMeasured);
      }
    }
  }
  EXPECT_EQ(h.valid_count(), valid);
  EXPECT_GT(valid, 0.8 * static_cast<double>(g.cell_count()));
}

INSTANTIATE_TEST_SUITE_P(Sizes, FrontMostOracle,
                         ::testing::Combine(::testing::Values(6000, 300000), ::testing::Bool()));

class ReprojectAnalytic : public ::testing::TestWithParam<SurfaceKind> {};

TEST_P(ReprojectAnalytic, DenseNoiseFreeGridIsWithinAQuarterCellOfTheSurface) {
  SyntheticSpec s;
  s.kind = GetParam();
  s.half_extent_m = 0.05;
  s.density_per_m2 = 4e7;  // ≈ 40 points per 1 mm cell
  s.seed = 3;
  const Cloud cloud = generate_surface(s);
  const auto r = reproject(cloud, with_n(101));
  const HeightField& h = r.value.depth;
  const double cell = h.cell_size_m();
  ASSERT_NEAR(cell, 1e-3, 1e-5);
  EXPECT_EQ(h.valid_count(), h.geometry().cell_count());  // dense: no pinholes

  const BilinearSurface f(HeightFieldView::of(h));
  const GridGeometry& g = h.geometry();
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> ux(g.x0_m, g.x_of_col(g.cols - 1));
  std::uniform_real_distribution<double> uy(g.y0_m, g.y_of_row(g.rows - 1));
  double sum_sq = 0.0;
  const int n = 20000;
  for (int i = 0; i < n; ++i) {
    const double x = ux(rng), y = uy(rng);
    const SurfaceSample v = f.sample(x, y);
    ASSERT_TRUE(v.valid);
    const double e = v.z_m - synthetic_height(s, x, y);
    sum_sq += e * e;
  }
  const double rms = std::sqrt(sum_sq / n);
  RecordProperty("rms_in_cells", std::to_string(rms / cell));
  EXPECT_LE(rms, 0.25 * cell) << to_string(s.kind) << ": RMS " << rms * 1e3 << " mm";
}

INSTANTIATE_TEST_SUITE_P(AllSurfaces, ReprojectAnalytic,
                         ::testing::Values(SurfaceKind::kPlane, SurfaceKind::kTiltedPlane,
                                           SurfaceKind::kSphereCap, SurfaceKind::kStep,
                                           SurfaceKind::kSinusoid),
                         [](const ::testing::TestParamInfo<SurfaceKind>& p) { return to_string(p.param); });

// ---------------------------------------------------------------------------------------------
// Splats

TEST(Reproject, SplatClosesPinholesWithoutMovingMeasuredCells) {
  SyntheticSpec s;
  s.kind = SurfaceKind::kTiltedPlane;
  s.half_extent_m = 0.025;
  s.density_per_m2 = 2e6;  // 2 points per 1 mm cell on average: ≈ 13 % of the cells stay empty
  s.seed = 5;
  const Cloud cloud = generate_surface(s);
  const auto plain = reproject(cloud, with_n(51));
  ReprojectOptions o = with_n(51);
  o.splat_radius_cells = 2.5;
  const auto splat = reproject(cloud, o);
  const HeightField& a = plain.value.depth;
  const HeightField& b = splat.value.depth;
  ASSERT_EQ(a.geometry(), b.geometry());
  const double cell = a.cell_size_m();

  std::size_t pinholes = 0;
  for (int r = 0; r < a.rows(); ++r) {
    for (int c = 0; c < a.cols(); ++c) {
      const auto i = static_cast<std::size_t>(r * a.cols() + c);
      ASSERT_TRUE(b.valid(r, c)) << "pinhole left at " << r << "," << c;
      if (a.valid(r, c)) {
        EXPECT_EQ(b.at(r, c), a.at(r, c));  // measured cells are untouched
        EXPECT_EQ(splat.value.flags[i], kCellMeasured);
      } else {
        ++pinholes;
        EXPECT_EQ(splat.value.flags[i], kCellSplatted);
        // A flat disc from a node within 2.5 cells, whose point lies within half a cell of it:
        // off by at most slope · (2.5 + 0.5) cells along each axis.
        const double truth = synthetic_height(s, a.geometry().x_of_col(c), a.geometry().y_of_row(r));
        EXPECT_NEAR(b.at(r, c), truth, (s.slope_x + s.slope_y) * 3.0 * cell + 1e-7);
      }
    }
  }
  EXPECT_GT(pinholes, a.geometry().cell_count() / 20);
  EXPECT_EQ(count_flag(splat.value, kCellSplatted), pinholes);
  EXPECT_EQ(figure(splat.report, "cells_splatted"), static_cast<double>(pinholes));
}

TEST(Reproject, SplatEqualsABruteForceDiscDilation) {
  std::mt19937_64 rng(8);
  std::uniform_real_distribution<double> u(0.0, 0.04), uz(-0.01, 0.01);
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 700; ++i) pts.emplace_back(u(rng), u(rng), uz(rng));
  const Cloud cloud = cloud_of(pts);
  for (double radius : {1.0, 1.5, 2.4, 3.0}) {
    const auto plain = reproject(cloud, with_n(61));
    ReprojectOptions o = with_n(61);
    o.splat_radius_cells = radius;
    const auto splat = reproject(cloud, o);
    const HeightField& a = plain.value.depth;
    const HeightField& b = splat.value.depth;
    for (int r = 0; r < a.rows(); ++r) {
      for (int c = 0; c < a.cols(); ++c) {
        if (a.valid(r, c)) {
          ASSERT_EQ(b.at(r, c), a.at(r, c));
          continue;
        }
        float want = -std::numeric_limits<float>::infinity();
        for (int rr = 0; rr < a.rows(); ++rr) {
          for (int cc = 0; cc < a.cols(); ++cc) {
            if ((rr - r) * (rr - r) + (cc - c) * (cc - c) <= radius * radius && a.valid(rr, cc)) {
              want = std::max(want, a.at(rr, cc));
            }
          }
        }
        if (std::isinf(want)) {
          ASSERT_TRUE(std::isnan(b.at(r, c))) << radius << ": " << r << "," << c;
        } else {
          ASSERT_EQ(b.at(r, c), want) << radius << ": " << r << "," << c;
        }
      }
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Interpolating splats (SplatMode::kInterpolate)

// The tilted plane z = 10 mm + 0.4·x − 0.25·y sampled on every third node of a 61 × 61 grid of
// 1 mm cells (points exactly on the nodes (3i, 3j) mm, i, j = 0 … 20).
constexpr double kPlaneSx = 0.4, kPlaneSy = -0.25, kLatticeCell = 1e-3;
double lattice_plane(double x, double y) { return 0.01 + kPlaneSx * x + kPlaneSy * y; }

Cloud sparse_plane_lattice() {
  std::vector<Eigen::Vector3d> pts;
  for (int j = 0; j <= 20; ++j) {
    for (int i = 0; i <= 20; ++i) {
      const double x = 3 * i * kLatticeCell, y = 3 * j * kLatticeCell;
      pts.emplace_back(x, y, lattice_plane(x, y));
    }
  }
  return cloud_of(pts);
}

ReprojectOptions interpolating(ReprojectOptions o, double radius) {
  o.splat_radius_cells = radius;
  o.splat_mode = SplatMode::kInterpolate;
  return o;
}

TEST(Reproject, InterpolatingSplatsLieOnATiltedPlaneWhereDiscsMakeTerraces) {
  const Cloud cloud = sparse_plane_lattice();
  const double radius = 3.0;
  const auto plain = reproject(cloud, with_cell(kLatticeCell));
  ReprojectOptions disc_o = with_cell(kLatticeCell);
  disc_o.splat_radius_cells = radius;
  const auto disc = reproject(cloud, disc_o);
  const auto interp = reproject(cloud, interpolating(with_cell(kLatticeCell), radius));
  const HeightField& a = plain.value.depth;
  const HeightField& d = disc.value.depth;
  const HeightField& b = interp.value.depth;
  ASSERT_EQ(a.cols(), 61);
  ASSERT_EQ(a.rows(), 61);
  ASSERT_EQ(b.geometry(), a.geometry());
  ASSERT_EQ(a.valid_count(), 21u * 21u);
  const GridGeometry& g = a.geometry();

  // Every cell is within 3 cells of a lattice node: all valid; measured cells unchanged.
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      const auto i = static_cast<std::size_t>(r * g.cols + c);
      ASSERT_TRUE(b.valid(r, c)) << r << "," << c;
      if (a.valid(r, c)) {
        EXPECT_EQ(b.at(r, c), a.at(r, c));
        EXPECT_EQ(interp.value.flags[i], kCellMeasured);
      } else {
        EXPECT_EQ(interp.value.flags[i], kCellSplatted) << r << "," << c;
      }
    }
  }
  EXPECT_EQ(figure(interp.report, "cells_splatted"), static_cast<double>(61 * 61 - 21 * 21));

  // Away from the border (where the samples are one-sided) the interpolated heights lie on the
  // plane and neighbour differences are the plane's slope · cell: no terraces. The discs give
  // steps of 0 and up to 3 slope · cell instead.
  const double step_x = kPlaneSx * kLatticeCell, step_y = kPlaneSy * kLatticeCell;
  double max_plane_err = 0.0, max_dev_x = 0.0, max_dev_y = 0.0, disc_dev_x = 0.0, disc_dev_y = 0.0;
  for (int r = 3; r < g.rows - 3; ++r) {
    for (int c = 3; c < g.cols - 3; ++c) {
      max_plane_err = std::max(max_plane_err, std::abs(b.at(r, c) - lattice_plane(g.x_of_col(c), g.y_of_row(r))));
      if (c + 1 < g.cols - 3) {
        max_dev_x = std::max(max_dev_x, std::abs(b.at(r, c + 1) - b.at(r, c) - step_x));
        disc_dev_x = std::max(disc_dev_x, std::abs(d.at(r, c + 1) - d.at(r, c) - step_x));
      }
      if (r + 1 < g.rows - 3) {
        max_dev_y = std::max(max_dev_y, std::abs(b.at(r + 1, c) - b.at(r, c) - step_y));
        disc_dev_y = std::max(disc_dev_y, std::abs(d.at(r + 1, c) - d.at(r, c) - step_y));
      }
    }
  }
  const double slope_cell = (std::abs(kPlaneSx) + std::abs(kPlaneSy)) * kLatticeCell;
  EXPECT_LT(max_plane_err, 0.05 * slope_cell);
  EXPECT_LT(max_dev_x, 0.1 * std::abs(step_x));
  EXPECT_LT(max_dev_y, 0.1 * std::abs(step_y));
  EXPECT_GT(disc_dev_x, 1.5 * std::abs(step_x));  // risers of 3 steps between flat terraces
  EXPECT_GT(disc_dev_y, 1.5 * std::abs(step_y));
  RecordProperty("plane_err_fraction", std::to_string(max_plane_err / slope_cell));
  RecordProperty("step_dev_x_fraction", std::to_string(max_dev_x / std::abs(step_x)));
  RecordProperty("disc_step_dev_x_fraction", std::to_string(disc_dev_x / std::abs(step_x)));
}

// A merged multi-view scan in miniature: the front surface (the tilted plane) sampled on every
// third node, and a back surface 20 mm behind it sampled on every other node, as the rear
// views of a statue show through the front view's sampling gaps. Interpolating splats with
// see-through handling must give the front plane everywhere: back samples are neither kept
// nor averaged in, and no cell is lost as see-through. (Before the occlusion step, every back
// node stayed a measured cell at −20 mm and the filled cells mixed both surfaces.)
TEST(Reproject, InterpolatingSplatsKeepOnlyTheFrontOfAMergedScan) {
  const double back_m = 0.02;
  std::vector<Eigen::Vector3d> pts;
  for (int j = 0; j <= 60; ++j) {
    for (int i = 0; i <= 60; ++i) {
      const double x = i * kLatticeCell, y = j * kLatticeCell;
      if (i % 3 == 0 && j % 3 == 0) {
        pts.emplace_back(x, y, lattice_plane(x, y));
      } else {
        pts.emplace_back(x, y, lattice_plane(x, y) - back_m);
      }
    }
  }
  ReprojectOptions o = interpolating(with_cell(kLatticeCell), 3.0);
  o.see_through_depth_m = 0.005;
  const auto out = reproject(cloud_of(pts), o);
  const HeightField& z = out.value.depth;
  const GridGeometry& g = z.geometry();
  ASSERT_EQ(g.cols, 61);
  ASSERT_EQ(g.rows, 61);
  EXPECT_EQ(z.valid_count(), 61u * 61u);
  EXPECT_EQ(count_flag(out.value, kCellMeasured), 21u * 21u);
  EXPECT_EQ(figure(out.report, "cells_occluded_by_splat"), static_cast<double>(61 * 61 - 21 * 21));
  EXPECT_EQ(figure(out.report, "cells_see_through"), 0.0);
  const double slope_cell = (std::abs(kPlaneSx) + std::abs(kPlaneSy)) * kLatticeCell;
  double max_err = 0.0, max_interior_err = 0.0;
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      const double e = std::abs(z.at(r, c) - lattice_plane(g.x_of_col(c), g.y_of_row(r)));
      max_err = std::max(max_err, e);
      if (r >= 3 && c >= 3 && r < g.rows - 3 && c < g.cols - 3) max_interior_err = std::max(max_interior_err, e);
    }
  }
  EXPECT_LT(max_interior_err, 0.05 * slope_cell);
  EXPECT_LT(max_err, 3.0 * slope_cell);  // one-sided means at the border, far from −20 mm
}

// Upsampling: the lattice has a point on every 3rd node; scanned on every 3rd node and
// interpolated, the grid is the plane itself (bilinear interpolation is exact on a plane).
TEST(Reproject, UpsampledGridIsTheCoarseScansBilinearSurface) {
  const Cloud cloud = sparse_plane_lattice();
  ReprojectOptions o = with_cell(kLatticeCell);
  o.upsample_factor = 3;
  const auto up = reproject(cloud, o);
  const HeightField& z = up.value.depth;
  const GridGeometry& g = z.geometry();
  ASSERT_EQ(g.cols, 61);
  ASSERT_EQ(g.rows, 61);
  EXPECT_EQ(z.valid_count(), 61u * 61u);
  EXPECT_EQ(count_flag(up.value, kCellMeasured), 21u * 21u);
  EXPECT_EQ(count_flag(up.value, kCellUpsampled), 61u * 61u - 21u * 21u);
  EXPECT_EQ(figure(up.report, "upsample_factor"), 3.0);
  double max_err = 0.0;
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      max_err = std::max(max_err, std::abs(z.at(r, c) - lattice_plane(g.x_of_col(c), g.y_of_row(r))));
    }
  }
  const double slope_cell = (std::abs(kPlaneSx) + std::abs(kPlaneSy)) * kLatticeCell;
  EXPECT_LT(max_err, 1e-3 * slope_cell);  // float rounding only
}

TEST(Reproject, AutoUpsampleFindsTheLatticeSpacing) {
  ReprojectOptions o = with_cell(kLatticeCell);
  o.upsample_factor = 0;
  const auto up = reproject(sparse_plane_lattice(), o);
  EXPECT_EQ(figure(up.report, "upsample_factor"), 3.0);  // K = 1, 2 leave lattice nodes isolated
  EXPECT_GE(figure(up.report, "upsample_coverage"), kAutoUpsampleCoverage);
  // A dense scan (a point on every node) is not upsampled.
  std::vector<Eigen::Vector3d> pts;
  for (int j = 0; j <= 30; ++j) {
    for (int i = 0; i <= 30; ++i) pts.emplace_back(i * kLatticeCell, j * kLatticeCell, lattice_plane(i * kLatticeCell, j * kLatticeCell));
  }
  EXPECT_EQ(figure(reproject(cloud_of(pts), o).report, "upsample_factor"), 1.0);
}

TEST(Reproject, UpsamplingNeverSpreadsAHoleBeyondItsCoarseCells) {
  // The lattice without its point at lattice (10, 10): coarse node (10, 10) has no data, so the
  // fine nodes within one coarse cell of it (|dr|, |dc| < 3 from node (30, 30)) have none.
  std::vector<Eigen::Vector3d> pts;
  for (int j = 0; j <= 20; ++j) {
    for (int i = 0; i <= 20; ++i) {
      if (i == 10 && j == 10) continue;
      const double x = 3 * i * kLatticeCell, y = 3 * j * kLatticeCell;
      pts.emplace_back(x, y, lattice_plane(x, y));
    }
  }
  ReprojectOptions o = with_cell(kLatticeCell);
  o.upsample_factor = 3;
  const auto up = reproject(cloud_of(pts), o);
  const HeightField& z = up.value.depth;
  const GridGeometry& g = z.geometry();
  ASSERT_EQ(g.cols, 61);
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      const bool in_hole = std::abs(r - 30) < 3 && std::abs(c - 30) < 3;
      EXPECT_EQ(z.valid(r, c), !in_hole) << r << "," << c;
      if (!in_hole) {
        EXPECT_NEAR(z.at(r, c), lattice_plane(g.x_of_col(c), g.y_of_row(r)), 1e-6);
      }
    }
  }
  EXPECT_EQ(up.value.flags[30 * 61 + 30], kCellEmpty);
}

TEST(ReprojectErrors, UpsampleFactorOutOfRangeIsAConfigError) {
  ReprojectOptions o = with_n(10);
  o.upsample_factor = kMaxUpsampleFactor + 1;
  EXPECT_THROW(reproject(sparse_plane_lattice(), o), ConfigError);
  o.upsample_factor = -1;
  EXPECT_THROW(reproject(sparse_plane_lattice(), o), ConfigError);
}

TEST(Reproject, InterpolatingSplatsEqualABruteForceNormalisedConvolution) {
  // Random sparse points with a 15 × 15 mm hole: the cells farther than the radius from every
  // measured cell stay no data, the others take Σ w z / Σ w (σ = radius / 2) over the measured
  // cells within the radius.
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0.0, 0.06), uz(-0.01, 0.01);
  std::vector<Eigen::Vector3d> pts = {{0.0, 0.0, 0.0}, {0.06, 0.06, 0.0}};
  while (pts.size() < 900) {
    const double x = u(rng), y = u(rng);
    if (x > 0.02 && x < 0.035 && y > 0.025 && y < 0.04) continue;
    pts.emplace_back(x, y, uz(rng));
  }
  const Cloud cloud = cloud_of(pts);
  const auto plain = reproject(cloud, with_cell(kLatticeCell));
  const HeightField& a = plain.value.depth;
  const GridGeometry& g = a.geometry();
  for (double radius : {0.7, 1.0, 1.5, 2.4, 3.0, 4.5}) {
    const auto interp = reproject(cloud, interpolating(with_cell(kLatticeCell), radius));
    const HeightField& b = interp.value.depth;
    const double sigma = radius / 2;
    const int reach = static_cast<int>(std::floor(radius));
    std::size_t filled = 0, far = 0;
    for (int r = 0; r < g.rows; ++r) {
      for (int c = 0; c < g.cols; ++c) {
        const auto i = static_cast<std::size_t>(r * g.cols + c);
        if (a.valid(r, c)) {
          ASSERT_EQ(b.at(r, c), a.at(r, c));
          ASSERT_EQ(interp.value.flags[i], kCellMeasured);
          continue;
        }
        double num = 0.0, den = 0.0;
        for (int rr = std::max(0, r - reach); rr <= std::min(g.rows - 1, r + reach); ++rr) {
          for (int cc = std::max(0, c - reach); cc <= std::min(g.cols - 1, c + reach); ++cc) {
            const double d2 = (rr - r) * (rr - r) + (cc - c) * (cc - c);
            if (d2 > radius * radius || !a.valid(rr, cc)) continue;
            const double w = std::exp(-d2 / (2 * sigma * sigma));
            num += w * a.at(rr, cc);
            den += w;
          }
        }
        if (den == 0.0) {
          ++far;
          ASSERT_TRUE(std::isnan(b.at(r, c))) << radius << ": " << r << "," << c;
          ASSERT_EQ(interp.value.flags[i], kCellEmpty);
        } else {
          ++filled;
          ASSERT_NEAR(b.at(r, c), num / den, 1e-8) << radius << ": " << r << "," << c;
          ASSERT_EQ(interp.value.flags[i], kCellSplatted);
        }
      }
    }
    EXPECT_EQ(figure(interp.report, "cells_splatted"), static_cast<double>(filled));
    EXPECT_GT(far, radius < 1.0 ? 1000u : 20u) << radius;  // the hole's centre stays empty
    if (radius >= 1.0) {
      EXPECT_GT(filled, 100u) << radius;
    }
  }
}

// ---------------------------------------------------------------------------------------------
// See-through

struct TwoLayer {
  Cloud cloud;
  double cell = 1e-3;
  int n = 61;  // nodes per side, cell 1 mm, x0 = y0 = −30 mm
};

// Front plane z = 0 with rectangular gaps (in node indices, inclusive) and optionally only over
// x < front_x_max; a back plane z = −10 mm everywhere. Dense (≈ 25 points per cell per layer).
// Corner points pin the bounding box so that node (r, c) sits at (−30 + c, −30 + r) mm.
TwoLayer two_layer(const std::vector<std::array<int, 4>>& gaps, double front_x_max = 1.0) {
  TwoLayer t;
  const double h = 0.5 * (t.n - 1) * t.cell;
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> u(-h, h);
  std::vector<Eigen::Vector3d> pts = {{-h, -h, -0.01}, {h, -h, -0.01}, {-h, h, -0.01}, {h, h, -0.01}};
  const int per_layer = 25 * t.n * t.n;
  for (int i = 0; i < per_layer; ++i) pts.emplace_back(u(rng), u(rng), -0.01);
  for (int i = 0; i < per_layer; ++i) {
    const double x = u(rng), y = u(rng);
    if (x >= front_x_max) continue;
    const int c = static_cast<int>(std::floor((x + h) / t.cell + 0.5));
    const int r = static_cast<int>(std::floor((y + h) / t.cell + 0.5));
    bool in_gap = false;
    for (const auto& gap : gaps) in_gap |= r >= gap[0] && r <= gap[1] && c >= gap[2] && c <= gap[3];
    if (!in_gap) pts.emplace_back(x, y, 0.0);
  }
  t.cloud = cloud_of(pts);
  return t;
}

TEST(Reproject, SeeThroughGapsBecomeNoDataAndNoFrontCellIsLost) {
  // A 3 × 3 gap, a 5 × 5 gap and a 1 × 6 slit in the front plane.
  const std::vector<std::array<int, 4>> gaps = {{10, 12, 10, 12}, {30, 34, 40, 44}, {50, 50, 20, 25}};
  const TwoLayer t = two_layer(gaps);
  ReprojectOptions o = with_cell(t.cell);
  const auto naive = reproject(t.cloud, o);
  ASSERT_EQ(naive.value.depth.cols(), t.n);
  ASSERT_EQ(naive.value.depth.rows(), t.n);
  o.see_through_depth_m = 0.002;
  o.see_through_window_cells = 5;  // reaches across the 5-cell gap from its corners
  const auto handled = reproject(t.cloud, o);
  const HeightField& h = handled.value.depth;

  std::size_t gap_cells = 0;
  for (int r = 0; r < t.n; ++r) {
    for (int c = 0; c < t.n; ++c) {
      bool in_gap = false;
      for (const auto& gap : gaps) in_gap |= r >= gap[0] && r <= gap[1] && c >= gap[2] && c <= gap[3];
      const auto i = static_cast<std::size_t>(r * t.n + c);
      if (in_gap) {
        ++gap_cells;
        EXPECT_FLOAT_EQ(naive.value.depth.at(r, c), -0.01f);  // the naive grid sees the back
        EXPECT_EQ(handled.value.flags[i], kCellSeeThrough) << r << "," << c;
        EXPECT_TRUE(std::isnan(h.at(r, c)));
      } else {
        EXPECT_EQ(handled.value.flags[i], kCellMeasured) << r << "," << c;
        EXPECT_FLOAT_EQ(h.at(r, c), 0.0f) << r << "," << c;
      }
    }
  }
  EXPECT_EQ(count_flag(handled.value, kCellSeeThrough), gap_cells);
  EXPECT_EQ(figure(handled.report, "cells_see_through"), static_cast<double>(gap_cells));
}

TEST(Reproject, SeeThroughKeepsAOneSidedDrop) {
  // The front plane covers x < 0.3 mm only: beyond its edge the back plane is the visible
  // surface (a silhouette, not a gap), so nothing is rejected.
  const TwoLayer t = two_layer({}, 0.0003);
  ReprojectOptions o = with_cell(t.cell);
  o.see_through_depth_m = 0.002;
  o.see_through_window_cells = 3;
  const auto r = reproject(t.cloud, o);
  EXPECT_EQ(count_flag(r.value, kCellSeeThrough), 0u);
  EXPECT_EQ(r.value.depth.valid_count(), r.value.depth.geometry().cell_count());
  EXPECT_FLOAT_EQ(r.value.depth.at(30, 30), 0.0f);
  EXPECT_FLOAT_EQ(r.value.depth.at(30, 31), -0.01f);
}

TEST(Reproject, SplatOccludesNarrowGapsWithTheFrontSurface) {
  // With splats on, a 1-cell gap is covered by the discs of the front points around it.
  const TwoLayer t = two_layer({{20, 20, 20, 20}});
  ReprojectOptions o = with_cell(t.cell);
  o.splat_radius_cells = 1.5;
  o.see_through_depth_m = 0.002;
  const auto r = reproject(t.cloud, o);
  EXPECT_FLOAT_EQ(r.value.depth.at(20, 20), 0.0f);
  EXPECT_EQ(r.value.flags[static_cast<std::size_t>(20 * t.n + 20)], kCellSplatted);
  EXPECT_EQ(count_flag(r.value, kCellSeeThrough), 0u);
  EXPECT_EQ(count_flag(r.value, kCellSplatted), 1u);
}

TEST(Reproject, InterpolatingSplatsOccludeAndSeeThroughRunsAfter) {
  // A back-plane cell seen through a 1-cell gap of the front plane (z = 0) lies 10 mm below the
  // front samples within the radius: the occlusion step empties it and the front surface
  // interpolates over it (as the discs do). A 5 × 5 gap is wider than the radius: its centre
  // keeps the back plane until the see-through test rejects it.
  const TwoLayer t = two_layer({{20, 20, 20, 20}, {40, 44, 40, 44}});
  ReprojectOptions o = interpolating(with_cell(t.cell), 1.5);
  o.see_through_depth_m = 0.002;
  const auto r = reproject(t.cloud, o);
  ASSERT_TRUE(r.value.depth.valid(20, 20));
  EXPECT_NEAR(r.value.depth.at(20, 20), 0.0, 1e-6);
  EXPECT_EQ(r.value.flags[static_cast<std::size_t>(20 * t.n + 20)], kCellSplatted);
  EXPECT_TRUE(std::isnan(r.value.depth.at(42, 42)));
  EXPECT_EQ(r.value.flags[static_cast<std::size_t>(42 * t.n + 42)], kCellSeeThrough);
  // No cell anywhere holds the back plane (−10 mm) or a mix of both surfaces.
  for (int row = 0; row < t.n; ++row) {
    for (int col = 0; col < t.n; ++col) {
      if (r.value.depth.valid(row, col)) {
        EXPECT_NEAR(r.value.depth.at(row, col), 0.0, 1e-6) << row << "," << col;
      }
    }
  }
  EXPECT_GE(figure(r.report, "cells_occluded_by_splat"), 1.0 + 16.0);  // the 1-cell gap + the 5 × 5 gap's rim
}

// ---------------------------------------------------------------------------------------------
// Hole filling

DepthGrid tilted_grid(int rows, int cols, double cell) {
  GridGeometry g{rows, cols, 0.0, 0.0, cell};
  DepthGrid d{HeightField(g), std::vector<std::uint8_t>(g.cell_count(), kCellMeasured)};
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) d.depth.at(r, c) = static_cast<float>(0.01 + 0.1 * g.x_of_col(c));
  }
  return d;
}

void carve(DepthGrid& d, int r0, int r1, int c0, int c1, CellFlag flag = kCellEmpty) {
  for (int r = r0; r <= r1; ++r) {
    for (int c = c0; c <= c1; ++c) {
      d.depth.at(r, c) = kNoData;
      d.flags[static_cast<std::size_t>(r * d.depth.cols() + c)] = flag;
    }
  }
}

TEST(FillHoles, FillsSmallInteriorHolesOnlyAndMarksThem) {
  DepthGrid d = tilted_grid(60, 80, 1e-3);
  carve(d, 10, 12, 10, 12);                   // 9 cells: filled
  carve(d, 20, 24, 30, 33, kCellSeeThrough);  // 20 cells (see-through): filled
  carve(d, 30, 39, 50, 59);                   // 100 cells: too large
  carve(d, 0, 59, 75, 79);                    // touches the border: background
  carve(d, 50, 51, 0, 2);                     // 6 cells on the border: background
  const DepthGrid before = d;
  const auto r = fill_holes(d, 50);
  const DepthGrid& out = r.value;
  const GridGeometry& g = out.depth.geometry();
  std::size_t filled = 0;
  for (int row = 0; row < g.rows; ++row) {
    for (int c = 0; c < g.cols; ++c) {
      const auto i = static_cast<std::size_t>(row * g.cols + c);
      const bool small = (row >= 10 && row <= 12 && c >= 10 && c <= 12) ||
                         (row >= 20 && row <= 24 && c >= 30 && c <= 33);
      if (small) {
        ++filled;
        EXPECT_EQ(out.flags[i], kCellFilled);
        ASSERT_TRUE(out.depth.valid(row, c));
        // Normalised convolution is a weighted mean of the known cells around a hole cell; on a
        // ramp its error is slope × the offset of that mean, less than 2 cells here.
        EXPECT_NEAR(out.depth.at(row, c), 0.01 + 0.1 * g.x_of_col(c), 0.1 * 2e-3);
      } else if (!before.depth.valid(row, c)) {
        EXPECT_TRUE(std::isnan(out.depth.at(row, c))) << row << "," << c;
        EXPECT_EQ(out.flags[i], before.flags[i]);
      } else {
        EXPECT_EQ(out.depth.at(row, c), before.depth.at(row, c));
        EXPECT_EQ(out.flags[i], kCellMeasured);
      }
    }
  }
  EXPECT_EQ(filled, 29u);
  EXPECT_EQ(r.report.count_out, r.report.count_in + 29);
  EXPECT_EQ(figure(r.report, "holes_filled"), 2.0);
  EXPECT_EQ(figure(r.report, "cells_filled"), 29.0);
}

TEST(FillHoles, ConstantSurfaceIsFilledExactlyAndSizeLimitIsInclusive) {
  GridGeometry g{30, 30, 0.0, 0.0, 1e-3};
  DepthGrid d{HeightField(g, 0.25f), std::vector<std::uint8_t>(g.cell_count(), kCellMeasured)};
  carve(d, 5, 9, 5, 9);  // 25 cells
  // Two 4-cell holes touching only at a corner: separate under 4-connectivity.
  carve(d, 15, 16, 15, 16);
  carve(d, 17, 18, 17, 18);
  const auto r = fill_holes(d, 25);
  EXPECT_EQ(r.value.depth.valid_count(), g.cell_count());
  for (float v : r.value.depth.values()) EXPECT_FLOAT_EQ(v, 0.25f);
  EXPECT_EQ(figure(r.report, "holes_filled"), 3.0);

  const auto limited = fill_holes(d, 24);  // the 25-cell hole is now too large
  EXPECT_EQ(limited.value.depth.valid_count(), g.cell_count() - 25);
  EXPECT_EQ(figure(limited.report, "holes_filled"), 2.0);
}

TEST(FillHoles, AHoleAcrossADepthStepStaysEmptyUnderARimStepLimit) {
  // Two flat surfaces: columns 0..14 at 0.0 m (a wall), columns 15..29 at 1.4 m (an object in
  // front). Hole A (2 x 2) sits across the step at columns 14..15; hole B (2 x 2) lies inside
  // the front surface. Without a limit both are filled (A with a value between the surfaces).
  // A's rim: 12 cells in columns 13..16 (4, 2, 2, 4 cells) at 0, 0, 1.4, 1.4 m. By hand, the
  // least-squares plane has mean 0.7 m and slope Σu·dz / Σu² = 9.8 / 19 m per column
  // (u = col − 14.5), so the residuals are ±0.074 m (columns 13, 16) and ±0.442 m (14, 15): a
  // spread of 0.884 m. B's rim is flat: spread 0.
  GridGeometry g{30, 30, 0.0, 0.0, 1e-2};
  DepthGrid d{HeightField(g, 0.0f), std::vector<std::uint8_t>(g.cell_count(), kCellMeasured)};
  for (int r = 0; r < 30; ++r)
    for (int c = 15; c < 30; ++c) d.depth.at(r, c) = 1.4f;
  carve(d, 10, 11, 14, 15);  // hole A: rows 10..11, columns 14..15
  carve(d, 20, 21, 22, 23);  // hole B
  const auto all = fill_holes(d, 16);
  EXPECT_EQ(all.value.depth.valid_count(), g.cell_count());
  const float a = all.value.depth.at(10, 14);
  EXPECT_GT(a, 0.05f);  // the invented in-between surface the limit exists to prevent
  EXPECT_LT(a, 1.35f);
  const auto limited = fill_holes(d, 16, 0.1);
  EXPECT_EQ(limited.value.depth.valid_count(), g.cell_count() - 4);
  for (int r = 10; r <= 11; ++r)
    for (int c = 14; c <= 15; ++c) EXPECT_TRUE(std::isnan(limited.value.depth.at(r, c)));
  EXPECT_FLOAT_EQ(limited.value.depth.at(20, 22), 1.4f);
  EXPECT_EQ(figure(limited.report, "holes_filled"), 1.0);
  EXPECT_EQ(figure(limited.report, "holes_at_depth_steps"), 1.0);
  // Either side of the hand-computed spread of 0.884 m.
  EXPECT_EQ(fill_holes(d, 16, 0.87).value.depth.valid_count(), g.cell_count() - 4);
  EXPECT_EQ(fill_holes(d, 16, 0.90).value.depth.valid_count(), g.cell_count());
  // A steep slope is one surface, not a step: its rim lies on a plane and the hole is filled,
  // with the plane's value, however small the limit.
  DepthGrid slope{HeightField(g, 0.0f), std::vector<std::uint8_t>(g.cell_count(), kCellMeasured)};
  for (int r = 0; r < 30; ++r)
    for (int c = 0; c < 30; ++c) slope.depth.at(r, c) = 0.2f * static_cast<float>(c) + 0.05f * static_cast<float>(r);
  carve(slope, 10, 12, 10, 12);
  const auto steep = fill_holes(slope, 16, 0.01);
  EXPECT_EQ(steep.value.depth.valid_count(), g.cell_count());
  EXPECT_NEAR(steep.value.depth.at(11, 11), 0.2 * 11 + 0.05 * 11, 1e-4);
  EXPECT_THROW(fill_holes(d, 16, -0.1), ConfigError);
  EXPECT_THROW(fill_holes(d, 16, std::numeric_limits<double>::infinity()), ConfigError);
}

TEST(FillHoles, ZeroDisablesAndNegativeIsAnError) {
  DepthGrid d = tilted_grid(10, 10, 1e-3);
  carve(d, 4, 5, 4, 5);
  const auto r = fill_holes(d, 0);
  EXPECT_EQ(r.value.depth.valid_count(), 96u);
  EXPECT_THROW(fill_holes(d, -1), ConfigError);
  DepthGrid bad = d;
  bad.flags = std::vector<std::uint8_t>(d.flags.size() - 1, kCellMeasured);
  EXPECT_THROW(fill_holes(bad, 10), InputError);
}

// ---------------------------------------------------------------------------------------------
// Errors

template <class E>
std::string message_of(const Cloud& c, const ReprojectOptions& o) {
  try {
    reproject(c, o);
  } catch (const E& e) {
    return e.what();
  } catch (const std::exception& e) {
    ADD_FAILURE() << "wrong exception type: " << e.what();
    return {};
  }
  ADD_FAILURE() << "no exception";
  return {};
}

TEST(ReprojectErrors, BadGridSpecIsAConfigError) {
  const Cloud c = cloud_of({{0, 0, 0}, {1, 1, 0}});
  EXPECT_NE(message_of<ConfigError>(c, with_n(1)).find("n_long_side = 1"), std::string::npos);
  EXPECT_NE(message_of<ConfigError>(c, with_n(-5)).find("n_long_side = -5"), std::string::npos);
  EXPECT_NE(message_of<ConfigError>(c, ReprojectOptions{}).find("unspecified"), std::string::npos);
  ReprojectOptions both = with_n(10);
  both.grid.cell_size_m = 0.1;
  EXPECT_NE(message_of<ConfigError>(c, both).find("ambiguous"), std::string::npos);
  EXPECT_NE(message_of<ConfigError>(c, with_cell(-0.1)).find("cell_size_m"), std::string::npos);
  ReprojectOptions splat = with_n(10);
  splat.splat_radius_cells = -1.0;
  EXPECT_NE(message_of<ConfigError>(c, splat).find("splat_radius_cells"), std::string::npos);
  ReprojectOptions win = with_n(10);
  win.see_through_depth_m = 0.001;
  win.see_through_window_cells = 0;
  EXPECT_NE(message_of<ConfigError>(c, win).find("see_through_window_cells"), std::string::npos);
}

// ---------------------------------------------------------------------------------------------
// Plane splats (SplatMode::kPlane): the oracle is the analytic surface the points were drawn from.

ReprojectOptions planes(ReprojectOptions o, double radius, double see_through_m = 0.0) {
  o.splat_radius_cells = radius;
  o.splat_mode = SplatMode::kPlane;
  o.see_through_depth_m = see_through_m;
  return o;
}

// `per_cell` points per 1 mm cell, uniform at random over [0, 60] mm², on z = f(x, y) + N(0, σ²).
template <class F>
std::vector<Eigen::Vector3d> random_samples(F f, double per_cell, double sigma_m, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 60.0 * kLatticeCell);
  std::normal_distribution<double> noise(0.0, sigma_m > 0.0 ? sigma_m : 1.0);
  std::vector<Eigen::Vector3d> pts;
  const auto n = static_cast<std::size_t>(per_cell * 60.0 * 60.0);
  for (std::size_t i = 0; i < n; ++i) {
    const double x = u(rng), y = u(rng);
    pts.emplace_back(x, y, f(x, y) + (sigma_m > 0.0 ? noise(rng) : 0.0));
  }
  pts.emplace_back(0.0, 0.0, f(0.0, 0.0));  // pin the box to [0, 60] mm, so nodes sit on whole mm
  pts.emplace_back(60.0 * kLatticeCell, 60.0 * kLatticeCell, f(60.0 * kLatticeCell, 60.0 * kLatticeCell));
  return pts;
}

// Brute-force oracle of SplatMode::kPlane's documented rule at node (r, c), in double: the
// points within `radius` cells in x-y, on the front surface when `gap_m` > 0 (z ≥ the highest
// front-most cell z within radius + √2/2 cells − gap), Gaussian weights (σ = radius / 2), and
// the value at the node of the weighted least-squares plane, its slope fitted along each
// eigenvector e of the weighted x-y covariance (Eigen's solver) with eigenvalue l only where
// (e·x̄)² ≤ 9·l. NaN when no point qualifies.
double plane_oracle(const Cloud& cloud, const DepthGrid& front_most, int r, int c, double radius, double gap_m) {
  const GridGeometry& g = front_most.depth.geometry();
  const double reach = radius + 0.7072;
  double ref = -std::numeric_limits<double>::infinity();
  for (int rr = 0; rr < g.rows; ++rr) {
    for (int cc = 0; cc < g.cols; ++cc) {
      if (!front_most.depth.valid(rr, cc) || (rr - r) * (rr - r) + (cc - c) * (cc - c) > reach * reach) continue;
      ref = std::max(ref, static_cast<double>(front_most.depth.at(rr, cc)));
    }
  }
  double sw = 0.0, sz = 0.0;
  Eigen::Vector2d sx = Eigen::Vector2d::Zero(), sxz = Eigen::Vector2d::Zero();
  Eigen::Matrix2d sxx = Eigen::Matrix2d::Zero();
  const double sigma = radius / 2.0;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const auto k = static_cast<Eigen::Index>(i);
    const double dx = (cloud.xyz(0, k) - g.x_of_col(c)) / g.cell_size_m, dy = (cloud.xyz(1, k) - g.y_of_row(r)) / g.cell_size_m;
    const double d2 = dx * dx + dy * dy;
    if (d2 > radius * radius || (gap_m > 0.0 && cloud.xyz(2, k) < ref - gap_m)) continue;
    const double w = std::exp(-d2 / (2.0 * sigma * sigma));
    sw += w;
    sx += w * Eigen::Vector2d(dx, dy);
    sz += w * cloud.xyz(2, k);
    sxx += w * Eigen::Vector2d(dx, dy) * Eigen::Vector2d(dx, dy).transpose();
    sxz += w * Eigen::Vector2d(dx, dy) * cloud.xyz(2, k);
  }
  if (sw == 0.0) return std::numeric_limits<double>::quiet_NaN();
  const Eigen::Vector2d xbar = sx / sw;
  const double zbar = sz / sw;
  const Eigen::Matrix2d cov = sxx / sw - xbar * xbar.transpose();
  const Eigen::Vector2d cz = sxz / sw - xbar * zbar;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(cov);
  Eigen::Vector2d slope = Eigen::Vector2d::Zero();
  for (int k = 0; k < 2; ++k) {
    const double l = eig.eigenvalues()(k);
    const Eigen::Vector2d e = eig.eigenvectors().col(k);
    if (l > 1e-9 && std::pow(e.dot(xbar), 2) <= 9.0 * l) slope += e * (e.dot(cz) / l);
  }
  return zbar - slope.dot(xbar);
}

TEST(Reproject, PlaneSplatsReproduceATiltedPlaneAtEveryInteriorNodeWhereFrontMostSamplesDoNot) {
  const Cloud cloud = cloud_of(random_samples(lattice_plane, 3.0, 0.0, 7));
  const auto plane = reproject(cloud, planes(with_cell(kLatticeCell), 1.5));
  const auto front = reproject(cloud, with_cell(kLatticeCell));
  const HeightField& p = plane.value.depth;
  const GridGeometry& g = p.geometry();
  ASSERT_EQ(g.cols, 61);
  ASSERT_EQ(g.rows, 61);
  double interior_err = 0.0, rim_err = 0.0, front_err = 0.0;
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      ASSERT_TRUE(p.valid(r, c)) << r << "," << c;  // 3 points per cell: every node has one within 1.5 cells
      const double truth = lattice_plane(g.x_of_col(c), g.y_of_row(r));
      const double e = std::abs(p.at(r, c) - truth);
      const bool interior = r >= 2 && c >= 2 && r <= g.rows - 3 && c <= g.cols - 3;
      (interior ? interior_err : rim_err) = std::max(interior ? interior_err : rim_err, e);
      if (front.value.depth.valid(r, c)) front_err = std::max(front_err, std::abs(front.value.depth.at(r, c) - truth));
    }
  }
  // Float heights of ~30 mm: a few ulps (ulp 1.9e-9 m). A front-most sample lies up to half a
  // cell diagonal from its node: up to (0.4 + 0.25)·0.5 mm off.
  EXPECT_LT(interior_err, 2e-8);
  EXPECT_GT(front_err, 1e-4);
  // At the border (a corner's points lie on one side) the slope may go unfitted in a direction:
  // the rule's value (the oracle), off the plane by less than the slope across the radius.
  EXPECT_LT(rim_err, (std::abs(kPlaneSx) + std::abs(kPlaneSy)) * 1.5 * kLatticeCell);
  const DepthGrid fm = front.value;
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      if (r >= 2 && c >= 2 && r <= g.rows - 3 && c <= g.cols - 3) continue;
      EXPECT_NEAR(p.at(r, c), plane_oracle(cloud, fm, r, c, 1.5, 0.0), 2e-8) << r << "," << c;
    }
  }
  RecordProperty("interior_err_m", std::to_string(interior_err));
}

TEST(Reproject, PlaneSplatsAverageScannerNoiseThatFrontMostSamplesBiasUpwards) {
  const double sigma = 1e-4;  // 0.1 mm of noise on z = 0
  const Cloud cloud = cloud_of(random_samples([](double, double) { return 0.0; }, 4.0, sigma, 11));
  const auto plane = reproject(cloud, planes(with_cell(kLatticeCell), 1.5));
  const auto front = reproject(cloud, with_cell(kLatticeCell));
  double plane_ss = 0.0, front_ss = 0.0, front_sum = 0.0;
  std::size_t n_plane = 0, n_front = 0;
  const GridGeometry& g = plane.value.depth.geometry();
  for (int r = 2; r <= g.rows - 3; ++r) {
    for (int c = 2; c <= g.cols - 3; ++c) {
      plane_ss += std::pow(plane.value.depth.at(r, c), 2);
      ++n_plane;
      if (!front.value.depth.valid(r, c)) continue;
      front_ss += std::pow(front.value.depth.at(r, c), 2);
      front_sum += front.value.depth.at(r, c);
      ++n_front;
    }
  }
  const double plane_rms = std::sqrt(plane_ss / static_cast<double>(n_plane));
  const double front_rms = std::sqrt(front_ss / static_cast<double>(n_front));
  // The maximum of ~4 normal samples has mean ≈ 1.03 σ; a plane through the ~28 points within
  // 1.5 cells has a standard error near σ / √(effective count), well under σ / 2.
  EXPECT_GT(front_sum / static_cast<double>(n_front), 0.7 * sigma);
  EXPECT_GT(front_rms, 0.8 * sigma);
  EXPECT_LT(plane_rms, 0.4 * sigma);
  RecordProperty("plane_rms_over_sigma", std::to_string(plane_rms / sigma));
  RecordProperty("front_rms_over_sigma", std::to_string(front_rms / sigma));
}

TEST(Reproject, PlaneSplatsTakeOnlyTheFrontSurfaceOfAMergedScanWithinTheSeeThroughDepth) {
  // Front: the tilted plane, 3 points per cell. Back: 5 mm below it, 3 points per cell, as a
  // merged scan of a thin object holds.
  auto pts = random_samples(lattice_plane, 3.0, 0.0, 3);
  const auto back = random_samples([](double x, double y) { return lattice_plane(x, y) - 0.005; }, 3.0, 0.0, 5);
  pts.insert(pts.end(), back.begin(), back.end());
  const Cloud cloud = cloud_of(pts);
  const auto banded = reproject(cloud, planes(with_cell(kLatticeCell), 1.5, 0.002));
  const auto blind = reproject(cloud, planes(with_cell(kLatticeCell), 1.5, 0.0));
  const GridGeometry& g = banded.value.depth.geometry();
  double banded_err = 0.0, blind_sum = 0.0;
  std::size_t n = 0;
  for (int r = 3; r <= g.rows - 4; ++r) {
    for (int c = 3; c <= g.cols - 4; ++c) {
      const double truth = lattice_plane(g.x_of_col(c), g.y_of_row(r));
      if (!banded.value.depth.valid(r, c)) continue;  // see-through test (on) may drop a node
      banded_err = std::max(banded_err, std::abs(banded.value.depth.at(r, c) - truth));
      blind_sum += truth - blind.value.depth.at(r, c);
      ++n;
    }
  }
  ASSERT_GT(n, 3000u);
  EXPECT_LT(banded_err, 2e-8);
  // Node by node, the documented rule evaluated by brute force.
  const DepthGrid fm = reproject(cloud, with_cell(kLatticeCell)).value;
  for (int r = 0; r < g.rows; r += 3) {
    for (int c = 0; c < g.cols; ++c) {
      if (!banded.value.depth.valid(r, c)) continue;
      EXPECT_NEAR(banded.value.depth.at(r, c), plane_oracle(cloud, fm, r, c, 1.5, 0.002), 2e-8) << r << "," << c;
    }
  }
  // Without the band the back surface enters every plane: on average 2/3 of the way down.
  EXPECT_GT(blind_sum / static_cast<double>(n), 0.002);
}

TEST(Reproject, PlaneSplatsOnASingleScanLineFollowItAndStayLevelAcrossIt) {
  // One line of points at y = 20.3 mm, z rising along x: the 2 × 2 system is singular across
  // the line; the ridge makes the cross slope 0, so nodes within the radius take the line's z.
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i <= 600; ++i) {
    const double x = 0.1 * i * kLatticeCell;
    pts.emplace_back(x, 20.3 * kLatticeCell, 0.01 + 0.4 * x);
  }
  pts.emplace_back(0.0, 0.0, 0.01);                        // sets the box; far from the line
  pts.emplace_back(0.0, 40.0 * kLatticeCell, 0.01);
  const Cloud cloud = cloud_of(pts);
  const auto r = reproject(cloud, planes(with_cell(kLatticeCell), 1.5));
  const HeightField& d = r.value.depth;
  const GridGeometry& g = d.geometry();
  std::size_t checked = 0;
  double err = 0.0;
  for (int row = 0; row < g.rows; ++row) {
    const double dy = std::abs(g.y_of_row(row) - 20.3 * kLatticeCell) / kLatticeCell;
    for (int c = 3; c <= g.cols - 4; ++c) {
      if (dy > 1.5) {
        if (row > 3 && row < g.rows - 4) {
          EXPECT_FALSE(d.valid(row, c)) << row << "," << c;  // beyond the radius of every point
        }
        continue;
      }
      ASSERT_TRUE(d.valid(row, c)) << row << "," << c;
      err = std::max(err, std::abs(d.at(row, c) - (0.01 + 0.4 * g.x_of_col(c))));
      ++checked;
    }
  }
  EXPECT_EQ(checked, 3u * static_cast<std::size_t>(g.cols - 6));  // rows 19, 20, 21
  EXPECT_LT(err, 2e-8);
}

TEST(Reproject, PlaneSplatsOnTwoThreadsMatchTheBruteForceRuleOnBothHalvesOfTheRows) {
  // 288 000 noisy points (over the 2^18 at which the rows are split between two threads):
  // every 7th node of every row, in both halves, against the rule evaluated in double.
  const Cloud cloud = cloud_of(random_samples(lattice_plane, 80.0, 1e-4, 17));
  ASSERT_GE(cloud.size(), std::size_t{1} << 18);
  const auto r = reproject(cloud, planes(with_cell(kLatticeCell), 1.2));
  const DepthGrid fm = reproject(cloud, with_cell(kLatticeCell)).value;
  const GridGeometry& g = r.value.depth.geometry();
  std::size_t checked = 0;
  for (int row = 0; row < g.rows; row += 4) {
    for (int c = row % 7; c < g.cols; c += 7) {
      ASSERT_TRUE(r.value.depth.valid(row, c));
      // Float moments of ~350 points within 1.5 mm of each other: about 1e-8 m of rounding.
      EXPECT_NEAR(r.value.depth.at(row, c), plane_oracle(cloud, fm, row, c, 1.2, 0.0), 2e-7) << row << "," << c;
      ++checked;
    }
  }
  EXPECT_GT(checked, 100u);
}

TEST(Reproject, PlaneSplatsFillExactlyTheEmptyNodesWithinTheRadiusOfAPoint) {
  const Cloud cloud = cloud_of(random_samples(lattice_plane, 0.15, 0.0, 13));
  const double radius = 1.2;
  const auto r = reproject(cloud, planes(with_cell(kLatticeCell), radius));
  const auto measured = reproject(cloud, with_cell(kLatticeCell));
  const GridGeometry& g = r.value.depth.geometry();
  std::size_t filled = 0;
  for (int row = 0; row < g.rows; ++row) {
    for (int c = 0; c < g.cols; ++c) {
      bool near = false;  // brute force over every point
      for (std::size_t i = 0; i < cloud.size() && !near; ++i) {
        const double dx = (cloud.xyz(0, static_cast<Eigen::Index>(i)) - g.x_of_col(c)) / kLatticeCell;
        const double dy = (cloud.xyz(1, static_cast<Eigen::Index>(i)) - g.y_of_row(row)) / kLatticeCell;
        near = dx * dx + dy * dy <= radius * radius;
      }
      const auto i = static_cast<std::size_t>(row * g.cols + c);
      EXPECT_EQ(r.value.depth.valid(row, c), near) << row << "," << c;
      if (measured.value.depth.valid(row, c)) {
        EXPECT_EQ(r.value.flags[i], kCellMeasured);
      } else if (near) {
        EXPECT_EQ(r.value.flags[i], kCellSplatted);
        ++filled;
      }
    }
  }
  EXPECT_GT(filled, 500u);
  EXPECT_EQ(figure(r.report, "cells_splat_filled_empty"), static_cast<double>(filled));
}

TEST(ReprojectErrors, OnePointAndEdgeOnCloudsAreDegenerate) {
  EXPECT_NE(message_of<DegenerateInputError>(cloud_of({{0.1, 0.2, 0.3}}), with_n(100))
                .find("zero projected area"),
            std::string::npos);
  // The same x-y position many times (a cloud seen exactly edge-on along z).
  EXPECT_NE(message_of<DegenerateInputError>(cloud_of({{0.1, 0.2, 0.3}, {0.1, 0.2, -0.3}}), with_n(100))
                .find("edge-on"),
            std::string::npos);
}

TEST(ReprojectErrors, PointsOnALineAreDegenerate) {
  std::vector<Eigen::Vector3d> line;
  for (int i = 0; i < 100; ++i) line.emplace_back(0.001 * i, 0.05, 0.01 * (i % 7));  // y constant
  const std::string m = message_of<DegenerateInputError>(cloud_of(line), with_n(200));
  EXPECT_NE(m.find("line along x"), std::string::npos) << m;
  EXPECT_NE(m.find("200 x 1"), std::string::npos) << m;
  // Nearly a line: the y extent is less than half a cell, so the grid still has one row.
  line.back().y() += 1e-7;
  EXPECT_THROW(reproject(cloud_of(line), with_n(200)), DegenerateInputError);
  // A line along y: an x-z plane seen from +z.
  std::vector<Eigen::Vector3d> wall;
  for (int i = 0; i < 100; ++i) wall.emplace_back(0.02, 0.001 * i, 0.001 * (i % 5));
  EXPECT_NE(message_of<DegenerateInputError>(cloud_of(wall), with_n(50)).find("line along y"),
            std::string::npos);
}

TEST(ReprojectErrors, AllPointsInOneCellAreDegenerate) {
  const Cloud c = cloud_of({{0.0, 0.0, 0.0}, {0.001, 0.002, 0.1}, {0.002, 0.0005, 0.2}});
  const std::string m = message_of<DegenerateInputError>(c, with_cell(0.01));
  EXPECT_NE(m.find("one cell"), std::string::npos) << m;
}

TEST(ReprojectErrors, MemoryCapNamesTheBytesNeeded) {
  const Cloud c = cloud_of({{0, 0, 0}, {1, 0.5, 0}});
  ReprojectOptions o = with_n(1001);  // 1001 x 501 = 501501 cells
  o.grid.max_cells = 500000;
  std::string m = message_of<ResourceError>(c, o);
  EXPECT_NE(m.find("501501 cells"), std::string::npos) << m;
  EXPECT_NE(m.find("max_cells = 500000"), std::string::npos) << m;
  EXPECT_NE(m.find(std::to_string(501501 * 5) + " bytes"), std::string::npos) << m;  // float + flag
  o.splat_radius_cells = 1.5;
  o.see_through_depth_m = 0.001;
  m = message_of<ResourceError>(c, o);
  EXPECT_NE(m.find(std::to_string(501501 * (5 + 8 + 8)) + " bytes"), std::string::npos) << m;
  // A request far beyond any machine does not overflow.
  o.grid.n_long_side = 2000000000;
  EXPECT_THROW(reproject(c, o), ResourceError);
}

TEST(ReprojectErrors, NoFinitePointIsAnInputError) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const Cloud c = cloud_of({{nan, nan, nan}, {0.0, nan, 1.0}, {0.0, 0.0, std::numeric_limits<double>::infinity()}});
  try {
    reproject(c, with_n(10));
    FAIL() << "expected InputError";
  } catch (const DegenerateInputError&) {
    FAIL() << "expected a plain InputError, not DegenerateInputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("none of the 3 input points is finite"), std::string::npos);
  }
  EXPECT_THROW(reproject(Cloud{}, with_n(10)), InputError);
}

}  // namespace
}  // namespace hc::pipeline
