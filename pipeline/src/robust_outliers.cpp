// Robust, density-aware outlier removal and far-cluster removal (robust_outliers.hpp).
//
// The test (remove_robust_outliers): d_i = mean distance to the k nearest neighbours; robust
// scale from the median and MAD of ln d on a stratified sample; a point goes when d_i exceeds the
// global bound D_glob, or local_ratio × max(median of its neighbours' d, median d), or when it
// stands off the surface its neighbours form (off_surface_ratio). No test can fail for
// d_i ≤ D_cert = min(local_ratio, off_surface_ratio) × median d, and "k other points within D_cert" proves
// d_i ≤ D_cert by counting alone, so most points of a scan are settled in their own grid cell
// without a k-NN query; the engine (knn_grid.hpp) answers the rest exactly.
//
// Far clusters (remove_far_clusters): single-linkage components on a cell grid of edge ≥ the
// linking distance (26-neighbour union-find), the largest is the main body; small components
// whose bounding box is far from the main body's are removed.

#include "hc/pipeline/robust_outliers.hpp"

#include "ball_set.hpp"
#include "knn_grid.hpp"
#include "near_knn.hpp"
#include "stage_util.hpp"
#include "voxel_keys.hpp"
#include "wanted_keys.hpp"

#include "hc/common/error.hpp"
#include "hc/common/format.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <numeric>
#include <optional>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

namespace hc::pipeline {

namespace {

using detail::BallSet;
using detail::build_grid;
using detail::group_by_wanted_key;
using detail::KeyGroups;
using detail::CellGrid;
using detail::LowerTable;
using detail::Clock;
using detail::kSearchThreads;
using detail::make_report;
using detail::PointQueries;
using detail::run_parallel;
using detail::seconds_since;
using detail::splitmix64;
using hc::format_number;

constexpr std::uint32_t kNotInGrid = std::numeric_limits<std::uint32_t>::max();

// AVX2 and baseline copies of a hot function, picked at load time (GCC/Clang function
// multiversioning: x86-64, ELF, glibc's ifunc). Not under ThreadSanitizer, whose runtime is not
// up when the ifunc resolver runs (GCC says so by __SANITIZE_THREAD__, Clang by __has_feature).
#if defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define HC_NO_SIMD_CLONES 1
#endif
#endif
#if defined(__x86_64__) && defined(__ELF__) && defined(__GLIBC__) && (defined(__GNUC__) || defined(__clang__)) && \
    !defined(__SANITIZE_THREAD__) && !defined(HC_NO_SIMD_CLONES)
#define HC_SIMD_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define HC_SIMD_CLONES
#endif

// The off-surface test (robust_outliers.hpp): points with d_i above off_surface_ratio × d_med
// whose k neighbours form a surface are removed when they stand off its least-squares plane by
// more than kOffSurfaceFraction × d_i.
constexpr double kOffSurfaceFraction = 0.5;

// Finite columns of the cloud.
std::vector<std::uint32_t> finite_rows(const Cloud& cloud, const char* who) {
  if (cloud.size() > std::numeric_limits<std::uint32_t>::max() - 1) {
    throw ResourceError(std::string(who) + ": " + std::to_string(cloud.size()) + " points, at most 4294967294 supported");
  }
  std::vector<std::uint32_t> rows;
  rows.reserve(cloud.size());
  for (Eigen::Index i = 0; i < cloud.xyz.cols(); ++i) {
    if (cloud.xyz.col(i).allFinite()) rows.push_back(static_cast<std::uint32_t>(i));
  }
  return rows;
}

}  // namespace

std::optional<std::array<double, 3>> robust_sample_centre(const std::vector<std::array<double, 3>>& xyz) {
  if (xyz.empty()) return std::nullopt;
  std::array<double, 3> centre{};
  std::vector<double> v(xyz.size());
  for (std::size_t a = 0; a < 3; ++a) {
    for (std::size_t j = 0; j < xyz.size(); ++j) v[j] = xyz[j][a];
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    centre[a] = v[v.size() / 2];
  }
  return centre;
}

namespace {

// The per-axis median (robust_sample_centre) of the points of `cloud` at the given columns.
Eigen::Vector3d centre_of_columns(const Cloud& cloud, const std::vector<std::uint32_t>& columns) {
  std::vector<std::array<double, 3>> at(columns.size());
  for (std::size_t j = 0; j < columns.size(); ++j) {
    const auto c = cloud.xyz.col(static_cast<Eigen::Index>(columns[j]));
    at[j] = {c.x(), c.y(), c.z()};
  }
  const auto mid = robust_sample_centre(at);
  return mid ? Eigen::Vector3d((*mid)[0], (*mid)[1], (*mid)[2]) : Eigen::Vector3d::Zero();
}

// The centre recentred() and mean_knn_distances_of over a Cloud use: the per-axis median of a
// sample of at most 4096 of the rows (positions j·n/m).
Eigen::Vector3d sample_centre(const Cloud& cloud, const std::vector<std::uint32_t>& rows) {
  const std::size_t m = std::min<std::size_t>(rows.size(), 4096);
  std::vector<std::uint32_t> columns(m);
  for (std::size_t j = 0; j < m; ++j) columns[j] = rows[j * rows.size() / m];
  return centre_of_columns(cloud, columns);
}

// The float32 coordinates of column `col` recentred on `centre` (the subtraction in double).
inline void recentre_point(const Cloud& cloud, std::uint32_t col, const Eigen::Vector3d& centre, float* out) {
  for (Eigen::Index a = 0; a < 3; ++a) {
    out[a] = static_cast<float>(cloud.xyz(a, static_cast<Eigen::Index>(col)) - centre(a));
  }
}

// Float32 copy of the given points, recentred (in double) on the per-axis median of a sample of
// at most 4096 of them (sample_centre): the bulk of the cloud keeps float's sub-micrometre
// resolution even when a far point or cluster 1 km away stretches the bounding box (its own
// coordinates lose precision, which cannot matter: it is far from everything).
std::vector<float> recentred(const Cloud& cloud, const std::vector<std::uint32_t>& rows) {
  const Eigen::Vector3d centre = sample_centre(cloud, rows);
  std::vector<float> p(3 * rows.size());
  for (std::size_t j = 0; j < rows.size(); ++j) recentre_point(cloud, rows[j], centre, p.data() + 3 * j);
  return p;
}

// Stratified deterministic sample of m of n indices (one per run of n/m, splitmix64).
std::vector<std::uint32_t> stratified_sample(std::size_t n, std::size_t m) {
  std::vector<std::uint32_t> s(m);
  for (std::size_t j = 0; j < m; ++j) {
    const std::size_t lo = j * n / m, hi = (j + 1) * n / m;
    s[j] = static_cast<std::uint32_t>(lo + splitmix64(j) % (hi - lo));
  }
  return s;
}

double median_of(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  double m = *mid;
  if (v.size() % 2 == 0) m = 0.5 * (m + *std::max_element(v.begin(), mid));
  return m;
}

// Exact k-NN distances of single points of a grid, cached per input index.
class ExactDistances {
 public:
  ExactDistances(const CellGrid& g, int k, std::size_t n) : q_(g, k), k_(k), d_(n, -1.0f), pos_(n, kNotInGrid) {
    for (std::size_t s = 0; s < g.original.size(); ++s) pos_[g.original[s]] = static_cast<std::uint32_t>(s);
    for (const std::uint32_t z : g.zero) d_[z] = 0.0f;  // copies left out: k others at distance 0
  }
  // Computes d for the listed input indices not known yet (grid order, two threads if long);
  // with `nearest`, also each listed point's distance to its nearest other point, in list
  // order, from the same searches (0 for a copy left out of the grid or a point with a copy in
  // it; a point whose d was known is searched again). With `top_d2`, likewise each listed
  // point's k + 1 smallest squared distances (PointQueries::mean_distance), at
  // (*top_d2)[i·(k + 1) ..] for list entry i (all 0 for a copy left out of the grid). Returns how
  // many queries ran.
  std::size_t compute(const std::vector<std::uint32_t>& list, std::vector<float>* nearest = nullptr,
                      std::vector<float>* top_d2 = nullptr) {
    const bool each = nearest != nullptr || top_d2 != nullptr;  // every listed point searched
    const auto k1 = static_cast<std::size_t>(k_) + 1;
    order_.clear();
    for (const std::uint32_t j : list) {
      if (d_[j] < 0.0f || (each && pos_[j] != kNotInGrid)) order_.emplace_back(pos_[j], j);
    }
    std::sort(order_.begin(), order_.end());
    order_.erase(std::unique(order_.begin(), order_.end()), order_.end());
    const std::size_t len = order_.size();
    const int th = len >= 4096 ? kSearchThreads : 1;
    std::vector<float> near(nearest != nullptr ? len : 0, 0.0f);  // by order_ entry
    std::vector<float> top(top_d2 != nullptr ? len * k1 : 0, 0.0f);  // by order_ entry, k + 1 each
    run_parallel(th, [&](int t) {
      PointQueries::Scratch s(k_);
      const std::size_t b = len * static_cast<std::size_t>(t) / static_cast<std::size_t>(th);
      const std::size_t e = len * static_cast<std::size_t>(t + 1) / static_cast<std::size_t>(th);
      for (std::size_t i = b; i < e; ++i) {
        const std::uint32_t j = order_[i].second;
        const float d = q_.mean_distance(order_[i].first, s, nearest != nullptr ? &near[i] : nullptr,
                                         top_d2 != nullptr ? top.data() + i * k1 : nullptr);
        if (d_[j] < 0.0f) d_[j] = d;  // a d known before stays as it was
      }
    });
    if (nearest != nullptr) nearest->assign(list.size(), 0.0f);
    if (top_d2 != nullptr) top_d2->assign(list.size() * k1, 0.0f);
    if (each) {
      for (std::size_t i = 0; i < list.size(); ++i) {
        const std::pair<std::uint32_t, std::uint32_t> key{pos_[list[i]], list[i]};
        const auto it = std::lower_bound(order_.begin(), order_.end(), key);
        if (it == order_.end() || *it != key) continue;  // a copy left out of the grid: 0
        const auto at = static_cast<std::size_t>(it - order_.begin());
        if (nearest != nullptr) (*nearest)[i] = near[at];
        if (top_d2 != nullptr) std::copy_n(top.begin() + static_cast<std::ptrdiff_t>(at * k1), k1, top_d2->begin() + static_cast<std::ptrdiff_t>(i * k1));
      }
    }
    return len;
  }
  // Exact d of the listed input indices (distinct, all in the grid) not known yet, as compute();
  // and for each one with d > d_min, its k nearest neighbours in nb[i·k .. i·k + k)
  // (PointQueries::nearest; the others' entries stay 0). In grid order, so that each search's
  // k-th distance is a good hint for the next. Per point, two ways to the same values:
  //  - d by mean_distance, then the neighbours by nearest when d > d_min;
  //  - the neighbours first, with d from the same search (PointQueries::nearest's mean_d: the
  //    same float squared distances, summed in ascending order). The two agree bit for bit
  //    unless the k distances span more than 2^19, where a double sum of floats is no longer
  //    exact in every order (mean_distance's own order then depends on its search path too): a
  //    duplicate point beside neighbours 10^6 times farther, for example.
  // Each thread takes the second while more than half of its points so far needed neighbours
  // (on the 10^7-point wall, 94 % of them: one search instead of two; on the Buddha few, and
  // nearest costs more than mean_distance). With kth_m, (*kth_m)[i] is the k-th of those
  // neighbours' float distances [m] (PointQueries::nearest's kth_m; +inf where none were
  // stored). With list_d, (*list_d)[i] is list[i]'s d (in list order: the candidates' tests
  // read it there, not at random places of the window's d). Returns how many d were not known.
  std::size_t compute_with_neighbours(const std::vector<std::uint32_t>& list, double d_min, std::vector<std::uint32_t>& nb,
                                      std::vector<float>* kth_m = nullptr, std::vector<float>* list_d = nullptr) {
    const auto k = static_cast<std::size_t>(k_);
    nb.assign(list.size() * k, 0);
    if (kth_m != nullptr) kth_m->assign(list.size(), std::numeric_limits<float>::infinity());
    if (list_d != nullptr) list_d->assign(list.size(), 0.0f);
    std::vector<std::pair<std::uint32_t, std::uint32_t>> order(list.size());  // (sorted position, i)
    std::size_t unknown = 0;
    for (std::size_t i = 0; i < list.size(); ++i) {
      order[i] = {pos_[list[i]], static_cast<std::uint32_t>(i)};
      unknown += d_[list[i]] < 0.0f ? 1U : 0U;
    }
    std::sort(order.begin(), order.end());
    const std::size_t len = order.size();
    const int th = len >= 4096 ? kSearchThreads : 1;
    run_parallel(th, [&](int t) {
      PointQueries::Scratch scratch(k_);
      std::vector<std::uint32_t> knn;
      std::size_t done = 0, wanted = 0;  // points so far, and those that needed neighbours
      const auto [b, e] = detail::share_of(len, t, th);
      for (std::size_t at = b; at < e; ++at, ++done) {
        const std::uint32_t s = order[at].first, i = order[at].second;  // not a binding: clang 14 cannot capture one
        const std::uint32_t j = list[i];
        float kth = std::numeric_limits<float>::infinity();
        auto store = [&] {
          std::copy(knn.begin(), knn.end(), nb.begin() + static_cast<std::ptrdiff_t>(i * k));
          if (kth_m != nullptr) (*kth_m)[i] = kth;
        };
        if (2 * wanted > done) {  // neighbours first
          float mean_d = 0.0f;
          q_.nearest(s, scratch, knn, &mean_d, &kth);
          if (d_[j] < 0.0f) d_[j] = mean_d;
          if (list_d != nullptr) (*list_d)[i] = d_[j];
          if (static_cast<double>(d_[j]) > d_min) {
            store();
            ++wanted;
          }
          continue;
        }
        if (d_[j] < 0.0f) d_[j] = q_.mean_distance(s, scratch);
        if (list_d != nullptr) (*list_d)[i] = d_[j];
        if (!(static_cast<double>(d_[j]) > d_min)) continue;
        q_.nearest(s, scratch, knn, nullptr, &kth);
        store();
        ++wanted;
      }
    });
    return unknown;
  }
  float operator[](std::size_t j) const { return d_[j]; }
  const PointQueries& queries() const { return q_; }
  std::uint32_t pos(std::size_t j) const { return pos_[j]; }
  // Where pos(j) is kept (for a prefetch).
  const std::uint32_t* pos_at(std::size_t j) const { return pos_.data() + j; }

