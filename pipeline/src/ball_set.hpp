#pragma once
// Balls indexed by an xy grid: which contains a point, and how far a search about a point may
// reach and stay inside one of them. The robust test's tile check against the balls where a set
// is complete (RobustOutlierOptions::TileBounds::complete_m) and the tiled run's gathering of
// the points inside them (tiled_run.cpp, judge_strays and gather_owned, which picks a tile's
// balls by ball_meets) share it.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

namespace hc::pipeline::detail {

/// Whether ball s {x, y, z, radius} meets the box b {x_min, x_max, y_min, y_max, z_min, z_max}
/// (the same frame, metres; sides may be infinite): the box's nearest point within the radius.
inline bool ball_meets(const std::array<double, 4>& s, const std::array<double, 6>& b) {
  const double dx = std::max({b[0] - s[0], s[0] - b[1], 0.0}), dy = std::max({b[2] - s[1], s[1] - b[3], 0.0});
  const double dz = std::max({b[4] - s[2], s[2] - b[5], 0.0});
  return dx * dx + dy * dy + dz * dz <= s[3] * s[3];
}

/// Balls {x, y, z, radius} [m] (any one frame) in an xy grid of 128 × 128 cells over their
/// bounding box. A ball is listed in each cell its xy box meets, or, when that would be more than
/// 256 cells and the lists already hold 2^22 entries, in each cell its xy box meets of a coarse
/// grid of 16 × 16 cells over the same box (the large balls: a stray's own search, and its
/// neighbours'; a query tests every large ball of its coarse cell, so the fine lists take as
/// many as the budget allows, largest first). A cell's list is kept in two parts, split at the
/// widest gap in z between its balls' z spans over the cell. A query reads a part of its cell's
/// list, and its coarse cell's list, only when the query's z lies in that part's or list's z
/// span over its cell (a stray's large ball above a surface lists the surface's cells, not its
/// points; a cell with both the surface's small balls and such a ball reads only one of them).
/// A ball inside another is left out. Memory: at most 2^22 entries plus 256 a ball, and 48
/// bytes a fine cell (768 KiB). Non-finite balls are refused by the caller. (Until 2026-11-24
/// the large balls were in one list every query read: at 10^8 points, hundreds of them for each
/// of the 274 M records a tiled run's second look read. Until 2026-11-28, forty-eighth session,
/// a fine list was one part: on the 10^8 wall the gathering's first pass tested some 76 M
/// records against both the surface's balls and the strays' behind it.)
class BallSet {
 public:
  using Ball = std::array<double, 4>;

