#include "hc/haptics/proxy.hpp"

#include "godobject_oracle.hpp"
#include "haptics_test_support.hpp"

#include "hc/common/error.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <random>
#include <vector>

namespace hc::haptics {
namespace {

using Eigen::Vector3d;
using test::make_field;
using test::tick_invariants;

constexpr double kDt = 1e-3;

/// Drives step_proxy with scripted HIP positions and checks the invariants on every tick.
struct Driver {
  const HapticSurface* surface;
  ProxyParams params;
  ProxyState state{};
  bool forces_enabled = true;
  int ticks = 0;
  double max_force_jump_n = 0.0;

  const ProxyState& tick(const Vector3d& hip, double dt = kDt) {
    const Vector3d before = state.force_n;
    state = step_proxy(state, HipInput{hip, dt, forces_enabled}, surface, params);
    ++ticks;
    EXPECT_TRUE(tick_invariants(state, *surface, params)) << "tick " << ticks;
    max_force_jump_n = std::max(max_force_jump_n, (state.force_n - before).norm());
    return state;
  }
  /// Moves the HIP in a straight line from a to b in n ticks (a excluded, b included).
  void move(const Vector3d& a, const Vector3d& b, int n) {
    for (int k = 1; k <= n; ++k) tick(a + (b - a) * (static_cast<double>(k) / n));
  }
};

ProxyParams no_ramp() {
  ProxyParams p;
  p.ramp_time_s = 0.0;
  return p;
}

// ---------------------------------------------------------------- the crossing test

TEST(FindFirstCrossing, AgreesWithDenseSamplingOnRandomGrids) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> height(0.0, 0.005);
  std::uniform_real_distribution<double> coord(-0.004, 0.014);
  std::uniform_real_distribution<double> zc(-0.002, 0.008);
  int hits = 0;
  for (int grid = 0; grid < 20; ++grid) {
    HeightField f = make_field(11, 11, 0.001, 0.0, 0.0, [&](double, double) { return height(rng); });
    if (grid % 2 == 1) f.at(5, 5) = kNoData;  // a hole: floor inside
    const auto s = test::make_surface(f);
    for (int seg = 0; seg < 100; ++seg) {
      Vector3d a(coord(rng), coord(rng), zc(rng));
      const Vector3d b(coord(rng), coord(rng), zc(rng));
      a.z() = std::max(a.z(), s->height(a.x(), a.y()) + 1e-6);  // start above the surface
      const SegmentHit h = find_first_crossing(*s, a, b, 10000);
      // Oracle: dense samples along the segment.
      constexpr int kN = 10000;
      double t_oracle = 2.0;
      for (int k = 0; k <= kN; ++k) {
        const double t = static_cast<double>(k) / kN;
        const Vector3d p = a + t * (b - a);
        if (p.z() < s->height(p.x(), p.y()) - 1e-9) {
          t_oracle = t;
          break;
        }
      }
      if (t_oracle <= 1.0) {
        ASSERT_TRUE(h.hit) << "missed a crossing at t = " << t_oracle;
        EXPECT_LE(h.t, t_oracle + 1e-12);  // never later than the oracle
        ++hits;
      }
      if (h.hit) {
        EXPECT_NEAR(h.point_m.z(), s->height(h.point_m.x(), h.point_m.y()), 1e-12);
        const Vector3d on_line = a + h.t * (b - a);
        EXPECT_NEAR(on_line.z(), h.point_m.z(), 1e-9);  // the crossing is on the segment
        // A real entry: just after the crossing the segment is below the surface.
        double min_gap = 1.0;
        for (int k = 1; k <= 5000; ++k) {
          const double t = std::min(1.0, h.t + 0.02 * k / 5000.0);
          const Vector3d p = a + t * (b - a);
          min_gap = std::min(min_gap, p.z() - s->height(p.x(), p.y()));
        }
        EXPECT_LT(min_gap, 0.0) << "reported crossing at t = " << h.t << " is not an entry";
        // Nothing before the reported crossing is below the surface.
        for (int k = 0; k < 200; ++k) {
          const double t = h.t * k / 200.0;
          const Vector3d p = a + t * (b - a);
          ASSERT_GE(p.z(), s->height(p.x(), p.y()) - 1e-9) << "t = " << t << " before " << h.t;
        }
      }
      EXPECT_FALSE(h.budget_exceeded);
    }
  }
  EXPECT_GT(hits, 300);  // the random segments do exercise crossings
}

TEST(FindFirstCrossing, StartBelowIsAHitAtZeroAndTouchingIsNot) {
  const HeightField f = make_field(5, 5, 0.001, 0, 0, [](double, double) { return 0.0; });
  const auto s = test::make_surface(f);
  SegmentHit h = find_first_crossing(*s, Vector3d(0.001, 0.001, -0.001), Vector3d(0.002, 0.002, 0.01), 100);
  EXPECT_TRUE(h.hit);
  EXPECT_EQ(h.t, 0.0);
  // Sliding exactly on the plane and leaving it upwards: no hit.
  h = find_first_crossing(*s, Vector3d(0.001, 0.001, 0.0), Vector3d(0.003, 0.002, 0.0), 100);
  EXPECT_FALSE(h.hit);
  h = find_first_crossing(*s, Vector3d(0.001, 0.001, 0.0), Vector3d(0.003, 0.002, 0.001), 100);
  EXPECT_FALSE(h.hit);
  // From on the surface going down: hit at 0.
  h = find_first_crossing(*s, Vector3d(0.001, 0.001, 0.0), Vector3d(0.003, 0.002, -0.001), 100);
  EXPECT_TRUE(h.hit);
  EXPECT_NEAR(h.t, 0.0, 1e-12);
}

TEST(FindFirstCrossing, VerticalAndGridAlignedSegments) {
  const HeightField f = make_field(5, 5, 0.001, 0, 0, [](double x, double y) { return x + 2 * y; });
  const auto s = test::make_surface(f);
  // Straight down through a node, an edge and a cell interior.
  for (const Vector3d& xy : {Vector3d(0.002, 0.002, 0), Vector3d(0.002, 0.0015, 0), Vector3d(0.0013, 0.0027, 0)}) {
    const double z = xy.x() + 2 * xy.y();
    const SegmentHit h = find_first_crossing(*s, Vector3d(xy.x(), xy.y(), z + 0.001),
                                             Vector3d(xy.x(), xy.y(), z - 0.001), 100);
    ASSERT_TRUE(h.hit);
    EXPECT_NEAR(h.t, 0.5, 1e-6);  // heights are stored as float
    EXPECT_NEAR(h.point_m.z(), z, 1e-8);
  }
  // Along a grid line, descending through the surface.
  const SegmentHit h = find_first_crossing(*s, Vector3d(0.0, 0.002, 0.006), Vector3d(0.004, 0.002, 0.006), 100);
  ASSERT_TRUE(h.hit);  // f = x + 0.004 reaches 0.006 at x = 0.002
  EXPECT_NEAR(h.point_m.x(), 0.002, 1e-9);
}

TEST(FindFirstCrossing, BeyondTheGridTheFloorIsSolid) {
  const HeightField f = make_field(5, 5, 0.001, 0, 0, [](double, double) { return 0.002; });
  SurfaceOptions opt;
  opt.floor_margin_m = 0.001;  // floor at 0.001
  const auto s = test::make_surface(f, opt);
  const SegmentHit h = find_first_crossing(*s, Vector3d(0.5, 0.5, 0.003), Vector3d(0.5, 0.5, 0.0), 100);
  ASSERT_TRUE(h.hit);
  EXPECT_NEAR(h.point_m.z(), 0.001, 1e-9);
  // A long segment passing over the grid and ending below the floor far away.
  const SegmentHit g = find_first_crossing(*s, Vector3d(-0.1, 0.002, 0.0015), Vector3d(0.1, 0.002, 0.0015), 1000);
  ASSERT_TRUE(g.hit);  // enters the padded ring, where the surface rises above z = 0.0015
  EXPECT_LT(g.point_m.x(), 0.0);
  EXPECT_GT(g.point_m.x(), -0.001);
}

TEST(FindFirstCrossing, WorkIsBounded) {
  const HeightField f = make_field(200, 200, 0.0005, 0, 0, [](double, double) { return 0.0; });
  const auto s = test::make_surface(f);
  const SegmentHit h = find_first_crossing(*s, Vector3d(0.0, 0.0, 0.01), Vector3d(0.09, 0.09, 0.01), 50);
  EXPECT_FALSE(h.hit);
  EXPECT_TRUE(h.budget_exceeded);
  EXPECT_EQ(h.cells_visited, 50);
  EXPECT_GT(h.t, 0.0);
  EXPECT_LT(h.t, 1.0);
}

// ---------------------------------------------------------------- friction factor

TEST(FrictionFactor, LimitsOfEquationFive) {
  EXPECT_EQ(friction_factor(1.0, 0.0, 0.5), 1.0);         // β = 90°: cot β = 0
  EXPECT_EQ(friction_factor(1.0, -1.0, 0.5), 1.0);        // β > 90°: clamped to 1
  EXPECT_EQ(friction_factor(0.0, 1.0, 0.5), 0.0);         // β = 0: cot β = ∞
  EXPECT_EQ(friction_factor(1e-300, 1.0, 0.5), 0.0);      // β → 0
  EXPECT_DOUBLE_EQ(friction_factor(1.0, 1.0, 0.5), 0.5);  // β = 45°
  EXPECT_EQ(friction_factor(0.0, 1.0, 0.0), 1.0);         // no friction
  EXPECT_EQ(friction_factor(0.3, 1.0, 0.3), 0.0);         // on the cone
  for (double t : {0.0, 1e-9, 0.1, 1.0, 1e9}) {
    for (double n : {-1.0, 0.0, 1e-9, 1.0}) {
      for (double mu : {0.0, 0.2, 1.0, 5.0}) {
        const double f = friction_factor(t, n, mu);
        EXPECT_TRUE(f >= 0.0 && f <= 1.0) << t << " " << n << " " << mu;
      }
    }
  }
}

// ---------------------------------------------------------------- contact on a plane

HeightField flat(int n = 101, double cell = 0.001, double z = 0.0) {
  return make_field(n, n, cell, -cell * (n - 1) / 2, -cell * (n - 1) / 2, [z](double, double) { return z; });
}

TEST(StepProxy, PressingOnAPlaneGivesTheSpringForceAlongTheNormal) {
  const HeightField f = flat();
  const auto s = test::make_surface(f);
  Driver d{s.get(), no_ramp()};
  d.tick(Vector3d(0.001, 0.002, 0.005));
  EXPECT_FALSE(d.state.in_contact);
  EXPECT_EQ(d.state.force_n.norm(), 0.0);
  d.move(Vector3d(0.001, 0.002, 0.005), Vector3d(0.001, 0.002, -0.003), 80);
  EXPECT_TRUE(d.state.in_contact);
  EXPECT_NEAR(d.state.proxy_m.x(), 0.001, 1e-12);
  EXPECT_NEAR(d.state.proxy_m.y(), 0.002, 1e-12);
  EXPECT_NEAR(d.state.proxy_m.z(), 0.0, 1e-12);
  EXPECT_NEAR(d.state.force_n.z(), 800.0 * 0.003, 1e-9);
  EXPECT_NEAR(d.state.force_n.head<2>().norm(), 0.0, 1e-9);
  EXPECT_NEAR(d.state.beta_rad(), 0.0, 1e-9);
  // Leaving: contact ends as soon as z_h ≥ f(x_h, y_h); the proxy rejoins the HIP.
  d.tick(Vector3d(0.001, 0.002, 0.0));
  EXPECT_FALSE(d.state.in_contact);
  EXPECT_EQ(d.state.force_n.norm(), 0.0);
  EXPECT_EQ(d.state.proxy_m, Vector3d(0.001, 0.002, 0.0));
}

TEST(StepProxy, ForceIsSaturatedKeepingItsDirection) {
  const HeightField f = make_field(101, 101, 0.001, -0.05, -0.05, [](double x, double) { return 0.5 * x; });
  const auto s = test::make_surface(f);
  ProxyParams p = no_ramp();
  p.max_force_n = 2.0;
  p.friction_enabled = false;
  Driver d{s.get(), p};
  d.tick(Vector3d(0.0, 0.0, 0.01));
  d.move(Vector3d(0.0, 0.0, 0.01), Vector3d(0.0, 0.0, -0.02), 200);
  ASSERT_TRUE(d.state.saturated);
  EXPECT_NEAR(d.state.force_n.norm(), 2.0, 1e-9);
  const Vector3d spring = d.state.proxy_m - d.state.hip_m;
  EXPECT_NEAR(d.state.force_n.normalized().dot(spring.normalized()), 1.0, 1e-12);
  // Frictionless: the proxy is the closest point, so the force is along the plane's normal.
  const Vector3d n = Vector3d(-0.5, 0.0, 1.0).normalized();
  EXPECT_NEAR(d.state.force_n.normalized().dot(n), 1.0, 1e-6);
}

TEST(StepProxy, DynamicFrictionOnFlatTextureKeepsTheProxyOnTheCone) {
  // Flat texture (H = K = 0): the friction map holds μ_max everywhere.
  const HeightField f = flat();
  SurfaceOptions opt;
  opt.default_mu_d = 0.4;
  opt.default_mu_s = 0.5;
  const auto s = test::make_surface(f, opt);
  Driver d{s.get(), no_ramp()};
  const double depth = 0.002;
  d.tick(Vector3d(-0.02, 0.0, 0.001));
  d.move(Vector3d(-0.02, 0.0, 0.001), Vector3d(-0.02, 0.0, -depth), 30);
  const double x_start = d.state.proxy_m.x();
  d.move(Vector3d(-0.02, 0.0, -depth), Vector3d(0.02, 0.0, -depth), 2000);  // 20 mm/s
  const double lag = d.state.hip_m.x() - d.state.proxy_m.x();
  EXPECT_NEAR(lag, 0.4 * depth, 3e-6);  // |f_t| = μ_d |f_n| while sliding (1 µm tolerance)
  EXPECT_NEAR(d.state.force_n.x() / d.state.force_n.z(), -0.4, 1e-3);
  EXPECT_NEAR(d.state.mu_d, 0.4, 1e-12);
  EXPECT_NEAR(std::tan(d.state.beta_rad()), 0.4, 1e-3);
  EXPECT_GT(d.state.proxy_m.x() - x_start, 0.039);  // it slid the whole way
}

TEST(StepProxy, StaticFrictionHoldsUntilTheStaticCone) {
  const HeightField f = flat();
  SurfaceOptions opt;
  opt.default_mu_d = 0.3;
  opt.default_mu_s = 0.5;
  const auto s = test::make_surface(f, opt);
  Driver d{s.get(), no_ramp()};
  const double depth = 0.002;
  d.tick(Vector3d(0.0, 0.0, 0.001));
  d.move(Vector3d(0.0, 0.0, 0.001), Vector3d(0.0, 0.0, -depth), 30);
  ASSERT_TRUE(d.state.in_contact);
  const Vector3d anchor = d.state.proxy_m;
  // Tangential offset up to just below μ_s·depth = 1 mm: the proxy does not move.
  d.move(Vector3d(0.0, 0.0, -depth), Vector3d(0.00099, 0.0, -depth), 99);
  EXPECT_TRUE(d.state.sticking);
  EXPECT_EQ(d.state.proxy_m, anchor);
  // Beyond it: break-away, then dynamic friction leaves a lag of μ_d·depth.
  d.move(Vector3d(0.00099, 0.0, -depth), Vector3d(0.005, 0.0, -depth), 400);
  EXPECT_NEAR(d.state.hip_m.x() - d.state.proxy_m.x(), 0.3 * depth, 3e-6);
  // Stop: after the last sub-micrometre convergence the proxy sticks again and stays.
  for (int k = 0; k < 5; ++k) d.tick(Vector3d(0.005, 0.0, -depth));
  const Vector3d rest = d.state.proxy_m;
  for (int k = 0; k < 50; ++k) d.tick(Vector3d(0.005, 0.0, -depth));
  EXPECT_TRUE(d.state.sticking);
  EXPECT_EQ(d.state.proxy_m, rest);
}

TEST(StepProxy, DynamicAboveStaticFrictionIsWellDefined) {
  const HeightField f = flat();
  SurfaceOptions opt;
  opt.default_mu_d = 0.5;  // μ_d ≥ μ_s
  opt.default_mu_s = 0.1;
  const auto s = test::make_surface(f, opt);
  Driver d{s.get(), no_ramp()};
  const double depth = 0.002;
  d.tick(Vector3d(0.0, 0.0, 0.001));
  d.move(Vector3d(0.0, 0.0, 0.001), Vector3d(0.0, 0.0, -depth), 30);
  const Vector3d anchor = d.state.proxy_m;
  // Past μ_s·depth but inside μ_d·depth: the dynamic cone still holds the proxy.
  d.move(Vector3d(0.0, 0.0, -depth), Vector3d(0.00095, 0.0, -depth), 95);
  EXPECT_EQ(d.state.proxy_m, anchor);
  d.move(Vector3d(0.00095, 0.0, -depth), Vector3d(0.006, 0.0, -depth), 500);
  EXPECT_NEAR(d.state.hip_m.x() - d.state.proxy_m.x(), 0.5 * depth, 3e-6);
}

TEST(StepProxy, ZeroTangentialForceWithZeroStaticFriction) {
  const HeightField f = flat();
  for (double mu_d : {0.0, 0.3}) {
    SurfaceOptions opt;
    opt.default_mu_d = mu_d;
    opt.default_mu_s = 0.0;
    const auto s = test::make_surface(f, opt);
    Driver d{s.get(), no_ramp()};
    d.tick(Vector3d(0.003, -0.004, 0.001));
    d.move(Vector3d(0.003, -0.004, 0.001), Vector3d(0.003, -0.004, -0.001), 20);
    for (int k = 0; k < 100; ++k) d.tick(Vector3d(0.003, -0.004, -0.001));  // f_t = 0 exactly
    EXPECT_EQ(d.state.proxy_m, Vector3d(0.003, -0.004, 0.0));
    EXPECT_EQ(d.state.beta_rad(), 0.0);
    EXPECT_NEAR(d.state.force_n.z(), 0.8, 1e-9);
  }
}

TEST(StepProxy, BetaOfNinetyDegreesLetsTheProxySlideWhateverMuD) {
  // A V-groove f = 0.5·|x|: from the left flank the HIP lies exactly on the flank's tangent
  // plane (f_n = 0, β = 90°) but inside the right flank.
  const HeightField f = make_field(41, 41, 0.0005, -0.01, -0.01, [](double x, double) { return 0.5 * std::fabs(x); });
  SurfaceOptions opt;
  opt.default_mu_d = 5.0;  // huge: would stop the proxy for any β < 79°
  opt.default_mu_s = 0.0;
  const auto s = test::make_surface(f, opt);
  ProxyParams p = no_ramp();
  p.max_iterations = 1;
  ProxyState st;
  st.initialized = true;
  st.in_contact = true;
  st.proxy_m = Vector3d(-0.002, 0.0, 0.001);
  st.hip_m = st.proxy_m;
  const Vector3d hip(0.002, 0.0, -0.001);
  ASSERT_LT(hip.z(), s->height(hip.x(), hip.y()));
  const ProxyState out = step_proxy(st, HipInput{hip, kDt, true}, s.get(), p);
  EXPECT_NEAR(out.beta_rad(), std::numbers::pi / 2, 1e-6);  // float heights
  EXPECT_GT(out.proxy_m.x(), -0.002 + 1e-4);  // moved towards the groove
  EXPECT_TRUE(tick_invariants(out, *s, p));
}

TEST(StepProxy, NonFiniteInputGivesZeroForce) {
  const HeightField f = flat();
  const auto s = test::make_surface(f);
  Driver d{s.get(), no_ramp()};
  d.tick(Vector3d(0, 0, 0.001));
  d.move(Vector3d(0, 0, 0.001), Vector3d(0, 0, -0.002), 10);
  ASSERT_GT(d.state.force_n.norm(), 1.0);
  const Vector3d proxy = d.state.proxy_m;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  for (const Vector3d& bad : {Vector3d(nan, 0, 0), Vector3d(0, inf, 0), Vector3d(0, 0, -inf)}) {
    const ProxyState out = step_proxy(d.state, HipInput{bad, kDt, true}, s.get(), d.params);
    EXPECT_EQ(out.force_n, Vector3d::Zero());
    EXPECT_EQ(out.status, ProxyStatus::kNonFiniteInput);
    EXPECT_EQ(out.proxy_m, proxy);
    EXPECT_FALSE(out.gate_open);
  }
  const ProxyState out = step_proxy(d.state, HipInput{Vector3d(0, 0, -0.002), nan, true}, s.get(), d.params);
  EXPECT_EQ(out.force_n, Vector3d::Zero());
  // No surface at all: free space.
  const ProxyState none = step_proxy(ProxyState{}, HipInput{Vector3d(0, 0, -1), kDt, true}, nullptr, d.params);
  EXPECT_EQ(none.status, ProxyStatus::kNoSurface);
  EXPECT_EQ(none.force_n, Vector3d::Zero());
}

TEST(StepProxy, ASpringForceThatOverflowsIsZeroedNotSent) {
  // A valid but absurd stiffness: k·|x| overflows to infinity for a 2 m penetration. The cap
  // cannot scale an infinite force; it must send zero, not NaN or infinity.
  const HeightField f = flat();
  const auto s = test::make_surface(f);
  ProxyParams p = no_ramp();
  p.stiffness_n_per_m = 1e308;
  ASSERT_NO_THROW(validate_proxy_params(p));
  ProxyState st;
  st = step_proxy(st, HipInput{Vector3d(0, 0, -2.0), kDt, true}, s.get(), p);
  ASSERT_TRUE(st.in_contact);
  EXPECT_TRUE(st.saturated);
  EXPECT_EQ(st.force_n, Vector3d::Zero());
  // A finite over-cap force on the next tick is capped, not zeroed (the branch above is only
  // for the non-finite case).
  st = step_proxy(st, HipInput{Vector3d(0, 0, -1e-300), kDt, true}, s.get(), p);
  EXPECT_TRUE(st.saturated);
  EXPECT_NEAR(st.force_n.z(), p.max_force_n, 1e-12);
}

// ---------------------------------------------------------------- gate and ramp

TEST(StepProxy, HipFiftyMillimetresInsideWhenForcesSwitchOn) {
  const HeightField f = flat();
  const auto s = test::make_surface(f);
  ProxyParams p;  // ramp 0.25 s, gate 0.5 N
  Driver d{s.get(), p};
  d.forces_enabled = false;
  const Vector3d deep(0.0, 0.0, -0.05);
  for (int k = 0; k < 100; ++k) d.tick(deep);  // the very first tick is already 50 mm inside
  EXPECT_TRUE(d.state.in_contact);
  EXPECT_NEAR(d.state.proxy_m.z(), 0.0, 1e-12);  // proxy waits on the surface above
  d.forces_enabled = true;                     // arm while deep inside
  for (int k = 0; k < 100; ++k) d.tick(deep);
  EXPECT_EQ(d.state.force_n.norm(), 0.0);      // the gate holds: no 40 N kick
  EXPECT_FALSE(d.state.gate_open);
  // The user withdraws at 10 mm/s: forces start only near the surface, then ramp.
  int first_force_tick = -1;
  for (int k = 1; k <= 5500; ++k) {
    const Vector3d hip(0.0, 0.0, -0.05 + 1e-5 * k);
    d.tick(hip);
    if (first_force_tick < 0 && d.state.gate_open) {
      first_force_tick = k;
      EXPECT_LE(-hip.z() * p.stiffness_n_per_m, p.gate_force_n + 1e-9);
    }
  }
  EXPECT_GT(first_force_tick, 0);
  EXPECT_LT(d.max_force_jump_n, 0.01);  // no jump anywhere
  // Press again after the ramp: full force.
  d.move(Vector3d(0, 0, 0.005), Vector3d(0, 0, -0.003), 300);
  EXPECT_NEAR(d.state.force_n.z(), 2.4, 1e-9);
  EXPECT_NEAR(d.state.ramp, 1.0, 1e-12);
}

TEST(StepProxy, WithoutRampTheGateLimitsTheStartingForce) {
  const HeightField f = flat();
  const auto s = test::make_surface(f);
  ProxyParams p = no_ramp();
  Driver d{s.get(), p};
  d.forces_enabled = true;
  d.move(Vector3d(0, 0, -0.05), Vector3d(0, 0, 0.001), 5100);
  EXPECT_LE(d.max_force_jump_n, p.gate_force_n + p.stiffness_n_per_m * 0.051 / 5100 + 1e-9);
}

TEST(StepProxy, DampingOpposesTheHipVelocityInContact) {
  const HeightField f = flat();
  const auto s = test::make_surface(f);
  ProxyParams p = no_ramp();
  p.damping_n_s_per_m = 2.0;
  p.friction_enabled = false;
  Driver d{s.get(), p};
  d.tick(Vector3d(0, 0, 0.001));
  d.move(Vector3d(0, 0, 0.001), Vector3d(0, 0, -0.002), 30);  // moving down at 0.1 m/s
  EXPECT_NEAR(d.state.force_n.z(), 800 * 0.002 + 2.0 * 0.1, 1e-9);
}

// ---------------------------------------------------------------- edges, cliffs, spikes, pits

TEST(StepProxy, SlidingAlongCellEdgesAndThroughCorners) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> bump(-0.0005, 0.0005);
  const HeightField f = make_field(41, 41, 0.001, -0.02, -0.02, [&](double, double) { return bump(rng); });
  SurfaceOptions opt;
  opt.default_mu_d = 0.2;
  opt.default_mu_s = 0.3;
  const auto s = test::make_surface(f, opt);
  for (int path = 0; path < 3; ++path) {
    Driver d{s.get(), no_ramp()};
    // Along a grid line (x = node), along a row (y = node) and diagonally through corners.
    const Vector3d a = path == 0 ? Vector3d(0.002, -0.015, 0.003)
                       : path == 1 ? Vector3d(-0.015, 0.004, 0.003)
                                   : Vector3d(-0.015, -0.015, 0.003);
    const Vector3d dir = path == 0 ? Vector3d(0, 1, 0) : path == 1 ? Vector3d(1, 0, 0) : Vector3d(1, 1, 0);
    d.tick(a);
    const Vector3d pressed = a - Vector3d(0, 0, 0.0045);
    d.move(a, pressed, 50);
    d.move(pressed, pressed + 0.03 * dir, 3000);
    const double lag = (d.state.hip_m - d.state.proxy_m).head<2>().norm();
    EXPECT_LT(lag, 0.003) << "path " << path;  // the proxy kept following
    EXPECT_TRUE(d.state.in_contact);
  }
}

