#include "hc/session/explore_scene.hpp"

#include <algorithm>
#include <utility>

namespace hc::session {

Scene explore_base_layers(const Scene& s) {
  Scene c;
  c.geometry = s.geometry;
  c.model_to_grid = s.model_to_grid;
  c.layers.depth = s.layers.depth;
  c.layers.envelope = s.layers.envelope;
  c.layers.texture = s.layers.texture;
  c.layers.mu_d = s.layers.mu_d;
  c.layers.mu_s = s.layers.mu_s;
  c.layers.cell_error = s.layers.cell_error;
  c.layers.colour_rgb8 = s.layers.colour_rgb8;
  c.friction_model = s.friction_model;
  return c;
}

std::shared_ptr<ExploreScene> build_explore_scene(Scene scene, const pipeline::SurfaceLayerOptions& layer_options,
                                                  const pipeline::LodOptions& lod_options, bool recompute_layers) {
  auto b = std::make_shared<ExploreScene>();
  if (recompute_layers) {
    pipeline::SurfaceLayers l = pipeline::compute_surface_layers(scene.depth(), layer_options, lod_options.window_cells).value;
    scene.layers.envelope = std::move(l.envelope_m);
    scene.layers.texture = std::move(l.texture_m);
    scene.layers.mu_d = std::move(l.mu_d);
    scene.layers.mu_s = std::move(l.mu_s);
    scene.friction_model = l.friction_model;
  }
  b->base = explore_base_layers(scene);
  b->pyramid = pipeline::LodPyramid::from_scene(std::move(scene), layer_options, lod_options);
  return b;
}

std::vector<float> cloud_preview(const pipeline::Cloud& grid_frame_cloud, const pipeline::ViewTransform& view,
                                 std::size_t max_points) {
  max_points = std::max<std::size_t>(1, max_points);
  const Eigen::Affine3d to_model = view.matrix().inverse();
  const std::size_t n = grid_frame_cloud.size();
  const std::size_t stride = std::max<std::size_t>(1, (n + max_points - 1) / max_points);
  std::vector<float> out;
  out.reserve(3 * (n / stride + 1));
  for (std::size_t i = 0; i < n; i += stride) {
    const Eigen::Vector3d p = to_model * grid_frame_cloud.xyz.col(static_cast<Eigen::Index>(i));
    if (!p.allFinite()) continue;
    for (int k = 0; k < 3; ++k) out.push_back(static_cast<float>(p[k]));
  }
  return out;
}

}  // namespace hc::session
