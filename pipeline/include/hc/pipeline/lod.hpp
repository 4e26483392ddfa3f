#pragma once
/// @file lod.hpp
/// Levels of detail (paper Sec. 4.1, "adaptive scaling"): a pyramid of Monge grids from the
/// finest depth grid (level 0) down to a configured minimum, each level half the resolution of
/// the one before, smoothed before it is decimated (anti-aliasing) with no-data handled, and
/// with its own texture, envelope, μ_d and μ_s computed for the level (compute_surface_layers).
/// Levels and haptic windows are built on demand and kept in an LRU cache under a memory
/// budget (docs/lod.md). No OpenCV, PCL or yaml-cpp in this header.

#include "hc/common/height_field.hpp"
#include "hc/pipeline/exact_sum.hpp"
#include "hc/pipeline/surface_layers.hpp"

#include <cstddef>
#include <span>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace hc::pipeline {

/// Options of the pyramid, the cache and the haptic window: hc::LodOptions (scene contract).
using hc::LodOptions;

/// One level: its depth grid and the layers computed for it. All fields share one geometry.
/// Level L has cell size 2^L·(level 0's) and the same origin (x0_m, y0_m): sample (r, c) of
/// level L sits on sample (2^L·r, 2^L·c) of level 0, so every level lives in the same grid frame.
struct LodLevel {
  int level = 0;
  HeightField depth_m;      ///< smoothed, decimated depth [m], NaN = no data
  HeightField envelope_m;   ///< f_b of this level [m] (empty when !has_layers)
  HeightField texture_m;    ///< h = f − f_b of this level [m]
  HeightField mu_d;         ///< μ_d [-] of this level (curvature with this level's cell size)
  HeightField mu_s;         ///< μ_s [-]
  bool has_layers = false;  ///< envelope, texture, μ_d, μ_s present
  /// Empty, or rows·cols·3 bytes, R G B per sample (the scan's colour, scene layer colour).
  /// Coarser levels: each channel by the same normalised smoothing as depth (downsample_2x over
  /// the samples with valid depth, rounded to 8 bit), so it is present exactly where depth is;
  /// 0, 0, 0 where depth is no data. Built together with the depth.
  CellBuffer<std::uint8_t> colour_rgb8{};
  /// Empty, or the scene's cross-check error per sample [m] (scene layer cell_error: 3-D
  /// distance from the level-0 grid sample to its nearest input point, ≥ 0, NaN = none). Level 0
  /// holds the scene's map; a coarser level holds level 0's map carried down by downsample_2x
  /// with the depth's σ and valid fraction (a local weighted mean of the finer errors: where the
  /// finest grid departs from the points, not this level's own error against them, which only
  /// `hapticloud levels` measures). Built together with the depth.
  HeightField cell_error_m{};
  double depth_seconds = 0.0;   ///< time to smooth and decimate from the level above [s] (0 for level 0)
  double layers_seconds = 0.0;  ///< time of compute_surface_layers for this level [s]
  /// Bytes held by the grids. Real-time: no.
  std::size_t bytes() const;
};

/// Cropped layers of one haptic window: `rows × cols` samples of a level starting at sample
/// (row0, col0). Fields share one geometry (the window's samples, grid frame); the layers other
/// than depth are empty when the level has none.
struct LodWindowLayers {
  int level = 0;
  int row0 = 0, col0 = 0;
  HeightField depth_m, envelope_m, texture_m, mu_d, mu_s;
  std::vector<std::uint8_t> colour_rgb8{};  ///< the level's colour cropped (empty if it has none)
  HeightField cell_error_m{};  ///< the level's cell_error_m cropped [m] (empty if it has none)
  std::size_t bytes() const;
};

/// Number of levels (≥ 1) for a finest grid: level L exists while the longer side of its grid
/// is ≥ min_cells (level 0 always exists). @throws hc::ConfigError for min_cells < 2.
int lod_level_count(const GridGeometry& finest, int min_cells);

/// Geometry of level L without building it: rows_L = ⌈rows_{L−1}/2⌉ (likewise cols), cell size
/// 2^L·cell, same origin. For an even size the last fine row/column has no coarse sample on it
/// (the coarse grid ends half a coarse cell short of it). @throws hc::ConfigError for L < 0.
GridGeometry lod_level_geometry(const GridGeometry& finest, int level);

