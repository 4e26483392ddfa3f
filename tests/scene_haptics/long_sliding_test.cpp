// Long sliding (issue 3, hard cases): 1000 s of sliding (10^6 ticks at 1 kHz) on the real Happy
// Buddha gridded at 200, 800 and 4096 cells along its height, and on the paper's sinusoid with
// fine texture at 4096² cells. On every tick the force stays within the cap and the proxy on or
// above the surface. Passivity: over every closed HIP loop, the work of the rendered force on the
// HIP plus the rise of the energy stored in the proxy spring is not positive (the hand never gets
// back more than it put in). "Never stuck": wherever the renderer holds the proxy although
// Eq. 5 asks it to slide, a brute-force god-object (godobject_oracle.hpp) cannot slide it
// either; and where the god-object physics lets a point proxy follow the HIP, it follows.
//
// The grids: 200 and 800 cells (1 mm and 0.25 mm) are scanned directly; 4096 (0.049 mm) is
// finer than the scan, so it is scanned on every 5th node (grid.upsample auto: 0.244 mm, where
// 90 % of the hit nodes have 4 hit neighbours) and interpolated bilinearly in between: its
// surface is that coarse scan's surface, without the flat splat terraces a direct 4096 scan
// has (which held even an ideal point proxy in 197 of 200 windows; measured before upsampling
// existed).
//
// Two HIP motions on the Buddha, an 8 mm circle on the belly at 1 loop/s (50 mm/s):
//
// 1. Scripted: the HIP pressed 1 mm below the rendered surface itself, f(x, y) − 1 mm, whatever
//    f does. This is the harshest motion for the renderer but not a physical one: the grids at
//    800 and 4096 have risers of up to 1.6 mm between neighbouring scan nodes (where scan views
//    overlap with ~0.2 mm misalignment, and on robe folds). The scripted HIP dives through such
//    risers. A point proxy pulled into a riser is held at its foot while the pull lies inside
//    the friction cone of the riser's face (for a face steeper than 90° − atan μ_d ≈ 73°,
//    whenever the HIP is not above the proxy), and even without friction while the HIP stays
//    below the riser's top (the foot is then a local minimum of the distance to the HIP); the
//    scripted HIP runs on. Measured with the oracle's search run as the proxy on this motion
//    (20 loops): held in 52 of 200 windows of 100 ms at 800 (lag up to 14 mm). So on this
//    motion only the no-stall, passivity and cap checks apply at 800 and 4096; the following
//    check applies at 200, where the ideal proxy follows.
//
// 2. A person: the device is held by a hand, the SimulatedDevice's virtual hand (spring-damper
//    and mass, VirtualHand defaults) that the rendered force pushes back, pulled towards a
//    target that presses 0.5 mm below the envelope a 1 mm-radius fingertip traces over the
//    statue (the lowest height of a 1 mm ball resting on it), which is what a person following
//    the shape of the belly does. The proxy must follow the HIP: in every 100 ms window it
//    travels at least 30 % of the HIP's path and lags it by less than 5 mm, at 200, 800 and
//    4096. (Scanned at 0.195 mm or 0.146 mm instead, the Buddha's view misalignment makes pits
//    that hold this hand too, for the renderer and the ideal proxy alike: the scan's detail ends
//    near 0.25 mm.)

#include "hc/haptics/haptic_surface.hpp"
#include "hc/haptics/proxy.hpp"
#include "hc/haptics/simulated_device.hpp"
#include "hc/pipeline/filters.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/transform.hpp"

#include <gtest/gtest.h>

#include "godobject_oracle.hpp"
#include "haptics_test_support.hpp"
#include "test_paths.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <numbers>
#include <string>
#include <utility>
#include <vector>

