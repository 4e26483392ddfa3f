// filters.pcl (issue 18): each stage against its PCL class called directly on the same points
// (the oracle), and the config keys' errors.
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/pcl_filters.hpp"

#include "hc/common/error.hpp"

#include <gtest/gtest.h>

#include <pcl/filters/approximate_voxel_grid.h>
#include <pcl/filters/crop_box.h>
#include <pcl/filters/passthrough.h>
#include <pcl/filters/radius_outlier_removal.h>
#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/filters/uniform_sampling.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>
#include <pcl/segmentation/extract_clusters.h>
#include <pcl/surface/mls.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

namespace {

using hc::pipeline::apply_pcl_filter;
using hc::pipeline::Cloud;
using hc::pipeline::PclFilterKind;
using hc::pipeline::PclFilterSpec;
using Xyz = pcl::PointCloud<pcl::PointXYZ>;
using Triple = std::array<float, 3>;

/// A wavy 0.09 m patch (8100 random points, about 1 mm apart), 200 scattered outliers, a small far
/// cluster (3rd) and a second patch (2nd cluster); intensity = the point's index, so the test
/// sees whether attributes stay with their points; one NaN point.
Cloud test_cloud() {
  std::mt19937 rng(1818);
  std::normal_distribution<double> jitter(0.0, 0.0002);
  std::uniform_real_distribution<double> box(-0.08, 0.08);
  std::vector<Eigen::Vector3d> pts;
  std::uniform_real_distribution<double> patch(-0.045, 0.045);
  for (int i = 0; i < 8100; ++i) {  // random (not gridded), so k-NN distances spread continuously
    const double x = patch(rng), y = patch(rng);
    pts.emplace_back(x, y, 0.01 * std::sin(60.0 * x) * std::cos(40.0 * y) + jitter(rng));
  }
  for (int i = 0; i < 30; ++i) {
    for (int j = 0; j < 30; ++j) pts.emplace_back(0.2 + 0.001 * i + jitter(rng), 0.001 * j + jitter(rng), 0.02 + jitter(rng));
  }
  for (int i = 0; i < 40; ++i) pts.emplace_back(-0.3 + jitter(rng), 0.3 + jitter(rng), jitter(rng));
  for (int i = 0; i < 200; ++i) pts.emplace_back(box(rng), box(rng), box(rng) + 0.05);
  pts.emplace_back(std::nan(""), 0.0, 0.0);
  Cloud c;
  c.xyz.resize(3, static_cast<Eigen::Index>(pts.size()));
  for (std::size_t i = 0; i < pts.size(); ++i) {
    c.xyz.col(static_cast<Eigen::Index>(i)) = pts[i];
    c.intensity.push_back(static_cast<float>(i));
  }
  return c;
}

/// The oracle's input: the finite points as float, built here (not through hc::pcl).
Xyz::Ptr oracle_input(const Cloud& c) {
  Xyz::Ptr p(new Xyz);
  for (Eigen::Index i = 0; i < c.xyz.cols(); ++i) {
    if (!c.xyz.col(i).allFinite()) continue;
    p->push_back(pcl::PointXYZ(static_cast<float>(c.xyz(0, i)), static_cast<float>(c.xyz(1, i)),
                               static_cast<float>(c.xyz(2, i))));
  }
  return p;
}

std::vector<Triple> triples(const Xyz& p) {
  std::vector<Triple> t;
  for (const auto& q : p) t.push_back({q.x, q.y, q.z});
  return t;
}

std::vector<Triple> triples(const Cloud& c) {
  std::vector<Triple> t;
  for (Eigen::Index i = 0; i < c.xyz.cols(); ++i) {
    t.push_back({static_cast<float>(c.xyz(0, i)), static_cast<float>(c.xyz(1, i)), static_cast<float>(c.xyz(2, i))});
  }
  return t;
}

std::vector<Triple> sorted(std::vector<Triple> t) {
  std::sort(t.begin(), t.end());
  return t;
}

/// Subset filters keep the original double points with their attributes.
void expect_points_keep_their_attributes(const Cloud& in, const Cloud& out) {
  ASSERT_EQ(out.intensity.size(), out.size());
  for (Eigen::Index i = 0; i < out.xyz.cols(); ++i) {
    const auto src = static_cast<Eigen::Index>(out.intensity[static_cast<std::size_t>(i)]);
    ASSERT_EQ(out.xyz.col(i), in.xyz.col(src)) << "point " << i;
  }
  for (std::size_t i = 1; i < out.intensity.size(); ++i) ASSERT_LT(out.intensity[i - 1], out.intensity[i]);  // input order
}

PclFilterSpec spec(PclFilterKind kind, const char* name) {
  PclFilterSpec s;
  s.kind = kind;
  s.name = name;
  return s;
}

TEST(PclFilters, StatisticalOutlierRemovalEqualsPcl) {
  const Cloud in = test_cloud();
  PclFilterSpec s = spec(PclFilterKind::kStatisticalOutlierRemoval, "StatisticalOutlierRemoval");
  s.mean_k = 12;
  s.stddev_mul = 0.1;  // the threshold inside the patch's distribution: a 1 % change moves points
  const auto r = apply_pcl_filter(in, s);
  pcl::StatisticalOutlierRemoval<pcl::PointXYZ> f;
  f.setInputCloud(oracle_input(in));
  f.setMeanK(12);
  f.setStddevMulThresh(0.1);
  Xyz expected;
  f.filter(expected);
  EXPECT_LT(expected.size(), in.size() - 1);  // it removed something
  Xyz nearby;  // the test would see a parameter passed slightly wrong
  f.setStddevMulThresh(0.101);
  f.filter(nearby);
  EXPECT_NE(nearby.size(), expected.size());
  EXPECT_EQ(triples(r.value), triples(expected));
  expect_points_keep_their_attributes(in, r.value);
  EXPECT_EQ(r.report.count_in, in.size());
  EXPECT_EQ(r.report.count_out, expected.size());
  EXPECT_EQ(r.report.stage, "pcl:StatisticalOutlierRemoval");
}

TEST(PclFilters, RadiusOutlierRemovalEqualsPcl) {
  const Cloud in = test_cloud();
  PclFilterSpec s = spec(PclFilterKind::kRadiusOutlierRemoval, "RadiusOutlierRemoval");
  s.radius_m = 0.0012;
  s.min_neighbors = 4;
  const auto r = apply_pcl_filter(in, s);
  pcl::RadiusOutlierRemoval<pcl::PointXYZ> f;
  f.setInputCloud(oracle_input(in));
  f.setRadiusSearch(0.0012);
  f.setMinNeighborsInRadius(4);
  Xyz expected;
  f.filter(expected);
  EXPECT_LT(expected.size(), in.size() - 150);
  Xyz nearby;  // one neighbour more or less changes the result on this cloud
  f.setMinNeighborsInRadius(5);
  f.filter(nearby);
  EXPECT_NE(nearby.size(), expected.size());
  EXPECT_EQ(triples(r.value), triples(expected));
  expect_points_keep_their_attributes(in, r.value);
}

TEST(PclFilters, PassThroughAndCropBoxEqualPcl) {
  const Cloud in = test_cloud();
  for (const bool negative : {false, true}) {
    PclFilterSpec s = spec(PclFilterKind::kPassThrough, "PassThrough");
    s.field = "y";
    s.min_m = -0.01;
    s.max_m = 0.02;
    s.negative = negative;
    const auto r = apply_pcl_filter(in, s);
    pcl::PassThrough<pcl::PointXYZ> f;
    f.setInputCloud(oracle_input(in));
    f.setFilterFieldName("y");
    f.setFilterLimits(-0.01f, 0.02f);
    f.setNegative(negative);
    Xyz expected;
    f.filter(expected);
    EXPECT_GT(expected.size(), 100u);
    EXPECT_EQ(triples(r.value), triples(expected)) << "negative " << negative;
    expect_points_keep_their_attributes(in, r.value);
  }
  for (const bool negative : {false, true}) {
    PclFilterSpec s = spec(PclFilterKind::kCropBox, "CropBox");
    s.box_min_m = Eigen::Vector3d(-0.02, -0.03, -0.005);
    s.box_max_m = Eigen::Vector3d(0.25, 0.01, 0.03);
    s.negative = negative;
    const auto r = apply_pcl_filter(in, s);
    pcl::CropBox<pcl::PointXYZ> f;
    f.setInputCloud(oracle_input(in));
    f.setMin(Eigen::Vector4f(-0.02f, -0.03f, -0.005f, 1.0f));
    f.setMax(Eigen::Vector4f(0.25f, 0.01f, 0.03f, 1.0f));
    f.setNegative(negative);
    Xyz expected;
    f.filter(expected);
    EXPECT_GT(expected.size(), 100u);
    EXPECT_EQ(triples(r.value), triples(expected)) << "negative " << negative;
    expect_points_keep_their_attributes(in, r.value);
  }
}

TEST(PclFilters, UniformSamplingKeepsExactlyPclsPointsInInputOrder) {
  const Cloud in = test_cloud();
  PclFilterSpec s = spec(PclFilterKind::kUniformSampling, "UniformSampling");
  s.radius_m = 0.0025;
  const auto r = apply_pcl_filter(in, s);
  pcl::UniformSampling<pcl::PointXYZ> f;
  f.setInputCloud(oracle_input(in));
  f.setRadiusSearch(0.0025);
  Xyz expected;
  f.filter(expected);
  EXPECT_LT(expected.size(), in.size() * 2 / 3);
  // PCL emits the points in its leaf map's order; the stage keeps input order: same set.
  EXPECT_EQ(sorted(triples(r.value)), sorted(triples(expected)));
  expect_points_keep_their_attributes(in, r.value);
}

TEST(PclFilters, EuclideanClusterExtractionKeepsThePclsLargestClusters) {
  const Cloud in = test_cloud();
  // (keep, max_cluster_size): with a maximum of 2000 the 8100-point patch is no cluster at all,
  // so the largest kept one is the 900-point second patch.
  for (const auto& [keep, max_size] : {std::pair{1, std::numeric_limits<int>::max()}, std::pair{2, std::numeric_limits<int>::max()},
                                       std::pair{1, 2000}}) {
    PclFilterSpec s = spec(PclFilterKind::kEuclideanClusterExtraction, "EuclideanClusterExtraction");
    s.tolerance_m = 0.004;
    s.min_cluster_size = 10;
    s.max_cluster_size = max_size;
    s.keep_clusters = keep;
    const auto r = apply_pcl_filter(in, s);
    const Xyz::Ptr p = oracle_input(in);
    pcl::search::KdTree<pcl::PointXYZ>::Ptr tree(new pcl::search::KdTree<pcl::PointXYZ>);
    tree->setInputCloud(p);
    pcl::EuclideanClusterExtraction<pcl::PointXYZ> f;
    f.setInputCloud(p);
    f.setSearchMethod(tree);
    f.setClusterTolerance(0.004);
    f.setMinClusterSize(10);
    f.setMaxClusterSize(max_size);
    std::vector<pcl::PointIndices> clusters;
    f.extract(clusters);
    ASSERT_GE(clusters.size(), max_size == 2000 ? 2u : 3u);  // the patch (unless too large), the second patch, the far cluster
    if (max_size == 2000) {
      EXPECT_EQ(clusters[0].indices.size(), 900u);
    }
    Xyz expected;
    for (int c = 0; c < keep; ++c) {
      for (const auto i : clusters[static_cast<std::size_t>(c)].indices) expected.push_back((*p)[static_cast<std::size_t>(i)]);
    }
    EXPECT_EQ(sorted(triples(r.value)), sorted(triples(expected))) << "keep " << keep << ", max " << max_size;
    // The stage's class is instantiated inside hapticloud (libpcl_segmentation is not linked),
    // so the call above may run the same code: the kept count also comes from single-linkage
    // components found here by brute force (union-find over every pair within the tolerance).
    const std::size_t np = p->size();
    std::vector<std::size_t> parent(np);
    for (std::size_t i = 0; i < np; ++i) parent[i] = i;
    const auto root = [&](std::size_t i) {
      while (parent[i] != i) i = parent[i] = parent[parent[i]];
      return i;
    };
    for (std::size_t i = 0; i < np; ++i) {
      for (std::size_t j = i + 1; j < np; ++j) {
        const float dx = (*p)[i].x - (*p)[j].x, dy = (*p)[i].y - (*p)[j].y, dz = (*p)[i].z - (*p)[j].z;
        if (dx * dx + dy * dy + dz * dz <= 0.004F * 0.004F) parent[root(i)] = root(j);
      }
    }
    std::vector<std::size_t> size_of(np, 0);
    for (std::size_t i = 0; i < np; ++i) ++size_of[root(i)];
    std::vector<std::size_t> sizes;
    for (std::size_t i = 0; i < np; ++i)
      if (parent[i] == i && size_of[i] >= 10 && size_of[i] <= static_cast<std::size_t>(max_size)) sizes.push_back(size_of[i]);
    std::sort(sizes.rbegin(), sizes.rend());
    std::size_t brute = 0;
    for (int c = 0; c < keep && c < static_cast<int>(sizes.size()); ++c) brute += sizes[static_cast<std::size_t>(c)];
    EXPECT_EQ(r.value.size(), brute) << "keep " << keep << ", max " << max_size;
    expect_points_keep_their_attributes(in, r.value);
  }
}

TEST(PclFilters, VoxelGridsAndMlsGivePclsPointsInPclsOrder) {
  const Cloud in = test_cloud();
  {
    PclFilterSpec s = spec(PclFilterKind::kVoxelGrid, "VoxelGrid");
    s.leaf_m = 0.003;
    const auto r = apply_pcl_filter(in, s);
    pcl::VoxelGrid<pcl::PointXYZ> f;
    f.setInputCloud(oracle_input(in));
    f.setLeafSize(0.003f, 0.003f, 0.003f);
    Xyz expected;
    f.filter(expected);
    EXPECT_LT(expected.size(), in.size() * 2 / 3);
    EXPECT_EQ(triples(r.value), triples(expected));
    EXPECT_FALSE(r.value.has_intensity());  // new points: attributes dropped, with a note
    EXPECT_FALSE(r.report.notes.empty());
  }
  {
    PclFilterSpec s = spec(PclFilterKind::kApproximateVoxelGrid, "ApproximateVoxelGrid");
    s.leaf_m = 0.003;
    const auto r = apply_pcl_filter(in, s);
    pcl::ApproximateVoxelGrid<pcl::PointXYZ> f;
    f.setInputCloud(oracle_input(in));
    f.setLeafSize(0.003f, 0.003f, 0.003f);
    Xyz expected;
    f.filter(expected);
    EXPECT_LT(expected.size(), in.size() * 2 / 3);
    EXPECT_EQ(triples(r.value), triples(expected));
  }
  {
    PclFilterSpec s = spec(PclFilterKind::kMovingLeastSquares, "MovingLeastSquares");
    s.search_radius_m = 0.004;
    s.polynomial_order = 1;  // not PCL's default (2): a stage that ignored the order would differ
    const auto r = apply_pcl_filter(in, s);
    pcl::MovingLeastSquares<pcl::PointXYZ, pcl::PointXYZ> f;
    pcl::search::KdTree<pcl::PointXYZ>::Ptr tree(new pcl::search::KdTree<pcl::PointXYZ>);
    f.setInputCloud(oracle_input(in));
    f.setSearchMethod(tree);
    f.setSearchRadius(0.004);
    f.setPolynomialOrder(1);
    Xyz expected;
    f.process(expected);
    EXPECT_GT(expected.size(), in.size() / 2);
    EXPECT_EQ(triples(r.value), triples(expected));
    // ... and PCL's default order gives other points, so the order was passed on.
    f.setPolynomialOrder(2);
    Xyz order2;
    f.process(order2);
    EXPECT_NE(triples(order2), triples(expected));
    // It smoothed: some point moved.
    const auto before = triples(*oracle_input(in));
    EXPECT_NE(sorted(before), sorted(triples(expected)));
  }
}

TEST(PclFilters, BadParametersInCodeAreConfigErrorsNamingTheParameter) {
  PclFilterSpec s = spec(PclFilterKind::kVoxelGrid, "VoxelGrid");
  s.leaf_m = 0.0;
  try {
    (void)apply_pcl_filter(test_cloud(), s);
    FAIL() << "no error";
  } catch (const hc::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("VoxelGrid.leaf_m = 0"), std::string::npos) << e.what();
  }
}

