#pragma once
// Far clusters of a whole scan, found tile by tile in memory bounded by a tile (the tiled run's
// stage tile_far_clusters, tiled_run.cpp; issue 14: "memory bounded by the grid tile and the
// chunk size, not by the cloud").
//
// The clusters are the connected components of the occupied coarse cells (edge E, the grid
// frame) under 26-neighbour adjacency: single linkage, as robust_outliers.cpp's
// remove_far_clusters does in core on cells of the linking distance. Until 2026-11-26 the stage
// kept every occupied cell of the scan in one table (about 95 bytes a cell: 2.77 M cells and
// 383 MB at 10^9 points) and joined them at the end. Now each tile's cells are joined among
// themselves, then to the cells that earlier tiles left on their far sides (the frontier), and
// dropped; a component keeps only its count, box and least cell key, and, while it is small
// enough to be removed, the keys of its cells. The components, their order and every figure
// are the same as one table's would be (tests/pipeline/far_cells_test.cpp checks it against a
// whole-scan flood fill).

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <vector>

namespace hc::pipeline::detail {

/// Far clusters on coarse cells, fed one tile's points at a time.
///
/// Cells: cell (i, j, l) holds the points p (grid frame [m]) with floor((p − origin)/E) =
/// (i, j, l) per axis, each index clamped to [0, 2^21 − 1]. Two cells are linked when their
/// indices differ by at most 1 on every axis.
///
/// The tiles' contract (Tiles::interior in tiled_run.cpp meets it): each tile is fed once
/// (begin_tile, add_points, end_tile) in row-major order (tile_row never decreases); the points
/// added to a tile are the ones its interior owns, each point of the scan added to exactly one
/// tile; every point of a later tile
/// of the same row has a larger x, and every point of a later row a larger y, than every point
/// of the earlier tiles (or an equal coordinate that floors to the same cell index; strict order
/// of the node indices gives this, since the nearest-node binning and the flooring are
/// monotone). Then a cell that neighbours a cell of a later tile lies within one index of its
/// own tile's largest x or y index, which is what the frontier keeps, and a cell of a tile
/// neighbours an earlier tile's cell only within one index of its own tile's smallest x or y
/// index, which is what is looked up.
///
/// Two ways to feed a tile: its points (add_points: cells on `origin` as above, the tiled run's
/// coarse whole-scan pass), or its cells whole (add_cell, keys from link_key: the link cells of
/// the points each tile's robust test kept, which the merge joins into the in-core run's far
/// clusters; sixty-sixth session, 2026-11-30). Do not mix them in one FarCells.
///
/// Memory: one tile's cells (about 95 bytes each: the cell, its key, two slots of the tile's
/// table), the frontier (about two rows
/// of tiles' far sides, about 40 bytes a cell), about 100 bytes per component and 8 bytes per
/// cell of each component of at most `small_points` points (a far cluster that may be removed);
/// no point is held. Not thread-safe.
class FarCells {
 public:
  /// origin_m: the corner of cell (0, 0, 0), grid frame [m]. edge_m: E [m], > 0.
  /// small_points: a component of at most this many points may be removed (max(max_points,
  /// max_fraction × points), FarClusterOptions); its cells' keys are kept until it grows past it.
  /// @throws std::invalid_argument when edge_m is not finite and positive.
  FarCells(const Eigen::Vector3d& origin_m, double edge_m, std::uint64_t small_points);

  /// E [m].
  double edge() const { return edge_; }

  /// A tile, streamed: begin_tile, add_points for its own points in any number of batches,
  /// end_tile. tile_row: the tile's row of tiles (0, 1, ...; non-decreasing over the tiles, see
  /// the class comment). Only the tile's cells are held until end_tile, not its points.
  /// @throws std::logic_error when tile_row decreases, a tile is begun twice or not begun, or
  ///         after components().
  void begin_tile(int tile_row);
  /// xyz: n points of the tile as x y z doubles [m] (grid frame), all the tile's own. Each point
  /// is added to its cell in the tile's own table (open addressing, at most half full: a tile's
  /// few thousand cells stay in cache, where a table sized by the points did not).
  void add_points(const double* xyz, std::size_t n);
  /// A cell of the tile whole: key from link_key (kNoKey not allowed), its points' count and
  /// box lo, hi (3 doubles each, grid frame [m]). A key given twice in one tile is one cell (the
  /// counts added, the boxes joined).
  /// @throws std::logic_error outside a tile, for kNoKey, or after add_points.
  void add_cell(std::uint64_t key, std::uint32_t count, const double* lo, const double* hi);
  /// Joins the tile's cells among themselves and to the frontier, and keeps its far sides.
  void end_tile();

  /// No cell: a point beyond link_key's range.
  static constexpr std::uint64_t kNoKey = std::numeric_limits<std::uint64_t>::max();
  /// The key of the cell of edge 1 / inv_edge [m] that holds the point at p (3 doubles, grid
  /// frame [m]): per axis floor(p · inv_edge), the in-core cell of remove_far_clusters
  /// (robust_outliers.cpp: the same product and floor, so the same cell of every point), plus
  /// 2^20 so that it fits 21 bits; kNoKey when an index lies outside [−2^20, 2^20 − 1] or p is
  /// not finite. Adjacency is unchanged by the shift, so the components are the in-core ones.
  static std::uint64_t link_key(const double* p, double inv_edge);

