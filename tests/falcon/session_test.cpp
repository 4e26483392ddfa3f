// Whole-driver sessions through the emulator: the servo loop renders a small synthetic surface on
// an emulated Falcon (homing, touching, buttons, unplug and reconnection) without hardware.
#include "falcon_test_support.hpp"
#include "hc/haptics/haptic_surface.hpp"
#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/shared_state.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <numbers>
#include <thread>

namespace hc::falcon {
namespace {

using Eigen::Vector3d;
using haptics::Command;
using haptics::CommandType;
using haptics::DeviceState;
using haptics::ManualClock;
using haptics::ServoConfig;
using haptics::ServoLoop;
using haptics::SharedState;

haptics::Snapshot latest(SharedState& shared) {
  haptics::Snapshot s;
  shared.snapshots.read(s);
  return s;
}

/// A gentle wave, 2 mm high, over a 100 mm square centred on the origin (grid = device frame).
std::unique_ptr<const haptics::HapticSurface> wave_surface() {
  const int n = 101;
  const double side = 0.1, cell = side / (n - 1);
  HeightField f(GridGeometry{n, n, -side / 2, -side / 2, cell});
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n; ++c) {
      const double x = -side / 2 + c * cell, y = -side / 2 + r * cell;
      f.at(r, c) = static_cast<float>(0.002 * std::sin(2 * std::numbers::pi * x / 0.04) * std::cos(2 * std::numbers::pi * y / 0.04));
    }
  haptics::SurfaceLayers layers;
  layers.depth = &f;
  return std::make_unique<haptics::HapticSurface>(layers, haptics::SurfaceOptions{});
}

/// Hand in device coordinates: from 10 mm above the centre, press 8 mm below mid height and
/// circle (radius 15 mm, one turn per 2 s).
EmulatedHand touching_hand(const DeviceFrame& frame, double t0) {
  return EmulatedHand{[frame, t0](double t_s) {
                        const double t = t_s - t0;
                        const double press = std::min(1.0, std::max(0.0, t / 0.5));
                        const double a = std::numbers::pi * std::max(0.0, t - 0.5);
                        const Vector3d dev(0.015 * std::cos(a) * press, 0.015 * std::sin(a) * press, 0.01 - 0.018 * press);
                        return frame.to_falcon(dev);
                      },
                      300.0, 8.0};
}

struct Session {
  ManualClock clock;
  test::EmulatedFalcon f;
  SharedState shared{wave_surface()};
  std::unique_ptr<ServoLoop> loop;
  explicit Session(const std::string& name) {
    f = test::make_emulated(clock, name);
    f.dev->open();
    loop = std::make_unique<ServoLoop>(*f.dev, shared, clock, ServoConfig{});
  }
  void home() {
    const double t0 = f.emu->time_s();
    f.emu->set_hand(EmulatedHand{[t0](double t) { return test::homing_gesture(t, t0); }, 300.0, 8.0});
    for (int k = 0; k < 20 && !f.dev->homed(); ++k) loop->run_ticks(100, clock);
    loop->run_ticks(300, clock);
  }
  /// Runs n ticks; returns ticks in contact and the largest upward motor force [N] felt.
  std::pair<int, double> touch(int n) {
    int contact = 0;
    double up = 0.0;
    for (int k = 0; k < n; ++k) {
      loop->run_ticks(1, clock);
      const haptics::Snapshot s = latest(shared);
      contact += s.in_contact ? 1 : 0;
      up = std::max(up, (f.dev->config().frame.rotation * f.emu->motor_force_n()).z());
    }
    return {contact, up};
  }
};

TEST(FalconSession, ServoLoopRendersASurfaceThroughTheEmulator) {
  Session s("falcon_session_surface");
  ASSERT_TRUE(s.shared.commands.try_push(Command::of(CommandType::kArm)));
  s.home();
  ASSERT_TRUE(s.f.dev->homed());
  EXPECT_EQ(s.f.dev->state(), DeviceState::kArmed);
  s.f.emu->set_hand(touching_hand(s.f.dev->config().frame, s.f.emu->time_s()));
  const auto [contact, up] = s.touch(3000);
  EXPECT_GT(contact, 2000);
  EXPECT_GT(up, 1.0);  // the surface pushes the hand back up
  // The HIP the loop saw is where the emulated grip really is, and the hand was held above the
  // surface by the rendered force (not sunk to its 8 mm target).
  const haptics::Snapshot snap = latest(s.shared);
  const Vector3d truth = s.f.dev->config().frame.to_device(s.f.emu->position_m());
  EXPECT_LT((snap.hip_m.eigen() - truth).norm(), 1.5e-3);
  EXPECT_GT(truth.z(), -0.006);
  EXPECT_EQ(s.shared.counters.device_errors.load(), 0U);
  EXPECT_GE(snap.proxy_m.z, s.shared.current_surface()->height(snap.proxy_m.x, snap.proxy_m.y) - 1e-6);
  EXPECT_LE(s.f.dev->last_fk_iterations(), 3);
}

TEST(FalconSession, ButtonPressesBecomeEvents) {
  Session s("falcon_session_buttons");
  s.loop->run_ticks(10, s.clock);
  s.f.emu->set_buttons(0x4);
  s.loop->run_ticks(5, s.clock);
  EXPECT_EQ(latest(s.shared).buttons, 0x4U);
  s.f.emu->set_buttons(0x6);
  s.loop->run_ticks(5, s.clock);
  s.f.emu->set_buttons(0x0);
  s.loop->run_ticks(5, s.clock);
  haptics::ButtonEvent e;
  ASSERT_TRUE(s.shared.button_events.try_pop(e));
  EXPECT_EQ(e.pressed, 0x4U);
  EXPECT_EQ(e.released, 0U);
  ASSERT_TRUE(s.shared.button_events.try_pop(e));
  EXPECT_EQ(e.pressed, 0x2U);
  EXPECT_EQ(e.buttons, 0x6U);
  ASSERT_TRUE(s.shared.button_events.try_pop(e));
  EXPECT_EQ(e.released, 0x6U);
  EXPECT_EQ(e.buttons, 0U);
  EXPECT_FALSE(s.shared.button_events.try_pop(e));
}

TEST(FalconSession, UnplugMidSessionThenReconnect) {
  Session s("falcon_session_unplug");
  ASSERT_TRUE(s.shared.commands.try_push(Command::of(CommandType::kArm)));
  s.home();
  s.f.emu->set_hand(touching_hand(s.f.dev->config().frame, s.f.emu->time_s()));
  auto [contact, up] = s.touch(1500);
  ASSERT_GT(contact, 500);
  ASSERT_GT(up, 1.0);

  // Pull the cable while pressing on the surface.
  s.f.emu->unplug();
  const std::uint64_t ticks_before = s.shared.counters.ticks.load();
  s.loop->run_ticks(200, s.clock);
  EXPECT_EQ(s.shared.counters.ticks.load(), ticks_before + 200);  // the loop survives
  EXPECT_EQ(s.f.dev->state(), DeviceState::kFault);
  EXPECT_EQ(s.f.dev->status().link, LinkState::kDown);
  EXPECT_GT(s.shared.counters.device_errors.load(), 0U);
  const haptics::Snapshot down = latest(s.shared);
  EXPECT_EQ(down.device_force_n.eigen().norm(), 0.0);
  EXPECT_NE(s.f.dev->homing_message().find("unplugged"), std::string::npos);
  s.f.dev->supervise();  // still unplugged: the attempt fails and is kept
  EXPECT_NE(s.f.dev->last_reconnect_error().find("unplugged"), std::string::npos);

  // Plug it back: the supervisor reloads the firmware and the link comes back, homing again.
  s.f.emu->plug();
  s.f.dev->supervise();
  EXPECT_EQ(s.f.dev->status().link, LinkState::kUp);
  EXPECT_EQ(s.f.dev->status().reconnections, 1U);
  EXPECT_TRUE(s.f.emu->firmware_running());
  EXPECT_EQ(s.f.emu->upload_attempts(), 2);
  EXPECT_FALSE(s.f.dev->homed());
  const std::uint64_t errors = s.shared.counters.device_errors.load();
  s.loop->run_ticks(50, s.clock);
  EXPECT_EQ(s.shared.counters.device_errors.load(), errors);  // reads work again
  EXPECT_EQ(s.f.dev->state(), DeviceState::kFault);           // until the user resets
  ASSERT_TRUE(s.shared.commands.try_push(Command::of(CommandType::kResetFault)));
  ASSERT_TRUE(s.shared.commands.try_push(Command::of(CommandType::kArm)));
  s.home();
  ASSERT_TRUE(s.f.dev->homed());
  EXPECT_EQ(s.f.dev->state(), DeviceState::kArmed);
  s.f.emu->set_hand(touching_hand(s.f.dev->config().frame, s.f.emu->time_s()));
  std::tie(contact, up) = s.touch(1500);
  EXPECT_GT(contact, 500);
  EXPECT_GT(up, 1.0);  // forces are back
}

}  // namespace
}  // namespace hc::falcon