HeightField cliff(double cell, double height) {
  // One-cell cliff: nodes with x ≤ 0 at 0, nodes with x ≥ cell at `height`.
  return make_field(81, 81, cell, -40 * cell, -40 * cell, [cell, height](double x, double) {
    return x > 0.5 * cell ? height : 0.0;
  });
}

TEST(StepProxy, OneCellCliffApproachedFromBelowIsAWall) {
  const double cell = 0.0005;
  const HeightField f = cliff(cell, 0.020);
  const auto s = test::make_surface(f);
  Driver d{s.get(), no_ramp()};
  d.tick(Vector3d(-0.015, 0.0, 0.002));
  d.move(Vector3d(-0.015, 0.0, 0.002), Vector3d(-0.015, 0.0, -0.001), 30);
  d.move(Vector3d(-0.015, 0.0, -0.001), Vector3d(0.015, 0.0, -0.001), 300);  // 0.1 m/s into the wall
  EXPECT_TRUE(d.state.in_contact);
  EXPECT_LE(d.state.proxy_m.x(), cell + 1e-12);  // never on top of the cliff
  EXPECT_LT(d.state.force_n.x(), 0.0);          // pushed back out of the wall
  EXPECT_LE(d.state.force_n.norm(), d.params.max_force_n);
  // Now from the low side but above the low plateau, 1 mm below the top: hits the face.
  Driver e{s.get(), no_ramp()};
  e.tick(Vector3d(-0.01, 0.0, 0.019));
  e.move(Vector3d(-0.01, 0.0, 0.019), Vector3d(0.01, 0.0, 0.019), 20);  // 1 m/s
  EXPECT_TRUE(e.state.in_contact);
  EXPECT_LE(e.state.proxy_m.x(), cell + 1e-12);
  EXPECT_LT(e.state.force_n.x(), 0.0);
}

