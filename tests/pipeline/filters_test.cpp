// Stage 4 tests: non-finite removal, crop box, voxel grid, and statistical outlier removal
// against PCL's StatisticalOutlierRemoval and a brute-force oracle.

#include "hc/common/error.hpp"
#include "hc/pipeline/filters.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/transform.hpp"
#include "test_paths.hpp"
#include "stage_figure.hpp"
#include "cloud_fixtures.hpp"

#include <gtest/gtest.h>
#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <set>
#include <vector>

namespace hp = hc::pipeline;

namespace {

using hc::test::cloud_of;

using hc::test::figure;

// Indices (into `c`) of the points remove_statistical_outliers keeps. Tags each point with a
// unique scan_id so the kept points can be traced back.
std::set<std::size_t> kept_by_hc(hp::Cloud c, int k, double sigma, hp::StageReport* report = nullptr) {
  c.scan_id.resize(c.size());
  for (std::size_t i = 0; i < c.size(); ++i) c.scan_id[i] = static_cast<std::uint16_t>(i % 65536);
  const std::size_t n = c.size();
  auto r = hp::remove_statistical_outliers(std::move(c), k, sigma);
  if (report) *report = r.report;
  // Kept points stay in order: walk both sequences to recover the indices.
  std::set<std::size_t> kept;
  std::size_t j = 0;
  for (std::size_t i = 0; i < n && j < r.value.size(); ++i) {
    if (r.value.scan_id[j] == static_cast<std::uint16_t>(i % 65536)) {
      kept.insert(i);
      ++j;
    }
  }
  EXPECT_EQ(j, r.value.size());
  return kept;
}

std::set<std::size_t> kept_by_pcl(const hp::Cloud& c, int k, double sigma) {
  pcl::PointCloud<pcl::PointXYZ>::Ptr pc(new pcl::PointCloud<pcl::PointXYZ>);
  for (Eigen::Index i = 0; i < c.xyz.cols(); ++i) {
    pc->push_back(pcl::PointXYZ(static_cast<float>(c.xyz(0, i)), static_cast<float>(c.xyz(1, i)),
                                static_cast<float>(c.xyz(2, i))));
  }
  pcl::StatisticalOutlierRemoval<pcl::PointXYZ> sor;
  sor.setInputCloud(pc);
  sor.setMeanK(k);
  sor.setStddevMulThresh(sigma);
  pcl::Indices kept;
  sor.filter(kept);
  return {kept.begin(), kept.end()};
}

// PCL's rule by brute force, in the same float arithmetic.
std::set<std::size_t> kept_by_brute_force(const hp::Cloud& c, int k, double sigma) {
  const std::size_t n = c.size();
  std::vector<float> p(3 * n);
  for (std::size_t i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) p[3 * i + static_cast<std::size_t>(a)] = static_cast<float>(c.xyz(a, static_cast<Eigen::Index>(i)));
  std::vector<float> d(n), d2(n);
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t j = 0; j < n; ++j) {
      const float dx = p[3 * j] - p[3 * i], dy = p[3 * j + 1] - p[3 * i + 1], dz = p[3 * j + 2] - p[3 * i + 2];
      d2[j] = dx * dx + dy * dy + dz * dz;
    }
    std::partial_sort(d2.begin(), d2.begin() + k + 1, d2.end());
    double sum = 0;
    for (int j = 1; j <= k; ++j) sum += std::sqrt(d2[static_cast<std::size_t>(j)]);
    d[i] = static_cast<float>(sum / k);
  }
  double sum = 0, sq = 0;
  for (const float v : d) {
    sum += v;
    sq += v * v;
  }
  const double nd = static_cast<double>(n);
  const double mean = sum / nd, sd = std::sqrt((sq - sum * sum / nd) / (nd - 1));
  std::set<std::size_t> kept;
  for (std::size_t i = 0; i < n; ++i)
    if (d[i] <= mean + sigma * sd) kept.insert(i);
  return kept;
}

std::size_t symmetric_difference(const std::set<std::size_t>& a, const std::set<std::size_t>& b) {
  std::vector<std::size_t> out;
  std::set_symmetric_difference(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(out));
  return out.size();
}

}  // namespace

