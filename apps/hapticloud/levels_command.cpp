/// `hapticloud levels SCENE`: speed against error per level of detail. Builds every level of the
/// scene's pyramid and prints, per level: cell size, size, build time, cross-check RMS and p95
/// against the original points (found through the scene's provenance), the servo's per-tick
/// cost on a window of the level and the time to switch to it. A tiled scene that stores its
/// levels (scale.scene_tiles) is read as stored, a window at a time (lod_report.hpp).

#include "commands.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/lod_report.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/session/level_timing.hpp"

#include <CLI/CLI.hpp>

#include <cstdint>
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

/// The points of the scene's scan for the cross-check: from --config, else from the run config
/// its provenance names (config_file, as given when the scene was made). The scan files must be
/// the ones the scene was made from (SHA-256 compared with the provenance).
/// @throws hc::InputError naming the config or the scan that is missing or changed.
pipeline::Cloud scene_points(const Scene& scene, const std::string& config_option) {
  const fs::path config_file = config_option.empty() ? fs::path(scene.provenance.config_file) : fs::path(config_option);
  if (config_file.empty() || !fs::is_regular_file(config_file)) {
    throw InputError("levels: the run config '" + config_file.string() +
                     "' the scene was made from is not found from this folder; give it with --config, run from the "
                     "folder the scene was made in, or pass --no-cross-check");
  }
  const pipeline::RunConfig config = pipeline::load_run_config(config_file);
  std::vector<std::string> inputs;
  for (const auto& f : config.input.files) inputs.push_back(f.string());
  if (config.input.conf) inputs.push_back(config.input.conf->string());
  // A scan too large to read whole is refused before its checksum and read take minutes.
  pipeline::check_in_core_fits(config, pipeline::memory_limit_bytes(),
                               config_option.empty()
                                   ? std::string("the scene stores no points sample (points_sample.bin: a tiled run's "
                                                 "scenes do); pass --no-cross-check")
                                   : std::string("leave --config out to cross-check against the points sample the scene "
                                                 "of a tiled run stores (points_sample.bin), or pass --no-cross-check"));
  for (const std::string& f : inputs) {
    if (!fs::exists(f)) throw InputError("levels: the scan '" + f + "' of " + config_file.string() + " does not exist");
    const std::string sum = pipeline::sha256_file(f);
    for (const SceneInput& in : scene.provenance.inputs) {
      if (fs::path(in.file).filename() == fs::path(f).filename() && !in.sha256.empty() && in.sha256 != sum) {
        throw InputError("levels: the scan '" + f + "' changed since the scene was made (sha256 " + sum.substr(0, 16) +
                         "… against " + in.sha256.substr(0, 16) + "… in scene.yaml); give the right config with "
                         "--config or pass --no-cross-check");
      }
    }
  }
  std::cout << "levels: reading the scene's points for the cross-check from " << config_file.string() << " ...\n"
            << std::flush;
  pipeline::Cloud points = pipeline::prepare_points(config);
  std::cout << "levels: " << points.size() << " points\n";
  return points;
}

