// The honest cross-check: the grid against the input as read, the grid's own spikes and pits,
// and the verdict. See honest_check.hpp for what each figure means.
//
// Point test ("isolated"): a point with fewer than m other input points within the radius
// rho = isolation_radius_spacings × spacing, where spacing is the median nearest-neighbour
// distance of the input. It is local: a scan region sampled 30 times more sparsely than the
// rest still has about pi·(rho/spacing)²/30 ≈ 10 neighbours within rho and is NOT isolated
// (the k-NN statistics of the outlier filter call it an outlier); a stray point in front of
// the surface or in the background has none. It cannot tell a surface sampled more than
// about pi·factor²/m times more sparsely than the median from scattered noise.

#include "hc/pipeline/honest_check.hpp"

#include "knn_grid.hpp"  // detail::radix_sort, run_parallel, kSearchThreads
#include "plane_solve.hpp"  // detail::solve_plane_ldlt
#include "stage_util.hpp"  // detail::run_two
#include "voxel_keys.hpp"
#include "wanted_keys.hpp"

#include "hc/common/bilinear_surface.hpp"
#include "hc/common/error.hpp"
#include "hc/common/format.hpp"
#include "hc/pipeline/reproject.hpp"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <functional>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <numeric>
#include <optional>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <utility>

namespace hc::pipeline {
namespace {

using Clock = std::chrono::steady_clock;

using detail::floor_of;
using detail::WantedKeys;

/// Points hashed into cubic voxels of one edge: sorted by voxel key; unique keys and the range
/// of each. Coordinates are floats in a local frame (the caller's origin).
class VoxelHash {
 public:
  VoxelHash(const std::vector<float>& xyz, const std::vector<std::uint8_t>& finite, double edge_m)
      : edge_(edge_m), inv_(1.0 / edge_m) {
    const std::size_t n = finite.size();
    // The box of occupied cells (cell() is monotone, so the cells of the coordinates' extremes).
    // Keys are linear indices in it, x slowest then y then z: the order of the coordinates, so
    // the sort's result does not depend on the key's form, and the radix sort sorts only as many
    // bits as the box has cells (about 20 instead of 63 for a scan).
    float lo_f[3] = {std::numeric_limits<float>::infinity(), std::numeric_limits<float>::infinity(),
                     std::numeric_limits<float>::infinity()};
    float hi_f[3] = {-lo_f[0], -lo_f[0], -lo_f[0]};
    for (std::size_t i = 0; i < n; ++i) {
      if (!finite[i]) continue;
      for (std::size_t a = 0; a < 3; ++a) {
        lo_f[a] = std::min(lo_f[a], xyz[3 * i + a]);
        hi_f[a] = std::max(hi_f[a], xyz[3 * i + a]);
      }
    }
    int bits = 64;
    if (lo_f[0] <= hi_f[0]) {
      double cells = 1.0;
      for (std::size_t a = 0; a < 3; ++a) {
        lo_[a] = cell(lo_f[a]);
        dim_[a] = cell(hi_f[a]) - lo_[a] + 1;
        cells *= static_cast<double>(dim_[a]);
      }
      if (cells < 0x1p62) {
        linear_ = true;
        cells_ = static_cast<std::size_t>(cells);
        bits = 1;
        while (bits < 62 && static_cast<double>(std::uint64_t{1} << bits) < cells) ++bits;
      }
    }
    std::size_t n_finite = 0;
    for (std::size_t i = 0; i < n; ++i) n_finite += finite[i];
    std::vector<std::uint64_t> keys;
    // Few cells per point: a table of each cell's first slot, so that a lookup needs no search.
    dense_ = linear_ && cells_ <= 2 * n_finite + 4096 && cells_ < std::numeric_limits<std::uint32_t>::max();
    if (dense_ && cells_ <= kCountingSortCells) {
      // A counting sort by key (stable, so the order of the radix sort): its counts stay in
      // cache. Beyond, the radix sort: the counts of a scan's points in random order miss the
      // cache (10 M points of a generated wall, 12 M cells: 0.6 s).
      // Two threads, each a contiguous half of the points with its own counts; a cell's slots
      // hold the first half's points before the second's, so the order is the serial one.
      const int threads = n > (std::size_t{1} << 17) ? detail::kSearchThreads : 1;
      std::vector<std::uint32_t> key32(n, 0);
      std::vector<std::vector<std::uint32_t>> next(static_cast<std::size_t>(threads));
      detail::run_parallel(threads, [&](int t) {
        std::vector<std::uint32_t>& count = next[static_cast<std::size_t>(t)];
        count.assign(cells_, 0);
        const auto [b, e] = detail::share_of(n, t, threads);
        for (std::size_t i = b; i < e; ++i) {
          if (!finite[i]) continue;
          key32[i] = static_cast<std::uint32_t>(key_of(&xyz[3 * i]));
          ++count[key32[i]];
        }
      });
      table_.assign(cells_ + 1, 0);
      std::uint32_t running = 0;
      for (std::size_t k = 0; k < cells_; ++k) {
        table_[k] = running;
        for (auto& count : next) {  // counts become each thread's next slot in the cell
          const std::uint32_t c = count[k];
          count[k] = running;
          running += c;
        }
      }
      table_[cells_] = running;
      keys.resize(n_finite);
      index_.resize(n_finite);
      detail::run_parallel(threads, [&](int t) {
        std::vector<std::uint32_t>& slot_of = next[static_cast<std::size_t>(t)];
        const auto [b, e] = detail::share_of(n, t, threads);
        for (std::size_t i = b; i < e; ++i) {
          if (!finite[i]) continue;
          const std::uint32_t slot = slot_of[key32[i]]++;
          index_[slot] = static_cast<std::uint32_t>(i);
          keys[slot] = key32[i];
        }
      });
    } else {
      // The keys on two threads, each a contiguous half of the points written at its offset
      // among the finite ones (so in the serial order).
      const int threads = n > (std::size_t{1} << 17) ? detail::kSearchThreads : 1;
      std::vector<std::size_t> offset(static_cast<std::size_t>(threads) + 1, 0);
      for (int t = 0; t < threads; ++t) {
        const auto [b, e] = detail::share_of(n, t, threads);
        offset[static_cast<std::size_t>(t) + 1] = offset[static_cast<std::size_t>(t)] +
            static_cast<std::size_t>(std::count(finite.begin() + static_cast<std::ptrdiff_t>(b), finite.begin() + static_cast<std::ptrdiff_t>(e), std::uint8_t{1}));
      }
      std::vector<std::uint32_t> order(n_finite);
      keys.resize(n_finite);
      detail::run_parallel(threads, [&](int t) {
        const auto [b, e] = detail::share_of(n, t, threads);
        std::size_t o = offset[static_cast<std::size_t>(t)];
        for (std::size_t i = b; i < e; ++i) {
          if (!finite[i]) continue;
          keys[o] = key_of(&xyz[3 * i]);
          order[o++] = static_cast<std::uint32_t>(i);
        }
      });
      detail::radix_sort(keys, order, bits);
      index_ = std::move(order);
      if (dense_) {  // the table from the sorted keys, in one sequential pass
        table_.assign(cells_ + 1, 0);
        std::size_t s = 0;
        for (std::size_t k = 0; k <= cells_; ++k) {
          while (s < keys.size() && keys[s] < k) ++s;
          table_[k] = static_cast<std::uint32_t>(s);
        }
      }
    }
    pts_.resize(3 * index_.size());
    const std::size_t m = index_.size();
    const int gather_threads = m > (std::size_t{1} << 17) ? detail::kSearchThreads : 1;
    detail::run_parallel(gather_threads, [&](int t) {
      const auto [b, e] = detail::share_of(m, t, gather_threads);
      for (std::size_t s = b; s < e; ++s) {
        std::memcpy(&pts_[3 * s], &xyz[3 * static_cast<std::size_t>(index_[s])], 3 * sizeof(float));
      }
    });
    for (std::size_t s = 0; s < m; ++s) {
      if (s == 0 || keys[s] != keys[s - 1]) {
        keys_.push_back(keys[s]);
        start_.push_back(static_cast<std::uint32_t>(s));
      }
    }
    start_.push_back(static_cast<std::uint32_t>(index_.size()));
  }

  static constexpr std::int64_t kLimit = detail::kVoxelLimit;
  /// Boxes of at most this many cells are sorted by counting (its counts fit in the cache).
  static constexpr std::size_t kCountingSortCells = std::size_t{1} << 21;
  static constexpr std::uint64_t kAbsent = ~std::uint64_t{0};  ///< a key no hashed point has

  /// A voxel coordinate and a voxel's key without the box: voxel_keys.hpp.
  static std::int64_t cell_index(float v, double inv_edge) { return detail::voxel_index(static_cast<double>(v), inv_edge); }
  static std::uint64_t pack21(std::int64_t x, std::int64_t y, std::int64_t z) { return detail::pack_voxel21(x, y, z); }
  std::int64_t cell(float v) const { return cell_index(v, inv_); }
  /// The key of cell (x, y, z), each coordinate clamped to ±kLimit (so keys repeat beyond it):
  /// the linear index in the occupied box, or kAbsent outside it; without the box (more than
  /// 2^62 cells), 21 bits per coordinate.
  std::uint64_t pack(std::int64_t x, std::int64_t y, std::int64_t z) const {
    x = std::clamp(x, -kLimit, kLimit), y = std::clamp(y, -kLimit, kLimit), z = std::clamp(z, -kLimit, kLimit);
    if (linear_) {
      x -= lo_[0], y -= lo_[1], z -= lo_[2];
      if (x < 0 || y < 0 || z < 0 || x >= dim_[0] || y >= dim_[1] || z >= dim_[2]) return kAbsent;
      return (static_cast<std::uint64_t>(x) * static_cast<std::uint64_t>(dim_[1]) + static_cast<std::uint64_t>(y)) *
                 static_cast<std::uint64_t>(dim_[2]) + static_cast<std::uint64_t>(z);
    }
    return pack21(x, y, z);
  }
  std::uint64_t key_of(const float* p) const { return pack(cell(p[0]), cell(p[1]), cell(p[2])); }

  /// Visits the hashed points (sorted slot s, its xyz, its original index) of the voxels within
  /// `reach` voxels of q's voxel, q's own voxel first; f returns false to stop.
  template <class F>
  void visit(const float* q, int reach, F&& f) const {
    visit(q, reach, reach, std::forward<F>(f));
  }
  /// As visit(q, reach, f), over reach voxels each way in x and y and reach_z in z.
  template <class F>
  void visit(const float* q, int reach, int reach_z, F&& f) const {
    const std::int64_t cx = cell(q[0]), cy = cell(q[1]), cz = cell(q[2]);
    const bool at_limit = std::max({std::abs(cx), std::abs(cy), std::abs(cz)}) + std::max(reach, reach_z) > kLimit;
    std::vector<std::uint64_t> seen;  // only at the clamp limit, where keys can repeat
    auto run = [&](std::uint64_t k) {
      if (k == kAbsent) return true;
      if (at_limit) {
        if (std::find(seen.begin(), seen.end(), k) != seen.end()) return true;
        seen.push_back(k);
      }
      std::uint32_t first = 0, last = 0;
      if (dense_) {
        first = table_[k], last = table_[k + 1];
      } else {
        const auto it = std::lower_bound(keys_.begin(), keys_.end(), k);
        if (it == keys_.end() || *it != k) return true;
        const auto v = static_cast<std::size_t>(it - keys_.begin());
        first = start_[v], last = start_[v + 1];
      }
      for (std::uint32_t s = first; s < last; ++s) {
        if (!f(s, &pts_[3 * static_cast<std::size_t>(s)], index_[s])) return false;
      }
      return true;
    };
    if (!run(pack(cx, cy, cz))) return;
    for (int dz = -reach_z; dz <= reach_z; ++dz)
      for (int dy = -reach; dy <= reach; ++dy)
        for (int dx = -reach; dx <= reach; ++dx) {
          if (dx == 0 && dy == 0 && dz == 0) continue;
          if (!run(pack(cx + dx, cy + dy, cz + dz))) return;
        }
  }

  double edge() const { return edge_; }
  std::size_t size() const { return index_.size(); }
  /// The hashed point at sorted slot s (voxel order) and its original index.
  const float* point(std::size_t s) const { return &pts_[3 * s]; }
  /// Occupied voxels, in key order; voxel v holds slots first_slot(v) .. first_slot(v + 1) − 1.
  std::size_t voxels() const { return keys_.size(); }
  std::size_t first_slot(std::size_t v) const { return start_[v]; }
  std::uint32_t original(std::size_t s) const { return index_[s]; }