 private:
  PointQueries q_;
  int k_;
  std::vector<float> d_;
  std::vector<std::uint32_t> pos_;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> order_;
};

// The grid's points in its cell order with each cell's run padded to a multiple of kLanes by
// sentinels (+inf on every axis: the squared distance to any point is +inf or NaN, never within
// a bound), for the counting pass's loops: whole vectors, no scalar remainder (on the 10^8-point
// wall a point's cell holds about 24 points, and the remainder took about as long as the vectors).
// Memory while the counting pass runs: 12 bytes a point and at most 92 a cell (7 sentinels and
// the start), on top of the grid.
constexpr std::size_t kLanes = 8;
constexpr float kFar = std::numeric_limits<float>::infinity();
struct PaddedCells {
  std::vector<float> x, y, z;
  std::vector<std::size_t> start;  // cell c's run: [start[c], start[c + 1]); size cells + 1

  // Two threads above 2^17 points.
  explicit PaddedCells(const CellGrid& g) : start(g.cells() + 1, 0) {
    for (std::size_t c = 0; c < g.cells(); ++c) {
      const std::size_t len = g.cell_start[c + 1] - g.cell_start[c];
      start[c + 1] = start[c] + (len + kLanes - 1) / kLanes * kLanes;
    }
    x.resize(start.back());
    y.resize(start.back());
    z.resize(start.back());
    const int th = g.x.size() > (std::size_t{1} << 17) ? kSearchThreads : 1;
    run_parallel(th, [&](int t) {
      const auto [cb, ce] = detail::share_of(g.cells(), t, th);
      for (std::size_t c = cb; c < ce; ++c) {
        const std::size_t pb = g.cell_start[c], len = g.cell_start[c + 1] - pb, q = start[c], qe = start[c + 1];
        std::copy_n(g.x.begin() + pb, len, x.begin() + q);
        std::copy_n(g.y.begin() + pb, len, y.begin() + q);
        std::copy_n(g.z.begin() + pb, len, z.begin() + q);
        std::fill(x.begin() + q + len, x.begin() + qe, kFar);
        std::fill(y.begin() + q + len, y.begin() + qe, kFar);
        std::fill(z.begin() + q + len, z.begin() + qe, kFar);
      }
    });
  }
};

// Eight floats, eight 32-bit lanes (GCC/Clang vector extensions: one AVX2 register in the AVX2
// clone, two SSE2 registers otherwise).
typedef float Lanes8f __attribute__((vector_size(32)));
typedef std::int32_t Lanes8i __attribute__((vector_size(32)));

// How many of the padded points [qb, qe) (a whole number of kLanes) lie within squared
// distance cert2 of pt (the same float arithmetic as a scalar loop: dx² + dy² + dz², in that
// order, compared with cert2). Inlined into its callers' clones.
inline std::uint32_t count_within(const PaddedCells& pc, std::size_t qb, std::size_t qe, const float* pt, float cert2) {
  static_assert(kLanes == 8, "Lanes8f holds kLanes floats");
  Lanes8i acc{};
  for (std::size_t b = qb; b < qe; b += kLanes) {
    Lanes8f x, y, z;
    std::memcpy(&x, pc.x.data() + b, sizeof x);
    std::memcpy(&y, pc.y.data() + b, sizeof y);
    std::memcpy(&z, pc.z.data() + b, sizeof z);
    const Lanes8f dx = x - pt[0], dy = y - pt[1], dz = z - pt[2];
    acc += dx * dx + dy * dy + dz * dz <= cert2;  // −1 where within, 0 elsewhere
  }
  std::int32_t cnt = 0;
  for (std::size_t l = 0; l < kLanes; ++l) cnt -= acc[l];
  return static_cast<std::uint32_t>(cnt);
}

// The counting pass of remove_robust_outliers over the cells [cb, ce): certified[s] = 1 for the
// sorted points s with at least need_count points (itself included) within squared distance
// cert2 (own cell, then the cells of the 3×3×3 block that come within reach: faces, edges, then
// corners, stopping at need_count); 0 otherwise; with `wanted` (one byte per cell), only the
// cells marked non-zero are counted (the others' points are left as they are). `table` is g's LowerTable (or empty),
// `pc` g's points padded (PaddedCells). Compiled also for AVX2 where the compiler can (the
// distance loops vectorise 8 wide), chosen at load time by the CPU.
HC_SIMD_CLONES void certify_by_counting(const CellGrid& g, const PaddedCells& pc, const LowerTable& table, float cert2,
                                        std::uint32_t need_count, std::size_t cb, std::size_t ce, std::uint8_t* certified,
                                        const std::uint8_t* wanted) {
  // The 3×3×3 block's padded point ranges, by (dx + 1) + 3 (dy + 1) + 9 (dz + 1).
  std::array<std::pair<std::size_t, std::size_t>, 27> block{};
  std::array<std::array<std::uint8_t, 12>, 3> by_class{};  // blocks within reach: faces, edges, corners
  std::vector<std::uint32_t> own;
  const auto edge = static_cast<float>(g.cell);
  // Cell (ix, iy, iz)'s padded range, empty outside the grid or for an empty cell.
  const auto padded_run = [&](std::int64_t ix, std::int64_t iy, std::int64_t iz) -> std::pair<std::size_t, std::size_t> {
    const std::size_t c = detail::occupied_cell(g, table, ix, iy, iz);
    if (c == g.cells()) return {0, 0};
    return {pc.start[c], pc.start[c + 1]};
  };
  for (std::size_t ci = cb; ci < ce; ++ci) {
    if (wanted != nullptr && wanted[ci] == 0) continue;
    const std::uint32_t pb = g.cell_start[ci], pe = g.cell_start[ci + 1];
    const std::size_t qb = pc.start[ci], qe = pc.start[ci + 1];
    own.assign(pe - pb, 0);
    bool all = true;
    for (std::uint32_t a = pb; a < pe; ++a) {
      const float pt[3] = {g.x[a], g.y[a], g.z[a]};
      const std::uint32_t cnt = count_within(pc, qb, qe, pt, cert2);
      own[a - pb] = cnt;
      const bool ok = cnt >= need_count;
      certified[a] = ok ? 1 : 0;
      all = all && ok;
    }
    if (all) continue;
    const auto c = g.coords(g.cell_key[ci]);
    for (std::int64_t dz = -1; dz <= 1; ++dz) {
      for (std::int64_t dy = -1; dy <= 1; ++dy) {
        for (std::int64_t dx = -1; dx <= 1; ++dx) {
          block[static_cast<std::size_t>((dx + 1) + 3 * (dy + 1) + 9 * (dz + 1))] = padded_run(c[0] + dx, c[1] + dy, c[2] + dz);
        }
      }
    }
    const float cell_lo[3] = {static_cast<float>(g.lo[0] + static_cast<double>(c[0]) * g.cell),
                              static_cast<float>(g.lo[1] + static_cast<double>(c[1]) * g.cell),
                              static_cast<float>(g.lo[2] + static_cast<double>(c[2]) * g.cell)};
    for (std::uint32_t a = pb; a < pe; ++a) {
      if (certified[a]) continue;
      const float pt[3] = {g.x[a], g.y[a], g.z[a]};
      // Per axis, the offsets whose cells come within d_cert: 0, and -1 or +1 when the point
      // lies within d_cert of that face (squared distance to the face as the gap term). The
      // gaps are only a shortcut: a cell skipped by rounding costs a certificate, never a
      // wrong one (only counted points certify).
      std::array<std::array<std::pair<int, float>, 3>, 3> axis{};
      std::array<std::size_t, 3> na{};
      for (std::size_t ax = 0; ax < 3; ++ax) {
        const float u = pt[ax] - cell_lo[ax], w = edge - u;
        axis[ax][na[ax]++] = {0, 0.0f};
        if (u * u <= cert2) axis[ax][na[ax]++] = {-1, u * u};
        if (w * w <= cert2) axis[ax][na[ax]++] = {1, w * w};
      }
      // The cells within reach (gap ≤ d_cert, not empty) by how many axes they are offset
      // along: the 6 face cells first, then the 12 edge cells, then the 8 corners. Each edge
      // cell's gap is at least its faces', each corner's at least its edges', so the nearest come
      // about first without a sort; the order only decides when the count stops at need_count,
      // never the verdict (every cell within reach is counted until then).
      std::array<std::size_t, 3> reach{};
      for (std::size_t iz = 0; iz < na[2]; ++iz) {
        for (std::size_t iy = 0; iy < na[1]; ++iy) {
          for (std::size_t ix = 0; ix < na[0]; ++ix) {
            const std::size_t off = (ix != 0 ? 1u : 0u) + (iy != 0 ? 1u : 0u) + (iz != 0 ? 1u : 0u);
            if (off == 0) continue;
            const float gap2 = axis[0][ix].second + axis[1][iy].second + axis[2][iz].second;
            const auto q = static_cast<std::uint8_t>((axis[0][ix].first + 1) + 3 * (axis[1][iy].first + 1) +
                                                     9 * (axis[2][iz].first + 1));
            if (gap2 > cert2 || block[q].second <= block[q].first) continue;
            by_class[off - 1][reach[off - 1]++] = q;
          }
        }
      }
      std::uint32_t cnt = own[a - pb];
      for (std::size_t cls = 0; cls < 3 && cnt < need_count; ++cls) {
        for (std::size_t r = 0; r < reach[cls] && cnt < need_count; ++r) {
          const auto& bl = block[by_class[cls][r]];
          cnt += count_within(pc, bl.first, bl.second, pt, cert2);
        }
      }
      certified[a] = cnt >= need_count ? 1 : 0;
    }
  }
}

}  // namespace

std::vector<std::uint32_t> robust_sample_indices(std::size_t n, std::size_t sample) {
  return n == 0 ? std::vector<std::uint32_t>() : stratified_sample(n, std::min(n, std::max<std::size_t>(sample, 1)));
}

namespace {
// The scale's figures are rounded to steps of 1/128 in ln d (0.8 %): a handful of added points
// (a far point, a far cluster) moves the median and the MAD by a fraction of a rank, so the
// rounded scale, hence every decision, stays the same (unless it lies within that fraction of
// a step boundary).
double scale_step(double v) { return std::round(v * 128.0) / 128.0; }

// Whether the medians of the lower and of the upper bounds round to the same step (false for a
// NaN: NaN compares unequal).
bool median_fixed(const std::vector<std::array<double, 2>>& b) {
  std::vector<double> lo(b.size()), hi(b.size());
  for (std::size_t i = 0; i < b.size(); ++i) {
    lo[i] = b[i][0];
    hi[i] = b[i][1];
  }
  return scale_step(median_of(std::move(lo))) == scale_step(median_of(std::move(hi)));
}
}  // namespace

bool robust_scale_fixed(const std::vector<std::array<double, 2>>& log_d, const std::vector<std::array<double, 2>>& log_nearest) {
  // A NaN bound: no order (and nth_element's ordering would be broken).
  for (const auto* b : {&log_d, &log_nearest}) {
    for (const auto& x : *b) {
      if (std::isnan(x[0]) || std::isnan(x[1])) return false;
    }
  }
  if (!log_nearest.empty() && !median_fixed(log_nearest)) return false;
  if (log_d.empty()) return true;
  if (!median_fixed(log_d)) return false;
  std::vector<double> hi(log_d.size());
  for (std::size_t i = 0; i < log_d.size(); ++i) hi[i] = log_d[i][1];
  const double m = scale_step(median_of(std::move(hi)));  // the median, fixed
  // |v − m| over v in [lo, hi]: 0 when m lies inside, else the nearer end; at most the farther
  // end. A value left out (−∞..+∞) gives 0..+∞, which brackets its absence as for the median.
  std::vector<std::array<double, 2>> dev(log_d.size());
  for (std::size_t i = 0; i < log_d.size(); ++i) {
    const double a = std::abs(log_d[i][0] - m), b = std::abs(log_d[i][1] - m);
    dev[i] = {log_d[i][0] <= m && m <= log_d[i][1] ? 0.0 : std::min(a, b), std::max(a, b)};
  }
  return median_fixed(dev);
}

std::optional<RobustScale> robust_scale_of(std::vector<double> logs, std::size_t sampled, std::vector<double> nearest_logs) {
  if (logs.empty()) return std::nullopt;
  const auto step = scale_step;
  RobustScale s;
  s.sample = sampled;
  s.median_log = step(median_of(logs));
  for (double& v : logs) v = std::abs(v - s.median_log);
  s.mad_log = step(median_of(std::move(logs)));
  if (!nearest_logs.empty()) s.spacing_m = std::exp(step(median_of(std::move(nearest_logs))));
  return s;
}

namespace detail {

namespace {

// The listed points are searched among a subset (near_rows) when they are at most this
// fraction of the cloud: a listed point's block holds some hundreds of points.
constexpr std::size_t kNearRatio = 1024;

// Rows (positions in src, increasing) of the subset mean_knn_distances_of searches for the
// listed rows `list` (positions in src): the union of the settled points' blocks and of the
// other listed points' balls (near_knn.hpp); empty when the cell size cannot be had or a bound
// is not finite. Distances
// are taken in double on the float coordinates the grid search uses; a bound is widened by
// a relative 1e-5 over the float search's rounding (about 1e-7), a block's clearance narrowed
// by a millionth of a cell over the cell arithmetic's.
// Src: the points' float coordinates by row (CloudRows, FloatRows): size(), get(j, out[3]).
template <class Src>
std::vector<std::uint32_t> near_rows(const Src& src, const std::vector<std::uint32_t>& list, int k, NearSearch& how) {
  const std::size_t n = src.size();
  const auto k1 = static_cast<std::size_t>(k) + 1;
  // A sample of at most 4096 rows (positions j·n/m; over a Cloud, sample_centre's): its 1 %–99 % box per axis gives
  // the cell edge (about k + 1 points on the box's largest face; a far point does not stretch
  // it), and its points a bound of any listed point's k-th distance (any k + 1 points bound it).
  const std::size_t m = std::min<std::size_t>(n, 4096);
  std::vector<float> sample(3 * m);
  for (std::size_t j = 0; j < m; ++j) src.get(j * n / m, sample.data() + 3 * j);
  std::array<double, 3> ext{};
  {
    std::vector<double> v(m);
    for (std::size_t a = 0; a < 3; ++a) {
      for (std::size_t j = 0; j < m; ++j) v[j] = sample[3 * j + a];
      std::sort(v.begin(), v.end());
      ext[a] = (v[m - 1 - m / 100] - v[m / 100]) / 0.98;
    }
  }
  const double face = std::max({ext[0] * ext[1], ext[0] * ext[2], ext[1] * ext[2]});
  const double edge = std::sqrt(face * static_cast<double>(k1) / static_cast<double>(n));
  if (!(edge > 0.0) || !std::isfinite(edge)) return {};
  constexpr double kWiden = 1.0 + 1e-5;
  std::vector<double> d2;
  // The (k + 1)-th smallest of d2 (at least k + 1 entries), as a widened distance bound.
  const auto bound = [&](std::vector<double>& v) {
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k1 - 1), v.end());
    return std::sqrt(v[k1 - 1]) * kWiden;
  };
  const auto dist2 = [](const float* a, const float* b) {
    double s2 = 0.0;
    for (std::size_t i = 0; i < 3; ++i) {
      const double d = static_cast<double>(a[i]) - static_cast<double>(b[i]);
      s2 += d * d;
    }
    return s2;
  };
  // A cell's integer coordinates fit 21 bits each about the centre ([−2^20, 2^20)). A point of
  // the cloud farther out than 2^20 − 1 cells has none; a listed point needs kWide + 1 cells
  // more (else it is searched by ball), so every cell of its blocks lies where every point has
  // one.
  constexpr std::int64_t kHalf = std::int64_t{1} << 20;
  // The wider block's half-width [cells] (9 × 9 × 9 cells), for the listed points the 3 × 3 × 3
  // block does not settle: on a wall's sparse back side (a nineteenth of the front's density, the
  // cells sized for the front) the k nearest lie about 3.3 cells away, where the sample's bound
  // gave balls of some 40 mm that took tens of thousands of the front's points each (the tiled
  // 10^8 wall: 250 k points of a window's 3.4 M in the subset; forty-seventh session,
  // 2026-11-28).
  constexpr std::int64_t kWide = 4;
  constexpr double kCloudReach = static_cast<double>(kHalf - 1), kListedReach = static_cast<double>(kHalf - 1 - kWide);
  const double inv_edge = 1.0 / edge;
  const auto cell_of = [&](const float* pf, double reach, std::array<std::int64_t, 3>& c) {
    for (std::size_t a = 0; a < 3; ++a) {
      const double f = static_cast<double>(pf[a]) * inv_edge;
      if (!(std::abs(f) < reach)) return false;
      c[a] = static_cast<std::int64_t>(detail::floor_of(f));
    }
    return true;
  };
  const auto key_of = [&](const std::array<std::int64_t, 3>& c, std::int64_t dx, std::int64_t dy, std::int64_t dz) {
    return static_cast<std::uint64_t>(c[0] + dx + kHalf) | (static_cast<std::uint64_t>(c[1] + dy + kHalf) << 21) |
           (static_cast<std::uint64_t>(c[2] + dz + kHalf) << 42);
  };
  std::vector<std::uint32_t> listed = list;
  std::sort(listed.begin(), listed.end());
  listed.erase(std::unique(listed.begin(), listed.end()), listed.end());
  std::vector<std::array<float, 3>> at(listed.size());
  std::vector<std::array<std::int64_t, 3>> cell(listed.size());
  std::vector<std::uint8_t> keyed(listed.size(), 0);
  std::vector<std::size_t> first_try;  // the keyed listed points
  for (std::size_t q = 0; q < listed.size(); ++q) {
    src.get(listed[q], at[q].data());
    keyed[q] = cell_of(at[q].data(), kListedReach, cell[q]) ? 1 : 0;
    if (keyed[q] != 0) first_try.push_back(q);
  }
  const int threads = n > (std::size_t{1} << 17) ? kSearchThreads : 1;
  std::vector<std::uint32_t> chosen;
  // Each listed point's bound so far [m]: the (k + 1)-th distance in a block that held k + 1
  // points (+inf before).
  std::vector<double> r_of(listed.size(), std::numeric_limits<double>::infinity());
  // The listed points `qs` against their blocks of (2R + 1)³ cells: one pass over the cloud (two
  // threads) groups the points of those cells by cell, those outside the blocks' x-y columns
  // passed over on their x and y alone (ColumnTable: before their z, their key and the hash;
  // in tile_scale the blocks' columns cover a few per cent of a window's). A listed point is
  // settled by its block when the block holds k + 1 points within a bound that stays inside it:
  // the block's points join `chosen`. Returns the others (r_of holds the bound of those whose
  // block held k + 1 points). The same points are grouped with or without the column table.
  const auto try_blocks = [&](const std::vector<std::size_t>& qs, std::int64_t R) {
    std::vector<std::uint64_t> keys;
    keys.reserve(qs.size() * static_cast<std::size_t>((2 * R + 1) * (2 * R + 1) * (2 * R + 1)));
    ColumnTable columns(inv_edge);
    for (const std::size_t q : qs) {
      for (std::int64_t dz = -R; dz <= R; ++dz) {
        for (std::int64_t dy = -R; dy <= R; ++dy) {
          for (std::int64_t dx = -R; dx <= R; ++dx) keys.push_back(key_of(cell[q], dx, dy, dz));
        }
      }
      columns.add(cell[q][0] - R, cell[q][0] + R, cell[q][1] - R, cell[q][1] + R);
    }
    const WantedKeys wanted(keys);
    how.columns = columns.build() || how.columns;
    const ColumnTable::Probe probe = columns.probe();
    const KeyGroups held = group_by_wanted_key(n, wanted, threads, [&, probe](std::size_t j, std::uint64_t& key) {
      float pt[3];
      std::array<std::int64_t, 3> ct{};
      src.get(j, pt);
      if (!probe.may_hold(pt)) return false;  // in no wanted cell
      if (!cell_of(pt, kCloudReach, ct)) return false;
      key = key_of(ct, 0, 0, 0);
      return true;
    });
    std::vector<std::size_t> unsettled;
    std::vector<std::uint32_t> block;
    float pf[3];
    for (const std::size_t q : qs) {
      d2.clear();
      block.clear();
      for (std::int64_t dz = -R; dz <= R; ++dz) {
        for (std::int64_t dy = -R; dy <= R; ++dy) {
          for (std::int64_t dx = -R; dx <= R; ++dx) {
            const std::uint32_t w = wanted.find(key_of(cell[q], dx, dy, dz));
            block.push_back(w);
            for (std::size_t i = held.first[w]; i < held.first[w + 1]; ++i) {
              src.get(held.members[i], pf);
              d2.push_back(dist2(pf, at[q].data()));
            }
          }
        }
      }
      if (d2.size() >= k1) {
        const double r = bound(d2);
        r_of[q] = std::min(r_of[q], r);
        double clearance = std::numeric_limits<double>::infinity();
        for (std::size_t a = 0; a < 3; ++a) {
          const double lo = static_cast<double>(cell[q][a] - R) * edge, hi = static_cast<double>(cell[q][a] + R + 1) * edge;
          clearance = std::min({clearance, static_cast<double>(at[q][a]) - lo, hi - static_cast<double>(at[q][a])});
        }
        if (r + 1e-6 * edge < clearance) {
          for (const std::uint32_t w : block) chosen.insert(chosen.end(), held.members.begin() + held.first[w], held.members.begin() + held.first[w + 1]);
          ++(R == 1 ? how.blocks : how.wide_blocks);
          continue;
        }
      }
      unsettled.push_back(q);
    }
    return unsettled;
  };
  // The 3 × 3 × 3 blocks, then the wider ones for the points those leave.
  const std::vector<std::size_t> left = try_blocks(try_blocks(first_try, 1), kWide);
  // The rest (and the listed points without a cell) are searched in a ball of the smaller of
  // their blocks' bound and the sample's.
  std::vector<BallSet::Ball> balls;
  std::vector<std::uint8_t> to_ball(listed.size(), 0);
  for (const std::size_t q : left) to_ball[q] = 1;
  for (std::size_t q = 0; q < listed.size(); ++q) {
    if (keyed[q] == 0) to_ball[q] = 1;
    if (to_ball[q] == 0) continue;
    double r = r_of[q];
    if (m >= k1) {
      d2.clear();
      for (std::size_t j = 0; j < m; ++j) d2.push_back(dist2(sample.data() + 3 * j, at[q].data()));
      r = std::min(r, bound(d2));
    }
    if (!std::isfinite(r)) return {};
    balls.push_back({at[q][0], at[q][1], at[q][2], r});
  }
  how.balls = balls.size();
  if (!balls.empty()) {
    // A second pass (two threads, each a contiguous share): the points in the balls, those
    // outside the columns of the balls' x-y boxes passed over first (ColumnTable; a column
    // more each side over the rounding of the boxes' sides: floor of a product is
    // non-decreasing, so a point within a ball's box has its column within the box's).
    const BallSet set(balls);
    ColumnTable ball_columns(inv_edge);
    for (const BallSet::Ball& b : balls) {
      const auto col = [&](double v) {  // clamped far out: build() then refuses the table
        const double f = std::clamp(v * inv_edge, -4.0 * kHalf, 4.0 * kHalf);
        return static_cast<std::int64_t>(detail::floor_of(f));
      };
      ball_columns.add(col(b[0] - b[3]) - 1, col(b[0] + b[3]) + 1, col(b[1] - b[3]) - 1, col(b[1] + b[3]) + 1);
    }
    (void)ball_columns.build();
    const ColumnTable::Probe probe = ball_columns.probe();
    std::vector<std::vector<std::uint32_t>> in_balls(static_cast<std::size_t>(threads));
    run_parallel(threads, [&, probe](int t) {
      const auto [jb, je] = detail::share_of(n, t, threads);
      float pt[3];
      double pd[3];
      for (std::size_t j = jb; j < je; ++j) {
        src.get(j, pt);
        if (!probe.may_hold(pt)) continue;  // in no ball's x-y box
        for (std::size_t a = 0; a < 3; ++a) pd[a] = pt[a];
        if (set.contains(pd)) in_balls[static_cast<std::size_t>(t)].push_back(static_cast<std::uint32_t>(j));
      }
    });
    for (const auto& v : in_balls) chosen.insert(chosen.end(), v.begin(), v.end());
  }
  // Ascending and each once: a bit per row of the cloud (n / 8 bytes), read back in order (a
  // sort of the 150 k entries of a tile_scale window took 7–9 ms, the bits about 1).
  std::vector<std::uint64_t> mark((n + 63) / 64, 0);
  for (const std::uint32_t j : chosen) mark[j >> 6] |= std::uint64_t{1} << (j & 63);
  chosen.clear();
  for (std::size_t w = 0; w < mark.size(); ++w) {
    for (std::uint64_t bits = mark[w]; bits != 0; bits &= bits - 1) {
      chosen.push_back(static_cast<std::uint32_t>(64 * w + static_cast<std::size_t>(std::countr_zero(bits))));
    }
  }
  return chosen;
}

// The rows of a cloud as near_rows and knn_of_listed read them: finite columns `rows`, float
// coordinates recentred (in double) on `centre` (recentre_point).
struct CloudRows {
  const Cloud& cloud;
  const std::vector<std::uint32_t>& rows;
  const Eigen::Vector3d& centre;
  std::size_t size() const { return rows.size(); }
  void get(std::size_t j, float* out) const { recentre_point(cloud, rows[j], centre, out); }
};

// Float coordinates given as they are (x y z of row j at p[3j]).
struct FloatRows {
  const float* p;
  std::size_t n;
  std::size_t size() const { return n; }
  void get(std::size_t j, float* out) const {
    out[0] = p[3 * j];
    out[1] = p[3 * j + 1];
    out[2] = p[3 * j + 2];
  }
};

// The mean k-NN distances of the listed rows `list` (positions in src, at least k + 2 rows)
// over src, and their nearest distances when nearest_m is given: near_knn.hpp.
template <class Src>
std::vector<double> knn_of_listed(const Src& src, std::vector<std::uint32_t> list, int k, std::vector<double>* nearest_m,
                                  bool near_only, NearSearch* how, std::vector<float>* top_d2 = nullptr) {
  const std::size_t n = src.size();
  NearSearch searched;
  std::vector<std::uint32_t> subset;
  if (near_only && !list.empty() && list.size() * kNearRatio <= n) subset = near_rows(src, list, k, searched);
  // The searched points: the subset's (in order) or every one.
  const bool near = subset.size() >= static_cast<std::size_t>(k) + 2 && subset.size() <= n / 2;
  const std::size_t count = near ? subset.size() : n;
  if (near) {
    searched.near = true;
    searched.subset_points = subset.size();
    for (std::uint32_t& j : list) j = static_cast<std::uint32_t>(std::lower_bound(subset.begin(), subset.end(), j) - subset.begin());
  }
  if (how != nullptr) *how = searched;
  std::vector<float> p(3 * count);
  for (std::size_t j = 0; j < count; ++j) src.get(near ? subset[j] : j, p.data() + 3 * j);
  const CellGrid g = build_grid(p, count, std::min(2 * k + 1, 1000));
  ExactDistances d(g, k, count);
  std::vector<float> near_d;
  d.compute(list, nearest_m != nullptr ? &near_d : nullptr, top_d2);
  std::vector<double> out;
  out.reserve(list.size());
  for (const std::uint32_t j : list) out.push_back(static_cast<double>(d[j]));
  if (nearest_m != nullptr) nearest_m->assign(near_d.begin(), near_d.end());
  return out;
}

void check_knn_k(int k) {
  if (k < 1 || k > 1000) throw ConfigError("mean_knn_distances: k = " + std::to_string(k) + ", expected 1..1000");
}

// what: "finite points" (a Cloud's) or "points" (floats, all finite by then).
void check_knn_count(std::size_t n, int k, const char* what) {
  if (n < static_cast<std::size_t>(k) + 2) {
    throw DegenerateInputError("mean_knn_distances: the cloud has " + std::to_string(n) + " " + what + "; k = " +
                               std::to_string(k) + " needs at least " + std::to_string(k + 2));
  }
}

}  // namespace

