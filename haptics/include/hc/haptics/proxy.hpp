#pragma once
/// @file proxy.hpp
/// The point proxy (god-object style) on the Monge surface z = f(x, y), with dynamic and static
/// friction, and the force stage (spring, damping, cap, small-force gate, ramp). One call of
/// step_proxy() is one servo tick: a pure function of the previous state, the HIP, the surface
/// and the parameters. Paper: Sec. 3 (Eq. 3–5), Sec. 3.2 (friction), Sec. 4 (F = −k·x).
///
/// Frame: every position is in the surface's grid frame, metres; z points towards the viewer,
/// the object is the region z < f(x, y). The force is in the same frame, newtons; stiffness and
/// damping act on displacements and velocities in that frame (the servo loop converts device
/// stiffness to grid-frame stiffness with the workspace scale).

#include "hc/haptics/haptic_surface.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace hc::haptics {

/// Parameters of the proxy and force stage. Validate with validate_proxy_params() off the
/// servo thread; step_proxy() assumes valid values.
struct ProxyParams {
  double stiffness_n_per_m = 800.0;  ///< k of F = −k·(X_h − X_p) [N/m], ≥ 0 (paper Sec. 4)
  double damping_n_s_per_m = 0.0;    ///< b ≥ 0: F −= b·v_hip while in contact [N·s/m]
  double max_force_n = 8.0;          ///< cap on |F| [N] > 0; direction is kept when saturating
  double rho = 0.9;                  ///< ρ ∈ (0, 1] of Eq. 4–5 [-]
  /// Bound on Eq. 5 iterations per tick, ≥ 1; what is left is carried to the next tick (the
  /// proxy resumes). 4 keeps the tick's p99.9 under 1 µs from 200² to 4096² cells; the lag it
  /// adds against a converged tick is in bench/README.md (issue 16, servo tick).
  int max_iterations = 4;
  double convergence_m = 1.0e-6;     ///< stop once the proxy is this close to where Eq. 5 leads [m]
  double max_step_cells = 4.0;       ///< bound on one iteration's xy move [cells] (> 0); see step_proxy
  bool friction_enabled = true;      ///< false: μ_d = μ_s = 0 whatever the surface holds
  double ramp_time_s = 0.25;         ///< forces ramp 0 → 1 over this time once the gate opens [s]
  double gate_force_n = 0.5;         ///< forces (re)start only when the unramped |F| ≤ this [N]
  int max_cells_per_tick = 4096;     ///< bound on cells visited by the free-space sweep
};

/// Throws hc::ConfigError naming the first field out of range and its value.
/// Real-time: no.
void validate_proxy_params(const ProxyParams& params);

/// One HIP sample given to step_proxy().
struct HipInput {
  Eigen::Vector3d position_m = Eigen::Vector3d::Zero();  ///< X_h, grid frame [m]
  double dt_s = 0.0;            ///< time since the previous tick [s] (ramp and damping), ≥ 0
  bool forces_enabled = false;  ///< device Armed: forces may pass the gate and ramp in
};

/// Outcome flags of a tick.
enum class ProxyStatus : std::uint8_t {
  kOk = 0,
  kNonFiniteInput,      ///< HIP or dt was NaN/inf: zero force, proxy unchanged, gate closed
  kCellBudgetExceeded,  ///< the free-space sweep hit max_cells_per_tick: proxy stopped early
  kNoSurface,           ///< surface == nullptr: free space, zero force
};

