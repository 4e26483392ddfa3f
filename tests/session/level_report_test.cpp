// The levels table (hapticloud levels and the run report): real runs of the pipeline on an
// analytic surface, the servo columns timed by hc::session, the scene's own LoD options read back
// from its typed metadata.

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/lod_report.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/session/level_timing.hpp"

#include <gtest/gtest.h>

#include "test_paths.hpp"

#include <nlohmann/json.hpp>

#include <fstream>

namespace hc::pipeline {
namespace {

namespace fs = std::filesystem;

const char* kSinusoid =
    "input: {synthetic: {surface: sinusoid, half_extent_m: 0.02, density_per_m2: 2.0e7, amplitude_m: 0.002, "
    "wavelength_m: 0.008, seed: 3}}\n"
    "filters: {outliers: {enabled: false}}\n"
    "grid: {n: 160, splat_radius_cells: 1.0}\n"
    "lod: {min_cells: 20, window_cells: 64}\n";

TEST(LodReport, RunReportHasTheLevelsTableAndPreviewsAndLevelsCommandFindsThePoints) {
  const fs::path dir = test::temp_dir("run");
  const RunConfig config = parse_run_config(kSinusoid, dir / "lod.yaml");
  const RunSummary summary = run_pipeline(config, dir / "out", {}, ExistingOutput::kRefuse, session::servo_level_timing());
  std::ifstream js(dir / "out" / "report.json");
  const nlohmann::json j = nlohmann::json::parse(js);
  ASSERT_TRUE(j.contains("levels"));
  const auto& levels = j["levels"];
  ASSERT_EQ(static_cast<int>(levels.size()), lod_level_count(summary.grid, 20));
  ASSERT_GE(levels.size(), 3U);
  double previous_rms = 0.0;
  for (std::size_t l = 0; l < levels.size(); ++l) {
    EXPECT_EQ(levels[l]["level"].get<int>(), static_cast<int>(l));
    EXPECT_NEAR(levels[l]["cell_size_m"].get<double>(), summary.grid.cell_size_m * (1 << l), 1e-12);
    EXPECT_GT(levels[l]["tick_p50_ns"].get<double>(), 0.0);
    EXPECT_GT(levels[l]["switch_ms"].get<double>(), 0.0);
    ASSERT_TRUE(levels[l].contains("point_vertical"));
    // Coarser levels smooth the 8 mm sinusoid more: their error against the points grows.
    const double rms = levels[l]["point_vertical"]["rms_mm"].get<double>();
    EXPECT_GT(rms, previous_rms) << "level " << l;
    previous_rms = rms;
    EXPECT_TRUE(fs::exists(dir / "out" / "previews" / ("lod_level_" + std::to_string(l) + ".png")));
  }
  // Level 0 reuses the run's own cross-check.
  EXPECT_NEAR(levels[0]["point_vertical"]["rms_mm"].get<double>(), summary.cross_check->point_vertical.rms_mm, 1e-12);
  EXPECT_TRUE(fs::exists(dir / "out" / "previews" / "lod_levels.png"));
  std::ifstream md_in(dir / "out" / "report.md");
  const std::string md((std::istreambuf_iterator<char>(md_in)), std::istreambuf_iterator<char>());
  EXPECT_NE(md.find("## Levels of detail"), std::string::npos);
  EXPECT_NE(md.find("previews/lod_levels.png"), std::string::npos);

  // `hapticloud levels`: the scene's typed options are the config's, the config gives the same
  // points (a synthetic input here) and the same table for level 0 when cross-checked afresh.
  Scene scene = load_scene(dir / "out" / "scene");
  const SurfaceLayerOptions lo = scene.layer_options;
  const LodOptions lod = scene.lod;
  EXPECT_EQ(lod.window_cells, 64);
  EXPECT_EQ(lod.min_cells, 20);
  EXPECT_EQ(lod, config.lod);
  EXPECT_EQ(lo, config.layers.options);
  const Cloud points = prepare_points(config);
  EXPECT_GT(points.size(), 30000U);
  auto pyramid = LodPyramid::from_scene(std::move(scene), lo, lod);
  LevelTableOptions to;
  auto rows = level_table(pyramid, &points, to);
  for (const LevelRow& r : rows) EXPECT_FALSE(r.timed);  // the pipeline alone times no servo
  EXPECT_NE(level_table_text(rows).find("-"), std::string::npos);
  session::time_levels(pyramid, rows, 200);
  for (const LevelRow& r : rows) {
    EXPECT_TRUE(r.timed);
    EXPECT_GT(r.tick_p50_ns, 0.0);
    EXPECT_GT(r.switch_ms, 0.0);
  }
  ASSERT_EQ(rows.size(), levels.size());
  ASSERT_TRUE(rows[0].point_vertical.has_value());
  EXPECT_NEAR(rows[0].point_vertical->rms_mm, summary.cross_check->point_vertical.rms_mm, 1e-9);
  EXPECT_NE(level_table_text(rows).find("switch_ms"), std::string::npos);
  EXPECT_NE(level_table_markdown(rows).find("| 2 |"), std::string::npos);
}

TEST(LodReport, TheTableIsOnlyMadeWhenTheConfigAsks) {
  const fs::path dir = test::temp_dir("off");
  const RunConfig config = parse_run_config(std::string(kSinusoid) + "", dir / "lod.yaml", {"lod.report=false"});
  run_pipeline(config, dir / "out");
  std::ifstream js(dir / "out" / "report.json");
  const nlohmann::json j = nlohmann::json::parse(js);
  EXPECT_FALSE(j.contains("levels"));
  EXPECT_FALSE(fs::exists(dir / "out" / "previews" / "lod_levels.png"));
  for (const auto& s : j["stages"]) EXPECT_NE(s["stage"].get<std::string>(), "levels");
}

}  // namespace
}  // namespace hc::pipeline
