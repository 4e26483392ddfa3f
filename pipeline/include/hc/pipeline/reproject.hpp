#pragma once
/// @file reproject.hpp
/// Stage 5: orthographic reprojection onto a regular grid (the depth-buffer scan of the paper),
/// see-through detection, and hole filling.

#include "hc/common/height_field.hpp"
#include "hc/pipeline/cloud.hpp"

#include <array>
#include <cstdint>
#include <optional>
#include <vector>

namespace hc::pipeline {

/// How the grid is sized. Exactly one of n_long_side or cell_size_m is > 0.
struct GridSpec {
  int n_long_side = 0;       ///< cells along the longer side of the points' x-y extent, ≥ 2
  double cell_size_m = 0.0;  ///< or the spacing [m]
  std::size_t max_cells = 64u * 1024u * 1024u;  ///< memory cap on rows·cols
};

/// How splat_radius_cells fills the cells around the measured ones.
enum class SplatMode {
  /// Flat discs: each point writes its z over the disc, front-most rule (see splat_radius_cells).
  /// Finer than the point spacing this leaves flat terraces with one-cell risers.
  kDisc,
  /// Normalised convolution restricted to the disc: each EMPTY cell within splat_radius_cells of
  /// at least one measured cell takes the Gaussian-weighted mean (σ = radius / 2 cells, weight
  /// exp(−d² / 2σ²) over the measured cells at distance d ≤ radius) of those measured heights.
  /// Measured cells keep their front-most z, except that with see-through handling on
  /// (see_through_depth_m > 0) a measured cell more than see_through_depth_m below the
  /// front-most measured cell within the radius is emptied first, as kDisc occludes it, and
  /// only measured cells within see_through_depth_m of that front-most one enter a cell's mean
  /// (so a merged multi-view scan's back surfaces are neither kept nor averaged in). Cells
  /// farther than the radius from every measured cell stay no data. A weighted
  /// mean is exact on a plane only where the weighted centroid of the measured cells is the
  /// cell itself (symmetric sampling); otherwise it is off by slope × that offset (at most
  /// slope × radius, at the rim of the data).
  kInterpolate,
  /// Weighted local planes, for unorganised and merged multi-view clouds: every node within
  /// splat_radius_cells (exact x-y distance from the point) of at least one gathered point (see
  /// below: with see-through handling, front-surface points only) takes the value at the node
  /// of the weighted least-squares plane through those points (weight
  /// exp(−d² / 2σ²), σ = radius / 2 cells), measured nodes included, so the noise and the
  /// registration offsets of overlapping views average out instead of the front-most sample
  /// deciding each node. With see_through_depth_m > 0 only points within see_through_depth_m
  /// below the front-most measured z within radius + √2/2 cells of the node enter its plane
  /// (the front surface); with it 0, every point in the radius does. The slope is fitted along
  /// each principal x-y direction of the node's points (eigenvectors e_k, weighted variances
  /// l_k of their offsets) only where the node lies within 3 standard deviations of their
  /// weighted centroid x̄ along it, (e_k·x̄)² ≤ 9·l_k; along the others the node takes the
  /// weighted mean (across a single scan line, at a single point, at a sparse rim), so no value
  /// is an extrapolation that amplifies noise. Exact on a plane (up to float rounding) wherever
  /// the slope is fitted in both directions; on a curved surface the fit averages over about σ. A measured node whose front-most point
  /// lies more than see_through_depth_m below its plane is flagged kCellSplatted and counted in
  /// cells_occluded_by_splat; filled empty nodes are kCellSplatted. Cost: a counting sort of
  /// the points' indices by row (8 bytes a point while it runs, 4 kept through the pass), then
  /// one pass over the points in that order touching (2·radius + 1)² nodes each, 36 bytes of
  /// moments per cell. A node sums its points in (row, input) order, so a window's sums equal
  /// the whole grid's (the tiled run).
  kPlane,
};

/// A window of a larger grid: rows [row0, row0 + rows) and columns [col0, col0 + cols) of
/// `grid` (the tiled pipeline, issue 14: one tile and its halo).
struct GridWindow {
  GridGeometry grid;  ///< the whole grid (origin, cell size, rows, cols)
  int row0 = 0, col0 = 0;
  int rows = 0, cols = 0;
};

/// Orthographic depth scan options.
struct ReprojectOptions {
  GridSpec grid;
  /// kDisc: each point also writes, front-most rule again, the nodes within this radius [cells]
  /// of the node it falls on (a disc splat), so sparse scans leave no pinholes. Splats fill
  /// empty cells and, with see-through handling on, hide measured cells lying more than
  /// see_through_depth_m behind them; they never move a measured cell otherwise.
  /// kInterpolate: empty cells within this radius of a measured cell are interpolated (see
  /// SplatMode) from the front surface only; with see-through handling on, measured cells
  /// lying more than see_through_depth_m behind a measured cell within the radius are emptied
  /// and interpolated too (counted in cells_occluded_by_splat). Either way the filled cells are flagged kCellSplatted, and see-through
  /// detection runs afterwards on the filled grid (splats act as occluders / bracketing cells).
  /// 0 = only the cell containing the point.
  double splat_radius_cells = 0.0;
  SplatMode splat_mode = SplatMode::kDisc;  ///< how that radius is filled
  /// See-through handling: a valid cell whose height lies more than this [m] below the
  /// robust front envelope of its neighbourhood is treated as a hole (a point seen through a
  /// gap in the front surface). The envelope test is two-sided: the cell is rejected when, on
  /// at least 2 of the 4 lines through it (row, column, both diagonals), BOTH directions reach
  /// a cell higher than z + see_through_depth_m within see_through_window_cells. A one-sided
  /// drop (a silhouette, the wall of a step) and a single outlier spike are kept; a gap is
  /// found when it is at most about see_through_window_cells wide in some direction; a genuine
  /// crease narrower than the window and deeper than the threshold is rejected too. ≤ 0
  /// disables.
  double see_through_depth_m = 0.0;
  int see_through_window_cells = 3;  ///< half-width of that neighbourhood [cells], 1 to 64
  /// Grids finer than the scan. 1: scan at the requested cells. K in [2, kMaxUpsampleFactor]:
  /// scan (binning, splats, see-through, all radii in coarse cells) on the grid of K× the cell
  /// size whose node (R, C) is requested node (K·R, K·C), then interpolate bilinearly onto the
  /// requested grid (flag kCellUpsampled; no data where a contributing coarse node has none).
  /// The result's bilinear surface equals the coarse grid's, so a grid finer than the points
  /// carries no invented detail: no flat splat terraces with one-cell risers, which hold a
  /// point proxy. 0 (auto): the smallest K at which at least kAutoUpsampleCoverage of the
  /// nodes hit by a point have their 4 neighbours hit too (reported as upsample_coverage).
  int upsample_factor = 1;
  /// Scan only this window of a given grid instead of a grid sized to the points' box (`grid`
  /// is then ignored). Node indices are computed as on the whole grid and shifted by the
  /// window's first row and column, so every node whose splats, see-through window and
  /// upsampling reach only points given here gets the value, flag and attributes the whole
  /// grid's reproject gives it, bit for bit, when the points come in the same order (a tile's
  /// interior, its halo wide enough: tiling.hpp), with disc or plane splats; interpolating
  /// splats sum heights relative to the window's first measured cell, so there only to float
  /// rounding. Points whose node lies outside the window are
  /// skipped (figure points_outside_window_or_non_finite). Needs upsample_factor ≥ 1 (the
  /// whole grid's; auto needs every point) and row0, col0 multiples of it; the result's
  /// geometry is the window's (origin at its first node).
  std::optional<GridWindow> window{};
};

/// Largest upsample factor (ReprojectOptions::upsample_factor).
inline constexpr int kMaxUpsampleFactor = 16;
/// Coverage the auto upsample factor asks for [-] (fraction of hit nodes with 4 hit neighbours).
inline constexpr double kAutoUpsampleCoverage = 0.9;

/// Per-cell classification masks, rows·cols each, row-major like the HeightField.
enum CellFlag : std::uint8_t {
  kCellEmpty = 0,        ///< no point fell (no data)
  kCellMeasured = 1,     ///< front-most point of the cell
  kCellSplatted = 2,     ///< written by a neighbouring point's splat
  kCellSeeThrough = 3,   ///< rejected as see-through (now no data)
  kCellFilled = 4,       ///< filled by hole filling
  kCellUpsampled = 5,    ///< interpolated between the nodes of a coarser scan (upsample_factor)
};

/// The result of the depth scan. `colour_rgb8` and `intensity` are filled only when the cloud
/// carries per-point rgb / intensity (else empty), with the layout of the scene's layers.
struct DepthGrid {
  HeightField depth;                ///< heights [m], NaN = no data
  CellBuffer<std::uint8_t> flags;   ///< CellFlag per cell (on the heap, or a scratch file's mapping: cell_buffer.hpp)
  /// Empty, or rows·cols·3 bytes, R G B per cell, row-major like `depth`. A cell takes the
  /// colour of the point that gave it its depth (see reproject); no-data cells are 0, 0, 0
  /// (the flag says no data).
  CellBuffer<std::uint8_t> colour_rgb8{};
  /// Empty, or the geometry of `depth`: the scanner intensity [-] of the point that gave the
  /// cell its depth (as stored by the scanner, see Cloud::intensity); NaN where depth is NaN.
  HeightField intensity{};