TEST(StepProxy, OneCellCliffApproachedFromAboveLetsTheProxyFallOff) {
  const double cell = 0.0005;
  const HeightField f = cliff(cell, 0.020);
  const auto s = test::make_surface(f);
  Driver d{s.get(), no_ramp()};
  d.tick(Vector3d(0.015, 0.0, 0.022));
  d.move(Vector3d(0.015, 0.0, 0.022), Vector3d(0.015, 0.0, 0.019), 30);  // press 1 mm on top
  ASSERT_TRUE(d.state.in_contact);
  d.move(Vector3d(0.015, 0.0, 0.019), Vector3d(-0.015, 0.0, 0.019), 300);  // walk off the edge
  EXPECT_FALSE(d.state.in_contact);  // in free space above the low plateau
  EXPECT_EQ(d.state.force_n.norm(), 0.0);
  EXPECT_EQ(d.state.proxy_m, d.state.hip_m);
  // Down onto the low plateau, back into the cliff's face from below the top.
  d.move(Vector3d(-0.015, 0.0, 0.019), Vector3d(-0.015, 0.0, -0.001), 100);
  d.move(Vector3d(-0.015, 0.0, -0.001), Vector3d(0.0, 0.0, -0.001), 150);
  EXPECT_TRUE(d.state.in_contact);
  EXPECT_LE(d.state.proxy_m.x(), cell);
}

