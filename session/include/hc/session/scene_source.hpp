#pragma once
/// @file scene_source.hpp
/// One way for every session (`touch`, `explore`, `levels`) to get its scene: from a scene folder
/// written by `hapticloud run`, or from a run config whose scene is built in memory (and whose run
/// folder is written for the record). Nothing reads its own output back, nothing parses a run
/// config out of a scene.

#include "hc/common/scene.hpp"
#include "hc/pipeline/cloud.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace hc::session {

struct SceneSourceOptions {
  /// For a run config: the run folder (scene, previews, report) is written here; empty: nothing
  /// is written.
  std::filesystem::path run_dir;
  /// For a run config: keep the filtered cloud (grid frame, metres) in the result.
  bool keep_cloud = false;
  /// For a run config: override its `lod.report` (the levels table of the run report; sessions
  /// that build levels on demand switch it off).
  std::optional<bool> lod_report;
  pipeline::ExistingOutput existing = pipeline::ExistingOutput::kRefuse;
  /// For a tiled scene folder that stores its levels (scene_io.hpp format 3): open them from disk
  /// (pipeline::LodPyramid::open_stored; OpenedScene::stored_levels) and load only the scene's
  /// metadata, not its layers (issue 14: a scene larger than memory). Other inputs load as usual.
  bool open_stored_levels = false;
  /// With open_stored_levels: the haptic window side [samples] of the stored pyramid (0: the
  /// scene's lod.window_cells). The stored μ_d was computed for the scene's own window (its
  /// device scale, docs/friction.md): another side only changes the window, and
  /// OpenedScene::notes says so.
  int stored_window_cells = 0;
  pipeline::ProgressFn progress;
};

/// What was opened.
struct OpenedScene {
  Scene scene;                                ///< typed scene (hc/common/scene.hpp)
  std::optional<pipeline::RunConfig> config;  ///< the run config, when the input was one
  std::optional<pipeline::Cloud> cloud;       ///< the filtered points, grid frame [m], when kept
  std::string description;                    ///< for messages: config name or scene folder name
  /// With SceneSourceOptions::open_stored_levels on a tiled scene: its levels read from disk;
  /// `scene` then holds geometry, frame and metadata but no layer. Else null.
  std::shared_ptr<pipeline::LodPyramid> stored_levels;
  /// What the caller should tell the user about how the input was opened (may be empty).
  std::vector<std::string> notes;
};

/// True if `input` names a run config (a regular file ending in .yaml or .yml).
bool is_run_config(const std::filesystem::path& input);

/// Opens `input`: a scene folder (holding scene.yaml) is loaded (pipeline::load_scene); a run
/// config is loaded (pipeline::load_run_config), its scene built in memory
/// (pipeline::build_scene) and, when options.run_dir is set, its run folder written there
/// (pipeline::write_run, levels table timed by servo_level_timing()).
/// @throws hc::InputError naming `input` when it is neither (and saying how to make a scene);
///         whatever loading, building or writing throws.
OpenedScene open_scene_or_config(const std::filesystem::path& input, const SceneSourceOptions& options = {});

}  // namespace hc::session