 private:
  double edge_, inv_;
  bool linear_ = false;           // keys are linear indices in the box lo_ + [0, dim_)
  std::int64_t lo_[3] = {0, 0, 0}, dim_[3] = {1, 1, 1};
  std::size_t cells_ = 0;         // the box's cells (linear keys)
  bool dense_ = false;            // table_[key] .. table_[key + 1]: the slots of cell `key`
  std::vector<std::uint32_t> table_;
  std::vector<std::uint64_t> keys_;
  std::vector<std::uint32_t> start_, index_;
  std::vector<float> pts_;
};

float dist_sq(const float* a, const float* b) {
  const float dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
  return dx * dx + dy * dy + dz * dz;
}

/// The points of a 3 × N matrix (x y z per column, metres) as float offsets from `centre_m`,
/// 3·N interleaved in `local` (0 for a non-finite point), and `finite` (N flags, 1 when all
/// three coordinates are finite): the local frame of the point tests (float keeps 1e-7 of the
/// distance from the centre). Two threads above 2^17 points, each a contiguous share. No errors.
void local_floats(const Eigen::Matrix3Xd& xyz_m, const Eigen::Vector3d& centre_m, std::vector<float>& local,
                  std::vector<std::uint8_t>& finite) {
  const auto n = static_cast<std::size_t>(xyz_m.cols());
  local.assign(3 * n, 0.0f);
  finite.assign(n, 0);
  const int threads = n > (std::size_t{1} << 17) ? detail::kSearchThreads : 1;
  detail::run_parallel(threads, [&](int t) {
    const auto [b, e] = detail::share_of(n, t, threads);
    for (std::size_t i = b; i < e; ++i) {
      const Eigen::Vector3d p = xyz_m.col(static_cast<Eigen::Index>(i));
      if (!p.allFinite()) continue;
      finite[i] = 1;
      for (int a = 0; a < 3; ++a) local[3 * i + static_cast<std::size_t>(a)] = static_cast<float>(p[a] - centre_m[a]);
    }
  });
}

/// Median nearest-neighbour distance [m] of up to 4096 evenly strided finite points, each
/// point's nearest among the finite points in the 3 × 3 × 3 voxels (edge e) about its own (the
/// voxels of VoxelHash: coordinates clamped at ±kLimit cells). Exact when the median is at most
/// e: every distance up to e is then exact and every larger one stays larger, so the median does
/// not depend on e. Only the points in the samples' voxels are collected (one pass over all
/// points, a table of the wanted voxels), not a hash of every point: 4096 queries do not pay for
/// sorting millions of points.
///
/// The edge: a pilot pass counts the points c in each sample's own voxel of edge start_edge_m;
/// on a surface the spacing is about e / √c, so e starts at twice the median of that (at most
/// start_edge_m) and grows 4-fold until the median is within it, up to start_edge_m · 4⁷ (the
/// range before the pilot); when the median is not within that either, start_edge_m · 4⁸ (a
/// lower bound of it). A start edge 12 spacings wide (a 10⁷-point wall at N = 800) put half of
/// all points in the wanted voxels and a thousand candidates about each sample: 0.77 s of CPU
/// against 0.36 s now (outlier_bench BM_MedianSpacing/10). start_edge_m: finite, > 0.
double median_spacing(const std::vector<float>& xyz, const std::vector<std::uint8_t>& finite, double start_edge_m) {
  std::vector<std::uint32_t> sample;
  const std::size_t n = finite.size();
  std::size_t n_finite = 0;
  for (auto f : finite) n_finite += f;
  const std::size_t stride = std::max<std::size_t>(1, n_finite / 4096);
  // Every stride-th finite point (a countdown: a 64-bit division per point cost more than the rest).
  for (std::size_t i = 0, left = 0; i < n; ++i) {
    if (!finite[i]) continue;
    if (left == 0) {
      sample.push_back(static_cast<std::uint32_t>(i));
      left = stride;
    }
    --left;
  }
  if (sample.empty()) return 0.0;
  const int threads = n > (std::size_t{1} << 17) ? detail::kSearchThreads : 1;
  auto key_fn = [](double edge) {
    return [inv = 1.0 / edge](const float* p) {
      return VoxelHash::pack21(VoxelHash::cell_index(p[0], inv), VoxelHash::cell_index(p[1], inv),
                               VoxelHash::cell_index(p[2], inv));
    };
  };
  // Calls f(t, w, i) for every finite point i whose key (key_of) is wanted key w, t being the
  // calling thread's number (of `threads`, each over a contiguous share of the points).
  auto pass = [&](const WantedKeys& table, auto key_of, auto&& f) {
    detail::run_parallel(threads, [&](int t) {
      const auto [b, e] = detail::share_of(n, t, threads);
      for (std::size_t i = b; i < e; ++i) {
        if (!finite[i]) continue;
        const std::uint32_t w = table.find(key_of(&xyz[3 * i]));
        if (w != WantedKeys::kNone) f(t, w, static_cast<std::uint32_t>(i));
      }
    });
  };

  const double max_edge = start_edge_m * 16384.0;  // start_edge_m · 4⁷
  double edge = start_edge_m;
  {  // the pilot: points in each sample's own voxel of the start edge
    const auto key_of = key_fn(start_edge_m);
    std::vector<std::uint64_t> own(sample.size());
    for (std::size_t k = 0; k < sample.size(); ++k) own[k] = key_of(&xyz[3 * static_cast<std::size_t>(sample[k])]);
    const WantedKeys table(own);
    std::vector<std::vector<std::uint32_t>> count(static_cast<std::size_t>(threads), std::vector<std::uint32_t>(table.size(), 0));
    pass(table, key_of, [&](int t, std::uint32_t w, std::uint32_t) { ++count[static_cast<std::size_t>(t)][w]; });
    std::vector<double> guess(sample.size());
    for (std::size_t k = 0; k < sample.size(); ++k) {
      const std::uint32_t w = table.find(own[k]);
      std::uint32_t c = 0;
      for (const auto& part : count) c += part[w];
      guess[k] = start_edge_m / std::sqrt(static_cast<double>(std::max<std::uint32_t>(c, 1)));
    }
    auto mid = guess.begin() + static_cast<std::ptrdiff_t>(guess.size() / 2);
    std::nth_element(guess.begin(), mid, guess.end());
    edge = std::min(start_edge_m, 2.0 * *mid);
  }
  for (;; edge = std::min(4.0 * edge, max_edge)) {
    const auto key_of = key_fn(edge);
    // Each sample's 27 voxel keys, all of them in one list (27 per sample: a key repeated at the
    // clamp limit only visits a voxel twice, which leaves a minimum as it is; the table keeps
    // each key once, so no sort is needed).
    std::vector<std::uint64_t> wanted(27 * sample.size());
    const double inv = 1.0 / edge;
    for (std::size_t k = 0; k < sample.size(); ++k) {
      const float* q = &xyz[3 * static_cast<std::size_t>(sample[k])];
      const std::int64_t cx = VoxelHash::cell_index(q[0], inv), cy = VoxelHash::cell_index(q[1], inv),
                         cz = VoxelHash::cell_index(q[2], inv);
      std::uint64_t* keys = &wanted[27 * k];
      std::size_t m = 0;
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) keys[m++] = VoxelHash::pack21(cx + dx, cy + dy, cz + dz);
    }
    const WantedKeys table(wanted);
    // The points in wanted voxels, grouped by voxel.
    const detail::KeyGroups groups = detail::group_by_wanted_key(n, table, threads, [&](std::size_t i, std::uint64_t& key) {
      if (!finite[i]) return false;
      key = key_of(&xyz[3 * i]);
      return true;
    });
    const std::vector<std::uint32_t>& first = groups.first;
    const std::vector<std::uint32_t>& members = groups.members;
    // Each sample's nearest distance, the samples shared by the threads (each writes its own).
    std::vector<double> nn(sample.size());
    const int nn_threads = sample.size() > 1024 ? threads : 1;
    detail::run_parallel(nn_threads, [&](int t) {
      const auto [kb, ke] = detail::share_of(sample.size(), t, nn_threads);
      for (std::size_t k = kb; k < ke; ++k) {
        const std::uint32_t i = sample[k];
        const float* q = &xyz[3 * static_cast<std::size_t>(i)];
        float best = std::numeric_limits<float>::infinity();
        for (std::size_t a = 0; a < 27; ++a) {
          const std::uint32_t w = table.find(wanted[27 * k + a]);
          for (std::uint32_t m = first[w]; m < first[w + 1]; ++m) {
            const std::uint32_t j = members[m];
            if (j != i) best = std::min(best, dist_sq(&xyz[3 * static_cast<std::size_t>(j)], q));
          }
        }
        nn[k] = std::sqrt(static_cast<double>(best));  // exact when ≤ edge
      }
    });
    auto mid = nn.begin() + static_cast<std::ptrdiff_t>(nn.size() / 2);
    std::nth_element(nn.begin(), mid, nn.end());
    if (*mid <= edge) return *mid;
    if (edge >= max_edge) return 4.0 * max_edge;  // never within reach: start_edge_m · 4⁸, as before the pilot
  }
}

/// The point test: flags[i] = 1 when finite point i (of n, the hashed ones) has fewer than
/// min_neighbours other points within radius_m (exact distances; counting stops at the
/// minimum); non-finite points, which the hash leaves out, get 0. `hash` has an edge of at least
/// radius_m. Used by check_input and remove_isolated_points, so the filter and the verdict apply
/// one rule. Two threads, each a contiguous half of the hash's voxel order (each writes only its
/// own points' flags).
std::vector<std::uint8_t> isolated_flags(const VoxelHash& hash, std::size_t n, double radius_m, int min_neighbours) {
  const auto rho2 = static_cast<float>(radius_m * radius_m);
  std::vector<std::uint8_t> isolated(n, 0);
  // In the hash's voxel order (the hashed points are exactly the finite ones): consecutive
  // queries look up the same voxels, so their searches stay in cache. A point's own voxel is
  // counted first without a key search; most points have enough neighbours there, and the
  // others are counted again over all 27 voxels.
  const std::size_t voxels = hash.voxels();
  const int threads = hash.size() > 20000 ? detail::kSearchThreads : 1;
  detail::run_parallel(threads, [&](int t) {
    const auto [vb, ve] = detail::share_of(voxels, t, threads);
    for (std::size_t v = vb; v < ve; ++v) {
      const std::size_t first = hash.first_slot(v), last = hash.first_slot(v + 1);
      for (std::size_t s = first; s < last; ++s) {
        const std::uint32_t i = hash.original(s);
        const float* q = hash.point(s);
        int count = 0;
        for (std::size_t o = first; o < last && count < min_neighbours; ++o) {
          if (o != s && dist_sq(hash.point(o), q) <= rho2) ++count;
        }
        if (count < min_neighbours) {
          count = 0;
          hash.visit(q, 1, [&](std::uint32_t, const float* p, std::uint32_t j) {
            if (j != i && dist_sq(p, q) <= rho2) ++count;
            return count < min_neighbours;
          });
        }
        isolated[i] = count < min_neighbours ? 1 : 0;
      }
    }
  });
  return isolated;
}

/// Whether every finite point of `local` lies within limit_m of its origin on each axis.
bool coordinates_within(const std::vector<float>& local, const std::vector<std::uint8_t>& finite, double limit_m) {
  for (std::size_t i = 0; i < finite.size(); ++i) {
    if (!finite[i]) continue;
    for (std::size_t a = 0; a < 3; ++a) {
      if (!(std::abs(static_cast<double>(local[3 * i + a])) <= limit_m)) return false;
    }
  }
  return true;
}

/// Whether InputCheckScope::near can spare tests (see there): the filters' radius filter_m at
/// most 0.9 × the test's radius_m, and every finite point of `local` (3 per point, the check's
/// frame) within 10^4 · radius_m of its origin per axis. The filters' frames are centred inside
/// the points' box, so their coordinates are at most twice as large; each float coordinate is
/// off by at most 2^-24 of its size, so a distance by at most 2·√3·2^-24 of the two frames'
/// sizes, about 6.2e-7 · 3 · 10^4 · radius_m ≈ 0.02 · radius_m, with the float products' few
/// 1e-7 relative: inside the 0.1 · radius_m between the two radii.
bool near_flags_usable(const std::vector<float>& local, const std::vector<std::uint8_t>& finite, double filter_m, double radius_m) {
  if (!(filter_m <= 0.9 * radius_m) || !(radius_m > 0.0)) return false;
  return coordinates_within(local, finite, 1e4 * radius_m);
}

/// A search of VoxelHash::visit about q over `reach` voxels each way in x and y and reach_z in z.
struct VoxelSearch {
  std::array<float, 3> q;
  int reach = 1, reach_z = 1;
};

/// Flags (1 per point of `finite`) of the finite points of `local` that lie in a voxel one of
/// the searches visits, in the voxels of a VoxelHash of edge edge_m (its inverse edge, floor and
/// clamp; packed without a box, so named independently of which points are hashed): a
/// VoxelHash of edge edge_m over only these points gives every such search what a hash of all
/// the points gives it. `count` receives their number.
std::vector<std::uint8_t> points_about(const std::vector<float>& local, const std::vector<std::uint8_t>& finite, double edge_m,
                                       const std::vector<VoxelSearch>& searches, std::size_t& count) {
  const std::size_t n = finite.size();
  std::vector<std::uint8_t> take(n, 0);
  count = 0;
  if (searches.empty()) return take;
  const double inv = 1.0 / edge_m;
  auto voxel_key = [inv](const float* q) {
    return VoxelHash::pack21(VoxelHash::cell_index(q[0], inv), VoxelHash::cell_index(q[1], inv), VoxelHash::cell_index(q[2], inv));
  };
  std::vector<std::uint64_t> marked;
  for (const VoxelSearch& v : searches) {
    const std::int64_t cx = VoxelHash::cell_index(v.q[0], inv), cy = VoxelHash::cell_index(v.q[1], inv),
                       cz = VoxelHash::cell_index(v.q[2], inv);
    for (int dx = -v.reach; dx <= v.reach; ++dx)
      for (int dy = -v.reach; dy <= v.reach; ++dy)
        for (int dz = -v.reach_z; dz <= v.reach_z; ++dz) marked.push_back(VoxelHash::pack21(cx + dx, cy + dy, cz + dz));
  }
  std::sort(marked.begin(), marked.end());
  marked.erase(std::unique(marked.begin(), marked.end()), marked.end());
  const detail::KeyBits filter(marked, 64);  // most points in no marked voxel pass without a search
  // Before both, the marked voxels' x-y columns (ColumnTable): most of a tile's points lie in
  // none of them, and are passed over on their x and y alone (forty-seventh session, 2026-11-28).
  detail::ColumnTable columns(inv);
  for (const VoxelSearch& v : searches) {
    const std::int64_t cx = VoxelHash::cell_index(v.q[0], inv), cy = VoxelHash::cell_index(v.q[1], inv);
    columns.add(cx - v.reach, cx + v.reach, cy - v.reach, cy + v.reach);
  }
  (void)columns.build();
  const detail::ColumnTable::Probe probe = columns.probe();
  const int threads = n > (std::size_t{1} << 17) ? detail::kSearchThreads : 1;
  std::vector<std::size_t> taken(static_cast<std::size_t>(threads), 0);
  detail::run_parallel(threads, [&, probe](int t) {
    const auto [b, e] = detail::share_of(n, t, threads);
    std::size_t c = 0;
    for (std::size_t i = b; i < e; ++i) {
      if (!finite[i]) continue;
      if (!probe.may_hold(&local[3 * i])) continue;  // in no marked voxel's column
      const std::uint64_t key = voxel_key(&local[3 * i]);
      if (!filter.maybe(key) || !std::binary_search(marked.begin(), marked.end(), key)) continue;
      take[i] = 1;
      ++c;
    }
    taken[static_cast<std::size_t>(t)] = c;
  });
  for (const std::size_t c : taken) count += c;
  return take;
}

/// isolated_flags for the finite points whose near flag is 0 (the others get 0, which the full
/// test gives them: InputCheckScope::near), with a voxel hash (edge radius_m, the full test's
/// voxels) of only the points in the 27 voxels about each tested point: every point the full
/// test's search about a tested point visits, so each flag is the full test's. `tested` and
/// `hashed` receive the counts (InputCheck::isolation_tested, isolation_hashed).
std::vector<std::uint8_t> isolated_flags_about(const std::vector<float>& local, const std::vector<std::uint8_t>& finite,
                                               const std::vector<std::uint8_t>& near, double radius_m, int min_neighbours,
                                               std::size_t& tested, std::size_t& hashed) {
  const std::size_t n = finite.size();
  std::vector<std::uint8_t> isolated(n, 0);
  std::vector<std::uint32_t> test;
  std::vector<VoxelSearch> searches;
  for (std::size_t i = 0; i < n; ++i) {
    if (!finite[i] || near[i]) continue;
    test.push_back(static_cast<std::uint32_t>(i));
    searches.push_back({{local[3 * i], local[3 * i + 1], local[3 * i + 2]}, 1, 1});
  }
  tested = test.size();
  hashed = 0;
  if (test.empty()) return isolated;
  const VoxelHash hash(local, points_about(local, finite, radius_m, searches, hashed), radius_m);
  const auto rho2 = static_cast<float>(radius_m * radius_m);
  for (const std::uint32_t i : test) {
    const float* q = &local[3 * static_cast<std::size_t>(i)];
    int count = 0;
    hash.visit(q, 1, [&](std::uint32_t, const float* p, std::uint32_t j) {
      if (j != i && dist_sq(p, q) <= rho2) ++count;
      return count < min_neighbours;
    });
    isolated[i] = count < min_neighbours ? 1 : 0;
  }
  return isolated;
}

struct Coord3Hash {
  std::size_t operator()(const std::array<std::uint64_t, 3>& k) const {
    std::uint64_t h = k[0] * 0x9E3779B97F4A7C15ULL;
    h ^= k[1] + 0x9E3779B97F4A7C15ULL + (h << 6) + (h >> 2);
    h ^= k[2] + 0x9E3779B97F4A7C15ULL + (h << 6) + (h >> 2);
    return static_cast<std::size_t>(h ^ (h >> 31));
  }
};

std::array<std::uint64_t, 3> bits_of(const double* p) {
  std::array<std::uint64_t, 3> k{};
  for (int a = 0; a < 3; ++a) {
    const double v = p[a] == 0.0 ? 0.0 : p[a];  // -0 == +0
    std::memcpy(&k[static_cast<std::size_t>(a)], &v, sizeof v);
  }
  return k;
}

struct FloodScratch {
  std::vector<std::size_t> stack, visited;
};

/// Whether the valid cells reachable from (r, c) through 8-neighbours whose heights differ by
/// at most step_m from one another number more than max_cells: the cell then continues a larger
/// surface (e.g. the thin visible strip of a far surface along an occlusion edge), not a spike.
/// Bounded: visits at most max_cells + 1 cells.
bool part_of_large_surface(const HeightField& grid, int r0, int c0, double step_m, int max_cells, FloodScratch& s) {
  const int rows = grid.rows(), cols = grid.cols();
  const auto ucols = static_cast<std::size_t>(cols);
  s.stack.assign(1, static_cast<std::size_t>(r0) * ucols + static_cast<std::size_t>(c0));
  s.visited.assign(1, s.stack.front());
  while (!s.stack.empty()) {
    const std::size_t k = s.stack.back();
    s.stack.pop_back();
    const int r = static_cast<int>(k / ucols), c = static_cast<int>(k % ucols);
    const double z = grid.at(r, c);
    for (int dr = -1; dr <= 1; ++dr)
      for (int dc = -1; dc <= 1; ++dc) {
        const int rr = r + dr, cc = c + dc;
        if ((dr == 0 && dc == 0) || rr < 0 || rr >= rows || cc < 0 || cc >= cols) continue;
        const float v = grid.at(rr, cc);
        if (std::isnan(v) || std::abs(static_cast<double>(v) - z) > step_m) continue;
        const std::size_t kk = static_cast<std::size_t>(rr) * ucols + static_cast<std::size_t>(cc);
        if (std::find(s.visited.begin(), s.visited.end(), kk) != s.visited.end()) continue;
        s.visited.push_back(kk);
        if (static_cast<int>(s.visited.size()) > max_cells) return true;
        s.stack.push_back(kk);
      }
  }
  return false;
}

/// The normal equations of the least-squares plane dz = a + b·dx + c·dy through cells at
/// offsets (dx, dy) [cells] from a cell, dz [m] their heights above it, summed as scalars in the
/// order the cells are added. The offsets' products are small integers (exact), and each
/// right-hand side sum adds q_i · dz in turn as Eigen's `a += q * q.transpose(); rhs += q * dz`
/// did with q = (1, dx, dy), so the plane is that vector form's to the bit (kept as scalars
/// for the sanitizer builds: see plane_offset_at).
struct PlaneSums {
  double n = 0.0, sx = 0.0, sy = 0.0, sxx = 0.0, sxy = 0.0, syy = 0.0, sz = 0.0, sxz = 0.0, syz = 0.0;
  void add(double dx, double dy, double dz) {
    n += 1.0;
    sx += dx;
    sy += dy;
    sxx += dx * dx;
    sxy += dx * dy;
    syy += dy * dy;
    sz += dz;
    sxz += dx * dz;
    syz += dy * dz;
  }
  /// (a, b, c) [m, m/cell, m/cell]; nullopt when the cells lie on one line (LDLT fails or its
  /// reciprocal condition is under 1e-9) or the solution is not finite. The solve is
  /// plane_solve.cpp's, which the sanitizer builds leave uninstrumented.
  [[nodiscard]] std::optional<Eigen::Vector3d> solve() const {
    Eigen::Matrix3d a;
    a << n, sx, sy, sx, sxx, sxy, sy, sxy, syy;
    return detail::solve_plane_ldlt(a, Eigen::Vector3d(sz, sxz, syz), 1e-9);
  }
};

/// The least-squares plane z = a + b·dc + c·dr (dc, dr: cell offsets) through the valid cells
/// of the (2h+1)² window about (r, c), the cell itself excluded, fitted once, then again
/// without the cells more than trim_m above the first plane; its height at the cell's node
/// [m]. nullopt when a fit has fewer than 3 cells or they lie on one line. noinline, as
/// plane_offset_at below and for the same reason.
[[gnu::noinline]] std::optional<double> trimmed_plane_at(const HeightField& grid, int r, int c, int h, double trim_m) {
  const int rows = grid.rows(), cols = grid.cols();
  const auto z0 = static_cast<double>(grid.at(r, c));
  std::optional<Eigen::Vector3d> plane;
  for (int pass = 0; pass < 2; ++pass) {
    PlaneSums sums;
    for (int rr = std::max(0, r - h); rr <= std::min(rows - 1, r + h); ++rr)
      for (int cc = std::max(0, c - h); cc <= std::min(cols - 1, c + h); ++cc) {
        const float v = grid.at(rr, cc);
        if ((rr == r && cc == c) || std::isnan(v)) continue;
        const auto dx = static_cast<double>(cc - c), dy = static_cast<double>(rr - r);
        const double dz = static_cast<double>(v) - z0;
        if (plane && dz - plane->dot(Eigen::Vector3d(1.0, dx, dy)) > trim_m) continue;
        sums.add(dx, dy, dz);
      }
    if (sums.n < 3.0) return std::nullopt;
    plane = sums.solve();
    if (!plane) return std::nullopt;
  }
  return z0 + (*plane)(0);
}

/// The least-squares plane z − z(r, c) = a + b·dc + c·dr (dc, dr: cell offsets) through the
/// valid cells of rows [r0, r1) and columns [c0, c1) but (r, c) itself (PlaneSums): a [m], the
/// plane's height at the cell's node above the cell. nullopt when the cells lie on one line or
/// the solution is not finite. The caller checks that at least 3 other cells are valid. Kept
/// out of remove_spike_points' cell verdict (noinline), which judges every cell: its frame
/// stays small (under ASan 536 bytes where it was 6 968 with the fit inline), and the sanitizer builds,
/// which poison a frame's temporaries on every call, judge the full windows quickly.
[[gnu::noinline]] std::optional<double> plane_offset_at(const HeightField& grid, int r, int c, int r0, int r1, int c0,
                                                         int c1) {
  const auto z = static_cast<double>(grid.at(r, c));
  PlaneSums sums;
  for (int rr = r0; rr < r1; ++rr)
    for (int cc = c0; cc < c1; ++cc) {
      const float v = grid.at(rr, cc);
      if ((rr == r && cc == c) || std::isnan(v)) continue;
      sums.add(static_cast<double>(cc - c), static_cast<double>(rr - r), static_cast<double>(v) - z);
    }
  const std::optional<Eigen::Vector3d> coef = sums.solve();
  if (!coef) return std::nullopt;
  return (*coef)(0);
}

/// Whether the valid cell (r, c) stands more than height_m above every valid 8-neighbour (at
/// least one): a peak one cell wide.
bool lone_peak(const HeightField& grid, int r, int c, double height_m) {
  float top = -std::numeric_limits<float>::infinity();
  for (int rr = std::max(0, r - 1); rr <= std::min(grid.rows() - 1, r + 1); ++rr)
    for (int cc = std::max(0, c - 1); cc <= std::min(grid.cols() - 1, c + 1); ++cc) {
      const float v = grid.at(rr, cc);
      if ((rr != r || cc != c) && !std::isnan(v)) top = std::max(top, v);
    }
  return static_cast<double>(grid.at(r, c)) - static_cast<double>(top) > height_m;
}

/// Whether the cell (r, c) has a no-data cell among its 8 neighbours inside the grid: the rim
/// of the surface (a silhouette, a hole's edge). The grid's border is not a rim: a window of a
/// tiled run has one that the whole grid does not.
bool rim_cell(const HeightField& grid, int r, int c) {
  const GridGeometry& g = grid.geometry();
  for (int rr = std::max(0, r - 1); rr <= std::min(g.rows - 1, r + 1); ++rr)
    for (int cc = std::max(0, c - 1); cc <= std::min(g.cols - 1, c + 1); ++cc) {
      if (std::isnan(grid.at(rr, cc))) return true;
    }
  return false;
}

[[noreturn]] void bad_option(const std::string& key, double value, const std::string& expected) {
  throw ConfigError("cross_check." + key + " = " + format_number(value) + ": expected " + expected);
}

std::string pct(double fraction) { return format_number(100.0 * fraction, 2, NumberStyle::kFixed) + " %"; }
std::string mm(double metres) { return format_number(metres * 1e3, 3) + " mm"; }

}  // namespace

