#pragma once
// A fixed set of 64-bit keys numbered in order of first appearance: the honest check's wanted
// voxels (honest_check.cpp), the cells about a few listed points (robust_outliers.cpp, near_rows)
// and the voxels about a tile's removed points (tiled_run.cpp, near_after_removal) look their
// points' keys up in it; group_by_wanted_key gathers the points by key.

#include "knn_grid.hpp"  // run_parallel, share_of

#include <cstddef>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

namespace hc::pipeline::detail {

/// A fixed set of keys → their index, for a pass over millions of points (in the honest check,
/// few of them holding a wanted voxel key): open addressing (at most half full, key and index side by side, so a hit
/// costs one cache line), behind a bitmap of 4 bits per slot that turns most misses away from
/// L2 (a miss in the table itself would be an L3 access per point).
class WantedKeys {
 public:
  static constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();

  /// keys: any, repeats allowed; the distinct ones are numbered 0, 1, ... in order of first
  /// appearance (size() of them).
  explicit WantedKeys(const std::vector<std::uint64_t>& keys) {
    while ((std::size_t{1} << bits_) < 2 * keys.size()) ++bits_;
    mask_ = (std::size_t{1} << bits_) - 1;
    slots_.assign(mask_ + 1, Slot{0, kNone});
    filter_.assign(((mask_ + 1) * 4 + 63) / 64, 0);
    for (const std::uint64_t key : keys) {
      const std::uint64_t h = mix(key);
      std::size_t i = home(h);
      while (slots_[i].index != kNone && slots_[i].key != key) i = (i + 1) & mask_;
      if (slots_[i].index != kNone) continue;  // a repeat
      slots_[i] = Slot{key, static_cast<std::uint32_t>(size_++)};
      const std::size_t b = filter_bit(h);
      filter_[b >> 6] |= std::uint64_t{1} << (b & 63);
    }
  }
  /// The number of distinct keys.
  std::size_t size() const { return size_; }
  /// The number of `key` among the constructor's distinct keys (0 .. size() − 1, in order of
  /// first appearance), or kNone.
  std::uint32_t find(std::uint64_t key) const {
    const std::uint64_t h = mix(key);
    const std::size_t b = filter_bit(h);
    if (((filter_[b >> 6] >> (b & 63)) & 1U) == 0) return kNone;
    for (std::size_t i = home(h);; i = (i + 1) & mask_) {
      const Slot& s = slots_[i];
      if (s.index == kNone || s.key == key) return s.index;
    }
  }

 private:
  struct Slot {
    std::uint64_t key;
    std::uint32_t index;
  };
  static std::uint64_t mix(std::uint64_t key) { return key * 0x9E3779B97F4A7C15ULL; }
  std::size_t home(std::uint64_t h) const { return static_cast<std::size_t>(h >> (64 - bits_)); }
  std::size_t filter_bit(std::uint64_t h) const { return static_cast<std::size_t>(h >> (62 - bits_)); }
  int bits_ = 4;
  std::size_t mask_ = 0;
  std::size_t size_ = 0;
  std::vector<Slot> slots_;
  std::vector<std::uint64_t> filter_;
};

/// Points grouped by wanted key (group_by_wanted_key): members[first[w] .. first[w + 1]) are the
/// points, ascending, whose key is the wanted key numbered w; first has size() + 1 entries.
struct KeyGroups {
  std::vector<std::uint32_t> first;
  std::vector<std::uint32_t> members;
};

/// One pass over points 0 .. n − 1 (n < 2^32) on `threads` threads, each a contiguous share:
/// key_of(i, key) gives point i's key (false: it has none, as a non-finite point), and the
/// points whose key `wanted` holds are grouped by its number (a counting sort). key_of is
/// called from every thread at once, so it must not write shared state. No errors (but
/// std::bad_alloc).
template <class KeyOf>
KeyGroups group_by_wanted_key(std::size_t n, const WantedKeys& wanted, int threads, KeyOf&& key_of) {
  std::vector<std::vector<std::pair<std::uint32_t, std::uint32_t>>> found(static_cast<std::size_t>(threads));
  run_parallel(threads, [&](int t) {
    auto& mine = found[static_cast<std::size_t>(t)];
    const auto [b, e] = share_of(n, t, threads);
    std::uint64_t key = 0;
    for (std::size_t i = b; i < e; ++i) {
      if (!key_of(i, key)) continue;
      const std::uint32_t w = wanted.find(key);
      if (w != WantedKeys::kNone) mine.emplace_back(w, static_cast<std::uint32_t>(i));
    }
  });
  KeyGroups g;
  g.first.assign(wanted.size() + 1, 0);
  for (const auto& part : found)
    for (const auto& [w, i] : part) ++g.first[w + 1];
  for (std::size_t w = 0; w < wanted.size(); ++w) g.first[w + 1] += g.first[w];
  g.members.resize(g.first.back());
  std::vector<std::uint32_t> fill(g.first.begin(), g.first.end() - 1);
  for (const auto& part : found)  // the shares in order, each ascending: members ascend per key
    for (const auto& [w, i] : part) g.members[fill[w]++] = i;
  return g;
}

}  // namespace hc::pipeline::detail