TEST(NonFinite, DropsNanAndInfinityAndSaysHowMany) {
  const double nan = std::numeric_limits<double>::quiet_NaN(), inf = std::numeric_limits<double>::infinity();
  hp::Cloud c = cloud_of({{0, 0, 0}, {nan, 0, 0}, {1, 2, 3}, {0, -inf, 0}, {4, 5, 6}});
  c.scan_id = {0, 1, 2, 3, 4};
  const auto r = hp::remove_non_finite(std::move(c));
  ASSERT_EQ(r.value.size(), 3u);
  EXPECT_EQ(r.value.scan_id, (std::vector<std::uint16_t>{0, 2, 4}));
  EXPECT_EQ(r.value.xyz.col(2), Eigen::Vector3d(4, 5, 6));
  EXPECT_EQ(r.report.count_in, 5u);
  EXPECT_EQ(r.report.count_out, 3u);
  EXPECT_EQ(figure(r.report, "dropped"), 2.0);
  ASSERT_FALSE(r.report.notes.empty());
  EXPECT_NE(r.report.notes[0].find("dropped 2 of 5"), std::string::npos) << r.report.notes[0];
}

TEST(NonFinite, CloudOfOnlyNanBecomesEmptyAndTheNextStageRejectsIt) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const auto r = hp::remove_non_finite(cloud_of({{nan, nan, nan}, {nan, 1, 2}}));
  EXPECT_EQ(r.value.size(), 0u);
  EXPECT_NE(r.report.notes[0].find("dropped 2 of 2"), std::string::npos);
  EXPECT_THROW(hp::crop_box(r.value, Eigen::Vector3d::Constant(-1), Eigen::Vector3d::Constant(1)), hc::InputError);
  EXPECT_THROW(hp::voxel_downsample(r.value, 0.01), hc::InputError);
  EXPECT_THROW(hp::remove_statistical_outliers(r.value, 8, 1.0), hc::InputError);
  EXPECT_THROW(hp::to_metres_and_recentre(r.value, 1.0, nullptr), hc::InputError);
}

TEST(CropBox, KeepsPointsInsideIncludingTheFaces) {
  hp::Cloud c = cloud_of({{0, 0, 0}, {1, 1, 1}, {1.0001, 0, 0}, {-1, -1, -1}, {0.5, -2, 0}});
  c.scan_id = {7, 8, 9, 10, 11};
  const auto r = hp::crop_box(c, Eigen::Vector3d(-1, -1, -1), Eigen::Vector3d(1, 1, 1));
  EXPECT_EQ(r.value.size(), 3u);
  EXPECT_EQ(r.value.scan_id, (std::vector<std::uint16_t>{7, 8, 10}));
  EXPECT_EQ(r.report.count_in, 5u);
  EXPECT_EQ(r.report.count_out, 3u);
  EXPECT_THROW(hp::crop_box(c, Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, 1, 1)), hc::ConfigError);
  EXPECT_THROW(hp::crop_box(c, Eigen::Vector3d::Constant(5), Eigen::Vector3d::Constant(6)), hc::DegenerateInputError);
}

TEST(VoxelGrid, ReplacesEachVoxelByItsCentroid) {
  const hp::Cloud c = cloud_of({{0.1, 0.1, 0.1}, {0.3, 0.5, 0.7}, {1.5, 0.5, 0.5}, {1.7, 0.9, 0.1}, {-0.5, 0.2, 0.2}});
  const auto r = hp::voxel_downsample(c, 1.0);
  ASSERT_EQ(r.value.size(), 3u);
  std::vector<Eigen::Vector3d> got;
  for (Eigen::Index i = 0; i < r.value.xyz.cols(); ++i) got.push_back(r.value.xyz.col(i));
  std::sort(got.begin(), got.end(), [](const auto& a, const auto& b) { return a.x() < b.x(); });
  EXPECT_TRUE(got[0].isApprox(Eigen::Vector3d(-0.5, 0.2, 0.2), 1e-6));
  EXPECT_TRUE(got[1].isApprox(Eigen::Vector3d(0.2, 0.3, 0.4), 1e-6));
  EXPECT_TRUE(got[2].isApprox(Eigen::Vector3d(1.6, 0.7, 0.3), 1e-6));
  EXPECT_EQ(r.report.count_in, 5u);
  EXPECT_EQ(r.report.count_out, 3u);
}

