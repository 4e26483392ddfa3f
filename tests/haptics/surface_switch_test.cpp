// A new surface and its workspace map reach the servo through the mailbox together: both switch
// at one tick, the proxy keeps its device position, and the force changes by at most the
// configured step per tick (it ramps in where the HIP ends up inside the new surface).

#include "hc/common/error.hpp"
#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/simulated_device.hpp"

#include "haptics_test_support.hpp"

#include <gtest/gtest.h>

#include <algorithm>

#include <atomic>
#include <chrono>
#include <optional>
#include <thread>
#include <vector>

namespace hc::haptics {
namespace {

using Eigen::Vector3d;

/// A device held where the test puts it.
class PinnedDevice final : public HapticDevice {
 public:
  PinnedDevice() : HapticDevice(SimulatedDevice::default_info()) {}
  Vector3d position = Vector3d(0, 0, 0.005);

 protected:
  void do_open() override {}
  void do_close() noexcept override {}
  DeviceStatus do_read(DeviceReading& out) noexcept override {
    out.position_m = position;
    return DeviceStatus::kOk;
  }
  DeviceStatus do_write(const Vector3d&) noexcept override { return DeviceStatus::kOk; }
};

std::unique_ptr<HapticSurface> flat_surface(double z_m) {
  return test::make_surface(test::make_square(41, 0.1, [z_m](double, double) { return z_m; }));
}

/// Arms, then presses the pinned HIP 2 mm into the surface at device (x, 0) until the force settles.
void press(ServoLoop& loop, PinnedDevice& dev, ManualClock& clock, SharedState& shared, double x_m = 0.01) {
  shared.commands.try_push(Command::of(CommandType::kArm));
  dev.position = Vector3d(x_m, 0, 0.005);
  loop.run_ticks(10, clock);
  dev.position = Vector3d(x_m, 0, -0.002);
  loop.run_ticks(600, clock);  // gate opens at once (small force), ramp 0.25 s
}

/// A frictionless servo loop on a flat surface at height 0, pressed 2 mm in by start().
class SurfaceSwitchPressed : public ::testing::Test {
 protected:
  SurfaceSwitchPressed() {
    dev.open();
    cfg.proxy.friction_enabled = false;
  }
  /// Makes the loop with `cfg` as set by the test and presses the HIP in (press()).
  ServoLoop& start() {
    loop_.emplace(dev, shared, clock, cfg);
    press(*loop_, dev, clock, shared);
    return *loop_;
  }
  SharedState shared{flat_surface(0.0)};
  ManualClock clock;
  PinnedDevice dev;
  ServoConfig cfg;

