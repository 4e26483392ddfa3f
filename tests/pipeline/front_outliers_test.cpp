// remove_front_statistical_outliers (filters.outliers.scope = front) against the full test.

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/filters.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/reproject.hpp"

#include <gtest/gtest.h>

#include "test_paths.hpp"
#include "stage_figure.hpp"

#include <cmath>
#include <random>
#include <string>

namespace {

using hc::test::figure;

using namespace hc::pipeline;

Cloud append(const Cloud& c, const Eigen::Matrix3Xd& extra) {
  Cloud out;
  out.xyz.resize(3, c.xyz.cols() + extra.cols());
  out.xyz << c.xyz, extra;
  return out;
}

ReprojectOptions run_options(int n) {
  ReprojectOptions o;
  o.grid.n_long_side = n;
  o.splat_radius_cells = 1.2;
  o.see_through_depth_m = 0.002;
  o.see_through_window_cells = 3;
  return o;
}

// Every cell equal (NaN = NaN), same flags, same geometry.
void expect_same_grid(const DepthGrid& a, const DepthGrid& b) {
  ASSERT_EQ(a.depth.geometry(), b.depth.geometry());
  std::size_t differ = 0;
  for (std::size_t i = 0; i < a.depth.values().size(); ++i) {
    const float x = a.depth.values()[i], y = b.depth.values()[i];
    if (!((std::isnan(x) && std::isnan(y)) || x == y) || a.flags[i] != b.flags[i]) ++differ;
  }
  EXPECT_EQ(differ, 0u) << "of " << a.depth.values().size() << " cells";
}

const Cloud& bunny() {
  static const Cloud c = load_cloud(hc::test::scan_path("bunny/bun000.ply")).value;
  return c;
}

TEST(FrontOutliers, BunnyWithOutliersInFrontAndFarAwayGivesTheFullTestsGrid) {
  const Cloud& base = bunny();
  ASSERT_LT(base.size() + 400, kFrontThresholdSample);  // every point in the threshold sample: exact
  std::mt19937 rng(7);
  std::uniform_int_distribution<Eigen::Index> pick(0, base.xyz.cols() - 1);
  std::uniform_real_distribution<double> lift(0.003, 0.010), jitter(-2e-4, 2e-4);
  // 300 points 3 to 10 mm in front of the surface, then 6 far points that would widen the x-y box.
  Eigen::Matrix3Xd extra(3, 306);
  for (Eigen::Index i = 0; i < 300; ++i) {
    const Eigen::Vector3d p = base.xyz.col(pick(rng));
    extra.col(i) = Eigen::Vector3d(p.x() + jitter(rng), p.y() + jitter(rng), p.z() + lift(rng));
  }
  const Eigen::Vector3d lo = base.xyz.rowwise().minCoeff(), hi = base.xyz.rowwise().maxCoeff();
  extra.col(300) = Eigen::Vector3d(hi.x() + 0.05, 0.5 * (lo.y() + hi.y()), hi.z());
  extra.col(301) = Eigen::Vector3d(hi.x() + 0.0501, 0.5 * (lo.y() + hi.y()), hi.z());
  extra.col(302) = Eigen::Vector3d(lo.x() - 0.03, lo.y() - 0.03, lo.z());
  extra.col(303) = Eigen::Vector3d(lo.x(), hi.y() + 0.08, lo.z());
  extra.col(304) = Eigen::Vector3d(lo.x(), hi.y() + 0.0802, lo.z());
  extra.col(305) = Eigen::Vector3d(lo.x(), hi.y() + 0.0804, lo.z());
  const Cloud cloud = append(base, extra);

  const auto all = remove_statistical_outliers(cloud, 16, 2.0);
  const ReprojectOptions opts = run_options(300);
  const auto front = remove_front_statistical_outliers(cloud, 16, 2.0, opts);
  EXPECT_DOUBLE_EQ(figure(front.report, "threshold_mm"), figure(all.report, "threshold_mm"));
  EXPECT_DOUBLE_EQ(figure(front.report, "threshold_sample"), static_cast<double>(cloud.size()));
  // The injected points are outliers for the full test, so the comparison means something.
  const double all_removed = figure(all.report, "removed");
  EXPECT_GE(all_removed, 280.0);
  EXPECT_LE(figure(front.report, "removed"), all_removed);

  const DepthGrid grid_all = reproject(all.value, opts).value;
  const DepthGrid grid_front = reproject(front.value, opts).value;
  expect_same_grid(grid_all, grid_front);
  // Without the far points the geometry is the bunny's own.
  const hc::GridGeometry own = reproject(base, opts).value.depth.geometry();
  EXPECT_EQ(grid_front.depth.geometry(), own);

  // With a threshold sample of 4000 points most points are never tested, and the far points
  // are found by the bounding-box step.
  const ReprojectOptions coarse = run_options(100);
  const auto sampled = remove_front_statistical_outliers(cloud, 16, 2.0, coarse, 4000);
  EXPECT_DOUBLE_EQ(figure(sampled.report, "threshold_sample"), 4000.0);
  EXPECT_GE(figure(sampled.report, "removed_at_bbox"), 4.0);
  EXPECT_LT(figure(sampled.report, "tested"), 0.5 * static_cast<double>(cloud.size()));
  const DepthGrid grid_sampled = reproject(sampled.value, coarse).value;
  const DepthGrid grid_all_coarse = reproject(all.value, coarse).value;
  EXPECT_EQ(grid_sampled.depth.geometry(), grid_all_coarse.depth.geometry());
}

TEST(FrontOutliers, FrontRemovesASubsetOfTheFullTestsOutliers) {
  const Cloud& cloud = bunny();
  const auto all = remove_statistical_outliers(cloud, 8, 1.0);
  const auto front = remove_front_statistical_outliers(cloud, 8, 1.0, run_options(150));
  // Every point kept by the full test is kept by the front test (same threshold, same test).
  std::size_t j = 0;
  for (Eigen::Index i = 0; i < all.value.xyz.cols(); ++i) {
    while (j < front.value.size() && front.value.xyz.col(static_cast<Eigen::Index>(j)) != all.value.xyz.col(i)) ++j;
    ASSERT_LT(j, front.value.size()) << "point " << i << " kept by scope all is missing in scope front";
    ++j;
  }
  expect_same_grid(reproject(all.value, run_options(150)).value, reproject(front.value, run_options(150)).value);
}

TEST(FrontOutliers, StackedOutliersAboveAFrontPointAreRemovedAndThePointTakesTheirPlace) {
  const Cloud& base = bunny();
  Eigen::Index top = 0;
  base.xyz.row(2).maxCoeff(&top);  // the front-most point of its cell
  const Eigen::Vector3d p = base.xyz.col(top);
  Eigen::Matrix3Xd extra(3, 2);
  extra.col(0) = p + Eigen::Vector3d(0, 0, 0.010);
  extra.col(1) = p + Eigen::Vector3d(0, 0, 0.020);
  const Cloud cloud = append(base, extra);
  ReprojectOptions opts;
  opts.grid.n_long_side = 200;
  const auto front = remove_front_statistical_outliers(cloud, 16, 2.0, opts);
  EXPECT_EQ(front.value.size(), cloud.size() - static_cast<std::size_t>(figure(front.report, "removed")));
  for (Eigen::Index i = 0; i < front.value.xyz.cols(); ++i) {
    ASSERT_LT(front.value.xyz(2, i), p.z() + 0.005) << "an injected outlier survived";
  }
  const DepthGrid g = reproject(front.value, opts).value;
  const double col = g.depth.geometry().col_of_x(p.x()), row = g.depth.geometry().row_of_y(p.y());
  const float z = g.depth.at(static_cast<int>(std::lround(row)), static_cast<int>(std::lround(col)));
  EXPECT_EQ(z, static_cast<float>(p.z()));
  // The full test keeps the point too: it is a genuine surface point.
  EXPECT_EQ(z, reproject(remove_statistical_outliers(cloud, 16, 2.0).value, opts)
                   .value.depth.at(static_cast<int>(std::lround(row)), static_cast<int>(std::lround(col))));
}

TEST(FrontOutliers, ThresholdFromTheSampleIsWithinAFewPercentOnTheMergedBuddha) {
  const Cloud cloud =
      load_cloud(hc::test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz")).value;
  ASSERT_GT(cloud.size(), 1000000u);
  const auto all = remove_statistical_outliers(cloud, 16, 2.0);
  const auto front = remove_front_statistical_outliers(cloud, 16, 2.0, run_options(800));
  const double t_all = figure(all.report, "threshold_mm"), t_front = figure(front.report, "threshold_mm");
  EXPECT_NEAR(t_front, t_all, 0.03 * t_all);
  EXPECT_NEAR(figure(front.report, "mean_knn_distance_mm"), figure(all.report, "mean_knn_distance_mm"),
              0.02 * figure(all.report, "mean_knn_distance_mm"));
  EXPECT_DOUBLE_EQ(figure(front.report, "threshold_sample"), static_cast<double>(kFrontThresholdSample));
  EXPECT_LT(figure(front.report, "tested"), 0.5 * static_cast<double>(cloud.size()));
}

TEST(FrontOutliers, RejectsBadParametersAndConfigReadsTheScope) {
  EXPECT_THROW(remove_front_statistical_outliers(bunny(), 0, 2.0, run_options(100)), hc::ConfigError);
  EXPECT_THROW(remove_front_statistical_outliers(bunny(), 16, -1.0, run_options(100)), hc::ConfigError);
  EXPECT_THROW(remove_front_statistical_outliers(bunny(), 16, 2.0, run_options(100), 1), hc::ConfigError);
  const std::string yaml = "input:\n  files: [scan.ply]\n";
  EXPECT_EQ(parse_run_config(yaml, "configs/test.yaml").filters.outliers.scope, OutlierScope::kAll);
  EXPECT_EQ(parse_run_config(yaml, "configs/test.yaml", {"filters.outliers.method=statistical", "filters.outliers.scope=front"}).filters.outliers.scope,
            OutlierScope::kFront);
  EXPECT_THROW(parse_run_config(yaml, "configs/test.yaml", {"filters.outliers.scope=back"}), hc::ConfigError);
}

}  // namespace
