// End-to-end: `hapticloud touch --level --window --zoom-path` on the synthetic sinusoid, and
// `hapticloud levels` on a scene made by `hapticloud run`.

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "app_runner.hpp"
#include "test_paths.hpp"

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <vector>
#include <string>

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using hc::test::is_png;
using hc::test::read_json;
using hc::test::run_app;

TEST(TouchLevels, ScriptedZoomPathSwitchesWindowsWithoutLeavingTheSurface) {
  const fs::path dir = hc::test::temp_dir("zoom");
  {
    std::ofstream zp(dir / "zoom.txt");
    zp << "# time action args\n0.8 in\n1.4 pan 25 -10\n2.0 out   # back\n2.4 window 1 3 7\n";
  }
  std::string log;
  ASSERT_EQ(run_app("touch --synthetic sinusoid --cells 401 --path circle --seconds 3 --level 2 --window-cells 100 --zoom-path " +
                        (dir / "zoom.txt").string() + " --out " + (dir / "out").string(),
                    &log),
            0)
      << log;
  std::ifstream in(dir / "out" / "summary.json");
  const json s = json::parse(in);
  ASSERT_TRUE(s.contains("lod")) << log;
  const json& sw = s["lod"]["switches"];
  ASSERT_EQ(sw.size(), 5U);  // the start and four requests
  EXPECT_EQ(sw[0]["level"].get<int>(), 2);
  EXPECT_EQ(sw[1]["level"].get<int>(), 1);
  EXPECT_EQ(sw[2]["level"].get<int>(), 1);
  EXPECT_EQ(sw[3]["level"].get<int>(), 2);
  EXPECT_EQ(sw[4]["level"].get<int>(), 1);
  EXPECT_EQ(sw[4]["col0"].get<int>(), 3);
  EXPECT_EQ(sw[4]["row0"].get<int>(), 7);
  EXPECT_NEAR(sw[0]["scale"].get<double>() / sw[1]["scale"].get<double>(), 2.0, 1e-9);
  EXPECT_NEAR(sw[1]["t_s"].get<double>(), 0.8, 1e-9);
  EXPECT_EQ(s["ticks"].get<long>(), 3000);
  EXPECT_LE(s["max_force_n"].get<double>(), 8.0);
  // Every trace row evaluated on the window it was rendered on: the proxy never below it.
  EXPECT_LE(s["deepest_proxy_below_surface_m"].get<double>(), 1e-6);
  EXPECT_GT(s["contact_fraction"].get<double>(), 0.3);
}

TEST(TouchLevels, ATiledSceneIsRenderedThroughItsStoredLevelsWithoutLevelOptions) {
  // `run` with scale.scene_tiles=on writes format 3; `touch` on it renders windows of the
  // stored levels (the coarsest without --level), also with --window-cells alone.
  const fs::path dir = hc::test::temp_dir("tiled");
  std::string log;
  ASSERT_EQ(run_app("run " + std::string(HC_SOURCE_DIR) + "/configs/sinusoid.yaml --out " + (dir / "run").string() +
                        " --set scale.scene_tiles=on --set scale.scene_tile_cells=64 --set lod.min_cells=40 -q",
                    &log),
            0)
      << log;
  ASSERT_EQ(run_app("touch " + (dir / "run" / "scene").string() + " --seconds 1 --window-cells 64 --out " +
                        (dir / "touch").string(),
                    &log),
            0)
      << log;
  EXPECT_NE(log.find("changes the window only"), std::string::npos) << log;  // μ_d was made for 200
  const json s = read_json(dir / "touch" / "summary.json");
  ASSERT_TRUE(s.contains("lod")) << log;
  const json& first = s["lod"]["switches"][0];
  // 200 samples, min_cells 40: levels 0 (200), 1 (100), 2 (50); the coarsest is rendered.
  EXPECT_EQ(first["level"].get<int>(), 2);
  EXPECT_EQ(first["cols"].get<int>(), 50);  // the level is smaller than the 64-sample window
  EXPECT_GT(s["contact_fraction"].get<double>(), 0.1);
}

TEST(TouchLevels, BadLevelOrZoomPathIsAOneLineError) {
  const fs::path dir = hc::test::temp_dir("bad");
  std::string log;
  EXPECT_EQ(run_app("touch --synthetic sinusoid --cells 101 --seconds 1 --level 9 --out " + dir.string(), &log), 1);
  EXPECT_NE(log.find("--level 9"), std::string::npos) << log;
  log.clear();
  EXPECT_EQ(run_app("touch --synthetic sinusoid --cells 101 --seconds 1 --zoom-path '1:sideways' --out " + dir.string(), &log), 1);
  EXPECT_NE(log.find("sideways"), std::string::npos) << log;
  log.clear();
  EXPECT_EQ(run_app("touch --synthetic sinusoid --cells 101 --seconds 1 --level 0 --window 3 --out " + dir.string(), &log), 1);
  EXPECT_NE(log.find("X,Y"), std::string::npos) << log;
}