void check_honest_options(const HonestCheckOptions& o) {
  if (!(o.tolerance_m > 0.0) || !std::isfinite(o.tolerance_m)) bad_option("tolerance_m", o.tolerance_m, "a distance > 0 [m]");
  if (!(o.hidden_band_m > 0.0) || !std::isfinite(o.hidden_band_m)) bad_option("hidden_band_m", o.hidden_band_m, "a distance > 0 [m]");
  if (!(o.isolation_radius_spacings >= 1.0 && o.isolation_radius_spacings <= 1000.0))
    bad_option("isolation_radius_spacings", o.isolation_radius_spacings, "a number in [1, 1000]");
  if (!(o.spacing_m >= 0.0) || !std::isfinite(o.spacing_m)) {
    throw ConfigError("HonestCheckOptions::spacing_m (set by the run, not a config key) = " + format_number(o.spacing_m) +
                      ": expected a spacing >= 0 [m] (0: estimate it)");
  }
  if (o.isolation_min_neighbours < 1 || o.isolation_min_neighbours > 1000)
    bad_option("isolation_min_neighbours", o.isolation_min_neighbours, "an integer in [1, 1000]");
  if (o.spike_window_cells < 3 || o.spike_window_cells > 15 || o.spike_window_cells % 2 == 0)
    bad_option("spike_window_cells", o.spike_window_cells, "an odd integer in [3, 15]");
  if (!(o.spike_min_height_m > 0.0) || !std::isfinite(o.spike_min_height_m))
    bad_option("spike_min_height_m", o.spike_min_height_m, "a height > 0 [m]");
  if (!(o.confirm_footprint_m >= 0.0) || !std::isfinite(o.confirm_footprint_m)) {
    throw ConfigError("honest cross-check: HonestCheckOptions::confirm_footprint_m = " + format_number(o.confirm_footprint_m) +
                      ": expected a distance ≥ 0 [m] ((grid.splat_radius_cells + √2/2) × cell size, set by run)");
  }
  if (!(o.spike_mad_factor > 0.0) || !std::isfinite(o.spike_mad_factor))
    bad_option("spike_mad_factor", o.spike_mad_factor, "a number > 0");
  if (o.spike_max_cells < 1 || o.spike_max_cells > 10000) bad_option("spike_max_cells", o.spike_max_cells, "an integer in [1, 10000]");
  if (o.island_max_cells < 1) bad_option("island_max_cells", o.island_max_cells, "an integer ≥ 1");
  if (o.max_spike_cells < 0) bad_option("max_spike_cells", o.max_spike_cells, "an integer ≥ 0");
  if (o.max_spikes_kept_cells < 0) bad_option("max_spikes_kept_cells", o.max_spikes_kept_cells, "an integer ≥ 0");
  if (o.max_island_cells < 0) bad_option("max_island_cells", o.max_island_cells, "an integer ≥ 0");
  for (const auto& [key, v] : {std::pair{"max_removed_fraction", o.max_removed_fraction},
                               std::pair{"max_surface_lost_fraction", o.max_surface_lost_fraction},
                               std::pair{"min_visible_on_surface_fraction", o.min_visible_on_surface_fraction},
                               std::pair{"min_supported_fraction", o.min_supported_fraction}}) {
    if (!(v >= 0.0 && v <= 1.0)) bad_option(key, v, "a fraction in [0, 1]");
  }
  if (!(o.max_filter_threshold_spacings > 0.0) || !std::isfinite(o.max_filter_threshold_spacings))
    bad_option("max_filter_threshold_spacings", o.max_filter_threshold_spacings, "a number > 0");
}

