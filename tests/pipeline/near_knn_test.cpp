// The mean k-NN distances of a few listed points searched among the points near them
// (near_knn.hpp) against the search over the whole cloud, bit for bit, and against brute force
// in double (float coordinates: 1e-5 relative).

#include "near_knn.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/robust_outliers.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>
#include <random>
#include <string>
#include <vector>

namespace {

using hc::pipeline::Cloud;
using hc::pipeline::detail::mean_knn_distances_of;
using hc::pipeline::detail::NearSearch;

Cloud cloud_of(const std::vector<Eigen::Vector3d>& pts) {
  Cloud c;
  c.xyz.resize(3, static_cast<Eigen::Index>(pts.size()));
  for (std::size_t i = 0; i < pts.size(); ++i) c.xyz.col(static_cast<Eigen::Index>(i)) = pts[i];
  return c;
}

// Mean distance to the k nearest other points and the nearest other point's distance, by brute
// force in double.
std::pair<double, double> brute(const Cloud& c, std::uint32_t q, int k) {
  std::vector<double> d;
  for (Eigen::Index j = 0; j < c.xyz.cols(); ++j) {
    if (j != static_cast<Eigen::Index>(q) && c.xyz.col(j).allFinite()) d.push_back((c.xyz.col(j) - c.xyz.col(q)).norm());
  }
  std::nth_element(d.begin(), d.begin() + (k - 1), d.end());
  std::sort(d.begin(), d.begin() + k);
  double s = 0.0;
  for (int i = 0; i < k; ++i) s += d[static_cast<std::size_t>(i)];
  return {s / k, d[0]};
}

// A relief 1 m × 0.5 m (`count` points: 0.6 per mm² at 300 000) far from the origin (a
// survey's frame), with what a scan holds: noise, strays up to 30 mm above the surface, a stack
// of 600 copies of one point (more than build_grid keeps in a crowded cell), a sparse strip (a
// fiftieth of the density), a small cluster 3 m away, and non-finite points among them (so
// that columns and finite rows differ).
struct Scene {
  Cloud cloud;
  std::vector<std::uint32_t> list;  // what the tests list: of every kind, and points at the edge
  std::uint32_t far = 0;            // a point of the far cluster
};

Scene relief(std::uint32_t seed, int count = 300000) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 5e-5);
  const Eigen::Vector3d origin(412345.0, 5012345.0, 120.0);
  std::vector<Eigen::Vector3d> pts;
  const auto surface = [&](double x, double y) {
    const double z = 0.004 * std::sin(30.0 * x) * std::cos(20.0 * y) + noise(rng);
    return Eigen::Vector3d(origin.x() + x, origin.y() + y, origin.z() + z);
  };
  Scene s;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (int i = 0; i < 3; ++i) pts.emplace_back(nan, 0.0, 0.0);
  for (int i = 0; i < count; ++i) {
    if (i % 50000 == 17) pts.emplace_back(origin.x(), nan, origin.z());
    const double x = u(rng), y = 0.5 * u(rng);
    if (x > 0.6 && x < 0.62 && u(rng) > 0.02) continue;  // the sparse strip
    pts.push_back(surface(x, y));
  }
  const std::size_t surface_points = pts.size();
  for (int i = 0; i < 60; ++i) {
    Eigen::Vector3d p = surface(u(rng), 0.5 * u(rng));
    p.z() += 0.002 + 0.028 * u(rng);
    pts.push_back(p);
  }
  const Eigen::Vector3d stacked = pts[1234];
  for (int i = 0; i < 600; ++i) pts.push_back(stacked);
  const std::size_t cluster = pts.size();
  for (int i = 0; i < 30; ++i) {
    const double x = 3.0 + 0.01 * u(rng), y = 0.2 + 0.01 * u(rng), z = 0.01 * u(rng);
    pts.emplace_back(origin.x() + x, origin.y() + y, origin.z() + z);
  }
  s.cloud = cloud_of(pts);
  for (std::uint32_t i = 3; i < surface_points; i += 4001) {
    if (pts[i].allFinite()) s.list.push_back(i);
  }
  for (std::size_t i = surface_points; i < surface_points + 60; i += 3) s.list.push_back(static_cast<std::uint32_t>(i));
  s.list.push_back(1234);
  s.list.push_back(static_cast<std::uint32_t>(surface_points + 75));   // a copy in the stack
  s.list.push_back(static_cast<std::uint32_t>(surface_points + 655));  // the last copy
  // The strip's points, and those nearest the relief's four edges.
  std::uint32_t edge[4] = {3, 3, 3, 3};
  for (std::uint32_t i = 3; i < surface_points; ++i) {
    if (!pts[i].allFinite()) continue;
    const Eigen::Vector3d p = pts[i] - origin;
    if (p.x() > 0.6 && p.x() < 0.62 && i % 11 == 0) s.list.push_back(i);
    if (p.x() < (pts[edge[0]] - origin).x()) edge[0] = i;
    if (p.x() > (pts[edge[1]] - origin).x()) edge[1] = i;
    if (p.y() < (pts[edge[2]] - origin).y()) edge[2] = i;
    if (p.y() > (pts[edge[3]] - origin).y()) edge[3] = i;
  }
  s.list.insert(s.list.end(), edge, edge + 4);
  s.list.push_back(s.list[5]);  // listed twice
  s.far = static_cast<std::uint32_t>(cluster + 7);
  EXPECT_TRUE(pts[1234].allFinite());
  return s;
}

