#pragma once
// Voxel coordinates and keys shared by the point tests' voxel hash (honest_check.cpp, VoxelHash)
// and the tiled run's subtraction of removed points from the robust test's neighbour counts
// (tiled_run.cpp, near_after_removal); a bit filter over a set of keys, which passes most
// points that are in no voxel of the set without a search of it; and a table of x-y columns
// that passes most points of a cloud outside a few cells on their x and y alone.

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
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

/// The x-y columns (cells of `edge` in x and y about the coordinates' origin: column
/// (⌊x / edge⌋, ⌊y / edge⌋) of float coordinates taken in double, as voxel_index and
/// near_rows' cell_of take them) that some rectangles of columns cover, a bit each over their
/// range, each rectangle widened by a column up in x and in y: a pass over a cloud for the
/// points of a few cells (near_rows in robust_outliers.cpp, points_about in honest_check.cpp)
/// passes over a point outside them on its x and y alone. The probe (Probe::may_hold) takes a
/// point's column as cell_of does (the float coordinate times 1 / edge, in double) but
/// truncated instead of floored: a negative value's truncation is its floor plus one, so the
/// widening keeps every point whose exact column is in a rectangle (the caller's exact test
/// follows). Empty (every point may be held) when the range spans more than 2^24 columns
/// (2 MiB), a rectangle reaches 2^20 − 2 columns from the origin, more than half the range is
/// covered (most points would pass), or none is given. A few
/// operations and one bit a point (on the tiled 10^8 wall, an exact floor took about as long as
/// the rest of the pass). No errors (but std::bad_alloc).
class ColumnTable {
 public:
  explicit ColumnTable(double inv_edge) : inv_edge_(inv_edge) {}
  /// Adds the columns [x0, x1] × [y0, y1] (call add for all, then build).
  void add(std::int64_t x0, std::int64_t x1, std::int64_t y0, std::int64_t y1) { rects_.push_back({x0, x1 + 1, y0, y1 + 1}); }
  /// Builds the table; returns whether it is in use (else probe() holds every point).
  bool build() {
    if (rects_.empty() || !std::isfinite(inv_edge_)) return false;
    std::int64_t x_lo = rects_[0][0], x_hi = rects_[0][1], y_lo = rects_[0][2], y_hi = rects_[0][3];
    for (const auto& r : rects_) x_lo = std::min(x_lo, r[0]), x_hi = std::max(x_hi, r[1]), y_lo = std::min(y_lo, r[2]), y_hi = std::max(y_hi, r[3]);
    constexpr std::int64_t kFar = (std::int64_t{1} << 20) - 2;
    if (x_lo < -kFar || y_lo < -kFar || x_hi > kFar || y_hi > kFar) return false;
    if ((x_hi - x_lo + 1) * (y_hi - y_lo + 1) > (std::int64_t{1} << 24)) return false;
    probe_.x0 = static_cast<std::int32_t>(x_lo), probe_.y0 = static_cast<std::int32_t>(y_lo);
    probe_.nx = static_cast<std::uint32_t>(x_hi - x_lo + 1), probe_.ny = static_cast<std::uint32_t>(y_hi - y_lo + 1);
    bits_.assign(static_cast<std::size_t>((probe_.nx * std::uint64_t{probe_.ny} + 63) / 64), 0);
    for (const auto& r : rects_) {
      for (std::int64_t y = r[2]; y <= r[3]; ++y) {
        for (std::int64_t x = r[0]; x <= r[1]; ++x) {
          const auto b = static_cast<std::size_t>((y - y_lo) * static_cast<std::int64_t>(probe_.nx) + (x - x_lo));
          bits_[b >> 6] |= std::uint64_t{1} << (b & 63);
        }
      }
    }
    std::vector<std::array<std::int64_t, 4>>().swap(rects_);
    // Most of the range covered: most points would pass, and the probe would only add its cost
    // (the honest check's isolation tests about thousands of points a tile, in voxels of the
    // test's radius).
    std::uint64_t set = 0;
    for (const std::uint64_t w : bits_) set += static_cast<std::uint64_t>(std::popcount(w));
    if (2 * set > std::uint64_t{probe_.nx} * probe_.ny) {
      std::vector<std::uint64_t>().swap(bits_);
      return false;
    }
    probe_.bits = bits_.data();
    probe_.inv_edge = inv_edge_;
    return true;
  }
  /// What a pass copies (a value: no reload through the table in its loop).
  struct Probe {
    const std::uint64_t* bits = nullptr;  // null: the table is not in use
    double inv_edge = 0.0;
    std::int32_t x0 = 0, y0 = 0;
    std::uint32_t nx = 0, ny = 0;
    /// Whether the point (float x y z) may lie in a column of the table: true for every point
    /// when the table is not in use; else false beyond 2^20 columns from the origin, where no
    /// rectangle reaches, and whether its column's bit is set.
    bool may_hold(const float* pt) const {
      if (bits == nullptr) return true;
      const double fx = static_cast<double>(pt[0]) * inv_edge, fy = static_cast<double>(pt[1]) * inv_edge;
      if (!(std::abs(fx) < 1048576.0) || !(std::abs(fy) < 1048576.0)) return false;
      const auto ux = static_cast<std::uint32_t>(static_cast<std::int32_t>(fx) - x0);
      const auto uy = static_cast<std::uint32_t>(static_cast<std::int32_t>(fy) - y0);
      if (ux >= nx || uy >= ny) return false;
      const std::uint64_t b = std::uint64_t{uy} * nx + ux;
      return ((bits[b >> 6] >> (b & 63)) & 1U) != 0;
    }
  };
  const Probe& probe() const { return probe_; }

 private:
  double inv_edge_;
  Probe probe_;
  std::vector<std::array<std::int64_t, 4>> rects_;
  std::vector<std::uint64_t> bits_;
};

}  // namespace hc::pipeline::detail
