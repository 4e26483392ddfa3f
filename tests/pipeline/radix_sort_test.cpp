// detail::radix_sort (knn_grid.hpp), the sort under the k-NN grid and the honest check's voxel
// hash, against std::stable_sort of (key, index) pairs on the same bits: keys and the permuted
// indices must match exactly (stability: equal keys keep their input order). Sizes on both sides
// of the two-thread threshold (2^17 keys), many equal keys, a middle digit equal in every key
// (skipped), a last digit narrower than 11 bits, and 64-bit keys.

#include "knn_grid.hpp"

#include <gtest/gtest.h>

#include <algorithm>
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

}  // namespace