TEST(StepProxy, OneCellSpikeAndPit) {
  const double cell = 0.0005;
  HeightField f = make_field(81, 81, cell, -40 * cell, -40 * cell, [](double, double) { return 0.0; });
  f.at(40, 30) = 0.020F;   // spike at x = −5 mm, y = 0
  f.at(40, 50) = -0.020F;  // pit at x = +5 mm, y = 0
  SurfaceOptions opt;
  opt.default_mu_d = 0.2;
  opt.default_mu_s = 0.25;
  const auto s = test::make_surface(f, opt);
  const double spike_x = -0.005;
  for (double y : {0.0, 0.0002, 0.0005}) {  // through the apex, off it, along the cell edge
    Driver d{s.get(), no_ramp()};
    d.tick(Vector3d(-0.015, y, 0.002));
    d.move(Vector3d(-0.015, y, 0.002), Vector3d(-0.015, y, -0.001), 30);
    d.move(Vector3d(-0.015, y, -0.001), Vector3d(0.015, y, -0.001), 3000);  // 10 mm/s
    if (y == 0.0) {
      // Straight at the 20 mm spike with a 1 mm press: the proxy cannot pass through it.
      EXPECT_LT(d.state.proxy_m.x(), spike_x);
      EXPECT_TRUE(d.state.saturated);
    } else {
      EXPECT_TRUE(d.state.in_contact || d.state.proxy_m == d.state.hip_m);
    }
  }
  // The pit alone, 20 mm deep, with a 1 mm press: the HIP falls in (free space) and pushes
  // sideways into the far wall, which holds the proxy (a wall, and a local distance minimum)
  // until the HIP is lifted out; then the proxy follows again.
  Driver d{s.get(), no_ramp()};
  d.tick(Vector3d(0.0, 0.0, 0.002));
  d.move(Vector3d(0.0, 0.0, 0.002), Vector3d(0.0, 0.0, -0.001), 30);
  d.move(Vector3d(0.0, 0.0, -0.001), Vector3d(0.012, 0.0, -0.001), 1200);
  EXPECT_TRUE(d.state.in_contact);
  EXPECT_GT(d.state.proxy_m.x(), 0.005);   // caught on the far wall of the pit
  EXPECT_LE(d.state.proxy_m.x(), 0.0055);
  EXPECT_LT(d.state.force_n.x(), -4.0);     // pulled back towards the pit
  // Lifting just above the plateau is not enough: the straight way from the proxy to the HIP
  // still runs into the wall, and friction holds the proxy against it.
  d.move(Vector3d(0.012, 0.0, -0.001), Vector3d(0.012, 0.0, 0.001), 20);
  EXPECT_TRUE(d.state.in_contact);
  EXPECT_LE(d.state.proxy_m.x(), 0.0055);
  d.move(Vector3d(0.012, 0.0, 0.001), Vector3d(0.012, 0.0, 0.010), 50);  // lift well out
  for (int k = 0; k < 50; ++k) d.tick(Vector3d(0.012, 0.0, 0.010));
  EXPECT_FALSE(d.state.in_contact);
  EXPECT_EQ(d.state.proxy_m, d.state.hip_m);
  d.move(Vector3d(0.012, 0.0, 0.010), Vector3d(0.012, 0.0, -0.001), 50);
  d.move(Vector3d(0.012, 0.0, -0.001), Vector3d(0.016, 0.0, -0.001), 400);
  EXPECT_NEAR(d.state.proxy_m.x(), 0.016 - 0.2 * 0.001, 3e-6);  // sliding with μ_d lag
}