void run_levels(const LevelsOptions& o) {
  // A batch over every level: freed heap kept for reuse (commands.hpp). The table's windows of a
  // stored level (up to 1025² samples, 28 MB with every layer) are read and dropped one after
  // another; with the C library's dynamic thresholds each was faulted in and zeroed afresh (the
  // 65 536 × 32 768 scene: 40 s of system time in a 66 s table, 3 s with the policy).
  keep_freed_memory_for_reuse();
  const fs::path dir(o.scene);
  // A tiled scene that stores its levels (issue 14) is opened as such: no level is built, and a
  // level larger than the table's window is read a window at a time (level_table).
  Scene scene = pipeline::load_scene(dir, false);
  const bool stored = scene.storage.stores_levels();
  if (stored && o.min_cells > 0) {
    throw ConfigError("levels --min-cells " + std::to_string(o.min_cells) + ": " + dir.string() + " stores its " +
                      std::to_string(scene.storage.stored_levels) + " levels, which the table reads as they are "
                      "(leave --min-cells out)");
  }
  // Levels ≥ 1 get the layers the scene's own options make (its typed metadata).
  pipeline::LodOptions lod = scene.lod;
  if (o.min_cells > 0) lod.min_cells = o.min_cells;
  if (o.window_cells > 0) lod.window_cells = o.window_cells;
  std::shared_ptr<pipeline::LodPyramid> pyramid;  // a stored one now (scene.yaml and directories only)
  if (stored) pyramid = pipeline::LodPyramid::open_stored(dir, lod);
  if (stored && !o.previews.empty()) {
    // Previews draw whole levels, which a stored pyramid reads only when they fit its budget
    // (LodPyramid::level): refused before the long table.
    for (int level = 0; level < pyramid->level_count(); ++level) {
      const GridGeometry& g = pyramid->geometry(level);
      const std::size_t bytes = g.cell_count() * pyramid->stored_bytes_per_sample();
      if (bytes > pyramid->entry_budget_bytes()) {
        throw ConfigError("levels --previews: level " + std::to_string(level) + " of " + dir.string() + " (" +
                          std::to_string(g.cols) + " x " + std::to_string(g.rows) + " samples, " +
                          std::to_string(bytes >> 20) + " MiB with its layers) is larger than the " +
                          std::to_string(pyramid->entry_budget_bytes() >> 20) + " MiB the scene's lod.memory_budget_mb "
                          "lets a whole level hold, and previews draw whole levels: leave --previews out (the run's "
                          "own previews are in its previews/ folder)");
      }
    }
  }
  if (!o.previews.empty()) {
    // Made before the (long) level table, so an unusable folder stops the command at once.
    std::error_code ec;
    fs::create_directories(o.previews, ec);
    if (ec || !fs::is_directory(o.previews)) {
      throw InputError("levels: --previews '" + o.previews + "': cannot create the folder" +
                       (ec ? ": " + ec.message() : std::string(" (a file of that name exists)")));
    }
  }
  if (!stored) scene = pipeline::load_scene(dir);
  const pipeline::SurfaceLayerOptions layer_options = scene.layer_options;
  std::optional<pipeline::Cloud> points;
  std::uint64_t points_represent = 0;
  if (!o.no_cross_check) {
    // The sample of its points a tiled scene, or a scene of a tiled run, stores
    // (points_sample.bin), unless --config asks for the scan: no scan read again, bounded
    // memory (issue 14).
    std::optional<pipeline::LevelPointSample> sample;
    if (o.config.empty()) sample = pipeline::read_level_point_sample(dir);
    if (sample) {
      std::cout << "levels: the cross-check's points: the " << sample->points.size() << " of " << sample->represents
                << " filtered points stored with the scene (" << pipeline::kLevelPointSampleFile
                << "; --config RUN.yaml reads the scan instead)\n";
      points_represent = sample->represents;  // every point: the whole set (level_table)
      points = std::move(sample->points);
    } else {
      points = scene_points(scene, o.config);
    }
  }
  if (!stored) pyramid = pipeline::LodPyramid::from_scene(std::move(scene), layer_options, lod);
  if (stored) {
    std::cout << "levels: " << dir.string() << " stores its levels: read as stored (a large level a window at a "
                 "time), not built\n";
  }
  pipeline::LevelTableOptions to;
  to.cross_check = points.has_value();
  to.sample_points = lod.report_sample_points;  // the scene's own (lod.report_sample_points)
  to.points_represent = points_represent;       // a stored sample of more points: (a) from it, no support
  auto rows = pipeline::level_table(pyramid, points ? &*points : nullptr, to);
  session::time_levels(pyramid, rows, o.ticks);
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
                  "Run config to read the points from (default: the points sample a tiled scene or a tiled run's scene stores, "
                  "points_sample.bin; without one, the run config named in scene.yaml's provenance)");
  cmd->add_flag("--no-cross-check", opts->no_cross_check, "Skip the cross-check (no points needed)");
  cmd->add_option("--previews", opts->previews, "Write a hillshade per level and all side by side into this folder");
  cmd->add_option("--min-cells", opts->min_cells, "Override lod.min_cells")->check(CLI::Range(2, 65536));
  cmd->add_option("--window-cells,--window", opts->window_cells, "Override lod.window_cells (haptic window side [samples])")
      ->check(CLI::Range(2, 4096));
  cmd->add_option("--ticks", opts->ticks, "Servo ticks timed per level")->capture_default_str()->check(CLI::Range(10, 10000000));
  cmd->callback([opts] { run_levels(*opts); });
}

}  // namespace hc::app