  bool has_colour() const { return !colour_rgb8.empty(); }
  bool has_intensity() const { return !intensity.values().empty(); }
  /// Every file-backed layer's pages given back to the kernel (CellBuffer::release_resident;
  /// nothing for layers on the heap): a tiled run's level 0 after a tile or a sweep.
  void release_resident() const {
    depth.values().release_resident();
    flags.release_resident();
    colour_rgb8.release_resident();
    intensity.values().release_resident();
  }
};

/// Reprojects grid-frame points (metres; z towards the viewer) onto a grid covering their x-y
/// bounding box; the front-most (largest) z per cell wins.
/// Geometry: with n_long_side = N the longer side of the finite points' x-y box holds N
/// samples, cell = extent / (N − 1); the other side holds round(extent / cell) + 1 samples,
/// centred on the box (likewise both sides for a given cell_size_m). Samples are node-centred
/// (GridGeometry) and each point goes to its nearest node (ties to the higher index).
/// Non-finite points are skipped (counted in figure points_non_finite).
/// Colour and intensity (only when the cloud has rgb / intensity; the depth and flags are the
/// same with or without them): a measured cell takes the attributes of its front-most point
/// (the largest z as float; among equal z the earliest point); a disc-splatted cell (filled or
/// occluding) those of the measured cell whose z it took (the front-most measured cell within
/// the disc; ties to the first in row-major order); an interpolated splat the same Gaussian-
/// weighted mean of the measured cells' attributes as its depth (colour rounded to 8 bit); an
/// upsampled node the same bilinear weights as its depth. Cells binned before see-through
/// rejection count as measured for the splats, as they do for the depth. No-data cells: colour
/// 0, 0, 0, intensity NaN. Extra memory while scanning: 8 bytes per cell.
/// @return depth grid plus flags; report figures: rows, cols, cell_size_mm, cells,
///         cells_valid, cells_measured, cells_splatted, cells_occluded_by_splat,
///         cells_see_through.
/// @throws hc::InputError if there is no finite point or rgb / intensity are not 3·N / N
///         long; hc::ResourceError for 2^32 − 1 points or more with rgb or intensity, or
///         more than 2^32 − 1 with plane splats;
///         hc::DegenerateInputError if the grid would have fewer than 2 samples along a side
///         (a single x-y position, all points on a line, e.g. a cloud edge-on to the view, or all points in one cell);
///         hc::ConfigError if n_long_side ≤ 1, neither or both of n_long_side and cell_size_m
///         are given, or an option is out of range; hc::ResourceError if rows·cols exceeds
///         max_cells (the message gives rows, cols, the cap and the bytes needed: 5 per cell,
///         +4·(1 + ⌊splat_radius_cells⌋) with disc splats, +12 with interpolating
///         splats, +8 with see-through handling).
/// Real-time: no. Threads: 2 for clouds of 2^18 points or more. Cost: two passes over the points
/// + O(rows·cols) (·r with disc splats of radius r; interpolating splats add O(r²) per empty
/// cell within r of the data, skipping the others with a summed-area table).
/// Source: depth-buffer scan of Sec. 1 of the paper; front-most rule as in an OpenGL z-buffer;
/// interpolating splats: normalised convolution (Knutsson & Westin, CVPR 1993), order 0.
StageResult<DepthGrid> reproject(const Cloud& points_m, const ReprojectOptions& options);

/// reproject(points_m, options) after points were removed, made again only about them: the
/// nodes within reach of a removed point's node (reproject_reach_cells, plus one node) are
/// scanned again in a window (ReprojectOptions::window) that holds every point whose node lies
/// within that reach of them, and copied into `before`'s grid; every other node's value depends
/// on none of the removed points. The result equals reproject(points_m, options) bit for bit
/// (depth, flags, colour, intensity) and so do its report's figures: cell counts are taken again
/// from the flags, and the scan's event counts (cells_splat_filled_empty, cells_occluded_by_splat,
/// cells_see_through, see_through_candidates) are corrected by each window's count with and
/// without the removed points (the two differ only on the nodes made again: the window reaches
/// one reach beyond them, and boxes that overlap are merged). A note says how many nodes were
/// made again.
/// It falls back to reproject(points_m, options) (and says why in a note) when the grid's box or
/// the auto upsample factor changes, with interpolating splats (which sum heights relative to a
/// window's first cell), for more than 4096 removed points, or when the windows would cover over
/// a third of the grid.
/// @param points_m  the cloud after the removal: the cloud `before` was made from without the
///        removed points, the rest in their order (as Cloud::keep_if leaves them).
/// @param removed   the removed points' coordinates and their columns in the cloud before
///        (RemovedPoints; remove_spike_points fills one).
/// @param before    reproject's result and report for the cloud before the removal, with the
///        same options (a window's, when options.window is set).
/// @throws what reproject throws; std::invalid_argument when `removed` is malformed (not 3
///         coordinates per point, columns not increasing or beyond the cloud before) or
///         `before` does not have the window's size.
/// Real-time: no. Cost: three passes over the points (their box; the coverage with upsample
/// auto; their windows) + O(removed points × (2·reach + 3)² nodes) + O(rows·cols) to count the
/// flags, against reproject's two passes and its O(rows·cols) scan. Threads: the gathering as
/// reproject; the windows are made again on two threads, taking them in turn (each writes only
/// its own nodes; the results equal one thread's; a window of 2^18 points or more is gridded on
/// two threads of its own, as reproject grids such a cloud).
/// Falls back to the whole grid for 2^32 − 1 points or more (windows list points by 32-bit
/// column).
/// Precondition not checked: `removed` holds the coordinates the points had when `before` was
/// made. The nodes made again are found from them, and the windows' scan before the removal is
/// made from them, so with other coordinates the result is wrong: the event counts always, and
/// the grid too unless each point's x and y stay in the same coarse node (only its z changed).
/// (The known defect documented on 2026-11-24 was this: the test had raised a point after
/// making `before`.)
/// Source: this project (the locality the tiled run relies on, tiling.hpp).
StageResult<DepthGrid> reproject_after_removal(const Cloud& points_m, const RemovedPoints& removed,
                                               StageResult<DepthGrid> before, const ReprojectOptions& options);

/// The geometry reproject gives points whose finite points (`finite` of them, > 0) span the x-y
/// box [x_min, x_max] × [y_min, y_max] [m] (the tiled run, whose points are never all in memory).
/// @throws as reproject for the options and a degenerate or too large grid.
GridGeometry grid_geometry_for_box(double x_min, double x_max, double y_min, double y_max, std::size_t finite,
                                   const ReprojectOptions& options);

/// upsample_factor 0 (auto) over points given in chunks: add() every point once, then factor()
/// is what reproject would choose for them all on grid g (the same node coverage per factor, the
/// same stopping rule). It tracks the factors k_first to k_last only, so that a streamed run can
/// decide the common factors (1 and 2) in one pass and read the points again for the rest only
/// when those fail (each factor's coverage comes from its own nodes, so the split changes
/// nothing). Memory: one bit per node of each tracked factor's grid (g's nodes / K²; 1 MB for a
/// 4 096 × 2 049 grid at factor 1), as reproject's own coverage keeps it.
class UpsampleCoverage {
 public:
  /// @throws std::invalid_argument unless 1 ≤ k_first ≤ k_last ≤ kMaxUpsampleFactor.
  explicit UpsampleCoverage(const GridGeometry& g, int k_first = 1, int k_last = kMaxUpsampleFactor);
  /// Marks the nodes of n points (3·n doubles, x y z, grid frame [m]); non-finite ones are skipped.
  void add(const double* xyz, std::size_t n);
  /// The factor K, and in *coverage the coverage reached at it; 0 when none of the tracked
  /// factors is chosen and larger ones remain (k_last < kMaxUpsampleFactor and factor
  /// k_last + 1's grid has at least 3 nodes along each side): track those next.
  /// The factors below k_first must have been rejected already (their coverage below
  /// kAutoUpsampleCoverage).
  int factor(double* coverage) const;
  /// Factor k's counts behind its coverage: {hit nodes off the border, those of them with their 4
  /// neighbours hit} (coverage = second / first); none for a factor not tracked or whose grid
  /// is too small. The tiled run bounds with them how far removing points can move the
  /// coverage (tiled_run.cpp, factor_may_change).
  std::optional<std::array<std::uint64_t, 2>> counts(int k) const;
  /// The points given to add() so far (non-finite ones too).
  std::uint64_t points() const { return points_; }