// A V-groove along the grid line x = 0 between two 76° facets (slope 4), falling along +y with
// slope 0.2; the HIP walks along it 1.5 mm below the groove line at 10 mm/s. The kink lies on
// the grid line, so the Eq. 5 step from either facet crosses into the other one, which bends up:
// the proxy has to slide along the crease (two active constraints). Known answers: without
// friction it rests on the groove point closest to the HIP, press·s/(1 + s²) ahead of it along
// y; with μ_d it trails where the pull along the groove is μ_d times the pull across it.
TEST(StepProxy, SlidesAlongACreaseToTheFrictionConeEquilibrium) {
  const double cell = 0.0005;
  const double slope = 0.2;
  const double press = 0.0015;
  const HeightField f = make_field(81, 81, cell, -40 * cell, -40 * cell, [slope](double x, double y) {
    return 4.0 * std::fabs(x) - slope * y;
  });
  const auto hip = [&](double y) { return Vector3d(0.0, y, -slope * y - press); };
  // Lag Δ = y_hip − y_proxy where the pull along the groove is mu times the pull across it.
  const auto equilibrium_lag = [&](double mu) {
    const Vector3d d = Vector3d(0.0, 1.0, -slope).normalized();
    const auto excess = [&](double lag) {
      const Vector3d vh(0.0, lag, -slope * lag - press);
      const double along = vh.dot(d);
      return along - mu * std::sqrt(vh.squaredNorm() - along * along);
    };
    double lo = -press, hi = press;  // excess(lo) < 0 < excess(hi)
    for (int k = 0; k < 200; ++k) (excess(0.5 * (lo + hi)) < 0.0 ? lo : hi) = 0.5 * (lo + hi);
    return 0.5 * (lo + hi);
  };
  EXPECT_NEAR(equilibrium_lag(0.0), -press * slope / (1 + slope * slope), 1e-12);
  for (double mu : {0.0, 0.3}) {
    SurfaceOptions opt;
    opt.default_mu_d = mu;
    opt.default_mu_s = 1.2 * mu;
    const auto s = test::make_surface(f, opt);
    Driver d{s.get(), no_ramp()};
    const Vector3d above = hip(-0.01) + Vector3d(0, 0, 0.0035);
    d.tick(above);
    d.move(above, hip(-0.01), 50);
    const double lag_eq = equilibrium_lag(mu);
    double worst = 0.0;      // |lag − lag_eq| once settled
    double held_back = 0.0;  // lag beyond the equilibrium at any tick
    double off_groove = 0.0;
    for (int k = 1; k <= 2000; ++k) {
      d.tick(hip(-0.01 + 1e-5 * k));
      ASSERT_TRUE(d.state.in_contact);
      const double lag = d.state.hip_m.y() - d.state.proxy_m.y();
      if (k > 20) worst = std::max(worst, std::fabs(lag - lag_eq));
      held_back = std::max(held_back, lag - lag_eq);
      off_groove = std::max(off_groove, std::fabs(d.state.proxy_m.x()));
    }
    EXPECT_LT(off_groove, 1e-12) << "mu " << mu;
    EXPECT_LT(held_back, 1e-6) << "mu " << mu << ": held back in the crease";
    EXPECT_LT(worst, 2e-6) << "mu " << mu << ": lag off the friction-cone equilibrium " << lag_eq;
  }
}