  /// What components() found.
  struct Result {
    std::size_t cells = 0;     ///< occupied coarse cells (distinct)
    std::size_t clusters = 0;  ///< components
    std::size_t removed_clusters = 0, kept_far_clusters = 0;
    std::uint64_t removed_points = 0;
    Eigen::Vector3d main_lo = Eigen::Vector3d::Zero(), main_hi = Eigen::Vector3d::Zero();  ///< the main body's box [m]
    /// The box of every point fed [m] (infinite, inverted, when none).
    Eigen::Vector3d box_lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), box_hi = -box_lo;
    std::vector<std::string> notes;  ///< the first 20 far clusters, in order of their least cell key
    // How much the tile-by-tile joining held (stage figures).
    std::size_t frontier_cells_peak = 0;  ///< most cells in the frontier at once
    std::size_t tile_components = 0;      ///< components numbered (the tiles' own, before joining)
    std::size_t listed_cells_peak = 0;    ///< most cell keys kept for small components at once
  };

  /// After the last end_tile: the components. The main body is the component of most points
  /// (the first in order of least cell key on a tie). A component other than it whose box lies
  /// more than far_m [m] from the main body's box (Euclidean distance between the boxes) is far;
  /// a far one of at most small_points points is removed (holds() then tells its points), a
  /// larger one is kept and noted. Boxes are the points' boxes, in doubles (until the
  /// sixty-sixth session float offsets from the origin). Same rule as remove_far_clusters
  /// (robust_outliers.hpp), but for a tie of the largest components (there the first in the
  /// cloud's order of points).
  /// @throws std::logic_error when called twice.
  Result components(double far_m);

  /// Whether the point at p (3 doubles, grid frame [m]) lies in a removed cluster's cell
  /// (false before components()). A bitmap over a hash of the key answers most points.
  /// The removed clusters' cells (empty before components()): their keys, increasing, and each
  /// one's cluster, numbered 0, 1, ... in the order of the clusters' least cell keys.
  struct FarCellList {
    std::vector<std::uint64_t> keys;
    std::vector<std::uint32_t> cluster;
  };
  FarCellList far_cells() const;

  /// For a FarCells fed points (add_points) only: its keys are the origin's, not link_key's.
  /// @throws std::logic_error on one fed whole cells (far_cells() lists theirs).
  bool holds(const double* p) const {
    if (cells_fed_) throw std::logic_error("FarCells::holds on cells fed whole: look their keys up in far_cells()");
    if (far_.empty()) return false;
    const std::uint64_t k = key(p);
    const std::uint64_t b = filter_bit(k);
    if (((far_filter_[b >> 6] >> (b & 63)) & 1U) == 0) return false;
    return far_.count(k) > 0;
  }

 private:
  // The cell key of the point at p (x index << 42 | y << 21 | z, each clamped to [0, 2^21 − 1]).
  std::uint64_t key(const double* p) const;
  static constexpr std::uint64_t kMask = (std::uint64_t{1} << 21) - 1;
  struct Cell {  // 56 bytes: the point count and the points' box [m]
    std::uint64_t count = 0;
    double lo[3] = {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
                    std::numeric_limits<double>::infinity()};
    double hi[3] = {-std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
                    -std::numeric_limits<double>::infinity()};
  };
  struct Comp {  // a component's summary, valid at its root
    std::uint64_t count = 0;
    std::uint64_t least_key = std::numeric_limits<std::uint64_t>::max();
    double lo[3] = {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
                    std::numeric_limits<double>::infinity()};
    double hi[3] = {-std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
                    -std::numeric_limits<double>::infinity()};
  };
  std::uint32_t find(std::uint32_t a);
  void join(std::uint32_t a, std::uint32_t b);
  void evict_before_row();

  Eigen::Vector3d origin_;
  double edge_, inv_;
  std::uint64_t small_;
  bool done_ = false, in_tile_ = false;
  bool points_fed_ = false, cells_fed_ = false;  // which way it was fed (not both)
  int row_ = 0;
  std::uint64_t y_seen_max_ = 0;  // the largest y index of any cell added so far
  std::size_t cells_ = 0, listed_ = 0;
  Result stats_;
  // The current tile's cells, in order of first appearance (tile_cells_, tile_keys_), found by
  // key through tile_slots_ (open addressing, a power of two slots, at most half full).
  struct Slot {
    std::uint64_t key;
    std::uint32_t index;  // into tile_cells_; kFree when the slot is free
  };
  static constexpr std::uint32_t kFree = std::numeric_limits<std::uint32_t>::max();
  // The slot where the search for `key` starts (Fibonacci hashing to tile_bits_ bits).
  std::size_t tile_home(std::uint64_t key) const { return static_cast<std::size_t>((key * 0x9E3779B97F4A7C15ULL) >> (64 - tile_bits_)); }
  std::uint32_t tile_cell(std::uint64_t key);      // the cell of `key`, added when new
  std::uint32_t tile_find(std::uint64_t key) const;  // the cell of a key the tile holds
  void tile_grow();
  int tile_bits_ = 10;
  std::vector<Slot> tile_slots_ = std::vector<Slot>(std::size_t{1} << 10, Slot{0, kFree});
  std::vector<Cell> tile_cells_;
  std::vector<std::uint64_t> tile_keys_;
  std::unordered_map<std::uint64_t, std::uint32_t> frontier_;  // cell key -> component
  std::vector<std::uint32_t> parent_;
  std::vector<Comp> comps_;
  std::vector<std::vector<std::uint64_t>> listed_cells_;  // per root of at most small_ points
  static constexpr int kFilterBits = 20;                 // 128 KiB
  static std::uint64_t filter_bit(std::uint64_t k) { return (k * 0x9E3779B97F4A7C15ULL) >> (64 - kFilterBits); }
  std::unordered_map<std::uint64_t, std::uint32_t> far_;  // removed cell key -> its cluster
  std::vector<std::uint64_t> far_filter_;
};

}  // namespace hc::pipeline::detail