// The near search takes a subset of a relief for listed points of every kind (on the relief, in
// the sparse strip, at the edges, strays up to 30 mm above it, copies), and its distances and
// nearest distances equal the whole cloud's search bit for bit, and brute force in double (the
// search's float coordinates are 0.03 µm apart at 0.5 m from the centre: 2e-7 m).
TEST(NearKnn, SameBitsAsTheWholeCloudsSearch) {
  // 300 000 points: the passes on two threads; 100 000: on one (at most 2^17 points).
  for (const auto& [seed, count] : {std::pair{1u, 300000}, std::pair{2u, 300000}, std::pair{3u, 100000}}) {
    const Scene s = relief(seed, count);
    for (const int k : {8, 16}) {
      NearSearch near, whole;
      std::vector<double> nn_near, nn_whole;
      const auto a = mean_knn_distances_of(s.cloud, s.list, k, &nn_near, true, &near);
      const auto b = mean_knn_distances_of(s.cloud, s.list, k, &nn_whole, false, &whole);
      ASSERT_TRUE(near.near) << "seed " << seed << ", k " << k;
      ASSERT_EQ(s.list.size() * 1024 <= s.cloud.size(), true) << "few enough listed points for the near search";
      EXPECT_FALSE(whole.near);
      // About 40 blocks, and 30 balls of 6–35 mm on a relief of 0.6 points per mm²: a tenth.
      EXPECT_LT(near.subset_points, s.cloud.size() / 5) << "a subset, not the cloud";
      EXPECT_GT(near.wide_blocks + near.balls, 0U) << "the strays above the relief, by the wider block or by ball";
      EXPECT_GT(near.blocks, 2 * (near.wide_blocks + near.balls)) << "the points on the relief, by block";
      EXPECT_TRUE(near.columns) << "the blocks' x-y columns span a few hundred cells a side";
      ASSERT_EQ(a.size(), s.list.size());
      ASSERT_EQ(nn_near.size(), s.list.size());
      for (std::size_t q = 0; q < s.list.size(); ++q) {
        EXPECT_EQ(a[q], b[q]) << "point " << s.list[q] << ", k " << k;
        EXPECT_EQ(nn_near[q], nn_whole[q]) << "point " << s.list[q] << ", k " << k;
      }
      for (std::size_t q = 0; q < s.list.size(); q += 7) {
        const auto [mean, nearest] = brute(s.cloud, s.list[q], k);
        EXPECT_NEAR(a[q], mean, 1e-6 * mean + 2e-7) << "point " << s.list[q];
        EXPECT_NEAR(nn_near[q], nearest, 1e-6 * nearest + 2e-7) << "point " << s.list[q];
      }
      // The public function takes the near search.
      EXPECT_EQ(hc::pipeline::mean_knn_distances(s.cloud, s.list, k), a);
    }
  }
}

