#pragma once
/// @file haptics_test_support.hpp
/// Small helpers shared by the hc::haptics tests: analytic height fields and invariant checks.

#include "hc/haptics/haptic_surface.hpp"
#include "hc/haptics/proxy.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <memory>
#include <numbers>

namespace hc::haptics::test {

/// rows × cols field over x0 + c·cell, y0 + r·cell filled from fn(x, y).
inline HeightField make_field(int rows, int cols, double cell_m, double x0_m, double y0_m,
                              const std::function<double(double, double)>& fn) {
  HeightField f(GridGeometry{rows, cols, x0_m, y0_m, cell_m});
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      f.at(r, c) = static_cast<float>(fn(x0_m + c * cell_m, y0_m + r * cell_m));
    }
  }
  return f;
}

/// Square field of n × n samples centred on the origin, side `side_m`.
inline HeightField make_square(int n, double side_m, const std::function<double(double, double)>& fn) {
  const double cell = side_m / (n - 1);
  return make_field(n, n, cell, -side_m / 2, -side_m / 2, fn);
}

inline std::unique_ptr<HapticSurface> make_surface(const HeightField& depth,
                                                   const SurfaceOptions& options = {}) {
  SurfaceLayers layers;
  layers.depth = &depth;
  return std::make_unique<HapticSurface>(layers, options);
}

/// The paper's validation sinusoid plus a fine texture: z = A sin(2πx/λ) sin(2πy/λ) + a sin(2πx/λt) sin(2πy/λt).
inline double sinusoid(double x, double y, double amp = 0.004, double lambda = 0.04,
                       double tex_amp = 0.0002, double tex_lambda = 0.002) {
  const double k = 2 * std::numbers::pi / lambda;
  const double kt = 2 * std::numbers::pi / tex_lambda;
  return amp * std::sin(k * x) * std::sin(k * y) + tex_amp * std::sin(kt * x) * std::sin(kt * y);
}

/// Invariants of every tick: finite outputs, force within the cap, proxy not below the surface.
inline ::testing::AssertionResult tick_invariants(const ProxyState& s, const HapticSurface& surface,
                                                  const ProxyParams& p) {
  if (!s.proxy_m.allFinite() || !s.force_n.allFinite() || !std::isfinite(s.beta_rad())) {
    return ::testing::AssertionFailure() << "non-finite output";
  }
  if (s.force_n.norm() > p.max_force_n * (1 + 1e-12)) {
    return ::testing::AssertionFailure() << "force " << s.force_n.norm() << " N above cap";
  }
  const double below = surface.height(s.proxy_m.x(), s.proxy_m.y()) - s.proxy_m.z();
  if (below > 1e-6) {
    return ::testing::AssertionFailure() << "proxy " << below * 1e6 << " um below the surface at ("
                                         << s.proxy_m.transpose() << ")";
  }
  return ::testing::AssertionSuccess();
}

}  // namespace hc::haptics::test
