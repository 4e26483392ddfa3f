#pragma once
/// @file run_internal.hpp
/// What the in-core run (run.cpp) shares with the tiled run (tiled_run.cpp): the stage helper,
/// the stored-precision check and the steps from a finished depth grid to the scene's layers.
/// Private to the pipeline (not installed, not public API).

#include "hc/pipeline/config.hpp"
#include "hc/pipeline/cross_check.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/honest_check.hpp"
#include "hc/pipeline/run.hpp"
#include "stage_util.hpp"

#include <Eigen/Geometry>

#include <array>
#include <atomic>
#include <cstddef>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

namespace hc::pipeline::detail {

/// cross_check() without its point-to-surface part (a): the same cell-to-point search (b), so
/// `cell_error_m`, `cell_to_point` and `supported_fraction` equal cross_check()'s bit for bit,
/// while the point counts by kind are 0 and point_vertical / point_normal empty. For the tiled
/// run, which measures (a) once over every tile's interior points and needs each window's cell
/// errors only. Arguments and errors as cross_check() (cross_check.hpp).
/// `query` {row_begin, row_end, col_begin, col_end} (grid indices, clamped to the grid): only
/// the samples inside it are searched (the tiled run's tile interior inside its window); the
/// others' cell_error_m is NaN, and cell_to_point and supported_fraction cover the searched
/// ones (supported_fraction 0 when none is valid). Every point and every valid sample's height
/// still set the search's float frame, so a searched sample's distance is the one the whole
/// search gives, bit for bit.
/// `frame`, when given, is the float frame and the sample positions of a larger grid of which
/// `grid` is a window (the tiled run: the whole grid, held whole): the samples sit at the whole
/// grid's x_of_col(col0 + c), y_of_row(row0 + r), and the float coordinates are taken about
/// `centre` (cross_check_frame_centre of the whole grid), so that a sample whose nearest point
/// the window holds gets the whole grid's cross_check() distance bit for bit (since
/// 2026-11-30; before, the window's own frame, to float rounding of the coordinates).
struct CellErrorFrame {
  GridGeometry whole;
  int row0 = 0, col0 = 0;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
};
StageResult<CrossCheck> cross_check_cell_errors(const Cloud& points_m, const HeightField& grid, double tolerance_m,
                                                double hidden_band_m,
                                                std::array<int, 4> query = {0, std::numeric_limits<int>::max(), 0,
                                                                            std::numeric_limits<int>::max()},
                                                const CellErrorFrame* frame = nullptr);

/// The float frame's centre cross_check() takes for `grid` [m, grid frame]: the grid's middle in
/// x and y (x_of_col((cols − 1) / 2), y_of_row((rows − 1) / 2)) and the middle of its valid
/// heights' range in z (0 without a valid cell).
Eigen::Vector3d cross_check_frame_centre(const HeightField& grid);

/// The distance cross_check() records for a float squared distance `best_sq` [m²] found in its
/// float frame: the float nearest √best_sq (the error map's value; the tiled run's search
/// again over other tiles records the same).
inline float cross_check_recorded_distance(float best_sq) { return static_cast<float>(std::sqrt(static_cast<double>(best_sq))); }

/// Resets the process's resident-memory high-water mark (Linux, proc(5): writing "5" to
/// /proc/self/clear_refs resets VmHWM). @return false when it cannot.
bool reset_peak_rss();
/// VmHWM of /proc/self/status [bytes]: the peak resident memory since the last reset; 0 if
/// unreadable.
std::size_t peak_rss();

/// Gives the heap's free pages back to the system (glibc malloc_trim(0), malloc(3): the free
/// pages of every arena, not only the top) when a StageHeapRelease is alive in the process;
/// else, or without glibc, nothing. Called by stage() and the write stage when they end.
/// `hapticloud run` keeps freed heap for reuse (mallopt thresholds of 1 GiB,
/// hc::pipeline::keep_freed_heap_for_reuse in run.hpp),
/// so without this a tiled run's resident size would be the sum of every stage's high-water
/// and the fragments between (10⁷ wall, N = 4096: 652 MB, 524 MB with it, docs/scale.md).
void release_freed_heap_if_asked();

/// CPU time the process has used so far, user plus system over all threads [s] (getrusage(2),
/// RUSAGE_SELF); 0 when unavailable. Differences of two calls time a stage's CPU.
double process_cpu_seconds();

/// The process's resident size [bytes] (VmRSS of /proc/self/status, proc(5)); 0 when unreadable.
std::size_t resident_bytes();

/// For a loop over tiles: gives freed heap back before a tile when the resident size has grown
/// more than `budget_bytes` past what it was after the last release (or at construction). A
/// tile's window needs about its points × kBytesPerWindowPoint; freed and kept, the windows'
/// fragments add up with the tiles (10⁹ points, 392 tiles: 1.4 GB resident for about 50 MB in
/// use between tiles), while a release before every tile costs its pages again (10⁸ points at
/// N = 4096: system time 6–7 → 15 s). Gives back only while a StageHeapRelease is alive.
/// Not thread-safe (one per loop); throws nothing. Source: malloc_trim(3), proc(5);
/// measurements in docs/scale.md ("10⁹ points under 1 GB").
class TileHeapBudget {
 public:
  /// About what the tile loop holds per window point [bytes] (docs/config.md, scale.tile_max_points).
  static constexpr std::size_t kBytesPerWindowPoint = 150;
  /// `budget_bytes` [bytes]; the resident size now is the first base.
  explicit TileHeapBudget(std::size_t budget_bytes);
  /// Before each tile: releases when the resident size exceeds the base by more than the
  /// budget, then takes the resident size after the release as the base. @return whether it
  /// gave freed heap back.
  bool before_tile();
  /// Before a step whose memory the tiles' freed fragments serve poorly (tiled_run.cpp,
  /// run_tiles, with more than one band: a band's gathering of strays, a band's first sweep
  /// after another band's second; at 10⁹ points each took over 400 MB above a resident size
  /// already near the budget): releases whatever the budget says, then takes the resident size
  /// after the release as the base. Source: malloc_trim(3); docs/scale.md, thirty-ninth
  /// session. @return whether it gave freed heap back (false while no StageHeapRelease is
  /// alive). Not thread-safe, throws nothing (as before_tile).
  bool release_now();
  std::size_t releases() const { return releases_; }

