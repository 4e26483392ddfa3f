#include "hc/session/scene_source.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/tiling.hpp"
#include "hc/session/level_timing.hpp"

namespace hc::session {
namespace fs = std::filesystem;

bool is_run_config(const fs::path& input) {
  std::error_code ec;
  return fs::is_regular_file(input, ec) && (input.extension() == ".yaml" || input.extension() == ".yml");
}

OpenedScene open_scene_or_config(const fs::path& input, const SceneSourceOptions& options) {
  OpenedScene out;
  std::error_code ec;
  if (is_run_config(input)) {
    pipeline::RunConfig config = pipeline::load_run_config(input);
    if (options.lod_report) config.lod.report = *options.lod_report;
    if (!options.run_dir.empty()) pipeline::check_output_target(options.run_dir, options.existing);
    // As run_pipeline: a tiled run hands the levels table a sample, so the table does not keep it in core.
    const bool cloud_for_levels = !options.run_dir.empty() && config.lod.report && config.lod.report_cross_check &&
                                  !pipeline::runs_tiled(config);
    pipeline::BuiltScene built = pipeline::build_scene(config, options.keep_cloud || cloud_for_levels, options.progress);
    if (!options.run_dir.empty()) {
      pipeline::write_run(built, config, options.run_dir, options.progress, options.existing, servo_level_timing());
    }
    out.scene = std::move(built.scene);
    if (options.keep_cloud) out.cloud = std::move(built.cloud);
    out.description = config.name;
    out.config = std::move(config);
    return out;
  }
  if (fs::is_directory(input, ec) && fs::exists(input / "scene.yaml", ec)) {
    out.description = "scene " + input.string();
    if (options.open_stored_levels) {
      Scene header = pipeline::load_scene(input, false);
      if (header.storage.stores_levels()) {
        pipeline::LodOptions lod = header.lod;
        if (options.stored_window_cells != 0 && options.stored_window_cells != lod.window_cells) {
          out.notes.push_back("the stored levels' mu_d was computed for a window of " +
                              std::to_string(lod.window_cells) + " samples; a window of " +
                              std::to_string(options.stored_window_cells) +
                              " changes the window only (run the scene again with lod.window_cells=" +
                              std::to_string(options.stored_window_cells) + " for its own friction scale)");
          lod.window_cells = options.stored_window_cells;
        }
        out.stored_levels = pipeline::LodPyramid::open_stored(input, lod);
        out.scene = std::move(header);
        return out;
      }
    }
    out.scene = pipeline::load_scene(input);
    out.description = "scene " + input.string();
    return out;
  }
  throw InputError("'" + input.string() +
                   "' is neither a scene folder (with scene.yaml) nor a run config (.yaml); make a scene with "
                   "`hapticloud run CONFIG`, or pass the config itself");
}

}  // namespace hc::session
