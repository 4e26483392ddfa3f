#pragma once
/// @file godobject_oracle.hpp
/// A brute-force reference for the point god-object with Coulomb friction, for tests: how far
/// would an ideal proxy slide from where step_proxy() left it? Used to tell a renderer that
/// stalls (a defect) from a proxy that is held by the geometry or by friction (correct).

#include "hc/haptics/haptic_surface.hpp"
#include "hc/haptics/proxy.hpp"

#include <Eigen/Core>

#include <cmath>
#include <numbers>

namespace hc::haptics::test {

/// Ideal frictional god-object motion from `proxy_m` (on the surface) under the pull of the
/// HIP `hip_m`, by exhaustive local search: repeatedly step along the best of 48 surface chords
/// about `step_cells` cells long around the current point (48 directions in x-y, ends put on
/// z = f(x, y), the x-y step shortened on steep ground), where "allowed"
/// means the pull along the chord exceeds mu times the pull across it (Coulomb: the proxy
/// slides while |f_t| > μ·|f_n|, with everything not along the motion counted as normal force,
/// which can only over-estimate friction) and the chord ends closer to the HIP; "best" is the
/// largest pull along it. Stops when no chord is allowed or after a path as long as the
/// proxy-HIP distance. Returns the distance between start and end, in cells.
/// Cost: 48 surface samples per step. Not real-time.
inline double godobject_slide_cells(const HapticSurface& s, const Eigen::Vector3d& proxy_m,
                                    const Eigen::Vector3d& hip_m, double mu,
                                    double step_cells = 0.02) {
  constexpr int kDirections = 48;
  const double cell = s.geometry().cell_size_m;
  const double step = step_cells * cell;
  Eigen::Vector3d q = proxy_m;
  const double budget = (hip_m - q).norm();
  double travelled = 0.0;
  while (travelled < budget) {
    const Eigen::Vector3d vh = hip_m - q;
    double best = -1.0;
    Eigen::Vector3d next = q;
    for (int i = 0; i < kDirections; ++i) {
      const double a = 2.0 * std::numbers::pi * i / kDirections;
      Eigen::Vector3d c(q.x() + step * std::cos(a), q.y() + step * std::sin(a), 0.0);
      c.z() = s.height(c.x(), c.y());
      const double chord = (c - q).norm();
      if (chord > 1.01 * step) {  // steep: shorten the x-y step so that the chord is ~step long
        const double h = step * step / chord;
        c = Eigen::Vector3d(q.x() + h * std::cos(a), q.y() + h * std::sin(a), 0.0);
        c.z() = s.height(c.x(), c.y());
      }
      const Eigen::Vector3d e = (c - q).normalized();
      const double along = vh.dot(e);
      const double across = (vh - along * e).norm();
      if (along > mu * across && along > best && (hip_m - c).squaredNorm() < vh.squaredNorm()) {
        best = along;
        next = c;
      }
    }
    if (best < 0.0) break;
    travelled += (next - q).norm();
    q = next;
  }
  return (q - proxy_m).norm() / cell;
}

/// True when step_proxy() left the proxy where it was although Eq. 5 asked it to slide: in
/// contact, not held by static friction, and the friction factor times |v_t| (the distance to
/// the point Eq. 5 heads for) above the convergence tolerance. `before_m` is the proxy of the
/// previous tick.
inline bool proxy_held_while_sliding(const ProxyState& s, const Eigen::Vector3d& before_m,
                                     const ProxyParams& p) {
  return s.in_contact && !s.sticking && s.proxy_m == before_m &&
         friction_factor(s.tangential_m, s.normal_m, s.mu_d) * s.tangential_m > p.convergence_m;
}

}  // namespace hc::haptics::test