// Blocky terraces like a scan splatted finer than its point spacing (the Buddha at 4096²):
// plateaus of 3 × 3 nodes at random heights up to 0.6 mm, so one-cell risers (slope up to 3),
// creases and pits everywhere. Pressed onto it, a point proxy is often held by a riser or in a
// pit, which is right for a god-object; it must never be held where the ideal god-object would
// slide (brute-force oracle), with or without friction.
TEST(StepProxy, NeverHeldWhereAGodObjectSlides) {
  const int n = 61;
  const double cell = 0.0002;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> level(0.0, 0.0006);
  std::vector<double> block(21 * 21);
  for (double& b : block) b = level(rng);
  const HeightField f = make_field(n, n, cell, -30 * cell, -30 * cell, [&](double x, double y) {
    const int c = static_cast<int>(std::lround(x / cell)) + 30;
    const int r = static_cast<int>(std::lround(y / cell)) + 30;
    return block[static_cast<std::size_t>((r / 3) * 21 + c / 3)];
  });
  for (double mu : {0.0, 0.3}) {
    SurfaceOptions opt;
    opt.default_mu_d = mu;
    opt.default_mu_s = 1.2 * mu;
    const auto s = test::make_surface(f, opt);
    Driver d{s.get(), no_ramp()};
    int held = 0;
    double worst_cells = 0.0;
    for (int k = 0; k < 20000; ++k) {  // 10 circles of 3 mm radius, 2 s each, HIP at z = 0
      const double a = 2 * std::numbers::pi * k / 2000.0;
      const double lift = k < 50 ? 0.002 * (1.0 - k / 50.0) : 0.0;
      const Vector3d before = d.state.proxy_m;
      d.tick(Vector3d(0.003 * std::cos(a), 0.003 * std::sin(a), lift));
      if (k < 50 || !test::proxy_held_while_sliding(d.state, before, d.params)) continue;
      ++held;
      worst_cells = std::max(worst_cells, test::godobject_slide_cells(*s, d.state.proxy_m,
                                                                      d.state.hip_m, mu));
    }
    EXPECT_GT(held, 100) << "mu " << mu << ": the terraces should hold the proxy at times";
    EXPECT_LT(worst_cells, 0.25) << "mu " << mu << ": held where a god-object slides";
  }
}