std::vector<double> mean_knn_distances_of(const Cloud& cloud, const std::vector<std::uint32_t>& columns, int k,
                                          std::vector<double>* nearest_m, bool near_only, NearSearch* how) {
  check_knn_k(k);
  const std::vector<std::uint32_t> rows = finite_rows(cloud, "mean_knn_distances");
  check_knn_count(rows.size(), k, "finite points");
  // Row index of each listed column (the rows are the finite columns, increasing).
  std::vector<std::uint32_t> list;
  list.reserve(columns.size());
  for (const std::uint32_t c : columns) {
    const auto it = std::lower_bound(rows.begin(), rows.end(), c);
    if (it == rows.end() || *it != c) {
      throw InputError("mean_knn_distances: column " + std::to_string(c) + " is not a finite point of the cloud");
    }
    list.push_back(static_cast<std::uint32_t>(it - rows.begin()));
  }
  const Eigen::Vector3d centre = sample_centre(cloud, rows);
  return knn_of_listed(CloudRows{cloud, rows, centre}, std::move(list), k, nearest_m, near_only, how);
}

std::vector<double> mean_knn_distances_of(const std::vector<float>& xyz, const std::vector<std::uint32_t>& list, int k,
                                          std::vector<double>* nearest_m, bool near_only, NearSearch* how,
                                          std::vector<float>* top_d2) {
  check_knn_k(k);
  if (xyz.size() % 3 != 0) {
    throw InputError("mean_knn_distances: " + std::to_string(xyz.size()) + " float coordinates, expected a multiple of 3");
  }
  const std::size_t n = xyz.size() / 3;
  if (n > std::numeric_limits<std::uint32_t>::max() - 1) {
    throw ResourceError("mean_knn_distances: " + std::to_string(n) + " points, at most 4294967294 supported");
  }
  for (std::size_t j = 0; j < xyz.size(); ++j) {
    if (!std::isfinite(xyz[j])) {
      throw InputError("mean_knn_distances: point " + std::to_string(j / 3) + " has a non-finite coordinate, expected finite points");
    }
  }
  check_knn_count(n, k, "points");
  for (const std::uint32_t j : list) {
    if (j >= n) throw InputError("mean_knn_distances: row " + std::to_string(j) + " listed, expected < " + std::to_string(n));
  }
  return knn_of_listed(FloatRows{xyz.data(), n}, list, k, nearest_m, near_only, how, top_d2);
}

}  // namespace detail