TEST(PclFilters, LeavesBeyondPclsVoxelIndexAreRefusedNotIgnored) {
  // Two points 2 m apart on each axis: at a 1 µm leaf the box holds (2·10^6 + 1)^3 voxels, far
  // over PCL's 32-bit voxel index (VoxelGrid would return its input unchanged with a warning,
  // UniformSampling would overflow). At 1 cm it holds 201^3 ≈ 8·10^6: accepted.
  Cloud two;
  two.xyz.resize(3, 2);
  two.xyz.col(0) = Eigen::Vector3d(0.0, 0.0, 0.0);
  two.xyz.col(1) = Eigen::Vector3d(2.0, 2.0, 2.0);
  for (const auto& [kind, name, param] :
       {std::tuple{PclFilterKind::kVoxelGrid, "VoxelGrid", "leaf_m"},
        std::tuple{PclFilterKind::kUniformSampling, "UniformSampling", "radius_m"}}) {
    PclFilterSpec s = spec(kind, name);
    s.leaf_m = s.radius_m = 1e-6;
    try {
      (void)apply_pcl_filter(two, s);
      ADD_FAILURE() << name << ": no error";
    } catch (const hc::ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(std::string(name) + "." + param), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("32-bit voxel index"), std::string::npos) << e.what();
    }
    s.leaf_m = s.radius_m = 0.01;
    EXPECT_EQ(apply_pcl_filter(two, s).value.size(), 2u) << name;
  }
}

