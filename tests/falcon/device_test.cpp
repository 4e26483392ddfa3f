#include "hc/falcon/falcon_device.hpp"

#include "falcon_test_support.hpp"
#include "hc/common/error.hpp"

#include <gtest/gtest.h>

#include <csignal>
#include <cstdlib>
#include <functional>
#include <vector>

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

/// Opens, homes and arms the emulated device. @return false if homing or arming failed.
bool open_home_arm(test::EmulatedFalcon& f, ManualClock& clock) {
  f.dev->open();
  return home(f, clock) && f.dev->arm();
}

/// Lets go of the grip and asks for 2 N up for two ticks. @return the force the motors give [N].
double push_up(test::EmulatedFalcon& f, ManualClock& clock) {
  f.emu->clear_hand();
  tick(*f.dev, clock, Vector3d(0, 0, 2.0));
  tick(*f.dev, clock, Vector3d(0, 0, 2.0));
  return f.emu->motor_force_n().norm();
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
  ASSERT_TRUE(open_home_arm(f, clock));
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
  ASSERT_TRUE(open_home_arm(f, clock));
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
  ASSERT_TRUE(open_home_arm(f, clock));
  EXPECT_GT(push_up(f, clock), 1.0);
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
  ASSERT_TRUE(open_home_arm(f, clock));
  EXPECT_GT(push_up(f, clock), 1.0);
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
  ASSERT_TRUE(open_home_arm(f, clock));
  tick(*f.dev, clock);
  clock.advance_ns(50000000);
  EXPECT_EQ(tick(*f.dev, clock), DeviceStatus::kIoError);
  EXPECT_EQ(tick(*f.dev, clock), DeviceStatus::kOk);  // reported once
}

TEST(FalconDevice, StopSignalZeroesForce) {
  ManualClock clock;
  auto f = test::make_emulated(clock, "falcon_dev_signal");
  ASSERT_TRUE(open_home_arm(f, clock));
  EXPECT_GT(push_up(f, clock), 1.0);
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
  ASSERT_TRUE(open_home_arm(f, clock));
  EXPECT_GT(push_up(f, clock), 1.0);
  f.dev->close();
  EXPECT_EQ(f.emu->motor_force_n().norm(), 0.0);
  EXPECT_EQ(f.dev->state(), DeviceState::kClosed);
}

TEST(FalconDevice, NoForceOnATickWhoseKinematicsDidNotConverge) {
  // One Newton step per tick: while the grip moves, a single warm step is not below the
  // tolerance, and those ticks must send zero force whatever is asked.
  ManualClock clock;
  FalconConfig cfg;
  cfg.fk_iterations = 1;
  auto f = test::make_emulated(clock, "falcon_dev_fk", cfg);
  f.dev->open();
  ASSERT_TRUE(home(f, clock));
  // Hold the grip still until the one-step solves converge (the homing gesture leaves it moving).
  const Vector3d hold = f.emu->position_m();
  f.emu->set_hand(EmulatedHand{[hold](double) { return hold; }, 300.0, 8.0});
  int still = 0;
  for (int k = 0; k < 3000 && still < 20; ++k) {
    tick(*f.dev, clock);
    still = f.dev->last_fk_converged() ? still + 1 : 0;
  }
  ASSERT_EQ(still, 20);
  ASSERT_TRUE(f.dev->arm());
  f.emu->clear_hand();
  int unconverged = 0, converged = 0;
  for (int k = 0; k < 60; ++k) {
    DeviceReading r;
    ASSERT_EQ(f.dev->read(r), DeviceStatus::kOk);
    const bool conv = f.dev->last_fk_converged();
    EXPECT_LE(f.dev->last_fk_iterations(), 1);
    (void)f.dev->write(Vector3d(0, 0, 2.0));
    clock.advance_ns(1000000);
    const double fn = f.emu->motor_force_n().norm();
    if (conv) {
      ++converged;
      EXPECT_GT(fn, 1.0) << "tick " << k;
    } else {
      ++unconverged;
      EXPECT_EQ(fn, 0.0) << "tick " << k;
    }
  }
  EXPECT_GT(unconverged, 0);
  EXPECT_GT(converged, 0);
}

