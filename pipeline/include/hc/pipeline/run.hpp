#pragma once
/// @file run.hpp
/// The whole offline pipeline of `hapticloud run`: scan(s) → Monge grid → scene + report.

#include "hc/pipeline/cloud.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/cross_check.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/lod_report.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace hc::pipeline {

/// Progress callback: called when a stage starts (done = false) and ends (done = true). Long
/// stages of the tiled run (tiling.hpp) also call it while they run (done = false), at most
/// about once a second, with the figures `progress_fraction` [0, 1] and `eta_s` (the seconds
/// left at the rate so far) and a note naming the pass.
using ProgressFn = std::function<void(const StageReport& stage, bool done)>;

struct RunSummary {
  std::vector<StageReport> stages;
  /// When enabled; cell_error_m holds the map, except in a tiled run's summary (build_scene's
  /// from_tiled_run, merge_tile_jobs: the map is moved into the scene's cell_error layer, not
  /// copied; since 2026-11-29) and in the summary write_run(BuiltScene&&) returns for a tiled
  /// scene without the levels table (its grid is freed before scene_levels).
  std::optional<CrossCheck> cross_check;
  std::optional<CrossCheck> naive_cross_check;  ///< the naive front-most grid's, when compared
  /// The honest cross-check (when the cross-check is enabled): the grid against the input as
  /// read, the grid's spikes, pits and islands, and the verdict (honest_check.hpp).
  std::optional<InputCheck> input_check;
  std::optional<GridSpikes> grid_spikes;
  std::optional<Verdict> verdict;
  GridGeometry grid;
  std::size_t valid_cells = 0;
  /// Warnings for the report (e.g. float-stored georeferenced coordinates coarser than a tenth
  /// of a cell); each also sits in its stage's notes.
  std::vector<std::string> warnings;
  double total_seconds = 0.0;             ///< file to scene (build_scene) or to written report (run_pipeline)
  std::filesystem::path out_dir;
  std::filesystem::path moved_aside;      ///< where a foreign out_dir was kept (--force), or empty
};

/// Where a run makes level 0's surface layers (envelope, texture, μ_d, μ_s; issue 14).
enum class SurfaceLayersAt {
  /// Stage surface_layers, on the whole grid in memory, into BuiltScene::scene (every run but
  /// the one below).
  kMemory,
  /// Not in memory: write_run's stage scene_levels makes them tile by tile from the stored
  /// depth (build_stored_levels with Level0Layers::kSceneFolder, level_builder.hpp), bit for
  /// bit the same files. Only for a tiled run (build_scene_tiled, merge_tile_jobs) that
  /// write_run will store as a tiled scene (writes_tiled_scene) without the levels table
  /// (lod.report off, which would hold level 0's layers anyway); run_pipeline and
  /// `hapticloud tile-merge` ask for it.
  kSceneLevels,
};

/// A scene built in memory, with what the report needs.
struct BuiltScene {
  Scene scene;                 ///< typed layers and metadata (hc/common/scene.hpp)
  /// kSceneLevels: `scene` has no surface layers (its friction_model is set) and write_run
  /// makes them in the scene folder; such a scene must be written with the config it was built
  /// with. kMemory otherwise (the layers are in `scene` when config.layers is on).
  SurfaceLayersAt surface_layers_at = SurfaceLayersAt::kMemory;
  /// Made by the tiled run (build_scene_tiled, merge_tile_jobs): write_run then gives each of
  /// its stages' freed heap back to the system when it ends, as the tiled run's stages do
  /// (docs/scale.md, "10⁹ points under 1 GB"); the in-core run keeps it for reuse.
  bool from_tiled_run = false;
  RunSummary summary;          ///< stage reports and the cross-check
  std::optional<Cloud> cloud;  ///< the filtered points in the grid frame [m], when kept
  /// An evenly strided sample of the filtered points (grid frame [m]) for the levels table's
  /// cross-check (a) and the points_sample.bin of a tiled scene or of any scene of a tiled run
  /// (lod_report.hpp; write_run stores it when the cross-check ran): the tiled run's,
  /// which keeps no cloud, when the cross-check or lod.report with lod.report_cross_check is on
  /// (every ⌈N_input / lod.report_sample_points⌉-th interior kept point, in tile order); the
  /// in-core run's when it keeps no cloud, the cross-check is on and the scene will be stored
  /// tiled (every ⌈N / lod.report_sample_points⌉-th point of its cloud). point_sample_of is the
  /// number of filtered points it stands for.
  std::optional<Cloud> point_sample;
  std::size_t point_sample_of = 0;
};

/// Per-stage peak memory (StageReport::peak_rss_bytes, report.json peak_rss_mb): off by default,
/// because measuring it resets the whole process's resident-memory high-water mark (Linux,
/// /proc/self/clear_refs), which a program embedding the library may read (getrusage
/// ru_maxrss, VmHWM). `hapticloud run` turns it on. Process-wide; thread-safe.
void set_stage_memory_measurement(bool on);