TEST(StepProxy, NoTunnellingThroughAThinRidgeAtTwoMetresPerSecond) {
  const double cell = 0.0005;
  // A one-node-wide ridge 10 mm tall along y at x = 0 on a plane at z = 0.
  const HeightField f = make_field(81, 81, cell, -40 * cell, -40 * cell, [cell](double x, double) {
    return std::fabs(x) < 0.5 * cell ? 0.010 : 0.0;
  });
  const auto s = test::make_surface(f);
  for (int rate_khz : {1, 10}) {
    const double dt = 1e-3 / rate_khz;
    const double speed = 2.0;
    for (int phase = 0; phase < 25; ++phase) {
      Driver d{s.get(), no_ramp()};
      Vector3d hip(-0.015 + phase * 0.00009, 0.0013 * phase / 25.0, 0.005);  // above the plane, below the top
      d.tick(hip, dt);
      bool crossed = false;
      for (int k = 0; k < 100 && hip.x() < 0.015; ++k) {
        hip.x() += speed * dt;
        d.tick(hip, dt);
        if (hip.x() > 0.001) {
          crossed = true;
          ASSERT_TRUE(d.state.in_contact) << "tunnelled at phase " << phase;
          ASSERT_LE(d.state.proxy_m.x(), 0.0) << "proxy passed the ridge at phase " << phase;
          ASSERT_LT(d.state.force_n.x(), 0.0);
        }
      }
      EXPECT_TRUE(crossed);
    }
  }
}

// A step longer than one cell is checked along the tangent path lifted by a tenth of a cell;
// when that path meets material the step is cut where it does (found analytically here), not
// to one cell, and never beyond. A flat plane with a one-node ridge of 10 mm at x = 3 mm
// (cells of 1 mm): the ridge's face rises from x = 2 mm by 10 mm per mm, so the lifted path
// (z = 0.1 mm) meets it at x = 2.01 mm. One iteration (max_iterations = 1), frictionless, HIP
// 10 mm ahead and 1 mm deep: the Eq. 5 step (9 mm) is capped to 4 cells, then cut to 2.01 mm.
TEST(StepProxy, AGuardedLongStepStopsWhereTheLiftedPathMeetsMaterial) {
  const double cell = 0.001;
  const HeightField f = make_field(41, 41, cell, -20 * cell, -20 * cell, [cell](double x, double) {
    return std::fabs(x - 3 * cell) < 0.5 * cell ? 0.010 : 0.0;
  });
  const auto s = test::make_surface(f);  // μ_d = μ_s = 0
  ProxyParams p = no_ramp();
  p.max_iterations = 1;
  ProxyState st;
  st.initialized = true;
  st.in_contact = true;
  st.proxy_m = Vector3d(0.0, 0.0005, 0.0);
  st.hip_m = Vector3d(0.010, 0.0005, -0.001);
  st = step_proxy(st, HipInput{st.hip_m, kDt, true}, s.get(), p);
  ASSERT_EQ(st.iterations, 1);
  EXPECT_TRUE(st.in_contact);
  EXPECT_NEAR(st.proxy_m.x(), 0.00201, 1e-7);  // 2 mm + 0.1 mm / 10
  EXPECT_NEAR(st.proxy_m.y(), 0.0005, 1e-12);
  EXPECT_NEAR(st.proxy_m.z(), s->height(st.proxy_m.x(), st.proxy_m.y()), 1e-12);
  // The next ticks climb no further than the ridge: the proxy stays before its crest.
  for (int k = 0; k < 200; ++k) st = step_proxy(st, HipInput{st.hip_m, kDt, true}, s.get(), p);
  EXPECT_LT(st.proxy_m.x(), 3 * cell);
}

