// Private helpers of the k-NN grid (knn_grid.hpp) against brute force.
//
// detail::radix_sort, the sort under the k-NN grid and the honest check's voxel hash, against
// std::stable_sort of (key, index) pairs on the same bits: keys and the permuted indices must
// match exactly (stability: equal keys keep their input order). Sizes on both sides of the
// two-thread threshold (2^17 keys), many equal keys, a middle digit equal in every key
// (skipped), a last digit narrower than 11 bits, and 64-bit keys.
//
// sort16 (Batcher's network) on every 0-1 input of 16 entries (by the 0-1 principle, then every
// input) and on shuffled 64-bit keys; smallest_keys_first (the k-NN queries' take of the k
// smallest candidates) against std::sort, for k = 16 (the network's path: one block, part of a
// second, whole blocks, keys in ascending, descending and no order) and k = 8 (the other path).
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
#include <bit>
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

TEST(SortingNetwork, SortsEveryZeroOneInputAndShuffledKeys) {
  std::size_t unsorted = 0;
  for (std::uint32_t bits = 0; bits < (1U << 16); ++bits) {
    std::uint32_t a[16];
    for (std::uint32_t i = 0; i < 16; ++i) a[i] = (bits >> i) & 1U;
    hc::pipeline::detail::sort16(a);
    unsorted += std::is_sorted(a, a + 16) && std::count(a, a + 16, 1U) == std::popcount(bits) ? 0U : 1U;
  }
  EXPECT_EQ(unsorted, 0U) << "0-1 inputs left unsorted (or changed) by sort16, of 65536";
  std::mt19937_64 rng(3);
  for (int t = 0; t < 1000; ++t) {
    std::uint64_t a[16];
    for (auto& v : a) v = rng() >> (t % 60);  // narrower keys now and then: equal ones
    std::vector<std::uint64_t> want(a, a + 16);
    std::sort(want.begin(), want.end());
    hc::pipeline::detail::sort16(a);
    ASSERT_TRUE(std::equal(want.begin(), want.end(), a)) << "trial " << t;
  }
}