InputCheck check_input(const Eigen::Matrix3Xd& as_read_m, const Cloud& kept_m, const HeightField& grid,
                       const HonestCheckOptions& o, double voxel_leaf_m, GridSpikes* spikes,
                       const CellBuffer<std::uint8_t>* cell_flags, const InputCheckScope* scope) {
  const auto t0 = Clock::now();
  check_honest_options(o);
  const GridGeometry& g = grid.geometry();
  InputCheck out;
  const std::size_t n = static_cast<std::size_t>(as_read_m.cols());
  if (scope && (!scope->owned || scope->owned->size() != n || !(scope->spacing_m > 0.0) ||
                (scope->removed && scope->removed->size() != n) || (scope->near && scope->near->size() != n))) {
    throw std::invalid_argument("check_input: a scope needs an owned flag per point (and a removed and a near flag, if any) and a spacing > 0");
  }
  auto owns = [&](std::size_t i) { return !scope || (*scope->owned)[i] != 0; };
  for (std::size_t i = 0; i < n; ++i) out.points += owns(i) ? 1U : 0U;

  // Box of the valid samples (a tile: the whole grid's); local frame centred on it (float keeps
  // 1e-7 of the distance; a tile: on its window, so its points stay near the origin).
  Eigen::Vector3d box_lo, box_hi, centre;
  if (scope) {
    box_lo = scope->valid_lo;
    box_hi = scope->valid_hi;
    centre = Eigen::Vector3d(g.x_of_col(0.5 * (g.cols - 1)), g.y_of_row(0.5 * (g.rows - 1)), 0.5 * (box_lo.z() + box_hi.z()));
  } else {
    int r_lo = g.rows, r_hi = -1, c_lo = g.cols, c_hi = -1;
    float z_lo = std::numeric_limits<float>::infinity(), z_hi = -z_lo;
    for (int r = 0; r < g.rows; ++r)
      for (int c = 0; c < g.cols; ++c) {
        const float z = grid.at(r, c);
        if (std::isnan(z)) continue;
        r_lo = std::min(r_lo, r), r_hi = std::max(r_hi, r), c_lo = std::min(c_lo, c), c_hi = std::max(c_hi, c);
        z_lo = std::min(z_lo, z), z_hi = std::max(z_hi, z);
      }
    if (r_hi < 0) throw InputError("check_input: the grid has no valid cell");
    box_lo = Eigen::Vector3d(g.x_of_col(c_lo), g.y_of_row(r_lo), z_lo);
    box_hi = Eigen::Vector3d(g.x_of_col(c_hi), g.y_of_row(r_hi), z_hi);
    centre = 0.5 * (box_lo + box_hi);
  }
  const double diag = std::max((box_hi - box_lo).norm(), g.cell_size_m);

  std::vector<float> local;
  std::vector<std::uint8_t> finite;
  local_floats(as_read_m, centre, local, finite);

  // 1. Removed by the filters.
  std::vector<std::uint8_t> removed(n, 1);
  // The filters keep the input's order (they only drop points), so the kept points are a
  // subsequence of the input: one greedy pass matches them by exact coordinates (equal points
  // are interchangeable: every figure below depends on coordinates only). Should a stage ever
  // reorder points, the pass does not reach the end of kept_m and the multiset match decides.
  bool matched = false;
  if (scope && scope->removed) {
    // Known per point (a tiled run's kept-point mask); a non-finite point is removed regardless.
    for (std::size_t i = 0; i < n; ++i) removed[i] = finite[i] && (*scope->removed)[i] == 0 ? 0 : 1;
    matched = true;
  } else if (voxel_leaf_m <= 0.0) {
    std::size_t j = 0;
    const auto m = static_cast<std::size_t>(kept_m.xyz.cols());
    for (std::size_t i = 0; i < n && j < m; ++i) {
      if (!finite[i]) continue;
      if (bits_of(as_read_m.col(static_cast<Eigen::Index>(i)).data()) ==
          bits_of(kept_m.xyz.col(static_cast<Eigen::Index>(j)).data())) {
        removed[i] = 0;
        ++j;
      }
    }
    matched = j == m;
    if (!matched) std::fill(removed.begin(), removed.end(), std::uint8_t{1});
  }
  if (matched) {
  } else if (voxel_leaf_m <= 0.0) {
    std::unordered_map<std::array<std::uint64_t, 3>, std::uint32_t, Coord3Hash> kept;
    kept.reserve(kept_m.size());
    for (Eigen::Index i = 0; i < kept_m.xyz.cols(); ++i) ++kept[bits_of(kept_m.xyz.col(i).data())];
    for (std::size_t i = 0; i < n; ++i) {
      if (!finite[i]) continue;
      const auto it = kept.find(bits_of(as_read_m.col(static_cast<Eigen::Index>(i)).data()));
      if (it != kept.end() && it->second > 0) {
        --it->second;
        removed[i] = 0;
      }
    }
  } else {
    out.removal_exact = false;
    const std::size_t m = kept_m.size();
    std::vector<float> kept_local(3 * m);
    std::vector<std::uint8_t> kept_finite(m, 0);
    for (std::size_t i = 0; i < m; ++i) {
      const Eigen::Vector3d p = kept_m.xyz.col(static_cast<Eigen::Index>(i));
      if (!p.allFinite()) continue;
      kept_finite[i] = 1;
      for (int a = 0; a < 3; ++a) kept_local[3 * i + static_cast<std::size_t>(a)] = static_cast<float>(p[a] - centre[a]);
    }
    const double reach_m = voxel_leaf_m * std::sqrt(3.0);
    const VoxelHash kept_hash(kept_local, kept_finite, reach_m);
    const auto r2 = static_cast<float>(reach_m * reach_m);
    for (std::size_t i = 0; i < n; ++i) {
      if (!finite[i]) continue;
      kept_hash.visit(&local[3 * i], 1, [&](std::uint32_t, const float* p, std::uint32_t) {
        if (dist_sq(p, &local[3 * i]) > r2) return true;
        removed[i] = 0;
        return false;
      });
    }
  }

  // 2. The point test: isolated points.
  out.spacing_m = scope                ? scope->spacing_m
                  : o.spacing_m > 0.0 ? o.spacing_m
                                      : median_spacing(local, finite, 2.0 * g.cell_size_m);
  out.isolation_radius_m = std::max(o.isolation_radius_spacings * out.spacing_m, 1e-9);
  // With the near flags (a tiled run), only the points not known to have neighbours are tested,
  // and steps 4 and 5 hash only the voxels their searches visit; else one hash of every point.
  std::vector<std::uint8_t> isolated;
  std::optional<VoxelHash> all_points;
  const double edge_m = out.isolation_radius_m;
  if (scope && scope->near && near_flags_usable(local, finite, isolated_filter_radius_m(o, out.spacing_m), edge_m)) {
    isolated = isolated_flags_about(local, finite, *scope->near, edge_m, o.isolation_min_neighbours, out.isolation_tested,
                                    out.isolation_hashed);
  } else {
    all_points.emplace(local, finite, edge_m);
    isolated = isolated_flags(*all_points, finite.size(), edge_m, o.isolation_min_neighbours);
    out.isolation_tested = out.isolation_hashed = all_points->size();
  }
  for (std::size_t i = 0; i < n; ++i) out.isolated += owns(i) ? isolated[i] : 0U;

  // 3. Classes of every point, far points, surface lost.
  cv::Mat gap_cells;  // x-y distance to the nearest valid sample [cells]
  {
    cv::Mat not_valid(g.rows, g.cols, CV_8UC1);
    for (int r = 0; r < g.rows; ++r)
      for (int c = 0; c < g.cols; ++c) not_valid.at<std::uint8_t>(r, c) = std::isnan(grid.at(r, c)) ? 255 : 0;
    cv::distanceTransform(not_valid, gap_cells, cv::DIST_L2, cv::DIST_MASK_PRECISE);
    // A tile's window: no farther than its size (a lower bound of the whole grid's gap, which
    // is then far above the tolerance; a window without a valid cell has no distance at all).
    if (scope) cv::min(gap_cells, static_cast<double>(g.rows + g.cols), gap_cells);
  }
  // The classes' surface and extent: the whole grid's where the scope gives it.
  const HeightField& classes_on = scope && scope->whole ? *scope->whole : grid;
  const GridGeometry& cg = classes_on.geometry();
  if (cg.cell_size_m != g.cell_size_m) {
    throw std::invalid_argument("check_input: the scope's whole grid has cells of " + format_number(cg.cell_size_m) +
                                " m, its window " + format_number(g.cell_size_m) + " m");
  }
  const BilinearSurface surface(HeightFieldView::of(classes_on));
  const double x_max = g.x_of_col(g.cols - 1), y_max = g.y_of_row(g.rows - 1);
  const double class_x_max = cg.x_of_col(cg.cols - 1), class_y_max = cg.y_of_row(cg.rows - 1);
  auto xy_gap = [&](double x, double y) {
    const double cx = std::clamp(x, g.x0_m, x_max), cy = std::clamp(y, g.y0_m, y_max);
    const int c = std::clamp(static_cast<int>(std::lround((cx - g.x0_m) / g.cell_size_m)), 0, g.cols - 1);
    const int r = std::clamp(static_cast<int>(std::lround((cy - g.y0_m) / g.cell_size_m)), 0, g.rows - 1);
    return std::hypot(x - cx, y - cy) + static_cast<double>(gap_cells.at<float>(r, c)) * g.cell_size_m;
  };
  // Two threads, each a contiguous half of the points with its own counts, summed after.
  const int class_threads = n > 20000 ? detail::kSearchThreads : 1;
  std::vector<InputCheck> part(static_cast<std::size_t>(class_threads));
  detail::run_parallel(class_threads, [&](int t) {
    InputCheck& pc = part[static_cast<std::size_t>(t)];
    const auto [b, e] = detail::share_of(n, t, class_threads);
    // The points in input order fall on random cells of the grid: each one's two grid rows
    // fetched kAhead points before it is classified (BilinearSurface::prefetch).
    constexpr std::size_t kAhead = 8;
    for (std::size_t i = b; i < e; ++i) {
      if (i + kAhead < e) surface.prefetch(as_read_m(0, static_cast<Eigen::Index>(i + kAhead)), as_read_m(1, static_cast<Eigen::Index>(i + kAhead)));
      if (!owns(i)) continue;  // a halo copy: its own tile counts it
      if (!finite[i]) {
        ++pc.removed;  // the non-finite filter drops it
        continue;
      }
      const Eigen::Vector3d p = as_read_m.col(static_cast<Eigen::Index>(i));
      const double to_box = (p - p.cwiseMax(box_lo).cwiseMin(box_hi)).norm();
      const bool far = to_box > diag;
      if (far) {
        ++pc.far;
        pc.far_max_distance_m = std::max(pc.far_max_distance_m, to_box);
      }
      // Geometry against the grid.
      double gap = 0.0;  // > tolerance: not represented
      enum { kOn, kOff, kHidden, kNoData, kOutside } cls = kOn;
      if (p.x() < cg.x0_m || p.x() > class_x_max || p.y() < cg.y0_m || p.y() > class_y_max) {
        cls = kOutside;
        gap = xy_gap(p.x(), p.y());
      } else {
        const SurfaceSample s = surface.sample(p.x(), p.y());
        if (!s.valid) {
          cls = kNoData;
          gap = xy_gap(p.x(), p.y());
        } else {
          const double res = p.z() - s.z_m;
          cls = res < -o.hidden_band_m ? kHidden : std::abs(res) <= o.tolerance_m ? kOn : kOff;
          gap = std::abs(res);
        }
      }
      if (removed[i]) {
        ++pc.removed;
        if (!isolated[i] && !far && gap > o.tolerance_m) {
          if (cls == kNoData || cls == kOutside) {
            ++pc.surface_lost;
            pc.surface_lost_max_gap_m = std::max(pc.surface_lost_max_gap_m, gap);
          } else if (cls == kOff) {
            ++pc.removed_in_front;
          }
        }
        continue;
      }
      switch (cls) {
        case kOn: ++pc.on_surface; break;
        case kOff: ++pc.off_surface; break;
        case kHidden: ++pc.hidden; break;
        case kNoData: ++pc.no_data; break;
        case kOutside: ++pc.outside; break;
      }
    }
  });
  for (const InputCheck& pc : part) out.add_classes(pc);  // (their points stay 0: counted above)

  // 4. Spikes kept: valid cells supported (within tolerance) only by isolated points.
  {
    const double tol = o.tolerance_m;
    const auto tol2 = static_cast<float>(tol * tol);
    const int reach_cells = static_cast<int>(std::ceil(tol / g.cell_size_m));
    const int reach_voxels = static_cast<int>(std::ceil(tol / edge_m));
    std::vector<std::size_t> candidates;
    auto sample_local = [&](int r, int c, float* q) {
      q[0] = static_cast<float>(g.x_of_col(c) - centre.x());
      q[1] = static_cast<float>(g.y_of_row(r) - centre.y());
      q[2] = static_cast<float>(static_cast<double>(grid.at(r, c)) - centre.z());
    };
    for (std::size_t i = 0; i < n; ++i) {
      // Only kept points support the grid: an isolated point the filters removed made no cell.
      if (!isolated[i] || removed[i]) continue;
      const Eigen::Vector3d p = as_read_m.col(static_cast<Eigen::Index>(i));
      const int c0 = static_cast<int>(std::lround((p.x() - g.x0_m) / g.cell_size_m));
      const int r0 = static_cast<int>(std::lround((p.y() - g.y0_m) / g.cell_size_m));
      const int rr0 = scope ? scope->cells[0] : 0, rr1 = scope ? scope->cells[1] : g.rows;
      const int cc0 = scope ? scope->cells[2] : 0, cc1 = scope ? scope->cells[3] : g.cols;
      for (int r = std::max(rr0, r0 - reach_cells); r <= std::min(rr1 - 1, r0 + reach_cells); ++r)
        for (int c = std::max(cc0, c0 - reach_cells); c <= std::min(cc1 - 1, c0 + reach_cells); ++c) {
          if (std::isnan(grid.at(r, c))) continue;
          float q[3];
          sample_local(r, c, q);
          if (dist_sq(q, &local[3 * i]) <= tol2)
            candidates.push_back(static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(c));
        }
    }
    std::sort(candidates.begin(), candidates.end());
    candidates.erase(std::unique(candidates.begin(), candidates.end()), candidates.end());
    // Step 5's reaches (the confirmations within conf_m, or within the footprint in x-y).
    const double conf_m = std::max(tol, o.spike_min_height_m);
    const int conf_reach = static_cast<int>(std::ceil(conf_m / edge_m));
    const bool footprint = o.confirm_footprint_m > 0.0 && cell_flags != nullptr &&
                           cell_flags->size() == static_cast<std::size_t>(g.rows) * static_cast<std::size_t>(g.cols);
    constexpr double kMaxFootprintVoxels = 16.0;
    const int foot_reach = static_cast<int>(std::min(kMaxFootprintVoxels, std::ceil(o.confirm_footprint_m / edge_m)));
    // The hash the searches of steps 4 and 5 read: every point's, or one of the points in the
    // voxels they visit.
    std::optional<VoxelHash> about;
    if (!all_points) {
      std::vector<VoxelSearch> searches;
      for (const std::size_t k : candidates) {
        VoxelSearch v;
        sample_local(static_cast<int>(k / static_cast<std::size_t>(g.cols)), static_cast<int>(k % static_cast<std::size_t>(g.cols)), v.q.data());
        v.reach = v.reach_z = reach_voxels;
        searches.push_back(v);
      }
      for (const auto& rc : spikes ? spikes->flagged : std::vector<std::array<int, 2>>{}) {
        VoxelSearch v;
        sample_local(rc[0], rc[1], v.q.data());
        v.reach = v.reach_z = conf_reach;
        searches.push_back(v);
        if (footprint) {
          v.reach = foot_reach;
          v.reach_z = std::max(1, conf_reach);
          searches.push_back(v);
        }
      }
      std::size_t count = 0;
      about.emplace(local, points_about(local, finite, edge_m, searches, count), edge_m);
      out.isolation_hashed += count;
    }
    const VoxelHash& hash = all_points ? *all_points : *about;
    for (std::size_t k : candidates) {
      const int r = static_cast<int>(k / static_cast<std::size_t>(g.cols)), c = static_cast<int>(k % static_cast<std::size_t>(g.cols));
      float q[3];
      sample_local(r, c, q);
      bool genuine = false;
      hash.visit(q, reach_voxels, [&](std::uint32_t, const float* p, std::uint32_t j) {
        if (!isolated[j] && dist_sq(p, q) <= tol2) genuine = true;
        return !genuine;
      });
      if (genuine) continue;
      ++out.spikes_kept;
      if (out.spikes_kept_cells.size() < 100) out.spikes_kept_cells.push_back({r, c});
    }
    // 5. Spikes and pits of the grid that the scan confirms (a not isolated point within tol).
    // Within max(tolerance, spike_min_height_m): a genuine point that close means the cell does
    // not stand more than the spike limit away from the scan. With a footprint, a measured or
    // splatted cell is also confirmed by a kept, not isolated point within the footprint in x-y
    // and that close in height: the point whose disc made the cell.
    if (spikes) {
      spikes->confirmed = 0;
      const auto conf2 = static_cast<float>(conf_m * conf_m);
      const auto conf_z = static_cast<float>(conf_m);
      const auto foot2 = static_cast<float>(o.confirm_footprint_m * o.confirm_footprint_m);
      for (const auto& rc : spikes->flagged) {
        float q[3];
        sample_local(rc[0], rc[1], q);
        bool genuine = false;
        hash.visit(q, conf_reach, [&](std::uint32_t, const float* p, std::uint32_t j) {
          if (!isolated[j] && dist_sq(p, q) <= conf2) genuine = true;
          return !genuine;
        });
        const std::uint8_t flag =
            footprint ? (*cell_flags)[static_cast<std::size_t>(rc[0]) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(rc[1])]
                      : std::uint8_t{0};
        if (!genuine && footprint && (flag == kCellMeasured || flag == kCellSplatted)) {
          hash.visit(q, foot_reach, std::max(1, conf_reach), [&](std::uint32_t, const float* p, std::uint32_t j) {
            const float dx = p[0] - q[0], dy = p[1] - q[1];
            if (!isolated[j] && !removed[j] && dx * dx + dy * dy <= foot2 && std::abs(p[2] - q[2]) <= conf_z) genuine = true;
            return !genuine;
          });
        }
        spikes->confirmed += genuine;
      }
    }
  }
  out.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return out;
}