/// Anti-aliased 2× decimation of a depth grid with no-data handling (normalised convolution,
/// Knutsson & Westin 1993): with the separable Gaussian kernel w (σ = sigma_cells fine samples,
/// radius ⌈3σ⌉) and m = 1 on valid samples inside the grid, 0 elsewhere (no data and beyond
/// the border),
///   z_coarse(r, c) = Σ w·m·z / Σ w·m   around fine sample (2r, 2c),
/// valid only if Σ w·m ≥ valid_fraction · Σ w·[inside the grid] (to a relative 1e-6: the sums
/// are single precision); else NaN. NaN never enters a
/// sum, so it never leaks into a valid sample; a plane is reproduced exactly away from holes and
/// the border (a one-sided neighbourhood there shifts it by at most slope·σ).
/// Output geometry: lod_level_geometry(fine, 1) relative to `fine`; model_to_grid is copied.
/// @throws hc::ConfigError for sigma_cells outside [0.5, 4] or valid_fraction outside (0, 1];
///         hc::InputError for an empty grid. Real-time: no. Cost: O(rows·cols·σ).
HeightField downsample_2x(const HeightField& fine, double sigma_cells, double valid_fraction);

/// SampleWindow (a block of samples of a grid) is declared in surface_layers.hpp.

/// Radius ⌈3σ⌉ [fine samples] of downsample_2x's kernel.
int downsample_2x_radius_cells(double sigma_cells);

/// Adds the finite values among `count` floats to `sum` (exactly: ExactFloatSum) and counts them
/// in `finite`. downsample_2x's reference height [m] is sum.value() / finite over its whole grid;
/// the grid's pieces (tiles, in any order or split between threads) give the same bits.
void add_finite_values(const float* values, std::size_t count, ExactFloatSum& sum, std::size_t& finite);

/// downsample_2x for a block of the coarse level (issue 14, a level built tile by tile):
/// `out_block` of the coarse grid of a fine grid of fine_rows × fine_cols samples, from
/// `fine` = fine_window.rows × fine_window.cols fine samples (row-major, NaN = no data) at
/// (fine_window.row0, fine_window.col0), which must hold every fine sample the block's kernels
/// reach (fine rows 2·row0 − radius … 2·(row0 + rows − 1) + radius clipped to the grid, likewise
/// columns; radius = downsample_2x_radius_cells). `ref` must be the whole fine grid's
/// reference height (add_finite_values). Writes out_block.rows × out_block.cols values (row-major) to `out`,
/// equal bit for bit to the same samples of downsample_2x on the whole grid.
/// @throws hc::ConfigError as downsample_2x; std::invalid_argument when the window misses a
///         kernel sample or the block leaves the coarse grid.
void downsample_2x_block(const float* fine, const SampleWindow& fine_window, int fine_rows, int fine_cols, double ref,
                         double sigma_cells, double valid_fraction, const SampleWindow& out_block, float* out);


/// The nodes of `g` with x0_m ≤ x ≤ x1_m and y0_m ≤ y ≤ y1_m (grid frame [m]), clipped to the
/// grid. @throws hc::ConfigError naming the window when the bounds are not finite with X0 < X1
/// and Y0 < Y1, or when it holds fewer than 2 × 2 nodes (naming the grid's extent).
SampleWindow window_of_extent(const GridGeometry& g, double x0_m, double y0_m, double x1_m, double y1_m);

/// rows × cols samples of `src` from (row0, col0) as a new field (geometry moved to the window's
/// first sample, model_to_grid kept). @throws std::invalid_argument when the window leaves `src`.
HeightField crop_height_field(const HeightField& src, int row0, int col0, int rows, int cols);

/// The colour bytes (3 per sample, row-major, of a grid `g`) of the same window. The caller keeps
/// the window inside `g` and `src` at 3·g.rows·g.cols bytes.
std::vector<std::uint8_t> crop_colour(std::span<const std::uint8_t> src, const GridGeometry& g, int row0, int col0,
                                      int rows, int cols);

