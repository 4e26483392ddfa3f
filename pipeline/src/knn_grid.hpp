#pragma once
/// @file knn_grid.hpp
/// Exact k-nearest-neighbour mean distances on a uniform grid of cubic cells: the search engine
/// of remove_statistical_outliers and remove_front_statistical_outliers (filters.cpp). Private
/// to the pipeline (not installed, not public API); the algorithm is described in knn_grid.cpp.
/// Coordinates are float32, interleaved x, y, z, recentred by the caller; distances are in the
/// coordinates' unit (metres in the pipeline).

#include "hc/pipeline/cloud.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <thread>
#include <utility>
#include <vector>

namespace hc::pipeline::detail {

/// Threads of the k-NN searches (the machines have two cores).
constexpr int kSearchThreads = 2;

/// The number of set bits of `x` (0 .. 64), inline whatever the target. A build for baseline
/// x86-64 (Debian's: no POPCNT) compiles std::popcount to a call into libgcc
/// (__popcountdi2, a table loop), which took about 1 % of the tiled 10^8 wall's tile loop from
/// LowerTable::lower in the k-NN queries (forty-seventh session, 2026-11-28); the branch-free
/// SWAR sum of bit fields (H. S. Warren, "Hacker's Delight", 2nd ed., section 5-1) costs a dozen
/// integer operations instead. Where the target has POPCNT, the instruction.
inline unsigned popcount64(std::uint64_t x) {
#if defined(__POPCNT__)
  return static_cast<unsigned>(std::popcount(x));
#else
  x = x - ((x >> 1) & 0x5555555555555555ULL);                            // 2-bit sums
  x = (x & 0x3333333333333333ULL) + ((x >> 2) & 0x3333333333333333ULL);  // 4-bit sums
  x = (x + (x >> 4)) & 0x0f0f0f0f0f0f0f0fULL;                            // byte sums
  return static_cast<unsigned>((x * 0x0101010101010101ULL) >> 56);      // their total
#endif
}

/// The 63 compare-exchanges of Batcher's odd-even merge sort for 16 entries (K. E. Batcher,
/// "Sorting networks and their applications", AFIPS 1968; the pairs as its iterative form
/// lists them, which sorts every 0-1 input and so every input, Knuth TAOCP vol. 3, 5.3.4).
inline constexpr unsigned char kBatcher16[63][2] = {
    {0, 1},   {2, 3},   {4, 5},   {6, 7},   {8, 9},   {10, 11}, {12, 13}, {14, 15}, {0, 2},   {1, 3},  {4, 6},
    {5, 7},   {8, 10},  {9, 11},  {12, 14}, {13, 15}, {1, 2},   {5, 6},   {9, 10},  {13, 14}, {0, 4},  {1, 5},
    {2, 6},   {3, 7},   {8, 12},  {9, 13},  {10, 14}, {11, 15}, {2, 4},   {3, 5},   {10, 12}, {11, 13}, {1, 2},
    {3, 4},   {5, 6},   {9, 10},  {11, 12}, {13, 14}, {0, 8},   {1, 9},   {2, 10},  {3, 11},  {4, 12}, {5, 13},
    {6, 14},  {7, 15},  {4, 8},   {5, 9},   {6, 10},  {7, 11},  {2, 4},   {3, 5},   {6, 8},   {7, 9},  {10, 12},
    {11, 13}, {1, 2},   {3, 4},   {5, 6},   {7, 8},   {9, 10},  {11, 12}, {13, 14}};

/// Orders a and b (a the smaller) without a branch on their values.
template <typename T>
inline void compare_exchange(T& a, T& b) {
  const T lo = b < a ? b : a, hi = b < a ? a : b;
  a = lo;
  b = hi;
}

/// Sorts a[0..16) ascending through kBatcher16: no branch on the values, which the compiler
/// keeps in registers (conditional moves). A k-NN query's candidates come in no order, and an
/// insertion sort or std::sort of 16 of them mispredicts about every other compare.
template <typename T>
inline void sort16(T* a) {
#pragma GCC unroll 63
  for (int c = 0; c < 63; ++c) compare_exchange(a[kBatcher16[c][0]], a[kBatcher16[c][1]]);
}

/// Moves the k smallest of the m >= k distinct keys at `keys` to keys[0..k), ascending;
/// keys[k..m) are left in no particular order (for k = 16 as they were, which may repeat keys
/// now among the first k). The take of every k-NN query
/// (PointQueries::nearest), where m is a few dozen: for k = 16 (the robust filter's default)
/// the first 16 sorted by sort16, then each further block of 16 (the last padded with the
/// largest key) sorted and merged in keeping the 16 smallest (the elementwise minimum of one
/// ascending and one descending run is a bitonic run of the 16 smallest of both, sorted by its
/// half-cleaners: 8, 4, 2, 1 apart; Batcher 1968). About a fifth of std::nth_element's and two
/// sorts' time for 27 keys on this project's VM (forty-ninth session, 2026-11-28). Other k:
/// std::nth_element, then std::sort of the first k − 1. The keys are distinct, so both give
/// the same keys in the same order.
inline void smallest_keys_first(std::uint64_t* keys, std::size_t m, std::size_t k) {
  if (k != 16) {
    std::nth_element(keys, keys + (k - 1), keys + m);
    std::sort(keys, keys + (k - 1));
    return;
  }
  std::uint64_t top[16], more[16];
  for (std::size_t i = 0; i < 16; ++i) top[i] = keys[i];
  sort16(top);
  for (std::size_t at = 16; at < m; at += 16) {
    const std::size_t n = std::min<std::size_t>(16, m - at);
    for (std::size_t i = 0; i < 16; ++i) more[i] = i < n ? keys[at + i] : ~std::uint64_t{0};
    sort16(more);
#pragma GCC unroll 16
    for (std::size_t i = 0; i < 16; ++i) top[i] = more[15 - i] < top[i] ? more[15 - i] : top[i];
#pragma GCC unroll 4
    for (std::size_t half = 8; half >= 1; half /= 2) {
#pragma GCC unroll 16
      for (std::size_t i = 0; i < 16; ++i) {
        if ((i & half) == 0) compare_exchange(top[i], top[i + half]);
      }
    }
  }
  for (std::size_t i = 0; i < 16; ++i) keys[i] = top[i];
}

/// Sorts a[0..n) ascending: sort16 for 16 entries (a k-NN query's neighbours' indices at
/// k = 16), std::sort otherwise.
inline void sort_indices(std::uint32_t* a, std::size_t n) {
  if (n == 16) {
    sort16(a);
  } else {
    std::sort(a, a + n);
  }
}

/// Points sorted into a uniform grid of cubic cells (built by build_grid).
struct CellGrid {
  double cell = 0.0;                     // edge [m]
  std::array<double, 3> lo{};            // grid origin [m]
  std::array<std::int64_t, 3> n{};       // cells per axis
  std::vector<std::uint64_t> cell_key;   // sorted unique keys of occupied cells
  std::vector<std::uint32_t> cell_start; // first sorted point of each cell; size cells + 1
  std::vector<float> x, y, z;            // points in cell order
  std::vector<std::uint32_t> original;   // sorted position -> input index
  std::vector<std::uint32_t> zero;       // input indices left out: copies beyond k+1 of one location
  double load = 0.0;                     // mean over points of their cell's point count

