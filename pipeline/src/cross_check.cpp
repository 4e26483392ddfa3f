// Stage 7: cross-check of the bilinear surface against the input points.
//
// (a) Points → surface. Every finite point inside the grid's x-y extent is evaluated against the
//     bilinear surface f: vertical residual |z − f| and normal distance |z − f|·n_z with
//     n_z = 1/√(1 + f_x² + f_y²) (exact for a locally planar f). A Monge surface seen along −z
//     only represents what is visible: a point more than hidden_band_m BELOW f is hidden behind
//     the surface (the back of a statue, the inside of an overhang) and is counted as hidden,
//     not as an error. Points above f always count: they reveal surface the grid lost (for
//     example a front surface replaced by a see-through cell). Points whose bilinear cell has a
//     no-data corner are counted as off-surface.
// (b) Grid → points. Every valid sample (x_c, y_r, z) is a 3-D query for its nearest input
//     point; the distance is the per-cell error map, and a cell is "supported" when it is within
//     tolerance_m. Invented surface (over-filled holes) shows up here.
//
// (b) is an exact nearest-neighbour search over ALL finite input points, organised for speed:
//   * Buckets. The points are counting-sorted by their nearest grid node (clamped to the grid;
//     a point outside the grid lands in a border cell, which only makes it look nearer than it
//     is, so no bound below is ever violated). Each cell keeps its points' z range.
//   * Query of the sample at node (r, c): scan the node's own bucket, then the buckets ring by
//     ring around (r, c), skipping every cell whose square (horizontally) and z range
//     (vertically) cannot beat the current best, and stop at the first ring whose nearest edge
//     is farther than the best. A search that would go beyond kRingsNearLimit rings (a sample
//     far from every point, e.g. a hole filled across a depth step) is deferred.
//   * Deferred samples (nanoflann kd-trees). A deferred sample with no point found yet gets a
//     bound from kd-trees over the front-most point of every non-empty bucket. Then the
//     deferred searches are finished by rings when that is cheap in total, else through
//     kd-trees over all points (one per half of the rows, built in parallel). The result is
//     always the exact nearest point over all points.
//     On a grid made from the points the trees are rarely needed: measured on the Buddha, the
//     buckets answer all of (b) in less time than nanoflann 1.4 needs to build a kd-tree over
//     the 1.1 M points (about 0.1 s of CPU per 0.55 M points).
//   * Two threads (std::thread), in phases: (1) each thread takes half of the points, runs
//     (a) on them and finds their buckets; (2) each scatters its points into the shared bucket
//     array (a two-thread counting sort); (3) the rows are split where both halves hold about
//     half of the valid cells, and each thread summarises the buckets of its rows; (4) each thread
//     answers the queries of its rows in grid order; (5) deferred far samples, if any (a
//     thread's trees hold its rows' points; the other half's tree is searched only when the
//     search sphere crosses the split). The statistics then run on both threads.
//   * Float in a local frame centred on the grid, so float keeps ~1e-7 relative precision even
//     for coordinates far from the origin. nanoflann's squared distances never leave this file.

#include "run_internal.hpp"
#include "stage_util.hpp"
#include "hc/pipeline/cross_check.hpp"

#include "hc/common/bilinear_surface.hpp"
#include "hc/common/error.hpp"

#include <nanoflann.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <exception>
#include <limits>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <thread>
#include <utility>

namespace hc::pipeline {

namespace {

using detail::run_two;

/// nanoflann dataset adaptor over packed float xyz triples, owned or viewed.
struct PackedPoints {
  std::vector<float> owned;
  const float* xyz = nullptr;
  std::size_t count = 0;
  std::size_t kdtree_get_point_count() const { return count; }
  float kdtree_get_pt(std::size_t i, std::size_t dim) const { return xyz[3 * i + dim]; }
  template <class BBox>
  bool kdtree_get_bbox(BBox& /*bb*/) const {
    return false;
  }
};

/// nanoflann result set keeping the single nearest point closer than an initial bound.
/// nanoflann works in SQUARED distances; this class never leaves this file.
class NearestWithinSq {
 public:
  using DistanceType = float;
  using IndexType = std::uint32_t;
  using CountType = std::size_t;

  explicit NearestWithinSq(float bound_sq) : best_sq_(bound_sq) {}
  bool addPoint(float dist_sq, std::uint32_t index) {
    if (dist_sq < best_sq_) {
      best_sq_ = dist_sq;
      index_ = index;
      found_ = true;
    }
    return true;
  }
  float worstDist() const { return best_sq_; }
  bool full() const { return found_; }
  float best_sq() const { return best_sq_; }

 private:
  float best_sq_;
  std::uint32_t index_ = 0;
  bool found_ = false;
};

/// Exact nearest-point distance in metres over a fixed set of points (kd-tree, nanoflann).
/// Build: O(n log n). Query: thread-safe (const), no allocation.
class NearestPointIndex {
 public:
  /// Over points it owns (3·n floats).
  explicit NearestPointIndex(std::vector<float> xyz) {
    points_.owned = std::move(xyz);
    points_.xyz = points_.owned.data();
    points_.count = points_.owned.size() / 3;
    build();
  }
  /// Over n points viewed at xyz (3·n floats), which must outlive the index.
  NearestPointIndex(const float* xyz, std::size_t n) {
    points_.xyz = xyz;
    points_.count = n;
    build();
  }
  NearestPointIndex(const NearestPointIndex&) = delete;
  NearestPointIndex& operator=(const NearestPointIndex&) = delete;
  std::size_t size() const { return points_.count; }

