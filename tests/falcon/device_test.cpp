#include "hc/falcon/falcon_device.hpp"

#include "falcon_test_support.hpp"
#include "hc/common/error.hpp"

#include <gtest/gtest.h>

#include <csignal>
#include <cstdlib>

namespace hc::falcon {
namespace {

using Eigen::Vector3d;
using haptics::DeviceReading;
using haptics::DeviceState;
using haptics::DeviceStatus;
using haptics::ManualClock;

DeviceStatus tick(FalconDevice& dev, ManualClock& clock, const Vector3d& force = Vector3d::Zero(),
                  DeviceReading* out = nullptr) {
  DeviceReading r;
  const DeviceStatus s = dev.read(r);
  (void)dev.write(force);
  clock.advance_ns(1000000);
  if (out != nullptr) *out = r;
  return s;
}

/// Plays the homing gesture until the device reports all arms homed (or 2 s pass).
bool home(test::EmulatedFalcon& f, ManualClock& clock) {
  const double t0 = f.emu->time_s();
  f.emu->set_hand(EmulatedHand{[t0](double t) { return test::homing_gesture(t, t0); }, 300.0, 8.0});
  for (int k = 0; k < 2000 && !f.dev->homed(); ++k) tick(*f.dev, clock);
  for (int k = 0; k < 400; ++k) tick(*f.dev, clock);  // back at the centre, settled
  return f.dev->homed();
}

TEST(FalconDevice, OpensLoadsFirmwareAndHomesWithGuidance) {
  ManualClock clock;
  auto f = test::make_emulated(clock, "falcon_dev_open");
  f.dev->open();
  EXPECT_EQ(f.dev->state(), DeviceState::kOpen);
  EXPECT_TRUE(f.dev->firmware_report().loaded);
  EXPECT_TRUE(f.emu->firmware_running());
  EXPECT_FALSE(f.dev->homed());
  EXPECT_NE(f.dev->homing_message().find("pull the grip all the way out"), std::string::npos);
  ASSERT_TRUE(f.dev->arm());
  // Not homed: the homing bit and the red LED go out, and no force whatever is asked.
  for (int k = 0; k < 20; ++k) EXPECT_EQ(tick(*f.dev, clock, Vector3d(0, 0, 3.0)), DeviceStatus::kOk);
  EXPECT_TRUE(f.emu->homing_requested());
  EXPECT_EQ(f.emu->leds(), kLedRed);
  EXPECT_EQ(f.emu->last_motor(), (std::array<std::int16_t, 3>{0, 0, 0}));

  ASSERT_TRUE(home(f, clock));
  EXPECT_FALSE(f.emu->homing_requested());
  EXPECT_EQ(f.emu->leds(), kLedGreen);
  EXPECT_NE(f.dev->homing_message().find("homed (LED green)"), std::string::npos);
  // Homed: the reported position is the emulator's true one (to encoder resolution).
  DeviceReading r;
  tick(*f.dev, clock, Vector3d::Zero(), &r);
  EXPECT_LT((r.position_m - f.dev->config().frame.to_device(f.emu->position_m())).norm(), 2e-4);
  EXPECT_LE(f.dev->last_fk_iterations(), 3);
  // A force in device axes arrives as that force in Falcon axes.
  f.emu->clear_hand();
  const Vector3d want(1.0, -2.0, 2.5);
  tick(*f.dev, clock, want);
  const Vector3d got = f.dev->config().frame.rotation * f.emu->motor_force_n();
  EXPECT_LT((got - want).norm(), 0.05) << got.transpose();
}

TEST(FalconDevice, ForceIsCappedKeepingItsDirection) {
  ManualClock clock;
  auto f = test::make_emulated(clock, "falcon_dev_cap");
  f.dev->open();
  ASSERT_TRUE(home(f, clock));
  ASSERT_TRUE(f.dev->arm());
  EXPECT_DOUBLE_EQ(f.dev->info().max_force_n, 8.0);
  const Vector3d dir = Vector3d(1, 2, -2).normalized();
  tick(*f.dev, clock, dir * 100.0);
  const Vector3d got = f.dev->config().frame.rotation * f.emu->motor_force_n();
  EXPECT_NEAR(got.norm(), 8.0, 0.05);
  EXPECT_GT(got.normalized().dot(dir), 0.9999);
}

TEST(FalconDevice, SurvivesGarbageAndShortFrames) {
  ManualClock clock;
  auto f = test::make_emulated(clock, "falcon_dev_garbage");
  f.dev->open();
  ASSERT_TRUE(home(f, clock));
  ASSERT_TRUE(f.dev->arm());
  f.emu->faults().garbage_every = 3;
  f.emu->faults().short_every = 7;
  int errors = 0;
  for (int k = 0; k < 1000; ++k) errors += tick(*f.dev, clock, Vector3d(0, 0, 1.0)) != DeviceStatus::kOk ? 1 : 0;
  const FalconStatus s = f.dev->status();
  EXPECT_EQ(errors, 0);
  EXPECT_GT(s.bad_frames, 50U);
  EXPECT_GT(s.skipped_bytes, 300U);
  EXPECT_GT(s.stale_reads, 50U);  // the ticks whose frame was cut
  EXPECT_EQ(f.dev->state(), DeviceState::kArmed);
  DeviceReading r;
  tick(*f.dev, clock, Vector3d::Zero(), &r);
  EXPECT_LT((r.position_m - f.dev->config().frame.to_device(f.emu->position_m())).norm(), 1e-3);
}

TEST(FalconDevice, SilentDeviceGetsZeroForceThenFaults) {
  ManualClock clock;
  FalconConfig cfg;
  cfg.max_missed_ticks = 5;
  auto f = test::make_emulated(clock, "falcon_dev_silent", cfg);
  f.dev->open();
  ASSERT_TRUE(home(f, clock));
  ASSERT_TRUE(f.dev->arm());
  f.emu->clear_hand();
  tick(*f.dev, clock, Vector3d(0, 0, 2.0));
  tick(*f.dev, clock, Vector3d(0, 0, 2.0));
  EXPECT_GT(f.emu->motor_force_n().norm(), 1.0);
  f.emu->faults().silent_every = 1;  // no more answers
  tick(*f.dev, clock, Vector3d(0, 0, 2.0));  // the last answer still arrives
  EXPECT_EQ(tick(*f.dev, clock, Vector3d(0, 0, 2.0)), DeviceStatus::kOk);  // stale read ...
  EXPECT_EQ(f.emu->motor_force_n().norm(), 0.0);                          // ... zero force
  DeviceStatus s = DeviceStatus::kOk;
  int k = 0;
  for (; k < 20 && s == DeviceStatus::kOk; ++k) s = tick(*f.dev, clock, Vector3d(0, 0, 2.0));
  EXPECT_EQ(s, DeviceStatus::kIoError);
  EXPECT_EQ(k, 5);
  EXPECT_EQ(f.emu->motor_force_n().norm(), 0.0);
}

TEST(FalconDevice, WatchdogZeroesForceWhenTicksAreMissed) {
  ManualClock clock;
  FalconConfig cfg;
  cfg.max_missed_ticks = 10;
  auto f = test::make_emulated(clock, "falcon_dev_watchdog", cfg);
  f.dev->open();
  ASSERT_TRUE(home(f, clock));
  ASSERT_TRUE(f.dev->arm());
  f.emu->clear_hand();
  tick(*f.dev, clock, Vector3d(0, 0, 2.0));
  tick(*f.dev, clock, Vector3d(0, 0, 2.0));
  EXPECT_GT(f.emu->motor_force_n().norm(), 1.0);
  clock.advance_ns(5000000);  // 5 missed ticks: tolerated
  f.dev->supervise();
  EXPECT_GT(f.emu->motor_force_n().norm(), 1.0);
  clock.advance_ns(20000000);  // the servo loop stalls for 20 more ticks
  f.dev->supervise();
  EXPECT_EQ(f.emu->motor_force_n().norm(), 0.0);
  EXPECT_EQ(f.dev->status().watchdog_trips, 1U);
  DeviceReading r;
  EXPECT_EQ(f.dev->read(r), DeviceStatus::kIoError);  // the servo loop learns of it and faults
}

TEST(FalconDevice, MissedTicksAreCaughtWithoutTheSupervisorToo) {
  ManualClock clock;
  auto f = test::make_emulated(clock, "falcon_dev_gap");
  f.dev->open();
  ASSERT_TRUE(home(f, clock));
  ASSERT_TRUE(f.dev->arm());
  tick(*f.dev, clock);
  clock.advance_ns(50000000);
  EXPECT_EQ(tick(*f.dev, clock), DeviceStatus::kIoError);
  EXPECT_EQ(tick(*f.dev, clock), DeviceStatus::kOk);  // reported once
}

TEST(FalconDevice, StopSignalZeroesForce) {
  ManualClock clock;
  auto f = test::make_emulated(clock, "falcon_dev_signal");
  f.dev->open();
  ASSERT_TRUE(home(f, clock));
  ASSERT_TRUE(f.dev->arm());
  f.emu->clear_hand();
  tick(*f.dev, clock, Vector3d(0, 0, 2.0));
  tick(*f.dev, clock, Vector3d(0, 0, 2.0));
  EXPECT_GT(f.emu->motor_force_n().norm(), 1.0);
  install_stop_signal_handlers();
  clear_stop_request();
  std::raise(SIGINT);  // handled: the process goes on
  EXPECT_TRUE(stop_requested());
  tick(*f.dev, clock, Vector3d(0, 0, 2.0));
  EXPECT_EQ(f.emu->motor_force_n().norm(), 0.0);
  EXPECT_EQ(f.emu->leds(), kLedBlue);
  clear_stop_request();
  std::signal(SIGINT, SIG_DFL);
  std::signal(SIGTERM, SIG_DFL);
}

TEST(FalconDevice, CloseSendsZeroForce) {
  ManualClock clock;
  auto f = test::make_emulated(clock, "falcon_dev_close");
  f.dev->open();
  ASSERT_TRUE(home(f, clock));
  ASSERT_TRUE(f.dev->arm());
  f.emu->clear_hand();
  tick(*f.dev, clock, Vector3d(0, 0, 2.0));
  tick(*f.dev, clock, Vector3d(0, 0, 2.0));
  EXPECT_GT(f.emu->motor_force_n().norm(), 1.0);
  f.dev->close();
  EXPECT_EQ(f.emu->motor_force_n().norm(), 0.0);
  EXPECT_EQ(f.dev->state(), DeviceState::kClosed);
}

TEST(FalconDevice, OpenWithoutFirmwareSaysWhatToSet) {
  ManualClock clock;
  ::unsetenv(kFirmwareEnvVar);
  auto emu = std::make_shared<FalconEmulator>();
  FalconConfig cfg;
  cfg.supervisor_thread = false;
  FalconDevice dev(clock, std::make_unique<EmulatorProvider>(emu), cfg);
  try {
    dev.open();
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find(kFirmwareEnvVar), std::string::npos);
  }
  EXPECT_EQ(dev.state(), DeviceState::kClosed);
}

TEST(FalconDevice, InvalidConfigIsRefused) {
  ManualClock clock;
  FalconConfig cfg;
  cfg.max_missed_ticks = 0;
  EXPECT_THROW(FalconDevice(clock, std::make_unique<EmulatorProvider>(std::make_shared<FalconEmulator>()), cfg),
               ConfigError);
  cfg = FalconConfig{};
  cfg.max_force_n = -1;
  EXPECT_THROW(FalconDevice(clock, std::make_unique<EmulatorProvider>(std::make_shared<FalconEmulator>()), cfg),
               ConfigError);
}

}  // namespace
}  // namespace hc::falcon
