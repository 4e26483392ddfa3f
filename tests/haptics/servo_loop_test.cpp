#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/simulated_device.hpp"

#include "haptics_test_support.hpp"

#include "hc/common/error.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <thread>
#include <vector>

namespace hc::haptics {
namespace {

using Eigen::Vector3d;

std::unique_ptr<const HapticSurface> sinusoid_surface(int n = 200) {
  const HeightField f = test::make_square(n, 0.1, [](double x, double y) { return test::sinusoid(x, y); });
  SurfaceOptions opt;
  opt.default_mu_d = 0.3;
  opt.default_mu_s = 0.4;
  return test::make_surface(f, opt);
}

// Polls `done` every 200 µs until it holds or 20 s have passed (a threaded loop's progress; the
// assertions after the wait decide, the bound only keeps a broken loop from hanging the suite).
template <class Done>
void wait_until(const Done& done) {
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (!done() && std::chrono::steady_clock::now() < give_up) std::this_thread::sleep_for(std::chrono::microseconds(200));
}

ScriptedPath circle_path() {
  ScriptedPath p;
  p.kind = PathKind::kCircle;
  p.half_x_m = 0.015;
  p.z_above_m = 0.01;
  p.z_contact_m = -0.01;  // the virtual hand pulls the HIP into the surface
  p.speed_m_per_s = 0.05;
  p.approach_s = 0.5;
  return p;
}

TEST(ServoLoop, ScriptedSessionAsFastAsPossible) {
  SharedState shared(sinusoid_surface());
  ManualClock clock;
  SimulatedDevice dev(clock, circle_path());
  dev.open();
  ServoConfig cfg;
  ServoLoop loop(dev, shared, clock, cfg);
  std::vector<TickRecord> trace(6000);
  loop.set_trace(trace);
  ASSERT_TRUE(shared.commands.try_push(Command::of(CommandType::kArm)));
  loop.run_ticks(5000, clock);
  EXPECT_EQ(dev.state(), DeviceState::kArmed);
  EXPECT_EQ(loop.stats().ticks, 5000U);
  EXPECT_EQ(loop.stats().compute.count(), 5000U);
  EXPECT_EQ(loop.trace_size(), 5000U);
  EXPECT_EQ(shared.counters.ticks.load(), 5000U);
  EXPECT_EQ(clock.now_ns(), 5000000000LL);
  // The hand pressed the HIP into the surface and the rendered force held it there.
  const HapticSurface& s = *shared.current_surface();
  int contact_ticks = 0;
  double max_force = 0.0;
  for (std::size_t k = 0; k < loop.trace_size(); ++k) {
    const TickRecord& r = trace[k];
    contact_ticks += r.in_contact ? 1 : 0;
    const double f = r.force_n.eigen().norm();
    max_force = std::max(max_force, f);
    ASSERT_LE(f, cfg.proxy.max_force_n + 1e-12);
    ASSERT_GE(r.proxy_m.z, s.height(r.proxy_m.x, r.proxy_m.y) - 1e-6);
  }
  EXPECT_GT(contact_ticks, 4000);
  EXPECT_GT(max_force, 1.0);
  // Rendered force fed back: the HIP stays far above the hand's target (−10 mm).
  EXPECT_GT(trace[4999].hip_m.z, -0.008);
  // The snapshot is the last tick; events told about the touch-down.
  Snapshot snap;
  ASSERT_TRUE(shared.snapshots.read(snap));
  EXPECT_EQ(snap.tick, 4999U);
  EXPECT_TRUE(snap.in_contact);
  EXPECT_EQ(static_cast<DeviceState>(snap.device_state), DeviceState::kArmed);
  ContactEvent e;
  ASSERT_TRUE(shared.events.try_pop(e));
  EXPECT_EQ(e.type, ContactEventType::kOnset);
  int slides = 0;
  while (shared.events.try_pop(e)) slides += e.type == ContactEventType::kSlide ? 1 : 0;
  EXPECT_GT(slides, 50);  // at most one per 10 ticks of sliding (not while sticking)
  EXPECT_GT(loop.stats().compute.percentile_ns(0.5), 0.0);
}

TEST(ServoLoop, AStillPressSendsPressEventsWithTheGrowingForce) {
  // The hand holds the centre, pressing 10 mm into the surface: after the onset the proxy does
  // not slip, so no slide events; press events (speed 0) carry the force as it ramps in.
  SharedState shared(sinusoid_surface());
  ManualClock clock;
  ScriptedPath hold = circle_path();
  hold.kind = PathKind::kHold;
  SimulatedDevice dev(clock, hold);
  dev.open();
  ServoLoop loop(dev, shared, clock, ServoConfig{});
  ASSERT_TRUE(shared.commands.try_push(Command::of(CommandType::kArm)));
  loop.run_ticks(2000, clock);
  ContactEvent e;
  std::vector<ContactEvent> events;
  while (shared.events.try_pop(e)) events.push_back(e);
  ASSERT_FALSE(events.empty());
  EXPECT_EQ(events.front().type, ContactEventType::kOnset);
  int presses = 0, slides = 0;
  double first_press_force = -1.0, last_press_force = 0.0;
  for (const ContactEvent& ev : events) {
    if (ev.type == ContactEventType::kSlide) ++slides;
    if (ev.type != ContactEventType::kPress) continue;
    ++presses;
    EXPECT_EQ(ev.speed_m_per_s, 0.0);
    const double f = ev.force_n.eigen().norm();
    if (first_press_force < 0.0) first_press_force = f;
    last_press_force = f;
  }
  EXPECT_GT(presses, 100);  // one per 10 ticks of contact without slip
  EXPECT_LT(slides, presses / 10);
  EXPECT_GT(last_press_force, 1.0);
  EXPECT_GT(last_press_force, 2.0 * first_press_force);
}

TEST(ServoLoop, CommandsAreClampedOrRejected) {
  SharedState shared(sinusoid_surface(50));
  ManualClock clock;
  SimulatedDevice dev(clock, circle_path());
  dev.open();
  ServoLoop loop(dev, shared, clock, ServoConfig{});
  shared.commands.try_push(Command::of(CommandType::kSetStiffness, 1e9));
  shared.commands.try_push(Command::of(CommandType::kSetMaxForce, std::numeric_limits<double>::quiet_NaN()));
  shared.commands.try_push(Command::of(CommandType::kSetRho, 5.0));
  WorkspaceMap bad;
  bad.scale = -1;
  shared.commands.try_push(Command::set_workspace(bad));
  WorkspaceMap zoom;
  zoom.scale = 0.5;
  shared.commands.try_push(Command::set_workspace(zoom));
  shared.commands.try_push(Command::of(CommandType::kResetFault));  // not in Fault: rejected
  loop.run_ticks(1, clock);
  EXPECT_EQ(loop.config().proxy.stiffness_n_per_m, dev.info().max_stable_stiffness_n_per_m);
  EXPECT_EQ(loop.config().proxy.rho, 1.0);
  EXPECT_EQ(loop.config().workspace.scale, 0.5);
  EXPECT_EQ(shared.counters.commands_applied.load(), 3U);
  EXPECT_EQ(shared.counters.commands_rejected.load(), 3U);
  shared.commands.try_push(Command::of(CommandType::kStop));
  loop.run_ticks(100, clock);
  EXPECT_EQ(loop.stats().ticks, 2U);  // stopped after the tick that applied kStop
}

TEST(ServoLoop, ConfigurationOutsideTheDeviceIsAnError) {
  SharedState shared;
  ManualClock clock;
  SimulatedDevice dev(clock, circle_path());
  ServoConfig cfg;
  cfg.rate_hz = 20000;
  EXPECT_THROW(ServoLoop(dev, shared, clock, cfg), ConfigError);
  cfg = ServoConfig{};
  cfg.proxy.stiffness_n_per_m = 1e5;
  EXPECT_THROW(ServoLoop(dev, shared, clock, cfg), ConfigError);
  cfg = ServoConfig{};
  cfg.proxy.max_force_n = 100;
  EXPECT_THROW(ServoLoop(dev, shared, clock, cfg), ConfigError);
  EXPECT_EQ(realtime_mode_from_string("enforce"), RealtimeMode::kEnforce);
  EXPECT_THROW(realtime_mode_from_string("always"), ConfigError);
  ServoLoop loop(dev, shared, clock, ServoConfig{});
  ManualClock wrong;
  EXPECT_THROW(loop.run_ticks(1, wrong), ConfigError);
  EXPECT_THROW(loop.start(), InputError);  // device closed
}

TEST(ServoLoop, ForceLimitsAreTheDevicesInConfigAndCommands) {
  SharedState shared(sinusoid_surface(50));
  ManualClock clock;
  SimulatedDevice dev(clock, circle_path());
  const DeviceInfo& info = dev.info();
  ServoConfig cfg;
  cfg.proxy.damping_n_s_per_m = info.max_damping_n_s_per_m * 2;
  EXPECT_THROW(ServoLoop(dev, shared, clock, cfg), ConfigError);
  dev.open();
  ServoLoop loop(dev, shared, clock, ServoConfig{});
  shared.commands.try_push(Command::of(CommandType::kSetDamping, 1e9));
  shared.commands.try_push(Command::of(CommandType::kSetMaxForce, 1e9));
  shared.commands.try_push(Command::of(CommandType::kSetMaxForce, -1.0));  // rejected
  shared.commands.try_push(Command::of(CommandType::kSetMaxForce, 0.0));   // rejected
  shared.commands.try_push(Command::of(CommandType::kSetStiffness, -5.0));
  shared.commands.try_push(Command::of(CommandType::kSetDamping, std::numeric_limits<double>::infinity()));  // rejected
  loop.run_ticks(1, clock);
  EXPECT_EQ(loop.config().proxy.damping_n_s_per_m, info.max_damping_n_s_per_m);
  EXPECT_EQ(loop.config().proxy.max_force_n, info.max_force_n);
  EXPECT_EQ(loop.config().proxy.stiffness_n_per_m, 0.0);
  EXPECT_EQ(shared.counters.commands_applied.load(), 3U);
  EXPECT_EQ(shared.counters.commands_rejected.load(), 3U);
}

/// A device whose position turns NaN on request: NaN in → zero force out, device faulted.
class GlitchDevice final : public HapticDevice {
 public:
  GlitchDevice() : HapticDevice(SimulatedDevice::default_info()) {}
  bool glitch = false;
  Vector3d position = Vector3d(0, 0, -0.002);

