// End-to-end: `hapticloud touch` on a run config (scene built first) and the paper's validation.

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

TEST(TouchCommand, ValidationOnTheSinusoidConfigWritesBothSessionsPlotsAndReport) {
  const fs::path out = hc::test::temp_dir("validate") / "touch";
  std::string log;
  const std::string cfg = (fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml").string();
  ASSERT_EQ(run_app("touch " + cfg + " --validate --seconds 3 --out " + out.string(), &log), 0) << log;
  EXPECT_TRUE(fs::exists(out / "pipeline" / "scene" / "scene.yaml"));
  EXPECT_TRUE(is_png(out / "validation_proxy_z.png"));
  EXPECT_TRUE(is_png(out / "validation_force.png"));
  EXPECT_TRUE(fs::exists(out / "report.md"));
  const json with = read_json(out / "with_texture_friction" / "summary.json");
  const json without = read_json(out / "without_texture_friction" / "summary.json");
  for (const json* s : {&with, &without}) {
    EXPECT_EQ((*s)["ticks"].get<long>(), 3000);
    EXPECT_GT((*s)["max_force_n"].get<double>(), 0.1);   // the hand pressed into the surface
    EXPECT_LE((*s)["max_force_n"].get<double>(), 8.0);   // never above the cap
    EXPECT_LE((*s)["deepest_proxy_below_surface_m"].get<double>(), 1e-6);
    EXPECT_GT((*s)["events"]["onset"].get<long>(), 0);
  }
  EXPECT_FALSE(with["texture_gain"].get<double>() == without["texture_gain"].get<double>());
  EXPECT_TRUE(with["friction"].get<bool>());
  EXPECT_FALSE(without["friction"].get<bool>());
}

TEST(TouchCommand, RasterOnARunSceneWritesTraceAndPlots) {
  const fs::path dir = hc::test::temp_dir("raster");
  std::string log;
  const std::string cfg = (fs::path(HC_SOURCE_DIR) / "configs" / "bunny.yaml").string();
  ASSERT_EQ(run_app("run " + cfg + " --quiet --out " + (dir / "run").string(), &log), 0) << log;
  ASSERT_EQ(run_app("touch " + (dir / "run" / "scene").string() + " --path raster --seconds 4 --out " +
                        (dir / "touch").string(), &log), 0) << log;
  const json s = read_json(dir / "touch" / "summary.json");
  EXPECT_EQ(s["ticks"].get<long>(), 4000);
  // Overruns (ticks whose compute exceeded the period) depend on the machine's load in this
  // as-fast-as-possible run, so they are reported, not asserted.
  EXPECT_TRUE(s.contains("overruns"));
  EXPECT_LE(s["max_force_n"].get<double>(), 8.0);
  EXPECT_LE(s["deepest_proxy_below_surface_m"].get<double>(), 1e-6);
  EXPECT_GT(s["contact_fraction"].get<double>(), 0.05);
  EXPECT_TRUE(is_png(dir / "touch" / "proxy_z.png"));
  EXPECT_TRUE(is_png(dir / "touch" / "force.png"));
  std::ifstream trace(dir / "touch" / "trace.csv");
  std::string header;
  std::getline(trace, header);
  EXPECT_EQ(header.rfind("t_s,hip_x_m,hip_y_m,hip_z_m,proxy_x_m", 0), 0u) << header;
}

TEST(TouchCommand, NotASceneIsAOneLineError) {
  const fs::path dir = hc::test::temp_dir("bad");
  std::string log;
  EXPECT_EQ(run_app("touch " + dir.string() + " --out " + (dir / "o").string(), &log), 1);
  EXPECT_NE(log.find("neither a scene folder"), std::string::npos) << log;
}

}  // namespace
