#pragma once
/// @file honest_check.hpp
/// The honest cross-check (issue "A surface you can trust", part 2): the grid against the
/// input AS READ (before the filters), a spike and pit test on the grid itself, and the run's
/// verdict (pass / warn / fail with reasons) from configured limits.
///
/// cross_check() (cross_check.hpp) compares the grid with the points that survived the filters;
/// a filter that removed real surface, or kept an outlier that became a spike, passes it. The
/// functions here close that gap:
///  - check_input():  every point as read is put in exactly one class (removed by the filters,
///    on the surface, off the surface, hidden behind it, on a no-data cell, outside the grid);
///    "surface lost" = removed points that are genuine surface samples (not isolated) and are
///    not represented by the grid; "spikes kept" = valid cells whose only support is isolated
///    points; "far" = points far from the grid's box.
///  - find_grid_spikes(): each valid cell against the median and MAD of its window; small
///    disconnected groups of valid cells (islands).
///  - decide_verdict(): the limits of cross_check.* (docs/config.md) applied to these figures
///    and to the filter stages' reports.

#include "hc/common/height_field.hpp"
#include "hc/pipeline/cloud.hpp"
#include "hc/pipeline/reproject.hpp"

#include <Eigen/Core>

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace hc::pipeline {

/// Limits of the honest cross-check and of the verdict (config keys cross_check.*, see
/// docs/config.md; the defaults let the shipped bunny and Buddha configs pass).
struct HonestCheckOptions {
  double tolerance_m = 0.0005;     ///< a point within this of the surface is on it [m]
  double hidden_band_m = 0.002;    ///< a point more than this below the surface is hidden [m]
  /// Point test: a point is isolated when fewer than isolation_min_neighbours other input points
  /// lie within isolation_radius_spacings × (median nearest-neighbour spacing of the input).
  double isolation_radius_spacings = 10.0;
  int isolation_min_neighbours = 3;
  /// Grid spike/pit test: window (2·h+1)² with h = spike_window_cells / 2 [cells, odd ≥ 3]; a
  /// cell is a spike (pit) when it lies more than spike_min_height_m AND spike_mad_factor ×
  /// 1.4826·MAD above (below) the window's median (the cell itself excluded). Pits are only
  /// sought where the window is full (no no-data cell, not at the grid's border): at a
  /// silhouette the surface legitimately falls away from the viewer.
  /// A flagged cell (deviation d from its window's median) is a spike or pit only if it belongs
  /// to a group of at most spike_max_cells cells joined by 8-neighbour steps of at most
  /// max(spike_min_height_m, |d|/2) (a larger group is a surface: the thin visible strip of a
  /// far surface along an occlusion edge, a steep slope at a silhouette) [cells].
  int spike_window_cells = 5;
  double spike_min_height_m = 0.002;
  double spike_mad_factor = 6.0;
  int spike_max_cells = 25;
  /// cross_check.confirm_by_splat_footprint (default off): for sparse scans of about one point
  /// per cell (airborne lidar), where a cell's node lies far from the point whose splat disc
  /// made it. When on, run sets confirm_footprint_m for grids splatted from points in disc mode
  /// (not meshes, not splat_mode interpolate). Off for object scans: it would confirm a stray
  /// point that is not isolated by the whole of its disc.
  bool confirm_by_splat_footprint = false;
  /// Horizontal reach of one point in the grid [m] (set by run, not a config key):
  /// (grid.splat_radius_cells + √2/2) × cell size, the splat radius plus the half cell diagonal
  /// between a point and its own cell's node. check_input then also confirms a flagged cell that
  /// is measured or splatted (cell_flags) by a kept, not isolated point within this of its node
  /// in x-y and within max(tolerance_m, spike_min_height_m) of its height: the point whose disc
  /// made the cell. Filled and upsampled cells are confirmed only in 3-D. 0 = off.
  double confirm_footprint_m = 0.0;
  /// The scan's spacing when known [m] (set by run, not a config key): the robust outlier
  /// test's sample's (RobustScale::spacing_m), so that a tiled run and the in-core run judge
  /// with one number. 0: check_input and remove_isolated_points estimate it from their points
  /// (median_spacing).
  double spacing_m = 0.0;
  /// The float frame's centre for remove_isolated_points [m, the cloud's frame] (set by run,
  /// not a config key): the robust test's (RobustScale::centre_m), so that a tiled run's
  /// windows and the in-core run round every distance of the filter's searches alike. Empty (the
  /// default): the filter centres on the median of its own points. Since 2026-11-29 (fifty-second
  /// session; before, each window rounded about its own median).
  std::optional<std::array<double, 3>> frame_centre_m;
  /// Connected groups of valid cells (8-neighbours) of at most this many cells, apart from the
  /// largest group, are islands [cells].
  int island_max_cells = 16;
  /// Whether the grid's largest group is spared as an island whatever its size (set by run, not
  /// a config key): true for a whole grid. A tiled run's window sets it false: the whole grid's
  /// largest group is larger than island_max_cells, so every group of at most island_max_cells
  /// cells is an island there, as in core, even where it is the window's largest. The run warns
  /// when no window showed such a group (WindowIslands::largest_exact_group): a grid of specks
  /// only, where the in-core run spares one speck no window can name. Since 2026-11-29
  /// (fifty-third session; before, a window beyond a silhouette holding only stray groups spared
  /// its largest, which the in-core run judged).
  bool spare_largest_group = true;
  // Verdict limits (decide_verdict).
  int max_spike_cells = 0;                  ///< unconfirmed spike + pit cells allowed before "fail"
  /// ... or this fraction of the tested cells, whichever allows more. The merged Buddha at
  /// N = 800 had 29 unconfirmed spike and pit cells (1.5e-4), every one a hole-filled cell
  /// bridging an occlusion gap in a fold; with grid.hole_fill_max_step_m (as its config) none.
  double max_spike_fraction = 5e-4;
  /// The fraction applies only while no spike among the worst listed cells (GridSpikes::worst)
  /// stands above its window by more than this [m]; pits (folds) do not cancel it.
  double spike_allowance_max_m = 0.03;
  int max_spikes_kept_cells = 0;            ///< cells supported only by isolated points ("fail")
  int max_island_cells = 2;                 ///< island cells before "warn"
  double max_removed_fraction = 0.01;       ///< of the input, removed by the filters ("warn")
  double max_surface_lost_fraction = 0.005; ///< of the input, surface lost ("warn")
  double min_visible_on_surface_fraction = 0.7;  ///< on / (on + off + no-data) ("warn")
  double min_supported_fraction = 0.95;     ///< cross_check's supported fraction ("warn")
  double max_filter_threshold_spacings = 20.0;  ///< outlier threshold / input spacing ("warn")
};

/// The input as read against the grid. Counts are points; every point as read is in exactly
/// one of removed, on_surface, off_surface, hidden, no_data, outside (they sum to `points`).
struct InputCheck {
  std::size_t points = 0;       ///< as read (after units, recentring and view transform)
  std::size_t removed = 0;      ///< removed by the filters (non-finite, crop, voxel, outliers)
  std::size_t on_surface = 0;   ///< kept, over a valid cell, |z − f(x, y)| ≤ tolerance
  std::size_t off_surface = 0;  ///< kept, over a valid cell, farther, but not hidden
  std::size_t hidden = 0;       ///< kept, more than hidden_band below the surface
  std::size_t no_data = 0;      ///< kept, over a cell with a no-data corner
  std::size_t outside = 0;      ///< kept, outside the grid's x-y extent
  /// Points (removed or kept) farther from the box of the grid's valid samples than that box's
  /// diagonal; far_max_distance_m is the farthest one's distance to the box [m].
  std::size_t far = 0;
  double far_max_distance_m = 0.0;
  /// Whether removal was judged by exact coordinates (false when the voxel filter replaced
  /// points by centroids: a point then counts as removed when no kept point lies within one
  /// voxel diagonal).
  bool removal_exact = true;
  double spacing_m = 0.0;           ///< the scan's spacing the point test used [m] (HonestCheckOptions::spacing_m, or the estimate)
  double isolation_radius_m = 0.0;  ///< radius of the point test [m]
  std::size_t isolated = 0;         ///< points the point test flags
  /// Points the point test searched about, and points its voxel hash held: every finite point
  /// for both, unless InputCheckScope::near spared the test (then the points not known to have
  /// neighbours, and the points in the voxels about them). Work counts, not judged.
  std::size_t isolation_tested = 0;
  std::size_t isolation_hashed = 0;
  /// Removed points that are not isolated, not far, and lie over no-data cells or outside the
  /// grid more than the tolerance (x-y) from its nearest valid sample: surface the grid lost.
  std::size_t surface_lost = 0;
  double surface_lost_max_gap_m = 0.0;  ///< largest x-y gap of a lost point to the grid [m]
  /// Removed points, not isolated, not far, over valid cells and more than the tolerance in
  /// front of the surface: either scanner artefacts at depth edges (mixed pixels, which the
  /// filters should remove) or a thin front surface lost; reported, not judged.
  std::size_t removed_in_front = 0;
  /// Valid cells whose every input point within the tolerance is isolated.
  std::size_t spikes_kept = 0;
  std::vector<std::array<int, 2>> spikes_kept_cells;  ///< (row, col), at most 100
  double seconds = 0.0;

  double fraction(std::size_t n) const { return points ? static_cast<double>(n) / static_cast<double>(points) : 0.0; }
  /// Adds the point classes and counts of a disjoint part (its points, removed, classes, far,
  /// surface lost, removed in front; the maxima by max). Spacing, radius, isolated, spikes kept
  /// and seconds are the caller's.
  void add_classes(const InputCheck& part) {
    points += part.points;
    removed += part.removed;
    on_surface += part.on_surface;
    off_surface += part.off_surface;
    hidden += part.hidden;
    no_data += part.no_data;
    outside += part.outside;
    far += part.far;
    far_max_distance_m = std::max(far_max_distance_m, part.far_max_distance_m);
    surface_lost += part.surface_lost;
    surface_lost_max_gap_m = std::max(surface_lost_max_gap_m, part.surface_lost_max_gap_m);
    removed_in_front += part.removed_in_front;
  }
};

/// One flagged grid cell: where, and how far from its window's median [m] (+ spike, − pit).
struct GridAnomaly {
  int row = 0, col = 0;
  float height_m = 0.0f;      ///< the cell's z [m]
  float deviation_m = 0.0f;   ///< z − median of the window [m]
};

/// Result of find_grid_spikes.
struct GridSpikes {
  std::size_t spikes = 0, pits = 0;   ///< cells above / below their window
  std::size_t tested = 0;             ///< valid cells with at least 3 valid window neighbours
  std::size_t islands = 0;            ///< groups of at most island_max_cells cells
  std::size_t island_cells = 0;       ///< cells in those groups
  std::vector<GridAnomaly> worst;     ///< the largest |deviation| first, at most 10
  std::vector<std::array<int, 2>> marked;  ///< (row, col) of spike, pit and island cells, at most 1000
  std::vector<std::array<int, 2>> flagged; ///< (row, col) of every spike and pit cell
  /// Spike and pit cells the scan confirms (check_input: a point that is not isolated within
  /// max(tolerance, spike_min_height_m), or, with confirm_footprint_m, a kept one within the
  /// footprint in x-y at the cell's height to that distance): relief such as deep folds or tree
  /// tops, not an error. The verdict counts the others.
  std::size_t confirmed = 0;
};

/// Grid vs the input as read. `as_read_m` (3 × N, grid frame, metres) is the cloud after units,
/// recentring and view transform, before any filter (non-finite columns count as removed and are
/// not classified: the run sets the points outside filters.crop to NaN, as a tiled run drops
/// them before its spill); `kept_m` the points the grid was made from
/// (the same frame); `grid` the final depth (metres, NaN = no data), `voxel_leaf_m` the voxel
/// filter's leaf (0 = off; see InputCheck::removal_exact).
/// Method: the point test counts, for every input point, the other points within the isolation
/// radius (a hash of cubic voxels of that edge, exact distances, stopping at the minimum); the
/// spacing is options.spacing_m when > 0 (the run's: the robust test's sample's), else the
/// scope's, else the median nearest-neighbour distance of up to 4096 evenly strided points.
/// Removal is an exact match of coordinates (a hash multiset of the kept points). The gap of a
/// lost point over no data or outside is its x-y distance to the nearest valid sample (OpenCV
/// distance transform of the valid mask, plus the distance to the grid's box).
/// @throws hc::ConfigError for options out of range (names the cross_check.* key);
///         hc::InputError if the grid has no valid cell.
/// Real-time: no. Threads: 2 (point test and classes). Cost: O(N) hashing plus O(N)
/// early-stopped neighbour counts, plus for each flagged spike cell a search of at most
/// (2·16 + 1)² × (2·z + 1) hash voxels when confirm_footprint_m is set, z = the 3-D reach in
/// voxels (at least 1; a footprint beyond 16 voxels is searched only that far: stricter, never
/// laxer). The 3-D confirmation counts any not isolated input point, kept or removed (a fold's
/// point the outlier filter dropped still shows the fold is there); the footprint one only kept
/// points (a removed point made no cell).
/// With `spikes` (find_grid_spikes of the same grid), also counts its confirmed cells;
/// `cell_flags` (rows·cols CellFlag values of reproject.hpp, or null) says which cells the
/// footprint may confirm (measured and splatted ones; none without flags).
struct InputCheckScope;
InputCheck check_input(const Eigen::Matrix3Xd& as_read_m, const Cloud& kept_m, const HeightField& grid,
                       const HonestCheckOptions& options, double voxel_leaf_m = 0.0,
                       GridSpikes* spikes = nullptr, const CellBuffer<std::uint8_t>* cell_flags = nullptr,
                       const InputCheckScope* scope = nullptr);

/// check_input on one tile of a tiled run (tiling.hpp): as_read_m and kept_m are the points of
/// the tile's window (its interior and halo, as spilled), `grid` the whole grid's cells over that
/// window, and the counts cover only what the tile owns, so that the tiles' InputChecks add up
/// to the whole run's (points, classes, isolated, surface lost, removed in front, spikes kept;
/// the maxima by max; spikes->confirmed by sum).
///  - the point test, the spike searches and the confirmations see every window point (the halo
///    is wider than their radii: docs/scale.md);
///  - the scan's spacing and the box of the valid samples are the whole run's, given here;
///  - a lost point's gap is measured to the nearest valid sample within the window (a gap that
///    reaches beyond it is at least the halo, far above the tolerance, so the decision is the
///    whole grid's; surface_lost_max_gap_m may then exceed the whole grid's);
///  - a window without a valid cell is not an error (its points are on no data or outside).
struct InputCheckScope {
  /// Per point of as_read_m: 1 = the tile's (its grid node lies in the tile's interior), 0 = a
  /// halo copy, a neighbour only. Size: as_read_m's columns.
  const std::vector<std::uint8_t>* owned = nullptr;
  /// Optional, per point of as_read_m: 1 = removed by the filters, 0 = kept (a tiled run knows
  /// this from its kept-point mask). When given, kept_m is not read (it may be empty) and not
  /// matched to as_read_m by coordinates: the figures are the same (they depend on coordinates
  /// only), without a copy of the kept points. Size: as_read_m's columns.
  const std::vector<std::uint8_t>* removed = nullptr;
  /// Optional, per point of as_read_m: 1 = the tile's filters found at least
  /// options.isolation_min_neighbours other points of as_read_m within
  /// isolated_filter_radius_m(options, spacing_m) of it (distances between float32 coordinates
  /// in a frame centred inside the box of as_read_m's points: remove_isolated_points and
  /// remove_robust_outliers recentre on a median of a subset of them), so the point test cannot
  /// flag it. Its test is
  /// then skipped and the voxel hash holds only the voxels about the points tested: the flags
  /// and every figure stay those of the full test. Used only when that radius is at most 0.9 ×
  /// the test's and every point lies within 10^4 test radii of the check's local frame's origin
  /// (the float rounding of both frames, at most about 6e-7 of that distance, then stays far
  /// inside the 10 % margin); otherwise ignored. A flag set on a point that has not the
  /// neighbours is the caller's error: the test would not look at it. Size: as_read_m's columns.
  const std::vector<std::uint8_t>* near = nullptr;
  /// The interior's cells in `grid`: rows [r0, r1), cols [c0, c1). Spikes kept are counted there.
  std::array<int, 4> cells{};
  double spacing_m = 0.0;  ///< the scan's median nearest-neighbour spacing [m], > 0
  /// Optional: the whole grid, of which `grid` is a window (same cell size, its origin on a
  /// node of this one). When given, each owned point's class (on, off, hidden, no data,
  /// outside) and residual come from this grid's bilinear surface and x-y extent, so that they
  /// are the whole run's bit for bit: `grid`'s own origin, the whole grid's plus a number of
  /// cells, rounds otherwise, and a point on the grid's last row or column (the one that set
  /// the box) could fall outside a window's extent by that rounding (found by
  /// tests/pipeline/tiled_differential_test.cpp, 2026-11-30). The other tests read `grid`.
  const HeightField* whole = nullptr;
  Eigen::Vector3d valid_lo = Eigen::Vector3d::Zero();  ///< box of the whole grid's valid samples [m]
  Eigen::Vector3d valid_hi = Eigen::Vector3d::Zero();
};

/// Median nearest-neighbour distance [m] of up to 4096 evenly strided finite points of `xyz_m`
/// (3 × N, metres; exact distances to the points in the 3 × 3 × 3 voxels about each sample,
/// collected in one pass over all points). The voxel edge: a pilot pass at start_edge_m counts
/// the points in each sample's voxel and starts at about twice the spacing that suggests (at
/// most start_edge_m); it grows ×4 until the median is within it, up to start_edge_m · 4⁷; the
/// result does not depend on the edge. When the median is not within start_edge_m · 4⁷ either,
/// returns start_edge_m · 4⁸ (a lower bound). The spacing check_input reports; a tiled run gives
/// each tile's and takes their median weighted by points. 0 for fewer than 2 finite points.
/// @throws hc::ConfigError when start_edge_m is not finite and > 0.
double median_point_spacing(const Eigen::Matrix3Xd& xyz_m, double start_edge_m);

/// Spike, pit and island test of a grid (metres, NaN = no data); see HonestCheckOptions.
/// Robust fit: median of the window's valid cells (the cell excluded), scale 1.4826·MAD (the
/// normal-consistent median absolute deviation; Rousseeuw & Croux 1993). Cells with fewer than
/// 3 valid window neighbours are not tested (the island test covers them). Islands: OpenCV
/// connected components (8-connectivity) of the valid mask.
/// @throws hc::ConfigError for a window < 3 or even, or non-positive limits.
/// Real-time: no. Threads: 2 (halves of the rows). Cost: O(cells · window²); the median and MAD
/// only where a neighbour differs from the cell by more than spike_min_height_m. Memory: a
/// file-backed grid (a tiled run's level 0, CellBuffer) is given back as each half passes its
/// rows, so a band of rows is resident, not the grid.
GridSpikes find_grid_spikes(const HeightField& grid, const HonestCheckOptions& options);

/// Removes the points the verdict calls isolated (check_input's point test, on this cloud): a
/// finite point with fewer than options.isolation_min_neighbours other points within
/// 0.9 × options.isolation_radius_spacings × the median nearest-neighbour spacing (10 % inside
/// the check's radius, whose sampled spacing estimate differs by about 1 %) (of up to 4096
/// evenly strided points, exact). Run by build_scene after the robust outlier test
/// (filters.outliers.method: robust), so that the filter removes what the verdict's
/// "spikes kept" would otherwise flag (the clean raw bunny keeps 3 such stray points).
/// Frame and units: the cloud's (grid frame, metres). Report figures: spacing_mm,
/// isolation_radius_mm, removed_isolated. Cost O(N) (a voxel hash of the radius, counting
/// stops at the minimum). Non-finite points are kept (the non_finite stage drops them).
/// The spacing is options.spacing_m when > 0 instead of this cloud's own estimate: build_scene
/// passes the robust test's (RobustScale::spacing_m), measured on the whole scan before that
/// test, so that the tiled run's tiles, which each hold a window of the scan, use the very same
/// number. Its searches run in float32 about options.frame_centre_m when given (build_scene and
/// the tiled run's tiles: the robust test's RobustScale::centre_m, one frame for every window),
/// else about the median of up to 65 536 evenly strided points.
/// @param removed_points when given, set to the removed points (coordinates and columns in
///        `cloud`): the tiled run checks that none lay within the radius of its window's edge.
/// @param known_near when given (one per column): 1 = at least isolation_min_neighbours other
///        points of `cloud` are known to lie within 0.99 × the filter's radius (distances
///        between float32 coordinates in a frame whose coordinates stay within 10^4 such radii:
///        the robust test's, RobustVerdicts::near), so the point is kept without its search, and the voxel hash
///        holds only the voxels about the points searched: the result is the full test's.
///        Used only when this filter's own recentred coordinates stay within 10^4 radii too
///        (the float rounding of both frames then stays under 0.5 % of the radius); otherwise
///        ignored. Report figure points_tested: the points searched.
/// @throws hc::ConfigError for options outside their ranges (check_honest_options; a
///         spacing_m that is negative or not finite among them); std::invalid_argument when
///         known_near has not one flag per column.
/// Source: the radius outlier test (Rusu 2009, PCL's RadiusOutlierRemoval), radius from the
/// scan's own spacing.
StageResult<Cloud> remove_isolated_points(Cloud cloud, const HonestCheckOptions& options,
                                          RemovedPoints* removed_points = nullptr,
                                          const std::vector<std::uint8_t>* known_near = nullptr);

/// remove_isolated_points' search radius [m] at the scan's spacing `spacing_m` [m]: 0.9 ×
/// options.isolation_radius_spacings × spacing_m (10 % inside check_input's verdict radius, so
/// that a spacing estimated a few per cent apart never removes a point the check would keep),
/// at least 1e-9 m. The tiled run sizes its halo with it. No validation (the callers check the
/// options). Source: this project.
double isolated_filter_radius_m(const HonestCheckOptions& options, double spacing_m);

/// Removes the stray points that make the grid's spikes and islands (a grid-level second look
/// after the robust outlier test, which judges points by their neighbours only: clutter a few
/// millimetres in front of a surface has that surface among its neighbours and passes). On
/// `grid` (heights [m], NaN = no data, made from `cloud` in the same frame, metres):
///  - spike cells: cells more than h = spike_min_height_m above the least-squares plane, at their
///    node, through the other valid cells of their spike_window_cells window (at least 3 not on
///    one line; in a full window, their mean). Not find_grid_spikes' median and MAD test: on a
///    steep flank the window's spread hides a spike from that test, not from the plane. A cell
///    between h/2 and h above that plane is judged against the plane fitted again without the
///    window's cells more than h/2 above the first (a stray's splat raises its neighbours and
///    they lift the plane);
///  - lone peaks: cells more than h/2 above their (trimmed) plane and more than h/2 above each
///    valid 8-neighbour (a stray whose splat did not spread; the plane's curvature error can
///    hide a stray just over h);
///  - island cells: island_mask's groups of at most island_max_cells cells apart from the
///    largest (as find_grid_spikes; the largest too when options.spare_largest_group is off);
///  - rim cells: the other valid cells, islands excepted, with a no-data cell among their 8
///    neighbours inside the grid (a stray just beyond a silhouette or a hole's edge extends the
///    surface there without standing above it; the grid's border is not a rim, so a tiled
///    run's window judges what the whole grid does);
///  - candidates: points binned (nearest node) within ⌈reach_cells⌉ cells (Chebyshev) of a spike
///    cell that stand more than h above its plane (a lone peak's: more than h/2), every point
///    within that reach of an island cell, and every point within ⌈reach_cells − 1⌉ cells of a
///    rim cell (a stray's disc reaches a cell that borders no data that near);
///  - a candidate is removed when fewer than options.isolation_min_neighbours other points lie
///    within ρ of it in 3-D, ρ = clamp(0.5 × its height above the plane, ρ_lo, ρ_hi) for a spike
///    and ρ_hi for an island, ρ_rim = max(4 scan cells, 4 × spacing_m) for a rim (a scan cell
///    is upsample_factor grid cells: the rim's test does not tighten on an upsampled grid; a
///    spike's or an island's radius wins where targets overlap), ρ_lo = max(2 cells, 2 × spacing_m), ρ_hi = max(4 cells,
///    4 × spacing_m) (spacing_m: the scan's median nearest-neighbour spacing, 0 if unknown; a
///    scan sparser than the grid keeps its points). Relief that stands h above its
///    surroundings is joined to them by a sampled surface, so a sphere of radius h/2 about its
///    top holds samples; a stray point h in front of the surface has none within h/2.
/// Pits are not touched (missing data, not added data). reach_cells is the splat radius × the
/// upsample factor (the cells a point's disc writes); upsample_factor ≥ 1 is that factor. Report stage "despike", figures:
/// spike_cells (lone peaks included), rim_cells, island_cells, candidates, removed_spike_points. The caller grids again when
/// points were removed (reproject_after_removal, given `removed`: the removed points' coordinates and
/// columns, when not null). Skipped (with a note) for 2^32 − 1 points or cells or more. Cost: O(cells)
/// (a summed-area table of the valid cells, the heights' column sums) plus O(N) binning plus, per candidate, the points within ρ_hi (2·⌈ρ_hi /
/// cell⌉ + 1)² cells.
/// @param window   when given, `grid` is this window of window->grid (rows and cols equal), and
///                 the points are binned by the whole grid's nodes (node = ⌊p · (1 / cell) +
///                 (0.5 − origin / cell)⌋ per axis, reproject's rule, less the window's first row
///                 and column), so that a tiled run's window bins each point where the whole grid
///                 does: a point on a node boundary rounds alike (the window's own origin, the
///                 whole grid's plus a number of cells, rounds otherwise; TiledDifferential seed
///                 308, sixty-fourth session, 2026-11-30). Without it, the same rule on `grid`.
/// @throws hc::ConfigError for options outside their ranges (check_honest_options);
///         std::invalid_argument if reach_cells or spacing_m is negative or not finite,
///         upsample_factor is below 1 or not finite, or `window` is not a window of its grid
///         of `grid`'s rows and cols.
/// Source: this project (the radius test of Rusu 2009 applied at the spike's own scale).
StageResult<Cloud> remove_spike_points(Cloud cloud, const HeightField& grid, const HonestCheckOptions& options,
                                       double reach_cells, double spacing_m, double upsample_factor = 1.0,
                                       RemovedPoints* removed = nullptr, const GridWindow* window = nullptr);

/// The widest of remove_spike_points' neighbour searches [m], ρ_rim = max(4 × upsample_factor ×
/// cell_m, 4 × spacing_m) (it bounds ρ_lo and ρ_hi), for a grid of cell_m [m] cells upsampled by
/// upsample_factor (≥ 1) over a scan of spacing spacing_m [m] (0 if unknown): the tiled run sizes
/// its halo with it and checks removed points against it. No validation. Source: this project.
double despike_search_radius_m(double cell_m, double upsample_factor, double spacing_m);

/// How far [grid cells, Chebyshev] remove_spike_points reads its grid about a point's node:
/// ⌈reach_cells⌉ to a spike cell the point is a candidate of, plus spike_window_cells / 2 (the
/// cell's plane window); a rim cell and its 8 neighbours lie nearer. Island labels (groups of
/// up to island_max_cells) can reach farther and are not counted: the tiled run checks each
/// window's with window_islands, or holds them with scale.island_halo. The tiled run sizes the
/// region whose points need the whole scan's verdicts with it (grid_share_cells). reach_cells as
/// remove_spike_points takes it (≥ 0). No validation. Source: this project.
int despike_grid_reach_cells(const HonestCheckOptions& options, double reach_cells);

/// What a window of a grid decides of the island test (find_grid_spikes' and
/// remove_spike_points' islands: groups of at most island_max_cells valid cells, 8-neighbours).
struct WindowIslands {
  /// Groups of the exact region (valid cells inside it, 8-connected) of at most max_cells cells
  /// that hold a cell of the needed region and touch an open side of the exact region: the
  /// whole grid's group may run on past that side, so the window cannot say whether they are
  /// islands.
  std::size_t undecided_groups = 0;
  std::size_t undecided_cells = 0;  ///< the cells of those groups
  std::array<int, 2> first_undecided{-1, -1};  ///< (row, col) in the window of one, or (-1, -1)
  /// Cells of the exact region's largest group: the whole grid holds a group at least this
  /// large (the exact region's groups are parts of the whole grid's).
  std::size_t largest_exact_group = 0;
};

/// Which island decisions a window of a grid can make as the whole grid would. `window`: the
/// window's grid (heights [m], NaN = no data). `exact`: the window's region {row0, row1, col0,
/// col1} (half-open, window cells) whose validity equals the whole grid's (a tiled run: the
/// cells within halo − filter share − R nodes of the interior, R the grid stages' reach). `needed`: the
/// region (inside `exact`) whose island labels the caller reads. `open`: per side of `exact`
/// {top, bottom, left, right}, whether whole-grid cells lie beyond it (false at the whole grid's
/// edge). A group of `exact`'s valid cells (8-connected) that touches no open side is a whole
/// group of the whole grid; one with more than max_cells cells is part of a group that is no
/// island; the rest, where they reach `needed`, are undecided. Cost: O(cells of `exact`).
/// @throws std::invalid_argument when `needed` is not inside `exact` or `exact` not inside the
///         window, or max_cells < 1.
/// Source: this project (the tiled run's despike, issue 14).
WindowIslands window_islands(const HeightField& window, int max_cells, const std::array<int, 4>& exact,
                             const std::array<int, 4>& needed, const std::array<bool, 4>& open);


namespace detail {
/// The cells a band of for_each_island_cell labels at a time by default (the rows of 16 M
/// cells, at least 4·max_cells rows): about 5 bytes a cell of its window while it runs
/// (OpenCV's 8-bit input and 32-bit labels).
inline constexpr std::size_t kIslandBandCells = std::size_t{1} << 24;
/// The island cells of `grid` (heights [m], NaN = no data), given to `cell` as row-major
/// indices in ascending order: the cells of the groups of at most max_cells valid cells
/// (8-connected), less the whole grid's largest group when spare_largest
/// (HonestCheckOptions::island_max_cells and spare_largest_group; find_grid_spikes' and
/// remove_spike_points' islands). *islands = the number of those groups. Labels `band_rows`
/// rows at a time (0: kIslandBandCells / cols, at least 4·max_cells) with max_cells rows above
/// and below, so memory is O((band_rows + 2·max_cells)·cols), not O(grid), and the result
/// equals one labelling of the whole grid. With spare_largest, cells are held back until a
/// group of more than max_cells cells shows (in a scanned surface, in the first band); in a
/// grid of specks only, the whole grid is labelled once to name the largest group as OpenCV
/// orders its labels. Source: this project (issue 14).
/// @throws std::invalid_argument for max_cells < 1.
void for_each_island_cell(const HeightField& grid, int max_cells, std::size_t* islands, bool spare_largest, int band_rows,
                          const std::function<void(std::size_t)>& cell);
/// for_each_island_cell's cells as a list (8 bytes a cell: for tests and small grids).
std::vector<std::size_t> island_cells(const HeightField& grid, int max_cells, std::size_t* islands, bool spare_largest,
                                      int band_rows = 0);
}  // namespace detail

/// One reason of a verdict: a stable code, its level and a sentence with the figures.
struct VerdictReason {
  std::string code;     ///< e.g. "grid_spikes", "spikes_kept", "surface_lost", "far_points"
  std::string level;    ///< "warn" or "fail"
  std::string message;  ///< what was found against which limit (config key named)
};

/// pass (no reason), warn (only warn reasons), fail (at least one fail reason).
struct Verdict {
  std::string status = "pass";
  std::vector<VerdictReason> reasons;
  bool has(const std::string& code) const;
};

/// The run's verdict from the figures of the honest cross-check, cross_check's supported
/// fraction (`supported_fraction`, NaN if the cross-check did not run) and the filter stages'
/// reports (`stages`: by stage and figure name; absent figures are skipped: "outliers"
/// threshold_mm, removed_far_clusters and far_clusters when a stage reports them; a tiled run's
/// far clusters, which has no "outliers" stage: "tile_far_clusters" removed_far_clusters and
/// far_clusters plus "tiles" sum_far_points_owned and sum_far_clusters_owned).
/// Reasons and their levels: grid_spikes (fail), spikes_kept (fail), islands (warn),
/// removed_fraction (warn), surface_lost (warn), far_points (warn), visible_off_surface (warn),
/// unsupported (warn), filter_threshold (warn). The limits are HonestCheckOptions'.
Verdict decide_verdict(const InputCheck& input, const GridSpikes& spikes, double supported_fraction,
                       const std::vector<StageReport>& stages, const HonestCheckOptions& options);

/// Checks HonestCheckOptions' ranges. @throws hc::ConfigError naming the cross_check.* key.
void check_honest_options(const HonestCheckOptions& options);

}  // namespace hc::pipeline