 protected:
  void do_open() override {}
  void do_close() noexcept override {}
  DeviceStatus do_read(DeviceReading& out) noexcept override {
    out.position_m = glitch ? Vector3d(std::numeric_limits<double>::quiet_NaN(), 0, 0) : position;
    return DeviceStatus::kOk;
  }
  DeviceStatus do_write(const Vector3d&) noexcept override { return DeviceStatus::kOk; }
};

TEST(ServoLoop, NonFiniteHipGivesZeroForceAndAFault) {
  const HeightField flat = test::make_square(21, 0.02, [](double, double) { return 0.0; });
  SharedState shared(test::make_surface(flat));
  ManualClock clock;
  GlitchDevice dev;
  dev.position = Vector3d(0, 0, 0.005);  // start above, then press
  dev.open();
  ServoConfig cfg;
  cfg.proxy.ramp_time_s = 0.0;
  ServoLoop loop(dev, shared, clock, cfg);
  shared.commands.try_push(Command::of(CommandType::kArm));
  loop.run_ticks(2, clock);
  dev.position = Vector3d(0, 0, -0.002);
  loop.run_ticks(5, clock);
  EXPECT_NEAR(dev.last_force_n().z(), cfg.proxy.stiffness_n_per_m * 0.002, 1e-9);
  dev.glitch = true;
  loop.run_ticks(1, clock);
  EXPECT_EQ(dev.last_force_n(), Vector3d::Zero());
  EXPECT_EQ(dev.state(), DeviceState::kFault);
  EXPECT_EQ(shared.counters.nonfinite_inputs.load(), 1U);
  dev.glitch = false;
  loop.run_ticks(3, clock);
  EXPECT_EQ(dev.last_force_n(), Vector3d::Zero());  // zero until an explicit reset
  shared.commands.try_push(Command::of(CommandType::kResetFault));
  shared.commands.try_push(Command::of(CommandType::kArm));
  loop.run_ticks(3, clock);
  EXPECT_EQ(dev.state(), DeviceState::kArmed);
  // The gate holds: 1.6 N at the HIP is above the 0.5 N gate, so the force stays off until
  // the user eases off.
  EXPECT_EQ(dev.last_force_n(), Vector3d::Zero());
  dev.position = Vector3d(0, 0, -0.0005);
  loop.run_ticks(3, clock);
  EXPECT_NEAR(dev.last_force_n().z(), cfg.proxy.stiffness_n_per_m * 0.0005, 1e-9);
}

/// A device whose read and write statuses the test sets (a flaky transport).
class FlakyDevice final : public HapticDevice {
 public:
  FlakyDevice() : HapticDevice(SimulatedDevice::default_info()) {}
  Vector3d position = Vector3d(0, 0, 0.005);
  DeviceStatus read_status = DeviceStatus::kOk;
  DeviceStatus write_status = DeviceStatus::kOk;

