#pragma once
/// @file config.hpp
/// The YAML run configuration of `hapticloud run`, validated into plain structs.
/// Every key, its type, default and allowed range is listed in docs/config.md.

#include "hc/audio/audio_config.hpp"
#include "hc/falcon/falcon_config.hpp"
#include "hc/pipeline/filters.hpp"
#include "hc/pipeline/pcl_filters.hpp"
#include "hc/pipeline/honest_check.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/robust_outliers.hpp"
#include "hc/pipeline/surface_layers.hpp"
#include "hc/pipeline/synthetic.hpp"
#include "hc/pipeline/transform.hpp"

#include <Eigen/Core>

#include <array>
#include <limits>
#include <map>

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace hc::pipeline {

struct InputConfig {
  std::vector<std::filesystem::path> files;     ///< scans, resolved against the config's folder
  std::optional<std::filesystem::path> conf;    ///< scanalyze .conf to merge several views
  /// input.shared_frame: the files are parts of one scan in one frame (the tiles of a survey, a
  /// scan cut in pieces): their points are taken in the listed order, as if from one file
  /// (load_files_in_one_frame, ingest.hpp). Exclusive with conf.
  bool shared_frame = false;
  std::string units = "m";                      ///< "m" | "cm" | "mm" | "ft" | "us-ft" | "in"
  std::vector<int> las_drop_classes{7, 18};     ///< LAS classes dropped on reading (0..255)
  double max_extent_m = kDefaultMaxExtentM;     ///< largest accepted bounding-box side [m]
  bool as_points = false;                       ///< meshes: vertices only, faces dropped
  std::optional<SyntheticSpec> synthetic;       ///< generate instead of reading files
};

struct OutlierConfig {
  bool enabled = true;
  int k = 16;                    ///< neighbours [-], 1..256
  double std_multiplier = 2.0;   ///< σ multiplier [-], (0, 100]
  OutlierScope scope = OutlierScope::kAll;  ///< "all" | "front" (which points are tested)
  OutlierMethod method = OutlierMethod::kRobust;  ///< "robust" | "statistical" (exact PCL SOR)
  double local_ratio = 3.0;      ///< robust: local test ratio [-], (1, 100]
  double mad_multiplier = 8.0;   ///< robust: global test in σ of ln d [-], (0, 100]
  double off_surface_ratio = 2.0;  ///< robust: off-surface test above this × median d [-]; 0 = off, else (1, 100]
  /// robust, points only: after gridding, remove the stray points that make grid spikes and
  /// islands (remove_spike_points) and grid again
  bool despike = true;
  FarClusterOptions far_clusters;  ///< robust: far-cluster removal (far_clusters.*)
};

struct FilterConfig {
  OutlierConfig outliers;
  std::optional<std::pair<Eigen::Vector3d, Eigen::Vector3d>> crop_m;  ///< min, max (grid frame)
  double voxel_m = 0.0;          ///< voxel-grid leaf [m]; 0 = off
  /// filters.pcl: PCL filters run in this order after crop and voxel, before the outliers stage,
  /// each its own stage "pcl:<name>" (pcl_filters.hpp). Empty = none.
  std::vector<PclFilterSpec> pcl;
};

struct GridConfig {
  ReprojectOptions reproject;    ///< N or cell size, splat radius, see-through
  int hole_fill_max_cells = 0;   ///< largest hole filled [cells]; 0 = off
  double hole_fill_max_step_m = 0.0;  ///< holes whose rim spans more depth stay no data [m]; 0 = no limit
  bool organised_mesh = false;   ///< grid.organised: mesh (organised scans meshed per scan) | splat
  double organised_max_edge_factor = 4.0;  ///< depth-jump limit / median sample spacing [-]
  /// grid.organised_blend_m: faces within this depth [m] of the front-most one are averaged
  /// at each node (rasterise_mesh layer_blend_m); 0 = front-most face only.
  double organised_blend_m = 0.0;
};

struct CrossCheckConfig {
  bool enabled = true;
  double tolerance_m = 0.0005;   ///< a cell is supported if a point lies within this [m]
  double hidden_band_m = 0.002;  ///< (a) uses points at most this far below the surface [m]
  bool compare_naive = false;    ///< also grid naively (front-most only) and cross-check that,
                                 ///< so the report shows what see-through handling, splats and
                                 ///< hole filling change
  /// The honest cross-check's tests and the verdict's limits (cross_check.* keys; its
  /// tolerance_m and hidden_band_m are copied from the two above).
  HonestCheckOptions honest;
};

struct LayersConfig {
  bool enabled = true;           ///< texture, curvature and friction layers (issue 3)
  SurfaceLayerOptions options;
};

/// scale.* (issue 14, tiling.hpp): the streaming tiled run for scans too large for memory.
struct ScaleConfig {
  enum class Tiled { kAuto, kOn, kOff };
  /// auto: tiled when the input is one binary PLY (streamed natively) of more than
  /// tiled_above_points points; on: always (an error names the keys it cannot honour); off: never.
  Tiled tiled = Tiled::kAuto;
  std::uint64_t tiled_above_points = 50'000'000;  ///< the auto threshold, ≥ 1
  int tile_cells = 512;           ///< largest tile side [grid cells], 16 to 65536 (rounded up to the upsample factor)
  /// The most points a tile's window (tile and halo) may hold [points], 0 (no bound) or 1000 to
  /// 2^40: where a window of tile_cells would hold more (a dense scan on a coarse grid), the
  /// plan counts the points per block of cells and takes smaller tiles, down to the halo's side
  /// (tiled_run.cpp, choose_tile_side). The tile loop holds about 150 bytes a window point.
  std::uint64_t tile_max_points = 4'000'000;
  /// scale.filter_halo_cells: auto, the halo from the scan's spacing (tiled_run.cpp,
  /// auto_filter_shares).
  static constexpr int kAutoFilterHalo = -1;
  /// Extra halo for the per-tile outlier filters and the honest check [cells], 0 to 4096, or
  /// kAutoFilterHalo: the least that holds their searches at the scan's spacing (an estimate at
  /// tile_plan, the robust sample's at tile_scale, the points spilled again when it is wider).
  int filter_halo_cells = kAutoFilterHalo;
  /// With the despike on: whether every tile's decided region is widened so that each group of
  /// up to cross_check.island_max_cells valid cells whose island label the despike reads near
  /// the interior lies inside it (tiled_run.cpp, grid_share_cells: 2R + ⌈reach⌉ +
  /// island_max_cells nodes instead of 2R + ⌈reach⌉ + spike_window_cells / 2; 26 instead of 12
  /// nodes at the shipped settings). on: always. off: a window that cannot decide such a group
  /// stops the run with a ConfigError naming this key. auto (the default, since 2026-11-29,
  /// fifty-fifth session): the narrower share; where a window cannot decide a group, the
  /// in-process run (build_scene_tiled) starts again from the plan with the wider one, and says
  /// so in a warning (islands near a tile's edge are rare: none in 56–275 tiles of the Buddha,
  /// the bunny and the E57 pump at 32-cell tiles). A tile job cannot widen its plan's halo: under
  /// auto `hapticloud tile-job` exits 5 (under off 1, as any error), and the Dask driver plans
  /// again with on. Before the fifty-fifth session a bool, false by default (the fifty-third
  /// session's).
  Tiled island_halo = Tiled::kAuto;
  /// scale.grid_on_kept_points: true (the default): where the outlier filters (the robust test,
  /// far clusters, the isolated filter) remove a point that sets the x-y box of the points the
  /// tiled run laid its grid on, the run starts again after its tile loop with the grid laid on
  /// the kept points' box, as the in-core run lays it; where its despike does, once more with
  /// the box it leaves, its removals taken over (at most three attempts: notes and figure
  /// `grid_relaid` of `tile_plan`; tiled_run.cpp, build_scene_tiled). false: the first grid
  /// stays, with the warning that the in-core scene differs. Through tile jobs, tile-merge
  /// writes the box for a new plan instead (GridBoxError, tile-plan --grid-box; tiling.hpp).
  bool grid_on_kept_points = true;
  /// Not a config key: set by the tiled run's later attempts (in process; through tile jobs,
  /// from plan.json's grid_box, which tile-plan --grid-box takes from a merge). The x-y box [m, grid frame] and
  /// the point count the plan lays the grid on (grid_geometry_for_box) instead of those of the
  /// points before the outlier filters; and, when the box is the one left after an attempt's
  /// despike, the points that despike removed (x y z [m, grid frame] each, sorted as triples):
  /// the tiles remove them instead of running the despike on this grid, as the in-core run
  /// lays its grid again after its despike without a second one.
  /// `despike_sums`: that despike's figures as the tiles summed them (the report's). `last`: the
  /// last attempt, which lays no other grid (a grid still unlike the in-core one is a warning).
  /// `upsample_factor` (grid.upsample: auto only; 0: the plan chooses it from every point): the
  /// factor auto gives the points the filters keep (or, with despiked_m, the despike leaves) on
  /// this box's grid, as the in-core run chooses it; the plan takes it (sixty-fourth session).
  struct GridBox {
    double x_min_m = 0.0, x_max_m = 0.0, y_min_m = 0.0, y_max_m = 0.0;
    std::uint64_t points = 0;
    int upsample_factor = 0;
    std::shared_ptr<const std::vector<std::array<double, 3>>> despiked_m;
    std::map<std::string, double> despike_sums;
    bool last = false;
  };
  std::optional<GridBox> grid_box;
  /// Not a config key: set by the in-process tiled run (tiled_run.cpp) for the tiles it processes
  /// again (or, where the spills are gone, for the attempt it starts again) when the in-core
  /// run's far clusters among the points the tiles' robust test kept (found at the merge from
  /// every tile's link cells) held more points than the tiles removed as far (sixty-sixth
  /// session, 2026-11-30). `keys`: the removed clusters' link cells (FarCells::link_key at
  /// edge link_m [m], increasing); the tiles of that attempt remove the points of their windows
  /// that the robust test keeps in those cells instead of judging far clusters themselves.
  /// `cluster`: each key's cluster (0, 1, ...). `points`, `clusters`: the in-core run's removed
  /// far-cluster points and clusters [-]; `notes`: its notes on them. The whole-scan pass's own
  /// removals (stage tile_far_clusters) are not among them. `last`: carried a second time (the
  /// grid moved the first ones); an attempt with them warns instead of starting again.
  struct FarCellKeys {
    double link_m = 0.0;
    std::vector<std::uint64_t> keys;
    std::vector<std::uint32_t> cluster;
    std::uint64_t points = 0, clusters = 0;
    std::vector<std::string> notes;
    bool last = false;
  };
  std::shared_ptr<const FarCellKeys> far_cells;
  std::size_t chunk_points = 1u << 20;  ///< points read per chunk, 1024 to 2^28
  std::filesystem::path scratch;  ///< folder for the spill files; empty = the system's temporary folder
  /// scale.level0_file: true (the default): a tiled run holds level 0's depth, flags, colour and
  /// intensity and the cross-check's error map (9 bytes a cell, 16 with colour and intensity) in shared mappings of files in the
  /// scratch folder (cell_buffer.hpp: reserved in full, unlinked at once), each stage giving
  /// their pages back to the kernel as it goes, so that the page cache, not the process, holds a
  /// level 0 larger than memory (docs/scale.md, "Level 0 in a file"); false: on the heap.
  bool level0_file = true;
  /// The most memory the robust test's first looks of a band of tiles hold [MiB], 0 to 65536:
  /// the tile loop looks at consecutive tiles until their verdicts (half a byte a window point, and
  /// the removed points') hold this much, judges their strays in one gathering, then finishes
  /// them (docs/scale.md, step 3). 0: one tile a band. A fraction of a MiB is taken as such.
  double band_mb = 128.0;
  /// The most gatherings of a band's strays, 1 to 64: where the second look's k-NN searches
  /// still leave the balls gathered (or those hold fewer than k + 2 points) after this many, the
  /// run stops with an InputError naming the tiles and the keys (tiled_run.cpp, judge_strays;
  /// docs/scale.md, step 3). The 10⁸ wall gathers twice in its one band; the 10⁷ wall with its
  /// coordinates rounded to whole millimetres 11 times (8 until the forty-second session, 2026-11-27, which stopped it).
  int max_gatherings = 32;
  double progress_interval_s = 1.0;  ///< least time between progress calls within a stage [s], 0 to 3600
  /// The tiled scene on disk (scene_io.hpp format 3, LodPyramid::open_stored): every layer in
  /// square tiles and every level of detail stored beside level 0, so that sessions read only the
  /// tiles of their window. auto: when level 0 has more than scene_tiles_above_cells samples.
  Tiled scene_tiles = Tiled::kAuto;
  std::uint64_t scene_tiles_above_cells = 4096ull * 4096ull;  ///< the auto threshold [samples], ≥ 1
  int scene_tile_cells = 256;  ///< tile side of the scene's layer files [samples], a multiple of 16 in [16, 4096]
  /// A tiled scene's previews: drawn from the finest stored level whose longer side is at most
  /// this many samples [samples], 64 to 65536 (level 0 when it fits; else after stage
  /// scene_levels, from that level's files, so a preview holds about this side squared; when
  /// lod.min_cells stops the stored levels above it, the coarsest stored level).
  int preview_max_side = 4096;
};

/// True when a run with `config` writes a tiled scene for a level 0 of `grid` (scale.scene_tiles).
bool writes_tiled_scene(const ScaleConfig& config, const GridGeometry& grid);

struct RunConfig {
  std::filesystem::path source;        ///< the config file it came from ("" when built in code)
  std::string name;                    ///< run name (default: the config file's stem)
  InputConfig input;
  ViewTransform view;
  FilterConfig filters;
  GridConfig grid;
  CrossCheckConfig cross_check;
  LayersConfig layers;
  /// Contact sounds (the optional `audio:` section, issue 7), parsed straight into the audio
  /// module's settings (hc::audio_config; relative clip and label paths resolved); absent = none.
  std::optional<audio::AudioConfig> audio;
  /// The Novint Falcon (`falcon.*`, issue 5), parsed straight into the driver's settings
  /// (hc::falcon_config; the firmware path resolved against the config's folder).
  falcon::FalconConfig falcon;
  LodOptions lod;                      ///< levels of detail and the haptic window (lod.*, issue 4)
  ScaleConfig scale;                   ///< the tiled run (scale.*, issue 14)
  std::string resolved_yaml;           ///< every key with the value used (defaults included)
};

/// Reads and validates a run config. `overrides` are "dotted.key=value" strings (the value is
/// parsed as YAML, so `view.rotation.axis=[0,1,0]` works) applied before validation.
/// Relative input paths are resolved against the config file's folder.
/// @throws hc::ConfigError naming the file, the dotted key, its line (or the --set override),
///         the offending value and the allowed type or range; also for unknown keys.
/// @throws hc::InputError if the file is missing or not valid YAML (with line and column).
RunConfig load_run_config(const std::filesystem::path& path,
                          const std::vector<std::string>& overrides = {});

/// The same from YAML text (used by tests); `origin` names it in messages and is the base for
/// relative paths (its parent folder).
RunConfig parse_run_config(const std::string& yaml_text, const std::filesystem::path& origin,
                           const std::vector<std::string>& overrides = {});

}  // namespace hc::pipeline