// A wall's two sides: a relief of 400 000 points, and 10 cm behind it a back side twenty times
// sparser (what a scanner sees past an open edge), as on the generated 10^8 wall. The cells are
// sized for the front, so a back-side point's 3 × 3 × 3 block holds too few points and it is
// searched in its 9 × 9 × 9 block (until 2026-11-28 in a ball of the sample's bound, which took
// in much of the front); the distances equal the whole cloud's search bit for bit, and brute
// force, for the cloud and for the same points given as floats (the tiled run's stage
// tile_scale).
TEST(NearKnn, SparseBackSideAndFloatPoints) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 400000; ++i) {
    const double x = 0.5 * u(rng), y = 0.5 * u(rng);
    pts.emplace_back(x, y, 0.003 * std::sin(40.0 * x) * std::cos(25.0 * y));
  }
  const auto front = static_cast<std::uint32_t>(pts.size());
  for (int i = 0; i < 20000; ++i) pts.emplace_back(0.5 * u(rng), 0.5 * u(rng), -0.1 + 1e-4 * u(rng));
  const Cloud c = cloud_of(pts);
  std::vector<std::uint32_t> list;
  for (std::uint32_t i = 5; i < front; i += 4000) list.push_back(i);
  std::vector<std::uint32_t> back;
  for (std::uint32_t i = front + 3; i < pts.size(); i += 700) back.push_back(i);
  list.insert(list.end(), back.begin(), back.end());
  const int k = 8;
  NearSearch near, whole;
  std::vector<double> nn_near, nn_whole;
  const auto a = mean_knn_distances_of(c, list, k, &nn_near, true, &near);
  const auto b = mean_knn_distances_of(c, list, k, &nn_whole, false, &whole);
  ASSERT_TRUE(near.near);
  EXPECT_GE(near.wide_blocks, back.size() / 2) << "most back-side points by the wider block";
  EXPECT_LT(near.subset_points, c.size() / 10) << "a subset, not the cloud";
  EXPECT_EQ(a, b);
  EXPECT_EQ(nn_near, nn_whole);
  for (std::size_t q = 0; q < list.size(); q += 3) {
    const auto [mean, nearest] = brute(c, list[q], k);
    EXPECT_NEAR(a[q], mean, 1e-6 * mean + 2e-7) << "point " << list[q];
    EXPECT_NEAR(nn_near[q], nearest, 1e-6 * nearest + 2e-7) << "point " << list[q];
  }
  // The same points as floats (the tiled run's form): the same distances.
  std::vector<float> xyz;
  for (const auto& p : pts) {
    for (int ax = 0; ax < 3; ++ax) xyz.push_back(static_cast<float>(p[ax]));
  }
  NearSearch near_f;
  std::vector<double> nn_f;
  NearSearch whole_f;
  std::vector<double> nn_fw;
  const auto f = mean_knn_distances_of(xyz, list, k, &nn_f, true, &near_f);
  const auto fw = mean_knn_distances_of(xyz, list, k, &nn_fw, false, &whole_f);
  EXPECT_TRUE(near_f.near);
  EXPECT_FALSE(whole_f.near);
  EXPECT_GE(near_f.wide_blocks, back.size() / 2) << "the back side by the wider block over the floats too";
  EXPECT_EQ(f, fw) << "near and whole search over the floats";
  EXPECT_EQ(nn_f, nn_fw) << "near and whole search over the floats";
  for (std::size_t q = 0; q < list.size(); q += 3) {
    const auto [mean, nearest] = brute(c, list[q], k);
    EXPECT_NEAR(f[q], mean, 1e-6 * mean + 2e-7) << "point " << list[q];
    EXPECT_NEAR(nn_f[q], nearest, 1e-6 * nearest + 2e-7) << "point " << list[q];
  }
}

