// The tiled scene at the size of a temple survey (issue 14: "opening a 65 536 × 32 768 scene and
// switching to any window takes under 1 s and 500 MB"). Two steps, each its own process, so the
// second's peak memory is the session's alone:
//
//   tiled_scene_bench generate DIR [--rows 32768] [--cols 65536] [--band 4096] [--tile 256] [--colour]
//                              [--min-cells 64] [--window-cells 200]
//     writes DIR/scene (scene format 3) tile by tile through pipeline::TiledSceneWriter: every
//     level of a grid of rows × cols samples of 1 mm, with the relief (a 4 mm sinusoid of 43 mm
//     wavelength plus a 0.2 mm texture of 2.7 mm) and its layers in a band of `band` rows across
//     the middle; the rest is no data and stored as sparse tiles (so that the folder fits on the
//     disk: a full 65 536 × 32 768 scene of five float layers is 57 GB). Every level is the
//     analytic relief sampled at that level's nodes (envelope, texture and μ from their
//     formulas), not a pyramid built from level 0 (for that: --level0-only, then `build`). --colour adds a colour
//     and a cross-check error layer (tests/fuzz/scene_tiled_base was made with it, small).
//     --level0-only writes level 0 alone (scene.yaml still names every level) for `build`.
//   tiled_scene_bench build DIR
//     builds the levels of DIR/scene (made with --level0-only) from level 0 with the streaming
//     level builder (pipeline::build_stored_levels), scratch in DIR/scratch; prints the time per
//     level, the bytes written, the builder's largest buffers and the peak resident memory.
//   tiled_scene_bench open DIR [--switches 300] [--seed 1] [--drop-caches] [--budget-mb M]
//     opens DIR/scene with LodPyramid::open_stored and makes `switches` random requests through
//     session::LodController::set_window (a random level, a window centred in the band): each
//     reads the window's tiles, builds its HapticSurface and publishes it. Prints the open time,
//     the first request's time, the median, p99 and maximum of the others, the tiles read, and
//     the peak resident memory (VmHWM). --drop-caches first asks the kernel to drop the page
//     cache (root only; says whether it did), so the first requests read from the disk.
//
// Figures and the machine: docs/scale.md ("The tiled scene"). Not a test: nothing is asserted.

#include "hc/common/scene.hpp"
#include "hc/haptics/shared_state.hpp"
#include "hc/pipeline/level_builder.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/session/lod_controller.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <numbers>
#include <random>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

/// VmHWM of /proc/self/status [MB].
double peak_rss_mb() {
  std::ifstream in("/proc/self/status");
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("VmHWM:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;
  }
  return 0.0;
}

int arg_int(int argc, char** argv, const std::string& name, int fallback) {
  for (int i = 0; i + 1 < argc; ++i) {
    if (argv[i] == name) return std::atoi(argv[i + 1]);
  }
  return fallback;
}
bool has_flag(int argc, char** argv, const std::string& name) {
  for (int i = 0; i < argc; ++i) {
    if (argv[i] == name) return true;
  }
  return false;
}

