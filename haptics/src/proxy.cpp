#include "hc/haptics/proxy.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <string>

namespace hc::haptics {
namespace {

/// A point counts as below the surface only when it is more than this below it [m].
constexpr double kBelowTol = 1.0e-12;
constexpr double kInf = std::numeric_limits<double>::infinity();

/// First s ∈ [0, L] where G(s) = C + B·s + A·s² drops below −kBelowTol, G(0) = C.
/// On success writes the root of G = 0 where G decreases (the entry into the solid).
bool first_drop(double A, double B, double C, double L, double& s_out) noexcept {
  if (C < -kBelowTol) {
    s_out = 0.0;
    return true;
  }
  C = std::max(C, 0.0);
  double lo = 0.0;
  double hi = L;
  // Restrict [lo, hi] to where G decreases, so that it holds exactly one downward root.
  if (A > 0.0) {
    const double sv = -B / (2.0 * A);
    if (!(sv > 0.0)) return false;  // G increasing on [0, L]
    if (sv < L) hi = sv;
  } else if (A < 0.0) {
    const double sv = -B / (2.0 * A);
    if (!(sv < L)) return false;  // G increasing on [0, L]
    if (sv > 0.0) lo = sv;
  }
  const double g_hi = C + hi * (B + A * hi);
  if (!(g_hi < -kBelowTol)) return false;
  // The decreasing root is (−B − √D)/(2A) = 2C/(−B + √D); pick the cancellation-free form.
  const double sq = std::sqrt(std::max(B * B - 4.0 * A * C, 0.0));
  double r = 0.0;
  if (B < 0.0) {
    r = 2.0 * C / (-B + sq);
  } else if (A != 0.0) {
    r = (-B - sq) / (2.0 * A);
  } else {
    r = hi;  // unreachable: B ≥ 0 and A = 0 cannot drop below zero from C ≥ 0
  }
  if (!(r == r)) r = hi;
  s_out = std::clamp(r, lo, hi);
  return true;
}

/// First drop below the constant floor on [t0, t1] of z(t) = az + dz·t.
bool floor_drop(double az, double dz, double floor_m, double t0, double t1, double& t_out) noexcept {
  const double g0 = az + dz * t0 - floor_m;
  if (g0 < -kBelowTol) {
    t_out = t0;
    return true;
  }
  const double g1 = az + dz * t1 - floor_m;
  if (!(g1 < -kBelowTol)) return false;
  const double g0c = std::max(g0, 0.0);
  t_out = std::clamp(t0 + (t1 - t0) * g0c / (g0c - g1), t0, t1);
  return true;
}

void clip_slab(double p, double d, double lo, double hi, double& t_in, double& t_out,
               bool& empty) noexcept {
  if (d == 0.0) {
    if (p < lo || p > hi) empty = true;
    return;
  }
  double t0 = (lo - p) / d;
  double t1 = (hi - p) / d;
  if (t0 > t1) std::swap(t0, t1);
  t_in = std::max(t_in, t0);
  t_out = std::min(t_out, t1);
}

/// Eq. 3–5 iterations with static friction; xp and sp (the sample at xp) are updated in place.
/// Uses the unnormalised normal m = (−f_x, −f_y, 1), q = |m|², so that n = m/√q, n·v_h = m·v_h/√q
/// and (n·v_h)·n = (m·v_h/q)·m: one division and one square root per iteration.
void contact_iterations(const HapticSurface& surface, const Eigen::Vector3d& xh,
                        Eigen::Vector3d& xp, SurfaceSample& sp, ProxyState& s,
                        const ProxyParams& p) noexcept {
  const double cell = surface.geometry().cell_size_m;
  const double max_step_xy = p.max_step_cells * cell;
  const double conv2 = p.convergence_m * p.convergence_m;
  const bool maps = p.friction_enabled && surface.has_friction_maps();
  const int guard_cells = 2 * static_cast<int>(std::ceil(p.max_step_cells)) + 4;
  const Eigen::Vector3d guard_lift(0.0, 0.0, 0.1 * cell);
  FrictionSample mu{0.0, 0.0};
  if (p.friction_enabled) mu = surface.friction(xp.x(), xp.y());
  const Eigen::Vector3d x_start = xp;
  bool friction_limited = false;
  double last_t2 = 0.0, last_q = 1.0, last_mv = 0.0;
  for (int k = 0; k < p.max_iterations; ++k) {
    const Eigen::Vector3d m(-sp.dz_dx, -sp.dz_dy, 1.0);  // normal, unnormalised
    const double q = m.squaredNorm();
    const Eigen::Vector3d vh = xh - xp;                   // Eq. 3: v_h = X_h − X_p
    const double mv = m.dot(vh);                          // √q·(n·v_h) = −√q·f_n/k
    const Eigen::Vector3d vt = vh - (mv / q) * m;          // Eq. 3: v_t = v_h − (n·v_h) n
    const double t2 = vt.squaredNorm();                   // |v_t|² ∝ |f_t|²
    last_t2 = t2;
    last_q = q;
    last_mv = mv;
    if (k == 0 && s.sticking) {
      // Static friction holds while |f_t| < μ_s·|f_n| (Sec. 3.2), with f_n > 0 (pressing).
      if (mv < 0.0 && t2 * q < mu.mu_s * mu.mu_s * mv * mv) break;
      s.sticking = false;
    }
    // Eq. 5 friction factor 1 − μ_d·cot β, cot β = f_n/|f_t| = −mv/√(q·t2), clamped to [0, 1].
    double factor = 1.0;
    if (mu.mu_d > 0.0 && mv < 0.0) {
      const double r = std::sqrt(q * t2);
      const double resist = -mu.mu_d * mv;
      factor = resist < r ? 1.0 - resist / r : 0.0;
    }
    if (factor <= 0.0) {
      // Inside the dynamic friction cone: the proxy stops. If it has not moved at all this
      // tick it is at rest, and static friction takes over.
      if (k == 0) s.sticking = true;
      break;
    }
    // Converged when the proxy is within tolerance of where Eq. 5 is heading (the friction-cone
    // equilibrium), whatever ρ: factor·|v_t| is that distance.
    if (factor * factor * t2 < conv2) {
      friction_limited = factor < 1.0;
      break;
    }
    Eigen::Vector3d step = (p.rho * factor) * vt;         // Eq. 5
    double step_xy2 = step.x() * step.x() + step.y() * step.y();
    if (step_xy2 > max_step_xy * max_step_xy) {
      step *= max_step_xy / std::sqrt(step_xy2);
      step_xy2 = max_step_xy * max_step_xy;
    }
    if (step_xy2 > cell * cell) {
      // A step over more than one cell could jump a thin feature: take it only if the tangent
      // path, lifted by a tenth of a cell, runs through no material; else one cell.
      const SegmentHit block =
          find_first_crossing(surface, xp + guard_lift, xp + step + guard_lift, guard_cells);
      if (block.hit || block.budget_exceeded) step *= cell / std::sqrt(step_xy2);
    }
    const double dist0_2 = vh.squaredNorm();
    bool accepted = false;
    for (int halving = 0; halving < 4 && !accepted; ++halving) {
      Eigen::Vector3d c = xp + step;
      SurfaceSample sc = surface.sample(c.x(), c.y());
      // Re-project along n: one Newton step on g(τ) = z + τ n_z − f(x + τ n_x, y + τ n_y),
      // worth a second sample only when the tangent step left the surface noticeably.
      const double g = c.z() - sc.z_m;
      if (g * g > conv2) {
        const double dg = m.z() - (sc.dz_dx * m.x() + sc.dz_dy * m.y());  // √q·g'(0) along n
        if (dg > 0.05 * std::sqrt(q)) {
          const double tau = std::clamp(-g / dg, -cell, cell);  // along m (= √q·n)
          c += tau * m;
          sc = surface.sample(c.x(), c.y());
        }
      }
      c.z() = sc.z_m;  // exactly onto z = f(x, y)
      if ((xh - c).squaredNorm() <= dist0_2 + kBelowTol * kBelowTol) {
        xp = c;
        sp = sc;
        accepted = true;
      } else {
        step *= 0.5;
      }
    }
    ++s.iterations;
    if (!accepted) break;
    if (maps) mu = surface.friction(xp.x(), xp.y());
  }
  // At rest on the dynamic friction cone for a whole tick: static friction takes over.
  if (friction_limited && (xp - x_start).squaredNorm() < conv2) s.sticking = true;
  s.tangential_m = std::sqrt(last_t2);
  s.normal_m = -last_mv / std::sqrt(last_q);
  s.mu_d = mu.mu_d;
  s.mu_s = mu.mu_s;
}

}  // namespace

void validate_proxy_params(const ProxyParams& p) {
  const auto fail = [](const char* name, double value, const char* expected) {
    std::ostringstream s;
    s << "proxy parameter " << name << " = " << value << ", expected " << expected;
    throw ConfigError(s.str());
  };
  if (!(p.stiffness_n_per_m >= 0.0) || !std::isfinite(p.stiffness_n_per_m))
    fail("stiffness_n_per_m", p.stiffness_n_per_m, "a finite value >= 0");
  if (!(p.damping_n_s_per_m >= 0.0) || !std::isfinite(p.damping_n_s_per_m))
    fail("damping_n_s_per_m", p.damping_n_s_per_m, "a finite value >= 0");
  if (!(p.max_force_n > 0.0) || !std::isfinite(p.max_force_n))
    fail("max_force_n", p.max_force_n, "a finite value > 0");
  if (!(p.rho > 0.0 && p.rho <= 1.0)) fail("rho", p.rho, "a value in (0, 1]");
  if (p.max_iterations < 1 || p.max_iterations > 1000)
    fail("max_iterations", p.max_iterations, "an integer in [1, 1000]");
  if (!(p.convergence_m >= 0.0) || !std::isfinite(p.convergence_m))
    fail("convergence_m", p.convergence_m, "a finite value >= 0");
  if (!(p.max_step_cells > 0.0) || !std::isfinite(p.max_step_cells))
    fail("max_step_cells", p.max_step_cells, "a finite value > 0");
  if (!(p.ramp_time_s >= 0.0) || !std::isfinite(p.ramp_time_s))
    fail("ramp_time_s", p.ramp_time_s, "a finite value >= 0");
  if (!(p.gate_force_n >= 0.0) || !std::isfinite(p.gate_force_n))
    fail("gate_force_n", p.gate_force_n, "a finite value >= 0");
  if (p.max_cells_per_tick < 1) fail("max_cells_per_tick", p.max_cells_per_tick, "an integer >= 1");
}

double friction_factor(double tangential_m, double normal_m, double mu_d) noexcept {
  if (!(mu_d > 0.0) || !(normal_m > 0.0)) return 1.0;  // no friction, or β ≥ 90°
  const double resist = mu_d * normal_m;               // μ_d·|f_n| in length units
  if (!(tangential_m > resist)) return 0.0;            // β → 0 or inside the friction cone
  return std::clamp(1.0 - resist / tangential_m, 0.0, 1.0);
}

SegmentHit find_first_crossing(const HapticSurface& surface, const Eigen::Vector3d& a,
                               const Eigen::Vector3d& b, int max_cells) noexcept {
  SegmentHit hit;
  hit.point_m = b;
  const GridGeometry& g = surface.geometry();
  const double cs = g.cell_size_m;
  const double ua = (a.x() - g.x0_m) / cs;
  const double va = (a.y() - g.y0_m) / cs;
  const double du = (b.x() - a.x()) / cs;
  const double dv = (b.y() - a.y()) / cs;
  const double dz = b.z() - a.z();
  const double max_u = static_cast<double>(g.cols - 1);
  const double max_v = static_cast<double>(g.rows - 1);
  const double floor_m = surface.floor_m();

  const auto finish = [&](double t, bool is_hit) {
    hit.hit = is_hit;
    hit.t = t;
    hit.point_m = a + t * (b - a);
    if (is_hit) hit.point_m.z() = surface.height(hit.point_m.x(), hit.point_m.y());
    return hit;
  };

  double t_in = 0.0;
  double t_out = 1.0;
  bool empty = false;
  clip_slab(ua, du, 0.0, max_u, t_in, t_out, empty);
  clip_slab(va, dv, 0.0, max_v, t_in, t_out, empty);
  if (t_in > t_out) empty = true;
  double t_hit = 0.0;
  if (empty) {
    if (floor_drop(a.z(), dz, floor_m, 0.0, 1.0, t_hit)) return finish(t_hit, true);
    return finish(1.0, false);
  }
  if (t_in > 0.0 && floor_drop(a.z(), dz, floor_m, 0.0, t_in, t_hit)) return finish(t_hit, true);

  // 2-D DDA over the padded grid's cells on [t_in, t_out].
  double t = t_in;
  const double u0 = ua + du * t;
  const double v0 = va + dv * t;
  int i = static_cast<int>(std::floor(u0));
  int j = static_cast<int>(std::floor(v0));
  if (du < 0.0 && u0 == static_cast<double>(i)) --i;  // leaving a grid line towards −u
  if (dv < 0.0 && v0 == static_cast<double>(j)) --j;
  i = std::clamp(i, 0, g.cols - 2);
  j = std::clamp(j, 0, g.rows - 2);
  const int si = du > 0.0 ? 1 : -1;
  const int sj = dv > 0.0 ? 1 : -1;
  const float* base = &surface.bilinear().view().data[0];
  const std::ptrdiff_t stride = surface.bilinear().view().row_stride;
  while (true) {
    if (hit.cells_visited >= max_cells) {
      hit.budget_exceeded = true;
      return finish(t, false);
    }
    ++hit.cells_visited;
    const double tu = du > 0.0 ? (i + 1 - ua) / du : (du < 0.0 ? (i - ua) / du : kInf);
    const double tv = dv > 0.0 ? (j + 1 - va) / dv : (dv < 0.0 ? (j - va) / dv : kInf);
    const double t_exit = std::max(t, std::min({tu, tv, t_out}));
    const float* r0 = base + static_cast<std::ptrdiff_t>(j) * stride + i;
    const double z00 = r0[0], z10 = r0[1], z01 = r0[stride], z11 = r0[stride + 1];
    const double e = z10 - z00;
    const double gg = z01 - z00;
    const double h = z00 - z10 - z01 + z11;
    const double uu = ua + du * t - i;
    const double vv = va + dv * t - j;
    // G(s) = z(t + s) − f(u(t + s), v(t + s)) = C + B·s + A·s² inside this cell.
    const double C = (a.z() + dz * t) - (z00 + e * uu + gg * vv + h * uu * vv);
    const double B = dz - (e * du + gg * dv + h * (uu * dv + vv * du));
    const double A = -h * du * dv;
    double s = 0.0;
    if (first_drop(A, B, C, t_exit - t, s)) return finish(t + s, true);
    if (t_exit >= t_out) break;
    if (tu <= tv) {
      i += si;
    } else {
      j += sj;
    }
    if (i < 0 || i > g.cols - 2 || j < 0 || j > g.rows - 2) break;
    t = t_exit;
  }
  if (t_out < 1.0 && floor_drop(a.z(), dz, floor_m, t_out, 1.0, t_hit)) return finish(t_hit, true);
  return finish(1.0, false);
}

ProxyState step_proxy(const ProxyState& previous, const HipInput& hip,
                      const HapticSurface* surface, const ProxyParams& p) noexcept {
  ProxyState s = previous;
  s.iterations = 0;
  s.cells_visited = 0;
  s.saturated = false;
  s.status = ProxyStatus::kOk;
  const Eigen::Vector3d& xh = hip.position_m;
  if (!xh.allFinite() || !std::isfinite(hip.dt_s)) {
    s.force_n.setZero();
    s.gate_open = false;
    s.ramp = 0.0;
    s.status = ProxyStatus::kNonFiniteInput;
    return s;
  }
  const double dt = std::max(hip.dt_s, 0.0);
  const bool had_history = previous.initialized && previous.hip_m.allFinite();
  Eigen::Vector3d xp = previous.proxy_m;
  s.tangential_m = 0.0;
  s.normal_m = 0.0;

  if (surface == nullptr) {
    xp = xh;
    s.in_contact = false;
    s.sticking = false;
    s.status = ProxyStatus::kNoSurface;
    s.initialized = true;
  } else {
    SurfaceSample sp;
    if (!previous.initialized || !xp.allFinite()) {
      // First tick: on the HIP, or on the surface above it when the HIP starts inside.
      s.initialized = true;
      sp = surface->sample(xh.x(), xh.y());
      xp = xh;
      s.in_contact = xh.z() < sp.z_m;
      s.sticking = s.in_contact;
      if (s.in_contact) xp.z() = sp.z_m;
    } else {
      sp = surface->sample(xp.x(), xp.y());
      if (s.in_contact) {
        xp.z() = sp.z_m;  // keep exactly on the (possibly new) surface
      } else if (xp.z() < sp.z_m) {
        xp.z() = sp.z_m;  // a new surface rose above a free proxy: lift it and touch down
        s.in_contact = true;
        s.sticking = true;
      }
    }
    const bool hip_inside = xh.z() < surface->height(xh.x(), xh.y());
    bool contact_phase = s.in_contact && hip_inside;
    if (!contact_phase) {
      const SegmentHit hit = find_first_crossing(*surface, xp, xh, p.max_cells_per_tick);
      s.cells_visited = hit.cells_visited;
      if (hit.hit) {
        if (!s.in_contact) s.sticking = true;  // touch-down: static until |f_t| ≥ μ_s|f_n|
        xp = hit.point_m;
        sp = surface->sample(xp.x(), xp.y());
        xp.z() = sp.z_m;
        s.in_contact = true;
        contact_phase = true;
      } else {
        xp = hit.point_m;
        s.in_contact = false;
        s.sticking = false;
        if (hit.budget_exceeded) {
          s.status = ProxyStatus::kCellBudgetExceeded;
          const double f = surface->height(xp.x(), xp.y());
          if (xp.z() < f) xp.z() = f;
        }
      }
    }
    if (contact_phase) {
      contact_iterations(*surface, xh, xp, sp, s, p);
    } else {
      const FrictionSample mu =
          p.friction_enabled ? surface->friction(xp.x(), xp.y()) : FrictionSample{};
      s.mu_d = mu.mu_d;
      s.mu_s = mu.mu_s;
    }
  }

  // Force stage (paper Sec. 4: F = −k·x, x = X_h − X_p), then cap, gate and ramp.
  Eigen::Vector3d raw = Eigen::Vector3d::Zero();
  if (s.in_contact) {
    raw = -p.stiffness_n_per_m * (xh - xp);
    if (p.damping_n_s_per_m > 0.0 && dt > 0.0 && had_history) {
      raw -= p.damping_n_s_per_m * (xh - previous.hip_m) / dt;
    }
  }
  double mag = raw.norm();
  if (!(mag <= p.max_force_n)) {
    if (std::isfinite(mag) && mag > 0.0) {
      raw *= p.max_force_n / mag;
      mag = p.max_force_n;
    } else {
      raw.setZero();
      mag = 0.0;
    }
    s.saturated = true;
  }
  if (!hip.forces_enabled) {
    s.gate_open = false;
    s.ramp = 0.0;
  } else if (!s.gate_open) {
    if (mag <= p.gate_force_n) {
      s.gate_open = true;
      s.ramp = p.ramp_time_s > 0.0 ? 0.0 : 1.0;
    }
  } else {
    s.ramp = p.ramp_time_s > 0.0 ? std::min(1.0, s.ramp + dt / p.ramp_time_s) : 1.0;
  }
  s.force_n = s.gate_open ? Eigen::Vector3d(s.ramp * raw) : Eigen::Vector3d::Zero();
  if (!s.force_n.allFinite()) s.force_n.setZero();
  s.proxy_m = xp;
  s.hip_m = xh;
  return s;
}

}  // namespace hc::haptics