/// Which of keep_freed_heap_for_reuse()'s settings the C library took.
struct HeapPolicyTaken {
  bool mmap_threshold_set = false;  ///< M_MMAP_THRESHOLD = 1 GiB taken
  bool trim_threshold_set = false;  ///< M_TRIM_THRESHOLD = 1 GiB taken
};

/// The batch commands' allocator policy (`hapticloud run`, `tile-plan`, `tile-job`,
/// `tile-merge`, `levels`; sessions keep the C library's default): glibc's M_MMAP_THRESHOLD and
/// M_TRIM_THRESHOLD set to 1 GiB [bytes], so that large blocks come from the heap and freed heap
/// is kept for reuse instead of every stage faulting in and zeroing fresh pages (glibc's dynamic
/// threshold maps blocks of up to 32 MB afresh; 10⁷ points in core: 1.8 → 0.7 s of system
/// time, the run 8.2–8.5 → 7.1–7.2 s; bench/README.md). In core the process keeps its peak
/// resident until it exits, and each stage's `peak_rss_mb` includes what the stages before it
/// kept. The tiled run gives freed heap back at each stage's end and within its tile loop
/// (docs/architecture.md, memory). A threshold taken
/// is recorded: the tile loop of a run of several bands maps its large blocks on their own for
/// a while and then restores it (docs/scale.md, fortieth session); without a recorded one it
/// leaves the threshold alone. Permanent for the process (glibc's dynamic mmap threshold stays
/// off; nothing undoes it); call it once, before any stage starts a thread, not while a run is
/// going. Source: mallopt(3). Throws nothing; without glibc it changes nothing and returns
/// {false, false}.
HeapPolicyTaken keep_freed_heap_for_reuse() noexcept;

/// The memory this process may use [bytes]: RAM and swap (sysinfo(2)), or the limit of its
/// memory cgroup or an ancestor's when lower (detail::memory_limit_from on /proc/self/cgroup
/// and /sys/fs/cgroup); 0 when unknown. Throws nothing.
std::uint64_t memory_limit_bytes() noexcept;

namespace detail {
/// The least of `ram_and_swap_bytes` (0: unknown) and the memory limits of the cgroups that
/// `proc_self_cgroup` (the text of /proc/self/cgroup: lines "<id>:<controllers>:<path>") places
/// the process in, and their ancestors', read under `cgroup_root` (/sys/fs/cgroup): cgroup v2
/// (the line "0::<path>") memory.max under the root or, on a hybrid host, its unified/ folder;
/// v1 (a line whose controllers include memory) memory.limit_in_bytes under memory/ or the
/// controllers' own folder ("cpuset,memory"). "max", a missing file and a value that is no number
/// are no limit. (The cgroup limits leave swap out.) Source: the kernel's cgroup-v2.rst and
/// cgroup-v1/memory.rst. @throws std::bad_alloc only.
std::uint64_t memory_limit_from(const std::string& proc_self_cgroup, const std::filesystem::path& cgroup_root,
                                std::uint64_t ram_and_swap_bytes);
}  // namespace detail

/// The least an in-core run holds per point of its scan at its peak [bytes]: measured 100–230
/// (docs/scale.md, "Scale"; 131 on the generated 2 M-point wall, fifty-seventh session).
inline constexpr std::uint64_t kInCoreBytesPerPointAtLeast = 100;

/// Refuses to read config's scan whole (in core) when it cannot fit: when its points counted
/// from the files' headers (counted_input_points with headers_only, tiling.hpp: binary PLY,
/// PCD, LAS, LAZ, E57, gzipped LAS and LAZ; no count costs a pass over a file) times
/// kInCoreBytesPerPointAtLeast exceed `limit_bytes` (memory_limit_bytes()), rather than being
/// killed by the kernel after minutes of reading. Nothing when the count or the limit (0) is
/// unknown. Source: this project (the per-point peaks measured in docs/scale.md).
/// @param way_out what the caller can do instead, appended to the message
/// @throws hc::ResourceError naming the input file(s), the points, the bytes needed and
///         available, and `way_out`.
void check_in_core_fits(const RunConfig& config, std::uint64_t limit_bytes, const std::string& way_out);

/// check_in_core_fits for build_scene's in-core path, `way_out` saying what keeps the run in
/// core: scale.tiled: off, an option the tiled run lacks (tiled_run_refusal, naming its key;
/// several files without input.shared_frame among them), keep_cloud under auto, or a count at
/// or below scale.tiled_above_points.
/// @throws hc::ResourceError as check_in_core_fits.
void check_in_core_run_fits(const RunConfig& config, bool keep_cloud, std::uint64_t limit_bytes);