  /// Distance [m] from q to its nearest point, or bound_m when no point is strictly closer.
  double nearest_distance_m(const float q[3], double bound_m) const {
    const auto bound_sq = static_cast<float>(bound_m * bound_m);
    if (!tree_) return bound_m;
    NearestWithinSq result(bound_sq);
    tree_->findNeighbors(result, q, nanoflann::SearchParams());
    return result.full() ? std::sqrt(static_cast<double>(result.best_sq())) : bound_m;
  }

 private:
  void build() {
    if (points_.count > 0) {
      tree_ = std::make_unique<Tree>(3, points_, nanoflann::KDTreeSingleIndexAdaptorParams(kLeafSize));
    }
  }
  static constexpr std::size_t kLeafSize = 16;
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, PackedPoints>,
                                                   PackedPoints, 3, std::uint32_t>;
  PackedPoints points_;
  std::unique_ptr<Tree> tree_;
};

template <class T>
ErrorStats stats_of(std::vector<T>& v) {
  ErrorStats s;
  s.count = v.size();
  if (v.empty()) return s;
  double sum_sq = 0.0;
  for (T& x : v) {
    if (!std::isfinite(x)) {
      std::ostringstream msg;
      msg << "error_stats_mm: a value is " << x << " (expected finite errors)";
      throw InputError(msg.str());
    }
    x = std::abs(x);
    sum_sq += static_cast<double>(x) * static_cast<double>(x);
  }
  const std::size_t n = v.size();
  auto rank = [n](double q) {
    const auto k = static_cast<std::size_t>(std::ceil(q * static_cast<double>(n)));
    return std::clamp<std::size_t>(k, 1, n) - 1;
  };
  // Successive selections, each on the upper part left by the previous one: O(n) in total.
  // (Each selection reorders its range, so a value is read right after its own selection.)
  auto select = [&v](std::size_t from, std::size_t k) {
    std::nth_element(v.begin() + static_cast<std::ptrdiff_t>(from), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
    return static_cast<double>(v[k]) * 1e3;
  };
  const std::size_t k50 = rank(0.50), k95 = rank(0.95), k99 = rank(0.99);
  s.p50_mm = select(0, k50);
  s.p95_mm = select(k50, k95);
  s.p99_mm = select(k95, k99);
  s.max_mm = static_cast<double>(*std::max_element(v.begin() + static_cast<std::ptrdiff_t>(k99), v.end())) * 1e3;
  s.rms_mm = std::sqrt(sum_sq / static_cast<double>(n)) * 1e3;
  return s;
}

/// What one of the two threads builds and computes. Thread h handles the points with index in
/// [point_begin, point_end) for (a) and bucketing, and the rows [row_begin, row_end) for the
/// kd-tree and the queries of (b).
struct Part {
  std::size_t point_begin = 0, point_end = 0;
  int row_begin = 0, row_end = 0;
  std::vector<std::uint32_t> count;          ///< per cell: points of this part (then offsets)
  std::vector<float> front_xyz;              ///< its rows' front-most point of each bucket
  std::unique_ptr<NearestPointIndex> front;  ///< kd-tree over front_xyz (only if needed)
  std::vector<float> vertical_m, normal_m;   ///< (a)
  std::size_t on_surface = 0, off_surface = 0, hidden = 0, outside = 0, finite = 0;
  std::vector<float> cell_m;                 ///< (b), in grid order
  std::size_t supported = 0;
  /// Samples whose search reaches beyond kRingsNearLimit rings: finished after phase 4.
  struct Far {
    int row, col;
    float best_sq;      ///< upper bound so far (squared, local frame)
    std::size_t slot;   ///< index in cell_m
  };
  std::vector<Far> far;
  std::unique_ptr<NearestPointIndex> all;  ///< kd-tree over all its rows' points (far samples)
};

/// Per bucket, packed for the queries (one cache line holds four cells): point range in
/// Run::sorted and z range.
struct Bucket {
  std::uint32_t begin, end;
  float z_lo, z_hi;
};

/// Beyond this many rings a sample's search is deferred to phase 5 [cells].
constexpr int kRingsNearLimit = 16;
/// Phase 5 finishes the deferred searches by rings if they visit fewer cells than this in
/// total, else it builds kd-trees over all points (≈ 0.2 µs per point and thread).
constexpr double kFarRingCellBudget = 2e7;
/// key of a non-finite point.
constexpr std::uint32_t kSkip = std::numeric_limits<std::uint32_t>::max();

/// The inputs and the state shared by the phases of one cross_check run.
struct Run {
  const Cloud& points_m;
  const HeightField& grid;
  const GridGeometry& g;
  double tolerance_m, hidden_band_m;
  CrossCheck& cc;  ///< the result being filled
  std::size_t ucols = 0, cells = 0, n_points = 0;
  std::size_t valid_total = 0;  ///< valid samples of the grid that are searched (inside the query box)
  /// The samples searched: rows [q_r0, q_r1), columns [q_c0, q_c1) (the whole grid by default).
  int q_r0 = 0, q_r1 = 0, q_c0 = 0, q_c1 = 0;
  /// Local frame of the float coordinates: centred on the grid (x, y) and on the middle of its
  /// height range (z), so that float keeps ~1e-9 relative precision even for coordinates far
  /// from the origin.
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  int split_row = 1;    ///< rows [0, split_row) belong to the lower half
  double y_split = 0;   ///< y of the boundary between the halves [m]
  BilinearSurface surface;
  bool point_residuals = true;  ///< (a) too; false: (b) only (cross_check_cell_errors)
  const detail::CellErrorFrame* frame = nullptr;  ///< a larger grid's frame and positions (cross_check_cell_errors)
  Part parts[2];
  std::vector<std::uint32_t> key;    ///< cell of each point, kSkip if not finite
  std::vector<std::uint32_t> first;  ///< bucket k = sorted points [first[k], first[k+1])
  std::vector<float> sorted;         ///< xyz, local frame, sorted by cell
  std::vector<Bucket> buckets;

  Run(const Cloud& points, const HeightField& grid_m, double tolerance, double hidden_band, CrossCheck& out)
      : points_m(points), grid(grid_m), g(grid_m.geometry()), tolerance_m(tolerance), hidden_band_m(hidden_band),
        cc(out), surface(HeightFieldView::of(grid_m)) {}
};

/// Runs f(run, 1) on a second thread and f(run, 0) on this one.
template <class F>
void on_both_halves(Run& run, F f) {
  run_two([&] { f(run, 1); }, [&] { f(run, 0); });
}

/// The argument checks that need no pass over the data.
void check_arguments(const Cloud& points_m, const HeightField& grid, double tolerance_m, double hidden_band_m) {
  std::ostringstream msg;
  if (!(tolerance_m > 0.0) || !std::isfinite(tolerance_m)) {
    msg << "cross_check: tolerance_m = " << tolerance_m << " (expected a finite distance > 0)";
    throw ConfigError(msg.str());
  }
  if (!(hidden_band_m > 0.0)) {
    msg << "cross_check: hidden_band_m = " << hidden_band_m << " (expected a distance > 0)";
    throw ConfigError(msg.str());
  }
  const GridGeometry& g = grid.geometry();
  if (g.rows < 2 || g.cols < 2) {
    msg << "cross_check: the grid is " << g.cols << " x " << g.rows
        << " samples (a bilinear surface needs at least 2 x 2)";
    throw InputError(msg.str());
  }
  if (points_m.size() == 0) throw InputError("cross_check: the point cloud is empty");
}

/// Sizes, the local frame, and the split of the rows so that both threads get about half of
/// the valid cells (and half of the points each).
void plan(Run& run) {
  const GridGeometry& g = run.g;
  std::ostringstream msg;
  run.ucols = static_cast<std::size_t>(g.cols);
  std::vector<std::size_t> valid_in_row(static_cast<std::size_t>(g.rows), 0);
  std::size_t valid_anywhere = 0;
  for (int r = 0; r < g.rows; ++r) {
    const float* row = run.grid.data() + static_cast<std::size_t>(r) * run.ucols;
    std::size_t n = 0, searched = 0;
    for (int c = 0; c < g.cols; ++c) {
      const bool valid = !std::isnan(row[c]);
      n += valid ? 1U : 0U;
      searched += valid && r >= run.q_r0 && r < run.q_r1 && c >= run.q_c0 && c < run.q_c1 ? 1U : 0U;
    }
    valid_in_row[static_cast<std::size_t>(r)] = searched;
    run.valid_total += searched;
    valid_anywhere += n;
  }
  if (valid_anywhere == 0) {
    msg << "cross_check: the " << g.cols << " x " << g.rows << " grid has no valid cell";
    throw InputError(msg.str());
  }
  run.centre = run.frame ? run.frame->centre : detail::cross_check_frame_centre(run.grid);
  std::size_t acc = 0;
  for (int r = 0; r < g.rows; ++r) {
    acc += valid_in_row[static_cast<std::size_t>(r)];
    if (2 * acc >= run.valid_total && run.valid_total > 0) {
      run.split_row = std::clamp(r + 1, 1, g.rows - 1);
      break;
    }
  }
  run.y_split = g.y_of_row(run.split_row - 0.5);

  run.cells = g.cell_count();
  run.n_points = run.points_m.size();
  if (run.n_points >= std::numeric_limits<std::uint32_t>::max() / 2) {
    msg << "cross_check: " << run.n_points << " points is more than this cross-check indexes (2^31)";
    throw ResourceError(msg.str());
  }
  for (int h = 0; h < 2; ++h) {
    Part& part = run.parts[h];
    part.point_begin = h == 0 ? 0 : run.n_points / 2;
    part.point_end = h == 0 ? run.n_points / 2 : run.n_points;
    part.row_begin = h == 0 ? 0 : run.split_row;
    part.row_end = h == 0 ? run.split_row : g.rows;
  }
  run.key.resize(run.n_points);
  run.first.resize(run.cells + 1);
  run.buckets.resize(run.cells);
}

/// Phase 1 (per half of the points): (a) against f, and each point's bucket.
void phase1_residuals_and_keys(Run& run, int h) {
  const GridGeometry& g = run.g;
  const double inv_cell = 1.0 / g.cell_size_m;
  const int split_row = run.split_row;
  Part& out = run.parts[h];
  out.count.assign(run.cells, 0);
  const double* p = run.points_m.xyz.data() + 3 * out.point_begin;
  // Points in input order fall on random cells: with (a), each one's two grid rows are fetched
  // kAhead points before its residual (BilinearSurface::prefetch).
  constexpr std::size_t kAhead = 8;
  for (std::size_t i = out.point_begin; i < out.point_end; ++i, p += 3) {
    if (run.point_residuals && i + kAhead < out.point_end) run.surface.prefetch(p[3 * kAhead], p[3 * kAhead + 1]);
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) {
      run.key[i] = kSkip;
      continue;
    }
    const int c = std::clamp(static_cast<int>(detail::floor_of((p[0] - g.x0_m) * inv_cell + 0.5)), 0, g.cols - 1);
    // Rows follow the exact y split, so that each thread's rows hold exactly its tree's points.
    const int r = p[1] < run.y_split
                      ? std::clamp(static_cast<int>(detail::floor_of((p[1] - g.y0_m) * inv_cell + 0.5)), 0, split_row - 1)
                      : std::clamp(static_cast<int>(detail::floor_of((p[1] - g.y0_m) * inv_cell + 0.5)), split_row, g.rows - 1);
    const auto k = static_cast<std::uint32_t>(static_cast<std::size_t>(r) * run.ucols + static_cast<std::size_t>(c));
    run.key[i] = k;
    ++out.count[k];
    ++out.finite;
    if (!run.point_residuals) continue;
    const PointResidual pr = point_residual(run.surface, g, p[0], p[1], p[2], run.hidden_band_m);
    switch (pr.kind) {
      case PointResidual::kOutside: ++out.outside; break;
      case PointResidual::kOffSurface: ++out.off_surface; break;
      case PointResidual::kHidden: ++out.hidden; break;
      case PointResidual::kOnSurface:
        ++out.on_surface;
        out.vertical_m.push_back(pr.vertical_m);
        out.normal_m.push_back(pr.normal_m);
        break;
    }
  }
}

/// Bucket offsets (counting sort): within a bucket, part 0's points come before part 1's.
void bucket_offsets(Run& run) {
  if (run.parts[0].finite + run.parts[1].finite == 0) {
    std::ostringstream msg;
    msg << "cross_check: none of the " << run.n_points << " points is finite";
    throw InputError(msg.str());
  }
  std::uint32_t running = 0;
  for (std::size_t k = 0; k < run.cells; ++k) {
    run.first[k] = running;
    const std::uint32_t n0 = run.parts[0].count[k], n1 = run.parts[1].count[k];
    run.parts[0].count[k] = running;
    run.parts[1].count[k] = running + n0;
    running += n0 + n1;
  }
  run.first[run.cells] = running;
  run.sorted.resize(3 * static_cast<std::size_t>(running));
}

/// Phase 2 (per half of the points): scatter into the buckets (float, local frame).
void phase2_scatter(Run& run, int h) {
  Part& out = run.parts[h];
  const double* p = run.points_m.xyz.data() + 3 * out.point_begin;
  for (std::size_t i = out.point_begin; i < out.point_end; ++i, p += 3) {
    if (run.key[i] == kSkip) continue;
    float* dst = &run.sorted[3 * static_cast<std::size_t>(out.count[run.key[i]]++)];
    dst[0] = static_cast<float>(p[0] - run.centre.x());
    dst[1] = static_cast<float>(p[1] - run.centre.y());
    dst[2] = static_cast<float>(p[2] - run.centre.z());
  }
  std::vector<std::uint32_t>().swap(out.count);
}

/// Phase 3 (per half of the rows): z range and front-most point of each bucket.
void phase3_bucket_summaries(Run& run, int h) {
  Part& out = run.parts[h];
  std::vector<float>& front = out.front_xyz;
  const std::vector<float>& sorted = run.sorted;
  const std::size_t k_end = static_cast<std::size_t>(out.row_end) * run.ucols;
  for (std::size_t k = static_cast<std::size_t>(out.row_begin) * run.ucols; k < k_end; ++k) {
    const std::uint32_t b = run.first[k], e = run.first[k + 1];
    run.buckets[k] = Bucket{b, e, 0.0f, 0.0f};
    if (b == e) continue;
    std::uint32_t top = b;
    float lo = sorted[3 * b + 2], hi = lo;
    for (std::uint32_t j = b + 1; j < e; ++j) {
      const float z = sorted[3 * j + 2];
      lo = std::min(lo, z);
      if (z > hi) {
        hi = z;
        top = j;
      }
    }
    run.buckets[k].z_lo = lo;
    run.buckets[k].z_hi = hi;
    front.insert(front.end(), &sorted[3 * top], &sorted[3 * top] + 3);
  }
}

/// Best squared distance from q to the points of bucket k, folded into best_sq.
void scan(const Run& run, std::size_t k, const float* q, float& best_sq) {
  const float* pt = run.sorted.data();
  for (std::uint32_t j = run.buckets[k].begin, e = run.buckets[k].end; j < e; ++j) {
    const float dx = pt[3 * j] - q[0], dy = pt[3 * j + 1] - q[1], dz = pt[3 * j + 2] - q[2];
    best_sq = std::min(best_sq, dx * dx + dy * dy + dz * dz);
  }
}

/// Scans the rings k_from, k_from + 1, ... of cells around (r, c) (ring k's nearest edge is
/// (k − ½) cells away), skipping cells whose square and z range cannot beat best_sq. Returns
/// true when the search is complete, false if it stopped after ring k_to.
bool search_rings(const Run& run, int r, int c, const float* q, float& best_sq, int k_from, int k_to) {
  const GridGeometry& g = run.g;
  const auto cell_f = static_cast<float>(g.cell_size_m);
  for (int k = k_from;; ++k) {
    const float gap = (static_cast<float>(k) - 0.5f) * cell_f;
    if (gap * gap >= best_sq || (k > r && k > c && r + k >= g.rows && c + k >= g.cols)) return true;
    if (k > k_to) return false;
    for (int dr = -k; dr <= k; ++dr) {
      const int rr = r + dr;
      if (rr < 0 || rr >= g.rows) continue;
      const float hy = std::max(0.0f, (static_cast<float>(std::abs(dr)) - 0.5f) * cell_f);
      const int step = (dr == -k || dr == k) ? 1 : 2 * k;  // full edge rows, else two cells
      for (int dc = -k; dc <= k; dc += step) {
        const int c2 = c + dc;
        if (c2 < 0 || c2 >= g.cols) continue;
        const std::size_t kc = static_cast<std::size_t>(rr) * run.ucols + static_cast<std::size_t>(c2);
        const Bucket& bk = run.buckets[kc];
        if (bk.begin == bk.end) continue;
        const float hx = std::max(0.0f, (static_cast<float>(std::abs(dc)) - 0.5f) * cell_f);
        const float vz = std::max({0.0f, bk.z_lo - q[2], q[2] - bk.z_hi});
        if (hx * hx + hy * hy + vz * vz >= best_sq) continue;
        scan(run, kc, q, best_sq);
      }
    }
  }
}

/// The sample at (r, c) in the local frame.
void query_point(const Run& run, int r, int c, float* q) {
  const double x = run.frame ? run.frame->whole.x_of_col(run.frame->col0 + c) : run.g.x_of_col(c);
  const double y = run.frame ? run.frame->whole.y_of_row(run.frame->row0 + r) : run.g.y_of_row(r);
  q[0] = static_cast<float>(x - run.centre.x());
  q[1] = static_cast<float>(y - run.centre.y());
  q[2] = static_cast<float>(static_cast<double>(run.grid.at(r, c)) - run.centre.z());
}

/// Stores the distance of the sample at (r, c) (error map and the part's list, at `slot`).
void record(Run& run, Part& out, int r, int c, std::size_t slot, float best_sq) {
  const float d = detail::cross_check_recorded_distance(best_sq);
  run.cc.cell_error_m.at(r, c) = d;
  out.cell_m[slot] = d;
  // Supported by the map's own value (float), as a tiled run counts from its merged map and a
  // reader of the scene's cell_error layer would; until 2026-11-30 the double before rounding,
  // so a distance within a float step of the tolerance could count otherwise.
  out.supported += static_cast<double>(d) <= run.tolerance_m ? 1U : 0U;
}

/// Phase 4 (per half of the rows): exact nearest input point of every valid sample inside the
/// query box, by rings up to kRingsNearLimit; farther searches are deferred to phase 5 (Part::far).
void phase4_near_queries(Run& run, int h) {
  Part& out = run.parts[h];
  out.cell_m.reserve(run.valid_total / 2 + 1);
  for (int r = std::max(out.row_begin, run.q_r0); r < std::min(out.row_end, run.q_r1); ++r) {
    const float* row = run.grid.data() + static_cast<std::size_t>(r) * run.ucols;
    for (int c = run.q_c0; c < run.q_c1; ++c) {
      if (std::isnan(row[c])) continue;
      float q[3];
      query_point(run, r, c, q);
      const std::size_t slot = out.cell_m.size();
      out.cell_m.push_back(0.0f);
      float best_sq = std::numeric_limits<float>::infinity();
      scan(run, static_cast<std::size_t>(r) * run.ucols + static_cast<std::size_t>(c), q, best_sq);
      if (!search_rings(run, r, c, q, best_sq, 1, kRingsNearLimit)) {
        out.far.push_back({r, c, best_sq, slot});
        continue;
      }
      record(run, out, r, c, slot, best_sq);
    }
  }
}

/// Deferred samples: how many, and how many went through the kd-trees over all points.
struct FarCounts {
  std::size_t total = 0, by_tree = 0;
};

/// Phase 5 (only if some sample is farther than kRingsNearLimit cells from every point; e.g. a
/// hole filled across a depth step). A deferred sample without any point found yet first gets
/// a bound from kd-trees over the buckets' front-most points. Then the deferred searches are
/// finished by rings if that is cheap in total, else through kd-trees over all points (each
/// thread: its rows' slice of the bucket array). Trees are built in parallel, one per thread.
FarCounts phase5_far_queries(Run& run) {
  const GridGeometry& g = run.g;
  Part* parts = run.parts;
  FarCounts counts;
  counts.total = parts[0].far.size() + parts[1].far.size();
  if (counts.total == 0) return counts;
  bool unbounded = false;
  for (int h = 0; h < 2; ++h) {
    for (const auto& f : parts[h].far) unbounded |= std::isinf(f.best_sq);
  }
  auto tree_bound = [&](int h, float* q, int row, float best_sq, bool full) {
    const NearestPointIndex& own = full ? *parts[h].all : *parts[h].front;
    const NearestPointIndex& other = full ? *parts[1 - h].all : *parts[1 - h].front;
    const double dy_split = g.y_of_row(row) - run.y_split;
    double d = std::sqrt(static_cast<double>(best_sq));
    d = own.nearest_distance_m(q, d);
    if (dy_split * dy_split < d * d) d = other.nearest_distance_m(q, d);
    return std::min(best_sq, static_cast<float>(d * d));
  };
  if (unbounded) {
    run_two([&] { parts[1].front = std::make_unique<NearestPointIndex>(std::move(parts[1].front_xyz)); },
            [&] { parts[0].front = std::make_unique<NearestPointIndex>(std::move(parts[0].front_xyz)); });
    auto bound = [&](int h) {
      for (auto& f : parts[h].far) {
        if (!std::isinf(f.best_sq)) continue;
        float q[3];
        query_point(run, f.row, f.col, q);
        f.best_sq = tree_bound(h, q, f.row, f.best_sq, false);
      }
    };
    run_two([&] { bound(1); }, [&] { bound(0); });
  }
  double ring_cells = 0.0;
  for (int h = 0; h < 2; ++h) {
    for (const auto& f : parts[h].far) {
      const double rings = std::sqrt(static_cast<double>(f.best_sq)) / g.cell_size_m + 1.0;
      ring_cells += 4.0 * rings * rings;
    }
  }
  const bool by_tree = ring_cells > kFarRingCellBudget;
  auto finish = [&](int h) {
    Part& out = parts[h];
    for (const auto& f : out.far) {
      float q[3];
      query_point(run, f.row, f.col, q);
      float best_sq = f.best_sq;
      if (by_tree) {
        best_sq = tree_bound(h, q, f.row, best_sq, true);
      } else {
        search_rings(run, f.row, f.col, q, best_sq, 1, std::numeric_limits<int>::max());
      }
      record(run, out, f.row, f.col, f.slot, best_sq);
    }
  };
  if (by_tree) {
    auto build_all = [&](int h) {
      const std::size_t b = run.first[static_cast<std::size_t>(parts[h].row_begin) * run.ucols];
      const std::size_t e = run.first[static_cast<std::size_t>(parts[h].row_end) * run.ucols];
      parts[h].all = std::make_unique<NearestPointIndex>(run.sorted.data() + 3 * b, e - b);
    };
    run_two([&] { build_all(1); }, [&] { build_all(0); });
    counts.by_tree = counts.total;
  }
  run_two([&] { finish(1); }, [&] { finish(0); });
  return counts;
}

/// The three distributions' statistics (two threads) and the counts of the result.
void summarise(Run& run) {
  Part* parts = run.parts;
  CrossCheck& cc = run.cc;
  auto concat = [](std::vector<float>& a, std::vector<float>& b) {
    a.insert(a.end(), b.begin(), b.end());
    std::vector<float>().swap(b);
    return std::move(a);
  };
  std::vector<float> vertical = concat(parts[0].vertical_m, parts[1].vertical_m);
  std::vector<float> normal = concat(parts[0].normal_m, parts[1].normal_m);
  std::vector<float> cell_dist = concat(parts[0].cell_m, parts[1].cell_m);
  run_two([&] { cc.point_vertical = stats_of(vertical); },
          [&] {
            cc.point_normal = stats_of(normal);
            cc.cell_to_point = stats_of(cell_dist);
          });

  cc.points_on_surface = parts[0].on_surface + parts[1].on_surface;
  cc.points_off_surface = parts[0].off_surface + parts[1].off_surface;
  cc.points_hidden = parts[0].hidden + parts[1].hidden;
  cc.points_outside = parts[0].outside + parts[1].outside;
  cc.hidden_band_m = run.hidden_band_m;
  cc.tolerance_m = run.tolerance_m;
  cc.supported_fraction = run.valid_total == 0 ? 0.0
                                              : static_cast<double>(parts[0].supported + parts[1].supported) /
                                                    static_cast<double>(run.valid_total);
}

/// The stage report: every figure of the result plus the search's own counts.
void fill_report(const Run& run, const FarCounts& far, StageReport& rep) {
  const CrossCheck& cc = run.cc;
  const Part* parts = run.parts;
  rep.stage = "cross_check";
  rep.count_in = run.points_m.size();
  rep.count_out = run.valid_total;
  add_error_stats_figures(rep, "point_vertical", cc.point_vertical);
  add_error_stats_figures(rep, "point_normal", cc.point_normal);
  add_error_stats_figures(rep, "cell_to_point", cc.cell_to_point);
  rep.figure("points_on_surface", static_cast<double>(cc.points_on_surface));
  rep.figure("points_off_surface", static_cast<double>(cc.points_off_surface));
  rep.figure("points_hidden", static_cast<double>(cc.points_hidden));
  rep.figure("points_outside", static_cast<double>(cc.points_outside));
  rep.figure("hidden_band_mm", run.hidden_band_m * 1e3);
  rep.figure("tolerance_mm", run.tolerance_m * 1e3);
  rep.figure("supported_fraction", cc.supported_fraction);
  rep.figure("samples_far", static_cast<double>(far.total));
  rep.figure("samples_far_by_full_tree", static_cast<double>(far.by_tree));
  rep.figure("kd_tree_points_built",
             static_cast<double>((parts[0].front ? parts[0].front->size() : 0) +
                                 (parts[1].front ? parts[1].front->size() : 0) +
                                 (parts[0].all ? parts[0].all->size() : 0) +
                                 (parts[1].all ? parts[1].all->size() : 0)));
}

}  // namespace

ErrorStats error_stats_mm(std::vector<double> abs_errors_m) { return stats_of(abs_errors_m); }
ErrorStats error_stats_mm_of_floats(std::vector<float> abs_errors_m) { return stats_of(abs_errors_m); }

void add_error_stats_figures(StageReport& report, const std::string& prefix, const ErrorStats& s) {
  report.figure(prefix + "_count", static_cast<double>(s.count));
  report.figure(prefix + "_rms_mm", s.rms_mm);
  report.figure(prefix + "_p50_mm", s.p50_mm);
  report.figure(prefix + "_p95_mm", s.p95_mm);
  report.figure(prefix + "_p99_mm", s.p99_mm);
  report.figure(prefix + "_max_mm", s.max_mm);
}

double supported_fraction(const Cloud& points_m, const HeightField& grid, double tolerance_m) {
  if (!(tolerance_m > 0.0) || !std::isfinite(tolerance_m)) {
    std::ostringstream msg;
    msg << "supported_fraction: tolerance_m = " << tolerance_m << " (expected a finite distance > 0)";
    throw ConfigError(msg.str());
  }
  const GridGeometry& g = grid.geometry();
  const std::size_t valid = grid.valid_count();
  if (valid == 0) {
    std::ostringstream msg;
    msg << "supported_fraction: the " << g.cols << " x " << g.rows << " grid has no valid cell";
    throw InputError(msg.str());
  }
  const std::size_t cols = static_cast<std::size_t>(g.cols);
  const double inv_cell = 1.0 / g.cell_size_m;
  const double reach = tolerance_m * inv_cell;  // tolerance in cells
  // A tolerance of many cells would have each point visit (2·reach + 1)² samples: the nearest-
  // point search of cross_check is cheaper there (and gives the same fraction).
  if (reach > 4.0 && g.rows >= 2 && g.cols >= 2) {
    return cross_check(points_m, grid, tolerance_m, 2.0 * tolerance_m).value.supported_fraction;
  }
  const double tol_sq = tolerance_m * tolerance_m;
  const float* f = grid.data();
  std::vector<std::uint8_t> marks[2];
  auto mark = [&](std::size_t begin, std::size_t end, std::vector<std::uint8_t>& m) {
    m.assign(g.cell_count(), 0);
    const double* p = points_m.xyz.data() + 3 * begin;
    for (std::size_t i = begin; i < end; ++i, p += 3) {
      if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) continue;
      const double cx = (p[0] - g.x0_m) * inv_cell, cy = (p[1] - g.y0_m) * inv_cell;
      // Outside the nodes' extent by more than the tolerance (also keeps the casts in range).
      if (cx + reach < 0.0 || cx - reach > g.cols - 1 || cy + reach < 0.0 || cy - reach > g.rows - 1) continue;
      const double last_col = g.cols - 1, last_row = g.rows - 1;  // clamped in double: casts in range
      const int c_lo = static_cast<int>(std::clamp(detail::ceil_of(cx - reach), 0.0, last_col));
      const int c_hi = static_cast<int>(std::clamp(detail::floor_of(cx + reach), 0.0, last_col));
      const int r_lo = static_cast<int>(std::clamp(detail::ceil_of(cy - reach), 0.0, last_row));
      const int r_hi = static_cast<int>(std::clamp(detail::floor_of(cy + reach), 0.0, last_row));
      for (int r = r_lo; r <= r_hi; ++r) {
        const double dy = p[1] - g.y_of_row(r);
        const std::size_t row = static_cast<std::size_t>(r) * cols;
        for (int c = c_lo; c <= c_hi; ++c) {
          const std::size_t k = row + static_cast<std::size_t>(c);
          if (m[k] != 0) continue;  // supported already: a dense scan marks most samples early
          const float z = f[k];
          if (std::isnan(z)) continue;
          const double dx = p[0] - g.x_of_col(c), dz = p[2] - static_cast<double>(z);
          if (dx * dx + dy * dy + dz * dz <= tol_sq) m[k] = 1;
        }
      }
    }
  };
  const std::size_t n = points_m.size();
  detail::run_two([&] { mark(0, n / 2, marks[0]); }, [&] { mark(n / 2, n, marks[1]); });
  std::size_t supported = 0;
  for (std::size_t k = 0; k < g.cell_count(); ++k) {
    supported += (marks[0][k] | marks[1][k]) != 0 && !std::isnan(f[k]) ? 1U : 0U;
  }
  return static_cast<double>(supported) / static_cast<double>(valid);
}

