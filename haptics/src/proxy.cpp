#include "hc/haptics/proxy.hpp"

#include "hc/common/error.hpp"

#include <Eigen/Geometry>

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
/// The tests that reject a cell (most cells of a walk) use no division: the vertex
/// s_v = −B/(2A) is compared by its numerator, and G(s_v) = C − B²/(4A) by 4A·G(s_v).
bool first_drop(double A, double B, double C, double L, double& s_out) noexcept {
  if (C < -kBelowTol) {
    s_out = 0.0;
    return true;
  }
  C = std::max(C, 0.0);
  // Restrict [lo, hi] to where G decreases, so that it holds exactly one downward root.
  bool vertex_lo = false, vertex_hi = false;  // lo / hi is the vertex s_v
  if (A > 0.0) {
    if (!(-B > 0.0)) return false;        // s_v ≤ 0: G increasing on [0, L]
    vertex_hi = -B < 2.0 * A * L;         // s_v < L
  } else if (A < 0.0) {
    if (!(-B > 2.0 * A * L)) return false;  // s_v ≥ L: G increasing on [0, L]
    vertex_lo = B > 0.0;                    // s_v > 0
  }
  // G at hi < −kBelowTol; at the vertex (A > 0): C − B²/(4A) < −tol ⇔ 4AC − B² < −4A·tol.
  const bool drops = vertex_hi ? 4.0 * A * C - B * B < -4.0 * A * kBelowTol : C + L * (B + A * L) < -kBelowTol;
  if (!drops) return false;
  const double lo = vertex_lo ? -B / (2.0 * A) : 0.0;
  const double hi = vertex_hi ? -B / (2.0 * A) : L;
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

/// Clips [t_in, t_out] to where p + t·d lies in [lo, hi]; inv_d = 1/d (unused when d = 0).
void clip_slab(double p, double d, double inv_d, double lo, double hi, double& t_in, double& t_out,
               bool& empty) noexcept {
  if (d == 0.0) {
    if (p < lo || p > hi) empty = true;
    return;
  }
  double t0 = (lo - p) * inv_d;
  double t1 = (hi - p) * inv_d;
  if (t0 > t1) std::swap(t0, t1);
  t_in = std::max(t_in, t0);
  t_out = std::min(t_out, t1);
}

/// Where the x-y move from p by t·d, t ∈ [0, 1], first meets the border of the grid cell that
/// HapticSurface::sample() uses at p (on a shared edge: the cell with the larger index).
struct CellExit {
  double t = 1.0;       ///< exit fraction; 1 when the move stays in the cell
  int axis = -1;        ///< the grid line met: 0 a line x = const, 1 a line y = const, −1 none
  bool corner = false;  ///< both lines met at once (the move leaves through a node)
};

CellExit cell_exit(const GridGeometry& g, const Eigen::Vector3d& p, const Eigen::Vector3d& d) noexcept {
  const double inv = 1.0 / g.cell_size_m;
  const double cu = std::clamp((p.x() - g.x0_m) * inv, 0.0, static_cast<double>(g.cols - 1));
  const double cv = std::clamp((p.y() - g.y0_m) * inv, 0.0, static_cast<double>(g.rows - 1));
  const double i = std::min(std::floor(cu), static_cast<double>(g.cols - 2));
  const double j = std::min(std::floor(cv), static_cast<double>(g.rows - 2));
  const double du = d.x() * inv;
  const double dv = d.y() * inv;
  const double tu = du > 0.0 ? (i + 1.0 - cu) / du : (du < 0.0 ? (i - cu) / du : kInf);
  const double tv = dv > 0.0 ? (j + 1.0 - cv) / dv : (dv < 0.0 ? (j - cv) / dv : kInf);
  CellExit e;
  // Through a corner (tu = tv) the line crossed along the larger component counts.
  const bool u_first = tu < tv || (tu == tv && std::fabs(du) >= std::fabs(dv));
  const double t = std::max(u_first ? tu : tv, 0.0);
  if (t < 1.0) {
    e.t = t;
    e.axis = u_first ? 0 : 1;
    // Both lines within 1e-6 cell of the point of exit: the move leaves through the node.
    e.corner = std::fabs(tu - tv) * std::max(std::fabs(du), std::fabs(dv)) <= 1.0e-6;
  }
  return e;
}

/// True when p lies on a grid line of its cell's border (within 1e-6 cell) and the x-y move d
/// leaves the cell across it at once.
bool on_line_heading_across(const GridGeometry& g, const Eigen::Vector3d& p,
                            const Eigen::Vector3d& d) noexcept {
  const CellExit e = cell_exit(g, p, d);
  return e.axis >= 0 && e.t * std::sqrt(d.x() * d.x() + d.y() * d.y()) <= 1.0e-6 * g.cell_size_m;
}

/// A candidate proxy position: (x, y) of c put exactly on the surface; taken (written to xp,
/// sp) only if it is no farther from the HIP than the proxy was (dist0_2, squared) — so a
/// fallback move can only release spring energy, never add any.
bool take_if_closer(const HapticSurface& surface, const Eigen::Vector3d& xh, Eigen::Vector3d c,
                    double dist0_2, Eigen::Vector3d& xp, SurfaceSample& sp) noexcept {
  const SurfaceSample sc = surface.sample(c.x(), c.y());
  c.z() = sc.z_m;
  if ((xh - c).squaredNorm() > dist0_2 + kBelowTol * kBelowTol) return false;
  xp = c;
  sp = sc;
  return true;
}

/// Slide along the grid line through xp (axis 0: the line x = const, so along y; axis 1:
/// along x). The bilinear surface is a straight segment between two nodes on a grid line, and
/// every kink of it lies on grid lines, so this is the god-object's motion along a crease (two
/// active constraints, Zilles & Salisbury 1995). Direction: the way along the line the pull
/// v_h favours; friction: Eq. 5 with everything of v_h across the line as the normal force.
/// The move stops at the end of the segment (the next node) and is at most one cell.
bool crease_slide(const HapticSurface& surface, const Eigen::Vector3d& xh, int axis, double mu_d,
                  const ProxyParams& p, Eigen::Vector3d& xp, SurfaceSample& sp) noexcept {
  const GridGeometry& g = surface.geometry();
  const double cell = g.cell_size_m;
  const Eigen::Vector3d vh = xh - xp;
  const double dist0_2 = vh.squaredNorm();
  const double eps = 1.0e-3 * cell;
  double along = 0.0;
  double sign = 0.0;
  Eigen::Vector3d dir = Eigen::Vector3d::Zero();  // unit, along the segment entered
  for (const double sg : {1.0, -1.0}) {
    const SurfaceSample a = axis == 0 ? surface.sample(xp.x(), xp.y() + sg * eps)
                                      : surface.sample(xp.x() + sg * eps, xp.y());
    const double slope = axis == 0 ? a.dz_dy : a.dz_dx;
    Eigen::Vector3d d(axis == 1 ? sg : 0.0, axis == 0 ? sg : 0.0, sg * slope);
    d /= std::sqrt(1.0 + slope * slope);
    const double al = vh.dot(d);
    if (al > along) {
      along = al;
      sign = sg;
      dir = d;
    }
  }
  if (!(along > 0.0)) return false;
  // Eq. 5 with the pull v_h split into the part along the line (the "tangential" share) and
  // the rest across it (the normal force).
  const double factor = friction_factor(along, std::sqrt(std::max(dist0_2 - along * along, 0.0)), mu_d);
  const double dxy = axis == 0 ? std::fabs(dir.y()) : std::fabs(dir.x());  // x-y share of dir
  // Room to the next node along the line, in cells (a whole cell when on a node already).
  const double c = axis == 0 ? (xp.y() - g.y0_m) / cell : (xp.x() - g.x0_m) / cell;
  const double node = std::round(c);
  const double room = std::fabs(c - node) < 1.0e-9 ? 1.0
                      : sign > 0.0                 ? std::floor(c) + 1.0 - c
                                                   : c - std::floor(c);
  double move_xy = std::min({p.rho * factor * along * dxy, room * cell, cell});
  if (!(move_xy > 1.0e-9 * cell) || factor * along < p.convergence_m) return false;
  for (int h = 0; h < 3; ++h, move_xy *= 0.5) {
    if (take_if_closer(surface, xh, xp + (move_xy / dxy) * dir, dist0_2, xp, sp)) return true;
  }
  return false;
}

/// Fallback of an Eq. 5 iteration whose tangent step `step` (and its halvings) was refused.
/// That happens at concave kinks of the bilinear surface: the step leaves the proxy's cell
/// across a grid line beyond which the neighbour cell bends up above the proxy's tangent plane
/// (one-cell risers, pits, creases), or the Newton re-projection along a steep normal swings
/// the proxy sideways. Without a fallback the proxy stalls there, although a god-object slides.
/// Candidates, each taken only if closer to the HIP (take_if_closer):
///  1. the tangent step put on the surface vertically instead of along n;
///  2. the point where the step leaves the proxy's cell (the proxy stops on the grid line);
///  3. on the line, the Eq. 5 step with the neighbour cell's normal, if it leads across;
///  4. otherwise a slide along the line (crease_slide), or from a node along either line.
/// Real-time: yes. Cost: at most 15 surface samples.
bool kink_fallback(const HapticSurface& surface, const Eigen::Vector3d& xh, double mu_d,
                   const Eigen::Vector3d& step, const ProxyParams& p, Eigen::Vector3d& xp,
                   SurfaceSample& sp) noexcept {
  const double cell = surface.geometry().cell_size_m;
  const Eigen::Vector3d vh = xh - xp;
  const double dist0_2 = vh.squaredNorm();
  if (take_if_closer(surface, xh, xp + step, dist0_2, xp, sp)) return true;  // 1
  const CellExit exit = cell_exit(surface.geometry(), xp, step);
  if (exit.axis < 0) return false;  // the step stays in the cell: nothing to add
  const double step_xy = std::sqrt(step.x() * step.x() + step.y() * step.y());  // no overflow: metres
  if (exit.t * step_xy > 1.0e-6 * cell) {
    return take_if_closer(surface, xh, xp + exit.t * step, dist0_2, xp, sp);  // 2
  }
  // On the line, heading out of the cell: the neighbour's normal, just across the line.
  const double nudge = 1.0e-3 * cell / step_xy;
  const SurfaceSample nb = surface.sample(xp.x() + nudge * step.x(), xp.y() + nudge * step.y());
  const Eigen::Vector3d m2(-nb.dz_dx, -nb.dz_dy, 1.0);
  const double q2 = m2.squaredNorm();
  const double mv2 = m2.dot(vh);
  const Eigen::Vector3d vt2 = vh - (mv2 / q2) * m2;
  if (vt2.x() * step.x() + vt2.y() * step.y() > 0.0) {  // 3: the neighbour plane leads on
    const double factor = friction_factor(vt2.norm(), -mv2 / std::sqrt(q2), mu_d);  // 1 if mv2 ≥ 0
    // At most one cell long in 3-D. When refused, shorten it by at least half, and more where
    // the patch bends away from the plane by e (≈ c·|s|², the bilinear twist on steep cells),
    // so that the bend, shrinking quadratically, becomes at most half the step.
    Eigen::Vector3d s2 = (p.rho * factor) * vt2;
    const double l2 = s2.squaredNorm();
    if (l2 > cell * cell) s2 *= cell / std::sqrt(l2);
    for (int h = 0; h < 3 && factor > 0.0; ++h) {
      Eigen::Vector3d c = xp + s2;
      const SurfaceSample sc = surface.sample(c.x(), c.y());
      const double bend = std::fabs(sc.z_m - c.z());
      c.z() = sc.z_m;
      if ((xh - c).squaredNorm() <= dist0_2 + kBelowTol * kBelowTol) {
        xp = c;
        sp = sc;
        return true;
      }
      const double len = s2.norm();
      s2 *= bend > len ? 0.5 * len / bend : 0.5;
    }
  }
  // 4: along the line; from a node, along either line through it.
  if (crease_slide(surface, xh, exit.axis, mu_d, p, xp, sp)) return true;
  return exit.corner && crease_slide(surface, xh, 1 - exit.axis, mu_d, p, xp, sp);
}

/// find_first_crossing() without its point (hit.point_m is left at zero): the walk and t, hit,
/// cells_visited and budget_exceeded. The proxy's guard needs only t, and the point's height
/// would cost a surface sample.
SegmentHit walk_segment(const HapticSurface& surface, const Eigen::Vector3d& a,
                        const Eigen::Vector3d& b, int max_cells) noexcept {
  SegmentHit hit;
  const GridGeometry& g = surface.geometry();
  const double inv_cs = 1.0 / g.cell_size_m;
  const double ua = (a.x() - g.x0_m) * inv_cs;
  const double va = (a.y() - g.y0_m) * inv_cs;
  // A move below DBL_MIN cells is none: its reciprocal would be infinite, and 0·inf NaN.
  const auto flush = [](double d) { return std::fabs(d) < std::numeric_limits<double>::min() ? 0.0 : d; };
  const double du = flush((b.x() - a.x()) * inv_cs);
  const double dv = flush((b.y() - a.y()) * inv_cs);
  const double dz = b.z() - a.z();
  const double max_u = static_cast<double>(g.cols - 1);
  const double max_v = static_cast<double>(g.rows - 1);
  const double floor_m = surface.floor_m();

  const auto finish = [&](double t, bool is_hit) {
    hit.hit = is_hit;
    hit.t = t;
    return hit;
  };

  double t_in = 0.0;
  double t_out = 1.0;
  bool empty = false;
  // Where the walk leaves cell column i / row j: t = (i + 1 − u_a)/du (or (i − u_a)/du), with
  // one division per call instead of two per cell.
  const double inv_du = du != 0.0 ? 1.0 / du : 0.0;
  const double inv_dv = dv != 0.0 ? 1.0 / dv : 0.0;
  clip_slab(ua, du, inv_du, 0.0, max_u, t_in, t_out, empty);
  clip_slab(va, dv, inv_dv, 0.0, max_v, t_in, t_out, empty);
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
  const double off_u = du > 0.0 ? 1.0 : 0.0, off_v = dv > 0.0 ? 1.0 : 0.0;  // the far line's offset
  const float* base = &surface.bilinear().view().data[0];
  const std::ptrdiff_t stride = surface.bilinear().view().row_stride;
  while (true) {
    if (hit.cells_visited >= max_cells) {
      hit.budget_exceeded = true;
      return finish(t, false);
    }
    ++hit.cells_visited;
    const double tu = du != 0.0 ? (i + off_u - ua) * inv_du : kInf;
    const double tv = dv != 0.0 ? (j + off_v - va) * inv_dv : kInf;
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
    // Branch-free: which line a diagonal walk meets next follows no pattern a predictor learns.
    const bool step_u = tu <= tv;
    i += step_u ? si : 0;
    j += step_u ? 0 : sj;
    if (i < 0 || i > g.cols - 2 || j < 0 || j > g.rows - 2) break;
    t = t_exit;
  }
  if (t_out < 1.0 && floor_drop(a.z(), dz, floor_m, t_out, 1.0, t_hit)) return finish(t_hit, true);
  return finish(1.0, false);
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
  double last_w2 = 0.0, last_q = 1.0, last_mv = 0.0;
  for (int k = 0; k < p.max_iterations; ++k) {
    const Eigen::Vector3d m(-sp.dz_dx, -sp.dz_dy, 1.0);  // normal, unnormalised
    const double q = m.squaredNorm();
    const Eigen::Vector3d vh = xh - xp;                   // Eq. 3: v_h = X_h − X_p
    const double mv = m.dot(vh);                          // √q·(n·v_h) = −√q·f_n/k
    // q·|v_t|² = |m × v_h|² (Lagrange's identity): the tangential share without waiting for the
    // division mv/q, which runs beside the square root and the friction factor's division.
    const double w2 = m.cross(vh).squaredNorm();          // q·|v_t|² ∝ |f_t|²
    last_w2 = w2;
    last_q = q;
    last_mv = mv;
    if (k == 0 && s.sticking) {
      // Static friction holds while |f_t| < μ_s·|f_n| (Sec. 3.2), with f_n > 0 (pressing).
      if (mv < 0.0 && w2 < mu.mu_s * mu.mu_s * mv * mv) break;
      s.sticking = false;
    }
    // Eq. 5 friction factor 1 − μ_d·cot β, cot β = f_n/|f_t| = −mv/√(q·|v_t|²), clamped to
    // [0, 1]. friction_factor() depends on tangential and normal only through their ratio, so
    // both are given scaled by √q (√w2 = √q·|v_t|, −mv = √q·(−n·v_h)).
    const double factor = friction_factor(std::sqrt(w2), -mv, mu.mu_d);
    const Eigen::Vector3d vt = vh - (mv / q) * m;          // Eq. 3: v_t = v_h − (n·v_h) n
    if (factor <= 0.0) {
      // Inside the dynamic friction cone: the proxy stops. If it has not moved at all this
      // tick it is at rest, and static friction takes over.
      if (k == 0) s.sticking = true;
      break;
    }
    // Converged when the proxy is within tolerance of where Eq. 5 is heading (the friction-cone
    // equilibrium), whatever ρ: factor·|v_t| is that distance (factor²·w2 < conv²·q).
    if (factor * factor * w2 < conv2 * q) {
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
          walk_segment(surface, xp + guard_lift, xp + step + guard_lift, guard_cells);
      if (block.hit || block.budget_exceeded) {
        // Up to where the lifted path first meets material (no feature lies before it), and
        // at least one cell.
        const double len = std::sqrt(step_xy2);
        step *= std::max(cell, block.t * len) / len;
      }
    }
    const double dist0_2 = vh.squaredNorm();
    const Eigen::Vector3d full_step = step;
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
      } else if (halving == 0 && on_line_heading_across(surface.geometry(), xp, step)) {
        break;  // every halving would cross the same kink: straight to the fallback
      } else {
        step *= 0.5;
      }
    }
    if (!accepted) accepted = kink_fallback(surface, xh, mu.mu_d, full_step, p, xp, sp);
    ++s.iterations;
    if (!accepted) break;
    if (maps) mu = surface.friction(xp.x(), xp.y());
  }
  // At rest on the dynamic friction cone for a whole tick: static friction takes over.
  if (friction_limited && (xp - x_start).squaredNorm() < conv2) s.sticking = true;
  const double sqrt_q = std::sqrt(last_q);
  s.tangential_m = std::sqrt(last_w2) / sqrt_q;
  s.normal_m = -last_mv / sqrt_q;
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

SegmentHit find_first_crossing(const HapticSurface& surface, const Eigen::Vector3d& a,
                               const Eigen::Vector3d& b, int max_cells) noexcept {
  SegmentHit hit = walk_segment(surface, a, b, max_cells);
  hit.point_m = a + hit.t * (b - a);
  if (hit.hit) hit.point_m.z() = surface.height(hit.point_m.x(), hit.point_m.y());
  return hit;
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
