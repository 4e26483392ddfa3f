#pragma once
// Balls indexed by an xy grid: which contains a point, and how far a search about a point may
// reach and stay inside one of them. The robust test's tile check against the balls where a set
// is complete (RobustOutlierOptions::TileBounds::complete_m) and the tiled run's gathering of
// the points inside them (tiled_run.cpp, judge_past_halo) share it.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace hc::pipeline::detail {

/// Balls {x, y, z, radius} [m] (any one frame) in an xy grid of 128 × 128 cells over their
/// bounding box. A ball is listed in each cell its xy box meets, or, when that would be more than
/// 256 cells, in each cell its xy box meets of a coarse grid of 16 × 16 cells over the same box
/// (the large balls: a stray's own search, and its neighbours'). A query reads its cell's list
/// and its coarse cell's. A ball inside another is left out. Memory: at most 256 entries per
/// ball. Non-finite balls are refused by the caller. (Until 2026-11-24 the large balls were in
/// one list every query read: at 10^8 points, hundreds of them for each of the 274 M records a
/// tiled run's second look read.)
class BallSet {
 public:
  using Ball = std::array<double, 4>;

  explicit BallSet(const std::vector<Ball>& balls) {
    const double inf = std::numeric_limits<double>::infinity();
    box_ = {inf, -inf, inf, -inf};
    for (const Ball& b : balls) {
      box_ = {std::min(box_[0], b[0] - b[3]), std::max(box_[1], b[0] + b[3]), std::min(box_[2], b[1] - b[3]),
              std::max(box_[3], b[1] + b[3])};
    }
    if (balls.empty()) return;
    cell_ = std::max({(box_[1] - box_[0]) / kSide, (box_[3] - box_[2]) / kSide, 1e-9});
    at_.resize(static_cast<std::size_t>(kSide) * kSide);
    // Largest first; a ball inside one kept (with a margin over rounding) adds nothing to
    // contains, margin or meets and is left out: the balls of a stray's neighbours, and the same
    // ball asked by several strays, are often inside another.
    std::vector<std::uint32_t> order(balls.size());
    for (std::uint32_t i = 0; i < order.size(); ++i) order[i] = i;
    std::stable_sort(order.begin(), order.end(),
                     [&](std::uint32_t x, std::uint32_t y) { return balls[x][3] > balls[y][3]; });
    for (const std::uint32_t o : order) {
      const Ball& b = balls[o];
      // A ball that holds b holds its centre in its xy box: it is listed in the centre's cells.
      const int rc = cell_of(b[1], 2), cc = cell_of(b[0], 0);
      const auto inside = [&](std::uint32_t k) {
        const Ball& a = balls_[k];
        const double dx = b[0] - a[0], dy = b[1] - a[1], dz = b[2] - a[2];
        if (dx == 0.0 && dy == 0.0 && dz == 0.0) return b[3] <= a[3];  // the same centre: exact
        return b[3] + std::sqrt(dx * dx + dy * dy + dz * dz) <= a[3] * (1.0 - 1e-12);
      };
      const auto& fine = at_[index(rc, cc)];
      if (std::any_of(fine.begin(), fine.end(), inside)) continue;
      if (!coarse_.empty()) {
        const auto& large = coarse_[coarse_index(rc, cc)];
        if (std::any_of(large.begin(), large.end(), inside)) continue;
      }
      const auto i = static_cast<std::uint32_t>(balls_.size());
      balls_.push_back(b);
      const int r0 = cell_of(b[1] - b[3], 2), r1 = cell_of(b[1] + b[3], 2);
      const int c0 = cell_of(b[0] - b[3], 0), c1 = cell_of(b[0] + b[3], 0);
      if ((r1 - r0 + 1) * (c1 - c0 + 1) > kMaxCellsPerBall) {
        if (coarse_.empty()) coarse_.resize(static_cast<std::size_t>(kCoarse) * kCoarse);
        for (int r = r0 / kPerCoarse; r <= r1 / kPerCoarse; ++r) {
          for (int c = c0 / kPerCoarse; c <= c1 / kPerCoarse; ++c) {
            coarse_[static_cast<std::size_t>(r) * kCoarse + static_cast<std::size_t>(c)].push_back(i);
          }
        }
        continue;
      }
      for (int r = r0; r <= r1; ++r) {
        for (int c = c0; c <= c1; ++c) at_[index(r, c)].push_back(i);
      }
    }
  }

