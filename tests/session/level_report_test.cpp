// The levels table (hapticloud levels and the run report): real runs of the pipeline on an
// analytic surface, the servo columns timed by hc::session, the scene's own LoD options read back
// from its typed metadata.

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/cross_check.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/lod_report.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/session/level_timing.hpp"

#include <gtest/gtest.h>

#include "test_paths.hpp"

#include <nlohmann/json.hpp>

#include <fstream>
#include <iterator>
#include <string>
#include <utility>
#include <vector>

namespace hc::pipeline {
namespace {

namespace fs = std::filesystem;

const char* kSinusoid =
    "input: {synthetic: {surface: sinusoid, half_extent_m: 0.02, density_per_m2: 2.0e7, amplitude_m: 0.002, "
    "wavelength_m: 0.008, seed: 3}}\n"
    "filters: {outliers: {enabled: false}}\n"
    "grid: {n: 160, splat_radius_cells: 1.0}\n"
    "lod: {min_cells: 20, window_cells: 64, report: true}\n";

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

// The table's cross-check on levels >= 1: (a) on every s-th point equals cross_check of exactly
// those points, the support equals cross_check's over every point, and a sample handed in as
// such (the tiled run's) gives (a) from it and no support.
TEST(LodReport, LevelsAreCrossCheckedOnAStridedSampleWithSupportOverEveryPoint) {
  const fs::path dir = test::temp_dir("sampled");
  const RunConfig config = parse_run_config(kSinusoid, dir / "lod.yaml");
  const Cloud points = prepare_points(config);
  BuiltScene built = build_scene(config);
  auto pyramid = LodPyramid::from_scene(std::move(built.scene), config.layers.options, config.lod);
  ASSERT_GE(pyramid->level_count(), 3);
  const std::size_t n = points.size();
  LevelTableOptions to;
  to.tolerance_m = config.cross_check.tolerance_m;
  to.hidden_band_m = config.cross_check.hidden_band_m;
  to.sample_points = 1000;
  const std::size_t stride = (n + 999) / 1000;
  ASSERT_GT(stride, 10U);
  Cloud every_sth;
  every_sth.xyz.resize(3, static_cast<Eigen::Index>((n + stride - 1) / stride));
  for (std::size_t i = 0, k = 0; i < n; i += stride, ++k) every_sth.xyz.col(static_cast<Eigen::Index>(k)) = points.xyz.col(static_cast<Eigen::Index>(i));
  const auto rows = level_table(pyramid, &points, to);
  to.points_represent = 10 * n;
  const auto from_sample = level_table(pyramid, &every_sth, to);
  for (int l = 0; l < pyramid->level_count(); ++l) {
    SCOPED_TRACE("level " + std::to_string(l));
    const HeightField& depth = pyramid->level(l)->depth_m;
    const CrossCheck on_sample = cross_check(every_sth, depth, to.tolerance_m, to.hidden_band_m).value;
    const CrossCheck on_all = cross_check(points, depth, to.tolerance_m, to.hidden_band_m).value;
    const LevelRow& r = rows[static_cast<std::size_t>(l)];
    ASSERT_TRUE(r.point_vertical.has_value());
    EXPECT_EQ(r.points_checked, static_cast<std::size_t>(every_sth.size()));
    EXPECT_EQ(r.points_total, n);
    EXPECT_EQ(r.point_vertical->count, on_sample.point_vertical.count);
    EXPECT_DOUBLE_EQ(r.point_vertical->rms_mm, on_sample.point_vertical.rms_mm);
    EXPECT_EQ(r.point_vertical->p95_mm, on_sample.point_vertical.p95_mm);
    EXPECT_EQ(r.point_vertical->max_mm, on_sample.point_vertical.max_mm);
    EXPECT_TRUE(r.support_measured);
    EXPECT_DOUBLE_EQ(r.supported_fraction, on_all.supported_fraction);
    // A sample of 1/37 of the points estimates the RMS of all of them.
    EXPECT_NEAR(r.point_vertical->rms_mm, on_all.point_vertical.rms_mm, 0.1 * on_all.point_vertical.rms_mm);
    const LevelRow& q = from_sample[static_cast<std::size_t>(l)];
    EXPECT_EQ(q.points_checked, every_sth.size());
    EXPECT_EQ(q.points_total, 10 * n);
    EXPECT_DOUBLE_EQ(q.point_vertical->rms_mm, on_sample.point_vertical.rms_mm);
    EXPECT_FALSE(q.support_measured);
  }
  const std::string md = level_table_markdown(rows);
  EXPECT_NE(md.find("Level 1: RMS and p95 from " + std::to_string(every_sth.size()) + " of " + std::to_string(n)),
            std::string::npos) << md;
  EXPECT_NE(level_table_markdown(from_sample).find("support not measured"), std::string::npos);
  EXPECT_EQ(level_table_text(from_sample).find("%"), std::string::npos) << "no support column value";
  // sample_points 0: every point, no note.
  to.sample_points = 0;
  to.points_represent = 0;
  const auto all = level_table(pyramid, &points, to);
  for (const LevelRow& r : all) EXPECT_EQ(r.points_checked, n);
  EXPECT_EQ(level_table_markdown(all).find("RMS and p95 from"), std::string::npos);
}

// Off by the override, and off when the config does not name lod.report (the table is made by
// request since issue 16: `hapticloud levels SCENE` or lod.report: true).
TEST(LodReport, TheTableIsOnlyMadeWhenTheConfigAsks) {
  const fs::path dir = test::temp_dir("off");
  std::string unnamed = kSinusoid;
  const std::string key = ", report: true";
  const auto at = unnamed.find(key);
  ASSERT_NE(at, std::string::npos);
  unnamed.erase(at, key.size());
  const std::vector<std::pair<std::string, RunConfig>> configs = {
      {"override", parse_run_config(kSinusoid, dir / "lod.yaml", {"lod.report=false"})},
      {"default", parse_run_config(unnamed, dir / "lod.yaml")}};
  for (const auto& [name, config] : configs) {
    EXPECT_FALSE(config.lod.report) << name;
    run_pipeline(config, dir / name);
    std::ifstream js(dir / name / "report.json");
    const nlohmann::json j = nlohmann::json::parse(js);
    EXPECT_FALSE(j.contains("levels")) << name;
    EXPECT_FALSE(fs::exists(dir / name / "previews" / "lod_levels.png")) << name;
    for (const auto& s : j["stages"]) EXPECT_NE(s["stage"].get<std::string>(), "levels") << name;
    std::ifstream md(dir / name / "report.md");
    const std::string text((std::istreambuf_iterator<char>(md)), std::istreambuf_iterator<char>());
    EXPECT_EQ(text.find("## Levels of detail"), std::string::npos) << name;
  }
}

}  // namespace
}  // namespace hc::pipeline