TEST(VoxelGrid, LeafTooSmallForPclIndicesIsAConfigError) {
  const hp::Cloud c = cloud_of({{0, 0, 0}, {1000, 1000, 1000}});
  try {
    hp::voxel_downsample(c, 1e-5);
    ADD_FAILURE() << "no exception";
  } catch (const hc::ConfigError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("2147483647"), std::string::npos) << msg;
    EXPECT_NE(msg.find("1e-05"), std::string::npos) << msg;
  }
  EXPECT_THROW(hp::voxel_downsample(c, 0.0), hc::ConfigError);
  EXPECT_THROW(hp::voxel_downsample(c, -1.0), hc::ConfigError);
}

TEST(StatisticalOutliers, RejectsBadParametersAndTooFewPoints) {
  const hp::Cloud c = cloud_of({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}, {2, 2, 2}});
  EXPECT_THROW(hp::remove_statistical_outliers(c, 0, 1.0), hc::ConfigError);
  EXPECT_THROW(hp::remove_statistical_outliers(c, 2, 0.0), hc::ConfigError);
  EXPECT_THROW(hp::remove_statistical_outliers(c, 2, std::nan("")), hc::ConfigError);
  EXPECT_THROW(hp::remove_statistical_outliers(c, 4, 1.0), hc::DegenerateInputError);
  EXPECT_NO_THROW(hp::remove_statistical_outliers(c, 3, 1.0));
}

// Oracle: PCL's StatisticalOutlierRemoval on the raw bunny scan with injected outliers (the
// bunny, not the Buddha, may be corrupted on purpose). The same float input gives the same set.
TEST(StatisticalOutliers, SameRemovedSetAsPclOnTheBunnyWithInjectedOutliers) {
  hp::Cloud c = hp::load_cloud(hc::test::scan_path("bunny/bun000.ply")).value;
  c.row.clear();  // the range_grid's row/col: the points added below have none
  c.col.clear();
  const std::size_t clean = c.size();
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> u(-0.12, 0.12);
  std::normal_distribution<double> jitter(0.0, 0.004);
  const std::size_t extra = 600;
  c.xyz.conservativeResize(Eigen::NoChange, static_cast<Eigen::Index>(clean + extra));
  for (std::size_t i = 0; i < extra; ++i) {
    const auto col = static_cast<Eigen::Index>(clean + i);
    if (i % 2 == 0) {
      c.xyz.col(col) = Eigen::Vector3d(u(rng), u(rng) + 0.11, u(rng));  // anywhere around the bunny
    } else {  // just off the surface
      const auto src = static_cast<Eigen::Index>(rng() % clean);
      c.xyz.col(col) = c.xyz.col(src) + Eigen::Vector3d(jitter(rng), jitter(rng), jitter(rng));
    }
  }
  c.xyz.col(static_cast<Eigen::Index>(clean + 1)) = Eigen::Vector3d(3.0, -2.0, 1.0);  // one far away
  // Recentre first so that both sides see the same float coordinates.
  c = hp::to_metres_and_recentre(std::move(c), 1.0, nullptr).value;

  for (const auto& [k, sigma] : {std::pair{16, 1.0}, std::pair{8, 2.5}, std::pair{30, 0.5}}) {
    hp::StageReport report;
    const auto ours = kept_by_hc(c, k, sigma, &report);
    const auto theirs = kept_by_pcl(c, k, sigma);
    EXPECT_EQ(symmetric_difference(ours, theirs), 0u) << "k " << k << " sigma " << sigma;
    EXPECT_EQ(report.count_out, ours.size());
    if (k == 16) {  // most of the points thrown around the bunny go (some land on it)
      std::size_t far_removed = 0;
      for (std::size_t i = clean; i < clean + extra; i += 2) far_removed += ours.count(i) ? 0u : 1u;
      EXPECT_GT(far_removed, extra / 2 * 8 / 10);
    }
    EXPECT_FALSE(ours.count(clean + 1)) << "the far point must go";
  }
}

