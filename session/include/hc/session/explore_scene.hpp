#pragma once
/// @file explore_scene.hpp
/// A scene made ready for an interactive session (`hapticloud explore`): level 0 with the layers a
/// pyramid and a friction rebuild need, and its level-of-detail pyramid; plus the orientation
/// tool's cloud preview. Built off the UI thread (a re-scan or friction rebuild worker) and handed
/// to the UI thread, which swaps it in (scene_swap.hpp). GL-free; no OpenCV, PCL or yaml.

#include "hc/common/scene.hpp"
#include "hc/pipeline/cloud.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/surface_layers.hpp"
#include "hc/pipeline/transform.hpp"

#include <Eigen/Geometry>

#include <cstddef>
#include <memory>
#include <string>
#include <vector>

namespace hc::session {

/// A scene ready to explore. Immutable once handed over (shared between the UI thread and the
/// worker that built it).
struct ExploreScene {
  /// Level 0: geometry, model_to_grid, friction model and the layers depth, envelope, texture,
  /// mu_d, mu_s, cell_error (grid frame, metres; μ dimensionless) and colour_rgb8 (when the
  /// scene has them), kept for friction rebuilds.
  Scene base;
  std::shared_ptr<pipeline::LodPyramid> pyramid;  ///< built from `base`'s layers
  /// The view rotation the scene was scanned with (model → grid; the orientation tool's start).
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
  std::string description;   ///< for the window title and messages
  bool disarm = true;        ///< a new object (re-scan): swap it in with zero force (SceneSwap)
  bool keep_window = false;  ///< same object (friction rebuild): keep the current level and window
};

/// Level 0 of `scene` with only what a pyramid, the viewer and a friction rebuild need:
/// geometry, model_to_grid, friction model and the depth, envelope, texture, mu_d, mu_s and
/// cell_error layers and the colour (rows·cols·3 bytes; layers absent in `scene` stay absent; no
/// region ids, intensity or metadata). Copies; any thread. Throws only std::bad_alloc.
Scene explore_base_layers(const Scene& scene);

/// The ExploreScene of `scene`: when `recompute_layers`, its envelope, texture, μ_d and μ_s (and
/// friction model) are first recomputed from its depth with `layer_options`
/// (pipeline::compute_surface_layers: the friction rebuild); then level 0 is kept
/// (explore_base_layers) and the pyramid built (pipeline::LodPyramid::from_scene with
/// `layer_options` and `lod_options`). orientation, description, disarm and keep_window keep
/// their defaults for the caller to set. Any thread (a worker; takes up to seconds for large
/// scenes when recomputing). @throws what compute_surface_layers and LodPyramid throw
/// (hc::ConfigError for out-of-range options, hc::InputError for an empty depth layer).
std::shared_ptr<ExploreScene> build_explore_scene(Scene scene, const pipeline::SurfaceLayerOptions& layer_options,
                                                  const pipeline::LodOptions& lod_options, bool recompute_layers);

/// The filtered cloud of a run (`grid_frame_cloud`: grid frame, metres) taken back to the
/// recentred model frame with the inverse of `view` (before the view transform, so the
/// orientation tool can turn it), every k-th point so that at most `max_points` remain (k =
/// ceil(n / max_points)), non-finite points dropped; as x, y, z float triplets [m].
/// `max_points` must be ≥ 1 (0 is taken as 1). Any thread. Throws only std::bad_alloc.
std::vector<float> cloud_preview(const pipeline::Cloud& grid_frame_cloud, const pipeline::ViewTransform& view,
                                 std::size_t max_points);

}  // namespace hc::session
