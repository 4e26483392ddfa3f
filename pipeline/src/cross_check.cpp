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
// Speed. Two threads (std::thread). The points are split at a grid-row boundary y_s chosen so
// that both halves hold about half of the valid cells; each thread converts its half to float,
// runs (a) on it and builds a nanoflann kd-tree over it. Queries of (b) then run in grid order,
// each thread on its own rows: the own half's tree first, and the other half's tree only when
// the query sphere crosses y = y_s, seeded with the distance already found so that it prunes
// at once. The result is the exact nearest neighbour over all points.

#include "hc/pipeline/cross_check.hpp"

#include "hc/common/bilinear_surface.hpp"
#include "hc/common/error.hpp"

#include <nanoflann.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <limits>
#include <memory>
#include <sstream>
#include <thread>
#include <utility>

namespace hc::pipeline {

namespace {

/// nanoflann dataset adaptor over packed float xyz triples.
struct PackedPoints {
  std::vector<float> xyz;
  std::size_t kdtree_get_point_count() const { return xyz.size() / 3; }
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
  explicit NearestPointIndex(std::vector<float> xyz) : points_{std::move(xyz)} {
    if (points_.kdtree_get_point_count() > 0) {
      tree_ = std::make_unique<Tree>(3, points_, nanoflann::KDTreeSingleIndexAdaptorParams(kLeafSize));
    }
  }
  std::size_t size() const { return points_.kdtree_get_point_count(); }

  /// Distance [m] from q to its nearest point, or bound_m when no point is strictly closer.
  double nearest_distance_m(const float q[3], double bound_m) const {
    const auto bound_sq = static_cast<float>(bound_m * bound_m);
    if (!tree_) return bound_m;
    NearestWithinSq result(bound_sq);
    tree_->findNeighbors(result, q, nanoflann::SearchParams());
    return result.full() ? std::sqrt(static_cast<double>(result.best_sq())) : bound_m;
  }