/// State carried from tick to tick (and the tick's diagnostics).
struct ProxyState {
  Eigen::Vector3d proxy_m = Eigen::Vector3d::Zero();  ///< X_p, grid frame [m]
  Eigen::Vector3d hip_m = Eigen::Vector3d::Zero();    ///< X_h of this tick [m]
  Eigen::Vector3d force_n = Eigen::Vector3d::Zero();  ///< rendered force (gated, ramped, capped)
  bool initialized = false;  ///< false before the first finite HIP
  bool in_contact = false;   ///< proxy constrained to the surface
  bool sticking = false;     ///< static friction holds the proxy (|f_t| < μ_s·|f_n|)
  bool gate_open = false;    ///< forces passed the small-force gate since being enabled
  bool saturated = false;    ///< |F| was capped this tick
  double ramp = 0.0;         ///< force scale [0, 1] of the ramp-in
  double mu_d = 0.0;         ///< μ_d at the proxy this tick [-]
  double mu_s = 0.0;         ///< μ_s at the proxy this tick [-]
  double tangential_m = 0.0; ///< |v_t| at the last contact evaluation [m] (∝ |f_t|)
  double normal_m = 0.0;     ///< −n·v_h at the last contact evaluation [m] (∝ f_n, > 0 pressing)
  int iterations = 0;        ///< Eq. 5 iterations used this tick
  int cells_visited = 0;     ///< cells swept by the free-space test this tick
  ProxyStatus status = ProxyStatus::kOk;

  /// β [rad] ∈ [0, π]: the angle between the reaction force and the surface normal,
  /// atan2(|f_t|, f_n) (paper Sec. 3.2); 0 in free space. Computed on demand (atan2 is costly
  /// on the servo thread). Real-time: yes.
  double beta_rad() const noexcept { return std::atan2(tangential_m, normal_m); }
};

/// Result of the swept-segment crossing test.
struct SegmentHit {
  bool hit = false;             ///< the segment goes below the surface somewhere
  double t = 1.0;               ///< first crossing parameter in [0, 1] (1 when no hit)
  Eigen::Vector3d point_m = Eigen::Vector3d::Zero();  ///< a + t·(b − a), z snapped to f
  int cells_visited = 0;        ///< grid cells examined
  bool budget_exceeded = false; ///< stopped after max_cells cells; t is where it stopped
};

/// First point where the segment a → b goes from on/above the surface to below it.
/// The segment's xy projection is marched cell by cell over the padded grid (a 2-D DDA), and
/// inside each cell the exact crossing with the bilinear patch is solved (a quadratic in t);
/// beyond the grid the surface is the constant floor. A start point already below the surface
/// (by more than 1e-12 m) is a hit at t = 0. Touching without going below is not a hit.
/// @param a, b       grid frame [m], finite.
/// @param max_cells  bound on the cells examined (bounded work); ≥ 1.
/// Real-time: yes (noexcept, no allocation). Cost: O(cells crossed) ≤ O(max_cells).
/// Source: god-object collision of Zilles & Salisbury (1995); grid walk of Amanatides & Woo (1987).
SegmentHit find_first_crossing(const HapticSurface& surface, const Eigen::Vector3d& a,
                               const Eigen::Vector3d& b, int max_cells) noexcept;

/// Friction factor (1 − μ_d·cot β) of Eq. 5 clamped to [0, 1].
/// @param tangential_m  |v_t| ≥ 0 [m]; @param normal_m  −n·v_h, penetration along the normal
///        [m] (> 0 when the HIP is below the tangent plane); cot β = normal_m / tangential_m.
/// β → 0 (tangential_m → 0 with normal_m > 0) gives 0; β = 90° gives 1; β > 90° gives 1.
/// step_proxy() uses it for every Eq. 5 step (contact iterations, kink fallback, crease slide).
/// Real-time: yes (inline: every contact iteration calls it). Source: paper Eq. 5 and the text
/// before it.
inline double friction_factor(double tangential_m, double normal_m, double mu_d) noexcept {
  if (!(mu_d > 0.0) || !(normal_m > 0.0)) return 1.0;  // no friction, or β ≥ 90°
  const double resist = mu_d * normal_m;               // μ_d·|f_n| in length units
  if (!(tangential_m > resist)) return 0.0;            // β → 0 or inside the friction cone
  return std::clamp(1.0 - resist / tangential_m, 0.0, 1.0);
}