/// Runs a touch session expected to fail: exit status 1, the message names `what`, and --out
/// is not made at all.
void expect_rejected(const std::string& args, const std::string& what) {
  const fs::path out = hc::test::temp_dir("rejected") / "out";
  std::string log;
  EXPECT_EQ(run_app("touch --synthetic sinusoid --cells 201 --seconds 1 " + args + " --out " + out.string(), &log), 1)
      << args << "\n" << log;
  EXPECT_NE(log.find(what), std::string::npos) << args << "\n" << log;
  EXPECT_FALSE(fs::exists(out)) << args;
}

TEST(TouchLevels, BadOptionsAreRejectedBeforeTheSessionNamingTheOption) {
  expect_rejected("--level -2", "--level -2");
  expect_rejected("--window-cells 50", "--window-cells 50 needs --level");
  // The option, not the config key lod.window_cells.
  expect_rejected("--level 0 --window-cells 1", "--window-cells 1:");
  // 201 samples with the default lod.min_cells (64): levels 0 (201) and 1 (101). Every scripted
  // level and window is checked before the first tick.
  expect_rejected("--level 0 --window-cells 50 --zoom-path '0.5:in,0.8:level:2'", "action '0.8:level:2': level 2");
  expect_rejected("--level 0 --zoom-path '0.5:window:1:101:0'", "action '0.5:window:1:101:0': window origin");
  expect_rejected("--level 1 --window 0,150", "--window 0,150: window origin");
}

TEST(TouchLevels, ZoomPathTextIsEscapedInTheSummary) {
  // A zoom path file with Windows line ends and tabs: the actions are reported as written, in
  // valid JSON.
  const fs::path dir = hc::test::temp_dir("crlf");
  {
    std::ofstream zp(dir / "zoom.txt", std::ios::binary);
    zp << "0.3 in\r\n0.5\tpan 5 5\r\n";
  }
  std::string log;
  ASSERT_EQ(run_app("touch --synthetic sinusoid --cells 201 --seconds 1 --level 1 --window-cells 50 --zoom-path " +
                        (dir / "zoom.txt").string() + " --out " + (dir / "out").string(),
                    &log),
            0)
      << log;
  const json s = read_json(dir / "out" / "summary.json");
  const json& sw = s["lod"]["switches"];
  ASSERT_EQ(sw.size(), 3U);
  EXPECT_EQ(sw[1]["request"].get<std::string>(), "0.3 in\r");
  EXPECT_EQ(sw[2]["request"].get<std::string>(), "0.5\tpan 5 5\r");
  EXPECT_EQ(s["lod"]["window_cells"].get<int>(), 50);
}

TEST(TouchLevels, SceneFolderLevelsUseTheScenesLayerAndLodSettings) {
  // A scene made with a static friction of 0.55 (default 0.2), levels down to 30 samples and
  // 40-sample windows: level 1 of touch's pyramid must be computed with those settings.
  const fs::path dir = hc::test::temp_dir("scene_options");
  {
    std::ofstream cfg(dir / "sin.yaml");
    cfg << "input: {synthetic: {surface: sinusoid, half_extent_m: 0.02, density_per_m2: 2.0e7, wavelength_m: 0.008}}\n"
           "filters: {outliers: {enabled: false}}\n"
           "grid: {n: 120, splat_radius_cells: 1.0}\n"
           "layers: {friction: {mu_s: 0.55}}\n"
           "lod: {min_cells: 25, window_cells: 40, report: false}\n";
  }
  std::string log;
  ASSERT_EQ(run_app("run " + (dir / "sin.yaml").string() + " --out " + (dir / "run").string(), &log), 0) << log;
  log.clear();
  ASSERT_EQ(run_app("touch " + (dir / "run" / "scene").string() + " --level 1 --path raster --seconds 2 --out " +
                        (dir / "out").string(),
                    &log),
            0)
      << log;
  const json s = read_json(dir / "out" / "summary.json");
  EXPECT_EQ(s["lod"]["levels"].size(), 3U);  // 120, 60, 30 (lod.min_cells 25)
  EXPECT_EQ(s["lod"]["window_cells"].get<int>(), 40);
  EXPECT_EQ(s["lod"]["switches"][0]["level"].get<int>(), 1);
  // μ_s of every tick in contact: the scene's 0.55, not the default 0.2.
  std::ifstream trace(dir / "out" / "trace.csv");
  std::string line;
  std::getline(trace, line);
  std::size_t contact = 0;
  while (std::getline(trace, line)) {
    std::vector<std::string> f;
    std::stringstream ss(line);
    for (std::string x; std::getline(ss, x, ',');) f.push_back(x);
    ASSERT_GE(f.size(), 15U);
    if (f[11] != "1") continue;  // contact
    ++contact;
    EXPECT_NEAR(std::stod(f[14]), 0.55, 1e-3) << line;
    if (::testing::Test::HasFailure()) break;
  }
  EXPECT_GT(contact, 100U);
}