  /// The balls kept (those inside another left out).
  std::size_t size() const { return balls_.size(); }

  bool empty() const { return balls_.empty(); }

  /// Whether p (x, y, z [m]) lies in one of the balls (distance at most the radius).
  bool contains(const double* p) const {
    if (!(p[0] >= box_[0] && p[0] <= box_[1] && p[1] >= box_[2] && p[1] <= box_[3])) return false;
    auto in = [&](std::uint32_t i) {
      const Ball& b = balls_[i];
      const double dx = p[0] - b[0], dy = p[1] - b[1], dz = p[2] - b[2];
      return dx * dx + dy * dy + dz * dz <= b[3] * b[3];
    };
    const int r = cell_of(p[1], 2), c = cell_of(p[0], 0);
    for (const std::uint32_t i : at_[index(r, c)]) {
      if (in(i)) return true;
    }
    if (coarse_.empty()) return false;
    const auto& large = coarse_[coarse_index(r, c)];
    return std::any_of(large.begin(), large.end(), in);
  }

  /// The largest R − |p − c| over the balls whose xy box holds p's xy [m]: the radius of a ball
  /// about p that lies inside one of them; 0 when there is none (a search of radius ≥ 0 about p
  /// is then not known to stay inside: the check lists it, as for any margin ≤ 0).
  double margin(const double* p) const {
    double best = 0.0;
    if (!(p[0] >= box_[0] && p[0] <= box_[1] && p[1] >= box_[2] && p[1] <= box_[3])) return best;
    auto take = [&](std::uint32_t i) {
      const Ball& b = balls_[i];
      const double dx = p[0] - b[0], dy = p[1] - b[1], dz = p[2] - b[2];
      best = std::max(best, b[3] - std::sqrt(dx * dx + dy * dy + dz * dz));
    };
    const int r = cell_of(p[1], 2), c = cell_of(p[0], 0);
    for (const std::uint32_t i : at_[index(r, c)]) take(i);
    if (!coarse_.empty()) {
      for (const std::uint32_t i : coarse_[coarse_index(r, c)]) take(i);
    }
    return best;
  }

  /// Whether a ball's xy disk meets the xy box b {x_min, x_max, y_min, y_max} [m] (sides may be
  /// infinite).
  bool meets(const std::array<double, 4>& b) const {
    for (const Ball& s : balls_) {
      const double dx = std::max({b[0] - s[0], s[0] - b[1], 0.0}), dy = std::max({b[2] - s[1], s[1] - b[3], 0.0});
      if (dx * dx + dy * dy <= s[3] * s[3]) return true;
    }
    return false;
  }

  /// The balls' xy bounding box {x_min, x_max, y_min, y_max} [m] (+inf, −inf when empty).
  const std::array<double, 4>& box_m() const { return box_; }

 private:
  static constexpr int kSide = 128;
  static constexpr int kCoarse = 16;
  static constexpr int kPerCoarse = kSide / kCoarse;  // cells per coarse cell, each way
  static constexpr int kMaxCellsPerBall = 256;
  // The cell of coordinate v along x (a = 0) or y (a = 2), clamped to the grid.
  int cell_of(double v, int a) const {
    const double c = (v - box_[static_cast<std::size_t>(a)]) / cell_;
    return c < 0.0 ? 0 : c >= kSide - 1 ? kSide - 1 : static_cast<int>(c);
  }
  static std::size_t index(int r, int c) { return static_cast<std::size_t>(r) * kSide + static_cast<std::size_t>(c); }
  // The coarse cell of cell (r, c).
  static std::size_t coarse_index(int r, int c) {
    return static_cast<std::size_t>(r / kPerCoarse) * kCoarse + static_cast<std::size_t>(c / kPerCoarse);
  }

  std::vector<Ball> balls_;
  std::array<double, 4> box_{};
  double cell_ = 1.0;
  std::vector<std::vector<std::uint32_t>> at_;
  std::vector<std::vector<std::uint32_t>> coarse_;  // the large balls by coarse cell (empty: none)
};

}  // namespace hc::pipeline::detail