// Brute-force oracle on a cloud built to exercise every search stage: a dense plane patch, a
// duplicate cluster, sparse points in a wide box and two far points.
TEST(StatisticalOutliers, MatchesBruteForceOnACloudThatNeedsEverySearchStage) {
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 60; ++i)
    for (int j = 0; j < 60; ++j) pts.emplace_back(0.001 * i, 0.001 * j, 0.0001 * std::sin(i * 0.7 + j));
  for (int i = 0; i < 25; ++i) pts.emplace_back(0.0301, 0.0302, 0.01);  // duplicates
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-0.2, 0.25);
  for (int i = 0; i < 250; ++i) pts.emplace_back(u(rng), u(rng), u(rng));
  pts.emplace_back(40.0, 0.0, 0.0);
  pts.emplace_back(40.0, 0.001, 0.0);
  hp::Cloud c = hp::to_metres_and_recentre(cloud_of(pts), 1.0, nullptr).value;
  for (const auto& [k, sigma] : {std::pair{10, 1.0}, std::pair{4, 0.3}}) {
    hp::StageReport report;
    const auto ours = kept_by_hc(c, k, sigma, &report);
    EXPECT_EQ(symmetric_difference(ours, kept_by_brute_force(c, k, sigma)), 0u) << "k " << k;
    EXPECT_GT(figure(report, "knn_beyond_3x3x3_block"), 0.0);
    EXPECT_GT(figure(report, "knn_by_cell_tree"), 0.0);
    EXPECT_EQ(report.count_in, pts.size());
  }
}

// Thousands of copies of one location (scanners often write "no return" as 0, 0, 0) and a
// very uneven density must neither slow the search down quadratically nor change the answer.
TEST(StatisticalOutliers, MatchesBruteForceWithAFloodOfDuplicatesAndAVeryDenseCluster) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> wide(-0.5, 0.5), tight(-0.0005, 0.0005);
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 2500; ++i) pts.emplace_back(0, 0, 0);
  for (int i = 0; i < 1500; ++i) pts.emplace_back(wide(rng), wide(rng), 0.01 * wide(rng));
  for (int i = 0; i < 40; ++i) pts.emplace_back(0.25, 0.25, 0.0);  // a smaller pile
  hp::Cloud flood = cloud_of(pts);
  for (const auto& [k, sigma] : {std::pair{16, 1.0}, std::pair{5, 2.0}}) {
    hp::StageReport report;
    const auto ours = kept_by_hc(flood, k, sigma, &report);
    EXPECT_EQ(symmetric_difference(ours, kept_by_brute_force(flood, k, sigma)), 0u) << "k " << k;
    EXPECT_GE(figure(report, "duplicates_left_out"), 2500.0 - (k + 1));
  }
  // Dense cluster: 5000 points in a 1 mm cube inside 1500 points spread over a metre (the grid
  // adapts), then 5000 more in a 1 µm cube (beyond what the grid adapts to: a kd-tree answers).
  for (int i = 0; i < 5000; ++i) pts.emplace_back(0.1 + tight(rng), 0.1 + tight(rng), tight(rng));
  const hp::Cloud uneven = cloud_of(pts);
  hp::StageReport report;
  auto ours = kept_by_hc(uneven, 12, 1.5, &report);
  EXPECT_EQ(symmetric_difference(ours, kept_by_brute_force(uneven, 12, 1.5)), 0u);
  EXPECT_EQ(figure(report, "knn_by_point_tree"), 0.0);
  for (int i = 0; i < 5000; ++i) pts.emplace_back(-0.1 + 1e-3 * tight(rng), 1e-3 * tight(rng), 1e-3 * tight(rng));
  const hp::Cloud extreme = cloud_of(pts);
  ours = kept_by_hc(extreme, 12, 1.5, &report);
  EXPECT_EQ(symmetric_difference(ours, kept_by_brute_force(extreme, 12, 1.5)), 0u);
  EXPECT_GT(figure(report, "knn_by_point_tree"), 0.0);
}

TEST(StatisticalOutliers, DropsNonFinitePointsAndKeepsScanIdsAligned) {
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 20; ++i)
    for (int j = 0; j < 20; ++j) pts.emplace_back(0.01 * i, 0.01 * j, 0.0);
  pts.emplace_back(std::nan(""), 0, 0);
  pts.emplace_back(5, 5, 5);
  hp::Cloud c = cloud_of(pts);
  c.scan_id.assign(c.size(), 3);
  c.scan_id.back() = 9;
  const auto r = hp::remove_statistical_outliers(c, 6, 1.0);
  EXPECT_EQ(r.report.count_in, 402u);
  EXPECT_LE(r.value.size(), 400u);
  EXPECT_TRUE(r.value.xyz.allFinite());
  EXPECT_EQ(std::count(r.value.scan_id.begin(), r.value.scan_id.end(), 9), 0);
  EXPECT_EQ(r.value.scan_id.size(), r.value.size());
}