/// Runs every stage of `config` in memory: ingest → units + recentre → view transform → filters
/// → reproject → hole fill → surface layers → cross-check. Nothing is written. When
/// runs_tiled(config) (scale.tiled; tiling.hpp) the streaming tiled run makes the scene instead:
/// it keeps no cloud (only BuiltScene::point_sample for the levels table) and runs the honest
/// cross-check tile by tile (tiling.hpp); with keep_cloud the run stays in core unless
/// scale.tiled is on (then no cloud is returned).
/// @param keep_cloud keep the filtered points (grid frame, metres) in the result (for the
///        levels table's cross-check or a viewer's cloud preview); otherwise they are freed.
/// @throws hc::Error subclasses from any stage (naming file, key or value); hc::ResourceError
///         before reading when an in-core run's scan cannot fit (check_in_core_run_fits).
/// Real-time: no. Threads: stages use up to two threads internally.
BuiltScene build_scene(const RunConfig& config, bool keep_cloud = false, const ProgressFn& progress = {});

/// build_scene on a cloud in memory instead of config.input's files (issue 18: a PCL user's
/// cloud, converted by hc::pcl): `cloud` takes the place of ingest (stage "ingest", its report
/// noting it); input.files, input.conf and input.synthetic are not read. Everything after ingest
/// is the file path's: `cloud` is in config.input.units and its file frame (recentred, turned
/// by config.view, filtered, gridded), so the same points give the same scene as from a file.
/// Provenance lists one input "(in-memory cloud, N points)" with the SHA-256 of its 3 × N
/// doubles. Cloud::float32_xyz is honoured like a reader's flag.
/// @throws as build_scene (an empty cloud: hc::InputError from the first stage that needs points).
BuiltScene build_scene(Cloud cloud, const RunConfig& config, bool keep_cloud = false, const ProgressFn& progress = {});

/// Fills the servo-timing columns of a levels table. The pipeline does not run servo loops;
/// hc::session::servo_level_timing() provides one (the `hapticloud` program passes it).
using LevelTimingFn = std::function<void(const std::shared_ptr<LodPyramid>&, std::vector<LevelRow>&)>;

/// Writes, atomically (StagingDir), the run folder `out_dir` of a built scene:
///   scene/ (write_scene), previews/*.png, report.md and report.json; with `config.lod.report`,
/// the levels table (pipeline::level_table, cross-checked against built.cloud, or else
/// built.point_sample, when lod.report_cross_check; timed by `level_timing` when given) and its
/// previews.
/// An existing out_dir is replaced only if it is an earlier output or an empty folder; a file or
/// a foreign folder is refused, or kept aside with ExistingOutput::kMoveAside (see StagingDir).
/// A tiled scene (writes_tiled_scene) gets its levels in stage scene_levels (build_stored_levels);
/// a scene built with SurfaceLayersAt::kSceneLevels gets level 0's surface layers there too,
/// and their previews from the stored files.
/// @return the summary with the write and levels stages appended, total_seconds = build + write.
/// @throws hc::InputError for a refused out_dir (before anything is written) or a file that
///         cannot be written; on a throw nothing is left at out_dir that was not there before;
///         std::invalid_argument (before anything is written) for a kSceneLevels scene and a
///         config that has layers off, writes no tiled scene or asks for the levels table.
RunSummary write_run(const BuiltScene& built, const RunConfig& config, const std::filesystem::path& out_dir,
                     const ProgressFn& progress = {}, ExistingOutput existing = ExistingOutput::kRefuse,
                     const LevelTimingFn& level_timing = {});
/// The same for a scene the caller no longer needs: the levels table's pyramid takes level 0's
/// layers (depth, colour, envelope, texture, μ_d, μ_s) from `built` instead of copying them, so
/// `built.scene.layers` is left without them (issue 14's memory bound: six layers are about
/// 200 MB at N = 4096); the summary is moved out of `built` too. Writing a tiled scene without
/// the levels table, it lets level 0's grids (not the flags) and the summary's cross-check
/// error grid go after the write stage, before stage scene_levels. run_pipeline uses it.
RunSummary write_run(BuiltScene&& built, const RunConfig& config, const std::filesystem::path& out_dir,
                     const ProgressFn& progress = {}, ExistingOutput existing = ExistingOutput::kRefuse,
                     const LevelTimingFn& level_timing = {});

/// build_scene then write_run: the whole of `hapticloud run`. A tiled run is asked for
/// SurfaceLayersAt::kSceneLevels: writing a tiled scene without the levels table, level 0's
/// surface layers are made tile by tile in stage scene_levels, never whole in memory.
/// @throws as build_scene and write_run; the out_dir check happens before any stage runs.
RunSummary run_pipeline(const RunConfig& config, const std::filesystem::path& out_dir,
                        const ProgressFn& progress = {},
                        ExistingOutput existing = ExistingOutput::kRefuse,
                        const LevelTimingFn& level_timing = {});

/// The points a run config's grid is made from, in its grid frame (metres): ingest, recentring,
/// view transform and filters, the stages of build_scene before reprojection (no report).
/// @throws whatever ingest and the filters throw (naming the file or key).
Cloud prepare_points(const RunConfig& config);

/// SHA-256 of a file as lowercase hex. @throws hc::InputError naming the file if unreadable.
std::string sha256_file(const std::filesystem::path& file);

}  // namespace hc::pipeline