/// One servo tick of the proxy and the force stage.
///
/// Free space, or HIP outside the surface (z_h ≥ f(x_h, y_h)): the proxy moves towards the HIP;
/// if the segment crosses the surface (find_first_crossing) it stops on the crossing and the
/// contact phase starts; otherwise it is placed on the HIP and contact ends. So contact ends
/// when z_h ≥ f(x_h, y_h) AND the straight way from the proxy to the HIP is free: a HIP that
/// got over a wall keeps its proxy on the near side of it.
/// Contact phase (paper Eq. 3–5), at most max_iterations times:
///   n = unit normal at X_p, v_h = X_h − X_p, v_t = v_h − (n·v_h)·n;
///   static friction: the proxy sticks while |f_t| < μ_s·|f_n| (|v_t| < μ_s·max(−n·v_h, 0));
///   X_p ← X_p + ρ·clamp(1 − μ_d·cot β, 0, 1)·v_t, with the xy step at most max_step_cells
///   cells; a step longer than one cell is taken only if the tangent path lifted by 0.1 cell
///   crosses no material (find_first_crossing), else it is cut where that path first meets
///   material (nothing lies before that point), but to no less than one cell, which cannot pass
///   over a one-cell spike (the spike raises a two-cell-wide zone);
///   then, when that leaves the surface by more than convergence_m, one Newton step along n onto
///   the surface, and finally exactly onto z = f(x, y); a step that would not bring the proxy
///   closer to the HIP is halved (at most 3 times);
///   if that fails too, the step ran into a concave kink of the bilinear surface (it leaves the
///   proxy's cell across a grid line beyond which the surface bends up: one-cell risers, pits,
///   creases), and the iteration falls back to, in order: the tangent step put on the surface
///   vertically; stopping where the step meets the grid line; from the line, the Eq. 5 step
///   with the neighbour cell's normal when it leads across; else a slide along the grid line
///   (the crease; all kinks of a bilinear surface lie on grid lines) up to the next node, with
///   the Eq. 5 friction factor in which all of v_h across the line is the normal force (two
///   active constraints, Zilles & Salisbury); each only if it brings the proxy closer to the
///   HIP, else the proxy stays;
///   stop when the proxy is within convergence_m of the point Eq. 5 heads for
///   (factor·|v_t| < convergence_m, independent of ρ), else resume at the next tick.
///   The proxy enters static friction when it stays at rest for a whole tick (inside the
///   dynamic cone at the first iteration, or converged without moving).
///   Where the bilinear normal jumps (cell edges, corners) the iteration uses the normal of the
///   cell holding the proxy.
/// Force: F = −k·(X_h − X_p) − b·v_hip in contact, 0 in free space; |F| capped at max_force_n
/// keeping its direction; then multiplied by the ramp. The gate opens (ramp starts from 0) only
/// while forces_enabled and the capped force is ≤ gate_force_n, so forces never start while the
/// HIP is deep inside; disabling forces closes the gate.
/// First tick: the proxy starts on the HIP, or on the surface above it if the HIP is inside.
/// A previous proxy found below the surface (a new surface was adopted) is lifted onto it.
/// NaN/inf HIP or dt: zero force, the previous proxy kept, gate closed, status kNonFiniteInput.
/// @param surface may be nullptr (status kNoSurface, proxy = HIP, zero force).
/// Guarantees: every output finite; |force_n| ≤ max_force_n; z_p ≥ f(x_p, y_p) − 1e-9 m; in
/// contact on an unchanged surface no move takes the proxy farther from the HIP, so proxy
/// motion never adds energy to the spring (passivity of the renderer itself).
/// Real-time: yes (noexcept, no allocation, no locks). Cost: O(max_iterations + cells swept);
/// a step refused with all its halvings costs at most 15 more surface samples.
ProxyState step_proxy(const ProxyState& previous, const HipInput& hip,
                      const HapticSurface* surface, const ProxyParams& params) noexcept;

}  // namespace hc::haptics