namespace filters_keep_if {

// Cloud::keep_if moves runs of kept points as blocks; oracle: a cloud built point by point from
// the kept points of a copy, every attribute with it. Masks: none kept, all kept, the first and
// last removed, single and long runs, random.
TEST(CloudKeepIf, KeepsEveryAttributeOfTheKeptPointsInOrder) {
  std::mt19937 rng(7);
  const std::size_t n = 997;
  hp::Cloud c;
  c.xyz.resize(3, static_cast<Eigen::Index>(n));
  for (std::size_t i = 0; i < n; ++i) {
    c.xyz.col(static_cast<Eigen::Index>(i)) = Eigen::Vector3d(static_cast<double>(i), 0.5 * static_cast<double>(i), -1.0 * static_cast<double>(i));
    c.scan_id.push_back(static_cast<std::uint16_t>(i % 7));
    c.intensity.push_back(static_cast<float>(i) * 0.25f);
    for (int k = 0; k < 3; ++k) {
      c.rgb.push_back(static_cast<std::uint8_t>((i * 3 + static_cast<std::size_t>(k)) % 251));
      c.normal.push_back(static_cast<float>(i) + 0.1f * static_cast<float>(k));
    }
    c.curvature.push_back(static_cast<float>(i) * 1e-3f);
    c.row.push_back(static_cast<std::int32_t>(i / 31));
    c.col.push_back(static_cast<std::int32_t>(i % 31));
  }
  std::vector<std::vector<bool>> masks;
  masks.emplace_back(n, false);
  masks.emplace_back(n, true);
  std::vector<bool> ends(n, true);
  ends.front() = ends.back() = false;
  masks.push_back(ends);
  std::vector<bool> alternate(n);
  for (std::size_t i = 0; i < n; ++i) alternate[i] = i % 2 == 0;
  masks.push_back(alternate);
  for (double p : {0.01, 0.5, 0.99}) {
    std::bernoulli_distribution keep(p);
    std::vector<bool> m(n);
    for (std::size_t i = 0; i < n; ++i) m[i] = keep(rng);
    masks.push_back(m);
  }
  for (std::size_t mi = 0; mi < masks.size(); ++mi) {
    const std::vector<bool>& mask = masks[mi];
    hp::Cloud got = c;
    got.keep_if(mask);
    std::size_t out = 0;
    for (std::size_t i = 0; i < n; ++i) {
      if (!mask[i]) continue;
      ASSERT_LT(out, got.size()) << "mask " << mi;
      const auto o = static_cast<Eigen::Index>(out);
      EXPECT_EQ(got.xyz.col(o), c.xyz.col(static_cast<Eigen::Index>(i))) << "mask " << mi << " point " << i;
      EXPECT_EQ(got.scan_id[out], c.scan_id[i]);
      EXPECT_EQ(got.intensity[out], c.intensity[i]);
      for (std::size_t k = 0; k < 3; ++k) {
        EXPECT_EQ(got.rgb[3 * out + k], c.rgb[3 * i + k]);
        EXPECT_EQ(got.normal[3 * out + k], c.normal[3 * i + k]);
      }
      EXPECT_EQ(got.curvature[out], c.curvature[i]);
      EXPECT_EQ(got.row[out], c.row[i]);
      EXPECT_EQ(got.col[out], c.col[i]);
      ++out;
    }
    EXPECT_EQ(got.size(), out) << "mask " << mi;
    EXPECT_EQ(got.scan_id.size(), out);
    EXPECT_EQ(got.intensity.size(), out);
    EXPECT_EQ(got.rgb.size(), 3 * out);
    EXPECT_EQ(got.normal.size(), 3 * out);
    EXPECT_EQ(got.curvature.size(), out);
    EXPECT_EQ(got.row.size(), out);
    EXPECT_EQ(got.col.size(), out);
  }
}

}  // namespace filters_keep_if
