// Private helpers of the k-NN grid (knn_grid.hpp) against brute force.
//
// detail::radix_sort, the sort under the k-NN grid and the honest check's voxel hash, against
// std::stable_sort of (key, index) pairs on the same bits: keys and the permuted indices must
// match exactly (stability: equal keys keep their input order). Sizes on both sides of the
// two-thread threshold (2^17 keys), many equal keys, a middle digit equal in every key
// (skipped), a last digit narrower than 11 bits, and 64-bit keys.
//
// PointQueries::nearest (the robust filter's neighbourhoods) against a full scan, on a cloud
// made to take every path: a dense lattice (equal distances everywhere: ties ordered by input
// index) with a sparse layer 4 mm behind it, whose neighbourhoods reach past the 3³ block into
// the dense layer, queried in grid order (the hint of the query before serves, or fails and the
// block search runs). Its mean distance (the robust filter's d when it searches the neighbours
// first) against the full scan's k smallest, summed in ascending order, and against
// mean_distance's, bit for bit.

#include "knn_grid.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <utility>
#include <vector>

namespace {

using hc::pipeline::detail::radix_sort;

void expect_stable_sorted(std::vector<std::uint64_t> keys, int bits, const char* what) {
  const std::uint64_t mask = bits >= 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << bits) - 1;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> oracle(keys.size());
  for (std::size_t i = 0; i < keys.size(); ++i) oracle[i] = {keys[i], static_cast<std::uint32_t>(i)};
  std::stable_sort(oracle.begin(), oracle.end(),
                   [mask](const auto& a, const auto& b) { return (a.first & mask) < (b.first & mask); });
  std::vector<std::uint32_t> idx(keys.size());
  for (std::size_t i = 0; i < idx.size(); ++i) idx[i] = static_cast<std::uint32_t>(i);
  radix_sort(keys, idx, bits);
  std::size_t wrong = 0;
  for (std::size_t i = 0; i < keys.size(); ++i)
    wrong += keys[i] != oracle[i].first || idx[i] != oracle[i].second ? 1U : 0U;
  EXPECT_EQ(wrong, 0U) << what << ": " << keys.size() << " keys, " << bits << " bits";
}

TEST(RadixSort, EqualsAStableSortOnBothSidesOfTheThreadThreshold) {
  std::mt19937_64 rng(11);
  for (const std::size_t n : {std::size_t{1000}, std::size_t{300000}}) {
    std::vector<std::uint64_t> keys(n);
    // 26-bit keys from 5 000 values: runs of equal keys, three 11-bit digits.
    std::uniform_int_distribution<std::uint64_t> pick(0, 4999);
    std::vector<std::uint64_t> values(5000);
    for (auto& v : values) v = rng() & ((std::uint64_t{1} << 26) - 1);
    for (auto& k : keys) k = values[pick(rng)];
    expect_stable_sorted(keys, 26, "repeated values");
    // The middle digit (bits 11..21) equal in every key: that pass is skipped.
    for (auto& k : keys) k = (k & 0x7FFU) | (std::uint64_t{0x155} << 11) | ((k >> 22) << 22);
    expect_stable_sorted(keys, 26, "a constant middle digit");
    // 20-bit keys (the last digit is 9 bits wide).
    for (auto& k : keys) k &= 0xFFFFFU;
    expect_stable_sorted(keys, 20, "20-bit keys");
    // Full 64-bit keys, distinct almost surely.
    for (auto& k : keys) k = rng();
    expect_stable_sorted(keys, 64, "64-bit keys");
  }
}

// The k nearest (ties by input index), their mean distance and the k-th distance (kth_m) against
// a full scan of every point.
TEST(PointQueriesNearest, EqualsAFullScanWithTiesByInputIndex) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<float> p;
  for (int i = 0; i < 60; ++i)  // dense: a 60 × 60 lattice of 0.5 mm, no jitter
    for (int j = 0; j < 60; ++j) p.insert(p.end(), {0.0005f * static_cast<float>(i), 0.0005f * static_cast<float>(j), 0.0f});
  for (int i = 0; i < 300; ++i) p.insert(p.end(), {0.03f * u(rng), 0.03f * u(rng), -0.004f - 0.001f * u(rng)});
  // Shuffled, so that input order differs from space.
  const std::size_t n = p.size() / 3;
  std::vector<std::size_t> perm(n);
  for (std::size_t i = 0; i < n; ++i) perm[i] = i;
  std::shuffle(perm.begin(), perm.end(), rng);
  std::vector<float> q(3 * n);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t a = 0; a < 3; ++a) q[3 * i + a] = p[3 * perm[i] + a];
  constexpr int k = 16;
  const hc::pipeline::detail::CellGrid g = hc::pipeline::detail::build_grid(q, n, k);
  const hc::pipeline::detail::PointQueries queries(g, k);
  hc::pipeline::detail::PointQueries::Scratch scratch(k), other(k);
  std::size_t wrong = 0, wrong_mean = 0, unlike_mean_distance = 0, wrong_kth = 0;
  std::vector<std::uint32_t> got;
  for (std::uint32_t s = 0; s < g.original.size(); ++s) {
    const std::uint32_t i = g.original[s];
    float mean_d = -1.0f, kth = -1.0f;
    queries.nearest(s, scratch, got, &mean_d, &kth);
    unlike_mean_distance += mean_d != queries.mean_distance(s, other) ? 1U : 0U;
    std::vector<std::pair<float, std::uint32_t>> all;
    for (std::uint32_t j = 0; j < n; ++j) {
      if (j == i) continue;
      const float dx = q[3 * j] - q[3 * i], dy = q[3 * j + 1] - q[3 * i + 1], dz = q[3 * j + 2] - q[3 * i + 2];
      all.emplace_back(dx * dx + dy * dy + dz * dz, j);
    }
    std::partial_sort(all.begin(), all.begin() + k, all.end());
    std::vector<std::uint32_t> want;
    double sum = 0.0;  // ascending: PCL's order
    for (int a = 0; a < k; ++a) {
      want.push_back(all[static_cast<std::size_t>(a)].second);
      sum += std::sqrt(all[static_cast<std::size_t>(a)].first);
    }
    std::sort(want.begin(), want.end());
    wrong += got != want ? 1U : 0U;
    wrong_mean += mean_d != static_cast<float>(sum / k) ? 1U : 0U;
    wrong_kth += kth != std::sqrt(all[k - 1].first) ? 1U : 0U;  // the k-th smallest distance
  }
  EXPECT_EQ(wrong_kth, 0U) << "k-th distances unlike the full scan's, of " << n;
  EXPECT_EQ(wrong, 0U) << "of " << n << " queries";
  EXPECT_EQ(wrong_mean, 0U) << "mean distances unlike the full scan's, of " << n;
  EXPECT_EQ(unlike_mean_distance, 0U) << "mean distances unlike mean_distance's, of " << n;
}

}  // namespace