/// The pyramid and its cache. Level 0 is given (the scene's depth and, when present, its
/// envelope, texture, μ_d and μ_s); every coarser level is built on first use from the level
/// above (its depth by downsample_2x, its layers by compute_surface_layers with `layer_options`)
/// and cached. Cached entries (levels ≥ 1, window crops) are evicted least recently used first
/// when their bytes exceed memory_budget_mb; an evicted level is rebuilt on demand (from the
/// nearest cached finer depth). Objects handed out stay valid while the caller holds them.
/// Thread-safe. The cache has one mutex, held only for lookups and inserts; builds run outside it,
/// serialised by a second (recursive) mutex, so two threads never build the same level and
/// lookups and windows of cached levels never wait for a build (a background prefetch, say).
class LodPyramid {
 public:
  /// @param finest level 0; its depth must have rows, cols ≥ 2 and a valid sample; its other
  ///        fields, when has_layers, must share the depth's geometry; its colour, if any,
  ///        must hold rows·cols·3 bytes; its cell_error_m, if any, must share the depth's geometry.
  /// @throws hc::ConfigError for options out of range (naming the lod.* key and the value);
  ///         hc::InputError for an empty or geometry-mismatched level 0.
  LodPyramid(LodLevel finest, const SurfaceLayerOptions& layer_options, const LodOptions& options);

  /// From a scene: moves its depth (and envelope, texture, mu_d, mu_s when all four are
  /// present, and its colour and cell_error when present) into level 0. Callers usually pass the scene's own layer_options and lod.
  /// @throws as the constructor (hc::InputError for an empty depth layer).
  static std::shared_ptr<LodPyramid> from_scene(hc::Scene&& scene, const SurfaceLayerOptions& layer_options,
                                                const LodOptions& options);

  /// The pyramid of a tiled scene folder (write_scene with SceneStorage::tile_cells > 0, then
  /// build_stored_levels, level_builder.hpp): every level is on disk, so nothing is built and nothing is loaded at
  /// open but scene.yaml; each layer file's directory is read on first use, and a window reads
  /// only the tiles it overlaps (issue 14: a 65 536 × 32 768 scene opens and switches windows in
  /// bounded memory). `options` as in the constructor: memory_budget_mb bounds the cache, a
  /// quarter of it for decoded tiles (shared by the windows that overlap them: a pan decodes only
  /// the tiles it adds), the rest for windows and whole levels; window_cells the haptic window.
  /// The level count is the stored one. level(L) reads a whole level only when it fits in that
  /// rest, else it throws.
  /// @throws hc::InputError naming the folder or file: not a tiled scene (format 3 with
  ///         stored_levels ≥ 1), a missing or malformed layer file; hc::ConfigError for options
  ///         out of range.
  static std::shared_ptr<LodPyramid> open_stored(const std::filesystem::path& scene_dir, const LodOptions& options);
  /// True for a pyramid opened by open_stored.
  bool stored() const noexcept { return stored_ != nullptr; }
  /// The scene folder a stored pyramid reads (open_stored's scene_dir); empty for a pyramid in
  /// memory. For the files stored beside the levels (points_sample.bin, lod_report.hpp).
  std::filesystem::path stored_dir() const;
  /// Tiles decoded from the stored layer files so far (0 for a pyramid in memory): what a
  /// window cost on disk, for tests and benchmarks.
  std::uint64_t tiles_read() const;
  /// A stored pyramid's bytes a sample of a window or whole level read with every layer it
  /// stores (four bytes a float layer, three for colour); 0 for a pyramid in memory.
  std::size_t stored_bytes_per_sample() const noexcept;
  /// The bytes cached windows and whole levels may hold [bytes]: 3/4 of memory_budget_mb for a
  /// stored pyramid (the rest is its decoded tiles'), all of it for one in memory. A stored level
  /// of more than this is never read whole (level() throws), nor is such a window.
  std::size_t entry_budget_bytes() const noexcept;

  int level_count() const noexcept { return level_count_; }
  /// Geometry of level L (nothing is built). @throws hc::InputError for L out of range.
  const GridGeometry& geometry(int level) const;
  const LodOptions& options() const noexcept { return options_; }
  const SurfaceLayerOptions& layer_options() const noexcept { return layer_options_; }

