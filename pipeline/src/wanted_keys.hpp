#pragma once
// A fixed set of 64-bit keys numbered in order of first appearance: the honest check's wanted
// voxels (honest_check.cpp) and the tiled run's far-cluster cells of a tile (tiled_run.cpp,
// FarCells::add_batch) look their points' keys up in it.

#include <cstddef>
#include <cstdint>
#include <limits>
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

}  // namespace hc::pipeline::detail