  std::size_t cells() const { return cell_key.size(); }
  std::uint64_t key(std::int64_t ix, std::int64_t iy, std::int64_t iz) const {
    return static_cast<std::uint64_t>(ix + n[0] * (iy + n[1] * iz));
  }
  std::array<std::int64_t, 3> coords(std::uint64_t k) const {
    const auto s = static_cast<std::int64_t>(k);
    return {s % n[0], (s / n[0]) % n[1], s / (n[0] * n[1])};
  }
  std::int64_t index_of(double v, int axis) const {
    const auto i = static_cast<std::int64_t>((v - lo[static_cast<std::size_t>(axis)]) / cell);
    return std::clamp<std::int64_t>(i, 0, n[static_cast<std::size_t>(axis)] - 1);
  }
  // First occupied cell with key >= k.
  std::size_t lower(std::uint64_t k) const {
    return static_cast<std::size_t>(std::lower_bound(cell_key.begin(), cell_key.end(), k) - cell_key.begin());
  }
};

/// CellGrid::lower for every key in O(1): a bit per key of the grid (set for an occupied cell)
/// with, per word of 64 keys, the number of occupied cells before it (a rank directory, as in
/// Jacobson's succinct bit vectors: G. Jacobson, "Space-efficient static trees and graphs", FOCS
/// 1989). lower(key) is the word's count plus the set bits below the key in its word, which is
/// exactly CellGrid::lower's binary search; occupied(key) is the key's bit. 16 bytes a word (a
/// quarter byte a key; until 2026-11-28 a dense table of 4 bytes a key, 114 MB for a window of
/// 3.9 M points of the 10^8 wall at N = 800). Empty when the grid has more than 64 keys per
/// point (plus 4096: 16 bytes a point at most): callers then use CellGrid::lower.
class LowerTable {
 public:
  LowerTable() = default;
  /// Built over `g` (its keys ascending, each below n0·n1·n2), or empty as above.
  explicit LowerTable(const CellGrid& g);
  bool empty() const { return words_.empty(); }
  /// The first occupied cell with a key >= `key` (0 .. n0·n1·n2, the last giving g.cells()).
  std::size_t lower(std::uint64_t key) const {
    const Word& w = words_[static_cast<std::size_t>(key >> 6)];
    return w.before + static_cast<std::size_t>(popcount64(w.bits & ((std::uint64_t{1} << (key & 63)) - 1)));
  }
  /// Whether the cell of key `key` (below n0·n1·n2) holds a point.
  bool occupied(std::uint64_t key) const { return ((words_[static_cast<std::size_t>(key >> 6)].bits >> (key & 63)) & 1U) != 0; }