 private:
  std::size_t budget_;
  std::size_t base_;
  std::size_t releases_ = 0;
};

/// The M_MMAP_THRESHOLD hc::pipeline::keep_freed_heap_for_reuse() set [bytes] (run.hpp); 0
/// while the C library keeps its own. Read by LargeBlocksMapped.
extern std::atomic<int> g_kept_mmap_threshold;

/// While alive: blocks of `threshold_bytes` or more are mapped on their own (glibc's
/// M_MMAP_THRESHOLD) and unmapped when freed, instead of coming from the kept heap; the
/// destructor restores the threshold keep_freed_heap_for_reuse() set. Acts only when that
/// function set one and a StageHeapRelease is alive (a tiled run of a batch command); else
/// nothing. For the tile loop of a run of several bands (tiled_run.cpp, run_tiles): there the
/// kept heap's holes, left by windows of other sizes, did not fit the next window's arrays, so
/// the resident size grew by several hundred MB above what was in use (10⁹ points, 392 tiles:
/// the tile loop 1 084 → 893 MB, its CPU 1 178 → 1 111 s with 157 → 19 releases, the scene the
/// same bytes; docs/scale.md, fortieth session). A mapped block costs its pages' faults and
/// zeroing each time, which the kept heap saves in a run of one band. Source: mallopt(3).
/// Guards nest and may live on several threads at once: the first that acts sets the
/// threshold, the last to end restores the one recorded when the first set it (a run's memory
/// only; results do not depend on it). Throws nothing.
class LargeBlocksMapped {
 public:
  explicit LargeBlocksMapped(std::size_t threshold_bytes);
  ~LargeBlocksMapped();
  LargeBlocksMapped(const LargeBlocksMapped&) = delete;
  LargeBlocksMapped& operator=(const LargeBlocksMapped&) = delete;
  /// Whether the threshold was changed (and is restored at the end).
  bool active() const { return active_; }