 private:
  GridGeometry g_;
  int k_first_ = 1, k_last_ = kMaxUpsampleFactor;
  bool next_too_small_ = false;  // factor k_last + 1's grid has fewer than 3 nodes along a side
  std::vector<GridGeometry> coarse_;
  std::vector<std::vector<std::uint64_t>> hit_;  // per tracked factor, a bit per node (row-major)
  std::uint64_t points_ = 0;
};

/// How far [fine nodes] a node's value in reproject can depend on points, for a window's halo:
/// a window's nodes this far or farther inside its edge (or on the whole grid's edge) equal the
/// whole grid's, value, flag and attributes, when the window got every point whose node (the
/// nearest, as reproject bins it) lies inside it. With r = splat_radius_cells, w =
/// see_through_window_cells (0 when see-through handling is off) and K = upsample_factor:
///  - the splat's reach S [scan nodes, Chebyshev]: kPlane ⌊r + 0.7072⌋ (its front reference is
///    the front-most binned node within r + 0.7072, the disc splat_discs takes; the points the
///    plane gathers, within r of the node, lie on nodes within ⌊r + ½⌋, never farther, up to a
///    rounding step of the two index formulas far below the 0.2 node between them; attributes
///    read the winners of that disc), kDisc ⌊r⌋ (the disc dilation of the binned
///    grid), kInterpolate ⌊r⌋, 2⌊r⌋ with see-through handling (a tap's own emptying then reads
///    its front disc); 0 without splats;
///  - the see-through test reads the splatted grid w nodes each way (a box, then rays);
///  - K = 1: S + w. K ≥ 2: K·(S + w + 2), the scan running on the coarse grid (a coarse node's
///    points lie on fine nodes within K of it; the bilinear upsampling reads the next coarse node).
/// The shipped plane splats (r = 1.2, w = 3) reach 4 nodes at K = 1. Until 2026-11-28 (fifty-first
/// session) this was K·(2⌈r⌉ + 3 + w) + K, 11 there: it added the reference disc to the
/// gathering radius (the disc lies about the node, not about the gathered points) and counted
/// the coarse grid's binning and upsampling at K = 1 too. Test: ReprojectWindow (tests/pipeline/
/// reproject_window_test.cpp: each mode, see-through on and off, K = 1 and 2, windows at every
/// offset of a cloud with back surfaces and gaps; at K = 1 without see-through one node less
/// finds nodes that differ). kInterpolate's windows equal the whole grid's to float rounding
/// only (its sums are taken relative to the first measured node's height, which a window finds
/// elsewhere).
/// @throws hc::ConfigError if K < 1.
int reproject_reach_cells(const ReprojectOptions& options, int upsample_factor);

/// Fills holes (connected no-data regions, 4-connectivity, empty or see-through) of at most
/// max_hole_cells cells that do not touch the grid border, by normalised convolution (Gaussian
/// σ = 1 cell over a 7 × 7 window, Σw·z / Σw over the known cells, evaluated at hole cells
/// only), from the rim inwards until the hole is full; larger holes and the background stay no
/// data. Filled cells get kCellFilled in `grid.flags`, and colour / intensity (when the grid
/// has them) by the same normalised convolution over the same known cells (colour rounded to
/// 8 bit; a known cell with NaN intensity makes the fill NaN). A fill is a weighted mean, so on a slope
/// it is off by up to slope × 2 cells, and across a depth step it invents an intermediate
/// surface (the cross-check's cell-to-point distance shows it).
/// @param max_hole_cells  0 disables filling.
/// @param max_rim_step_m  a hole whose rim (the valid cells 8-adjacent to it) spreads about the
///        least-squares plane through it (max − min of the residuals) by more than this [m] is
///        an occlusion gap between a near and a far surface, not a hole in one surface: it stays
///        no data (figure holes_at_depth_steps). A slope fits the plane (spread 0) and is filled;
///        a depth step of height H gives a spread of about 0.6–0.9·H (0.63·H for a 2 × 2 hole
///        centred on it), so steps above about 1.1–1.6 × this are caught. 0 = no limit. Filling such a gap makes cells between the two surfaces
///        that no scan point supports (the E57 pump: a 4-cell gap filled 1.4 m in front of the
///        wall behind it).
/// @throws hc::ConfigError if max_hole_cells < 0 or max_rim_step_m < 0 or not finite;
///         hc::InputError if flags, colour or intensity and depth disagree in size.
///         Real-time: no. Cost: O(rows·cols) labelling + O(filled cells · 49 · sweeps).
StageResult<DepthGrid> fill_holes(DepthGrid grid, int max_hole_cells, double max_rim_step_m = 0.0);

}  // namespace hc::pipeline
