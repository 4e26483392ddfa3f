#pragma once
/// @file scene_io.hpp
/// The scene on disk: the one data contract between the offline pipeline and the online
/// renderer. A folder holding one 32-bit float TIFF per layer (metres or [-], NaN = no data,
/// row 0 = smallest y) and `scene.yaml` (format version, grid geometry, frame, provenance).

#include "hc/common/height_field.hpp"
#include "hc/common/scene.hpp"

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace hc::pipeline {

/// Format written by write_scene for whole-grid layers. Version 1 (before the typed scene) still loads.
inline constexpr int kSceneFormatVersion = 2;
/// Format written by write_scene with tiles (SceneStorage::tile_cells > 0): the layer TIFFs are
/// tiled, the colour is a tiled RGB TIFF (`colour.tiff`) and scene.yaml has a `storage` map
/// (tile_cells, stored_levels, levels_folder). Readers of format 2 refuse it by its number.
inline constexpr int kTiledSceneFormatVersion = 3;
/// The folder of a tiled scene holding levels k ≥ 1: `<scene>/levels/L<k>/<layer>.tiff`.
inline constexpr const char* kSceneLevelsFolder = "levels";

/// The scene type is hc::Scene (hc/common/scene.hpp); the pipeline names it too.
using hc::Scene;

/// Writes `scene` into the folder `scene_dir` (created; must not exist yet, its parent must): one 32-bit float
/// TIFF per present layer (`<name>.tiff`: depth, envelope, texture, mu_d, mu_s, cell_error,
/// region_id, intensity; TIFF row 0 = grid row 0 = smallest y), `flags.png` (8-bit CellFlag
/// codes) and `colour.png` (RGB, 8 bit) when present, and `scene.yaml` (format_version 2): grid
/// geometry, the model→grid frame, the layer list, friction model, layer_options, lod and
/// provenance as typed keys, and the resolved config under `resolved_config` (for the record).
/// Callers make the write atomic by writing into a temporary folder (see StagingDir).
/// @throws hc::InputError if the folder exists, its parent does not, or a file cannot be written (names it and the
///         reason); std::invalid_argument if a layer's geometry differs from scene.geometry or
///         the depth layer is empty.
///
/// With `storage.tile_cells` > 0 (a multiple of 16, 16..4096) every float layer is a tiled TIFF
/// (square tiles of that side; tiles of no data only are stored without bytes), the colour is
/// `colour.tiff` (tiled RGB), the flags stay `flags.png`, format_version is 3 and scene.yaml
/// records `storage` (tile_cells and stored_levels: how many levels build_stored_levels,
/// level_builder.hpp, will put beside level 0; the caller makes them). @throws std::invalid_argument also for a
/// tile side that is not a multiple of 16 in [16, 4096], or stored_levels < 0.
void write_scene(const Scene& scene, const std::filesystem::path& scene_dir, const SceneStorage& storage = {});

/// Lists level 0's surface layers (envelope, texture, mu_d, mu_s: `<name>.tiff` beside
/// depth.tiff) in scene.yaml of the tiled scene folder `scene_dir`, after they were written there
/// following write_scene (issue 14: build_stored_levels with Level0Layers::kSceneFolder, for a run
/// that kept none in memory). scene.yaml is written again from what it held (the other layers,
/// flags, colour, options, provenance and the resolved config's text unchanged), with
/// `friction_model` set to layer_options' when it was absent, through a temporary file renamed
/// over it (no half-written scene.yaml is ever seen or left). @throws hc::InputError naming the
/// file: not a tiled scene (format 3), one of the four files missing, scene.yaml unreadable or
/// malformed, or it cannot be replaced.
void add_level0_surface_layers(const std::filesystem::path& scene_dir);

/// Writes a tiled scene folder (format 3, as write_scene with tiles and build_stored_levels) tile
/// by tile, for a scene larger than memory (issue 14): a generator or a streaming level builder
/// hands over one tile of one layer of one level at a time, in any order. Every layer file of
/// every level is open from construction to finish(): memory is about one tile per open file
/// (libtiff's write buffer: 256 KB per file at 256-sample float tiles) plus the files' tile
/// indices. Tiles never written are no data (sparse: NaN, or
/// colour 0). Level k's geometry is lod_level_geometry(level 0, k) (lod.hpp), so
/// LodPyramid::open_stored reads the folder. Not thread-safe.
class TiledSceneWriter {
 public:
  /// What the folder holds besides depth.
  struct Contents {
    bool surface_layers = true;  ///< envelope, texture, mu_d, mu_s
    bool cell_error = false;
    bool colour = false;         ///< colour.tiff (8-bit RGB)
  };
  /// Creates `scene_dir` (it must not exist; its parent must) and every layer file of every
  /// level. `header`: level 0's geometry, the frame, friction model, options and provenance (its
  /// layers are ignored). `storage`: tile_cells a multiple of 16 in [16, 4096]; stored_levels ≥ 1
  /// and no more than the levels whose longer side keeps ≥ 2 samples.
  /// @throws std::invalid_argument for a bad storage; hc::InputError naming a file or folder that
  ///         cannot be made.
  TiledSceneWriter(const std::filesystem::path& scene_dir, const Scene& header, const SceneStorage& storage,
                   const Contents& contents);
  ~TiledSceneWriter();
  TiledSceneWriter(const TiledSceneWriter&) = delete;
  TiledSceneWriter& operator=(const TiledSceneWriter&) = delete;

  /// Geometry of stored level L (grid frame). @throws std::out_of_range for L out of range.
  const GridGeometry& level_geometry(int level) const;
  int tile_cells() const noexcept;
  /// Writes tile (tile_row, tile_col) of `layer` ("depth", "envelope", "texture", "mu_d", "mu_s",
  /// "cell_error": tile_cells² floats [m or -], row-major, NaN = no data; "colour": tile_cells²·3
  /// bytes) of level `level`. Samples past the level's edge are ignored. An all-NaN float tile is
  /// stored without bytes. @throws std::invalid_argument for a layer the writer does not hold, a
  /// tile outside the level or a call after finish(); std::out_of_range for a level not stored;
  /// hc::InputError naming the file on a write error.
  void write_tile(int level, const std::string& layer, int tile_row, int tile_col, const void* data);
  /// Closes every layer file and writes scene.yaml last (a folder without it is not a scene).
  /// @return bytes of tile data written. @throws hc::InputError naming a file on a write error.
  std::uint64_t finish();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Name of the marker file every output folder written through StagingDir holds: it tells a
/// later run that the folder is hapticloud's own output and may be replaced.
inline constexpr const char* kOutputMarkerFile = ".hapticloud-output";

/// What StagingDir may do with an existing target that is not an earlier hapticloud output.
enum class ExistingOutput {
  kRefuse,    ///< refuse (default): a file, or a non-empty folder without the marker
  kMoveAside  ///< `--force`: keep it as `<target>.replaced-<time>` (never deleted)
};

/// A temporary sibling folder `<target>.partial-<pid>[-k]` that replaces `target` only on
/// commit(): a failed run (an exception, a crash) never leaves a half-written `target`, and an
/// existing `target` from an earlier run is only removed once the new one is complete.
/// Never deletes what hapticloud did not write: an existing `target` is replaced only if it is
/// an empty folder or an earlier output (it holds kOutputMarkerFile, or it is a pre-marker run
/// folder: only scene/, previews/, report.md, report.json with scene/scene.yaml present);
/// anything else is refused, or with ExistingOutput::kMoveAside renamed aside and kept.
/// Stale siblings `<target>.partial-<pid>` and `<target>.old-<pid>` left by a process that no
/// longer runs (a crash, a kill -9) are removed when they hold the output marker.
class StagingDir {
 public:
  /// @throws hc::InputError if `target` is a file or a foreign non-empty folder (kRefuse; the
  ///         message names it and suggests --force) or the staging folder cannot be created.
  explicit StagingDir(std::filesystem::path target, ExistingOutput existing = ExistingOutput::kRefuse);
  ~StagingDir();  ///< removes the staging folder unless committed
  StagingDir(const StagingDir&) = delete;
  StagingDir& operator=(const StagingDir&) = delete;

  const std::filesystem::path& path() const { return staging_; }
  const std::filesystem::path& target() const { return target_; }
  /// Where a foreign target was moved by commit() (kMoveAside), else empty.
  const std::filesystem::path& moved_aside() const { return moved_aside_; }
  /// Renames staging → target (an earlier output is moved aside first, then removed; a foreign
  /// target, allowed by kMoveAside, is moved aside and kept).
  /// @throws hc::InputError naming both paths if a rename fails.
  void commit();

 private:
  std::filesystem::path target_;
  std::filesystem::path staging_;
  std::filesystem::path moved_aside_;
  bool target_is_foreign_ = false;
  bool committed_ = false;
};

/// Refuses an output target as StagingDir would, without creating anything: a file or a
/// non-empty folder that is not an earlier output, unless `existing` is kMoveAside.
/// @return true if the target exists and is foreign (it will be moved aside).
/// @throws hc::InputError naming the target and suggesting --force.
bool check_output_target(const std::filesystem::path& target, ExistingOutput existing);

/// Removes the staging folders of every StagingDir alive in this process, the scratch folders
/// and files registered with register_live_scratch_dir, and the entries registered with
/// register_live_scratch_entries (for a signal watcher thread: SIGINT/SIGTERM during a run, a
/// tile plan or a tile job must not leave `<out>.partial-<pid>`, spill files or temporary files
/// behind). A folder is first renamed aside (a fresh `<folder>.removing-<pid>`
/// name), so that a writer's next file in it fails to open.
/// `final` (the watcher, which then _exit()s): the registry's lock is never released again, so
/// every later register_*, unregister_*, open_live_scratch_file and rename_live_scratch waits
/// until the process ends: nothing is created or renamed into place after the clean-up.
/// Not async-signal-safe: call it from a normal thread (sigwait), not from a signal handler.
/// @return how many registrations were acted on. Never throws.
int remove_live_staging_dirs(bool final = false) noexcept;

/// Registers `path`, a scratch folder or file this process owns whole, before it exists (the
/// tiled run's `hapticloud-tiles-*` spill folder under scale.scratch, a tile job's temporary
/// kept files, a write_atomically temporary, the cross-check's residual file),
/// for remove_live_staging_dirs; unregister_live_scratch_dir before removing it, and move it
/// with rename_live_scratch. A trailing separator is ignored. @throws std::bad_alloc only.
void register_live_scratch_dir(const std::filesystem::path& path);
/// Undoes register_live_scratch_dir (nothing when `path` is not registered). Never throws
/// (waits for the process to end once a final clean-up has begun).
void unregister_live_scratch_dir(const std::filesystem::path& path) noexcept;

/// A scratch file of this process's, registered for the signal clean-up while this lives
/// (register_live_scratch_dir, before the file exists) and removed when it goes, whatever
/// happened (nothing is removed once rename_live_scratch has moved it to its final name).
/// Users: a tile job's temporary kept file, write_atomically's temporary, the cross-check's
/// residual file. @throws std::bad_alloc only.
class LiveScratchFile {
 public:
  explicit LiveScratchFile(std::filesystem::path file);
  ~LiveScratchFile();  ///< unregisters, then removes the file (errors ignored)
  LiveScratchFile(const LiveScratchFile&) = delete;
  LiveScratchFile& operator=(const LiveScratchFile&) = delete;
  const std::filesystem::path& path() const { return file_; }

 private:
  std::filesystem::path file_;
};

/// std::fopen(file, mode) under the registry's lock: a scratch file (one registered, or an entry
/// of registered prefix) is never created after a final clean-up has scanned for it (the call
/// then waits for the process to end). What is written to it afterwards through the FILE*
/// goes to a removed file. @return fopen's result (nullptr and errno on failure).
std::FILE* open_live_scratch_file(const std::filesystem::path& file, const char* mode);

/// Unregisters `from` (register_live_scratch_dir) and renames it to `to` under the registry's
/// lock, so that a final clean-up never races with the rename (once one has begun this waits
/// for the process to end). `ec` gets the rename's error. Never throws (but std::bad_alloc).
void rename_live_scratch(const std::filesystem::path& from, const std::filesystem::path& to, std::error_code& ec);

/// Registers the entries of folder `dir` (not the folder: it may be the user's) whose names
/// start with one of `prefixes`, for remove_live_staging_dirs: `hapticloud tile-plan` into a
/// folder that existed (empty) registers its own files (`tile_`, `plan.json`, `.plan.json`).
/// A second call for the same `dir` replaces the prefixes. @throws std::bad_alloc only.
void register_live_scratch_entries(const std::filesystem::path& dir, const std::vector<std::string>& prefixes);
/// Undoes register_live_scratch_entries for `dir`. Never throws.
void unregister_live_scratch_entries(const std::filesystem::path& dir) noexcept;

/// True if `dir` is an output folder hapticloud wrote (see StagingDir). Never throws.
bool is_hapticloud_output(const std::filesystem::path& dir);

/// Loads a scene folder written by `hapticloud run` (format_version 2, or 1: then the layer
/// and LoD options were not recorded as typed keys, defaults are assumed and a note says so).
/// Scene::loaded_from is set to `scene_dir`.
/// @throws hc::InputError naming the folder or file when scene.yaml or a layer is missing or
///         malformed, the format version is unknown, or a layer's size disagrees with the geometry.
///
/// Format 3 (tiled) loads the same way (every tile read). With `layers` false only scene.yaml
/// is read: geometry, frame, friction model, options, provenance and `storage`, no layer (for
/// LodPyramid::open_stored, which reads tiles on demand); the files scene.yaml lists must still
/// exist.
Scene load_scene(const std::filesystem::path& scene_dir, bool layers = true);

}  // namespace hc::pipeline