TEST(LevelsCommand, PrintsOneRowPerLevelWithCrossCheckAndWritesPreviews) {
  const fs::path dir = hc::test::temp_dir("levels");
  {
    std::ofstream cfg(dir / "sin.yaml");
    cfg << "input: {synthetic: {surface: sinusoid, half_extent_m: 0.02, density_per_m2: 2.0e7, wavelength_m: 0.008}}\n"
           "filters: {outliers: {enabled: false}}\n"
           "grid: {n: 120, splat_radius_cells: 1.0}\n"
           "lod: {min_cells: 25, report: false}\n";
  }
  std::string log;
  ASSERT_EQ(run_app("run " + (dir / "sin.yaml").string() + " --out " + (dir / "run").string(), &log), 0) << log;
  log.clear();
  ASSERT_EQ(run_app("levels " + (dir / "run" / "scene").string() + " --ticks 300 --window-cells 50 --previews " +
                        (dir / "prev").string(),
                    &log),
            0)
      << log;
  EXPECT_NE(log.find("window 50 samples"), std::string::npos) << log;
  EXPECT_NE(log.find("rms_mm"), std::string::npos) << log;
  EXPECT_NE(log.find("\n2 "), std::string::npos) << log;   // levels 0, 1, 2 (120 → 60 → 30)
  EXPECT_EQ(log.find("\n3 "), std::string::npos) << log;
  EXPECT_TRUE(fs::exists(dir / "prev" / "lod_levels.png"));
  log.clear();
  EXPECT_EQ(run_app("levels " + (dir / "nothing").string(), &log), 1);
  // A previews folder that cannot be made (its parent is a file): an error naming --previews.
  { std::ofstream(dir / "a_file") << "x"; }
  log.clear();
  EXPECT_EQ(run_app("levels " + (dir / "run" / "scene").string() + " --no-cross-check --previews " +
                        (dir / "a_file" / "prev").string(),
                    &log),
            1);
  EXPECT_NE(log.find("--previews"), std::string::npos) << log;

  // The same run storing a tiled scene with its levels (scale.scene_tiles: on): the table reads
  // the stored levels (no build; rows say "stored") and gives each level's RMS and p95 as the
  // untiled scene's table does (the oracle: the stored levels equal the in-memory pyramid's).
  const auto columns = [](const std::string& text, const std::string& level) {
    const auto at = text.find("\n" + level + " ");
    std::istringstream row(at == std::string::npos ? std::string() : text.substr(at + 1, text.find('\n', at + 1) - at - 1));
    std::vector<std::string> out;
    for (std::string w; row >> w;) out.push_back(w);
    return out;  // level cell cols x rows build rms p95 ...
  };
  std::string plain;
  ASSERT_EQ(run_app("levels " + (dir / "run" / "scene").string() + " --ticks 300", &plain), 0) << plain;
  ASSERT_EQ(run_app("run " + (dir / "sin.yaml").string() + " --out " + (dir / "tiled").string() + " --set scale.scene_tiles=on", &log), 0)
      << log;
  log.clear();
  ASSERT_EQ(run_app("levels " + (dir / "tiled" / "scene").string() + " --ticks 300", &log), 0) << log;
  EXPECT_NE(log.find("stores its levels"), std::string::npos) << log;
  EXPECT_NE(log.find("filtered points stored with the scene"), std::string::npos) << "the stored sample, not the scan: " << log;
  for (const char* level : {"0", "1", "2"}) {
    const auto a = columns(log, level), b = columns(plain, level);
    ASSERT_GE(a.size(), 8U) << log;
    ASSERT_GE(b.size(), 8U) << plain;
    EXPECT_EQ(a[5], "stored") << log;
    EXPECT_EQ(a[6], b[6]) << "RMS of level " << level;
    EXPECT_EQ(a[7], b[7]) << "p95 of level " << level;
  }
  log.clear();
  EXPECT_EQ(run_app("levels " + (dir / "tiled" / "scene").string() + " --min-cells 30", &log), 1) << log;
  EXPECT_NE(log.find("stores its 3 levels"), std::string::npos) << log;
  // Previews draw whole levels: with a budget no level 0 fits (0.05 MB: 120 × 120 samples of
  // 27 bytes are 0.37 MB), refused before the table, naming the level, and no folder made.
  log.clear();
  ASSERT_EQ(run_app("run " + (dir / "sin.yaml").string() + " --out " + (dir / "small").string() +
                        " --set scale.scene_tiles=on --set lod.memory_budget_mb=0.05",
                    &log),
            0)
      << log;
  log.clear();
  EXPECT_EQ(run_app("levels " + (dir / "small" / "scene").string() + " --no-cross-check --previews " + (dir / "prev_small").string(),
                    &log),
            1);
  EXPECT_NE(log.find("levels --previews: level 0 of"), std::string::npos) << log;
  EXPECT_EQ(log.find("rms_mm"), std::string::npos) << "refused before the table: " << log;
  EXPECT_FALSE(fs::exists(dir / "prev_small"));
}

