// explore_scene: the friction rebuild of a session gives the layers the pipeline computes from
// the same depth with the new options (level 0 kept and in the pyramid), and the cloud preview
// takes grid-frame points back to the model frame.

#include "layered_sinusoid.hpp"

#include "hc/pipeline/surface_layers.hpp"
#include "hc/pipeline/transform.hpp"
#include "hc/session/explore_scene.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <numbers>

namespace hc::session {
namespace {

/// The validation sinusoid with its layers for `options` (tests/support/layered_sinusoid.hpp).
Scene sinusoid_scene(int n, const pipeline::SurfaceLayerOptions& options) { return test::layered_sinusoid(n, options); }

TEST(ExploreScene, TheFrictionRebuildGivesThePipelinesLayersForTheNewOptions) {
  pipeline::SurfaceLayerOptions before;
  before.friction_model = FrictionModel::kPaper;
  before.mu_s = 0.2;
  const Scene scene = sinusoid_scene(161, before);
  pipeline::SurfaceLayerOptions after = before;
  after.friction_model = FrictionModel::kCurvature;
  after.mu_s = 0.45;
  pipeline::LodOptions lod;
  lod.window_cells = 64;
  lod.min_cells = 20;

  const auto rebuilt = build_explore_scene(explore_base_layers(scene), after, lod, true);
  // Oracle: the pipeline's own layers for the same depth, the new options and the same haptic
  // window (μ_d's device scale depends on lod.window_cells, docs/friction.md).
  const pipeline::SurfaceLayers want = pipeline::compute_surface_layers(scene.depth(), after, lod.window_cells).value;
  ASSERT_NE(want.mu_d.values(), scene.layers.mu_d.values()) << "the new model must change μ_d for the test to mean anything";
  EXPECT_EQ(rebuilt->base.layers.mu_d.values(), want.mu_d.values());
  EXPECT_EQ(rebuilt->base.layers.mu_s.values(), want.mu_s.values());
  EXPECT_EQ(rebuilt->base.layers.envelope.values(), want.envelope_m.values());
  EXPECT_EQ(rebuilt->base.layers.texture.values(), want.texture_m.values());
  EXPECT_EQ(rebuilt->base.layers.depth.values(), scene.depth().values());
  ASSERT_TRUE(rebuilt->base.friction_model.has_value());
  EXPECT_EQ(*rebuilt->base.friction_model, FrictionModel::kCurvature);
  // The pyramid's level 0 holds the rebuilt layers.
  const auto l0 = rebuilt->pyramid->level(0);
  EXPECT_EQ(l0->mu_d.values(), want.mu_d.values());
  EXPECT_EQ(l0->mu_s.values(), want.mu_s.values());
  EXPECT_EQ(l0->depth_m.values(), scene.depth().values());
  EXPECT_GT(rebuilt->pyramid->level_count(), 1);

  // Without recomputing, the scene's own layers go in unchanged.
  const auto kept = build_explore_scene(explore_base_layers(scene), before, lod, false);
  EXPECT_EQ(kept->base.layers.mu_d.values(), scene.layers.mu_d.values());
  EXPECT_EQ(kept->pyramid->level(0)->mu_d.values(), scene.layers.mu_d.values());
}

TEST(ExploreScene, BaseLayersKeepOnlyWhatAPyramidTheViewerAndARebuildNeed) {
  Scene scene = sinusoid_scene(41, pipeline::SurfaceLayerOptions{});
  scene.layers.region_id = scene.layers.depth;
  scene.layers.intensity = scene.layers.depth;
  scene.layers.colour_rgb8.assign(41 * 41 * 3, 7);
  scene.layers.cell_error = HeightField(scene.geometry, 0.0005F);
  scene.model_to_grid.translate(Eigen::Vector3d(0.01, 0.02, 0.03));
  const Scene base = explore_base_layers(scene);
  EXPECT_EQ(base.layers.region_id.rows(), 0);
  EXPECT_EQ(base.layers.intensity.rows(), 0);
  // The viewer's colour and cross-check error survive (a friction rebuild starts from `base`).
  EXPECT_EQ(base.layers.colour_rgb8, scene.layers.colour_rgb8);
  EXPECT_EQ(base.layers.cell_error.values(), scene.layers.cell_error.values());
  const auto rebuilt = build_explore_scene(base, pipeline::SurfaceLayerOptions{}, LodOptions{}, true);
  EXPECT_EQ(rebuilt->pyramid->level(0)->colour_rgb8, scene.layers.colour_rgb8);
  EXPECT_EQ(rebuilt->pyramid->level(0)->cell_error_m.values(), scene.layers.cell_error.values());
  EXPECT_TRUE(base.layers.has_surface_layers());
  EXPECT_EQ(base.layers.texture.values(), scene.layers.texture.values());
  EXPECT_TRUE(base.model_to_grid.isApprox(scene.model_to_grid));
  EXPECT_EQ(base.geometry.rows, 41);
}

TEST(ExploreScene, TheCloudPreviewIsTheModelFrameCloudSubsampled) {
  pipeline::ViewTransform view;
  view.rotation = pipeline::rotation_from_axis_angle(Eigen::Vector3d(1, 2, 3), 40.0);
  view.translation_m = Eigen::Vector3d(0.01, -0.02, 0.5);
  view.scale = 2.0;
  const int n = 10;
  Eigen::Matrix3Xd model(3, n);
  for (int i = 0; i < n; ++i) model.col(i) = Eigen::Vector3d(0.001 * i, -0.002 * i, 0.003 * (i % 3));
  pipeline::Cloud grid;
  grid.xyz.resize(3, n);
  for (int i = 0; i < n; ++i) {
    // p_grid = scale · R · p + t (transform.hpp), written out here as the oracle.
    grid.xyz.col(i) = view.scale * (view.rotation * model.col(i)) + view.translation_m;
  }
  grid.xyz.col(4).setConstant(std::numeric_limits<double>::quiet_NaN());

  const std::vector<float> all = cloud_preview(grid, view, 100);
  ASSERT_EQ(all.size(), 3U * (n - 1));  // the NaN point is dropped
  std::size_t j = 0;
  for (int i = 0; i < n; ++i) {
    if (i == 4) continue;
    for (int k = 0; k < 3; ++k, ++j) EXPECT_NEAR(all[j], model(k, i), 1e-6) << "point " << i;
  }
  // At most 3 points: every 4th (ceil(10 / 3)): 0, 4 (NaN, dropped), 8.
  const std::vector<float> few = cloud_preview(grid, view, 3);
  ASSERT_EQ(few.size(), 6U);
  EXPECT_NEAR(few[0], model(0, 0), 1e-6);
  EXPECT_NEAR(few[3], model(0, 8), 1e-6);
  EXPECT_NEAR(few[4], model(1, 8), 1e-6);
}

}  // namespace
}  // namespace hc::session
