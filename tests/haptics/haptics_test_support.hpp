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

// ---------------------------------------------------------------- long sliding, passivity

struct LoopResult {
  double first_loop_work_j = 0, max_loop_work_j = -1e9, total_work_j = 0;
  double max_lag_m = 0, min_window_travel_ratio = 1e9;
  double max_force_n = 0;
};

/// Circles of radius r around centre_m (x, y), one per `ticks_per_loop`, pressing `press_m` below the
/// envelope; trapezoidal work of the rendered force on the HIP per loop.
inline LoopResult slide_loops(const HapticSurface& s, const ProxyParams& p, int loops, int ticks_per_loop,
                              const Eigen::Vector3d& centre_m, double r, double press_m,
                              const std::function<double(double, double)>& envelope) {
  using Eigen::Vector3d;
  constexpr double kDt = 1e-3;
  LoopResult res;
  ProxyState st;
  const auto hip_at = [&](int k) {
    const double a = 2 * std::numbers::pi * k / ticks_per_loop;
    const double x = centre_m.x() + r * std::cos(a), y = centre_m.y() + r * std::sin(a);
    return Vector3d(x, y, envelope(x, y) - press_m);
  };
  // Approach from above to the start of the loop.
  const Vector3d start = hip_at(0);
  for (int k = 0; k <= 50; ++k) {
    st = step_proxy(st, HipInput{start + Vector3d(0, 0, 0.01 * (50 - k) / 50.0), kDt, true}, &s, p);
  }
  for (int k = 0; k < 300; ++k) st = step_proxy(st, HipInput{start, kDt, true}, &s, p);  // ramp done
  Vector3d f_prev = st.force_n, x_prev = start;
  double loop_work = 0, window_hip = 0, window_proxy = 0;
  Vector3d proxy_prev = st.proxy_m;
  for (int loop = 0; loop < loops; ++loop) {
    loop_work = 0;
    for (int k = 1; k <= ticks_per_loop; ++k) {
      const Vector3d x = hip_at(k);
      st = step_proxy(st, HipInput{x, kDt, true}, &s, p);
      if (!(st.force_n.norm() <= p.max_force_n * (1 + 1e-12)) || !st.proxy_m.allFinite()) {
        ADD_FAILURE() << "bad force or proxy at loop " << loop << " tick " << k;
        return res;
      }
      const double below = s.height(st.proxy_m.x(), st.proxy_m.y()) - st.proxy_m.z();
      if (below > 1e-6) {
        ADD_FAILURE() << "proxy below surface by " << below;
        return res;
      }
      loop_work += 0.5 * (f_prev + st.force_n).dot(x - x_prev);
      window_hip += (x - x_prev).head<2>().norm();
      window_proxy += (st.proxy_m - proxy_prev).head<2>().norm();
      if (k % 100 == 0) {
        res.min_window_travel_ratio = std::min(res.min_window_travel_ratio, window_proxy / window_hip);
        window_hip = window_proxy = 0;
      }
      res.max_lag_m = std::max(res.max_lag_m, (x - st.proxy_m).head<2>().norm());
      res.max_force_n = std::max(res.max_force_n, st.force_n.norm());
      f_prev = st.force_n;
      x_prev = x;
      proxy_prev = st.proxy_m;
    }
    if (loop == 0) res.first_loop_work_j = loop_work;
    res.max_loop_work_j = std::max(res.max_loop_work_j, loop_work);
    res.total_work_j += loop_work;
  }
  return res;
}

}  // namespace hc::haptics::test
