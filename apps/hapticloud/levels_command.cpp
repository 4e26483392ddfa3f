/// `hapticloud levels SCENE`: speed against error per level of detail. Builds every level of the
/// scene's pyramid and prints, per level: cell size, size, build time, cross-check RMS and p95
/// against the original points (found through the scene's provenance), the servo's per-tick
/// cost on a window of the level and the time to switch to it.

#include "commands.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/lod_report.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <CLI/CLI.hpp>

#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <string>

namespace hc::app {
namespace {

namespace fs = std::filesystem;

struct LevelsOptions {
  std::string scene;
  std::string config;
  bool no_cross_check = false;
  std::string previews;
  int min_cells = 0;
  int window_cells = 0;
  int ticks = 3000;
};

void run_levels(const LevelsOptions& o) {
  const fs::path dir(o.scene);
  if (!o.previews.empty()) {
    // Made before the (long) level table, so an unusable folder stops the command at once.
    std::error_code ec;
    fs::create_directories(o.previews, ec);
    if (ec || !fs::is_directory(o.previews)) {
      throw InputError("levels: --previews '" + o.previews + "': cannot create the folder" +
                       (ec ? ": " + ec.message() : std::string(" (a file of that name exists)")));
    }
  }
  pipeline::Scene scene = pipeline::load_scene(dir);
  pipeline::SurfaceLayerOptions layer_options;
  pipeline::LodOptions lod;
  pipeline::scene_options(scene, layer_options, lod);
  if (o.min_cells > 0) lod.min_cells = o.min_cells;
  if (o.window_cells > 0) lod.window_cells = o.window_cells;
  std::optional<pipeline::Cloud> points;
  if (!o.no_cross_check) {
    std::cout << "levels: reading the scene's points for the cross-check ...\n" << std::flush;
    points = pipeline::scene_points(scene, o.config.empty() ? std::nullopt : std::optional<fs::path>(o.config));
    std::cout << "levels: " << points->size() << " points\n";
  }
  const auto pyramid = pipeline::LodPyramid::from_scene(std::move(scene), layer_options, lod);
  pipeline::LevelTableOptions to;
  to.cross_check = points.has_value();
  to.ticks = o.ticks;
  const auto rows = pipeline::level_table(pyramid, points ? &*points : nullptr, to);
  std::cout << "levels of " << dir.string() << " (window " << lod.window_cells << " samples; switch = request to "
            << "first tick on the new window, level cached, as fast as possible):\n"
            << pipeline::level_table_text(rows);
  if (!o.previews.empty()) {
    const fs::path out(o.previews);
    const auto names = pipeline::write_level_previews(*pyramid, out);
    std::cout << "levels: previews in " << out.string() << " (" << names.back() << ": all levels side by side)\n";
  }
}

}  // namespace

void add_levels_command(CLI::App& app) {
  auto opts = std::make_shared<LevelsOptions>();
  CLI::App* cmd = app.add_subcommand("levels", "Speed against error per level of detail of a scene (build time, "
                                               "cross-check, per-tick cost, switch time).");
  cmd->add_option("SCENE", opts->scene, "Scene folder written by `hapticloud run`")->required();
  cmd->add_option("--config", opts->config,
                  "Run config to read the points from (default: the one stored in scene.yaml)");
  cmd->add_flag("--no-cross-check", opts->no_cross_check, "Skip the cross-check (no points needed)");
  cmd->add_option("--previews", opts->previews, "Write a hillshade per level and all side by side into this folder");
  cmd->add_option("--min-cells", opts->min_cells, "Override lod.min_cells");
  cmd->add_option("--window-cells,--window", opts->window_cells, "Override lod.window_cells (haptic window side [samples])");
  cmd->add_option("--ticks", opts->ticks, "Servo ticks timed per level")->capture_default_str();
  cmd->callback([opts] { run_levels(*opts); });
}

}  // namespace hc::app
