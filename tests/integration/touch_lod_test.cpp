// End-to-end: `hapticloud touch --level --window --zoom-path` on the synthetic sinusoid, and
// `hapticloud levels` on a scene made by `hapticloud run`.

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "app_runner.hpp"
#include "test_paths.hpp"

#include <cstdio>
#include <fstream>
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
  ASSERT_EQ(run_app("levels " + (dir / "run" / "scene").string() + " --ticks 300 --previews " + (dir / "prev").string(), &log),
            0)
      << log;
  EXPECT_NE(log.find("rms_mm"), std::string::npos) << log;
  EXPECT_NE(log.find("\n2 "), std::string::npos) << log;   // levels 0, 1, 2 (120 → 60 → 30)
  EXPECT_EQ(log.find("\n3 "), std::string::npos) << log;
  EXPECT_TRUE(fs::exists(dir / "prev" / "lod_levels.png"));
  log.clear();
  EXPECT_EQ(run_app("levels " + (dir / "nothing").string(), &log), 1);
}

}  // namespace