TEST(FalconDevice, RepeatedTransportErrorsTakeTheLinkDownAndItReconnects) {
  ManualClock clock;
  FalconConfig cfg;
  cfg.max_consecutive_io_errors = 5;
  auto f = test::make_emulated(clock, "falcon_dev_ioerr", cfg);
  f.dev->open();
  ASSERT_TRUE(home(f, clock));
  f.emu->faults().io_errors = true;
  // Each tick is one failed read and one failed write: below the limit the link stays up ...
  EXPECT_EQ(tick(*f.dev, clock), DeviceStatus::kIoError);
  EXPECT_EQ(tick(*f.dev, clock), DeviceStatus::kIoError);
  EXPECT_EQ(f.dev->status().link, LinkState::kUp);
  EXPECT_EQ(f.dev->status().io_errors, 4U);
  // ... the fifth error in a row takes it down, like an unplug.
  EXPECT_EQ(tick(*f.dev, clock), DeviceStatus::kIoError);
  EXPECT_EQ(f.dev->status().link, LinkState::kDown);
  EXPECT_EQ(f.dev->status().io_errors, 5U);
  EXPECT_FALSE(f.dev->homed());
  f.emu->faults().io_errors = false;
  f.dev->supervise();
  EXPECT_EQ(f.dev->status().reconnections, 1U);
  EXPECT_EQ(f.dev->status().link, LinkState::kUp);
  EXPECT_EQ(tick(*f.dev, clock), DeviceStatus::kOk);
  EXPECT_TRUE(f.dev->homed());  // the emulated Falcon kept its homing
}

TEST(FalconDevice, ErrorsThatAreNotInARowKeepTheLinkUp) {
  ManualClock clock;
  FalconConfig cfg;
  cfg.max_consecutive_io_errors = 3;
  auto f = test::make_emulated(clock, "falcon_dev_ioerr_sparse", cfg);
  f.dev->open();
  for (int k = 0; k < 10; ++k) {
    f.emu->faults().io_errors = true;
    DeviceReading r;
    EXPECT_EQ(f.dev->read(r), DeviceStatus::kIoError);  // one error ...
    f.emu->faults().io_errors = false;
    EXPECT_EQ(f.dev->write(Vector3d::Zero()), DeviceStatus::kOk);  // ... then a success
    clock.advance_ns(1000000);
  }
  EXPECT_EQ(f.dev->status().link, LinkState::kUp);
  EXPECT_EQ(f.dev->status().io_errors, 10U);
}

/// Opens emulated transports and runs a hook first (a servo tick arriving mid-reconnection).
class HookedProvider final : public TransportProvider {
 public:
  explicit HookedProvider(std::shared_ptr<FalconEmulator> emu) : inner_(std::move(emu)) {}
  std::unique_ptr<Transport> open() override {
    if (hook) hook();
    return inner_.open();
  }
  std::string describe() const override { return "hooked emulated Falcon"; }
  std::function<void()> hook;

 private:
  EmulatorProvider inner_;
};

TEST(FalconDevice, ServoTicksDuringAReconnectionGetIoErrorsAndNoTransport) {
  ManualClock clock;
  EmulatorOptions eo;
  eo.expected_image_size = 1000;
  auto emu = std::make_shared<FalconEmulator>(eo);
  auto provider = std::make_unique<HookedProvider>(emu);
  HookedProvider* hooked = provider.get();
  FalconConfig cfg;
  cfg.firmware_path = test::write_fake_image("falcon_dev_hook").string();
  cfg.supervisor_thread = false;
  cfg.reconnect_interval_ms = 0;
  FalconDevice dev(clock, std::move(provider), cfg);
  dev.open();
  emu->unplug();
  DeviceReading r;
  EXPECT_EQ(dev.read(r), DeviceStatus::kIoError);
  EXPECT_EQ(dev.status().link, LinkState::kDown);
  emu->plug();
  std::vector<DeviceStatus> seen;
  hooked->hook = [&] {
    DeviceReading rr;
    seen.push_back(dev.read(rr));
    seen.push_back(dev.write(Vector3d(0, 0, 2.0)));
  };
  dev.supervise();
  hooked->hook = nullptr;
  ASSERT_EQ(seen.size(), 2U);
  EXPECT_EQ(seen[0], DeviceStatus::kIoError);
  EXPECT_EQ(seen[1], DeviceStatus::kIoError);
  EXPECT_EQ(dev.status().reconnections, 1U);
  EXPECT_EQ(dev.status().link, LinkState::kUp);
  EXPECT_EQ(dev.read(r), DeviceStatus::kOk);
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