std::vector<double> mean_knn_distances(const Cloud& cloud, const std::vector<std::uint32_t>& columns, int k,
                                       std::vector<double>* nearest_m) {
  return detail::mean_knn_distances_of(cloud, columns, k, nearest_m, true, nullptr);
}

StageResult<Cloud> remove_robust_outliers(Cloud cloud, const RobustOutlierOptions& o, RobustVerdicts* verdicts,
                                          RobustScale* scale_used) {
  const auto t0 = Clock::now();
  const int k = o.k;
  if (k < 1 || k > 1000) throw ConfigError("remove_robust_outliers: k = " + std::to_string(k) + ", expected 1..1000");
  if (!(o.local_ratio > 1.0) || !std::isfinite(o.local_ratio)) {
    throw ConfigError("remove_robust_outliers: local_ratio = " + format_number(o.local_ratio) + ", expected a finite value > 1");
  }
  if (!(o.mad_multiplier > 0.0) || !std::isfinite(o.mad_multiplier)) {
    throw ConfigError("remove_robust_outliers: mad_multiplier = " + format_number(o.mad_multiplier) +
                      ", expected a finite value > 0");
  }
  if (!(o.max_surface_variation >= 0.0) || o.max_surface_variation > 1.0 / 3.0) {
    throw ConfigError("remove_robust_outliers: max_surface_variation = " + format_number(o.max_surface_variation) +
                      ", expected 0..1/3");
  }
  if (!(o.off_surface_ratio == 0.0 || (o.off_surface_ratio > 1.0 && std::isfinite(o.off_surface_ratio)))) {
    throw ConfigError("remove_robust_outliers: off_surface_ratio = " + format_number(o.off_surface_ratio) +
                      ", expected 0 (off) or a finite value > 1");
  }
  if (o.sample < 2) throw ConfigError("remove_robust_outliers: sample = " + std::to_string(o.sample) + ", expected at least 2");
  if (o.tile) {
    for (const auto& b : o.tile->complete_m) {
      if (!(std::isfinite(b[0]) && std::isfinite(b[1]) && std::isfinite(b[2]) && b[3] >= 0.0 && std::isfinite(b[3]))) {
        throw ConfigError("remove_robust_outliers: tile.complete_m holds the ball {" + format_number(b[0]) + ", " +
                          format_number(b[1]) + ", " + format_number(b[2]) + ", " + format_number(b[3]) +
                          "}, expected a finite centre and a finite radius >= 0");
      }
    }
  }
  if (!(o.near_radius_m >= 0.0) || !std::isfinite(o.near_radius_m)) {
    throw ConfigError("remove_robust_outliers: near_radius_m = " + format_number(o.near_radius_m) +
                      ", expected a finite distance >= 0 [m] (0: not asked)");
  }
  const bool near_asked = o.near_radius_m > 0.0 && verdicts != nullptr;
  const bool listed = !o.judge_only.empty();
  const bool masked = !o.judge_mask.empty();
  const bool judging = listed || masked;
  if (listed && masked) throw ConfigError("remove_robust_outliers: judge_only and judge_mask given together (expected one)");
  if (masked && o.judge_mask.size() != cloud.size()) {
    throw ConfigError("remove_robust_outliers: judge_mask holds " + std::to_string(o.judge_mask.size()) + " bytes for a cloud of " +
                      std::to_string(cloud.size()) + " points (expected one a point)");
  }
  if (o.verdicts_only && verdicts == nullptr) {
    throw ConfigError("remove_robust_outliers: verdicts_only needs the verdicts asked for (verdicts is null)");
  }
  if (judging && !o.scale) {
    throw ConfigError(std::string("remove_robust_outliers: ") + (listed ? "judge_only" : "judge_mask") +
                      " needs the scale given (options.scale)");
  }
  if (verdicts) *verdicts = RobustVerdicts{};
  StageReport report = make_report("outliers", cloud.size());
  const std::vector<std::uint32_t> rows = finite_rows(cloud, "remove_robust_outliers");
  const std::size_t n = rows.size();
  // Every column finite (a tile's points): rows is the identity, and the loops that map a
  // finite index to a column in a random order skip reading it.
  const bool rows_identity = n == cloud.size();
  if (n < static_cast<std::size_t>(k) + 2) {
    throw DegenerateInputError("remove_robust_outliers: the cloud has " + std::to_string(n) + " finite points; k = " +
                               std::to_string(k) + " needs at least " + std::to_string(k + 2));
  }
  // The float frame (RobustScale::centre_m): the sample's per-axis median, or the given scale's
  // centre, so that a tiled run's windows compute the in-core run's floats; a given scale
  // without one: this cloud's own (sample_centre).
  std::size_t m = std::min(n, o.sample);
  std::vector<std::uint32_t> sample;
  Eigen::Vector3d centre;
  if (!o.scale) {
    sample = stratified_sample(n, m);
    std::vector<std::uint32_t> columns(sample.size());
    for (std::size_t j = 0; j < sample.size(); ++j) columns[j] = rows[sample[j]];
    centre = centre_of_columns(cloud, columns);
  } else if (o.scale->centre_m) {
    centre = Eigen::Vector3d((*o.scale->centre_m)[0], (*o.scale->centre_m)[1], (*o.scale->centre_m)[2]);
  } else {
    centre = sample_centre(cloud, rows);
  }
  std::vector<float> p(3 * n);
  for (std::size_t j = 0; j < n; ++j) recentre_point(cloud, rows[j], centre, p.data() + 3 * j);
  // Cells of about 0.85·(3k+2) points: larger cells settle more points in their own cell by
  // counting, smaller ones make the exact queries cheaper; on the Buddha (k = 16) 2k+1 and 4k+1
  // cost about 10 % and 2 % more CPU than 3k+1 (outlier_bench, BM_RobustAndFar/0).
  const CellGrid g = build_grid(p, n, std::min(3 * k + 1, 1000));
  ExactDistances d(g, k, n);
  const double t_grid = seconds_since(t0);

  // 1. Robust scale from the sample: median and MAD of ln d over its points with d > 0 (or the
  // scale given: the tiled run's, reduced across its tiles).
  std::size_t queries = 0;
  std::optional<RobustScale> scale = o.scale;
  if (!scale) {
    std::vector<float> near;
    queries = d.compute(sample, &near);
    std::vector<double> logs, nearest_logs;
    logs.reserve(m);
    nearest_logs.reserve(m);
    for (const std::uint32_t j : sample) {
      if (d[j] > 0.0f) logs.push_back(std::log(static_cast<double>(d[j])));
    }
    for (const float v : near) {
      if (v > 0.0f) nearest_logs.push_back(std::log(static_cast<double>(v)));
    }
    scale = robust_scale_of(std::move(logs), m, std::move(nearest_logs));
    if (scale) scale->centre_m = std::array<double, 3>{centre.x(), centre.y(), centre.z()};
  } else {
    m = scale->sample;
    report.notes.push_back("scale (median and MAD of ln d) given, reduced over " + std::to_string(m) +
                           " sampled points of the whole scan");
  }
  if (scale && scale_used != nullptr) *scale_used = *scale;
  if (!scale) {
    // Every sampled point has k copies of itself: nothing is sparse relative to anything.
    report.count_out = cloud.size();
    report.notes.push_back("every sampled point has k exact copies (mean k-NN distance 0): nothing removed");
    report.figure("removed_robust", 0.0);
    if (o.tile) {
      report.figure("halo_shortfall_mm", 0.0);
      report.figure("points_judged_past_halo", 0.0);
    }
    if (verdicts) {
      verdicts->verdict.assign(cloud.size(), 4);
      for (const std::uint32_t r : rows) verdicts->verdict[r] = 0;
      if (near_asked) verdicts->near.assign(cloud.size(), 0);
    }
    report.seconds = seconds_since(t0);
    return {std::move(cloud), std::move(report)};
  }
  const double med = scale->median_log;
  const double mad = scale->mad_log;
  const double sigma = 1.4826 * mad;
  const double d_med = std::exp(med);
  const double d_local = o.local_ratio * d_med;
  const double d_glob = robust_global_threshold_m(*scale, o);
  // Below d_cert no test can fail: the local and global tests need d_i > d_local, the
  // off-surface test d_i > d_off.
  const double d_off = o.off_surface_ratio > 0.0 ? o.off_surface_ratio * d_med : std::numeric_limits<double>::infinity();
  const double d_cert = std::min(d_local, d_off);
  const double t_sample = seconds_since(t0);

  // 2. Counting pass: at least k other points within d_cert (own cell, then the cells of the
  // 3×3×3 block that come within d_cert, faces before edges before corners, stopping at k + 1)
  // prove d_i <= d_cert.
  // Cells split in two halves.
  const auto cert2 = static_cast<float>(d_cert * d_cert * (1.0 - 1e-5));
  const std::size_t cells = g.cells();
  const auto need_count = static_cast<std::uint32_t>(k) + 1;  // the point itself counts once
  // Judging listed points only (options.judge_only): no counting, the listed are the uncertain.
  // Judging the marked points (options.judge_mask): counting over the cells that hold one, the
  // marked points it does not settle are the uncertain.
  std::vector<std::uint8_t> judged(judging ? n : 0, 0);
  if (masked) {
    for (std::size_t j = 0; j < n; ++j) judged[j] = o.judge_mask[rows_identity ? j : rows[j]] != 0 ? 1 : 0;
  }
  if (listed) {
    std::vector<std::uint32_t> finite_of(cloud.size(), kNotInGrid);
    for (std::size_t j = 0; j < n; ++j) finite_of[rows[j]] = static_cast<std::uint32_t>(j);
    for (const std::uint32_t c : o.judge_only) {
      if (c >= cloud.size() || finite_of[c] == kNotInGrid) {
        throw InputError("remove_robust_outliers: judge_only lists column " + std::to_string(c) + ", not a finite point of the " +
                         std::to_string(cloud.size()) + "-point cloud");
      }
      judged[finite_of[c]] = 1;
    }
  }
  // certified in grid order, 0 for the points to judge (the listed or marked), 1 for the others:
  // one pass in grid order, a random read of judged each (the mask and the counting pass's fix-up
  // below read these bytes, in grid order, instead).
  std::vector<std::uint8_t> certified(g.original.size(), judging ? 1 : 0);
  for (std::size_t s = 0; judging && s < certified.size(); ++s) certified[s] = judged[g.original[s]] ? 0 : 1;
  // With the mask: which points in grid order are marked (the counting pass overwrites certified
  // for all of a cell's points; the near counts below read it in grid order too).
  std::vector<std::uint8_t> marked_s;
  if (!listed) {
    // With the mask: the cells that hold a marked point (the others' points stay settled).
    std::vector<std::uint8_t> wanted(masked ? cells : 0, 0);
    if (masked) {
      marked_s.resize(certified.size());
      for (std::size_t s = 0; s < certified.size(); ++s) marked_s[s] = certified[s] ^ 1;
      for (std::size_t ci = 0; ci < wanted.size(); ++ci) {
        std::uint8_t any = 0;
        for (std::uint32_t s = g.cell_start[ci]; s < g.cell_start[ci + 1]; ++s) any |= marked_s[s];
        wanted[ci] = any;
      }
    }
    const PaddedCells padded(g);
    run_parallel(cells > 64 ? kSearchThreads : 1, [&](int t) {
      const int th = cells > 64 ? kSearchThreads : 1;
      const std::size_t cb = cells * static_cast<std::size_t>(t) / static_cast<std::size_t>(th);
      const std::size_t ce = cells * static_cast<std::size_t>(t + 1) / static_cast<std::size_t>(th);
      certify_by_counting(g, padded, d.queries().lower_table(), cert2, need_count, cb, ce, certified.data(),
                          masked ? wanted.data() : nullptr);
    });
    // A counted cell's unmarked points are not judged: settled, as the ones not counted.
    for (std::size_t s = 0; masked && s < certified.size(); ++s) certified[s] = static_cast<std::uint8_t>(certified[s] | (marked_s[s] ^ 1));
  }
  std::vector<std::uint32_t> uncertain;
  std::size_t n_certified = g.zero.size();
  for (std::size_t s = 0; s < certified.size(); ++s) {
    if (certified[s]) {
      ++n_certified;
    } else {
      uncertain.push_back(g.original[s]);
    }
  }
  const double t_cert = seconds_since(t0);

  // 3. Exact d for the rest; the candidates of the tests (d > d_cert), with their k nearest
  // neighbours (step 4's neighbourhoods).
  std::vector<std::uint32_t> uncertain_nb;  // k per uncertain point (candidates only)
  std::vector<float> uncertain_kth;         // with a tile: each candidate's k-th float distance [m]
  std::vector<float> uncertain_d;           // each uncertain point's d
  queries += d.compute_with_neighbours(uncertain, d_cert, uncertain_nb, o.tile ? &uncertain_kth : nullptr, &uncertain_d);
  if (judging) {
    // The chance-plane test of a listed point asks whether its neighbours are scattered
    // candidates: they are judged as candidates too (their own verdicts are not reported).
    std::vector<std::uint32_t> more;
    for (std::size_t u = 0; u < uncertain.size(); ++u) {
      if (!(static_cast<double>(uncertain_d[u]) > d_cert)) continue;
      for (std::size_t a = 0; a < static_cast<std::size_t>(k); ++a) {
        const std::uint32_t j = uncertain_nb[u * static_cast<std::size_t>(k) + a];
        if (!judged[j] && d.pos(j) != kNotInGrid) more.push_back(j);
      }
    }
    std::sort(more.begin(), more.end());
    more.erase(std::unique(more.begin(), more.end()), more.end());
    std::vector<std::uint32_t> more_nb;
    std::vector<float> more_d;
    queries += d.compute_with_neighbours(more, d_cert, more_nb, nullptr, &more_d);
    uncertain.insert(uncertain.end(), more.begin(), more.end());
    uncertain_d.insert(uncertain_d.end(), more_d.begin(), more_d.end());
    uncertain_nb.insert(uncertain_nb.end(), more_nb.begin(), more_nb.end());
    if (o.tile) uncertain_kth.resize(uncertain.size(), std::numeric_limits<float>::infinity());
  }
  std::vector<std::uint8_t> out(n, 0);  // 1 = global, 2 = local, 3 = off surface
  std::vector<std::uint32_t> cand;
  std::vector<std::size_t> cand_at;  // each candidate's place in uncertain
  std::vector<float> cand_d;         // each candidate's d, read in candidate order (not d[cand[i]]: a random read)
  for (std::size_t u = 0; u < uncertain.size(); ++u) {
    if (static_cast<double>(uncertain_d[u]) > d_cert) {
      cand.push_back(uncertain[u]);
      cand_at.push_back(u);
      cand_d.push_back(uncertain_d[u]);
    }
  }
  const double t_exact = seconds_since(t0);

  // 4. Neighbours of the candidates (exact); surface variation (and below d_glob the distance
  // from the neighbours' plane) of each.
  const auto uk = static_cast<std::size_t>(k);
  // Candidate i's k neighbours (input indices, ascending).
  auto nbrs = [&](std::size_t i) {
    const std::uint32_t* first = uncertain_nb.data() + cand_at[i] * uk;
    return std::span<const std::uint32_t>(first, uk);
  };
  std::vector<double> variation(cand.size(), 0.0), off_plane(cand.size(), 0.0);
  // With near_radius_m: how many of each candidate's k nearest lie within it (RobustVerdicts::near),
  // counted here where their coordinates are at hand.
  const auto most_near = static_cast<std::uint8_t>(std::min(k, 255));
  std::vector<std::uint8_t> cand_near(near_asked ? cand.size() : 0, 0);
  {
    const int th = cand.size() >= 256 ? kSearchThreads : 1;
    run_parallel(th, [&](int t) {
      std::vector<Eigen::Vector3d> around(uk + 1);
      const std::size_t b = cand.size() * static_cast<std::size_t>(t) / static_cast<std::size_t>(th);
      const std::size_t e = cand.size() * static_cast<std::size_t>(t + 1) / static_cast<std::size_t>(th);
      for (std::size_t i = b; i < e; ++i) {
        // The neighbours' grid positions lie at random places (input order): fetched two
        // candidates ahead, and their coordinates one ahead (the positions fetched then).
        if (i + 2 < e) {
          __builtin_prefetch(d.pos_at(cand[i + 2]));
          for (const std::uint32_t q : nbrs(i + 2)) __builtin_prefetch(d.pos_at(q));
        }
        if (i + 1 < e) {
          for (const std::uint32_t q : nbrs(i + 1)) {  // a neighbour is a grid point: pos is known
            const std::uint32_t sq = d.pos(q);
            __builtin_prefetch(g.x.data() + sq);
            __builtin_prefetch(g.y.data() + sq);
            __builtin_prefetch(g.z.data() + sq);
          }
        }
        const std::uint32_t s = d.pos(cand[i]);
        const std::span<const std::uint32_t> knn = nbrs(i);
        // Surface variation λ0 / (λ0 + λ1 + λ2) (Pauly et al. 2002), near 0 on a surface or a line
        // at any density, about 1/3 in isotropic clutter: above d_glob of the point and its k
        // neighbours; below it of the neighbours alone, with the point's distance from their
        // least-squares plane (normal = eigenvector of λ0) as a fraction of d_i.
        const bool above = static_cast<double>(cand_d[i]) > d_glob;
        auto at = [&](std::uint32_t q) { return Eigen::Vector3d(g.x[q], g.y[q], g.z[q]); };
        // The point (above d_glob) and its neighbours, gathered once.
        std::size_t held = 0;
        if (above) around[held++] = at(s);
        for (const std::uint32_t q : knn) around[held++] = at(d.pos(q));
        if (near_asked) {
          const Eigen::Vector3d c = at(s);
          const double r2 = o.near_radius_m * o.near_radius_m;
          int within = 0;
          for (std::size_t a = above ? 1 : 0; a < held; ++a) within += (around[a] - c).squaredNorm() <= r2 ? 1 : 0;
          cand_near[i] = static_cast<std::uint8_t>(std::min<int>(within, most_near));
        }
        Eigen::Vector3d mean = Eigen::Vector3d::Zero();
        for (std::size_t a = 0; a < held; ++a) mean += around[a];
        mean /= static_cast<double>(held);
        // The scatter matrix's six sums in scalars: the same products summed in the same order as
        // Eigen's cov += (p − mean)(p − mean)ᵀ (one bit pattern), without the 3×3 temporary that
        // GCC 12 spilled to the stack and read back wider than written (a store-forwarding stall
        // on every neighbour: about a quarter of this loop's time at 10^8 points).
        double sxx = 0.0, sxy = 0.0, sxz = 0.0, syy = 0.0, syz = 0.0, szz = 0.0;
        for (std::size_t a = 0; a < held; ++a) {
          const double dx = around[a].x() - mean.x(), dy = around[a].y() - mean.y(), dz = around[a].z() - mean.z();
          sxx += dx * dx;
          sxy += dx * dy;
          sxz += dx * dz;
          syy += dy * dy;
          syz += dy * dz;
          szz += dz * dz;
        }
        Eigen::Matrix3d cov;
        cov << sxx, sxy, sxz, sxy, syy, syz, sxz, syz, szz;
        const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(cov);
        const Eigen::Vector3d ev = es.eigenvalues();
        const double tr = ev.sum();
        variation[i] = tr > 0.0 ? std::max(ev(0), 0.0) / tr : 0.0;
        if (above) continue;
        const double di = static_cast<double>(cand_d[i]);
        off_plane[i] = di > 0.0 ? std::abs(es.eigenvectors().col(0).dot(at(s) - mean)) / di : 0.0;
      }
    });
  }
  // A point above D_glob lies on no surface when its own neighbourhood is none, or when more
  // than half of its k neighbours are such points (above D_glob, their neighbourhood no surface):
  // k + 1 points of isotropic clutter now and then happen to lie near a plane, the clutter
  // around them does not. Every point above D_glob is a candidate (D_glob >= D_cert).
  std::vector<std::uint32_t> cand_of(n, kNotInGrid);
  for (std::size_t i = 0; i < cand.size(); ++i) cand_of[cand[i]] = static_cast<std::uint32_t>(i);
  auto scattered = [&](std::uint32_t j) {
    if (!(static_cast<double>(d[j]) > d_glob)) return false;
    const std::uint32_t ci = cand_of[j];
    return ci != kNotInGrid && variation[ci] > o.max_surface_variation;
  };
  std::size_t n_planar = 0, n_among_scattered = 0;
  std::vector<std::uint32_t> need;
  for (std::size_t i = 0; i < cand.size(); ++i) {
    if (static_cast<double>(cand_d[i]) > d_glob) {
      if (variation[i] > o.max_surface_variation) {
        out[cand[i]] = 1;
        continue;
      }
      std::size_t among = 0;
      for (const std::uint32_t j : nbrs(i)) among += scattered(j) ? 1u : 0u;
      if (2 * among > uk) {
        out[cand[i]] = 1;
        ++n_among_scattered;
        continue;
      }
      ++n_planar;
    } else if (static_cast<double>(cand_d[i]) > d_off && variation[i] <= o.max_surface_variation &&
               off_plane[i] > kOffSurfaceFraction) {
      out[cand[i]] = 3;
      continue;
    }
    if (static_cast<double>(cand_d[i]) > d_local && (!judging || judged[cand[i]])) {
      need.insert(need.end(), nbrs(i).begin(), nbrs(i).end());
    }
  }
  queries += d.compute(need);

  // 5. Local test against the neighbours' median distance.
  std::size_t n_local = 0, n_global = 0, n_off = 0, local_tests = 0;
  for (std::size_t i = 0; i < cand.size(); ++i) {
    if (out[cand[i]] != 0 || static_cast<double>(cand_d[i]) <= d_local || (judging && !judged[cand[i]])) continue;
    ++local_tests;
    std::vector<double> nd;
    nd.reserve(uk);
    for (const std::uint32_t j : nbrs(i)) nd.push_back(d[j]);
    const double ref = std::max(median_of(std::move(nd)), d_med);
    if (static_cast<double>(cand_d[i]) > o.local_ratio * ref) out[cand[i]] = 2;
  }
  // The largest recentred coordinate (step 6's slack, the near counts' frame limit): over four
  // interleaved runs, which the compiler can keep in one vector (a single running maximum is
  // one dependent compare a coordinate: about 0.2 % of the 10^8-point wall's CPU); the maximum
  // of finite floats does not depend on the order.
  float max_abs = 0.0f;
  if (o.tile || near_asked) {
    std::array<float, 4> most{};
    std::size_t at = 0;
    for (; at + 4 <= p.size(); at += 4) {
      for (std::size_t a = 0; a < 4; ++a) most[a] = std::max(most[a], std::abs(p[at + a]));
    }
    for (; at < p.size(); ++at) most[0] = std::max(most[0], std::abs(p[at]));
    max_abs = std::max(std::max(most[0], most[1]), std::max(most[2], most[3]));
  }
  // 6. A tile's searches against its window (options.tile; see the header).
  double shortfall_m = 0.0;
  std::size_t past_halo = 0;
  if (o.tile) {
    const auto& win = o.tile->window_m;
    const auto& dec = o.tile->decides_m;
    auto xyz = [&](std::uint32_t j) { return cloud.xyz.col(static_cast<Eigen::Index>(rows[j])); };
    // The searches ran in float32 on recentred coordinates: a relative slack of 1e-5 on their
    // distances, and an absolute one of 8 float steps of the largest recentred coordinate.
    const double slack_m = 8.0 * static_cast<double>(std::numeric_limits<float>::epsilon()) * static_cast<double>(max_abs);
    std::vector<std::array<double, 4>> reach;  // candidate i's balls (RobustVerdicts::reach_m)
    PointQueries::Scratch scratch(k);
    std::vector<std::uint32_t> knn_j;
    std::vector<std::uint8_t> searched;  // per neighbour of candidate i: its ball from its own search
    std::unordered_map<std::uint32_t, double> narrowed;  // a listed point's neighbour's k-th distance, by its own search
    // How far a search about q may reach and stay where the cloud is complete: the xy distance
    // to the window's open sides (an infinite side is none), or the most any complete ball
    // leaves about q.
    const BallSet balls(o.tile->complete_m);
    auto margin = [&](const Eigen::Vector3d& q) {
      if (balls.empty()) return std::min({q.x() - win[0], win[1] - q.x(), q.y() - win[2], win[3] - q.y()});
      return balls.margin(q.data());
    };
    // The k-th distance of a search about c that found `knn`, with the slack.
    auto kth = [&](const Eigen::Vector3d& c, std::span<const std::uint32_t> knn) {
      double r = 0.0;
      for (const std::uint32_t q : knn) r = std::max(r, (xyz(q) - c).norm());
      return r * (1.0 + 1e-5) + slack_m;
    };
    // The candidates come in grid order, their coordinates at random places of the window's
    // cloud: fetched a few candidates ahead.
    constexpr std::size_t kAhead = 8;
    for (std::size_t i = 0; i < cand.size(); ++i) {
      if (i + kAhead < cand.size()) {
        const std::uint32_t ahead = cand[i + kAhead];
        __builtin_prefetch(cloud.xyz.data() + 3 * static_cast<std::size_t>(rows_identity ? ahead : rows[ahead]));
      }
      const Eigen::Vector3d x = xyz(cand[i]);
      if (listed ? !judged[cand[i]]
                 : (masked && !judged[cand[i]]) || !(x.x() >= dec[0] && x.x() < dec[1] && x.y() >= dec[2] && x.y() < dec[3])) {
        continue;
      }
      if (balls.empty()) {
        // Far inside the window, no search of the verdict can leave it, and the point's and its
        // neighbours' searches are not bounded one by one (a random read of k neighbours each,
        // the larger part of this step on a dense scan). The point's k-th distance r is at most
        // k·d_i (the largest of k distances is at most their sum), widened here well beyond the
        // float searches' rounding and the slack; a neighbour j lies within r of it, so its
        // bound below is at most 2r plus the slack, and its margin (the distance to the
        // window's open sides, which moves by at most |x_j − x_i|) at least margin(x) − r. Every
        // excess is then below 0, as the full test would find. The search's own k-th float
        // distance bounds r as tightly as the float slack allows (often 20 times below k·d_i on
        // a surface: the band of candidates checked one by one along the window's open sides
        // narrows alike).
        const double kth_f = static_cast<double>(uncertain_kth[cand_at[i]]);
        const double r_ub = (std::min(static_cast<double>(k) * static_cast<double>(cand_d[i]), kth_f) * 1.001 + 4.0 * slack_m) * 1.001 + slack_m;
        if (3.01 * r_ub + 4.0 * slack_m < margin(x)) continue;
      }
      const double r = kth(x, nbrs(i));
      double excess = r - margin(x);
      reach.clear();
      reach.push_back({x.x(), x.y(), x.z(), r});
      // The neighbours' searches count where the verdict used them: the chance-plane and local
      // tests (not a removal by the point's own surface variation or off-surface distance).
      // Neighbour j's k-th distance r_j is at most |x_j − x_i| + r_i, and at most k·d_j (d_j, the
      // mean of its k distances, known: every neighbour of a candidate that reaches the local
      // test, and every candidate; an unknown d_j is certified by counting, below D_cert), and
      // where both reach past the margin, at most its k-th distance here.
      const double di = static_cast<double>(cand_d[i]);
      const bool own = (di > d_glob && variation[i] > o.max_surface_variation) || out[cand[i]] == 3;
      searched.clear();
      if (di > d_local && !own) {
        for (const std::uint32_t j : nbrs(i)) {
          const Eigen::Vector3d xj = xyz(j);
          double rj = (xj - x).norm() * (1.0 + 1e-5) + slack_m + r;
          if (d[j] >= 0.0f) rj = std::min(rj, static_cast<double>(k) * static_cast<double>(d[j]) * (1.0 + 1e-5) + slack_m);
          const double mj = margin(xj);
          const bool search = rj >= mj && d.pos(j) != kNotInGrid;
          if (search) {
            // Short of the bounds: j's own k-th distance here (one search; an upper bound of the
            // whole scan's).
            d.queries().nearest(d.pos(j), scratch, knn_j);
            rj = std::min(rj, kth(xj, knn_j));
          }
          searched.push_back(search || d.pos(j) == kNotInGrid ? 1 : 0);
          excess = std::max(excess, rj - mj);
          reach.push_back({xj.x(), xj.y(), xj.z(), rj});
        }
      }
      if (excess >= 0.0) {
        ++past_halo;
        shortfall_m = std::max(shortfall_m, excess);
        // The balls go to a gathering, which reads every point inside them: the neighbours'
        // balls the bounds kept within the margin are narrowed by their own search here too
        // (the bounds |x_j − x_i| + r_i and k·d_j can be several times the k-th distance, and a
        // ball twice as wide as needed about a stray above a surface holds a wide disc of it).
        for (std::size_t a = 0; verdicts && a < searched.size(); ++a) {
          if (searched[a]) continue;
          const std::uint32_t j = nbrs(i)[a];
          auto [it, fresh] = narrowed.try_emplace(j, 0.0);
          if (fresh) {
            d.queries().nearest(d.pos(j), scratch, knn_j);
            it->second = kth(xyz(j), knn_j);
          }
          reach[a + 1][3] = std::min(reach[a + 1][3], it->second);
        }
        if (verdicts) {
          verdicts->past_halo.push_back(rows[cand[i]]);
          verdicts->reach_m.insert(verdicts->reach_m.end(), reach.begin(), reach.end());
        }
      }
    }
  }
  if (verdicts) std::sort(verdicts->past_halo.begin(), verdicts->past_halo.end());
  if (near_asked) {
    // How many others each point is shown to have within near_radius_m (RobustVerdicts::near):
    // a point settled by counting has k within D_cert; a point whose mean k-NN distance d is
    // known has its j-th nearest within k·d / (k + 1 − j) (at least k + 1 − j of the k
    // distances are as large); a candidate's k nearest are counted (in step 4). Distances
    // between the float32 recentred coordinates, so nothing is claimed when those exceed 10^4
    // radii: a distance's rounding is then at most about 2e-3 of the radius, far inside the
    // users' 10 % margins (the honest check's limit too, InputCheckScope::near). 10^3 until
    // 2026-11-28: a tiled run's windows now share the in-core run's frame (RobustScale::
    // centre_m), so their coordinates reach as far as the scan does (a 15 m façade at the 10^8
    // wall's 0.2 mm spacing: 10^4 radii of 1.6 mm).
    verdicts->near.assign(cloud.size(), 0);
    const double r = o.near_radius_m;
    if (static_cast<double>(max_abs) <= 1e4 * r) {
      // The points settled by counting in grid order (a store each, which does not stall the
      // loop as a load in input order would); then the points whose d is known: the uncertain
      // ones (candidates among them) and the copies left out of the grid (d = 0).
      const auto by_mean = [&](std::uint32_t j) {
        if (!(d[j] >= 0.0f)) return;
        const double within = std::floor(static_cast<double>(k) + 1.0 - static_cast<double>(k) * static_cast<double>(d[j]) * (1.0 + 1e-5) / r);
        std::uint8_t& shown = verdicts->near[rows[j]];
        shown = std::max(shown, static_cast<std::uint8_t>(std::clamp(within, 0.0, static_cast<double>(most_near))));
      };
      if (!listed && d_cert <= r) {
        for (std::size_t s = 0; s < certified.size(); ++s) {
          if (certified[s] && (!masked || marked_s[s])) verdicts->near[rows_identity ? g.original[s] : rows[g.original[s]]] = most_near;
        }
      }
      for (const std::uint32_t j : uncertain) {
        if (!judging || judged[j]) by_mean(j);
      }
      for (const std::uint32_t j : g.zero) {
        if (!judging || judged[j]) by_mean(j);
      }
      for (std::size_t i = 0; i < cand.size(); ++i) {
        if (judging && !judged[cand[i]]) continue;
        std::uint8_t& shown = verdicts->near[rows[cand[i]]];
        shown = std::max(shown, cand_near[i]);
      }
    }
  }
  std::vector<bool> keep(cloud.size(), false);
  // With the mask, an unmarked point's verdict is not this test's to give (a neighbour judged as a
  // candidate for a marked point's chance-plane test may have one here): 0.
  for (std::size_t j = 0; masked && j < n; ++j) out[j] = judged[j] ? out[j] : 0;
  for (std::size_t j = 0; j < n; ++j) {
    n_global += out[j] == 1 ? 1u : 0u;
    n_local += out[j] == 2 ? 1u : 0u;
    n_off += out[j] == 3 ? 1u : 0u;
    keep[rows[j]] = out[j] == 0;
  }
  if (verdicts) {
    verdicts->verdict.assign(cloud.size(), 4);
    for (std::size_t j = 0; j < n; ++j) verdicts->verdict[rows[j]] = judging && !judged[j] ? 0 : out[j];
  }
  if (!judging && !o.verdicts_only) cloud.keep_if(keep);  // else the verdicts carry the result
  report.count_out = o.verdicts_only ? static_cast<std::size_t>(std::count(keep.begin(), keep.end(), true)) : cloud.size();
  report.figure("k", k);
  report.figure("local_ratio", o.local_ratio);
  report.figure("mad_multiplier", o.mad_multiplier);
  report.figure("sample", static_cast<double>(m));
  report.figure("median_knn_distance_mm", d_med * 1e3);
  if (scale->spacing_m > 0.0) report.figure("sample_spacing_mm", scale->spacing_m * 1e3);
  report.figure("mad_log_knn_distance", mad);
  report.figure("sigma_log_knn_distance", sigma);
  report.figure("global_threshold_mm", d_glob * 1e3);
  report.figure("certify_distance_mm", d_cert * 1e3);
  report.figure("certified", static_cast<double>(n_certified));
  report.figure("exact_queries", static_cast<double>(queries));
  report.figure("max_surface_variation", o.max_surface_variation);
  report.figure("local_tests", static_cast<double>(local_tests));
  report.figure("coherent_above_global", static_cast<double>(n_planar));
  report.figure("planar_among_scattered", static_cast<double>(n_among_scattered));
  report.figure("removed_robust", static_cast<double>(n_global + n_local + n_off));
  report.figure("removed_global", static_cast<double>(n_global));
  report.figure("removed_local", static_cast<double>(n_local));
  report.figure("removed_off_surface", static_cast<double>(n_off));
  report.figure("local_threshold_mm", d_local * 1e3);
  report.figure("off_surface_ratio", o.off_surface_ratio);
  report.figure("duplicates_left_out", static_cast<double>(g.zero.size()));
  report.figure("knn_grid_cell_mm", g.cell * 1e3);
  if (o.tile) {
    report.figure("halo_shortfall_mm", shortfall_m * 1e3);
    report.figure("points_judged_past_halo", static_cast<double>(past_halo));
  }
  report.figure("grid_s", t_grid);
  report.figure("sample_s", t_sample - t_grid);
  report.figure("certify_s", t_cert - t_sample);
  report.figure("exact_s", t_exact - t_cert);
  report.figure("local_s", seconds_since(t0) - t_exact);
  report.notes.push_back("robust: removed " + std::to_string(n_global) + " points with mean k-NN distance above " +
                         format_number(d_glob * 1e3) + " mm (median " + format_number(d_med * 1e3) + " mm, sigma(ln d) " +
                         format_number(sigma) + ") whose neighbourhood is not a surface (" +
                         std::to_string(n_among_scattered) + " of them on a chance plane among such points; " +
                         std::to_string(n_planar) + " such points lie on a surface and were judged locally) and " + std::to_string(n_local) + " more than " +
                         format_number(o.local_ratio) + " x sparser than their neighbours and " + std::to_string(n_off) +
                         " standing off their neighbours' surface; " + std::to_string(n_certified) +
                         " of " + std::to_string(n) + " points settled by counting");
  if (n != report.count_in) report.notes.push_back("dropped " + std::to_string(report.count_in - n) + " non-finite points");
  report.seconds = seconds_since(t0);
  return {std::move(cloud), std::move(report)};
}