namespace {

// The groups of valid cells (8-connected, OpenCV's connected components) of `grid`'s region
// {row0, row1, col0, col1} (half-open): labels (CV_32S, the region's shape, 0 = no data) and
// stats (CC_STAT_AREA per label); returns the number of labels, background included.
int valid_groups(const HeightField& grid, const std::array<int, 4>& region, cv::Mat& labels, cv::Mat& stats) {
  cv::Mat valid(region[1] - region[0], region[3] - region[2], CV_8UC1);
  for (int r = 0; r < valid.rows; ++r)
    for (int c = 0; c < valid.cols; ++c) valid.at<std::uint8_t>(r, c) = std::isnan(grid.at(region[0] + r, region[2] + c)) ? 0 : 255;
  cv::Mat centroids;
  return cv::connectedComponentsWithStats(valid, labels, stats, centroids, 8, CV_32S);
}

// Per cell (row-major), 1 where the cell belongs to an island: a group of valid cells
// (8-connected, OpenCV's connected components) of at most max_cells cells that is not the
// largest group (with spare_largest; without it, the largest too when that small:
// HonestCheckOptions::spare_largest_group). *islands = the number of such groups. One
// labelling of the whole grid: 6 bytes a cell while it runs (detail::island_cells' reference,
// and its way when every group is small and the largest is spared).
std::vector<std::uint8_t> island_mask_whole(const HeightField& grid, int max_cells, std::size_t* islands, bool spare_largest) {
  const GridGeometry& g = grid.geometry();
  cv::Mat labels, stats;
  const int n_labels = valid_groups(grid, {0, g.rows, 0, g.cols}, labels, stats);
  int largest = 0, largest_area = -1;
  for (int l = 1; l < n_labels; ++l) {
    const int area = stats.at<int>(l, cv::CC_STAT_AREA);
    if (area > largest_area) largest_area = area, largest = l;
  }
  std::vector<std::uint8_t> is_island(static_cast<std::size_t>(std::max(n_labels, 1)), 0);
  *islands = 0;
  for (int l = 1; l < n_labels; ++l) {
    if ((spare_largest && l == largest) || stats.at<int>(l, cv::CC_STAT_AREA) > max_cells) continue;
    is_island[static_cast<std::size_t>(l)] = 1;
    ++*islands;
  }
  std::vector<std::uint8_t> mask(g.cell_count(), 0);
  if (*islands == 0) return mask;
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c)
      mask[static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(c)] =
          is_island[static_cast<std::size_t>(labels.at<int>(r, c))];
  return mask;
}

// island_mask_whole's mask from detail::for_each_island_cell (rows of bands, not the whole grid
// at once): the mask and the band's labels, no list of the cells.
std::vector<std::uint8_t> island_mask(const HeightField& grid, int max_cells, std::size_t* islands, bool spare_largest) {
  std::vector<std::uint8_t> mask(grid.geometry().cell_count(), 0);
  detail::for_each_island_cell(grid, max_cells, islands, spare_largest, 0, [&mask](std::size_t i) { mask[i] = 1; });
  return mask;
}

}  // namespace

void detail::for_each_island_cell(const HeightField& grid, int max_cells, std::size_t* islands, bool spare_largest,
                                  int band_rows, const std::function<void(std::size_t)>& cell) {
  const GridGeometry& g = grid.geometry();
  if (max_cells < 1) throw std::invalid_argument("island_cells: max_cells = " + std::to_string(max_cells) + " (expected >= 1)");
  // A group of at most max_cells cells spans at most max_cells rows. So a group with a cell in
  // a band's rows [b0, b1) that the window [b0 − max_cells, b1 + max_cells) cuts runs over at
  // least max_cells + 1 of the window's rows, more than max_cells cells there: no island, as in
  // the whole grid. Every other group with a cell in the band lies whole in the window, with
  // its whole area. Each group is counted by the band holding its top row; each cell is
  // given by the band holding it, in row-major order. The default band is at least 4·max_cells
  // rows, so the windows' overlap costs at most half again; a band of the grid's rows is one
  // labelling of the whole grid.
  const std::int64_t over = max_cells;
  std::int64_t band = band_rows > 0 ? band_rows
                                    : std::max<std::int64_t>({1, static_cast<std::int64_t>(kIslandBandCells / static_cast<std::size_t>(std::max(g.cols, 1))),
                                                              4 * over});
  band = std::min<std::int64_t>(band, std::max(g.rows, 1));
  std::size_t count = 0;
  // Whether some group has more than max_cells cells: then the largest group is none of the
  // islands and every small group is one. Until a band shows one, the cells are held back: in
  // a grid of specks only, with the largest spared, one labelling of the whole grid names that
  // group (OpenCV's first among equals), below.
  bool some_group_larger = !spare_largest;
  std::vector<std::size_t> held;
  for (std::int64_t b0 = 0; b0 < g.rows; b0 += band) {
    const int b1 = static_cast<int>(std::min<std::int64_t>(g.rows, b0 + band));
    const int w0 = static_cast<int>(std::max<std::int64_t>(0, b0 - over));
    const int w1 = static_cast<int>(std::min<std::int64_t>(g.rows, b1 + over));
    cv::Mat labels, stats;
    const int n_labels = valid_groups(grid, {w0, w1, 0, g.cols}, labels, stats);
    std::vector<std::uint8_t> small(static_cast<std::size_t>(std::max(n_labels, 1)), 0);
    for (int l = 1; l < n_labels; ++l) {
      if (stats.at<int>(l, cv::CC_STAT_AREA) > max_cells) {
        some_group_larger = true;
        continue;
      }
      small[static_cast<std::size_t>(l)] = 1;
      const std::int64_t top = w0 + stats.at<int>(l, cv::CC_STAT_TOP);
      if (top >= b0 && top < b1) ++count;
    }
    if (some_group_larger && !held.empty()) {
      for (const std::size_t i : held) cell(i);
      std::vector<std::size_t>().swap(held);
    }
    for (int r = static_cast<int>(b0); r < b1; ++r)
      for (int c = 0; c < g.cols; ++c)
        if (small[static_cast<std::size_t>(labels.at<int>(r - w0, c))]) {
          const std::size_t i = static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(c);
          if (some_group_larger) {
            cell(i);
          } else {
            held.push_back(i);
          }
        }
    grid.values().release_resident();  // a file-backed level 0's band given back (cell_buffer.hpp)
  }
  if (!some_group_larger && count > 0) {
    // Every group is small and the largest is spared: only one labelling of the whole grid
    // names it as OpenCV orders its labels.
    const std::vector<std::uint8_t> mask = island_mask_whole(grid, max_cells, islands, true);
    for (std::size_t i = 0; i < mask.size(); ++i)
      if (mask[i]) cell(i);
    return;
  }
  *islands = count;
}

std::vector<std::size_t> detail::island_cells(const HeightField& grid, int max_cells, std::size_t* islands, bool spare_largest,
                                              int band_rows) {
  std::vector<std::size_t> out;
  for_each_island_cell(grid, max_cells, islands, spare_largest, band_rows, [&out](std::size_t i) { out.push_back(i); });
  return out;
}

