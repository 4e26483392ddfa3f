// Sessions on a tiled scene's stored levels (issue 14): a scripted touch session that reads its
// windows from disk (LodPyramid::open_stored, through open_scene_or_config) renders the same
// forces, tick for tick, as the same session on the scene loaded whole into memory, across
// scripted level switches and pans; and open_scene_or_config loads no layer for it.

#include "layered_sinusoid.hpp"
#include "test_paths.hpp"

#include "hc/pipeline/level_builder.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/pipeline/surface_layers.hpp"
#include "hc/session/scene_source.hpp"
#include "hc/session/touch_session.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

namespace hc::session {
namespace {

namespace fs = std::filesystem;

TEST(StoredSceneSession, TouchOnStoredLevelsRendersTheForcesOfTheSceneInMemory) {
  pipeline::SurfaceLayerOptions options;
  Scene scene = hc::test::layered_sinusoid(321, options, 120);
  scene.lod.min_cells = 40;
  const fs::path dir = hc::test::temp_dir("scene") / "scene";
  pipeline::write_scene(scene, dir, SceneStorage{64, pipeline::lod_level_count(scene.geometry, scene.lod.min_cells)});
  (void)pipeline::build_stored_levels(dir, dir.parent_path() / "scratch");

  SceneSourceOptions so;
  so.open_stored_levels = true;
  const OpenedScene opened = open_scene_or_config(dir, so);
  ASSERT_TRUE(opened.stored_levels);
  EXPECT_EQ(opened.scene.layers.depth.rows(), 0) << "no layer is loaded for a stored scene";
  ASSERT_GE(opened.stored_levels->level_count(), 3);

  TouchSessionOptions o;
  o.path = "raster";
  o.seconds = 2.0;
  o.levels = true;
  o.level = 1;
  // A level switch to the finest level and a pan, both on the stored pyramid's windows.
  o.zoom_path = parse_zoom_path("0.6 level 0; 1.2 pan 20 -10");
  const TouchSessionResult stored = run_touch_session(opened.scene, o, {}, opened.stored_levels);
  const TouchSessionResult memory = run_touch_session(scene, o);
  ASSERT_EQ(stored.trace.size(), memory.trace.size());
  ASSERT_EQ(stored.trace.size(), 2000u);
  std::size_t contact = 0;
  for (std::size_t i = 0; i < stored.trace.size(); ++i) {
    const auto& a = stored.trace[i];
    const auto& b = memory.trace[i];
    ASSERT_EQ(a.force_n.eigen(), b.force_n.eigen()) << "tick " << i;
    ASSERT_EQ(a.proxy_m.eigen(), b.proxy_m.eigen()) << "tick " << i;
    ASSERT_EQ(a.mu_d, b.mu_d) << "tick " << i;
    contact += a.in_contact ? 1u : 0u;
  }
  EXPECT_GT(contact, 500u) << "the session must touch the surface for the comparison to mean anything";
  EXPECT_GT(opened.stored_levels->tiles_read(), 0u);
}

}  // namespace
}  // namespace hc::session