TEST(StepProxy, HolesAndTheGridBorderAreAFloor) {
  HeightField f = make_field(41, 41, 0.001, -0.02, -0.02, [](double, double) { return 0.005; });
  for (int r = 15; r < 25; ++r)
    for (int c = 15; c < 25; ++c) f.at(r, c) = kNoData;
  SurfaceOptions opt;
  opt.floor_margin_m = 0.003;  // floor at 2 mm
  const auto s = test::make_surface(f, opt);
  Driver d{s.get(), no_ramp()};
  d.tick(Vector3d(-0.019, 0.0, 0.007));
  d.move(Vector3d(-0.019, 0.0, 0.007), Vector3d(-0.019, 0.0, 0.004), 30);  // press 1 mm
  // Slide across the hole: the proxy falls in (free) and meets the far wall.
  d.move(Vector3d(-0.019, 0.0, 0.004), Vector3d(0.0, 0.0, 0.004), 2000);
  EXPECT_FALSE(d.state.in_contact);  // over the hole, 2 mm above its floor
  d.move(Vector3d(0.0, 0.0, 0.004), Vector3d(0.0, 0.0, 0.0015), 100);
  EXPECT_TRUE(d.state.in_contact);  // on the floor of the hole
  EXPECT_NEAR(d.state.proxy_m.z(), 0.002, 1e-7);
  EXPECT_NEAR(d.state.force_n.z(), 800 * 0.0005, 1e-4);
  // Out beyond the border, pressing on the floor there.
  d.move(Vector3d(0.0, 0.0, 0.0015), Vector3d(0.0, 0.0, 0.007), 100);
  d.move(Vector3d(0.0, 0.0, 0.007), Vector3d(0.05, 0.05, 0.007), 500);
  d.move(Vector3d(0.05, 0.05, 0.007), Vector3d(0.05, 0.05, 0.001), 100);
  EXPECT_TRUE(d.state.in_contact);
  EXPECT_NEAR(d.state.proxy_m.z(), 0.002, 1e-7);
  EXPECT_NEAR(d.state.force_n.z(), 800 * 0.001, 1e-4);
}

TEST(StepProxy, RhoSmallAndRhoNearOne) {
  const HeightField f = make_field(101, 101, 0.001, -0.05, -0.05, [](double x, double y) {
    return test::sinusoid(x, y, 0.002, 0.04, 0.0, 1.0);
  });
  const auto s = test::make_surface(f);
  for (double rho : {0.01, 0.999, 1.0}) {
    ProxyParams p = no_ramp();
    p.rho = rho;
    p.friction_enabled = false;
    Driver d{s.get(), p};
    d.tick(Vector3d(0.0, 0.0, 0.003));
    d.move(Vector3d(0.0, 0.0, 0.003), Vector3d(0.0, 0.0, -0.001), 30);
    const Vector3d target(0.004, 0.003, -0.001);
    d.tick(target);  // a sudden 5 mm sideways jump of the HIP
    double prev_dist = (d.state.hip_m - d.state.proxy_m).norm();
    for (int k = 0; k < 400; ++k) {
      d.tick(target);
      const double dist = (d.state.hip_m - d.state.proxy_m).norm();
      EXPECT_LE(dist, prev_dist + 1e-12) << "rho " << rho;  // monotone approach: never pushed away
      prev_dist = dist;
    }
    // Converged to the closest surface point: the force is along the normal there.
    const SurfaceSample q = s->sample(d.state.proxy_m.x(), d.state.proxy_m.y());
    const Vector3d n = Vector3d(-q.dz_dx, -q.dz_dy, 1).normalized();
    EXPECT_NEAR(d.state.force_n.normalized().dot(n), 1.0, 1e-4) << "rho " << rho;
  }
}

// ---------------------------------------------------------------- long sliding, passivity

void long_sliding(int n, double mu_d) {
  const auto env = [](double x, double y) { return test::sinusoid(x, y, 0.004, 0.04, 0.0, 1.0); };
  const HeightField f = test::make_square(n, 0.1, [](double x, double y) { return test::sinusoid(x, y); });
  SurfaceOptions opt;
  opt.default_mu_d = mu_d;
  opt.default_mu_s = mu_d * 1.2;
  const auto s = test::make_surface(f, opt);
  ProxyParams p;
  // 1000 loops of 1 s each at 1 kHz: 10^6 ticks, 1000 s of sliding.
  const test::LoopResult r = test::slide_loops(*s, p, 1000, 1000, Vector3d::Zero(), 0.015, 0.0015, env);
  EXPECT_LE(r.max_force_n, p.max_force_n);
  EXPECT_LT(r.max_lag_m, 0.003) << n << "^2";
  EXPECT_GT(r.min_window_travel_ratio, 0.5) << n << "^2: the proxy stopped following";
  // Passivity: no loop returns energy to the hand (trapezoidal work of the force on the HIP).
  EXPECT_LE(r.max_loop_work_j, 1e-4) << n << "^2";
  EXPECT_LE(r.total_work_j, 1e-3) << n << "^2";
}

TEST(StepProxyLongSliding, SinusoidWithFineTexture200WithFriction) { long_sliding(200, 0.3); }
TEST(StepProxyLongSliding, SinusoidWithFineTexture800WithFriction) { long_sliding(800, 0.3); }
TEST(StepProxyLongSliding, SinusoidWithFineTexture800Frictionless) { long_sliding(800, 0.0); }

TEST(ProxyParams, ValidationNamesTheField) {
  ProxyParams p;
  EXPECT_NO_THROW(validate_proxy_params(p));
  p.rho = 0.0;
  try {
    validate_proxy_params(p);
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("rho"), std::string::npos);
  }
  p = ProxyParams{};
  p.max_force_n = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(validate_proxy_params(p), ConfigError);
}

}  // namespace
}  // namespace hc::haptics