 private:
  bool active_ = false;
};

/// While alive, every stage's end gives freed heap back (release_freed_heap_if_asked). The
/// tiled run holds one: its stages free what they used (a tile's window, a pass's tables), so
/// the next stage starts from the memory it keeps, and a refault costs one window's pages. The
/// in-core run does not: its stages allocate arrays of every point, which freeing and faulting
/// in again would cost (1.8 s of system time at 10⁷ points). Nests; thread-safe.
class StageHeapRelease {
 public:
  StageHeapRelease();
  ~StageHeapRelease();
  StageHeapRelease(const StageHeapRelease&) = delete;
  StageHeapRelease& operator=(const StageHeapRelease&) = delete;
};

/// Runs one stage: announces it, runs it, records its report (seconds, CPU seconds, peak memory).
template <class F>
auto stage(const char* name, std::vector<StageReport>& reports, const ProgressFn& progress, F&& body) {
  StageReport announce;
  announce.stage = name;
  if (progress) progress(announce, false);
  const bool measured = reset_peak_rss();
  const auto t0 = Clock::now();
  const double cpu0 = process_cpu_seconds();
  auto result = body();
  result.report.stage = name;
  if (result.report.seconds <= 0.0) result.report.seconds = seconds_since(t0);
  result.report.cpu_seconds = process_cpu_seconds() - cpu0;
  if (measured) result.report.peak_rss_bytes = peak_rss();
  release_freed_heap_if_asked();
  reports.push_back(result.report);
  if (progress) progress(result.report, true);
  return std::move(result.value);
}


/// What ingest tells about the stored precision of the coordinates (Cloud::float32_xyz).
struct StoredPrecision {
  bool float32 = false;
  std::string file;                                  ///< the (first) input, for messages
  std::string crs;                                   ///< Cloud::crs as read
  Eigen::Vector3d max_abs_m = Eigen::Vector3d::Zero();  ///< largest |coordinate| per file axis [m], before recentring
  Eigen::Vector3i distinct = Eigen::Vector3i::Zero();   ///< distinct stored values per axis, counted up to kDistinctCap
};
constexpr int kDistinctCap = 64;
/// Fewer distinct stored values than this along a grid axis: the grid has collapsed.
constexpr int kCollapsedDistinct = 16;

/// The stored precision of `cloud` as read (file units; unit_m converts to metres).
StoredPrecision stored_precision(const Cloud& cloud, double unit_m, const std::string& file);

/// The input files named in one phrase for messages: the file, or "<first> and N more files".
inline std::string inputs_label(const std::vector<std::filesystem::path>& files) {
  if (files.empty()) return "no file";
  if (files.size() == 1) return files.front().string();
  return files.front().string() + " and " + std::to_string(files.size() - 1) + (files.size() == 2 ? " more file" : " more files");
}

/// The float-precision check once the cell size is known (warnings, or an error naming the
/// collapsed axis); see run.cpp.
void check_stored_precision(const StoredPrecision& p, double cell_m, const Eigen::Matrix3d& view_rotation,
                            StageReport& report, std::vector<std::string>& warnings);

/// From a finished depth grid (reprojected, despiked) to the scene's grid layers, as the run
/// makes them: the stored-precision check (into reports[grid_report]), corrugation, hole fill,
/// the scene's geometry, model-to-grid transform, flags, colour and intensity; the surface layers
/// are the caller's next step (scene_surface_layers: in core at once, tiled after the checks).
/// `grid` keeps the hole-filled depth (the cross-check's); built.summary gets grid and
/// valid_cells. @return the model-to-grid transform.
Eigen::Affine3d scene_from_grid(DepthGrid& grid, const RunConfig& config, std::vector<StageReport>& reports,
                                const ProgressFn& progress, const StoredPrecision& precision,
                                const Eigen::Vector3d& offset_m, std::size_t grid_report, BuiltScene& built);

/// Stage surface_layers (envelope, texture, μ_d, μ_s of compute_surface_layers) on `depth`, the
/// scene's hole-filled level 0 (its model_to_grid set, as scene_from_grid leaves it), into
/// built.scene; or, for a scene whose level 0 the level builder will make them for
/// (SurfaceLayersAt::kSceneLevels), only the friction model. The tiled run calls it after its
/// checks, which do not read the layers: their 16 bytes a sample are then not held beside the
/// checks' windows (the run's peak stage at 10^8 and 10^9 points, 2026-11-26).
void scene_surface_layers(const HeightField& depth, const RunConfig& config, std::vector<StageReport>& reports,
                          const ProgressFn& progress, BuiltScene& built);

/// cross_check.honest with the splat footprint the confirmation may use (disc splats, not a
/// rasterised mesh): (splat_radius_cells + ½√2) × upsample_factor × cell [m]; see run.cpp.
HonestCheckOptions honest_options_for(const RunConfig& config, bool rasterised, double upsample_factor, double cell_m);

/// The honest_check stage's figures and notes from its results (in-core and tiled runs alike).
void add_honest_figures(const InputCheck& in, const GridSpikes& spikes, StageReport& report);

}  // namespace hc::pipeline::detail