namespace {

// find_far_clusters; `removed_rows`, when given, receives the cloud columns of the removed
// clusters' points, and `removed_cluster`, when given too, each one's cluster (its component's
// number, the same for the points of one cluster).
FarClusters far_clusters_impl(const Cloud& cloud, double link_m, const FarClusterOptions& o,
                              std::vector<std::uint32_t>* removed_rows, const FarClusterScope* scope, std::size_t size_points,
                              std::vector<std::uint32_t>* removed_cluster = nullptr) {
  if (!(link_m > 0.0) || !std::isfinite(link_m)) {
    throw ConfigError("find_far_clusters: link distance = " + format_number(link_m) + " m, expected a finite value > 0");
  }
  if (!(o.far_distance_m >= 0.0) || !std::isfinite(o.far_distance_m)) {
    throw ConfigError("find_far_clusters: far_distance_m = " + format_number(o.far_distance_m) +
                      " m, expected a finite value >= 0 (0 = 10 x the linking distance)");
  }
  if (!(o.max_fraction >= 0.0) || o.max_fraction > 1.0) {
    throw ConfigError("find_far_clusters: max_fraction = " + format_number(o.max_fraction) + ", expected 0..1");
  }
  std::vector<std::uint32_t> rows = finite_rows(cloud, "find_far_clusters");
  if (rows.empty()) throw InputError("find_far_clusters: the cloud has no finite points");
  const double* xyz = cloud.xyz.data();  // column-major 3 × N: point i at xyz[3i .. 3i+2]
  // The per-point passes on two threads, each a contiguous share of the points (the step was
  // serial: 27 ms of the Buddha's outlier stage). Box, keys, cells, components, counts and
  // boxes are exactly the serial passes'; a centroid's coordinate sum is the sum of the two
  // shares' sums (its last bits may differ from one running sum; it is only reported).
  const auto threads_for = [](std::size_t points) { return points > (std::size_t{1} << 17) ? kSearchThreads : 1; };
  const auto box = detail::parallel_box<double>(
      rows.size(), threads_for(rows.size()), [&](std::size_t j) { return xyz + 3 * static_cast<std::size_t>(rows[j]); });
  const std::array<double, 3>& lo = box.first;  // named references: the lambdas below capture them
  const std::array<double, 3>& hi = box.second;
  // Cells of edge >= link (at most 2^21 per axis: keys fit 63 bits). The edge is link_m unless
  // the box spans more than 2 097 150 links on an axis (2 km at a 1 mm link); only then does it
  // depend on the box, and a part of a scan may link otherwise than the whole.
  const double edge = std::max({link_m, (hi[0] - lo[0]) / 2097150.0, (hi[1] - lo[1]) / 2097150.0, (hi[2] - lo[2]) / 2097150.0});
  const double far_m = o.far_distance_m > 0.0 ? o.far_distance_m : 10.0 * link_m;
  // With a scope (a tile of a scan, whose main body box is given), only the points that could
  // belong to a far cluster are linked (fifty-seventh session, 2026-11-29): those farther than
  // far − δ from the main body box, δ the longest link (two cell edges per axis, a millionth
  // more for the index's rounding, so 2√3 edges) and ε = a millionth of an edge (far above the
  // distances' rounding). Why the far clusters are the same: the distance to a box changes by
  // at most a step's length along a chain of links, so a chain from a point farther than `far`
  // to a point left out passes a kept point within far − ε first, and only through kept points;
  // a kept component holding no point within far − ε is then the whole cloud's component (its
  // points, box and count), and one holding such a point has a gap below `far`, as has the
  // whole cloud's component around it: not far, not removed. The cells are the whole cloud's (on
  // multiples of its edge in the frame). On a tile of a scanned surface almost every point lies in the main
  // body's box, so the linking, the larger part of the tile's far-cluster time, is spared.
  std::size_t near_main_body = 0;
  if (scope != nullptr) {
    const double delta = 2.0 * std::sqrt(3.0) * edge * (1.0 + 1e-6) + 1e-6 * edge;
    const double cut = far_m - delta;  // a point at most this far from the box cannot be in a far cluster
    if (cut >= 0.0) {
      const double cut2 = cut * cut;
      const Eigen::Vector3d& bmin = scope->main_body_min_m;
      const Eigen::Vector3d& bmax = scope->main_body_max_m;
      std::size_t w = 0;
      for (const std::uint32_t i : rows) {
        const double* q = xyz + 3 * static_cast<std::size_t>(i);
        double d2 = 0.0;
        for (int a = 0; a < 3; ++a) {
          const double g = std::max({bmin[a] - q[a], q[a] - bmax[a], 0.0});
          d2 += g * g;
        }
        if (!(d2 <= cut2)) rows[w++] = i;
      }
      near_main_body = rows.size() - w;
      rows.resize(w);
    }
  }
  FarClusters result;
  result.link_m = link_m;
  result.far_distance_m = far_m;
  result.points_near_main_body = near_main_body;
  if (scope != nullptr) {  // the whole scan's main body; every component of the linked points judged
    result.main_body.min_m = scope->main_body_min_m;
    result.main_body.max_m = scope->main_body_max_m;
    result.main_body.centroid_m = 0.5 * (scope->main_body_min_m + scope->main_body_max_m);
  }
  const std::size_t n = rows.size();
  const int threads = threads_for(n);
  if (n == 0) {  // every point within far − δ of the scope's main body: no far cluster
    if (removed_rows) removed_rows->clear();
    if (removed_cluster) removed_cluster->clear();
    return result;
  }
  // A point's cell: floor(q · (1 / edge)) per axis, counted from the box's lowest cell: the
  // cells lie on multiples of the edge in the cloud's frame, whatever part of the scan the cloud
  // holds, so that a tile of a scan (the tiled run, the same frame and coordinates) links its
  // points as the whole scan does (sixty-fourth session, 2026-11-30; before, the cells started
  // at the cloud's own box, and two points between link_m and 2√3 edges apart could share a
  // component in one and not in the other). The multiplication rounds monotonically, so every
  // point's index lies within [base, floor(hi · (1 / edge))]; an index one off at a cell
  // boundary still joins every pair closer than the link: they stay in adjacent cells.
  const double inv_edge = 1.0 / edge;
  std::array<std::int64_t, 3> base{}, nc{};
  for (std::size_t a = 0; a < 3; ++a) {
    base[a] = static_cast<std::int64_t>(std::floor(lo[a] * inv_edge));
    nc[a] = static_cast<std::int64_t>(std::floor(hi[a] * inv_edge)) - base[a] + 1;
  }
  auto key_of = [&](std::int64_t x, std::int64_t y, std::int64_t z) {
    return static_cast<std::uint64_t>(x + nc[0] * (y + nc[1] * z));
  };
  std::vector<std::uint64_t> point_keys(n);
  run_parallel(threads, [&](int t) {
    const auto [b, e] = detail::share_of(n, t, threads);
    for (std::size_t j = b; j < e; ++j) {
      const double* q = xyz + 3 * static_cast<std::size_t>(rows[j]);
      std::array<std::int64_t, 3> c{};
      for (std::size_t a = 0; a < 3; ++a) {
        c[a] = std::clamp<std::int64_t>(static_cast<std::int64_t>(std::floor(q[a] * inv_edge)) - base[a], 0, nc[a] - 1);
      }
      point_keys[j] = key_of(c[0], c[1], c[2]);
    }
  });
  // Occupied cells: cell_of[j] is point j's cell id, keys[id] its key; cell_at(key) finds a
  // cell's id (kNotInGrid if unoccupied). Dense table of ids when the box has at most 4 cells
  // per point (ids in order of first point), else the sorted keys (stable radix sort, binary
  // search).
  const std::uint64_t max_key = static_cast<std::uint64_t>(nc[0] * nc[1] * nc[2]);
  std::vector<std::uint64_t> keys;
  std::vector<std::uint32_t> cell_of(n);
  std::vector<std::uint32_t> dense;
  if (max_key <= 4u * static_cast<std::uint64_t>(n) + 4096u) {
    dense.assign(static_cast<std::size_t>(max_key), kNotInGrid);
    for (std::size_t j = 0; j < n; ++j) {
      std::uint32_t& id = dense[static_cast<std::size_t>(point_keys[j])];
      if (id == kNotInGrid) {
        id = static_cast<std::uint32_t>(keys.size());
        keys.push_back(point_keys[j]);
      }
      cell_of[j] = id;
    }
  } else {
    std::vector<std::uint32_t> order(n);
    std::iota(order.begin(), order.end(), 0u);
    detail::radix_sort(point_keys, order, std::max(1, static_cast<int>(std::bit_width(max_key))));
    for (std::size_t s = 0; s < n; ++s) {
      if (keys.empty() || keys.back() != point_keys[s]) keys.push_back(point_keys[s]);
      cell_of[order[s]] = static_cast<std::uint32_t>(keys.size() - 1);
    }
  }
  point_keys = {};
  auto cell_at = [&](std::uint64_t key) -> std::uint32_t {
    if (!dense.empty()) return dense[static_cast<std::size_t>(key)];
    const auto it = std::lower_bound(keys.begin(), keys.end(), key);
    return it == keys.end() || *it != key ? kNotInGrid : static_cast<std::uint32_t>(it - keys.begin());
  };
  // Union-find over the occupied cells, 26-neighbourhood (the 13 "forward" offsets suffice).
  std::vector<std::uint32_t> parent(keys.size());
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](std::uint32_t x) {
    while (parent[x] != x) {
      parent[x] = parent[parent[x]];
      x = parent[x];
    }
    return x;
  };
  for (std::size_t c = 0; c < keys.size(); ++c) {
    const auto s = static_cast<std::int64_t>(keys[c]);
    const std::array<std::int64_t, 3> cc = {s % nc[0], (s / nc[0]) % nc[1], s / (nc[0] * nc[1])};
    for (std::int64_t dz = 0; dz <= 1; ++dz) {
      for (std::int64_t dy = dz == 0 ? 0 : -1; dy <= 1; ++dy) {
        for (std::int64_t dx = (dz == 0 && dy == 0) ? 1 : -1; dx <= 1; ++dx) {
          const std::int64_t x = cc[0] + dx, y = cc[1] + dy, z = cc[2] + dz;
          if (x < 0 || y < 0 || x >= nc[0] || y >= nc[1] || z >= nc[2]) continue;
          const std::uint32_t other = cell_at(key_of(x, y, z));
          if (other == kNotInGrid) continue;
          const std::uint32_t a = find(static_cast<std::uint32_t>(c)), b = find(other);
          if (a != b) parent[std::max(a, b)] = std::min(a, b);
        }
      }
    }
  }
  // Component statistics, components created in the order of their first point.
  std::vector<std::uint32_t> root_of(keys.size());
  for (std::size_t c = 0; c < keys.size(); ++c) root_of[c] = find(static_cast<std::uint32_t>(c));
  std::vector<std::uint32_t> comp_of_cell(keys.size(), kNotInGrid);
  std::size_t n_comps = 0;
  for (std::size_t j = 0; j < n; ++j) {  // ids in order of first point (serial), statistics below
    std::uint32_t& id = comp_of_cell[root_of[cell_of[j]]];
    if (id == kNotInGrid) id = static_cast<std::uint32_t>(n_comps++);
  }
  PointCluster empty;
  empty.min_m = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  empty.max_m = -empty.min_m;
  // Count, box and coordinate sum per component, per thread; summed in thread order after. One
  // thread when there are many components (a scattered cloud): each thread's copy of them would
  // cost more than it saves.
  const int stat_threads = n_comps <= 4096 ? threads : 1;
  std::vector<std::vector<PointCluster>> part_comps(static_cast<std::size_t>(stat_threads), std::vector<PointCluster>(n_comps, empty));
  std::vector<std::vector<Eigen::Vector3d>> part_sums(static_cast<std::size_t>(stat_threads),
                                                      std::vector<Eigen::Vector3d>(n_comps, Eigen::Vector3d::Zero()));
  run_parallel(stat_threads, [&](int t) {
    std::vector<PointCluster>& cs = part_comps[static_cast<std::size_t>(t)];
    std::vector<Eigen::Vector3d>& ss = part_sums[static_cast<std::size_t>(t)];
    const auto [b, e] = detail::share_of(n, t, stat_threads);
    for (std::size_t j = b; j < e; ++j) {
      const std::uint32_t id = comp_of_cell[root_of[cell_of[j]]];
      PointCluster& pc = cs[id];
      const Eigen::Map<const Eigen::Vector3d> q(xyz + 3 * static_cast<std::size_t>(rows[j]));
      ++pc.count;
      ss[id] += q;
      pc.min_m = pc.min_m.cwiseMin(q);
      pc.max_m = pc.max_m.cwiseMax(q);
    }
  });
  std::vector<PointCluster> comps = std::move(part_comps.front());
  std::vector<Eigen::Vector3d> sums = std::move(part_sums.front());
  for (std::size_t t = 1; t < part_comps.size(); ++t) {
    for (std::size_t i = 0; i < n_comps; ++i) {
      const PointCluster& pc = part_comps[t][i];
      comps[i].count += pc.count;
      comps[i].min_m = comps[i].min_m.cwiseMin(pc.min_m);
      comps[i].max_m = comps[i].max_m.cwiseMax(pc.max_m);
      sums[i] += part_sums[t][i];
    }
  }
  for (std::size_t i = 0; i < comps.size(); ++i) comps[i].centroid_m = sums[i] / static_cast<double>(comps[i].count);
  std::vector<std::uint32_t> rank(comps.size());
  std::iota(rank.begin(), rank.end(), 0u);
  std::stable_sort(rank.begin(), rank.end(), [&](std::uint32_t a, std::uint32_t b) { return comps[a].count > comps[b].count; });
  if (scope == nullptr) result.main_body = comps[rank.front()];
  const std::size_t n_size = scope != nullptr ? scope->points : size_points > 0 ? size_points : n;  // N of the size limit
  const double small = std::max(static_cast<double>(o.max_points), o.max_fraction * static_cast<double>(n_size));
  // A point linked to a cluster lies less than two cell edges from it per axis (adjacent cells;
  // a millionth of an edge more for the index's rounding at a cell boundary).
  const double reach = 2.0 * edge * (1.0 + 1e-6);
  for (std::size_t i = scope != nullptr ? 0 : 1; i < comps.size(); ++i) {
    PointCluster& pc = comps[rank[i]];
    const Eigen::Vector3d gap = (result.main_body.min_m - pc.max_m).cwiseMax(pc.min_m - result.main_body.max_m).cwiseMax(0.0);
    pc.gap_m = gap.norm();
    pc.removed = static_cast<double>(pc.count) <= small && pc.gap_m > result.far_distance_m;
    if (pc.removed && scope != nullptr) {
      const auto& b = scope->complete_xy_m;
      const bool complete =
          pc.min_m.x() - reach >= b[0] && pc.max_m.x() + reach <= b[1] && pc.min_m.y() - reach >= b[2] && pc.max_m.y() + reach <= b[3];
      pc.undecided = !complete;
      pc.removed = complete;
    }
    result.others.push_back(pc);
  }
  if (removed_rows) {
    removed_rows->clear();
    if (removed_cluster) removed_cluster->clear();
    std::vector<std::uint8_t> cell_removed(keys.size(), 0);
    bool any = false;
    for (std::size_t c = 0; c < keys.size(); ++c) {
      cell_removed[c] = comps[comp_of_cell[root_of[c]]].removed ? 1 : 0;
      any = any || cell_removed[c] != 0;
    }
    for (std::size_t j = 0; any && j < n; ++j) {
      if (cell_removed[cell_of[j]] == 0) continue;
      removed_rows->push_back(rows[j]);
      if (removed_cluster) removed_cluster->push_back(comp_of_cell[root_of[cell_of[j]]]);
    }
  }
  return result;
}

}  // namespace