 private:
  std::optional<ServoLoop> loop_;
};

TEST_F(SurfaceSwitchPressed, SurfaceAndMapSwitchAtOneTickAndTheProxyKeepsItsDevicePosition) {
  ServoLoop& loop = start();
  Snapshot before;
  ASSERT_TRUE(shared.snapshots.read(before));
  ASSERT_TRUE(before.in_contact);
  EXPECT_NEAR(before.device_force_n.z, 800.0 * 0.002, 1e-6);
  EXPECT_EQ(before.surface_tag, 0U);

  // A window twice as coarse, elsewhere in the grid frame, 3 mm higher in grid terms.
  WorkspaceMap next;
  next.scale = 2.0;
  next.origin_m = Vector3d(0.3, -0.2, 0.003);
  // The new surface spans x ∈ [0.2, 0.4], y ∈ [−0.3, −0.1]: the new map's device box.
  shared.publish_surface(test::make_surface(test::make_field(41, 41, 0.005, 0.2, -0.3, [](double, double) { return 0.003; })),
                         next, 7);
  loop.run_ticks(1, clock);
  Snapshot after;
  ASSERT_TRUE(shared.snapshots.read(after));
  EXPECT_EQ(after.surface_tag, 7U);
  EXPECT_EQ(shared.counters.surface_tag.load(), 7U);
  EXPECT_EQ(shared.counters.surfaces_adopted.load(), 1U);
  // The HIP was mapped with the new map on the very tick the new surface was rendered.
  EXPECT_TRUE(after.hip_m.eigen().isApprox(next.to_grid(dev.position), 1e-12));
  // The proxy kept its device position: same spring, same force (the new surface sits at the
  // same device height: (0.003 − 0.003)/2 = 0).
  EXPECT_NEAR(next.to_device(after.proxy_m.eigen()).x(), 0.01, 1e-9);
  EXPECT_NEAR(next.to_device(after.proxy_m.eigen()).z(), 0.0, 1e-9);
  EXPECT_TRUE(after.in_contact);
  EXPECT_NEAR((after.device_force_n.eigen() - before.device_force_n.eigen()).norm(), 0.0, 1e-6);
  // Grid-frame stiffness follows the new scale: the device force is still k·2 mm.
  EXPECT_NEAR(after.device_force_n.z, 800.0 * 0.002, 1e-6);
  EXPECT_EQ(shared.collect_retired(), 1U);
}

TEST_F(SurfaceSwitchPressed, ForceStepIsLimitedAndRampsInWhenTheHipEndsUpInside) {
  cfg.switch_max_force_step_n = 0.5;
  ServoLoop& loop = start();
  std::vector<TickRecord> trace(400);
  loop.set_trace(trace);
  loop.run_ticks(5, clock);
  // The new surface is 5 mm higher: the HIP ends up 7 mm inside (5.6 N).
  shared.publish_surface(flat_surface(0.005), WorkspaceMap{}, 2);
  loop.run_ticks(395, clock);
  ASSERT_EQ(loop.trace_size(), 400U);
  double worst_step = 0.0;
  for (std::size_t k = 1; k < trace.size(); ++k) {
    worst_step = std::max(worst_step, (trace[k].force_n.eigen() - trace[k - 1].force_n.eigen()).norm());
    ASSERT_LE(trace[k].force_n.eigen().norm(), cfg.proxy.max_force_n + 1e-12);
    if (k >= 5) {  // on the new surface from tick 5 on
      ASSERT_GE(trace[k].proxy_m.z, shared.current_surface()->height(trace[k].proxy_m.x, trace[k].proxy_m.y) - 1e-9);
    }
  }
  EXPECT_LE(worst_step, cfg.switch_max_force_step_n + 1e-9);
  EXPECT_GT(worst_step, 0.05);  // there was a step to limit
  // The force reached the new surface's value: k·7 mm.
  EXPECT_NEAR(trace.back().force_n.z, 800.0 * 0.007, 1e-6);
  // ... within the ramp time or the step-limited time, whichever is longer (here ~23 ticks).
  EXPECT_NEAR(trace[5 + 60].force_n.z, 800.0 * 0.007, 1e-6);
}

TEST_F(SurfaceSwitchPressed, SmallChangesAreNotBlendedAndOldPublicationsStillWork) {
  ServoLoop& loop = start();
  shared.publish_surface(flat_surface(0.0002));  // without a map: the map stays
  loop.run_ticks(1, clock);
  Snapshot s;
  ASSERT_TRUE(shared.snapshots.read(s));
  EXPECT_NEAR(s.device_force_n.z, 800.0 * 0.0022, 1e-6);  // 0.16 N step: taken at once
  EXPECT_EQ(s.surface_tag, 0U);
}

TEST_F(SurfaceSwitchPressed, AWorkspaceCommandAloneAlsoCarriesTheProxyOverAndBlends) {
  ServoLoop& loop = start();
  std::vector<TickRecord> trace(200);
  loop.set_trace(trace);
  loop.run_ticks(2, clock);
  // Same surface, a map at half the scale whose device z = 0 lies 3 mm below the surface: the
  // surface moves to device z = +6 mm, the HIP (device −2 mm) ends up 8 mm inside: 6.4 N.
  WorkspaceMap m;
  m.scale = 0.5;
  m.origin_m = Vector3d(0.0, 0.0, -0.003);
  shared.commands.try_push(Command::set_workspace(m));
  loop.run_ticks(198, clock);
  double worst = 0.0;
  for (std::size_t k = 1; k < loop.trace_size(); ++k) {
    worst = std::max(worst, (trace[k].force_n.eigen() - trace[k - 1].force_n.eigen()).norm());
  }
  EXPECT_LE(worst, cfg.switch_max_force_step_n + 1e-9);
  EXPECT_GT(worst, 0.05);
  EXPECT_TRUE(trace.back().in_contact);
  EXPECT_NEAR(trace.back().force_n.z, 800.0 * 0.008, 1e-6);
  EXPECT_NEAR(m.to_device(trace.back().proxy_m.eigen()).x(), 0.01, 1e-9);  // device position kept
}

TEST_F(SurfaceSwitchPressed, BlendUnderARotatedMapReportsTheSentForceInGridAxes) {
  ServoLoop& loop = start();
  // A slope (grid z = 5 mm + 0.3·x) under a map rotated by 0.8 rad: the HIP ends up ~9 mm
  // inside, and the force has components along grid x, so the rotation matters.
  WorkspaceMap next;
  next.rotation_rad = 0.8;
  shared.publish_surface(test::make_surface(test::make_square(41, 0.1, [](double x, double) { return 0.005 + 0.3 * x; })),
                         next, 3);
  Snapshot prev;
  ASSERT_TRUE(shared.snapshots.read(prev));
  double worst_step = 0.0;
  int blended_ticks = 0;
  for (int k = 0; k < 300; ++k) {
    loop.run_ticks(1, clock);
    Snapshot s;
    ASSERT_TRUE(shared.snapshots.read(s));
    ASSERT_EQ(s.surface_tag, 3U);
    const Vector3d sent = s.device_force_n.eigen();
    worst_step = std::max(worst_step, (sent - prev.device_force_n.eigen()).norm());
    // The grid-frame force reported is the force sent, in grid axes (the forward map, tested
    // on its own in workspace_map_test.cpp, takes it back to device axes).
    EXPECT_TRUE(next.force_to_device(s.force_n.eigen()).isApprox(sent, 1e-12)) << "tick " << k;
    EXPECT_NEAR(s.force_n.eigen().norm(), sent.norm(), 1e-12) << "tick " << k;
    if ((sent - prev.device_force_n.eigen()).norm() > 1e-3) ++blended_ticks;
    prev = s;
  }
  EXPECT_LE(worst_step, cfg.switch_max_force_step_n + 1e-9);
  EXPECT_GT(blended_ticks, 5);  // the switch was blended over several ticks
  // At rest, frictionless: the force is along the plane's normal in grid axes.
  const Vector3d n = Vector3d(-0.3, 0.0, 1.0).normalized();
  EXPECT_NEAR(prev.force_n.eigen().normalized().dot(n), 1.0, 1e-6);
  EXPECT_GT(prev.force_n.eigen().norm(), 5.0);
}

TEST(SurfaceSwitch, InvalidMapsAndLimitsAreRejected) {
  SharedState shared;
  WorkspaceMap bad;
  bad.scale = 0.0;
  EXPECT_THROW(shared.publish_surface(flat_surface(0.0), bad, 1), ConfigError);
  EXPECT_FALSE(shared.surface_pending());
  ManualClock clock;
  PinnedDevice dev;
  ServoConfig cfg;
  cfg.switch_max_force_step_n = 0.0;
  EXPECT_THROW(ServoLoop(dev, shared, clock, cfg), ConfigError);
  cfg.switch_max_force_step_n = 0.5;
  cfg.switch_ramp_s = -1.0;
  EXPECT_THROW(ServoLoop(dev, shared, clock, cfg), ConfigError);
  cfg.switch_ramp_s = 0.05;
  cfg.workspace.scale = 0.0;  // an invalid map at construction
  EXPECT_THROW(ServoLoop(dev, shared, clock, cfg), ConfigError);
}

TEST(SurfaceSwitch, ThreadedPublicationsWithMapsAreAdoptedInOrder) {
  SharedState shared(flat_surface(0.0));
  SteadyClock clock;
  PinnedDevice dev;
  dev.position = Vector3d(0.0, 0.0, -0.001);
  dev.open();
  ServoConfig cfg;
  cfg.rate_hz = 4000;
  cfg.realtime = RealtimeMode::kOff;
  ServoLoop loop(dev, shared, clock, cfg);
  shared.commands.try_push(Command::of(CommandType::kArm));
  loop.start();
  std::uint64_t last = 0;
  // The tags the servo adopted, as seen from this thread: they may skip (a publication replaced
  // before any tick) but never go back.
  std::uint64_t seen = shared.counters.surface_tag.load();
  bool went_back = false;
  const auto observe = [&] {
    const std::uint64_t now = shared.counters.surface_tag.load();
    went_back = went_back || now < seen;
    seen = std::max(seen, now);
  };
  for (std::uint64_t tag = 1; tag <= 40; ++tag) {
    WorkspaceMap m;
    m.scale = 1.0 + 0.01 * static_cast<double>(tag);
    shared.publish_surface(flat_surface(0.0001 * static_cast<double>(tag % 3)), m, tag);
    last = tag;
    std::this_thread::sleep_for(std::chrono::microseconds(300));
    observe();
    shared.collect_retired();
  }
  // A hang guard, not a speed limit: a loop that never adopts the last surface fails the test
  // instead of blocking the suite.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  while (shared.counters.surface_tag.load() != last && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
    observe();
  }
  observe();
  loop.stop();
  EXPECT_FALSE(went_back) << "an older surface was adopted after a newer one";
  ASSERT_EQ(shared.counters.surface_tag.load(), last) << "the last surface was not adopted within 30 s";
  Snapshot s;
  ASSERT_TRUE(shared.snapshots.read(s));
  EXPECT_EQ(s.surface_tag, last);
  EXPECT_NEAR(loop.config().workspace.scale, 1.4, 1e-12);
  shared.collect_retired();
}

}  // namespace
}  // namespace hc::haptics
