// The viewer on scenes built by the pipeline (the paper's sinusoid and the Buddha at a small N),
// with the real LoD pyramid and controller answering level commands.

#include "test_paths.hpp"
#include "viewer_fixture.hpp"

#include "hc/haptics/shared_state.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/session/lod_controller.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/viewer/viewer.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <memory>
#include <set>
#include <string>
#include <vector>

namespace hc {
namespace {

namespace fs = std::filesystem;

/// Builds `config` with overrides into a temporary folder and loads the scene.
pipeline::Scene build_scene(const std::string& config, const std::vector<std::string>& overrides, const std::string& tag) {
  const fs::path dir = test::temp_dir(tag);
  const pipeline::RunConfig cfg = pipeline::load_run_config(fs::path(HC_SOURCE_DIR) / "configs" / config, overrides);
  pipeline::run_pipeline(cfg, dir / "run");
  return pipeline::load_scene(dir / "run" / "scene");
}

/// What `hapticloud explore` shows for the controller's window.
std::shared_ptr<viewer::DisplayScene> display_of(session::LodController& lod) {
  const session::HapticWindow& w = lod.window();
  auto d = std::make_shared<viewer::DisplayScene>();
  const auto win = lod.pyramid().window(w.level, w.row0, w.col0, w.rows, w.cols);
  d->window = win->depth_m;
  d->window_layers = {win->colour_rgb8, win->texture_m, win->mu_d, win->cell_error_m};
  const auto ov = lod.pyramid().level(lod.level_count() - 1);
  d->overview = ov->depth_m;
  d->overview_layers = {std::vector<std::uint8_t>(ov->colour_rgb8.begin(), ov->colour_rgb8.end()), ov->texture_m, ov->mu_d, ov->cell_error_m};
  d->workspace = w.map;
  d->level = w.level;
  d->level_count = lod.level_count();
  return d;
}

/// A session's view of a pipeline scene: pyramid, controller on a SharedState, viewer whose
/// level commands go to the controller.
struct SceneSession {
  haptics::SharedState shared;
  std::unique_ptr<session::LodController> lod;
  std::unique_ptr<viewer::Viewer> view;