 private:
  static constexpr std::size_t kLeafSize = 16;
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, PackedPoints>,
                                                   PackedPoints, 3, std::uint32_t>;
  PackedPoints points_;
  std::unique_ptr<Tree> tree_;
};

/// Runs a() on a second thread and b() on this one; rethrows the first exception.
template <class A, class B>
void run_two(A&& a, B&& b) {
  std::exception_ptr error_a, error_b;
  std::thread worker([&] {
    try {
      a();
    } catch (...) {
      error_a = std::current_exception();
    }
  });
  try {
    b();
  } catch (...) {
    error_b = std::current_exception();
  }
  worker.join();
  if (error_a) std::rethrow_exception(error_a);
  if (error_b) std::rethrow_exception(error_b);
}

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

/// What one thread computes over its half of the points and rows.
struct HalfResult {
  std::vector<float> vertical_m, normal_m;
  std::size_t on_surface = 0, off_surface = 0, hidden = 0, outside = 0;
  std::unique_ptr<NearestPointIndex> index;
  std::vector<float> cell_m;
  std::size_t supported = 0;
};

}  // namespace

ErrorStats error_stats_mm(std::vector<double> abs_errors_m) { return stats_of(abs_errors_m); }

StageResult<CrossCheck> cross_check(const Cloud& points_m, const HeightField& grid,
                                    double tolerance_m, double hidden_band_m) {
  const auto t0 = std::chrono::steady_clock::now();
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

  // Split rows so that both threads get about half of the valid cells.
  const auto ucols = static_cast<std::size_t>(g.cols);
  std::vector<std::size_t> valid_in_row(static_cast<std::size_t>(g.rows), 0);
  std::size_t valid_total = 0;
  for (int r = 0; r < g.rows; ++r) {
    const float* row = grid.data() + static_cast<std::size_t>(r) * ucols;
    std::size_t n = 0;
    for (int c = 0; c < g.cols; ++c) n += std::isnan(row[c]) ? 0U : 1U;
    valid_in_row[static_cast<std::size_t>(r)] = n;
    valid_total += n;
  }
  if (valid_total == 0) {
    msg << "cross_check: the " << g.cols << " x " << g.rows << " grid has no valid cell";
    throw InputError(msg.str());
  }
  // The kd-tree works in float, in a local frame centred on the grid (x, y) and on the middle
  // of its height range (z), so that float keeps ~1e-9 relative precision even for
  // coordinates far from the origin.
  Eigen::Vector3d centre(g.x_of_col(0.5 * (g.cols - 1)), g.y_of_row(0.5 * (g.rows - 1)), 0.0);
  {
    float z_lo = std::numeric_limits<float>::infinity(), z_hi = -z_lo;
    for (float v : grid.values()) {
      if (std::isnan(v)) continue;
      z_lo = std::min(z_lo, v);
      z_hi = std::max(z_hi, v);
    }
    centre.z() = 0.5 * (static_cast<double>(z_lo) + static_cast<double>(z_hi));
  }
  int split_row = 1;  // rows [0, split_row) belong to the lower half
  {
    std::size_t acc = 0;
    for (int r = 0; r < g.rows; ++r) {
      acc += valid_in_row[static_cast<std::size_t>(r)];
      if (2 * acc >= valid_total) {
        split_row = std::clamp(r + 1, 1, g.rows - 1);
        break;
      }
    }
  }
  const double y_split = g.y_of_row(split_row - 0.5);

  const BilinearSurface surface(HeightFieldView::of(grid));
  const double x_lo = g.x0_m, x_hi = g.x_of_col(g.cols - 1);
  const double y_lo = g.y0_m, y_hi = g.y_of_row(g.rows - 1);
  HalfResult halves[2];

  // Phase 1 (per half): select and pack the points, check them against f, build the kd-tree.
  auto phase1 = [&](int h) {
    HalfResult& out = halves[h];
    std::vector<float> packed;
    packed.reserve(3 * (points_m.size() / 2 + 1));
    const double* p = points_m.xyz.data();
    for (std::size_t i = 0; i < points_m.size(); ++i, p += 3) {
      if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) continue;
      if ((p[1] < y_split) != (h == 0)) continue;
      packed.push_back(static_cast<float>(p[0] - centre.x()));
      packed.push_back(static_cast<float>(p[1] - centre.y()));
      packed.push_back(static_cast<float>(p[2] - centre.z()));
      if (p[0] < x_lo || p[0] > x_hi || p[1] < y_lo || p[1] > y_hi) {
        ++out.outside;
        continue;
      }
      const SurfaceSample s = surface.sample(p[0], p[1]);
      if (!s.valid) {
        ++out.off_surface;
        continue;
      }
      const double residual = p[2] - s.z_m;
      if (residual < -hidden_band_m) {
        ++out.hidden;
        continue;
      }
      ++out.on_surface;
      const double n_z = 1.0 / std::sqrt(1.0 + s.dz_dx * s.dz_dx + s.dz_dy * s.dz_dy);
      out.vertical_m.push_back(static_cast<float>(std::abs(residual)));
      out.normal_m.push_back(static_cast<float>(std::abs(residual) * n_z));
    }
    out.index = std::make_unique<NearestPointIndex>(std::move(packed));
  };
  run_two([&] { phase1(1); }, [&] { phase1(0); });
  if (halves[0].index->size() + halves[1].index->size() == 0) {
    msg << "cross_check: none of the " << points_m.size() << " points is finite";
    throw InputError(msg.str());
  }