// --- config -------------------------------------------------------------------------------

const std::string kMinimal = "input:\n  files: [scan.ply]\n";

std::string config_error(const std::string& yaml, const std::vector<std::string>& sets = {}) {
  try {
    (void)hc::pipeline::parse_run_config(yaml, "configs/test.yaml", sets);
  } catch (const hc::ConfigError& e) {
    return e.what();
  }
  return "NO CONFIG ERROR";
}

TEST(PclFiltersConfig, TheListIsReadInOrderWithParametersAndDefaults) {
  const auto c = hc::pipeline::parse_run_config(kMinimal +
                                                    "filters:\n"
                                                    "  pcl:\n"
                                                    "    - name: StatisticalOutlierRemoval\n"
                                                    "      mean_k: 20\n"
                                                    "    - {name: VoxelGrid, leaf_m: 0.0005}\n"
                                                    "    - {name: PassThrough, field: x, min_m: -0.1, max_m: 0.1, negative: true}\n"
                                                    "    - {name: CropBox, min_m: [-1, -1, -1], max_m: [1, 1, 0.5]}\n"
                                                    "    - {name: EuclideanClusterExtraction, tolerance_m: 0.002, keep_clusters: 2}\n"
                                                    "    - {name: MovingLeastSquares, search_radius_m: 0.003}\n",
                                                "configs/test.yaml");
  const auto& f = c.filters.pcl;
  ASSERT_EQ(f.size(), 6u);
  EXPECT_EQ(f[0].kind, PclFilterKind::kStatisticalOutlierRemoval);
  EXPECT_EQ(f[0].mean_k, 20);
  EXPECT_EQ(f[0].stddev_mul, 1.0);  // default
  EXPECT_EQ(f[1].kind, PclFilterKind::kVoxelGrid);
  EXPECT_EQ(f[1].leaf_m, 0.0005);
  EXPECT_EQ(f[2].field, "x");
  EXPECT_TRUE(f[2].negative);
  EXPECT_EQ(f[3].box_max_m, Eigen::Vector3d(1, 1, 0.5));
  EXPECT_EQ(f[4].keep_clusters, 2);
  EXPECT_EQ(f[4].min_cluster_size, 1);
  EXPECT_EQ(f[5].polynomial_order, 2);
  EXPECT_NE(c.resolved_yaml.find("VoxelGrid"), std::string::npos) << c.resolved_yaml;
}