GridSpikes find_grid_spikes(const HeightField& grid, const HonestCheckOptions& o) {
  check_honest_options(o);
  const GridGeometry& g = grid.geometry();
  const int h = o.spike_window_cells / 2;
  // The rows in two halves, one per thread; each half's anomalies in row-major order, so the
  // concatenation is the single-threaded order.
  struct Half {
    std::size_t tested = 0, spikes = 0, pits = 0;
    std::vector<GridAnomaly> all;
  };
  // Each cell's window minimum, maximum and valid count come from its rows' horizontal ones (a
  // ring of 2h + 1 rows, each entry over the row's 2h + 1 cells about a column, clipped to the
  // grid, NaN left out): the same exact values as the window's cells one by one, about
  // 2(2h + 1) reads a cell instead of (2h + 1)². Only a cell that the smooth test below does
  // not settle (a neighbour farther than spike_min_height_m from it) gathers its window. (Until
  // 2026-11-28, forty-eighth session, every valid cell gathered its window: at 10^8 points, a
  // 4096 × 2049 grid, 1.1 s of CPU of the tiled run's honest check.)
  const int wside = 2 * h + 1;
  const auto ucols = static_cast<std::size_t>(g.cols);
  auto scan_rows = [&](int row_begin, int row_end, Half& out) {
    std::vector<float> win, dev;
    FloodScratch flood;
    win.reserve(static_cast<std::size_t>(wside * wside));
    dev.reserve(win.capacity());
    std::vector<float> row_lo(static_cast<std::size_t>(wside) * ucols), row_hi(row_lo.size());
    std::vector<std::uint8_t> row_valid(row_lo.size());
    // Row rr's horizontal minimum, maximum and valid count about each column, into its slot.
    auto horizontal = [&](int rr) {
      const std::size_t at = static_cast<std::size_t>(rr % wside) * ucols;
      for (int c = 0; c < g.cols; ++c) {
        float lo = std::numeric_limits<float>::infinity(), hi = -lo;
        std::uint8_t n = 0;
        for (int cc = std::max(0, c - h); cc <= std::min(g.cols - 1, c + h); ++cc) {
          const float v = grid.at(rr, cc);
          if (std::isnan(v)) continue;
          lo = std::min(lo, v);
          hi = std::max(hi, v);
          ++n;
        }
        row_lo[at + static_cast<std::size_t>(c)] = lo;
        row_hi[at + static_cast<std::size_t>(c)] = hi;
        row_valid[at + static_cast<std::size_t>(c)] = n;
      }
    };
    for (int rr = std::max(0, row_begin - h); rr < std::min(g.rows, row_begin + h); ++rr) horizontal(rr);
    // A file-backed level 0's rows this half has passed, given back every kReleaseEveryCells
    // cells (cell_buffer.hpp): the sweep holds a band of rows resident, not the grid; the other
    // half's rows stay. (Before 2026-12-01, sixty-ninth session, the whole depth became resident
    // here: 537 MB of the tiled run's honest check at N = 16384.)
    int released_to = row_begin;
    for (int r = row_begin; r < row_end; ++r) {
      if (r + h < g.rows) horizontal(r + h);
      if (const int done = r - h; done > released_to &&
          static_cast<std::size_t>(done - released_to) * ucols >= kReleaseEveryCells) {
        grid.values().release_resident(static_cast<std::size_t>(released_to) * ucols,
                                       static_cast<std::size_t>(done - released_to) * ucols);
        released_to = done;
      }
      const int r0 = std::max(0, r - h), r1 = std::min(g.rows - 1, r + h);
      for (int c = 0; c < g.cols; ++c) {
        const float z = grid.at(r, c);
        if (std::isnan(z)) continue;
        // The window's minimum, maximum and valid count (z among them), from the ring.
        float lo = z, hi = z;
        int valid = 0;
        for (int rr = r0; rr <= r1; ++rr) {
          const std::size_t i = static_cast<std::size_t>(rr % wside) * ucols + static_cast<std::size_t>(c);
          lo = std::min(lo, row_lo[i]);
          hi = std::max(hi, row_hi[i]);
          valid += row_valid[i];
        }
        if (valid - 1 < 3) continue;  // fewer than 3 valid neighbours: not tested
        ++out.tested;
        // The median lies in [lo, hi]: when every neighbour is within spike_min_height_m of z,
        // so is the median, and the test below cannot fire (exact; saves the selections on
        // the smooth majority of cells).
        if (std::max(static_cast<double>(z) - static_cast<double>(lo), static_cast<double>(hi) - static_cast<double>(z)) <=
            o.spike_min_height_m) {
          continue;
        }
        // The window's valid neighbours, and whether it holds no data or crosses the border.
        win.clear();
        bool edge = false;
        for (int rr = r - h; rr <= r + h; ++rr)
          for (int cc = c - h; cc <= c + h; ++cc) {
            if (rr < 0 || rr >= g.rows || cc < 0 || cc >= g.cols) {
              edge = true;
              continue;
            }
            if (rr == r && cc == c) continue;
            const float v = grid.at(rr, cc);
            if (std::isnan(v)) {
              edge = true;
            } else {
              win.push_back(v);
            }
          }
        // Median (upper median for an even count) and MAD.
        const auto mid = win.begin() + static_cast<std::ptrdiff_t>(win.size() / 2);
        std::nth_element(win.begin(), mid, win.end());
        const double median = *mid;
        dev.clear();
        for (float v : win) dev.push_back(std::abs(static_cast<float>(v - median)));
        const auto dmid = dev.begin() + static_cast<std::ptrdiff_t>(dev.size() / 2);
        std::nth_element(dev.begin(), dmid, dev.end());
        const double scale = 1.4826 * static_cast<double>(*dmid);
        const double d = static_cast<double>(z) - median;
        if (std::abs(d) <= o.spike_min_height_m || std::abs(d) <= o.spike_mad_factor * scale) continue;
        // At a silhouette the surface falls away from the viewer: a low cell there is expected.
        if (d < 0 && edge) continue;
        // Neighbours closer than half the deviation continue the cell's own surface (a steep
        // slope along a silhouette); a spike's foot differs from it by about the whole deviation.
        const double step_m = std::max(o.spike_min_height_m, 0.5 * std::abs(d));
        if (part_of_large_surface(grid, r, c, step_m, o.spike_max_cells, flood)) continue;
        (d > 0 ? out.spikes : out.pits) += 1;
        out.all.push_back({r, c, z, static_cast<float>(d)});
      }
    }
  };
  Half halves[2];
  const int split = g.rows / 2;
  detail::run_two([&] { scan_rows(split, g.rows, halves[1]); }, [&] { scan_rows(0, split, halves[0]); });
  GridSpikes out;
  std::vector<GridAnomaly> all = std::move(halves[0].all);
  all.insert(all.end(), halves[1].all.begin(), halves[1].all.end());
  out.tested = halves[0].tested + halves[1].tested;
  out.spikes = halves[0].spikes + halves[1].spikes;
  out.pits = halves[0].pits + halves[1].pits;
  std::sort(all.begin(), all.end(), [](const GridAnomaly& a, const GridAnomaly& b) {
    return std::abs(a.deviation_m) > std::abs(b.deviation_m);
  });
  for (const auto& a : all) {
    if (out.marked.size() < 1000) out.marked.push_back({a.row, a.col});
    out.flagged.push_back({a.row, a.col});
  }
  all.resize(std::min<std::size_t>(all.size(), 10));
  out.worst = all;

  // Islands: small groups of valid cells away from the largest group (island_mask).
  // (Labelled in bands, the cells counted as they come: no whole-grid labels, mask or list;
  // issue 14.)
  detail::for_each_island_cell(grid, o.island_max_cells, &out.islands, o.spare_largest_group, 0, [&](std::size_t i) {
    ++out.island_cells;
    if (out.marked.size() < 1000)
      out.marked.push_back({static_cast<int>(i / static_cast<std::size_t>(g.cols)), static_cast<int>(i % static_cast<std::size_t>(g.cols))});
  });
  return out;
}

bool Verdict::has(const std::string& code) const {
  return std::any_of(reasons.begin(), reasons.end(), [&](const VerdictReason& r) { return r.code == code; });
}

Verdict decide_verdict(const InputCheck& in, const GridSpikes& sp, double supported_fraction,
                       const std::vector<StageReport>& stages, const HonestCheckOptions& o) {
  Verdict v;
  auto add = [&v](const char* code, const char* level, std::string message) {
    v.reasons.push_back({code, level, std::move(message)});
  };
  auto figure = [&stages](const std::string& stage, const std::string& name) {
    for (const auto& s : stages) {
      if (s.stage != stage) continue;
      for (const auto& [k, val] : s.figures)
        if (k == name) return val;
    }
    return std::numeric_limits<double>::quiet_NaN();
  };
  const std::size_t spike_cells = sp.spikes + sp.pits - std::min(sp.confirmed, sp.spikes + sp.pits);
  // The fractional allowance holds only while no spike (a cell ABOVE its window) among the
  // worst listed stands out by more than spike_allowance_max_m: a +500 m spike is never "a few
  // cells", while deep pits are the relief of folds (the Buddha: −40.9 mm, confirmed by points).
  double worst_spike_m = 0.0;
  for (const GridAnomaly& w : sp.worst) worst_spike_m = std::max(worst_spike_m, static_cast<double>(w.deviation_m));
  const auto spike_limit =
      worst_spike_m <= o.spike_allowance_max_m
          ? std::max(static_cast<std::size_t>(o.max_spike_cells),
                     static_cast<std::size_t>(o.max_spike_fraction * static_cast<double>(sp.tested)))
          : static_cast<std::size_t>(o.max_spike_cells);
  if (spike_cells > spike_limit) {
    std::string worst;
    if (!sp.worst.empty()) {
      const GridAnomaly& w = sp.worst.front();
      worst = "; worst at cell (row " + std::to_string(w.row) + ", col " + std::to_string(w.col) + "): " +
              (w.deviation_m > 0 ? "+" : "") + mm(w.deviation_m) + " from its neighbourhood";
    }
    add("grid_spikes", "fail",
        "the grid has " + std::to_string(sp.spikes) + " spike and " + std::to_string(sp.pits) + " pit cells, " +
            std::to_string(spike_cells) + " of them not confirmed by a scan point that is not isolated (more than " + mm(o.spike_min_height_m) + " and " + format_number(o.spike_mad_factor) +
            " MAD from the median of their " + std::to_string(o.spike_window_cells) + " x " +
            std::to_string(o.spike_window_cells) + " window" + worst + "; limit " + std::to_string(spike_limit) + " cells: cross_check.max_spike_cells = " +
            std::to_string(o.max_spike_cells) + " or, while no listed spike stands above its window by more than cross_check.spike_allowance_max_m = " +
            mm(o.spike_allowance_max_m) + ", cross_check.max_spike_fraction = " + format_number(o.max_spike_fraction) +
            " of " + std::to_string(sp.tested) + " tested cells)");
  }
  if (in.spikes_kept > static_cast<std::size_t>(o.max_spikes_kept_cells)) {
    add("spikes_kept", "fail",
        std::to_string(in.spikes_kept) + " grid cells are supported only by isolated input points (fewer than " +
            std::to_string(o.isolation_min_neighbours) + " neighbours within " + mm(in.isolation_radius_m) +
            "): outliers the filters kept (limit cross_check.max_spikes_kept_cells = " +
            std::to_string(o.max_spikes_kept_cells) + ")");
  }
  if (sp.island_cells > static_cast<std::size_t>(o.max_island_cells)) {
    add("islands", "warn",
        std::to_string(sp.islands) + " islands (" + std::to_string(sp.island_cells) + " cells in groups of at most " +
            std::to_string(o.island_max_cells) + " cells apart from the surface; limit cross_check.max_island_cells = " +
            std::to_string(o.max_island_cells) + ")");
  }
  double far_clusters_removed = figure("outliers", "removed_far_clusters");
  double clusters = figure("outliers", "far_clusters");
  if (!std::isfinite(far_clusters_removed)) {
    // A tiled run (tiled_run.cpp) has no outliers stage: its far clusters are those of the
    // whole-scan pass before the tiles (stage tile_far_clusters) and the tiles' own (stage
    // tiles: each point summed by the tile that owns it, each cluster by the owner of its least
    // point), together the in-core counts where the scenes agree.
    const double pass = figure("tile_far_clusters", "removed_far_clusters");
    const double owned = figure("tiles", "sum_far_points_owned");
    if (std::isfinite(pass) || std::isfinite(owned)) {
      const auto or0 = [](double x) { return std::isfinite(x) ? x : 0.0; };
      far_clusters_removed = or0(pass) + or0(owned);
      clusters = or0(figure("tile_far_clusters", "far_clusters")) + or0(figure("tiles", "sum_far_clusters_owned"));
    }
  }
  if (in.far > 0 || (std::isfinite(far_clusters_removed) && far_clusters_removed > 0)) {
    std::string msg = std::to_string(in.far) + " input points lie farther from the grid's box than its diagonal";
    if (in.far > 0) msg += " (the farthest " + format_number(in.far_max_distance_m, 4) + " m away)";
    if (std::isfinite(far_clusters_removed) && far_clusters_removed > 0) {
      msg += "; the outlier stage removed " + format_number(far_clusters_removed) + " points in far clusters";
      if (std::isfinite(clusters)) msg += " (" + format_number(clusters) + " clusters)";
    }
    add("far_points", "warn", msg + ": far points in the scan (stray returns or another object); crop them "
                                   "(filters.crop) if they are not part of the object");
  }
  if (in.fraction(in.removed) > o.max_removed_fraction) {
    add("removed_fraction", "warn",
        "the filters removed " + pct(in.fraction(in.removed)) + " of the input (" + std::to_string(in.removed) + " of " +
            std::to_string(in.points) + " points; limit cross_check.max_removed_fraction = " +
            pct(o.max_removed_fraction) + ")");
  }
  if (in.fraction(in.surface_lost) > o.max_surface_lost_fraction) {
    add("surface_lost", "warn",
        std::to_string(in.surface_lost) + " points (" + pct(in.fraction(in.surface_lost)) +
            " of the input) removed by the filters are surface samples (not isolated) that the grid does not "
            "represent, up to " + mm(in.surface_lost_max_gap_m) + " from it (limit cross_check.max_surface_lost_fraction = " +
            pct(o.max_surface_lost_fraction) + ")");
  }
  const std::size_t visible = in.on_surface + in.off_surface + in.no_data;
  if (visible > 0) {
    const double f = static_cast<double>(in.on_surface) / static_cast<double>(visible);
    if (f < o.min_visible_on_surface_fraction) {
      add("visible_off_surface", "warn",
          "only " + pct(f) + " of the kept, visible input points lie within " + mm(o.tolerance_m) +
              " of the surface (limit cross_check.min_visible_on_surface_fraction = " +
              pct(o.min_visible_on_surface_fraction) + ")");
    }
  }
  if (std::isfinite(supported_fraction) && supported_fraction < o.min_supported_fraction) {
    add("unsupported", "warn",
        pct(supported_fraction) + " of the valid cells have a point within " + mm(o.tolerance_m) +
            " (limit cross_check.min_supported_fraction = " + pct(o.min_supported_fraction) + ")");
  }
  const double threshold_mm = figure("outliers", "threshold_mm");
  if (std::isfinite(threshold_mm) && in.spacing_m > 0.0 &&
      threshold_mm * 1e-3 > o.max_filter_threshold_spacings * in.spacing_m) {
    add("filter_threshold", "warn",
        "the outlier filter's threshold (" + format_number(threshold_mm, 4) + " mm) is " +
            format_number(threshold_mm * 1e-3 / in.spacing_m, 3) + " times the input's point spacing (" +
            mm(in.spacing_m) + "): its statistics are inflated by outliers, so it removes too little (limit "
            "cross_check.max_filter_threshold_spacings = " + format_number(o.max_filter_threshold_spacings) + ")");
  }
  for (const auto& r : v.reasons) {
    if (r.level == "fail") v.status = "fail";
    else if (v.status == "pass") v.status = "warn";
  }
  return v;
}

double isolated_filter_radius_m(const HonestCheckOptions& options, double spacing_m) {
  return std::max(0.9 * options.isolation_radius_spacings * spacing_m, 1e-9);
}

double despike_search_radius_m(double cell_m, double upsample_factor, double spacing_m) {
  return std::max(4.0 * upsample_factor * cell_m, 4.0 * spacing_m);
}

int despike_grid_reach_cells(const HonestCheckOptions& options, double reach_cells) {
  return static_cast<int>(std::ceil(reach_cells)) + options.spike_window_cells / 2;
}