FarClusters find_far_clusters(const Cloud& cloud, double link_m, const FarClusterOptions& o, const FarClusterScope* scope) {
  return far_clusters_impl(cloud, link_m, o, nullptr, scope, 0);
}

namespace {

std::string describe(const PointCluster& c) {
  return std::to_string(c.count) + " points at (" + format_number(c.centroid_m.x()) + ", " + format_number(c.centroid_m.y()) +
         ", " + format_number(c.centroid_m.z()) + ") m, " + format_number(c.gap_m) + " m from the main body";
}

}  // namespace

StageResult<Cloud> remove_far_clusters(Cloud cloud, double link_m, const FarClusterOptions& o, const FarClusterScope* scope,
                                       std::size_t size_points, RemovedPoints* removed) {
  const auto t0 = Clock::now();
  if (removed != nullptr) *removed = RemovedPoints{};
  StageReport report = make_report("far_clusters", cloud.size());
  std::vector<std::uint32_t> gone, gone_cluster;
  const FarClusters fc = far_clusters_impl(cloud, link_m, o, &gone, scope, size_points, removed != nullptr ? &gone_cluster : nullptr);
  std::size_t removed_clusters = 0, kept_far = 0, undecided = 0;
  for (const auto& c : fc.others) {
    removed_clusters += c.removed ? 1u : 0u;
    undecided += c.undecided ? 1u : 0u;
    kept_far += !c.removed && !c.undecided && c.gap_m > fc.far_distance_m ? 1u : 0u;
  }
  if (!gone.empty()) {
    std::vector<bool> keep(cloud.size(), true);
    for (const std::uint32_t i : gone) keep[i] = false;
    if (removed != nullptr) {
      // `gone` lists the columns in increasing order (far_clusters_impl walks the finite rows in
      // order), with each one's component; the clusters are numbered 0, 1, ... as first met.
      std::unordered_map<std::uint32_t, std::uint32_t> number;
      for (std::size_t g = 0; g < gone.size(); ++g) {
        const std::uint32_t i = gone[g];
        removed->at.push_back(i);
        for (Eigen::Index a = 0; a < 3; ++a) removed->xyz.push_back(cloud.xyz(a, static_cast<Eigen::Index>(i)));
        removed->cluster.push_back(number.emplace(gone_cluster[g], static_cast<std::uint32_t>(number.size())).first->second);
      }
    }
    cloud.keep_if(keep);
  }
  report.count_out = cloud.size();
  report.figure("link_mm", fc.link_m * 1e3);
  report.figure("far_distance_mm", fc.far_distance_m * 1e3);
  // With a scope the main body is the scope's box, no component of the cloud.
  report.figure("clusters", static_cast<double>(fc.others.size() + (scope != nullptr ? 0 : 1)));
  report.figure("far_clusters", static_cast<double>(removed_clusters));
  report.figure("removed_far_clusters", static_cast<double>(report.count_in - report.count_out));
  report.figure("kept_far_clusters", static_cast<double>(kept_far));
  if (scope != nullptr) {
    report.figure("undecided_far_clusters", static_cast<double>(undecided));
    report.figure("points_near_main_body", static_cast<double>(fc.points_near_main_body));
  }
  std::size_t listed = 0;
  for (const auto& c : fc.others) {
    if (!c.removed && !(c.gap_m > fc.far_distance_m)) continue;
    if (++listed > 20) {
      report.notes.push_back("... and more far clusters");
      break;
    }
    report.notes.push_back(std::string(c.removed     ? "removed far cluster: "
                                       : c.undecided ? "kept far cluster (it may continue past the part of the scan held): "
                                                     : "kept far cluster (too large to remove): ") +
                           describe(c));
  }
  report.seconds = seconds_since(t0);
  return {std::move(cloud), std::move(report)};
}