// Bad float input is refused with the value named.
TEST(NearKnn, FloatInputRefused) {
  std::vector<float> xyz(3 * 20, 0.0f);
  for (std::size_t j = 0; j < xyz.size(); ++j) xyz[j] = static_cast<float>(j);
  const auto message = [&](const std::vector<float>& p, std::vector<std::uint32_t> list) {
    try {
      (void)mean_knn_distances_of(p, list, 4, nullptr, true, nullptr);
    } catch (const std::exception& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message(xyz, {20}).find("row 20 listed, expected < 20"), std::string::npos);
  std::vector<float> bad = xyz;
  bad[3 * 7 + 1] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_NE(message(bad, {1}).find("point 7 has a non-finite coordinate"), std::string::npos);
  bad = xyz;
  bad.pop_back();
  EXPECT_NE(message(bad, {1}).find("59 float coordinates, expected a multiple of 3"), std::string::npos);
  EXPECT_NE(message(std::vector<float>(xyz.begin(), xyz.begin() + 15), {1}).find("5 points; k = 4 needs at least 6"),
            std::string::npos);
  // The kinds of error (hc/common/error.hpp).
  bad = xyz;
  bad[5] = std::numeric_limits<float>::infinity();
  EXPECT_THROW((void)mean_knn_distances_of(bad, {1}, 4, nullptr, true, nullptr), hc::InputError);
  EXPECT_THROW((void)mean_knn_distances_of(xyz, {20}, 4, nullptr, true, nullptr), hc::InputError);
  EXPECT_THROW((void)mean_knn_distances_of(std::vector<float>(xyz.begin(), xyz.begin() + 15), {1}, 4, nullptr, true, nullptr),
               hc::DegenerateInputError);
  for (const int k : {0, 1001}) {
    EXPECT_THROW((void)mean_knn_distances_of(xyz, {1}, k, nullptr, true, nullptr), hc::ConfigError) << "k = " << k;
  }
}

// A listed point whose k-th neighbour is far (one of a cluster of 30 points 3 m away, k = 40:
// 11 of its neighbours lie on the relief): its ball holds much of the relief, and the result
// is the whole cloud's, as brute force gives it. With more listed points than 1/1024 of the
// cloud, the whole cloud is searched without a subset.
TEST(NearKnn, FarNeighboursAndManyListedPoints) {
  const Scene s = relief(4);
  std::vector<std::uint32_t> list = s.list;
  list.push_back(s.far);
  NearSearch near, whole;
  const auto a = mean_knn_distances_of(s.cloud, list, 40, nullptr, true, &near);
  const auto b = mean_knn_distances_of(s.cloud, list, 40, nullptr, false, &whole);
  EXPECT_GT(near.balls, 0U);
  EXPECT_EQ(a, b);
  const double far_mean = brute(s.cloud, s.far, 40).first;
  EXPECT_GT(far_mean, 0.5) << "11 of its 40 neighbours are on the relief, 3 m away";
  EXPECT_NEAR(a.back(), far_mean, 1e-6 * far_mean);
  std::vector<std::uint32_t> many;
  for (std::uint32_t i = 0; many.size() < 2000; ++i) {
    if (s.cloud.xyz.col(i * 97 + 3).allFinite()) many.push_back(i * 97 + 3);
  }
  (void)mean_knn_distances_of(s.cloud, many, 16, nullptr, true, &near);
  EXPECT_FALSE(near.near);
  EXPECT_EQ(near.balls, 0U);
  EXPECT_EQ(near.subset_points, 0U);
}

// Listed points whose blocks' x-y columns span more than 2^24 columns (two small clusters
// 400 m from the relief on either side, diagonally: about 2 × 10^5 cells each way): the pass
// over the cloud keys every point without the column table, and the result is still the whole
// cloud's search, bit for bit; with the relief's listed points alone it takes the table, to the
// same bits.
TEST(NearKnn, ListedPointsFarApartKeyEveryPoint) {
  Scene s = relief(5);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0.0, 0.01);
  const Eigen::Index n0 = s.cloud.xyz.cols();
  const Eigen::Vector3d at = s.cloud.xyz.col(static_cast<Eigen::Index>(s.list.front()));
  s.cloud.xyz.conservativeResize(3, n0 + 40);
  for (Eigen::Index i = 0; i < 40; ++i) {
    const double side = i < 20 ? -400.0 : 400.0;
    s.cloud.xyz.col(n0 + i) = at + Eigen::Vector3d(side + u(rng), side + u(rng), u(rng));
  }
  for (const bool far_listed : {true, false}) {
    std::vector<std::uint32_t> list = s.list;
    if (far_listed) {
      list.push_back(static_cast<std::uint32_t>(n0 + 3));
      list.push_back(static_cast<std::uint32_t>(n0 + 27));
    }
    NearSearch near, whole;
    const auto a = mean_knn_distances_of(s.cloud, list, 8, nullptr, true, &near);
    const auto b = mean_knn_distances_of(s.cloud, list, 8, nullptr, false, &whole);
    ASSERT_TRUE(near.near) << "far listed: " << far_listed;
    EXPECT_EQ(near.columns, !far_listed);
    ASSERT_EQ(a.size(), list.size());
    for (std::size_t q = 0; q < list.size(); ++q) EXPECT_EQ(a[q], b[q]) << "point " << list[q] << ", far listed: " << far_listed;
    if (far_listed) {
      const double far_mean = brute(s.cloud, list.back(), 8).first;
      EXPECT_LT(far_mean, 0.02) << "its 8 nearest are in its own cluster";
      EXPECT_NEAR(a.back(), far_mean, 1e-5 * far_mean + 1e-4) << "float coordinates 400 m from the centre";
    }
  }
}

}  // namespace