WindowIslands window_islands(const HeightField& window, int max_cells, const std::array<int, 4>& exact,
                             const std::array<int, 4>& needed, const std::array<bool, 4>& open) {
  const GridGeometry& g = window.geometry();
  const auto region = [](const std::array<int, 4>& a) {
    return "{" + std::to_string(a[0]) + ", " + std::to_string(a[1]) + ", " + std::to_string(a[2]) + ", " + std::to_string(a[3]) + "}";
  };
  if (max_cells < 1) throw std::invalid_argument("window_islands: max_cells = " + std::to_string(max_cells) + " (expected >= 1)");
  if (!(0 <= exact[0] && exact[0] <= exact[1] && exact[1] <= g.rows && 0 <= exact[2] && exact[2] <= exact[3] && exact[3] <= g.cols)) {
    throw std::invalid_argument("window_islands: exact region " + region(exact) + " is not inside the window of " +
                                std::to_string(g.rows) + " x " + std::to_string(g.cols) + " cells");
  }
  if (needed[0] < needed[1] && needed[2] < needed[3] &&
      !(exact[0] <= needed[0] && needed[1] <= exact[1] && exact[2] <= needed[2] && needed[3] <= exact[3])) {
    throw std::invalid_argument("window_islands: needed region " + region(needed) + " is not inside the exact region " + region(exact));
  }
  WindowIslands out;
  const int rows = exact[1] - exact[0], cols = exact[3] - exact[2];
  if (rows <= 0 || cols <= 0) return out;
  cv::Mat labels, stats;
  const int n_labels = valid_groups(window, exact, labels, stats);
  // Per group: whether it touches an open side, and one of its cells in the needed region.
  std::vector<std::uint8_t> touches(static_cast<std::size_t>(std::max(n_labels, 1)), 0);
  std::vector<std::array<int, 2>> needed_cell(touches.size(), {-1, -1});
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const int l = labels.at<int>(r, c);
      if (l == 0) continue;
      const std::size_t ul = static_cast<std::size_t>(l);
      if ((open[0] && r == 0) || (open[1] && r == rows - 1) || (open[2] && c == 0) || (open[3] && c == cols - 1)) touches[ul] = 1;
      const int wr = exact[0] + r, wc = exact[2] + c;
      if (needed_cell[ul][0] < 0 && needed[0] <= wr && wr < needed[1] && needed[2] <= wc && wc < needed[3]) needed_cell[ul] = {wr, wc};
    }
  for (int l = 1; l < n_labels; ++l) {
    const auto area = static_cast<std::size_t>(stats.at<int>(l, cv::CC_STAT_AREA));
    out.largest_exact_group = std::max(out.largest_exact_group, area);
    const std::size_t ul = static_cast<std::size_t>(l);
    if (area > static_cast<std::size_t>(max_cells) || !touches[ul] || needed_cell[ul][0] < 0) continue;
    ++out.undecided_groups;
    out.undecided_cells += area;
    if (out.first_undecided[0] < 0) out.first_undecided = needed_cell[ul];
  }
  return out;
}

StageResult<Cloud> remove_isolated_points(Cloud cloud, const HonestCheckOptions& o, RemovedPoints* removed_points,
                                          const std::vector<std::uint8_t>* known_near) {
  check_honest_options(o);
  if (known_near != nullptr && known_near->size() != cloud.size()) {
    throw std::invalid_argument("remove_isolated_points: " + std::to_string(known_near->size()) + " known_near flags for " +
                                std::to_string(cloud.size()) + " points");
  }
  if (removed_points != nullptr) *removed_points = RemovedPoints{};
  const auto t0 = std::chrono::steady_clock::now();
  StageReport report;
  report.stage = "isolated";
  report.count_in = cloud.size();
  const std::size_t n = cloud.size();
  std::vector<float> local;
  std::vector<std::uint8_t> finite(n, 0);
  // Recentre on the per-axis median (a far point must not cost the rest its float precision),
  // and start the spacing search at the edge of the central 98 % box's volume per point.
  Eigen::Vector3d centre = Eigen::Vector3d::Zero(), lo = Eigen::Vector3d::Zero(), hi = Eigen::Vector3d::Zero();
  const double* xyz = cloud.xyz.data();
  std::size_t n_finite = 0;
  for (std::size_t i = 0; i < n; ++i) {
    finite[i] = std::isfinite(xyz[3 * i]) && std::isfinite(xyz[3 * i + 1]) && std::isfinite(xyz[3 * i + 2]) ? 1 : 0;
    n_finite += finite[i];
  }
  if (n_finite < 2) {
    report.count_out = n;
    report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return {std::move(cloud), std::move(report)};
  }
  // The quantiles of at most about 2^16 evenly strided finite points (every stride-th, by a
  // countdown): they only place the local frame and the first guess of the spacing search.
  const std::size_t stride = std::max<std::size_t>(1, n_finite >> 16);
  std::array<std::vector<double>, 3> v;
  for (auto& axis : v) axis.reserve(n_finite / stride + 1);
  for (std::size_t i = 0, left = 0; i < n; ++i) {
    if (!finite[i]) continue;
    if (left == 0) {
      for (std::size_t a = 0; a < 3; ++a) v[a].push_back(xyz[3 * i + a]);
      left = stride;
    }
    --left;
  }
  for (std::size_t a = 0; a < 3; ++a) {
    auto at = [&axis = v[a]](double q) {
      auto it = axis.begin() + static_cast<std::ptrdiff_t>(q * static_cast<double>(axis.size() - 1));
      std::nth_element(axis.begin(), it, axis.end());
      return *it;
    };
    const auto e = static_cast<Eigen::Index>(a);
    centre[e] = at(0.5);
    lo[e] = at(0.01);
    hi[e] = at(0.99);
  }
  // The run's frame when given (HonestCheckOptions::frame_centre_m), so that a tile's window
  // rounds its searches as the in-core run does.
  if (o.frame_centre_m) centre = Eigen::Vector3d((*o.frame_centre_m)[0], (*o.frame_centre_m)[1], (*o.frame_centre_m)[2]);
  local_floats(cloud.xyz, centre, local, finite);  // the same flags again, and the copy
  const Eigen::Vector3d ext = (hi - lo).cwiseMax(1e-9);
  const double start_edge = std::max(std::cbrt(ext.prod() / static_cast<double>(n_finite)), 1e-9);
  const double spacing = o.spacing_m > 0.0 ? o.spacing_m : median_spacing(local, finite, start_edge);
  // 10 % inside the verdict's radius: the spacing is estimated on a sample (the robust test's,
  // when given: its sampled points' nearest-point distances before that test), and the check's
  // estimate (on the cloud as read) differs from it by a few per cent, which must not leave a
  // point the check calls isolated (the Buddha: 0.1466 mm given against 0.1455 mm there).
  const double radius = isolated_filter_radius_m(o, spacing);
  std::vector<std::uint8_t> isolated;
  std::size_t tested = 0, hashed = 0;
  if (known_near != nullptr && coordinates_within(local, finite, 1e4 * radius)) {
    // The flags' frame and this one each round a distance by at most 2·√3·2^-24 of their
    // coordinates' size (10^4 radii): 4e-3 radii in all, inside the 1 % between 0.99 × radius
    // and radius. (10^3 radii until 2026-11-29, fifty-second session, when a tile's window
    // still centred on its own median; in the run's frame a window lies as far out as the scan
    // reaches, as the robust test's near counts do since the fifty-first session.)
    isolated = isolated_flags_about(local, finite, *known_near, radius, o.isolation_min_neighbours, tested, hashed);
  } else {
    const VoxelHash hash(local, finite, radius);
    isolated = isolated_flags(hash, finite.size(), radius, o.isolation_min_neighbours);
    tested = hash.size();
  }
  std::vector<bool> keep(n, true);
  std::size_t removed = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (!isolated[i]) continue;
    keep[i] = false;
    ++removed;
    if (removed_points != nullptr) {
      const auto c = cloud.xyz.col(static_cast<Eigen::Index>(i));
      removed_points->xyz.insert(removed_points->xyz.end(), {c.x(), c.y(), c.z()});
      removed_points->at.push_back(i);
    }
  }
  if (removed > 0) cloud.keep_if(keep);
  report.count_out = cloud.size();
  report.figure("spacing_mm", spacing * 1e3);
  report.figure("isolation_radius_mm", radius * 1e3);
  report.figure("removed_isolated", static_cast<double>(removed));
  report.figure("points_tested", static_cast<double>(tested));
  report.notes.push_back("removed " + std::to_string(removed) + " isolated points (fewer than " +
                         std::to_string(o.isolation_min_neighbours) + " others within " + format_number(radius * 1e3) +
                         " mm, " + format_number(o.isolation_radius_spacings) + " x the median spacing " +
                         format_number(spacing * 1e3) +
                         (o.spacing_m > 0.0 ? " mm of the robust test's sample" : " mm") + "; cross_check.isolation_*)");
  report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return {std::move(cloud), std::move(report)};
}