 private:
  struct Word {
    std::uint64_t bits = 0;     // bit b: key 64·w + b occupied
    std::uint32_t before = 0;   // occupied cells with a key below 64·w
    std::uint32_t unused = 0;   // 16 bytes a word: one cache line holds four, a lookup one load
  };
  std::vector<Word> words_;
};

/// The number (0 .. cells() − 1) of the occupied cell at integer coordinates (ix, iy, iz) of
/// `g`, or g.cells() when the cell lies outside the grid or holds no point. `table` is g's
/// LowerTable: O(1), or a binary search when it is empty.
inline std::size_t occupied_cell(const CellGrid& g, const LowerTable& table, std::int64_t ix, std::int64_t iy, std::int64_t iz) {
  if (ix < 0 || iy < 0 || iz < 0 || ix >= g.n[0] || iy >= g.n[1] || iz >= g.n[2]) return g.cells();
  const std::uint64_t key = g.key(ix, iy, iz);
  if (!table.empty()) return table.occupied(key) ? table.lower(key) : g.cells();
  const std::size_t c = g.lower(key);
  return c < g.cells() && g.cell_key[c] == key ? c : g.cells();
}

/// Sorted-position range [first, last) of the points of the cell at integer coordinates
/// (ix, iy, iz) of `g`; empty when the cell lies outside the grid or holds no point
/// (occupied_cell).
inline std::pair<std::uint32_t, std::uint32_t> cell_points(const CellGrid& g, const LowerTable& table, std::int64_t ix,
                                                           std::int64_t iy, std::int64_t iz) {
  const std::size_t c = occupied_cell(g, table, ix, iy, iz);
  if (c == g.cells()) return {0, 0};
  return {g.cell_start[c], g.cell_start[c + 1]};
}

/// Builds the grid over `count` points (`p` holds 3·count floats, x, y, z interleaved). The cell
/// edge is chosen so that a point's cell holds about 0.85·(k+1) points; it only affects speed,
/// never the result. Copies beyond k+1 of one location are left out (CellGrid::zero).
CellGrid build_grid(const std::vector<float>& p, std::size_t count, int k);

/// Mean distance of every point of `p` (3·count floats) to its k nearest neighbours, exact, in
/// PCL's arithmetic (float distances, double sum). Left-out copies get 0. Adds the search's
/// figures (grid_*, knn_*) to `report` when given. Cost: about O(count·k); two threads.
std::vector<float> mean_knn_distances(const std::vector<float>& p, std::size_t count, int k,
                                      StageReport* report);

/// Mean k-NN distance of single points of a built grid on demand, from any thread (each thread
/// with its own Scratch). Same result as mean_knn_distances for the same point.
class PointQueries {
 public:
  /// `g` must outlive this object.
  PointQueries(const CellGrid& g, int k);
  ~PointQueries();
  PointQueries(const PointQueries&) = delete;
  PointQueries& operator=(const PointQueries&) = delete;

  /// Per-thread buffers and search radius hint.
  class Scratch {
   public:
    explicit Scratch(int k);
    ~Scratch();
    Scratch(const Scratch&) = delete;
    Scratch& operator=(const Scratch&) = delete;

   private:
    friend class PointQueries;
    struct State;
    std::unique_ptr<State> state_;
  };