  /// Level L with its layers, built if needed (a stored pyramid reads it from its files, not
  /// through the tile cache). @throws hc::InputError for L out of range, for a stored level
  /// larger than 3/4 of memory_budget_mb (naming its size: only its windows can be read), and whatever
  /// compute_surface_layers throws. Real-time: no.
  std::shared_ptr<const LodLevel> level(int level);
  /// Level L with at least its depth (layers not computed if not cached). Real-time: no.
  std::shared_ptr<const LodLevel> depth_level(int level);
  /// True when level L's depth (and layers, if `with_layers`) are cached.
  bool is_cached(int level, bool with_layers = true) const;

  /// The window of rows × cols samples of level L at (row0, col0), clamped so that it lies
  /// inside the level (a level smaller than the window gives the whole level), cropped from the
  /// level's layers (a stored pyramid: read from the tiles it overlaps) and cached.
  /// `keep` false: a window read once (a sweep over a level, as the levels table's): taken from
  /// the cache when it is there, else read (a stored pyramid's tiles still pass the tile cache)
  /// and not added to the cache, so the sweep does not fill the budget with windows nobody reads
  /// again, nor evict the session's.
  /// @throws hc::InputError for L out of range or a size < 2; for a stored pyramid also for a
  ///         window larger than 3/4 of memory_budget_mb and a file that cannot be read (naming it).
  std::shared_ptr<const LodWindowLayers> window(int level, int row0, int col0, int rows, int cols, bool keep = true);

  /// Cache figures.
  struct CacheStats {
    std::size_t bytes = 0;          ///< bytes of the cached entries (levels ≥ 1 and windows; a stored
                                    ///< pyramid's level 0 too)
    std::size_t budget_bytes = 0;   ///< memory_budget_mb in bytes
    std::size_t finest_bytes = 0;   ///< level 0, held outside the budget
    std::uint64_t hits = 0, misses = 0, evictions = 0;
    int levels_cached = 0, windows_cached = 0;
    /// A stored pyramid's decoded tiles with data (a quarter of the budget; windows and levels get
    /// the rest). bytes + tile_bytes stays within budget_bytes up to the entry just added; memory
    /// also holds the entry being read and entries callers still hold after eviction.
    std::size_t tile_bytes = 0;
    int tiles_cached = 0;
    std::uint64_t tile_hits = 0;  ///< tiles a window took from the cache instead of the file
  };
  CacheStats cache_stats() const;

 private:
  struct Entry;
  struct Stored;
  LodPyramid(std::shared_ptr<Stored> stored, const SurfaceLayerOptions& layer_options, const LodOptions& options,
             int level_count, const GridGeometry& finest);
  std::shared_ptr<LodWindowLayers> read_stored_window(int level, int row0, int col0, int rows, int cols,
                                                      bool cached) const;
  double entry_budget_mb() const noexcept;  // the share of memory_budget_mb for windows and levels
  static std::shared_ptr<LodWindowLayers> crop_window_locked(const LodLevel& lvl, int level, int row0, int col0, int rows,
                                                             int cols);
  // Cached level (mutex_ held): the level, or null; *depth_only gets a cached depth-only level.
  std::shared_ptr<const LodLevel> cached_locked(int level, bool with_layers,
                                                std::shared_ptr<const LodLevel>* depth_only);
  std::shared_ptr<const LodLevel> get_level(int level, bool with_layers);
  void touch_locked(Entry& e);
  void evict_locked();

  LodOptions options_;
  SurfaceLayerOptions layer_options_;
  int level_count_ = 1;
  std::vector<GridGeometry> geometries_;
  std::shared_ptr<LodLevel> finest_;  // null for a stored pyramid (level 0 is then a cache entry)
  std::shared_ptr<Stored> stored_;    // the tiled scene's files, or null
  mutable std::mutex mutex_;          // the cache: entries_, finest_, counters
  std::recursive_mutex build_mutex_;  // one build at a time (a level builds the depth above it)
  std::vector<std::shared_ptr<Entry>> entries_;  // cached levels ≥ 1 and windows
  std::uint64_t clock_ = 0;
  std::size_t bytes_ = 0;
  std::uint64_t hits_ = 0, misses_ = 0, evictions_ = 0;
};

}  // namespace hc::pipeline
