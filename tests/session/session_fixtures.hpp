#pragma once
/// @file session_fixtures.hpp
/// Pyramids and controller options shared by the hc::session tests.

#include "hc/haptics/simulated_device.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/session/lod_controller.hpp"

#include <memory>
#include <utility>

namespace hc::session::test {

/// A pyramid over `depth` (level 0, no layers; levels computed with μ_d in [0.1, 0.3], μ_s 0.2).
inline std::shared_ptr<pipeline::LodPyramid> pyramid_of(HeightField depth, int window_cells, int min_cells) {
  pipeline::LodLevel l0;
  l0.depth_m = std::move(depth);
  pipeline::LodOptions opt;
  opt.window_cells = window_cells;
  opt.min_cells = min_cells;
  pipeline::SurfaceLayerOptions layers;
  layers.mu_min = 0.1;
  layers.mu_max = 0.3;
  layers.mu_s = 0.2;
  return std::make_shared<pipeline::LodPyramid>(std::move(l0), layers, opt);
}

/// Controller options for the simulated device's workspace.
inline LodControllerOptions controller_options(bool prefetch_neighbours = true) {
  LodControllerOptions o;
  o.device_half_extent_m = haptics::SimulatedDevice::default_info().workspace_half_extent_m;
  o.prefetch_neighbours = prefetch_neighbours;
  return o;
}

}  // namespace hc::session::test