namespace {

StageResult<CrossCheck> run_cross_check(const Cloud& points_m, const HeightField& grid, double tolerance_m,
                                        double hidden_band_m, bool point_residuals,
                                        std::array<int, 4> query = {0, std::numeric_limits<int>::max(), 0,
                                                                    std::numeric_limits<int>::max()},
                                        const detail::CellErrorFrame* frame = nullptr) {
  const auto t0 = detail::Clock::now();
  check_arguments(points_m, grid, tolerance_m, hidden_band_m);
  StageResult<CrossCheck> result;
  Run run(points_m, grid, tolerance_m, hidden_band_m, result.value);
  run.point_residuals = point_residuals;
  if (frame && (frame->whole.cell_size_m != grid.geometry().cell_size_m || frame->row0 < 0 || frame->col0 < 0 ||
                frame->row0 + grid.geometry().rows > frame->whole.rows || frame->col0 + grid.geometry().cols > frame->whole.cols)) {
    throw std::invalid_argument("cross_check_cell_errors: the frame's grid does not hold the window (cells, rows, cols)");
  }
  run.frame = frame;
  const GridGeometry& qg = grid.geometry();
  run.q_r0 = std::clamp(query[0], 0, qg.rows);
  run.q_r1 = std::clamp(query[1], run.q_r0, qg.rows);
  run.q_c0 = std::clamp(query[2], 0, qg.cols);
  run.q_c1 = std::clamp(query[3], run.q_c0, qg.cols);
  plan(run);
  on_both_halves(run, phase1_residuals_and_keys);  // (a), and each point's bucket
  bucket_offsets(run);
  on_both_halves(run, phase2_scatter);
  std::vector<std::uint32_t>().swap(run.key);
  on_both_halves(run, phase3_bucket_summaries);
  result.value.cell_error_m = HeightField(run.g, kNoData);
  result.value.cell_error_m.model_to_grid = grid.model_to_grid;
  on_both_halves(run, phase4_near_queries);  // (b)
  const FarCounts far = phase5_far_queries(run);
  summarise(run);
  fill_report(run, far, result.report);
  result.report.seconds = detail::seconds_since(t0);
  return result;
}

}  // namespace