namespace {

using namespace hc;
using Eigen::Vector3d;

constexpr double kDt = 1e-3;
constexpr int kTicksPerLoop = 1000;
constexpr int kLoops = 1000;

/// The merged Buddha, recentred, in metres (loaded once for all tests of this file).
const pipeline::Cloud& buddha() {
  static const pipeline::Cloud cloud = [] {
    pipeline::Cloud c =
        pipeline::load_cloud(test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz")).value;
    Vector3d offset;
    return pipeline::to_metres_and_recentre(std::move(c), 1.0, &offset).value;
  }();
  return cloud;
}

HeightField buddha_grid(int n) {
  pipeline::ReprojectOptions opt;
  opt.grid.n_long_side = n;
  // Finer than the scan (0.2 mm cells and below) the scan runs on every K-th node and is
  // interpolated in between (auto K: 5 at 4096, 0.244 mm); 1.2-cell splats (coarse cells)
  // close its pinholes.
  if (0.2 / n < 0.0002) {
    opt.upsample_factor = 0;
    opt.splat_radius_cells = 1.2;
  }
  opt.see_through_depth_m = 0.002;
  pipeline::DepthGrid g = pipeline::reproject(buddha(), opt).value;
  g = pipeline::fill_holes(std::move(g), 64).value;
  return std::move(g.depth);
}

/// Energy stored in the proxy spring [J]: the potential whose gradient is the rendered force
/// (F = −k·x, capped at max_force_n), 0 out of contact. Ramp 1 and no damping assumed.
double spring_energy_j(const haptics::ProxyState& s, const haptics::ProxyParams& p) {
  if (!s.in_contact) return 0.0;
  const double x = (s.hip_m - s.proxy_m).norm();
  const double x_cap = p.max_force_n / p.stiffness_n_per_m;
  return x <= x_cap ? 0.5 * p.stiffness_n_per_m * x * x
                    : 0.5 * p.stiffness_n_per_m * x_cap * x_cap + p.max_force_n * (x - x_cap);
}

struct SessionResult {
  double max_force_n = 0.0;
  double max_lag_m = 0.0;                  ///< HIP − proxy in x-y, over all ticks
  double min_window_travel_ratio = 1e9;    ///< proxy / HIP x-y travel per 100 ticks
  double max_loop_balance_j = -1e9;        ///< max over loops of work on the HIP + Δ stored energy
  double total_work_j = 0.0;               ///< work of the force on the HIP over all loops
  double contact_fraction = 0.0;
  long held_ticks = 0;                     ///< ticks held although Eq. 5 asked for a slide
  double max_godobject_slide_cells = 0.0;  ///< the oracle's slide from those held proxies
  bool invariants_ok = true;
};

/// Runs kLoops closed loops of kTicksPerLoop ticks after a lead-in. `hip(tick, force)` gives
/// the HIP of tick `tick` from the force rendered on the previous one; ticks −lead_in … 0 are
/// the lead-in (not measured), then loop l holds ticks l·kTicksPerLoop + 1 … (l + 1)·kTicksPerLoop.
SessionResult run_session(const haptics::HapticSurface& s, const haptics::ProxyParams& p,
                          int lead_in_ticks,
                          const std::function<Vector3d(long, const Vector3d&)>& hip) {
  SessionResult r;
  haptics::ProxyState st;
  for (long k = -lead_in_ticks; k <= 0; ++k) {
    st = haptics::step_proxy(st, haptics::HipInput{hip(k, st.force_n), kDt, true}, &s, p);
  }
  Vector3d f_prev = st.force_n, x_prev = st.hip_m;
  double window_hip = 0.0, window_proxy = 0.0;
  long contact = 0;
  for (int loop = 0; loop < kLoops; ++loop) {
    double loop_work = 0.0;
    const double stored_start = spring_energy_j(st, p);
    for (int k = 1; k <= kTicksPerLoop; ++k) {
      const Vector3d before = st.proxy_m;
      const Vector3d x = hip(static_cast<long>(loop) * kTicksPerLoop + k, st.force_n);
      st = haptics::step_proxy(st, haptics::HipInput{x, kDt, true}, &s, p);
      if (r.invariants_ok && !haptics::test::tick_invariants(st, s, p)) {
        ADD_FAILURE() << "loop " << loop << " tick " << k << ": "
                      << haptics::test::tick_invariants(st, s, p).message();
        r.invariants_ok = false;
      }
      loop_work += 0.5 * (f_prev + st.force_n).dot(x - x_prev);
      window_hip += (x - x_prev).head<2>().norm();
      window_proxy += (st.proxy_m - before).head<2>().norm();
      if (k % 100 == 0) {
        r.min_window_travel_ratio = std::min(r.min_window_travel_ratio, window_proxy / window_hip);
        window_hip = window_proxy = 0.0;
      }
      r.max_lag_m = std::max(r.max_lag_m, (x - st.proxy_m).head<2>().norm());
      r.max_force_n = std::max(r.max_force_n, st.force_n.norm());
      contact += st.in_contact ? 1 : 0;
      if (haptics::test::proxy_held_while_sliding(st, before, p)) {
        ++r.held_ticks;
        r.max_godobject_slide_cells =
            std::max(r.max_godobject_slide_cells,
                     haptics::test::godobject_slide_cells(s, st.proxy_m, st.hip_m, st.mu_d));
      }
      f_prev = st.force_n;
      x_prev = x;
    }
    r.max_loop_balance_j = std::max(r.max_loop_balance_j, loop_work + spring_energy_j(st, p) - stored_start);
    r.total_work_j += loop_work;
  }
  r.contact_fraction = static_cast<double>(contact) / (static_cast<double>(kLoops) * kTicksPerLoop);
  return r;
}

/// The checks that hold on any motion: cap, passivity, no stall.
void expect_sound(const SessionResult& r, const haptics::ProxyParams& p, const char* what) {
  EXPECT_TRUE(r.invariants_ok) << what;
  EXPECT_LE(r.max_force_n, p.max_force_n * (1 + 1e-12)) << what;
  EXPECT_LE(r.max_loop_balance_j, 1e-6) << what << ": a loop returned more energy than was stored";
  EXPECT_LE(r.total_work_j, 1e-3) << what;
  EXPECT_LT(r.max_godobject_slide_cells, 0.25)
      << what << ": held where a god-object slides (" << r.held_ticks << " held ticks)";
}

void expect_follows(const SessionResult& r, const char* what) {
  EXPECT_GT(r.min_window_travel_ratio, 0.3) << what << ": the proxy stopped following the HIP";
  EXPECT_LT(r.max_lag_m, 0.005) << what;
}

const Vector3d kBellyCentre(0.005, 0.005, 0.0);  // the front-most dome, recentred frame
constexpr double kRadius = 0.008;

Vector3d on_circle(double loop_fraction) {
  const double a = 2 * std::numbers::pi * loop_fraction;
  return Vector3d(kBellyCentre.x() + kRadius * std::cos(a), kBellyCentre.y() + kRadius * std::sin(a), 0.0);
}

/// Motion 1: the HIP 1 mm below f itself along the circle, after a 50-tick descent from 10 mm
/// above the start and 300 ticks of rest there.
SessionResult scripted_press(const haptics::HapticSurface& s, const haptics::ProxyParams& p) {
  const auto at = [&](double fraction) {
    Vector3d x = on_circle(fraction);
    x.z() = s.height(x.x(), x.y()) - 0.001;
    return x;
  };
  const Vector3d start = at(0.0);
  return run_session(s, p, 350, [&](long tick, const Vector3d&) {
    if (tick <= -300) return Vector3d(start + Vector3d(0, 0, 0.01 * static_cast<double>(-300 - tick) / 50.0));
    if (tick <= 0) return start;
    return at(static_cast<double>((tick - 1) % kTicksPerLoop + 1) / kTicksPerLoop);
  });
}

/// Motion 2: a hand (m·a = k_h·(target − x) − b_h·v + F, integrated like SimulatedDevice in
/// 0.25 ms sub-steps with the last rendered force) pulled towards a target that circles 0.5 mm
/// below the envelope traced by a 1 mm ball, after a lead-in (target 0.5 s descending from 10 mm
/// above the start, then 0.5 s at rest there, long enough for the force ramp to end).
SessionResult hand_press(const haptics::HapticSurface& s, const haptics::ProxyParams& p) {
  constexpr double kBall = 0.001, kPress = 0.0005;
  // Envelope of the ball along the circle, one sample per tick, linear in between.
  const double cell = s.geometry().cell_size_m;
  const int reach = static_cast<int>(std::ceil(kBall / cell));
  std::vector<double> envelope(kTicksPerLoop);
  for (int k = 0; k < kTicksPerLoop; ++k) {
    const Vector3d c = on_circle(static_cast<double>(k) / kTicksPerLoop);
    double z = -1e9;
    for (int i = -reach; i <= reach; ++i) {
      for (int j = -reach; j <= reach; ++j) {
        const double d2 = (i * i + j * j) * cell * cell;
        if (d2 > kBall * kBall) continue;
        z = std::max(z, s.height(c.x() + i * cell, c.y() + j * cell) + std::sqrt(kBall * kBall - d2) - kBall);
      }
    }
    envelope[static_cast<std::size_t>(k)] = z;
  }
  const Vector3d top = on_circle(0.0) + Vector3d(0, 0, envelope[0] - kPress);
  const auto target_at = [&](double t_s) {  // one loop per second
    if (t_s <= -0.5) return Vector3d(top + Vector3d(0, 0, 0.04 * (t_s + 0.5) * (t_s + 0.5)));
    if (t_s <= 0.0) return top;
    const double u = t_s * kTicksPerLoop;
    const double w = u - std::floor(u);
    const long i0 = static_cast<long>(std::floor(u)) % kTicksPerLoop;
    const long i1 = (i0 + 1) % kTicksPerLoop;
    Vector3d x = on_circle(t_s);
    x.z() = (1 - w) * envelope[static_cast<std::size_t>(i0)] + w * envelope[static_cast<std::size_t>(i1)] - kPress;
    return x;
  };
  const haptics::VirtualHand hand;
  Vector3d x = target_at(-1.0), v = Vector3d::Zero();
  return run_session(s, p, 1000, [&](long tick, const Vector3d& force) {
    for (int sub = 1; sub <= 4; ++sub) {
      const Vector3d target = target_at((static_cast<double>(tick - 1) + 0.25 * sub) * kDt);
      const Vector3d a = (hand.stiffness_n_per_m * (target - x) - hand.damping_n_s_per_m * v + force) / hand.mass_kg;
      v += 0.25 * kDt * a;
      x += 0.25 * kDt * v;
    }
    return x;
  });
}

void slide_on_buddha(int n, bool follows_scripted, bool follows_hand) {
  const HeightField depth = buddha_grid(n);
  haptics::SurfaceOptions opt;
  opt.default_mu_d = 0.3;
  opt.default_mu_s = 0.36;
  const auto s = haptics::test::make_surface(depth, opt);
  const haptics::ProxyParams p;
  const SessionResult a = scripted_press(*s, p);
  expect_sound(a, p, "scripted");
  if (follows_scripted) expect_follows(a, "scripted");
  const SessionResult b = hand_press(*s, p);
  expect_sound(b, p, "hand");
  if (follows_hand) expect_follows(b, "hand");
  EXPECT_GT(b.contact_fraction, 0.5) << n << ": the hand should be sliding, not flying";
  for (const auto& [name, r] : {std::pair<const char*, const SessionResult&>{"scripted", a}, {"hand", b}}) {
    const std::string key(name);
    ::testing::Test::RecordProperty(key + "_min_window_ratio", std::to_string(r.min_window_travel_ratio));
    ::testing::Test::RecordProperty(key + "_max_lag_mm", std::to_string(1e3 * r.max_lag_m));
    ::testing::Test::RecordProperty(key + "_max_loop_balance_uj", std::to_string(1e6 * r.max_loop_balance_j));
    ::testing::Test::RecordProperty(key + "_held_ticks", std::to_string(r.held_ticks));
    ::testing::Test::RecordProperty(key + "_max_godobject_slide_cells", std::to_string(r.max_godobject_slide_cells));
    ::testing::Test::RecordProperty(key + "_contact_fraction", std::to_string(r.contact_fraction));
  }
}

TEST(LongSlidingOnScenes, Buddha200) { slide_on_buddha(200, true, true); }
TEST(LongSlidingOnScenes, Buddha800) { slide_on_buddha(800, false, true); }
TEST(LongSlidingOnScenes, Buddha4096) { slide_on_buddha(4096, false, true); }

TEST(LongSlidingOnScenes, SinusoidWithFineTexture4096) {
  const HeightField f =
      haptics::test::make_square(4096, 0.1, [](double x, double y) { return haptics::test::sinusoid(x, y); });
  haptics::SurfaceOptions opt;
  opt.default_mu_d = 0.3;
  opt.default_mu_s = 0.36;
  const auto s = haptics::test::make_surface(f, opt);
  haptics::ProxyParams p;
  const auto env = [](double x, double y) { return haptics::test::sinusoid(x, y, 0.004, 0.04, 0.0, 1.0); };
  const auto r = haptics::test::slide_loops(*s, p, 1000, 1000, Vector3d::Zero(), 0.015, 0.0015, env);
  EXPECT_LE(r.max_force_n, p.max_force_n * (1 + 1e-12));
  EXPECT_GT(r.min_window_travel_ratio, 0.5) << "the proxy stopped following the HIP";
  EXPECT_LT(r.max_lag_m, 0.003);
  EXPECT_LE(r.max_loop_work_j, 1e-4);
  EXPECT_LE(r.total_work_j, 1e-3);
}

}  // namespace