StageResult<Cloud> remove_outliers_robust(Cloud cloud, const RobustOutlierOptions& options, const FarClusterOptions& far,
                                          RobustScale* scale_used) {
  return remove_far_clusters_after(remove_robust_outliers(std::move(cloud), options, nullptr, scale_used), far);
}

double robust_global_threshold_m(const RobustScale& scale, const RobustOutlierOptions& o) {
  const double sigma = 1.4826 * scale.mad_log;
  return std::max(std::exp(scale.median_log + o.mad_multiplier * sigma), o.local_ratio * std::exp(scale.median_log));
}

double far_link_m(const FarClusterOptions& far, double global_threshold_m) {
  double link = far.link_m;
  if (!(link > 0.0)) link = (global_threshold_m * 1e3) * 1e-3;
  if (!(link > 0.0)) link = 1e-3;
  return link;
}

double far_link_m(const FarClusterOptions& far, const StageReport& robust_report) {
  double link = far.link_m;
  if (!(link > 0.0)) {
    for (const auto& [name, v] : robust_report.figures) {
      if (name == "global_threshold_mm") link = v * 1e-3;
    }
  }
  if (!(link > 0.0)) link = 1e-3;  // every point a copy of another: any positive link
  return link;
}

StageResult<Cloud> remove_far_clusters_after(StageResult<Cloud> robust, const FarClusterOptions& far, const FarClusterScope* scope,
                                             RemovedPoints* removed_points) {
  if (removed_points != nullptr) *removed_points = RemovedPoints{};
  const auto t0 = Clock::now();
  StageReport report = std::move(robust.report);
  const double robust_s = report.seconds;
  auto removed = static_cast<double>(report.count_in - robust.value.size());
  if (far.enabled && robust.value.size() > 0) {
    const double link = far_link_m(far, report);
    // N of the size limit: the points the robust test was given (after non-finite and crop), a
    // number a tiled run knows before its tiles run (it cannot know the count after the test).
    auto fc = remove_far_clusters(std::move(robust.value), link, far, scope, report.count_in, removed_points);
    report.figure("far_s", fc.report.seconds);
    robust.value = std::move(fc.value);
    for (auto& f : fc.report.figures) report.figures.push_back(std::move(f));
    for (auto& s : fc.report.notes) report.notes.push_back(std::move(s));
    removed = static_cast<double>(report.count_in - robust.value.size());
  } else {
    report.figure("removed_far_clusters", 0.0);
  }
  report.figure("removed", removed);
  report.count_out = robust.value.size();
  report.seconds = robust_s + seconds_since(t0);
  return {std::move(robust.value), std::move(report)};
}