 protected:
  void do_open() override {}
  void do_close() noexcept override {}
  DeviceStatus do_read(DeviceReading& out) noexcept override {
    out.position_m = position;
    return read_status;
  }
  DeviceStatus do_write(const Vector3d&) noexcept override { return write_status; }
};

TEST(ServoLoop, DeviceIoErrorsFaultTheDeviceAndTheGateHoldsAfterTheReset) {
  SharedState shared(test::make_surface(test::make_square(21, 0.02, [](double, double) { return 0.0; })));
  ManualClock clock;
  FlakyDevice dev;
  dev.open();
  ServoConfig cfg;
  cfg.proxy.ramp_time_s = 0.0;
  ServoLoop loop(dev, shared, clock, cfg);
  const double k = cfg.proxy.stiffness_n_per_m;
  const auto press_to = [&](double z_m) {
    dev.position = Vector3d(0, 0, z_m);
    loop.run_ticks(5, clock);
  };
  shared.commands.try_push(Command::of(CommandType::kArm));
  press_to(0.005);
  press_to(-0.002);
  ASSERT_NEAR(dev.last_force_n().z(), k * 0.002, 1e-9);

  // A failed read: no position to render, so zero force at once, and the device is faulted.
  dev.read_status = DeviceStatus::kIoError;
  loop.run_ticks(1, clock);
  Snapshot s;
  ASSERT_TRUE(shared.snapshots.read(s));
  EXPECT_EQ(dev.state(), DeviceState::kFault);
  EXPECT_EQ(dev.last_force_n(), Vector3d::Zero());
  EXPECT_EQ(s.device_force_n.eigen(), Vector3d::Zero());
  EXPECT_EQ(s.force_n.eigen(), Vector3d::Zero());
  EXPECT_FALSE(s.gate_open);
  EXPECT_EQ(shared.counters.device_errors.load(), 1U);
  dev.read_status = DeviceStatus::kOk;
  loop.run_ticks(5, clock);
  EXPECT_EQ(dev.last_force_n(), Vector3d::Zero());  // zero until an explicit reset
  // Reset and re-arm while still pressed 2 mm in (1.6 N, above the 0.5 N gate): no kick.
  shared.commands.try_push(Command::of(CommandType::kResetFault));
  shared.commands.try_push(Command::of(CommandType::kArm));
  loop.run_ticks(5, clock);
  EXPECT_EQ(dev.state(), DeviceState::kArmed);
  EXPECT_EQ(dev.last_force_n(), Vector3d::Zero());
  press_to(-0.0005);  // eased off below the gate: forces return
  EXPECT_NEAR(dev.last_force_n().z(), k * 0.0005, 1e-9);

  // A failed write: counted, the device is faulted and its force zeroed in the same tick.
  dev.write_status = DeviceStatus::kIoError;
  loop.run_ticks(1, clock);
  ASSERT_TRUE(shared.snapshots.read(s));
  EXPECT_EQ(dev.state(), DeviceState::kFault);
  EXPECT_EQ(dev.last_force_n(), Vector3d::Zero());
  EXPECT_EQ(s.device_force_n.eigen(), Vector3d::Zero());
  EXPECT_EQ(shared.counters.device_errors.load(), 2U);
  dev.write_status = DeviceStatus::kOk;
  loop.run_ticks(5, clock);
  EXPECT_EQ(dev.last_force_n(), Vector3d::Zero());
}

TEST(ServoLoop, NewSurfaceIsAdoptedAtATickBoundaryAndTheOldOneRetired) {
  SharedState shared(sinusoid_surface(50));
  ManualClock clock;
  SimulatedDevice dev(clock, circle_path());
  dev.open();
  ServoLoop loop(dev, shared, clock, ServoConfig{});
  shared.commands.try_push(Command::of(CommandType::kArm));
  loop.run_ticks(1500, clock);
  const HapticSurface* before = shared.current_surface();
  // A higher surface appears under the proxy: it is lifted onto it, never left inside.
  const HeightField higher = test::make_square(50, 0.1, [](double x, double y) { return test::sinusoid(x, y) + 0.003; });
  shared.publish_surface(test::make_surface(higher));
  std::vector<TickRecord> trace(10);
  loop.set_trace(trace);
  loop.run_ticks(10, clock);
  EXPECT_NE(shared.current_surface(), before);
  EXPECT_EQ(shared.counters.surfaces_adopted.load(), 1U);
  EXPECT_EQ(shared.collect_retired(), 1U);
  for (const TickRecord& r : trace) {
    EXPECT_GE(r.proxy_m.z, shared.current_surface()->height(r.proxy_m.x, r.proxy_m.y) - 1e-6);
    EXPECT_LE(r.force_n.eigen().norm(), loop.config().proxy.max_force_n + 1e-12);
  }
}

// The parts of a threaded loop on the steady clock: a sinusoid of n² cells, the scripted circle
// (device open), `rate_hz`, no real-time scheduling; the test sets the rest of `cfg`.
struct ThreadedRig {
  ThreadedRig(int n, double rate_hz) : shared(sinusoid_surface(n)), dev(clock, circle_path()) {
    dev.open();
    cfg.rate_hz = rate_hz;
    cfg.realtime = RealtimeMode::kOff;
  }
  SharedState shared;
  SteadyClock clock;
  SimulatedDevice dev;
  ServoConfig cfg;
};

TEST(ServoLoop, ThreadedLoopRunsAndStops) {
  ThreadedRig rig(50, 2000);
  ServoLoop loop(rig.dev, rig.shared, rig.clock, rig.cfg);
  rig.shared.commands.try_push(Command::of(CommandType::kArm));
  const RealtimeReport rep = loop.start();
  EXPECT_FALSE(rep.fifo_granted);
  EXPECT_FALSE(rep.memory_locked);
  EXPECT_TRUE(loop.running());
  EXPECT_THROW(loop.start(), ConfigError);
  wait_until([&] { return rig.shared.counters.ticks.load() >= 300; });
  Snapshot snap;
  EXPECT_TRUE(rig.shared.snapshots.read(snap));
  loop.stop();
  EXPECT_FALSE(loop.running());
  EXPECT_GE(loop.stats().ticks, 300U);
  EXPECT_EQ(loop.stats().lateness.count(), loop.stats().ticks);
  EXPECT_EQ(rig.dev.last_force_n(), Vector3d::Zero());  // stop() leaves zero force
  EXPECT_EQ(loop.period_ns(), 500000);
}

/// Runs a threaded loop at `rate_hz`, publishes a surface (tag 7) just after the second tick,
/// and returns the trace up to at least one tick after the surface was adopted.
std::vector<TickRecord> publish_between_ticks(double rate_hz, double wake_min_period, ServoStats& stats) {
  ThreadedRig rig(50, rate_hz);
  rig.cfg.wake_on_surface_min_period = wake_min_period;
  ServoLoop loop(rig.dev, rig.shared, rig.clock, rig.cfg);
  std::vector<TickRecord> trace(64);
  loop.set_trace(trace);
  loop.start();
  wait_until([&] { return rig.shared.counters.ticks.load() >= 2; });
  rig.shared.publish_surface(sinusoid_surface(50), rig.cfg.workspace, 7);
  wait_until([&] { return rig.shared.counters.surface_tag.load() == 7; });
  // The adopting tick stores the tag before it counts itself, so `ticks` read here may not yet
  // include it: two more counted ticks guarantee the row after the adopting one is in the trace.
  const std::uint64_t adopted_at = rig.shared.counters.ticks.load();
  wait_until([&] { return rig.shared.counters.ticks.load() >= adopted_at + 2; });
  loop.stop();
  stats = loop.stats();
  trace.resize(loop.trace_size());
  return trace;
}

std::size_t first_row_with_tag(const std::vector<TickRecord>& trace, std::uint32_t tag) {
  for (std::size_t k = 0; k < trace.size(); ++k) {
    if (trace[k].surface_tag == tag) return k;
  }
  return trace.size();
}

TEST(ServoLoop, APublishedSurfaceWakesTheLoopButNotSoonerThanTheMinimumGap) {
  // 2 Hz: a period of 500 ms, so that only a scheduling delay of 250 ms could turn the wake tick
  // into a deadline tick.
  ServoStats stats;
  const std::vector<TickRecord> trace = publish_between_ticks(2.0, 0.5, stats);
  const std::size_t a = first_row_with_tag(trace, 7);
  ASSERT_GE(a, 2U);
  ASSERT_LT(a + 1, trace.size());
  // The surface was adopted on a tick run for it, not on a deadline.
  EXPECT_EQ(stats.surface_wake_ticks, 1U);
  EXPECT_EQ(stats.lateness.count() + stats.surface_wake_ticks, stats.ticks);
  // That tick came at least half a period after the one before it (lower bounds the loop
  // guarantees: absolute sleeps never end early), and the next tick a whole period after it.
  EXPECT_GE(trace[a].t_s - trace[a - 1].t_s, 0.25 - 1e-3);
  EXPECT_GE(trace[a + 1].t_s - trace[a].t_s, 0.5 - 1e-3);
}

TEST(ServoLoop, WithTheWakeOffASurfaceIsAdoptedOnADeadline) {
  ServoStats stats;
  const std::vector<TickRecord> trace = publish_between_ticks(4.0, 1.0, stats);
  ASSERT_LT(first_row_with_tag(trace, 7), trace.size());
  EXPECT_EQ(stats.surface_wake_ticks, 0U);
  EXPECT_EQ(stats.lateness.count(), stats.ticks);
}

// Publications far faster than the loop (every 20 ms at 4 Hz): one early tick at most between
// two deadline ticks, so the loop never runs at the publication rate. Lower bounds only: every
// interval is at least the minimum gap, and of two successive intervals one is a whole period.
TEST(ServoLoop, SurfacesPublishedEveryHalfPeriodWakeTheLoopAtMostOnceBetweenDeadlines) {
  SharedState shared(sinusoid_surface(20));
  SteadyClock clock;
  SimulatedDevice dev(clock, circle_path());
  dev.open();
  ServoConfig cfg;
  cfg.rate_hz = 4.0;
  cfg.realtime = RealtimeMode::kOff;
  ServoLoop loop(dev, shared, clock, cfg);
  std::vector<TickRecord> trace(64);
  loop.set_trace(trace);
  loop.start();
  for (int k = 0; k < 120; ++k) {  // 2.4 s
    shared.publish_surface(sinusoid_surface(20), cfg.workspace, static_cast<std::uint64_t>(k + 1));
    shared.collect_retired();
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  loop.stop();
  shared.collect_retired();
  trace.resize(loop.trace_size());
  ASSERT_GE(trace.size(), 6U);
  EXPECT_GE(loop.stats().surface_wake_ticks, 1U) << "the publications did wake the loop";
  EXPECT_LE(loop.stats().surface_wake_ticks, loop.stats().lateness.count() + 1);
  for (std::size_t k = 2; k < trace.size(); ++k) {
    const double a = trace[k - 1].t_s - trace[k - 2].t_s, b = trace[k].t_s - trace[k - 1].t_s;
    EXPECT_GE(b, 0.125 - 1e-3) << "tick " << k;
    EXPECT_GE(std::max(a, b), 0.25 - 1e-3) << "two early ticks in a row at tick " << k;
  }
}

TEST(ServoLoop, TheWakeGapOutsideAQuarterToOnePeriodIsAnError) {
  SharedState shared;
  ManualClock clock;
  SimulatedDevice dev(clock, circle_path());
  for (const double bad : {-0.1, 0.0, 0.2, 1.5, std::numeric_limits<double>::quiet_NaN()}) {
    ServoConfig cfg;
    cfg.wake_on_surface_min_period = bad;
    try {
      ServoLoop loop(dev, shared, clock, cfg);
      ADD_FAILURE() << "accepted wake_on_surface_min_period = " << bad;
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("wake_on_surface_min_period"), std::string::npos) << e.what();
    }
  }
  for (const double good : {0.25, 1.0}) {
    ServoConfig cfg;
    cfg.wake_on_surface_min_period = good;
    EXPECT_NO_THROW(ServoLoop(dev, shared, clock, cfg));
  }
}

// The cache warm-up before each deadline (ServoConfig::warm_up_ns) must not move the tick: the
// thread wakes warm_up_ns early, but the tick (and the device read) waits for the deadline. At
// 4 Hz with a 60 ms warm-up (a quarter period is 62.5 ms), tick k starts no sooner than its
// deadline, (k + 1) periods after the start (a lower bound: absolute sleeps and the spin never
// end early, and a missed deadline only moves the next ones later). A loop that ran the tick
// when the warm-up begins would start every tick 60 ms early.
TEST(ServoLoop, TheWarmUpBeforeADeadlineDoesNotMoveTheTick) {
  ThreadedRig rig(20, 4.0);
  rig.cfg.wake_on_surface_min_period = 1.0;  // deadline ticks only
  rig.cfg.warm_up_ns = 60'000'000;
  ServoLoop loop(rig.dev, rig.shared, rig.clock, rig.cfg);
  std::vector<TickRecord> trace(8);
  loop.set_trace(trace);
  const double t0_s = static_cast<double>(rig.clock.now_ns()) * 1e-9;
  loop.start();
  wait_until([&] { return rig.shared.counters.ticks.load() >= 4; });
  loop.stop();
  trace.resize(loop.trace_size());
  ASSERT_GE(trace.size(), 4U);
  for (std::size_t k = 0; k < trace.size(); ++k) {
    EXPECT_GE(trace[k].t_s - t0_s, 0.25 * static_cast<double>(k + 1) - 1e-4) << "tick " << k << " came before its deadline";
  }
  EXPECT_EQ(loop.stats().lateness.count(), loop.stats().ticks) << "deadline ticks only";
  EXPECT_GE(loop.stats().warm_ups, 1U) << "the warm-up ran";
}

// warm_up() is dry: the ticks of a loop that runs it before every tick equal, bit for bit, those
// of a loop that does not (the same scripted hand on the same surface, ManualClock). It steps the
// proxy on a sinusoid with texture and friction, so a warm-up that wrote its step back (or moved
// the HIP) would change the trace.
TEST(ServoLoop, TheWarmUpChangesNoTick) {
  const auto run = [](bool warm) {
    SharedState shared(sinusoid_surface(50));
    ManualClock clock;
    SimulatedDevice dev(clock, circle_path());
    dev.open();
    ServoLoop loop(dev, shared, clock, ServoConfig{});
    std::vector<TickRecord> trace(3000);
    loop.set_trace(trace);
    EXPECT_TRUE(shared.commands.try_push(Command::of(CommandType::kArm)));
    for (int k = 0; k < 3000; ++k) {
      if (warm) loop.warm_up();
      loop.run_ticks(1, clock);
    }
    EXPECT_EQ(loop.stats().warm_ups, warm ? 3000U : 0U);
    trace.resize(loop.trace_size());
    return trace;
  };
  const std::vector<TickRecord> plain = run(false), warmed = run(true);
  ASSERT_EQ(plain.size(), 3000U);
  ASSERT_EQ(warmed.size(), plain.size());
  std::size_t contact = 0, differ = 0;
  for (std::size_t k = 0; k < plain.size(); ++k) {
    contact += plain[k].in_contact ? 1U : 0U;
    const TickRecord &a = plain[k], &b = warmed[k];  // every field but the measured compute_ns
    const auto same = [](const auto& x, const auto& y) { return std::memcmp(&x, &y, sizeof x) == 0; };
    const bool equal = same(a.t_s, b.t_s) && same(a.hip_m.x, b.hip_m.x) && same(a.hip_m.y, b.hip_m.y) && same(a.hip_m.z, b.hip_m.z) &&
                       same(a.proxy_m.x, b.proxy_m.x) && same(a.proxy_m.y, b.proxy_m.y) && same(a.proxy_m.z, b.proxy_m.z) &&
                       same(a.force_n.x, b.force_n.x) && same(a.force_n.y, b.force_n.y) && same(a.force_n.z, b.force_n.z) &&
                       same(a.mu_d, b.mu_d) && same(a.mu_s, b.mu_s) && same(a.beta_rad, b.beta_rad) && a.iterations == b.iterations &&
                       a.in_contact == b.in_contact && a.sticking == b.sticking && a.device_state == b.device_state &&
                       a.surface_tag == b.surface_tag;
    differ += equal ? 0U : 1U;
  }
  EXPECT_GT(contact, 1000U) << "the proxy was on the surface";
  EXPECT_EQ(differ, 0U);
}

TEST(ServoLoop, AWarmUpOutsideZeroToAQuarterPeriodIsAnError) {
  SharedState shared;
  ManualClock clock;
  SimulatedDevice dev(clock, circle_path());
  for (const auto& [rate_hz, bad] : {std::pair<double, std::int64_t>{1000.0, -1}, {1000.0, 250'001}, {10000.0, 25'001}}) {
    ServoConfig cfg;
    cfg.rate_hz = rate_hz;
    cfg.warm_up_ns = bad;
    try {
      ServoLoop loop(dev, shared, clock, cfg);
      ADD_FAILURE() << "accepted warm_up_ns = " << bad << " at " << rate_hz << " Hz";
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("warm_up_ns"), std::string::npos) << e.what();
    }
  }
  for (const auto& [rate_hz, good] : {std::pair<double, std::int64_t>{1000.0, 0}, {1000.0, 250'000}, {10000.0, 20'000}}) {
    ServoConfig cfg;
    cfg.rate_hz = rate_hz;
    cfg.warm_up_ns = good;
    EXPECT_NO_THROW(ServoLoop(dev, shared, clock, cfg));
  }
}

/// How many of this process's file descriptors point at `path` (/proc/self/fd).
int open_fds_to(const std::string& path) {
  int n = 0;
  for (const auto& e : std::filesystem::directory_iterator("/proc/self/fd")) {
    std::error_code ec;
    if (std::filesystem::read_symlink(e.path(), ec).string() == path) ++n;
  }
  return n;
}

TEST(ServoLoop, EnforcedRealtimeEitherGetsItOrRefusesToStart) {
  SharedState shared(sinusoid_surface(50));
  SteadyClock clock;
  SimulatedDevice dev(clock, circle_path());
  dev.open();
  ServoConfig cfg;
  cfg.realtime = RealtimeMode::kEnforce;
  ServoLoop loop(dev, shared, clock, cfg);
  try {
    const RealtimeReport rep = loop.start();
    EXPECT_TRUE(rep.fifo_granted);
    EXPECT_TRUE(rep.memory_locked);
    EXPECT_EQ(rep.priority, cfg.fifo_priority);
    loop.stop();
  } catch (const ResourceError& e) {
    const std::string what = e.what();
    EXPECT_TRUE(what.find("SCHED_FIFO") != std::string::npos || what.find("mlockall") != std::string::npos) << what;
    EXPECT_FALSE(loop.running());
  }
  // Warn: runs in any case and says what it got.
  ServoConfig warn = cfg;
  warn.realtime = RealtimeMode::kWarn;
  ServoLoop loop2(dev, shared, clock, warn);
  const RealtimeReport rep = loop2.start();
  EXPECT_EQ(rep.detail.empty(), rep.fifo_granted && rep.memory_locked && rep.cpu_latency_pinned);
  // The CPU wake-up latency request is either held (the file open while the loop runs) or its
  // refusal is said.
  EXPECT_TRUE(rep.cpu_latency_pinned || rep.detail.find("/dev/cpu_dma_latency") != std::string::npos) << rep.detail;
  EXPECT_EQ(open_fds_to("/dev/cpu_dma_latency"), rep.cpu_latency_pinned ? 1 : 0);
  loop2.stop();
  EXPECT_EQ(open_fds_to("/dev/cpu_dma_latency"), 0);  // stop() ends the request
}

TEST(LatencyHistogram, PercentilesAndOverflow) {
  LatencyHistogram h;
  EXPECT_EQ(h.percentile_ns(0.5), 0.0);
  for (int k = 1; k <= 1000; ++k) h.add(k);
  EXPECT_EQ(h.count(), 1000U);
  EXPECT_NEAR(h.mean_ns(), 500.5, 1e-9);
  EXPECT_EQ(h.percentile_ns(0.5), 500.0);
  EXPECT_EQ(h.percentile_ns(0.999), 999.0);
  EXPECT_EQ(h.max_ns(), 1000);
  h.add(10000);      // coarse bin
  h.add(5000000);    // overflow bin: its percentile is the exact max
  EXPECT_EQ(h.percentile_ns(1.0), 5000000.0);
  EXPECT_EQ(h.max_ns(), 5000000);
  h.reset();
  EXPECT_EQ(h.count(), 0U);
}

}  // namespace
}  // namespace hc::haptics
