// LodController: windows, maps and scales per level, and level switches and pans during
// contact in a scripted servo session (no force step above the limit, proxy on the surface).

#include "hc/common/error.hpp"
#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/simulated_device.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/session/lod_controller.hpp"

#include <gtest/gtest.h>

#include "session_fixtures.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <memory>
#include <numbers>
#include <thread>
#include <vector>

namespace hc::session {
namespace {

using namespace hc::pipeline;

using Eigen::Vector3d;

/// The paper's validation sinusoid (A = 4 mm, λ = 40 mm) with a fine texture (0.2 mm, λ = 2 mm)
/// over a 100 mm square: n × n samples.
std::shared_ptr<LodPyramid> sinusoid_pyramid(int n, int window_cells, int min_cells) {
  const double side = 0.1, cell = side / (n - 1);
  HeightField depth(GridGeometry{n, n, -side / 2, -side / 2, cell});
  const double k = 2 * std::numbers::pi / 0.04, kt = 2 * std::numbers::pi / 0.002;
  for (int r = 0; r < n; ++r) {
    for (int c = 0; c < n; ++c) {
      const double x = depth.geometry().x_of_col(c), y = depth.geometry().y_of_row(r);
      depth.at(r, c) = static_cast<float>(0.004 * std::sin(k * x) * std::sin(k * y) + 0.0002 * std::sin(kt * x) * std::sin(kt * y));
    }
  }
  return test::pyramid_of(std::move(depth), window_cells, min_cells);
}

TEST(LodController, TheNeighbouringLevelsAreBuiltInTheBackground) {
  auto pyr = sinusoid_pyramid(401, 100, 30);  // levels 401, 201, 101, 51
  haptics::SharedState shared;
  LodController lod(pyr, shared, test::controller_options());
  lod.set_window(2, 0, 0);
  lod.wait_prefetch_idle();
  EXPECT_TRUE(pyr->is_cached(1, true));
  EXPECT_TRUE(pyr->is_cached(3, true));
  // The prefetched level is the level a direct build gives (same depth, same layers).
  auto fresh = sinusoid_pyramid(401, 100, 30);
  const auto a = pyr->level(1), b = fresh->level(1);
  EXPECT_EQ(a->depth_m.values(), b->depth_m.values());
  EXPECT_EQ(a->texture_m.values(), b->texture_m.values());
  EXPECT_EQ(a->mu_d.values(), b->mu_d.values());
  // A switch to a prefetched level builds only its window.
  const HapticWindow& w = lod.zoom_in();
  EXPECT_EQ(w.level, 1);
  EXPECT_EQ(w.level_seconds, 0.0);
  // Switched off: nothing is built beyond what is asked for.
  auto quiet = sinusoid_pyramid(401, 100, 30);
  LodControllerOptions off = test::controller_options();
  off.prefetch_neighbours = false;
  LodController still(quiet, shared, off);
  still.set_window(2, 0, 0);
  still.wait_prefetch_idle();
  EXPECT_FALSE(quiet->is_cached(1, true));
  EXPECT_FALSE(quiet->is_cached(3, true));
}

TEST(LodPyramid, ConcurrentRequestsGiveTheLevelsAndWindowsOfASequentialPyramid) {
  auto shared_pyr = sinusoid_pyramid(301, 60, 20);
  auto reference = sinusoid_pyramid(301, 60, 20);
  const int levels = shared_pyr->level_count();
  ASSERT_GE(levels, 3);
  std::vector<std::shared_ptr<const LodWindowLayers>> got_a, got_b;
  std::thread other([&] {
    for (int l = levels - 1; l >= 0; --l) got_b.push_back(shared_pyr->window(l, 5, 7, 60, 60));
  });
  for (int l = 0; l < levels; ++l) got_a.push_back(shared_pyr->window(l, 5, 7, 60, 60));
  other.join();
  for (int l = 0; l < levels; ++l) {
    const auto ref = reference->window(l, 5, 7, 60, 60);
    const auto& b = got_b[static_cast<std::size_t>(levels - 1 - l)];
    for (const auto* w : {got_a[static_cast<std::size_t>(l)].get(), b.get()}) {
      EXPECT_EQ(w->depth_m.values(), ref->depth_m.values()) << "level " << l;
      EXPECT_EQ(w->envelope_m.values(), ref->envelope_m.values()) << "level " << l;
      EXPECT_EQ(w->mu_s.values(), ref->mu_s.values()) << "level " << l;
    }
  }
}

TEST(LodController, EachFinerLevelHalvesTheScaleAndWindowsFitTheDeviceBox) {
  auto pyr = sinusoid_pyramid(401, 100, 30);
  ASSERT_EQ(pyr->level_count(), 4);  // 401, 201, 101, 51
  haptics::SharedState shared;
  LodController lod(pyr, shared, test::controller_options());
  EXPECT_FALSE(lod.has_window());
  EXPECT_THROW(lod.window(), InputError);
  EXPECT_THROW(lod.pan(1, 0), InputError);
  double previous_scale = 0.0;
  for (int level = 0; level < 3; ++level) {
    const HapticWindow& w = lod.set_window(level, 10, 20);
    EXPECT_EQ(w.level, level);
    EXPECT_EQ(w.rows, 100);
    EXPECT_EQ(w.cols, 100);
    EXPECT_EQ(w.col0, std::min(10, lod.level_geometry(level).cols - 100));
    EXPECT_EQ(w.row0, std::min(20, lod.level_geometry(level).rows - 100));
    // The window's x-y extent fills the 100 mm device box exactly (square window, square box).
    const Vector3d lo = w.map.to_grid(Vector3d(-0.05, -0.05, 0.0)), hi = w.map.to_grid(Vector3d(0.05, 0.05, 0.0));
    EXPECT_NEAR(lo.x(), w.geometry.x0_m, 1e-12);
    EXPECT_NEAR(lo.y(), w.geometry.y0_m, 1e-12);
    EXPECT_NEAR(hi.x(), w.geometry.x_of_col(w.cols - 1), 1e-12);
    EXPECT_NEAR(hi.y(), w.geometry.y_of_row(w.rows - 1), 1e-12);
    // Device z = 0 at the window's mid height; z scales like x and y (uniform map).
    EXPECT_NEAR(w.map.origin_m.z(), 0.5 * (w.min_height_m + w.max_height_m), 1e-12);
    if (level > 0) {
      EXPECT_NEAR(w.map.scale / previous_scale, 2.0, 1e-12);
    }
    previous_scale = w.map.scale;
    EXPECT_EQ(w.tag, static_cast<std::uint64_t>(level + 1));
    EXPECT_TRUE(shared.surface_pending());
  }
  // Level 3 (51² samples) is coarser than the 100-sample window: the window is the whole level,
  // centred in the device box, at the level's scale.
  const HapticWindow& w3 = lod.set_window(3, 40, 40);
  EXPECT_EQ(w3.rows, 51);
  EXPECT_EQ(w3.col0, 0);
  EXPECT_NEAR(w3.map.scale / previous_scale, 2.0, 1e-12);
  EXPECT_NEAR(w3.map.origin_m.x(), 0.0, 1e-12);
  // Windows touching the border are clamped inside the level, and pan stops there.
  const HapticWindow& edge = lod.set_window(0, 1000, -7);
  EXPECT_EQ(edge.col0, 301);
  EXPECT_EQ(edge.row0, 0);
  const std::uint64_t tag = edge.tag;
  EXPECT_EQ(lod.pan(5, -3).tag, tag);  // nothing moves: no publication
  const HapticWindow& panned = lod.pan(-10, 4);
  EXPECT_EQ(panned.col0, 291);
  EXPECT_EQ(panned.row0, 4);
  EXPECT_NEAR(panned.map.origin_m.x() - lod.level_geometry(0).x_of_col(291 + 49.5), 0.0, 1e-12);
  EXPECT_THROW(lod.set_window(4, 0, 0), InputError);
  // Centring: the window's centre sample is the nearest to the point.
  const HapticWindow& c = lod.centre_window(1, 0.0, 0.0);
  EXPECT_NEAR(c.geometry.x_of_col(49.5), 0.0, lod.level_geometry(1).cell_size_m);
}

TEST(LodController, ZoomKeepsTheAnchorInBothFrames) {
  auto pyr = sinusoid_pyramid(401, 100, 30);
  haptics::SharedState shared;
  LodController lod(pyr, shared, test::controller_options());
  lod.set_level(2);
  const Vector3d anchor(0.012, -0.007, 0.001);
  const haptics::WorkspaceMap before = lod.window().map;
  const HapticWindow& w = lod.zoom_in(anchor);
  EXPECT_EQ(w.level, 1);
  EXPECT_NEAR(before.scale / w.map.scale, 2.0, 1e-12);
  EXPECT_TRUE(w.map.to_device(anchor).isApprox(before.to_device(anchor), 1e-12));
  // The window is centred on where the device box lands.
  EXPECT_NEAR(w.geometry.x_of_col(0.5 * (w.cols - 1)), w.map.origin_m.x(), w.geometry.cell_size_m);
  EXPECT_EQ(lod.zoom_in(anchor).level, 0);
  const std::uint64_t tag = lod.window().tag;
  EXPECT_EQ(lod.zoom_in(anchor).tag, tag);  // finest already
  EXPECT_EQ(lod.zoom_out(anchor).level, 1);
}

/// Force steps at the switch (tick first_new) and proxy-on-surface from it on.
struct SwitchCheck {
  double worst_step_n = 0.0;
  double worst_below_m = 0.0;
  bool contact_kept = true;
};

/// The longest a switch's force blend can last [ticks]: switch_ramp_s, or longer when the gap
/// between the old and the new force is large: each tick moves by at most half the step limit,
/// and the gap is at most twice the force cap (opposite forces).
std::size_t blend_ticks(const haptics::ServoConfig& cfg) {
  const double ramp = cfg.switch_ramp_s * cfg.rate_hz;
  const double by_gap = 2.0 * cfg.proxy.max_force_n / (0.5 * cfg.switch_max_force_step_n);
  return static_cast<std::size_t>(std::ceil(std::max(ramp, by_gap))) + 1;
}

SwitchCheck check_trace(const std::vector<haptics::TickRecord>& trace, std::size_t first_new, std::size_t n,
                        const haptics::HapticSurface& s, std::size_t blend) {
  SwitchCheck c;
  for (std::size_t k = 1; k < n; ++k) {
    const double step = (trace[k].force_n.eigen() - trace[k - 1].force_n.eigen()).norm();
    // The switch's steps: from the switch tick to the end of the longest possible blend.
    if (k >= first_new && k <= first_new + blend) c.worst_step_n = std::max(c.worst_step_n, step);
    if (k < first_new) continue;
    c.worst_below_m = std::max(c.worst_below_m, s.height(trace[k].proxy_m.x, trace[k].proxy_m.y) - trace[k].proxy_m.z);
    c.contact_kept = c.contact_kept && trace[k].in_contact;
  }
  return c;
}

TEST(LodController, LevelSwitchAndPanDuringContactHaveNoForceSpike) {
  auto pyr = sinusoid_pyramid(401, 120, 30);
  const haptics::DeviceInfo info = haptics::SimulatedDevice::default_info();
  haptics::SharedState shared;
  // The envelope only (texture gain 0) and no friction (below): the rendered force then varies
  // smoothly while sliding (the 0.2 mm texture's crests and static friction's stick-slip snap
  // the proxy now and then, steps of their own), so every step within the blend is the switch's.
  LodControllerOptions options = test::controller_options();
  options.surface.texture_gain = 0.0;
  LodController lod(pyr, shared, options);
  const HapticWindow& start = lod.set_level(1);

  haptics::ManualClock clock;
  haptics::ScriptedPath path;
  path.kind = haptics::PathKind::kCircle;
  path.half_x_m = 0.004;  // small circles: the hand keeps pressing while the level changes
  path.z_above_m = 0.02;
  path.z_contact_m = -0.01;
  path.speed_m_per_s = 0.02;
  path.approach_s = 0.3;
  haptics::SimulatedDevice dev(clock, path, haptics::VirtualHand{}, info);
  dev.open();
  haptics::ServoConfig cfg;
  cfg.workspace = start.map;
  cfg.proxy.stiffness_n_per_m = 800.0;
  cfg.switch_max_force_step_n = 0.5;
  // Without friction the rendered force varies smoothly while sliding (static friction's
  // stick-slip steps are the renderer's, not the switch's), so any step seen is the switch's.
  cfg.proxy.friction_enabled = false;
  haptics::ServoLoop loop(dev, shared, clock, cfg);
  shared.commands.try_push(haptics::Command::of(haptics::CommandType::kArm));
  loop.run_ticks(2000, clock);
  ASSERT_TRUE(lod.adopted());

  std::vector<haptics::TickRecord> trace(400);
  const auto run_switch = [&](const char* what, const std::function<void(const Vector3d&)>& request) {
    haptics::Snapshot snap;
    shared.snapshots.read(snap);
    ASSERT_TRUE(snap.in_contact) << what;
    const double force_before = snap.force_n.eigen().norm();
    EXPECT_GT(force_before, 0.5) << what;
    loop.set_trace(trace);
    loop.run_ticks(20, clock);
    shared.snapshots.read(snap);
    request(snap.proxy_m.eigen());
    loop.run_ticks(trace.size() - 20, clock);
    ASSERT_TRUE(lod.adopted()) << what;
    ASSERT_GT(loop.trace_size(), 20 + blend_ticks(cfg)) << what;  // the trace covers the whole blend
    const SwitchCheck c = check_trace(trace, 20, loop.trace_size(), *shared.current_surface(), blend_ticks(cfg));
    EXPECT_LE(c.worst_step_n, cfg.switch_max_force_step_n) << what;
    EXPECT_LT(c.worst_below_m, 1e-6) << what;
    EXPECT_TRUE(c.contact_kept) << what;
    shared.collect_retired();
  };
  run_switch("zoom in", [&](const Vector3d& proxy) {
    const HapticWindow& w = lod.zoom_in(proxy);
    EXPECT_EQ(w.level, 0);
  });
  run_switch("pan", [&](const Vector3d&) { EXPECT_EQ(lod.pan(15, -10).level, 0); });
  run_switch("zoom out twice", [&](const Vector3d& proxy) {
    lod.zoom_out(proxy);
    EXPECT_EQ(lod.zoom_out(proxy).level, 2);
  });
  // start, zoom in, pan, and the second zoom out (it replaced the first before any tick).
  EXPECT_EQ(shared.counters.surfaces_adopted.load(), 4U);
}

TEST(LodController, ACornerWindowIsRenderedWithTheProxyAlwaysOnItsSurface) {
  // The window touching two borders of the finest level; a hand rastering over nearly the whole
  // device box, so the proxy passes the window's edges (padding ring, floor beyond).
  auto pyr = sinusoid_pyramid(301, 80, 30);
  haptics::SharedState shared;
  LodController lod(pyr, shared, test::controller_options());
  const HapticWindow& w = lod.set_window(0, 10000, 10000);
  EXPECT_EQ(w.col0, 301 - 80);
  EXPECT_EQ(w.row0, 301 - 80);
  haptics::ManualClock clock;
  haptics::ScriptedPath path;
  path.kind = haptics::PathKind::kRaster;
  path.half_x_m = 0.048;
  path.half_y_m = 0.048;
  path.raster_spacing_m = 0.012;
  path.z_above_m = (w.max_height_m - w.map.origin_m.z()) / w.map.scale + 0.01;
  path.z_contact_m = -0.006;
  path.speed_m_per_s = 0.1;
  path.approach_s = 0.2;
  haptics::SimulatedDevice dev(clock, path, haptics::VirtualHand{}, haptics::SimulatedDevice::default_info());
  dev.open();
  haptics::ServoConfig cfg;
  cfg.workspace = w.map;
  haptics::ServoLoop loop(dev, shared, clock, cfg);
  std::vector<haptics::TickRecord> trace(4000);
  loop.set_trace(trace);
  shared.commands.try_push(haptics::Command::of(haptics::CommandType::kArm));
  loop.run_ticks(4000, clock);
  const haptics::HapticSurface& s = *shared.current_surface();
  int contact = 0;
  for (const haptics::TickRecord& r : trace) {
    ASSERT_LE(r.force_n.eigen().norm(), cfg.proxy.max_force_n + 1e-12);
    ASSERT_GE(r.proxy_m.z, s.height(r.proxy_m.x, r.proxy_m.y) - 1e-6);
    contact += r.in_contact ? 1 : 0;
  }
  EXPECT_GT(contact, 2000);
}

}  // namespace
}  // namespace hc::session