TEST(PclFiltersConfig, ErrorsNameTheKeyTheLineAndTheAllowedValues) {
  // Unknown filter name: the line of the name, the allowed classes.
  std::string msg = config_error(kMinimal + "filters:\n  pcl:\n    - name: VoxelGird\n      leaf_m: 0.001\n");
  EXPECT_NE(msg.find("configs/test.yaml:5"), std::string::npos) << msg;
  EXPECT_NE(msg.find("filters.pcl[0].name = 'VoxelGird'"), std::string::npos) << msg;
  EXPECT_NE(msg.find("ApproximateVoxelGrid"), std::string::npos) << msg;
  EXPECT_NE(msg.find("EuclideanClusterExtraction"), std::string::npos) << msg;

  // Unknown parameter: its line, the allowed parameters of that filter.
  msg = config_error(kMinimal + "filters:\n  pcl:\n    - name: VoxelGrid\n      leaf_m: 0.001\n    - name: UniformSampling\n      leaf_m: 0.001\n");
  EXPECT_NE(msg.find("configs/test.yaml:8"), std::string::npos) << msg;
  EXPECT_NE(msg.find("filters.pcl[1].leaf_m"), std::string::npos) << msg;
  EXPECT_NE(msg.find("allowed here: name, radius_m"), std::string::npos) << msg;

  // Out of range, wrong type, missing.
  msg = config_error(kMinimal + "filters:\n  pcl:\n    - {name: StatisticalOutlierRemoval, mean_k: 0}\n");
  EXPECT_NE(msg.find("configs/test.yaml:5"), std::string::npos) << msg;
  EXPECT_NE(msg.find("filters.pcl[0].mean_k (StatisticalOutlierRemoval) = '0': expected an integer in [1, 1000]"),
            std::string::npos)
      << msg;
  msg = config_error(kMinimal + "filters:\n  pcl:\n    - {name: VoxelGrid, leaf_m: big}\n");
  EXPECT_NE(msg.find("leaf_m (VoxelGrid) = 'big': expected a number in (0, 10]"), std::string::npos) << msg;
  msg = config_error(kMinimal + "filters:\n  pcl:\n    - {name: RadiusOutlierRemoval}\n");
  EXPECT_NE(msg.find("lacks 'radius_m'"), std::string::npos) << msg;
  msg = config_error(kMinimal + "filters:\n  pcl:\n    - {name: PassThrough, field: w, min_m: 0, max_m: 1}\n");
  EXPECT_NE(msg.find("field (PassThrough) = 'w': expected one of: x, y, z"), std::string::npos) << msg;
  msg = config_error(kMinimal + "filters:\n  pcl:\n    - {name: PassThrough, field: z, min_m: 1, max_m: 0}\n");
  EXPECT_NE(msg.find("expected a number >= min_m"), std::string::npos) << msg;
  msg = config_error(kMinimal + "filters:\n  pcl:\n    - {leaf_m: 1}\n");
  EXPECT_NE(msg.find("filters.pcl[0] lacks 'name'"), std::string::npos) << msg;
  msg = config_error(kMinimal + "filters:\n  pcl:\n    - {name: VoxelGrid, leaf_m: 0.001}\n    - UniformSampling\n");
  EXPECT_NE(msg.find("filters.pcl has an element [1] = 'UniformSampling' that is not a key: value map"), std::string::npos)
      << msg;
  msg = config_error(kMinimal + "filters:\n  pcl: VoxelGrid\n");
  EXPECT_NE(msg.find("filters.pcl = 'VoxelGrid': expected a list"), std::string::npos) << msg;
  // From --set: named as the override.
  msg = config_error(kMinimal, {"filters.pcl=[{name: Nope}]"});
  EXPECT_NE(msg.find("--set filters.pcl"), std::string::npos) << msg;
}

}  // namespace