  // Phase 2 (per half of the rows): nearest input point of every valid sample, in grid order.
  StageResult<CrossCheck> result;
  CrossCheck& cc = result.value;
  cc.cell_error_m = HeightField(g, kNoData);
  cc.cell_error_m.model_to_grid = grid.model_to_grid;
  auto phase2 = [&](int h) {
    HalfResult& out = halves[h];
    const NearestPointIndex& own = *halves[h].index;
    const NearestPointIndex& other = *halves[1 - h].index;
    const int r_begin = h == 0 ? 0 : split_row, r_end = h == 0 ? split_row : g.rows;
    out.cell_m.reserve(valid_total / 2 + 1);
    const double unbounded = std::numeric_limits<double>::infinity();
    for (int r = r_begin; r < r_end; ++r) {
      const float* row = grid.data() + static_cast<std::size_t>(r) * ucols;
      float* err = cc.cell_error_m.data() + static_cast<std::size_t>(r) * ucols;
      const double y = g.y_of_row(r);
      const double dy_split = y - y_split;
      const auto y_local = static_cast<float>(y - centre.y());
      for (int c = 0; c < g.cols; ++c) {
        if (std::isnan(row[c])) continue;
        const float q[3] = {static_cast<float>(g.x_of_col(c) - centre.x()), y_local,
                            static_cast<float>(static_cast<double>(row[c]) - centre.z())};
        double d = own.nearest_distance_m(q, unbounded);
        if (dy_split * dy_split < d * d) d = other.nearest_distance_m(q, d);
        err[c] = static_cast<float>(d);
        out.cell_m.push_back(static_cast<float>(d));
        out.supported += d <= tolerance_m ? 1U : 0U;
      }
    }
  };
  run_two([&] { phase2(1); }, [&] { phase2(0); });

  // Phase 3: statistics (two threads over the three distributions).
  auto concat = [](std::vector<float>& a, std::vector<float>& b) {
    a.insert(a.end(), b.begin(), b.end());
    std::vector<float>().swap(b);
    return std::move(a);
  };
  std::vector<float> vertical = concat(halves[0].vertical_m, halves[1].vertical_m);
  std::vector<float> normal = concat(halves[0].normal_m, halves[1].normal_m);
  std::vector<float> cells = concat(halves[0].cell_m, halves[1].cell_m);
  run_two([&] { cc.point_vertical = stats_of(vertical); },
          [&] {
            cc.point_normal = stats_of(normal);
            cc.cell_to_point = stats_of(cells);
          });

  cc.points_on_surface = halves[0].on_surface + halves[1].on_surface;
  cc.points_off_surface = halves[0].off_surface + halves[1].off_surface;
  cc.points_hidden = halves[0].hidden + halves[1].hidden;
  cc.points_outside = halves[0].outside + halves[1].outside;
  cc.hidden_band_m = hidden_band_m;
  cc.tolerance_m = tolerance_m;
  cc.supported_fraction = static_cast<double>(halves[0].supported + halves[1].supported) /
                          static_cast<double>(valid_total);

  StageReport& rep = result.report;
  rep.stage = "cross_check";
  rep.count_in = points_m.size();
  rep.count_out = valid_total;
  auto add = [&rep](const std::string& prefix, const ErrorStats& s) {
    rep.figure(prefix + "_count", static_cast<double>(s.count));
    rep.figure(prefix + "_rms_mm", s.rms_mm);
    rep.figure(prefix + "_p50_mm", s.p50_mm);
    rep.figure(prefix + "_p95_mm", s.p95_mm);
    rep.figure(prefix + "_p99_mm", s.p99_mm);
    rep.figure(prefix + "_max_mm", s.max_mm);
  };
  add("point_vertical", cc.point_vertical);
  add("point_normal", cc.point_normal);
  add("cell_to_point", cc.cell_to_point);
  rep.figure("points_on_surface", static_cast<double>(cc.points_on_surface));
  rep.figure("points_off_surface", static_cast<double>(cc.points_off_surface));
  rep.figure("points_hidden", static_cast<double>(cc.points_hidden));
  rep.figure("points_outside", static_cast<double>(cc.points_outside));
  rep.figure("hidden_band_mm", hidden_band_m * 1e3);
  rep.figure("tolerance_mm", tolerance_m * 1e3);
  rep.figure("supported_fraction", cc.supported_fraction);
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

}  // namespace hc::pipeline
