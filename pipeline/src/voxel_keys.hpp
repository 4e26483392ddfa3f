#pragma once
// Voxel coordinates and keys shared by the point tests' voxel hash (honest_check.cpp, VoxelHash)
// and the tiled run's subtraction of removed points from the robust test's neighbour counts
// (tiled_run.cpp, near_after_removal); and a bit filter over a set of keys, which passes most
// points that are in no voxel of the set without a search of it.

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace hc::pipeline::detail {

/// Voxel coordinates are clamped to ±kVoxelLimit (beyond, keys repeat: clamping moves two points
/// at most as far apart in voxels as before, so a search of the voxels within r of a point's
/// still finds every point within r voxels).
inline constexpr std::int64_t kVoxelLimit = (std::int64_t{1} << 20) - 1;

/// ⌊v · inv_edge⌋ clamped to ±kVoxelLimit (v finite, inv_edge > 0 [1/m]): a voxel coordinate.
/// Without branches (min and max, truncation corrected by a comparison): std::floor is a library
/// call on the baseline x86-64 target, and a branch on the sign mispredicts on every other point
/// of a cloud in no spatial order.
inline std::int64_t voxel_index(double v, double inv_edge) {
  constexpr auto lim = static_cast<double>(kVoxelLimit);
  const double c = std::min(std::max(v * inv_edge, -lim), lim);
  const auto t = static_cast<std::int64_t>(c);
  return t - static_cast<std::int64_t>(static_cast<double>(t) > c);
}

/// Voxel (x, y, z), each clamped to ±kVoxelLimit, in 21 bits each: keys in the order of the
/// coordinates, x slowest. Injective on the clamped coordinates.
inline std::uint64_t pack_voxel21(std::int64_t x, std::int64_t y, std::int64_t z) {
  auto u = [](std::int64_t v) { return static_cast<std::uint64_t>(std::clamp(v, -kVoxelLimit, kVoxelLimit) + kVoxelLimit + 1); };
  return (u(x) << 42) | (u(y) << 21) | u(z);
}

/// A bit per slot of a multiplicative hash of a set of 64-bit keys, at least bits_per_key
/// slots a key (a power of two, at most 2^40): maybe(k) is true for every key of the set and for
/// about a 1/bits_per_key share of the others, so a caller tests the set itself (a search, a
/// table) only where it is. Memory: bits_per_key bits a key, rounded up to a power of two.
class KeyBits {
 public:
  KeyBits(const std::vector<std::uint64_t>& keys, std::size_t bits_per_key) {
    int bits = 6;
    while (bits < 40 && (std::size_t{1} << bits) < bits_per_key * keys.size()) ++bits;
    shift_ = 64 - bits;
    words_.assign((std::size_t{1} << bits) / 64 + 1, 0);
    for (const std::uint64_t k : keys) words_[slot(k) >> 6] |= std::uint64_t{1} << (slot(k) & 63);
  }
  bool maybe(std::uint64_t key) const {
    const std::uint64_t h = slot(key);
    return ((words_[h >> 6] >> (h & 63)) & 1U) != 0;
  }

 private:
  std::uint64_t slot(std::uint64_t key) const { return (key * 0xC2B2AE3D27D4EB4FULL) >> shift_; }
  int shift_ = 58;
  std::vector<std::uint64_t> words_;
};

}  // namespace hc::pipeline::detail
