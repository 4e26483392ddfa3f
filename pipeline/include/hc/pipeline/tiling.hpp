#pragma once
/// @file tiling.hpp
/// The streaming tiled run (issue 14): a scan larger than memory should hold is read in chunks
/// (point_stream.hpp) and gridded tile by tile, each tile with a halo, so that memory is bounded
/// by the grid, one tile's points and one chunk, not by the cloud.
///
/// Passes (docs/scale.md):
///  1. plan: stream the input twice, (a) the x-y-z box of the finite points in file units (the
///     recentring offset, as to_metres_and_recentre takes it; the stored-precision figures), (b)
///     every point through units, recentring, view transform, non-finite and crop, exactly as the
///     in-core stages compute them: the grid's box (the geometry reproject would make) and, for
///     grid.upsample: auto, the node coverage at every upsample factor (UpsampleCoverage); on a
///     scan of at least 4 points per grid node the coverage is left to the spill, which takes it
///     as it writes the tiles cut for factor 1, and spills again only when it finds another
///     factor or a smaller tile side (docs/scale.md);
///  2. spill: stream a third time and write each point (x y z as double in the grid frame,
///     colour and intensity when the scan has them, in the input's order) to the spill file of every
///     tile whose window (the tile plus its halo) holds its grid node;
///  3. per tile, in order: read its points (file order), the robust outlier filter and the
///     isolated-point filter when enabled, reproject the tile's window, despike and reproject
///     again when enabled; copy the tile's interior into the grid; keep the filtered points;
///  4. on the whole grid, as in core: corrugation, hole fill, surface layers;
///  5. the kd-tree cross-check, per tile over its kept points (interior points for (a), interior
///     cells for (b)), merged exactly: counts, maxima and the nearest-rank percentiles by a
///     two-pass radix selection over the float values (a second read of the kept points).
/// A file that is not streamed natively (point_stream.hpp) is read whole at every pass.
/// Spill files live in a fresh folder under scale.scratch (default: the system's temporary
/// folder), removed when the run ends or fails; their peak size is reported (tile_spill stage).
///
/// What equals the in-core run: with filters.outliers disabled, the depth, flags, colour,
/// intensity, texture, friction and cross-check (a) figures are identical bit for bit, for
/// every splat mode (interpolating splats sum each cell's heights relative to its own disc's
/// first measured cell since 2026-11-30; before, to the window's, and agreed to float rounding
/// only; the halo's grid share is at least
/// reproject_reach_cells, 2 × it plus the despike's reads of the grid with the despike on, so
/// every node of a tile's interior sees every point it depends on, in file order, with the
/// whole scan's verdict; with scale.filter_halo_cells auto the decided region adds the
/// isolated filter's radius, whose counts then see only checked robust verdicts, and holds the
/// despike's count searches about the points within the grid stages' reach); (b)'s error map,
/// its percentiles and the supported fraction too (each tile searches in the whole grid's float
/// frame, at its sample positions: detail::CellErrorFrame; since 2026-11-30, before to float
/// rounding), and the RMS figures to the last bits (summed in another order).
/// With the robust outlier filter, the scale is the whole scan's (stage tile_scale) and far
/// clusters are found over the whole scan on coarse cells (stage tile_far_clusters; the grid is
/// then laid out and spilled again without them). What does not yet equal the in-core run: each
/// tile's k-NN searches are cut at the halo (points whose searches leave it are judged again),
/// far clusters joined to the main body only through others are kept, and the grid's box and upsample factor are those of the points before filtering (in core:
/// after). The honest cross-check runs tile by tile (check_input with an InputCheckScope: each
/// tile's input points as spilled and its kept points against the whole grid over its window; the
/// spacing is the robust sample's as in core, or without the robust filter the tiles' median
/// weighted by points, where the isolated count may differ by a few), then the verdict as in core; points dropped before the
/// spill (non-finite, crop) count as removed without a class. The levels table's support column
/// is missing (no cloud: a sample instead).
/// Several files are read as one scan with input.shared_frame (open_point_streams).
/// Not supported (tiled: on is an error naming the key): input.conf, several files without
/// input.shared_frame, input.synthetic, filters.voxel_m, filters.pcl, filters.outliers other than robust,
/// grid.organised: mesh, meshes.

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/run.hpp"

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace hc::pipeline {

/// A tile's window could not decide whether a group of at most cross_check.island_max_cells
/// valid cells near its interior is an island of the despike (honest_check.hpp, window_islands):
/// the group runs on past the window's cells that are the whole grid's. A ConfigError whose
/// message names the stage, a grid cell of the group (row, col), scale.island_halo and
/// cross_check.island_max_cells. build_scene_tiled under scale.island_halo: auto catches it and
/// starts again with the key on; a tile job (run_tile_jobs) cannot widen its plan's halo, and
/// `hapticloud tile-job` exits 5 for it under auto, so that the Dask driver plans again with the
/// key on (docs/scale.md, "Islands in a tile's window"). Source: this project.
class UndecidedIslandsError : public ConfigError {
 public:
  UndecidedIslandsError(const std::string& what, std::size_t t, int now, int then, bool auto_key)
      : ConfigError(what), tile(t), halo_now(now), halo_then(then), under_auto(auto_key) {}
  std::size_t tile;  ///< the tile whose window met the group
  int halo_now;      ///< the plan's halo [grid nodes]
  int halo_then;     ///< the halo with scale.island_halo on [grid nodes]
  bool under_auto;   ///< the config's scale.island_halo is auto (not false)
};

/// Thrown by merge_tile_jobs (`hapticloud tile-merge` exits 6 for it) where the outlier filters or
/// the despike removed a point that set the x-y box of the plan's grid, so that the in-core run
/// lays its grid on another box (scale.grid_on_kept_points; build_scene_tiled starts again in
/// process there). The merge wrote that box to `box_file` (WORK/grid_box.json: the kept points'
/// x-y bounds in the grid frame [m], the despike's removed points where it set the box) and no
/// scene. write_tile_plan with box_file makes the plan whose jobs and merge give the in-core
/// grid (at most three plans on grid boxes counting the first, as the in-process run's three
/// attempts: a merge of a plan that had a box marks the box it writes `last`). Source: this project.
class GridBoxError : public Error {
 public:
  GridBoxError(const std::string& what, std::filesystem::path file) : Error(what), box_file(std::move(file)) {}
  std::filesystem::path box_file;  ///< the box for the next plan (tile-plan --grid-box)
};

/// The points of config.input's files counted without reading them, as scale.tiled: auto counts
/// them: each file natively streamed (point_stream.hpp) by its header or first-look count (a
/// gzipped LAS, LAZ or E57 by its header's or XML section's); nullopt for a synthetic input, a
/// .conf, no file, or a file not counted so (a mesh, another format, a file that does not open:
/// the in-core read reports it). With `headers_only`, also nullopt where counting costs a pass
/// over a file (text formats, gzipped ones but LAS and LAZ) or the header overcounts what the read
/// keeps (LAS and LAZ whose input.las_drop_classes name classes other than the noise ones, 7
/// and 18). Throws nothing the in-core read would not.
std::optional<std::uint64_t> counted_input_points(const RunConfig& config, bool headers_only = false);

/// The first option of `config` the tiled run does not support, as "<key> <why>" (e.g.
/// "filters.voxel_m is > 0"; scale.tiled: on refuses it naming it), or "" when it takes them
/// all. Throws nothing.
std::string tiled_run_refusal(const RunConfig& config);

/// Whether build_scene runs `config` tiled: scale.tiled on, or auto and the input is one natively
/// streamed file (point_stream.hpp), or several with input.shared_frame, of more than
/// scale.tiled_above_points points in all (each file's header or first-look count).
/// @throws what opening the input throws (auto only); hc::ConfigError for tiled: on with an
///         option the tiled run does not support (the message names the key).
bool runs_tiled(const RunConfig& config);

/// The tiled run (see the file comment): the same BuiltScene build_scene gives, without the
/// cloud (a strided sample of it instead, BuiltScene::point_sample, when the cross-check is on
/// or the config's levels table cross-checks); the report has stages tile_plan,
/// tile_spill (spill_bytes_peak_mb, tiles, halo_cells) and tiles (per-tile sums), then the
/// in-core stages from corrugation on (the honest_check stage tile by tile). With the cross-check
/// or the levels sample on, the input's spill files stay on disk until the kept points have been
/// read through them and the honest check has read them (the spill peak is then the input's
/// files and the kept-point masks, a byte a record, together).
/// Under scale.island_halo: auto, a tile whose window cannot decide an island group makes the
/// run start again from the plan with the key on (up to twice the time; a warning in the
/// summary and in tile_plan's notes says so); under false it throws UndecidedIslandsError.
/// @throws hc::ConfigError as runs_tiled, and UndecidedIslandsError (above); hc::InputError for
///         unreadable input or a scratch folder that cannot be written (naming it); what the
///         stages throw.
/// With `layers` SurfaceLayersAt::kSceneLevels (run.hpp) and a scene write_run will store tiled
/// without the levels table, level 0's surface layers are left to write_run's level builder
/// (no stage surface_layers; BuiltScene::surface_layers_at says which happened).
/// Real-time: no. Memory: the grid's layers, one tile's points and one chunk.
BuiltScene build_scene_tiled(const RunConfig& config, const ProgressFn& progress = {},
                             SurfaceLayersAt layers = SurfaceLayersAt::kMemory);

// ---------------------------------------------------------------------------------------------
// Tile jobs in other processes or on other machines (`hapticloud tile-plan`, `tile-job`,
// `tile-merge`; the Dask driver tools/dask/hapticloud-dask). The same three steps
// build_scene_tiled runs in process, with their state in a work folder on storage every process
// sees:
//   WORK/plan.json      the plan (tiles, grid geometry bit for bit as hexadecimal floats, the
//                       robust test's scale, the config's path, --set overrides and resolved YAML,
//                       the plan stages' reports, each spill file's size);
//   WORK/tile_<t>.bin   tile t's spilled points (the spill pass's records);
//   WORK/part_<t>.bin   tile t's result: its interior of the grid and its summed figures
//                       (written last, through a rename: it marks the job done);
//   WORK/kept_<t>.bin   which of tile t's spilled records it kept after the filters (the
//                       cross-check's points): a byte per record of tile_<t>.bin, 0 removed,
//                       1 interior, 2 halo copy; no file when it kept none.
// A tile job reads only plan.json and tile_<t>.bin (and, where the robust test's searches leave
// tile t's window, the spill files of the tiles about it; every spill file's size is checked
// against the plan first) and writes only part_<t>.bin and
// kept_<t>.bin, each through a temporary file and a rename, so a job can be run again (a retry
// after a lost worker) and two attempts of one tile leave one complete result.

/// What write_tile_plan made.
struct TilePlanInfo {
  std::filesystem::path plan_file;  ///< WORK/plan.json
  std::size_t tiles = 0;            ///< tile jobs to run: 0 .. tiles − 1
  std::uintmax_t spill_bytes = 0;   ///< the spill files' total size [bytes]
};

/// `hapticloud tile-plan`: passes 1, 2 and 2b of the tiled run (plan, spill, the robust test's
/// scale) for `config_file` with `overrides` ("dotted.key=value", as load_run_config), into
/// `work_dir` (created; or an existing empty folder), kept for tile jobs. The config is read
/// through its absolute path, so the resolved input paths hold in every process.
/// `grid_box_file` (`--grid-box`; empty: none): the grid box a tile-merge wrote (GridBoxError),
/// on which this plan lays its grid and whose despike removals it takes over; its tile_plan
/// report then says why (figure grid_relaid, notes), as build_scene_tiled's later attempts do.
/// @throws hc::ConfigError as load_run_config, or for an option the tiled run lacks (naming the
///         key), or for a grid box made with a config that resolves to other values outside
///         `scale`; hc::InputError for a work_dir that exists and is not an empty folder,
///         unreadable input, a grid box file that is not as tile-merge writes it (naming the
///         key) or was made from other input files or another recentring, or a write that fails
///         (what the plan wrote is removed again: the folder if it made it, else its tile_*.bin
///         and plan.json).
TilePlanInfo write_tile_plan(const std::filesystem::path& config_file, const std::vector<std::string>& overrides,
                             const std::filesystem::path& work_dir, const ProgressFn& progress = {},
                             const std::filesystem::path& grid_box_file = {});

/// The number of tiles of a plan written by write_tile_plan.
/// @throws hc::InputError for a file that is not such a plan (naming it and the key).
std::size_t tile_plan_tiles(const std::filesystem::path& plan_file);

/// `hapticloud tile-job`: step 3 of the tiled run (filters, reprojection of the tile's window,
/// which of its spilled records it keeps) for each of `tiles`, writing WORK/kept_<t>.bin and
/// WORK/part_<t>.bin.
/// Idempotent: running a tile again gives the same bytes.
/// @throws hc::InputError for a plan that cannot be read, a tile index outside the plan, or a
///         spill file whose size is not the plan's (naming it); hc::ConfigError when the plan's
///         config now resolves to other values than when the plan was made;
///         UndecidedIslandsError where the plan's halo cannot decide an island group.
/// Memory: one tile's points and its window of the grid.
void run_tile_jobs(const std::filesystem::path& plan_file, const std::vector<std::size_t>& tiles);

/// The scene of a plan whose tile jobs have all run, and the config it was made with.
struct MergedTileRun {
  RunConfig config;
  BuiltScene built;
};

/// `hapticloud tile-merge`: gathers every tile's result and runs steps 4 and 5 (the whole grid's
/// layers, the merged cross-check): the BuiltScene build_scene_tiled gives for the same config,
/// bit for bit in its layers and cross-check counts (tests/pipeline/tile_jobs_test.cpp).
/// @throws hc::InputError naming the tiles without a result (a partial scene is never made), a
///         result written for another plan or by another version, truncated, or whose kept file
///         has another size or a byte that is not 0, 1 or 2; a spill file whose size is not the
///         plan's; hc::ConfigError as run_tile_jobs; GridBoxError where the in-core run lays
///         its grid on another box (scale.grid_on_kept_points: the plan's folder then holds
///         grid_box.json for a new plan; nothing else is written).
/// `layers` as build_scene_tiled's.
MergedTileRun merge_tile_jobs(const std::filesystem::path& plan_file, const ProgressFn& progress = {},
                              SurfaceLayersAt layers = SurfaceLayersAt::kMemory);

}  // namespace hc::pipeline