  SceneSession(pipeline::Scene scene, int window_cells, int start_level) {
    pipeline::LodOptions lo;
    lo.window_cells = window_cells;
    lo.min_cells = 32;
    auto pyramid = pipeline::LodPyramid::from_scene(std::move(scene), pipeline::SurfaceLayerOptions{}, lo);
    lod = std::make_unique<session::LodController>(pyramid, shared, session::LodControllerOptions{});
    const GridGeometry& g = lod->level_geometry(0);
    lod->centre_window(start_level, g.x_of_col(0.5 * (g.cols - 1)), g.y_of_row(0.5 * (g.rows - 1)));
    viewer::ViewerCallbacks cb;
    cb.on_region = [this](const viewer::RegionCommand& c) {
      if (c.type == viewer::RegionCommandType::kFiner) lod->zoom_in();
      if (c.type == viewer::RegionCommandType::kCoarser) lod->zoom_out();
      view->set_scene(display_of(*lod));
    };
    view = std::make_unique<viewer::Viewer>(shared, test::test_options(), cb);
    view->set_scene(display_of(*lod));
  }
};

void expect_drawn_and_shaded(const viewer::Image& img, const viewer::PixelRect& r, double min_fraction) {
  const test::RegionStats s = test::region_stats(img, r);
  EXPECT_GT(static_cast<double>(s.foreground), min_fraction * static_cast<double>(s.pixels));
  EXPECT_GT(s.stddev_luma, 15.0);
  EXPECT_GT(s.distinct_luma, 60);
}

TEST(ViewerScene, SinusoidFromThePipelineIsDrawnAndALevelSwitchChangesTheWindow) {
  pipeline::Scene scene = build_scene("sinusoid.yaml", {"grid.n=160", "cross_check.enabled=false"}, "sinusoid");
  SceneSession s(std::move(scene), 64, 1);  // level 1: 80 × 80 samples, larger than the 64-sample window
  const viewer::Image coarse = s.view->capture();
  viewer::write_png(coarse, (test::temp_dir("shots") / "sinusoid_level1.png").string());
  expect_drawn_and_shaded(coarse, s.view->main_view(), 0.5);
  const double cell1 = s.view->scene()->window.cell_size_m();

  s.view->issue({viewer::RegionCommandType::kFiner});
  const viewer::Image fine = s.view->capture();
  ASSERT_EQ(s.view->scene()->level, 0);
  EXPECT_NEAR(s.view->scene()->window.cell_size_m(), 0.5 * cell1, 1e-12);
  expect_drawn_and_shaded(fine, s.view->main_view(), 0.5);
  EXPECT_GT(test::fraction_changed(coarse, fine, s.view->main_view()), 0.3);
}

TEST(ViewerScene, PipelineLayersReachTheLayerMapAtEveryLevel) {
  // The sinusoid with its cross-check: texture, μ_d and the per-cell error go scene → pyramid →
  // window and overview → the viewer's layer map (no colour: the synthetic surface has none).
  pipeline::Scene scene = build_scene("sinusoid.yaml", {"grid.n=120"}, "sinusoid_layers");
  ASSERT_GT(scene.layers.cell_error.valid_count(), 0U);
  SceneSession s(std::move(scene), 64, 1);
  for (const char* name : {"texture", "mu_d", "error"}) {
    s.view->set_display(viewer::display_choice_from_string(name, "--display"));
    for (int level : {1, 0}) {
      if (level == 0) s.view->issue({viewer::RegionCommandType::kFiner});
      const viewer::Image img = s.view->capture();
      ASSERT_EQ(s.view->scene()->level, level);
      EXPECT_TRUE(s.view->display_note().empty()) << name << ": " << s.view->display_note();
      EXPECT_GT(s.view->window_range().hi, s.view->window_range().lo + 1e-9) << name;
      EXPECT_GT(s.view->overview_range().hi, s.view->overview_range().lo + 1e-9) << name;
      // The layer varies over the window, so the map's colours do: many distinct hues.
      std::set<int> hues;
      const viewer::PixelRect r = s.view->main_view();
      for (int y = r.y; y < r.y + r.height; y += 4) {
        for (int x = r.x; x < r.x + r.width; x += 4) {
          if (test::is_background(img, x, y)) continue;
          const int sum = std::max(1, img.at(x, y, 0) + img.at(x, y, 1) + img.at(x, y, 2));
          hues.insert(20 * img.at(x, y, 0) / sum * 20 + 20 * img.at(x, y, 2) / sum);
        }
      }
      EXPECT_GT(hues.size(), 5U) << name << " at level " << level;
    }
    s.view->issue({viewer::RegionCommandType::kCoarser});
    s.view->capture();
  }
  s.view->set_display({viewer::DisplayMode::kColour, viewer::MapLayer::kTexture});
  s.view->capture();
  EXPECT_NE(s.view->display_note().find("no colour"), std::string::npos);
}

TEST(ViewerScene, BuddhaAtSmallNIsDrawnAndShaded) {
  pipeline::Scene scene = build_scene(
      "happy_buddha.yaml", {"grid.n=200", "filters.outliers.enabled=false", "cross_check.enabled=false"}, "buddha");
  SceneSession s(std::move(scene), 128, 0);
  s.view->issue({viewer::RegionCommandType::kCoarser});  // the whole statue in one window
  const viewer::Image img = s.view->capture();
  viewer::write_png(img, (test::temp_dir("shots") / "buddha.png").string());
  // The statue is tall and narrow: a smaller share of the view than a full square grid.
  expect_drawn_and_shaded(img, s.view->main_view(), 0.12);
  // Finer: the window shows a part of the statue at twice the resolution.
  s.view->issue({viewer::RegionCommandType::kFiner});
  const viewer::Image fine = s.view->capture();
  EXPECT_EQ(s.view->scene()->level, 0);
  EXPECT_GT(test::fraction_changed(img, fine, s.view->main_view()), 0.3);
  expect_drawn_and_shaded(fine, s.view->main_view(), 0.12);
}

}  // namespace
}  // namespace hc