namespace hc::falcon {
namespace {

/// Waits (bounded) until pred() holds; returns whether it did. Not a speed requirement: the bound
/// only keeps a broken build from hanging.
template <class Pred>
bool wait_for(Pred pred) {
  for (int k = 0; k < 1000 && !pred(); ++k) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  return pred();
}

TEST(FalconSession, ThreadedLoopAndSupervisorSurviveAnUnplug) {
  haptics::SteadyClock clock;
  FalconConfig cfg;
  cfg.max_missed_ticks = 1000;  // a shared 2-core machine may stall the threads; not under test here
  EmulatorOptions eo;
  eo.firmware_preloaded = true;
  auto emu = std::make_shared<FalconEmulator>(eo);
  cfg.supervisor_thread = true;
  cfg.reconnect_interval_ms = 0;
  FalconDevice dev(clock, std::make_unique<EmulatorProvider>(emu), cfg);
  dev.open();
  haptics::SharedState shared(wave_surface());
  haptics::ServoConfig scfg;
  scfg.realtime = haptics::RealtimeMode::kOff;
  haptics::ServoLoop loop(dev, shared, clock, scfg);
  loop.start();
  ASSERT_TRUE(wait_for([&] { return shared.counters.ticks.load() > 50; }));
  emu->unplug();
  EXPECT_TRUE(wait_for([&] { return dev.state() == DeviceState::kFault; }));
  EXPECT_TRUE(wait_for([&] { return !dev.last_reconnect_error().empty(); }));
  emu->plug();
  EXPECT_TRUE(wait_for([&] { return dev.status().reconnections == 1 && dev.status().link == LinkState::kUp; }));
  const std::uint64_t frames = dev.status().frames;
  EXPECT_TRUE(wait_for([&] { return dev.status().frames > frames + 20; }));  // frames flow again
  EXPECT_TRUE(loop.running());
  loop.stop();
  dev.close();
  EXPECT_EQ(emu->motor_force_n().norm(), 0.0);
}

}  // namespace
}  // namespace hc::falcon