TEST(SortingNetwork, SmallestKeysFirstEqualsAFullSort) {
  std::mt19937_64 rng(4);
  for (const std::size_t k : {std::size_t{16}, std::size_t{8}}) {
    for (const std::size_t m : {16, 17, 27, 31, 32, 33, 48, 100, 257}) {
      if (m < k) continue;
      for (int order = 0; order < 3; ++order) {  // no order, ascending, descending
        std::vector<std::uint64_t> keys(m);
        for (auto& v : keys) v = rng();
        std::sort(keys.begin(), keys.end());
        keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
        ASSERT_EQ(keys.size(), m);
        if (order == 0) std::shuffle(keys.begin(), keys.end(), rng);
        if (order == 2) std::reverse(keys.begin(), keys.end());
        std::vector<std::uint64_t> want = keys;
        std::sort(want.begin(), want.end());
        hc::pipeline::detail::smallest_keys_first(keys.data(), m, k);
        EXPECT_TRUE(std::equal(want.begin(), want.begin() + static_cast<std::ptrdiff_t>(k), keys.begin()))
            << "k " << k << ", m " << m << ", order " << order;
      }
    }
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

// LowerTable (the k-NN grid's cell lookup: a bit per key and a rank directory) against a linear
// count of the grid's occupied keys, for every key 0 .. n0·n1·n2 (the last one the end): lower()
// is the number of occupied keys below the key, occupied() whether the key is one of them. Grids
// of a wall with a sparse back layer (words with several cells, empty words, runs across words),
// of 63, 64 and 65 points on a line (the last word full, one past it), and of a single point;
// a grid with more than 64 keys a point leaves the table empty (callers search instead).
TEST(LowerTable, CountsTheOccupiedKeysBelowEveryKey) {
  using hc::pipeline::detail::CellGrid;
  using hc::pipeline::detail::LowerTable;
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<std::vector<float>> clouds;
  {
    std::vector<float> p;
    for (int i = 0; i < 3000; ++i) p.insert(p.end(), {0.2f * u(rng), 0.1f * u(rng), 0.002f * u(rng)});
    for (int i = 0; i < 200; ++i) p.insert(p.end(), {0.2f * u(rng), 0.1f * u(rng), -0.03f - 0.01f * u(rng)});
    clouds.push_back(std::move(p));
  }
  for (const int n : {63, 64, 65}) {
    std::vector<float> p;
    for (int i = 0; i < n; ++i) p.insert(p.end(), {0.001f * static_cast<float>(i), 0.0f, 0.0f});
    clouds.push_back(std::move(p));
  }
  clouds.push_back({0.5f, 0.25f, 0.125f});
  std::size_t checked = 0, wrong_lower = 0, wrong_occupied = 0, built = 0;
  for (const auto& p : clouds) {
    const std::size_t n = p.size() / 3;
    const CellGrid g = hc::pipeline::detail::build_grid(p, n, 1);
    const LowerTable t(g);
    const auto total = static_cast<std::uint64_t>(g.n[0] * g.n[1] * g.n[2]);
    if (total > 64u * n + 4096u) {
      EXPECT_TRUE(t.empty()) << total << " keys for " << n << " points";
      continue;
    }
    ASSERT_FALSE(t.empty()) << total << " keys for " << n << " points";
    ++built;
    std::size_t below = 0;  // occupied keys < key, counted along
    std::size_t next = 0;   // the next occupied key's place in cell_key
    for (std::uint64_t key = 0; key <= total; ++key) {
      const bool occ = next < g.cell_key.size() && g.cell_key[next] == key;
      wrong_lower += t.lower(key) != below ? 1U : 0U;
      if (key < total) wrong_occupied += t.occupied(key) != occ ? 1U : 0U;
      if (occ) {
        ++below;
        ++next;
      }
      ++checked;
    }
    EXPECT_EQ(below, g.cells());
  }
  EXPECT_GE(built, 4U);
  EXPECT_GT(checked, 1000U);
  EXPECT_EQ(wrong_lower, 0U) << "of " << checked << " keys";
  EXPECT_EQ(wrong_occupied, 0U) << "of " << checked << " keys";
  // More than 64 keys a point: two points at the ends of a long diagonal.
  const std::vector<float> sparse = {0.0f, 0.0f, 0.0f, 1.0f, 1.0f, 1.0f, 0.0f, 0.0f, 0.001f};
  const CellGrid gs = hc::pipeline::detail::build_grid(sparse, 3, 1);
  const auto total = static_cast<std::uint64_t>(gs.n[0] * gs.n[1] * gs.n[2]);
  EXPECT_EQ(LowerTable(gs).empty(), total > 64u * 3u + 4096u) << total << " keys";
}

// popcount64 (LowerTable's count of set bits: SWAR on a baseline x86-64 build, the POPCNT
// instruction where the target has it) against a count bit by bit: 0, all ones, every single
// bit, every prefix mask (as LowerTable::lower forms them) and random words of every density.
TEST(Popcount64, EqualsACountBitByBit) {
  using hc::pipeline::detail::popcount64;
  const auto by_bits = [](std::uint64_t x) {
    unsigned n = 0;
    for (int b = 0; b < 64; ++b) n += static_cast<unsigned>((x >> b) & 1U);
    return n;
  };
  std::vector<std::uint64_t> words = {0, ~std::uint64_t{0}};
  for (int b = 0; b < 64; ++b) {
    words.push_back(std::uint64_t{1} << b);
    words.push_back((std::uint64_t{1} << b) - 1);
  }
  std::mt19937_64 rng(47);
  for (int i = 0; i < 20000; ++i) {
    std::uint64_t x = rng();
    for (int thin = i % 4; thin > 0; --thin) x &= rng();  // sparser words
    for (int thick = (i / 4) % 3; thick > 0; --thick) x |= rng();  // denser words
    words.push_back(x);
  }
  std::size_t wrong = 0;
  for (const std::uint64_t x : words) wrong += popcount64(x) != by_bits(x) ? 1U : 0U;
  EXPECT_EQ(wrong, 0U) << "of " << words.size() << " words";
  EXPECT_EQ(popcount64(~std::uint64_t{0}), 64U);
  EXPECT_EQ(popcount64(0x8000000000000001ULL), 2U);
}