StageResult<Cloud> remove_spike_points(Cloud cloud, const HeightField& grid, const HonestCheckOptions& o,
                                       double reach_cells, double spacing_m, double upsample_factor,
                                       RemovedPoints* removed_points, const GridWindow* window) {
  check_honest_options(o);
  if (removed_points != nullptr) *removed_points = RemovedPoints{};
  if (window != nullptr && (window->rows != grid.rows() || window->cols != grid.cols() || window->row0 < 0 || window->col0 < 0 ||
                            window->row0 + window->rows > window->grid.rows || window->col0 + window->cols > window->grid.cols)) {
    throw std::invalid_argument("remove_spike_points: a window of rows " + std::to_string(window->row0) + " + " +
                                std::to_string(window->rows) + ", cols " + std::to_string(window->col0) + " + " +
                                std::to_string(window->cols) + " of a " + std::to_string(window->grid.rows) + " x " +
                                std::to_string(window->grid.cols) + " grid for a " + std::to_string(grid.rows()) + " x " +
                                std::to_string(grid.cols()) + " height field");
  }
  if (!(reach_cells >= 0.0) || !std::isfinite(reach_cells)) {
    throw std::invalid_argument("remove_spike_points: reach_cells = " + std::to_string(reach_cells) +
                                " (expected a finite value >= 0)");
  }
  if (!(upsample_factor >= 1.0) || !std::isfinite(upsample_factor)) {
    throw std::invalid_argument("remove_spike_points: upsample_factor = " + std::to_string(upsample_factor) +
                                " (expected a finite value >= 1)");
  }
  if (!(spacing_m >= 0.0) || !std::isfinite(spacing_m)) {
    throw std::invalid_argument("remove_spike_points: spacing_m = " + std::to_string(spacing_m) +
                                " (expected a finite value >= 0)");
  }
  const auto t0 = std::chrono::steady_clock::now();
  StageReport report;
  report.stage = "despike";
  report.count_in = cloud.size();
  const GridGeometry& g = grid.geometry();
  const int h = o.spike_window_cells / 2;
  // Spike cells and the height of their window's plane at the node.
  struct Target {
    int row, col;
    double base_m;  // the window's plane at the node [m]; NaN for an island or a rim cell
    double min_above_m;  // a candidate stands more than this above base_m [m]
    bool rim = false;  // a rim cell: every point within reach_rim is a candidate (radius ρ_rim)
  };
  std::vector<Target> targets;
  std::size_t n_spike = 0;
  // Spike cells: more than spike_min_height_m above the least-squares plane through the other
  // valid cells of the window (at least 3 of them). A plane, not the median: on a steep flank
  // the window's spread hides a spike from a median and MAD test, not from the plane. In a full
  // window the offsets are symmetric, so the plane at the node is the mean of the other cells;
  // partial windows (rims, holes) are solved. The valid cells are counted by a summed-area
  // table (integers: exact); a full window's heights are summed in a fixed order about the cell
  // (its columns' sums of 2h + 1 rows, then those left to right), so that a tile's window of
  // the grid gives the whole grid's base to the bit. (Until the sixty-fourth session,
  // 2026-11-30, a summed-area table of the heights gave it, whose rounding depends on where
  // the grid starts: a cell a rounding error from the spike height could be judged otherwise
  // in a window. No run was seen to differ by it.)
  const std::size_t ucols = static_cast<std::size_t>(g.cols), w1 = ucols + 1;
  std::vector<std::uint32_t> sat_n((static_cast<std::size_t>(g.rows) + 1) * w1, 0u);
  for (int r = 0; r < g.rows; ++r) {
    std::uint32_t run_n = 0;
    for (int c = 0; c < g.cols; ++c) {
      run_n += std::isnan(grid.at(r, c)) ? 0U : 1U;
      const std::size_t k = (static_cast<std::size_t>(r) + 1) * w1 + static_cast<std::size_t>(c) + 1;
      sat_n[k] = sat_n[k - w1] + run_n;
    }
  }
  // column_z[r · cols + c]: the valid heights of column c over rows r − h .. r + h (clipped),
  // summed top to bottom.
  std::vector<double> column_z(static_cast<std::size_t>(g.rows) * ucols, 0.0);
  for (int r = 0; r < g.rows; ++r) {
    double* out = column_z.data() + static_cast<std::size_t>(r) * ucols;
    for (int rr = std::max(0, r - h); rr < std::min(g.rows, r + h + 1); ++rr) {
      for (int c = 0; c < g.cols; ++c) {
        const float v = grid.at(rr, c);
        out[c] += std::isnan(v) ? 0.0 : static_cast<double>(v);
      }
    }
  }
  const auto full = static_cast<std::uint32_t>((2 * h + 1) * (2 * h + 1));
  // Island cells: every point within the reach of one is a candidate (found first, so that an
  // island's cells are not judged again as rim cells).
  std::size_t n_islands = 0, n_island_cells = 0;
  const std::vector<std::uint8_t> island = island_mask(grid, o.island_max_cells, &n_islands, o.spare_largest_group);
  // A valid cell's target, if it is a spike cell, a lone peak or a rim cell.
  auto judge = [&](int r, int c) -> std::optional<Target> {
    const float z = grid.at(r, c);
    if (std::isnan(z)) return std::nullopt;
    if (island[static_cast<std::size_t>(r) * ucols + static_cast<std::size_t>(c)]) return std::nullopt;
    // A cell at the surface's rim (a silhouette, a hole's edge) that is not a spike cell or a
    // lone peak: the points within the reach are judged, so that a stray just beyond the rim,
    // which extends the surface there without standing above it, is (uniform clutter on the
    // bunny left 4 such cells 2.1–2.6 mm from every scan point at 1 %). Within the reach, not
    // only its own cell: with a splat radius of 1.5 cells or more a stray's disc covers its
    // cell's 8 neighbours, and the rim lies further out.
    const auto rim_or_nothing = [&]() -> std::optional<Target> {
      if (!rim_cell(grid, r, c)) return std::nullopt;
      return Target{r, c, std::numeric_limits<double>::quiet_NaN(), 0.0, true};
    };
    const std::size_t r0 = static_cast<std::size_t>(std::max(0, r - h)), r1 = static_cast<std::size_t>(std::min(g.rows, r + h + 1));
    const std::size_t c0 = static_cast<std::size_t>(std::max(0, c - h)), c1 = static_cast<std::size_t>(std::min(g.cols, c + h + 1));
    const std::uint32_t n_win = sat_n[r1 * w1 + c1] + sat_n[r0 * w1 + c0] - sat_n[r0 * w1 + c1] - sat_n[r1 * w1 + c0];
    double base;
    if (n_win == full) {
      const double* col_sums = column_z.data() + static_cast<std::size_t>(r) * ucols;
      double sum = 0.0;
      for (std::size_t cc = c0; cc < c1; ++cc) sum += col_sums[cc];
      base = (sum - static_cast<double>(z)) / static_cast<double>(full - 1);
    } else {
      if (n_win < 4) return rim_or_nothing();  // the cell and at least 3 others
      const std::optional<double> offset =
          plane_offset_at(grid, r, c, static_cast<int>(r0), static_cast<int>(r1), static_cast<int>(c0), static_cast<int>(c1));
      if (!offset) return rim_or_nothing();  // collinear cells: no plane
      base = static_cast<double>(z) + *offset;  // the plane at the cell's node
    }
    // A point's splat raises the cells around its own with it, and they pull the plane up: a
    // stray just over spike_min_height_m in front shows only about 2/3 of it above a full
    // 5 × 5 window's mean. Where the cell stands more than half the height above the plane (and
    // not more than the height), the plane is fitted again without the window's cells more than
    // half the height above the first one. A trimmed fit only there: on the steep flanks at a
    // silhouette, where cells stand above the plane anyway, it would call true points spikes.
    const double half = 0.5 * o.spike_min_height_m;
    const double above_plane = static_cast<double>(z) - base;
    if (above_plane > half && above_plane <= o.spike_min_height_m) {
      if (const auto trimmed = trimmed_plane_at(grid, r, c, h, half)) base = *trimmed;
    }
    // A cell more than half the height above the plane and above each of its 8 neighbours is a
    // peak one cell wide (a stray the splat did not spread: its neighbours have points of their
    // own): its points more than half the height above the plane are candidates, so that a
    // stray at the spike height that the plane's curvature error hides is still judged.
    double min_above = o.spike_min_height_m;
    if (static_cast<double>(z) - base <= o.spike_min_height_m) {
      if (static_cast<double>(z) - base <= half || !lone_peak(grid, r, c, half)) return rim_or_nothing();
      min_above = half;
    }
    return Target{r, c, base, min_above};
  };
  // Two threads, each a contiguous half of the rows with its own list, joined in row order.
  const int scan_threads = g.cell_count() > (std::size_t{1} << 16) ? detail::kSearchThreads : 1;
  std::vector<std::vector<Target>> found(static_cast<std::size_t>(scan_threads));
  detail::run_parallel(scan_threads, [&](int t) {
    const int row_b = g.rows * t / scan_threads, row_e = g.rows * (t + 1) / scan_threads;
    for (int r = row_b; r < row_e; ++r)
      for (int c = 0; c < g.cols; ++c) {
        if (auto target = judge(r, c)) found[static_cast<std::size_t>(t)].push_back(*target);
      }
  });
  std::size_t n_rim = 0;
  for (const auto& part : found) {
    targets.insert(targets.end(), part.begin(), part.end());
    for (const Target& t : part) (t.rim ? n_rim : n_spike) += 1;
  }
  for (std::size_t i = 0; i < island.size(); ++i) {
    if (!island[i]) continue;
    targets.push_back({static_cast<int>(i / ucols), static_cast<int>(i % ucols), std::numeric_limits<double>::quiet_NaN(), 0.0});
    ++n_island_cells;
  }
  std::size_t candidates = 0, removed = 0;
  const bool indexable = cloud.size() < std::numeric_limits<std::uint32_t>::max() &&
                         g.cell_count() < std::numeric_limits<std::uint32_t>::max();
  if (!indexable) report.notes.push_back("skipped: more than 2^32 - 1 points or cells (32-bit point and cell indices)");
  if (!targets.empty() && indexable) {
    // Points binned by nearest node (reproject's rule), as compressed rows: first[cell]..first[cell + 1].
    const std::size_t n = cloud.size(), cells = g.cell_count();
    const double inv = 1.0 / g.cell_size_m;
    // Nodes as reproject bins them, on the whole grid when a window is given.
    const GridGeometry& whole = window != nullptr ? window->grid : g;
    const double inv_whole = 1.0 / whole.cell_size_m;
    const double cx = 0.5 - whole.x0_m * inv_whole, cy = 0.5 - whole.y0_m * inv_whole;
    const double first_col = window != nullptr ? window->col0 : 0, first_row = window != nullptr ? window->row0 : 0;
    std::vector<std::uint32_t> cell_of(n, std::numeric_limits<std::uint32_t>::max());
    std::vector<std::uint32_t> first(cells + 1, 0);
    const int bin_threads = n > (std::size_t{1} << 17) ? detail::kSearchThreads : 1;
    detail::run_parallel(bin_threads, [&](int t) {
      const auto [b, e] = detail::share_of(n, t, bin_threads);
      for (std::size_t i = b; i < e; ++i) {
        const auto p = cloud.xyz.col(static_cast<Eigen::Index>(i));
        if (!p.allFinite()) continue;
        const double fc = floor_of(p.x() * inv_whole + cx) - first_col, fr = floor_of(p.y() * inv_whole + cy) - first_row;
        if (fc < 0.0 || fr < 0.0 || fc >= g.cols || fr >= g.rows) continue;
        cell_of[i] = static_cast<std::uint32_t>(static_cast<std::size_t>(fr) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(fc));
      }
    });
    for (std::size_t i = 0; i < n; ++i) {
      if (cell_of[i] != std::numeric_limits<std::uint32_t>::max()) ++first[cell_of[i] + 1];
    }
    std::partial_sum(first.begin(), first.end(), first.begin());
    std::vector<std::uint32_t> order(first.back());
    {
      std::vector<std::uint32_t> fill(first.begin(), first.end() - 1);
      for (std::size_t i = 0; i < n; ++i)
        if (cell_of[i] != std::numeric_limits<std::uint32_t>::max()) order[fill[cell_of[i]]++] = static_cast<std::uint32_t>(i);
    }
    std::vector<double> radius_of(n, 0.0);  // > 0: a candidate, with its search radius [m]
    std::vector<std::uint8_t> rim_only(n, 0);  // within the reach of a rim cell
    // Search radii: 2 to 4 cells, or 2 to 4 point spacings where the scan is sparser than the grid.
    const double rho_lo = std::max(2.0 * g.cell_size_m, 2.0 * spacing_m), rho_hi = std::max(4.0 * g.cell_size_m, 4.0 * spacing_m);
    // A rim's radius in scan cells: on an upsampled grid 4 grid cells are a fraction of the
    // scan's spacing, and a sparse silhouette's true points would go (the Buddha at N = 4096,
    // K = 5: 836 points with ρ_hi, 93 with this).
    const double rho_rim = despike_search_radius_m(g.cell_size_m, upsample_factor, spacing_m);
    const int reach_all = static_cast<int>(std::ceil(reach_cells));
    // A stray's disc (radius reach_cells) reaches a cell that borders no data within
    // ⌈reach_cells − 1⌉ cells of the stray's own (0 for a radius of one cell).
    const int reach_rim = std::max(0, static_cast<int>(std::ceil(reach_cells - 1.0)));
    for (const Target& t : targets) {
      const int reach = t.rim ? reach_rim : reach_all;
      for (int rr = std::max(0, t.row - reach); rr <= std::min(g.rows - 1, t.row + reach); ++rr)
        for (int cc = std::max(0, t.col - reach); cc <= std::min(g.cols - 1, t.col + reach); ++cc) {
          const std::size_t cell = static_cast<std::size_t>(rr) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(cc);
          for (std::uint32_t k = first[cell]; k < first[cell + 1]; ++k) {
            const std::uint32_t i = order[k];
            if (t.rim) {
              rim_only[i] = 1;
              continue;
            }
            double rho = rho_hi;
            // A spike's points above its plane; an island's points within the reach (on an
            // upsampled grid a stray point's nearest fine node may itself be no data).
            if (!std::isnan(t.base_m)) {
              const double above = cloud.xyz(2, static_cast<Eigen::Index>(i)) - t.base_m;
              if (above <= t.min_above_m) continue;
              rho = std::clamp(0.5 * above, rho_lo, rho_hi);
            }
            radius_of[i] = std::max(radius_of[i], rho);
          }
        }
    }
    // A point near a rim takes ρ_rim only if no spike or island made it a candidate: a larger
    // radius than a spike's would let a stray beside a silhouette find its neighbours.
    std::vector<std::uint32_t> cand;
    for (std::size_t i = 0; i < n; ++i) {
      if (radius_of[i] == 0.0 && rim_only[i]) radius_of[i] = rho_rim;
      if (radius_of[i] > 0.0) cand.push_back(static_cast<std::uint32_t>(i));
    }
    candidates = cand.size();
    // Two threads, each a contiguous half of the candidates (each writes only their verdicts).
    std::vector<std::uint8_t> stray(cand.size(), 0);
    const int test_threads = cand.size() > 4096 ? detail::kSearchThreads : 1;
    detail::run_parallel(test_threads, [&](int t) {
      const auto [b, e] = detail::share_of(cand.size(), t, test_threads);
      for (std::size_t ci = b; ci < e; ++ci) {
        const std::uint32_t i = cand[ci];
        const Eigen::Vector3d p = cloud.xyz.col(static_cast<Eigen::Index>(i));
        const double rho = radius_of[i];
        const int span = static_cast<int>(std::ceil(rho * inv));
        const int r0 = static_cast<int>(cell_of[i] / static_cast<std::uint32_t>(g.cols));
        const int c0 = static_cast<int>(cell_of[i] % static_cast<std::uint32_t>(g.cols));
        // The cells in rings about the point's own (Chebyshev distance 0, 1, ..., span), nearest
        // first, until the count is reached: the verdict is the same in any order, and a point on
        // the surface usually finds its neighbours in its own cell.
        int count = 0;
        const auto visit = [&](int rr, int cc) {
          const std::size_t cell = static_cast<std::size_t>(rr) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(cc);
          for (std::uint32_t k = first[cell]; k < first[cell + 1]; ++k) {
            const std::uint32_t j = order[k];
            if (j != i && (cloud.xyz.col(static_cast<Eigen::Index>(j)) - p).squaredNorm() <= rho * rho) ++count;
          }
        };
        visit(r0, c0);
        for (int d = 1; d <= span && count < o.isolation_min_neighbours; ++d) {
          const int c_lo = std::max(0, c0 - d), c_hi = std::min(g.cols - 1, c0 + d);
          for (int rr = std::max(0, r0 - d); rr <= std::min(g.rows - 1, r0 + d); ++rr) {
            if (rr == r0 - d || rr == r0 + d) {
              for (int cc = c_lo; cc <= c_hi; ++cc) visit(rr, cc);  // the ring's top or bottom row
            } else {
              if (c0 - d >= 0) visit(rr, c0 - d);  // its sides
              if (c0 + d < g.cols) visit(rr, c0 + d);
            }
          }
        }
        stray[ci] = count < o.isolation_min_neighbours ? 1 : 0;
      }
    });
    std::vector<bool> keep(n, true);
    for (std::size_t ci = 0; ci < cand.size(); ++ci) {
      if (!stray[ci]) continue;
      keep[cand[ci]] = false;
      ++removed;
    }
    if (removed > 0 && removed_points != nullptr) {
      for (std::size_t i = 0; i < n; ++i) {
        if (keep[i]) continue;
        removed_points->at.push_back(i);
        const auto p = cloud.xyz.col(static_cast<Eigen::Index>(i));
        removed_points->xyz.insert(removed_points->xyz.end(), {p[0], p[1], p[2]});
      }
    }
    if (removed > 0) cloud.keep_if(keep);
  }
  report.count_out = cloud.size();
  report.figure("spike_cells", static_cast<double>(n_spike));
  report.figure("rim_cells", static_cast<double>(n_rim));
  report.figure("island_cells", static_cast<double>(n_island_cells));
  report.figure("candidates", static_cast<double>(candidates));
  report.figure("removed_spike_points", static_cast<double>(removed));
  report.notes.push_back("removed " + std::to_string(removed) + " of " + std::to_string(candidates) +
                         " points standing in grid spikes, at the surface's rim or in islands with fewer than " +
                         std::to_string(o.isolation_min_neighbours) + " other points within half their height (2-4 cells or spacings)");
  report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return {std::move(cloud), std::move(report)};
}

double median_point_spacing(const Eigen::Matrix3Xd& xyz_m, double start_edge_m) {
  if (!std::isfinite(start_edge_m) || !(start_edge_m > 0.0)) {
    throw ConfigError("median_point_spacing: start_edge_m = " + format_number(start_edge_m) +
                      " (expected a finite voxel edge > 0 m)");
  }
  const std::size_t n = static_cast<std::size_t>(xyz_m.cols());
  if (n < 2) return 0.0;
  // The local frame of check_input: float offsets from the points' mean.
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  std::size_t m = 0;
  for (Eigen::Index i = 0; i < xyz_m.cols(); ++i) {
    if (!xyz_m.col(i).allFinite()) continue;
    mean += xyz_m.col(i);
    ++m;
  }
  if (m < 2) return 0.0;
  mean /= static_cast<double>(m);
  std::vector<float> local;
  std::vector<std::uint8_t> finite;
  local_floats(xyz_m, mean, local, finite);
  return median_spacing(local, finite, start_edge_m);
}

}  // namespace hc::pipeline
