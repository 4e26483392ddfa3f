#pragma once
// A scene of the paper's validation sinusoid with its surface layers, built in the test (the
// session tests' common fixture): a 100 mm square of n × n samples centred on the origin, a
// 4 mm sinusoid of 40 mm wavelength plus a 0.2 mm texture of 2 mm (grid frame, metres), and the
// envelope, texture, μ_d and μ_s that pipeline::compute_surface_layers makes with `options` for a
// haptic window of `window_cells` samples.

#include "hc/common/scene.hpp"
#include "hc/pipeline/surface_layers.hpp"

#include <cmath>
#include <numbers>

namespace hc::test {

inline Scene layered_sinusoid(int n, const pipeline::SurfaceLayerOptions& options, int window_cells = 200) {
  const double side = 0.1, cell = side / (n - 1);
  Scene s;
  s.geometry = GridGeometry{n, n, -side / 2, -side / 2, cell};
  s.layers.depth = HeightField(s.geometry);
  const double k = 2 * std::numbers::pi / 0.04, kt = 2 * std::numbers::pi / 0.002;
  for (int r = 0; r < n; ++r) {
    for (int c = 0; c < n; ++c) {
      const double x = s.geometry.x_of_col(c), y = s.geometry.y_of_row(r);
      s.layers.depth.at(r, c) =
          static_cast<float>(0.004 * std::sin(k * x) * std::sin(k * y) + 0.0002 * std::sin(kt * x) * std::sin(kt * y));
    }
  }
  const pipeline::SurfaceLayers l = pipeline::compute_surface_layers(s.depth(), options, window_cells).value;
  s.layers.envelope = l.envelope_m;
  s.layers.texture = l.texture_m;
  s.layers.mu_d = l.mu_d;
  s.layers.mu_s = l.mu_s;
  s.friction_model = l.friction_model;
  s.layer_options = options;
  s.lod.window_cells = window_cells;
  return s;
}

}  // namespace hc::test