  /// fine_budget: the entries the fine lists may hold before large balls go by coarse cell (the
  /// tests lower it to reach that path).
  explicit BallSet(const std::vector<Ball>& balls, std::size_t fine_budget = kFineBudget) {
    const double inf = std::numeric_limits<double>::infinity();
    box_ = {inf, -inf, inf, -inf};
    for (const Ball& b : balls) {
      box_ = {std::min(box_[0], b[0] - b[3]), std::max(box_[1], b[0] + b[3]), std::min(box_[2], b[1] - b[3]),
              std::max(box_[3], b[1] + b[3])};
    }
    if (balls.empty()) return;
    cell_ = std::max({(box_[1] - box_[0]) / kSide, (box_[3] - box_[2]) / kSide, 1e-9});
    inv_cell_ = 1.0 / cell_;
    at_.resize(static_cast<std::size_t>(kSide) * kSide);
    // Largest first; a ball inside one kept (with a margin over rounding) adds nothing to
    // contains, margin or meets and is left out: the balls of a stray's neighbours, and the same
    // ball asked by several strays, are often inside another.
    std::vector<std::uint32_t> order(balls.size());
    for (std::uint32_t i = 0; i < order.size(); ++i) order[i] = i;
    std::stable_sort(order.begin(), order.end(),
                     [&](std::uint32_t x, std::uint32_t y) { return balls[x][3] > balls[y][3]; });
    std::size_t listed = 0;  // entries in at_
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
      const auto cells = static_cast<std::size_t>(r1 - r0 + 1) * static_cast<std::size_t>(c1 - c0 + 1);
      if (cells > kMaxCellsPerBall && listed + cells > fine_budget) {
        if (coarse_.empty()) coarse_.resize(static_cast<std::size_t>(kCoarse) * kCoarse);
        for (int r = r0 / kPerCoarse; r <= r1 / kPerCoarse; ++r) {
          for (int c = c0 / kPerCoarse; c <= c1 / kPerCoarse; ++c) {
            coarse_[static_cast<std::size_t>(r) * kCoarse + static_cast<std::size_t>(c)].push_back(i);
          }
        }
        continue;
      }
      listed += cells;
      for (int r = r0; r <= r1; ++r) {
        for (int c = c0; c <= c1; ++c) at_[index(r, c)].push_back(i);
      }
    }
    // Each fine list in two parts by z over its cell (split_by_z), each with its z span, and
    // each coarse list's z span: a query's z outside a span skips that list (a stray's ball
    // above a surface covers the surface's cells in x-y but not its points' z; where a cell
    // holds both, the surface's small balls and the stray's large one are apart in z).
    fine_z_ = split_by_z(at_, fine_mid_);
    flatten(at_, fine_at_, fine_);
    for (std::size_t l = 0; l < at_.size(); ++l) fine_mid_[l] += fine_at_[l];
    flatten(coarse_, coarse_at_, coarse_flat_);
    coarse_z_.resize(coarse_.size());
    for (std::size_t l = 0; l < coarse_.size(); ++l) coarse_z_[l] = span_of_list(coarse_[l], l, kPerCoarse);
    std::vector<std::vector<std::uint32_t>>().swap(at_);
    std::vector<std::vector<std::uint32_t>>().swap(coarse_);
  }

  /// The balls kept (those inside another left out).
  std::size_t size() const { return balls_.size(); }
  const std::vector<Ball>& balls() const { return balls_; }

  bool empty() const { return balls_.empty(); }

  /// The fine cells whose list is in two non-empty parts (split_by_z): for the tests.
  std::size_t cells_split() const {
    std::size_t n = 0;
    for (std::size_t l = 0; l + 1 < fine_at_.size(); ++l) n += fine_mid_[l] > fine_at_[l] && fine_mid_[l] < fine_at_[l + 1] ? 1U : 0U;
    return n;
  }

  /// Whether p (x, y, z [m]) lies in one of the balls (distance at most the radius).
  bool contains(const double* p) const {
    if (!(p[0] >= box_[0] && p[0] <= box_[1] && p[1] >= box_[2] && p[1] <= box_[3])) return false;
    auto in = [&](std::uint32_t i) {
      const Ball& b = balls_[i];
      const double dx = p[0] - b[0], dy = p[1] - b[1], dz = p[2] - b[2];
      return dx * dx + dy * dy + dz * dz <= b[3] * b[3];
    };
    const int r = cell_of(p[1], 2), c = cell_of(p[0], 0);
    const std::size_t f = index(r, c);
    const auto& z = fine_z_[f];
    if (p[2] >= z[0] && p[2] <= z[1]) {
      for (std::size_t k = fine_at_[f]; k < fine_mid_[f]; ++k) {
        if (in(fine_[k])) return true;
      }
    }
    if (p[2] >= z[2] && p[2] <= z[3]) {
      for (std::size_t k = fine_mid_[f]; k < fine_at_[f + 1]; ++k) {
        if (in(fine_[k])) return true;
      }
    }
    if (coarse_flat_.empty()) return false;
    const std::size_t g = coarse_index(r, c);
    if (!(p[2] >= coarse_z_[g][0] && p[2] <= coarse_z_[g][1])) return false;
    for (std::size_t k = coarse_at_[g]; k < coarse_at_[g + 1]; ++k) {
      if (in(coarse_flat_[k])) return true;
    }
    return false;
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
    const std::size_t f = index(r, c);
    for (std::size_t k = fine_at_[f]; k < fine_at_[f + 1]; ++k) take(fine_[k]);
    if (!coarse_flat_.empty()) {
      const std::size_t g = coarse_index(r, c);
      for (std::size_t k = coarse_at_[g]; k < coarse_at_[g + 1]; ++k) take(coarse_flat_[k]);
    }
    return best;
  }