std::string describe_far_points(const Cloud& cloud) {
  try {
    const std::vector<std::uint32_t> rows = finite_rows(cloud, "describe_far_points");
    const int k = 16;
    if (rows.size() < static_cast<std::size_t>(k) + 2) return "";
    const std::vector<float> p = recentred(cloud, rows);
    const CellGrid g = build_grid(p, rows.size(), k);
    ExactDistances d(g, k, rows.size());
    const std::vector<std::uint32_t> sample = stratified_sample(rows.size(), std::min<std::size_t>(rows.size(), 5000));
    d.compute(sample);
    std::vector<double> v;
    for (const std::uint32_t j : sample) {
      if (d[j] > 0.0f) v.push_back(d[j]);
    }
    if (v.empty()) return "";
    const double link = 10.0 * median_of(v);
    FarClusterOptions o;
    o.max_points = 0;
    o.max_fraction = 0.0;
    const FarClusters fc = find_far_clusters(cloud, link, o);
    std::string far;
    std::size_t count = 0, listed = 0;
    for (const auto& c : fc.others) {
      if (!(c.gap_m > fc.far_distance_m)) continue;
      count += c.count;
      if (listed++ < 5) far += (far.empty() ? "" : "; ") + describe(c);
    }
    if (count == 0) return "";
    const PointCluster& b = fc.main_body;
    return "; " + std::to_string(count) + " points lie far from the main body (" + std::to_string(b.count) +
           " points): " + far + (listed > 5 ? "; ..." : "") + ". Remove them with filters.crop, e.g. min_m: [" +
           format_number(b.min_m.x()) + ", " + format_number(b.min_m.y()) + ", " + format_number(b.min_m.z()) + "], max_m: [" +
           format_number(b.max_m.x()) + ", " + format_number(b.max_m.y()) + ", " + format_number(b.max_m.z()) +
           "] (the main body's box, grid frame), or enable filters.outliers.far_clusters";
  } catch (const std::exception&) {
    return "";
  }
}

}  // namespace hc::pipeline

#undef HC_SIMD_CLONES
#undef HC_NO_SIMD_CLONES