// A scene of a tiled run that is not itself stored tiled (a grid below scale.scene_tiles' size):
// the run stores its sample of the kept points beside it (points_sample.bin), and `levels`
// cross-checks against that instead of reading the scan again. The oracle: the table from the
// scan read again through --config (the same points: no filter, fewer than
// lod.report_sample_points, so the sample is every point), and the sample's own file.
TEST(LevelsCommand, ASceneOfATiledRunIsCrossCheckedAgainstTheSampleItStores) {
  const fs::path dir = hc::test::temp_dir("levels_tiled_run");
  {
    // A sinusoid relief on a jittered raster, 150 x 150 points over 4 cm (x y z in metres).
    std::ofstream xyz(dir / "relief.xyz");
    std::uint32_t state = 12345;
    const auto jitter = [&state] {
      state = state * 1664525u + 1013904223u;
      return (static_cast<double>(state >> 8) / 16777216.0 - 0.5) * 1e-4;
    };
    char line[96];
    for (int i = 0; i < 150; ++i)
      for (int j = 0; j < 150; ++j) {
        const double x = -0.02 + 0.04 * j / 149.0 + jitter(), y = -0.02 + 0.04 * i / 149.0 + jitter();
        const double z = 0.002 * std::sin(2.0 * 3.14159265358979 * x / 0.008) * std::cos(2.0 * 3.14159265358979 * y / 0.011);
        std::snprintf(line, sizeof line, "%.9f %.9f %.9f\n", x, y, z);
        xyz << line;
      }
    std::ofstream cfg(dir / "relief.yaml");
    cfg << "input: {files: [relief.xyz], units: m}\n"
           "filters: {outliers: {enabled: false}}\n"
           "grid: {n: 100, splat_radius_cells: 1.0}\n"
           "lod: {min_cells: 25, report: false}\n";
  }
  std::string log;
  ASSERT_EQ(run_app("run " + (dir / "relief.yaml").string() + " --out " + (dir / "run").string() +
                        " --set scale.tiled=on --set scale.tile_cells=32",
                    &log),
            0)
      << log;
  const fs::path scene = dir / "run" / "scene";
  ASSERT_TRUE(fs::exists(scene / "points_sample.bin")) << "a tiled run's scene stores its sample";
  EXPECT_EQ(fs::file_size(scene / "points_sample.bin"), 24U + 150U * 150U * 24U) << "every point: 150 x 150 of them";
  ASSERT_FALSE(fs::exists(scene / "levels")) << "the scene itself is not stored tiled";
  const auto columns = [](const std::string& text, const std::string& level) {
    const auto at = text.find("\n" + level + " ");
    std::istringstream row(at == std::string::npos ? std::string() : text.substr(at + 1, text.find('\n', at + 1) - at - 1));
    std::vector<std::string> out;
    for (std::string w; row >> w;) out.push_back(w);
    return out;  // level cell cols x rows build rms p95 supported ...
  };
  std::string from_sample, from_scan;
  ASSERT_EQ(run_app("levels " + scene.string() + " --ticks 300", &from_sample), 0) << from_sample;
  EXPECT_NE(from_sample.find("filtered points stored with the scene"), std::string::npos) << from_sample;
  EXPECT_EQ(from_sample.find("reading the scene's points"), std::string::npos) << "no scan read: " << from_sample;
  ASSERT_EQ(run_app("levels " + scene.string() + " --ticks 300 --config " + (dir / "relief.yaml").string(), &from_scan), 0)
      << from_scan;
  EXPECT_NE(from_scan.find("reading the scene's points"), std::string::npos) << from_scan;
  for (const char* level : {"0", "1", "2"}) {
    const auto a = columns(from_sample, level), b = columns(from_scan, level);
    ASSERT_GE(a.size(), 9U) << from_sample;
    ASSERT_GE(b.size(), 9U) << from_scan;
    EXPECT_EQ(a[6], b[6]) << "RMS of level " << level;
    EXPECT_EQ(a[7], b[7]) << "p95 of level " << level;
    EXPECT_EQ(a[8], b[8]) << "supported (every point stored) of level " << level;
  }
}

}  // namespace