  /// Whether a ball's xy disk meets the xy box b {x_min, x_max, y_min, y_max} [m] (sides may be
  /// infinite).
  bool meets(const std::array<double, 4>& b) const {
    const double inf = std::numeric_limits<double>::infinity();
    return meets(std::array<double, 6>{b[0], b[1], b[2], b[3], -inf, inf});
  }

  /// Whether a ball meets the box b {x_min, x_max, y_min, y_max, z_min, z_max} [m] (sides may be
  /// infinite).
  bool meets(const std::array<double, 6>& b) const {
    return std::any_of(balls_.begin(), balls_.end(), [&](const Ball& s) { return ball_meets(s, b); });
  }

  /// The balls' xy bounding box {x_min, x_max, y_min, y_max} [m] (+inf, −inf when empty).
  const std::array<double, 4>& box_m() const { return box_; }

 private:
  static constexpr int kSide = 128;
  static constexpr int kCoarse = 16;
  static constexpr int kPerCoarse = kSide / kCoarse;  // cells per coarse cell, each way
  // A ball of more cells than this is listed by coarse cell once the fine lists hold kFineBudget
  // entries (16 MiB).
  static constexpr std::size_t kMaxCellsPerBall = 256;
  static constexpr std::size_t kFineBudget = std::size_t{1} << 22;
  // The cell of coordinate v along x (a = 0) or y (a = 2), clamped to the grid: non-decreasing
  // in v (a subtraction and a multiplication by a positive number), so a point in a ball's xy
  // box falls in a cell between those of the box's sides.
  int cell_of(double v, int a) const {
    const double c = (v - box_[static_cast<std::size_t>(a)]) * inv_cell_;
    return c < 0.0 ? 0 : c >= kSide - 1 ? kSide - 1 : static_cast<int>(c);
  }
  // Lists per cell as offsets (cells + 1) and one flat array.
  static void flatten(const std::vector<std::vector<std::uint32_t>>& lists, std::vector<std::size_t>& at,
                      std::vector<std::uint32_t>& flat) {
    at.assign(lists.size() + 1, 0);
    for (std::size_t i = 0; i < lists.size(); ++i) at[i + 1] = at[i] + lists[i].size();
    flat.clear();
    flat.reserve(at.back());
    for (const auto& l : lists) flat.insert(flat.end(), l.begin(), l.end());
  }
  static std::size_t index(int r, int c) { return static_cast<std::size_t>(r) * kSide + static_cast<std::size_t>(c); }
  // The z span {lo, hi} [m] of ball i over cell l's x-y rectangle (cell l of a side × side grid
  // of cells of `per` fine cells each way: the fine grid or the coarse one): every z of a point
  // in the ball that cell_of puts in the cell lies in it. The rectangle is widened by a
  // millionth of a fine cell and 1e-12 of its coordinates (cell_of's rounding), the grid's outer
  // cells to infinity (cell_of clamps), and the span by a millionth of the radius and 1e-12 of
  // the centre's z and radius (the rounding of contains' squared distance, whose error is a few
  // units in the last place of R², so of √(1e-15)·R in z).
  std::array<double, 2> span_of(std::uint32_t i, std::size_t l, int per) const {
    const double inf = std::numeric_limits<double>::infinity();
    const int side = kSide / per;
    const auto sides = [&](int k, int a) {
      const double lo = box_[static_cast<std::size_t>(a)] + static_cast<double>(k * per) * cell_;
      const double hi = box_[static_cast<std::size_t>(a)] + static_cast<double>((k + 1) * per) * cell_;
      const double pad = 1e-6 * cell_ + 1e-12 * (std::abs(lo) + std::abs(hi));
      return std::array<double, 2>{k == 0 ? -inf : lo - pad, k == side - 1 ? inf : hi + pad};
    };
    const auto ys = sides(static_cast<int>(l) / side, 2), xs = sides(static_cast<int>(l) % side, 0);
    const Ball& b = balls_[i];
    const double dx = std::max({xs[0] - b[0], b[0] - xs[1], 0.0}), dy = std::max({ys[0] - b[1], b[1] - ys[1], 0.0});
    const double half = std::sqrt(std::max(0.0, b[3] * b[3] - (dx * dx + dy * dy)));
    const double pad = 1e-6 * b[3] + 1e-12 * (std::abs(b[2]) + b[3]);
    return {b[2] - half - pad, b[2] + half + pad};
  }
  // The z span of a whole list (cell l's), {+inf, −inf} when it is empty.
  std::array<double, 2> span_of_list(const std::vector<std::uint32_t>& list, std::size_t l, int per) const {
    const double inf = std::numeric_limits<double>::infinity();
    std::array<double, 2> z{inf, -inf};
    for (const std::uint32_t i : list) {
      const auto s = span_of(i, l, per);
      z = {std::min(z[0], s[0]), std::max(z[1], s[1])};
    }
    return z;
  }
  // Each fine list reordered into two parts split at the widest gap in z between its balls'
  // spans over the cell (span_of; no gap: the second part empty). Returns per list the parts'
  // spans {lo0, hi0, lo1, hi1} ({+inf, −inf} for an empty part); `mid` gets the second part's
  // start in the list. The union of the two spans holds every ball's span, so a query whose z
  // lies in neither skips the list, and otherwise reads only the part whose span holds it.
  std::vector<std::array<double, 4>> split_by_z(std::vector<std::vector<std::uint32_t>>& lists, std::vector<std::size_t>& mid) const {
    const double inf = std::numeric_limits<double>::infinity();
    std::vector<std::array<double, 4>> z(lists.size(), std::array<double, 4>{inf, -inf, inf, -inf});
    mid.assign(lists.size(), 0);
    std::vector<std::pair<std::array<double, 2>, std::uint32_t>> spans;
    for (std::size_t l = 0; l < lists.size(); ++l) {
      auto& list = lists[l];
      if (list.empty()) continue;
      spans.clear();
      for (const std::uint32_t i : list) spans.push_back({span_of(i, l, 1), i});
      std::sort(spans.begin(), spans.end());  // by lo, then hi, then ball: the same order every time
      // The widest gap between the running top of the spans so far and the next span's bottom.
      double top = spans[0].first[1], best_gap = 0.0;
      std::size_t cut = spans.size();  // the second part's first span
      for (std::size_t k = 1; k < spans.size(); ++k) {
        const double gap = spans[k].first[0] - top;
        if (gap > best_gap) {
          best_gap = gap;
          cut = k;
        }
        top = std::max(top, spans[k].first[1]);
      }
      for (std::size_t k = 0; k < spans.size(); ++k) {
        list[k] = spans[k].second;
        const std::size_t part = k < cut ? 0 : 2;
        z[l][part] = std::min(z[l][part], spans[k].first[0]);
        z[l][part + 1] = std::max(z[l][part + 1], spans[k].first[1]);
      }
      mid[l] = cut;
    }
    return z;
  }
  // The coarse cell of cell (r, c).
  static std::size_t coarse_index(int r, int c) {
    return static_cast<std::size_t>(r / kPerCoarse) * kCoarse + static_cast<std::size_t>(c / kPerCoarse);
  }

  std::vector<Ball> balls_;
  std::array<double, 4> box_{};
  double cell_ = 1.0;
  double inv_cell_ = 1.0;
  // The balls by cell, and the large ones by coarse cell, while the constructor adds them.
  std::vector<std::vector<std::uint32_t>> at_, coarse_;
  // The same lists flattened (queries read these): cell i's balls are fine_[fine_at_[i]] ..
  // fine_[fine_at_[i + 1] - 1], its second part (split_by_z) from fine_[fine_mid_[i]];
  // coarse_flat_ empty when no ball is large.
  std::vector<std::size_t> fine_at_, fine_mid_, coarse_at_;
  std::vector<std::uint32_t> fine_, coarse_flat_;
  // Per fine cell its two parts' z spans {lo0, hi0, lo1, hi1} (split_by_z), per coarse cell its
  // list's z span (span_of_list): a query outside a span skips that list.
  std::vector<std::array<double, 4>> fine_z_;
  std::vector<std::array<double, 2>> coarse_z_;
};

}  // namespace hc::pipeline::detail