int generate(const fs::path& dir, int rows, int cols, int band, int tile, bool colour, int min_cells, int window_cells,
             bool level0_only) {
  hc::Scene header;
  header.geometry = hc::GridGeometry{rows, cols, 0.0, 0.0, 0.001};
  header.friction_model = hc::FrictionModel::kPaper;
  header.provenance.tool = "tiled_scene_bench";
  header.provenance.synthetic = "analytic relief in a band of " + std::to_string(band) + " rows";
  header.lod.min_cells = min_cells;
  header.lod.window_cells = window_cells;
  const int levels = hc::pipeline::lod_level_count(header.geometry, header.lod.min_cells);
  hc::pipeline::TiledSceneWriter::Contents contents;
  contents.cell_error = colour;
  contents.colour = colour;
  fs::create_directories(dir);
  const auto t0 = Clock::now();
  hc::pipeline::TiledSceneWriter w(dir / "scene", header, hc::SceneStorage{tile, levels}, contents);
  const double band_y0 = 0.001 * (rows / 2 - band / 2), band_y1 = 0.001 * (rows / 2 + band / 2);
  // Wavelengths incommensurate with the 1 mm cell and its powers of two, so that no level samples
  // the texture at its zeros only.
  const double k = 2 * std::numbers::pi / 0.043, kt = 2 * std::numbers::pi / 0.0027;
  std::vector<std::vector<float>> tiles(6, std::vector<float>(static_cast<std::size_t>(tile) * tile));
  std::vector<std::uint8_t> rgb(3 * static_cast<std::size_t>(tile) * tile);
  const char* names[5] = {"depth", "envelope", "texture", "mu_d", "mu_s"};
  std::uint64_t written = 0;
  for (int level = 0; level < (level0_only ? 1 : levels); ++level) {
    const hc::GridGeometry& g = w.level_geometry(level);
    for (int tr = 0; tr * tile < g.rows; ++tr) {
      const double ty0 = g.y_of_row(tr * tile), ty1 = g.y_of_row(std::min(g.rows - 1, (tr + 1) * tile - 1));
      if (ty1 < band_y0 || ty0 > band_y1) continue;  // no data: the tile stays sparse
      for (int tc = 0; tc * tile < g.cols; ++tc) {
        for (int r = 0; r < tile; ++r) {
          const double y = g.y_of_row(tr * tile + r);
          const bool in_band = y >= band_y0 && y <= band_y1 && tr * tile + r < g.rows;
          for (int c = 0; c < tile; ++c) {
            const std::size_t i = static_cast<std::size_t>(r) * tile + c;
            const double x = g.x_of_col(tc * tile + c);
            const double e = 0.004 * std::sin(k * x) * std::sin(k * y);
            const double t = 0.0002 * std::sin(kt * x) * std::sin(kt * y);
            const float nan = std::numeric_limits<float>::quiet_NaN();
            tiles[0][i] = in_band ? static_cast<float>(e + t) : nan;
            tiles[1][i] = in_band ? static_cast<float>(e) : nan;
            tiles[2][i] = in_band ? static_cast<float>(t) : nan;
            tiles[3][i] = in_band ? static_cast<float>(0.2 + 0.6 * std::abs(std::sin(kt * x))) : nan;
            tiles[4][i] = in_band ? 0.3f : nan;
            tiles[5][i] = in_band ? static_cast<float>(1e-4 * (1.0 + std::sin(k * y))) : nan;  // cross-check error [m]
            rgb[3 * i] = in_band ? static_cast<std::uint8_t>(128 + 120 * std::sin(k * x)) : 0;
            rgb[3 * i + 1] = in_band ? static_cast<std::uint8_t>(128 + 120 * std::cos(k * y)) : 0;
            rgb[3 * i + 2] = in_band ? 90 : 0;
          }
        }
        for (int l = 0; l < 5; ++l) w.write_tile(level, names[l], tr, tc, tiles[static_cast<std::size_t>(l)].data());
        if (colour) {
          w.write_tile(level, "cell_error", tr, tc, tiles[5].data());
          w.write_tile(level, "colour", tr, tc, rgb.data());
        }
      }
    }
  }
  written = w.finish();
  if (level0_only) fs::remove_all(dir / "scene" / hc::pipeline::kSceneLevelsFolder);  // empty files: `build` makes them
  std::printf("generate: %d x %d samples, %d levels, band of %d rows, tiles of %d: %.1f GB of tiles in %.1f s\n", rows,
              cols, levels, band, tile, static_cast<double>(written) / 1e9, seconds_since(t0));
  return 0;
}

/// Builds the levels of a scene generated with --level0-only with the streaming level builder.
int build(const fs::path& dir) {
  const auto t0 = Clock::now();
  const hc::pipeline::StoredLevelsReport r = hc::pipeline::build_stored_levels(dir / "scene", dir / "scratch");
  std::printf("build: %d levels in %.1f s, %.2f GB of tiles, peak buffers %.1f MB, scratch %.2f GB, peak RSS %.0f MB\n",
              r.levels_built, seconds_since(t0), static_cast<double>(r.bytes) / 1e9,
              static_cast<double>(r.peak_buffer_bytes) / (1024.0 * 1024.0), static_cast<double>(r.scratch_bytes) / 1e9,
              peak_rss_mb());
  for (std::size_t k = 0; k < r.depth_seconds.size(); ++k) {
    std::printf("  level %zu: depth %.2f s, layers %.2f s\n", k + 1, r.depth_seconds[k], r.layers_seconds[k]);
  }
  return 0;
}

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const std::size_t i = std::min(v.size() - 1, static_cast<std::size_t>(std::ceil(p * static_cast<double>(v.size())) - 1));
  return v[i];
}