  /// Mean distance from the point at sorted grid position `sorted` to its k nearest neighbours.
  /// `nearest_m`, when given, receives the distance to the nearest of them (the same float
  /// squared distance's square root; 0 when the point has a copy in the grid). `top_d2`, when
  /// given (k + 1 floats), receives the search's k + 1 smallest squared distances [m²], the
  /// point's own 0 among them, unordered: the largest of them is the squared radius of the ball
  /// the mean depends on (the tiled run's tile_scale bounds a window's truncated searches with them).
  float mean_distance(std::uint32_t sorted, Scratch& s, float* nearest_m = nullptr, float* top_d2 = nullptr) const;

  /// The grid's LowerTable (built once by the constructor; empty on very sparse grids).
  const LowerTable& lower_table() const;

  /// The k nearest neighbours of the point at sorted grid position `sorted`, itself excluded, as
  /// input indices in `out`, ascending (size k; needs at least k + 1 points in the grid). Exact; equal
  /// squared distances (float) are ordered by input index, so the set does not depend on the
  /// grid. First the points within the Scratch's hint (the k-th distance of its previous query
  /// × 1.15; queries in grid order make it a good one) over the cells that cover them; when
  /// fewer than k lie there, blocks of 3³, 5³, 7³ cells, then the cell-centre kd-tree (as
  /// mean_distance). Either way the same set. With mean_d, also the mean distance to them, which
  /// equals mean_distance's value (the same float squared distances and square roots; summed in
  /// ascending order, so equal unless they span more than 2^19: then a double sum of floats is
  /// not exact in every order). With kth_m, also the largest of the k distances [m] (the float
  /// square root of the k-th smallest float squared distance).
  /// @throws std::invalid_argument when the grid holds fewer than k + 1 points.
  void nearest(std::uint32_t sorted, Scratch& s, std::vector<std::uint32_t>& out, float* mean_d = nullptr,
               float* kth_m = nullptr) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Sorts keys (each below 2^bits, bits 1..64) ascending and permutes idx alike; stable (equal
/// keys keep their input order). LSD radix sort, 11-bit digits, a digit equal in every key
/// skipped; O(n) per digit, scratch n keys + n indices; two threads above 2^17 keys (each
/// counts and scatters a contiguous share; the result is the one-thread sort's). Used by the
/// k-NN grid and the honest cross-check's voxel hash.
void radix_sort(std::vector<std::uint64_t>& keys, std::vector<std::uint32_t>& idx, int bits);

/// Thread t's contiguous share [first, last) of n items split among `threads` (the shares tile
/// [0, n) in order, so results written per share keep the serial order).
inline std::pair<std::size_t, std::size_t> share_of(std::size_t n, int t, int threads) {
  return {n * static_cast<std::size_t>(t) / static_cast<std::size_t>(threads),
          n * static_cast<std::size_t>(t + 1) / static_cast<std::size_t>(threads)};
}

/// Runs f(0) on this thread and f(1..threads-1) on new threads, then joins them.
template <class F>
void run_parallel(int threads, F&& f) {
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(f, t);
  f(0);
  for (auto& th : pool) th.join();
}

/// Per-axis box {lo, hi} of n points, `point(i)` giving point i's x, y, z (a pointer to 3 values
/// of type T, in the caller's unit and frame), each of `threads` threads over its share_of the
/// points, the shares' boxes joined after. A NaN coordinate is passed over, as a serial
/// std::min / std::max loop passes over it; n = 0 gives lo = +inf, hi = −inf. No errors.
template <class T, class PointFn>
std::pair<std::array<T, 3>, std::array<T, 3>> parallel_box(std::size_t n, int threads, PointFn&& point) {
  using Box = std::pair<std::array<T, 3>, std::array<T, 3>>;
  Box empty;
  empty.first.fill(std::numeric_limits<T>::infinity());
  empty.second.fill(-std::numeric_limits<T>::infinity());
  std::vector<Box> part(static_cast<std::size_t>(threads), empty);
  run_parallel(threads, [&](int t) {
    Box box = empty;
    const auto [b, e] = share_of(n, t, threads);
    for (std::size_t i = b; i < e; ++i) {
      const T* q = point(i);
      for (std::size_t a = 0; a < 3; ++a) {
        box.first[a] = std::min(box.first[a], q[a]);
        box.second[a] = std::max(box.second[a], q[a]);
      }
    }
    part[static_cast<std::size_t>(t)] = box;
  });
  Box all = empty;
  for (const Box& box : part) {
    for (std::size_t a = 0; a < 3; ++a) {
      all.first[a] = std::min(all.first[a], box.first[a]);
      all.second[a] = std::max(all.second[a], box.second[a]);
    }
  }
  return all;
}

}  // namespace hc::pipeline::detail
