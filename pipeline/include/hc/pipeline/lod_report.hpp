#pragma once
/// @file lod_report.hpp
/// Speed against error per level of detail (`hapticloud levels SCENE` and the run report):
/// cell size, size, build time, cross-check against the original points, per-tick cost of the
/// servo loop on a window of the level, and the time to switch to it; plus preview images of
/// every level side by side. No OpenCV, PCL or yaml-cpp in this header.

#include "hc/pipeline/cloud.hpp"
#include "hc/pipeline/cross_check.hpp"
#include "hc/pipeline/lod.hpp"

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace hc::pipeline {


/// One row of the levels table.
struct LevelRow {
  int level = 0;
  int rows = 0, cols = 0;
  double cell_size_m = 0.0;
  std::size_t valid_cells = 0;
  double build_seconds = 0.0;   ///< smoothing + decimation + layers of this level [s] (level 0: its layers, if computed here)
  bool stored = false;          ///< read from a stored pyramid (LodPyramid::open_stored): not built here, build_seconds 0
  std::optional<ErrorStats> point_vertical;  ///< cross-check (a): points vs the level's bilinear surface
  double supported_fraction = 0.0;           ///< cross-check (b): samples with a point within tolerance
  bool support_measured = false;             ///< supported_fraction was measured (it needs every point)
  std::size_t points_checked = 0;            ///< points (a) looked at (on the surface or not) [-]
  std::size_t points_total = 0;              ///< points of the set they were drawn from [-]; equal: no sampling
  double cross_check_seconds = 0.0;          ///< time of this row's (a) and support [s] (0: reused or none)
  /// μ_d of the level: clamp counts and 10 bins between μ_min and μ_max (the pyramid's layer
  /// options); empty when the level has no friction layer.
  std::optional<FrictionHistogram> mu_d;
  bool timed = false;           ///< the servo columns below were measured (hc::session::time_levels)
  double tick_p50_ns = 0.0, tick_p99_ns = 0.0;  ///< servo tick compute on a window of this level,
                                                 ///< median and 99th percentile [ns]
  double switch_ms = 0.0;       ///< request → first servo tick on the new window, level cached [ms]
                                ///< (window crop + HapticSurface + mailbox + one tick; as fast as possible;
                                ///< a real-time loop adds the wait for its next tick, ≤ 1 period)
};

struct LevelTableOptions {
  bool cross_check = true;      ///< needs `points`
  double tolerance_m = 0.0005;
  double hidden_band_m = 0.002;
  /// (a) on every ⌈N / sample_points⌉-th point of `points` (N of them; in their order), so a
  /// level costs O(sample_points) for (a) whatever N; 0 = every point (lod.report_sample_points).
  std::size_t sample_points = 200000;
  /// When `points` is itself an evenly strided sample of a larger set (the tiled run keeps one,
  /// points_sample.bin stores one), that set's size: (a) uses the sample as it is and the support
  /// is not measured (it needs every point). 0, or at most points->size() (a sample that holds
  /// every point): `points` is the whole set.
  std::size_t points_represent = 0;
  /// Level 0's cross-check when the caller has it already (the run's): reused, not recomputed.
  std::optional<CrossCheck> level0_cross_check;
  /// A stored pyramid's level of more than this² samples is read in windows of this side
  /// [samples], ≥ 2 (each read with one more row and column), never whole (issue 14); smaller
  /// where lod.memory_budget_mb would not hold such a window (level_table).
  int stored_window_samples = 1024;
};

/// Builds every level of `pyramid` (with layers) and measures its row: size, build time and the
/// cross-check of `points` (grid frame, metres, as the grid was made from; may be null: no
/// cross-check) against the level's bilinear surface: (a) point_residual (cross_check.hpp) of
/// every s-th point, s = ⌈N / sample_points⌉ (s = 1 when sample_points is 0 or N ≤ it), and
/// the supported fraction over every point (supported_fraction, cross_check.hpp; not measured
/// when `points` is a sample, options.points_represent > its size). Level 0 takes
/// options.level0_cross_check when given (the run's exact cross-check over every point). The
/// rows say what was sampled (points_checked of points_total). The servo columns (tick cost,
/// switch time) are left unmeasured (`timed` false): the pipeline does not run servo loops;
/// hc::session's time_levels fills them.
/// A stored pyramid (LodPyramid::open_stored, a tiled scene) builds nothing: a level of more than
/// side² samples is read a window of side × side samples at a time, side the smaller of
/// options.stored_window_samples and what half of the pyramid's window budget holds (memory: one
/// window of every layer, and per sampled point a residual and an index, 12 bytes), with the same figures as the whole
/// level gives (bit for bit: the residuals by point_residual_of_part, the μ_d histogram's counts
/// summed) except the support, which is not measured there (reported so); smaller levels are read
/// whole. Rows say `stored`.
/// @throws what building the levels or the cross-check throws; hc::ConfigError for
/// stored_window_samples < 2; what reading a stored window throws (hc::InputError naming the
/// file). Real-time: no. Cost: every level is built (or read); per level O(sample_points)
/// residuals and an O(N) support pass with no search structure.
std::vector<LevelRow> level_table(const std::shared_ptr<LodPyramid>& pyramid, const Cloud* points,
                                  const LevelTableOptions& options);

/// The table as Markdown (one header line, one row per level).
std::string level_table_markdown(const std::vector<LevelRow>& rows);
/// The table as plain text for a terminal.
std::string level_table_text(const std::vector<LevelRow>& rows);

/// The levels table's points stored beside a tiled scene, or any scene of a tiled run (issue
/// 14): `points_sample.bin` in the scene folder, so that `hapticloud levels` cross-checks a
/// scene larger than memory, or one made from a scan larger than memory, without reading its
/// scan again. Little-endian: the 8 bytes "HCPSMP1\n", uint64 count, uint64
/// represents (the filtered points the sample stands for, ≥ count), then count × (x, y, z) as
/// float64, grid frame [m]. Source: this project.
struct LevelPointSample {
  Cloud points;                 ///< grid frame [m]
  std::uint64_t represents = 0; ///< ≥ points.size(); equal: the sample is every point
};
inline constexpr const char* kLevelPointSampleFile = "points_sample.bin";

/// The stride of the levels table's stored sample of n filtered points: ⌈n / s⌉ ≥ 1, s =
/// sample_points, or lod.report_sample_points' default (200 000) for 0 (a stored sample never
/// holds every point of a large scan). The tiled run's and the in-core run's rule.
std::size_t level_sample_stride(std::uint64_t n, std::size_t sample_points);
/// Every stride-th point of `points` (stride ≥ 1, from the first; xyz only, as they are).
Cloud every_nth_point(const Cloud& points, std::size_t stride);
/// Writes `points` (grid frame [m]) to scene_dir/points_sample.bin with `represents` (0: the
/// points' count).
/// @throws hc::InputError naming the file when it cannot be written.
void write_level_point_sample(const std::filesystem::path& scene_dir, const Cloud& points, std::uint64_t represents = 0);
/// Reads scene_dir/points_sample.bin: nullopt when the file does not exist.
/// @throws hc::InputError naming the file when it is not such a file (magic, sizes, count
///         above represents, a non-finite coordinate).
std::optional<LevelPointSample> read_level_point_sample(const std::filesystem::path& scene_dir);

/// Writes `lod_level_<L>.png` (hillshade) for every level into `dir`, and `lod_levels.png`: all
/// levels side by side at the same height (nearest-neighbour enlargement, so coarse levels show
/// their cells). @return the file names written (relative to dir), composite last.
/// @throws hc::InputError naming a file that cannot be written.
std::vector<std::string> write_level_previews(LodPyramid& pyramid, const std::filesystem::path& dir);

}  // namespace hc::pipeline