int open_and_switch(const fs::path& dir, int switches, unsigned seed, bool drop, int budget_mb) {
  if (drop) {
    ::sync();
    std::ofstream dc("/proc/sys/vm/drop_caches");
    dc << "3\n";
    dc.flush();
    std::printf("page cache %s\n", dc ? "dropped" : "NOT dropped (needs root): the reads below may be cached");
  }
  const double rss_before = peak_rss_mb();
  const auto t0 = Clock::now();
  const hc::Scene header = hc::pipeline::load_scene(dir / "scene", false);
  hc::LodOptions lod = header.lod;
  if (budget_mb > 0) lod.memory_budget_mb = budget_mb;
  auto pyramid = hc::pipeline::LodPyramid::open_stored(dir / "scene", lod);
  const double open_s = seconds_since(t0);
  const double rss_open = peak_rss_mb();
  hc::haptics::SharedState shared;
  hc::session::LodController controller(pyramid, shared, hc::session::LodControllerOptions{});
  const hc::GridGeometry& g0 = pyramid->geometry(0);
  const std::string band = header.provenance.synthetic;
  const int band_rows = std::atoi(band.substr(band.find("band of ") + 8).c_str());
  std::mt19937 rng(seed);
  std::vector<double> times;
  double first_s = 0.0;
  for (int i = 0; i < switches; ++i) {
    const int level = static_cast<int>(rng() % static_cast<unsigned>(pyramid->level_count()));
    const double x = g0.x0_m + g0.cell_size_m * (g0.cols - 1) * std::uniform_real_distribution<double>(0.0, 1.0)(rng);
    const double yc = g0.y0_m + g0.cell_size_m * (g0.rows / 2);
    const double y = yc + g0.cell_size_m * band_rows * std::uniform_real_distribution<double>(-0.4, 0.4)(rng);
    const auto t = Clock::now();
    controller.centre_window(level, x, y);
    const double s = seconds_since(t);
    if (i == 0) {
      first_s = s;
    } else {
      times.push_back(s);
    }
  }
  std::printf("open: %d x %d samples, %d levels, tiles of %d: %.1f ms, peak RSS %.1f MB (%.1f MB before)\n", g0.rows,
              g0.cols, pyramid->level_count(), header.storage.tile_cells, open_s * 1e3, rss_open, rss_before);
  std::printf("switches: %d (random level, window centred in the band): first %.2f ms; then median %.2f ms, p99 %.2f ms, "
              "max %.2f ms\n",
              switches, first_s * 1e3, percentile(times, 0.5) * 1e3, percentile(times, 0.99) * 1e3,
              percentile(times, 1.0) * 1e3);
  const auto stats = pyramid->cache_stats();
  std::printf("tiles decoded %llu, taken from the cache %llu; cache %.1f MB of windows (%d) + %.1f MB of tiles (%d) of "
              "%.1f MB, %llu window evictions; peak RSS %.1f MB\n",
              static_cast<unsigned long long>(pyramid->tiles_read()), static_cast<unsigned long long>(stats.tile_hits),
              static_cast<double>(stats.bytes) / 1048576.0, stats.windows_cached,
              static_cast<double>(stats.tile_bytes) / 1048576.0, stats.tiles_cached,
              static_cast<double>(stats.budget_bytes) / 1048576.0, static_cast<unsigned long long>(stats.evictions),
              peak_rss_mb());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3 || (std::string(argv[1]) != "generate" && std::string(argv[1]) != "open" && std::string(argv[1]) != "build")) {
    std::cerr << "usage: tiled_scene_bench generate DIR [--rows R] [--cols C] [--band B] [--tile T] [--colour] [--min-cells M]\n"
                 "                                  [--window-cells W] [--level0-only]\n"
                 "       tiled_scene_bench build DIR\n"
                 "       tiled_scene_bench open DIR [--switches N] [--seed S] [--drop-caches] [--budget-mb M]\n";
    return 2;
  }
  try {
    if (std::string(argv[1]) == "generate") {
      return generate(argv[2], arg_int(argc, argv, "--rows", 32768), arg_int(argc, argv, "--cols", 65536),
                      arg_int(argc, argv, "--band", 4096), arg_int(argc, argv, "--tile", 256), has_flag(argc, argv, "--colour"),
                      arg_int(argc, argv, "--min-cells", 64), arg_int(argc, argv, "--window-cells", 200),
                      has_flag(argc, argv, "--level0-only"));
    }
    if (std::string(argv[1]) == "build") {
      return build(argv[2]);
    }
    return open_and_switch(argv[2], arg_int(argc, argv, "--switches", 300),
                           static_cast<unsigned>(arg_int(argc, argv, "--seed", 1)), has_flag(argc, argv, "--drop-caches"),
                           arg_int(argc, argv, "--budget-mb", 0));
  } catch (const std::exception& e) {
    std::cerr << "tiled_scene_bench: " << e.what() << "\n";
    return 1;
  }
}