StageResult<CrossCheck> cross_check(const Cloud& points_m, const HeightField& grid,
                                    double tolerance_m, double hidden_band_m) {
  return run_cross_check(points_m, grid, tolerance_m, hidden_band_m, true);
}

namespace detail {

StageResult<CrossCheck> cross_check_cell_errors(const Cloud& points_m, const HeightField& grid, double tolerance_m,
                                                double hidden_band_m, std::array<int, 4> query, const CellErrorFrame* frame) {
  return run_cross_check(points_m, grid, tolerance_m, hidden_band_m, false, query, frame);
}

Eigen::Vector3d cross_check_frame_centre(const HeightField& grid) {
  const GridGeometry& g = grid.geometry();
  Eigen::Vector3d centre(g.x_of_col(0.5 * (g.cols - 1)), g.y_of_row(0.5 * (g.rows - 1)), 0.0);
  float z_lo = std::numeric_limits<float>::infinity(), z_hi = -z_lo;
  const CellBuffer<float>& cells = grid.values();
  for (std::size_t i = 0; i < cells.size(); ++i) {
    // A file-backed level 0 given back as the sweep passes it (cell_buffer.hpp; before
    // 2026-12-01, sixty-ninth session, this sweep made the whole depth resident: the tiled
    // cross-check's 579 MB at N = 16384).
    if (i % kReleaseEveryCells == kReleaseEveryCells - 1) cells.release_resident();
    const float v = cells[i];
    if (std::isnan(v)) continue;
    z_lo = std::min(z_lo, v);
    z_hi = std::max(z_hi, v);
  }
  if (z_lo <= z_hi) centre.z() = 0.5 * (static_cast<double>(z_lo) + static_cast<double>(z_hi));
  return centre;
}

}  // namespace detail

}  // namespace hc::pipeline
