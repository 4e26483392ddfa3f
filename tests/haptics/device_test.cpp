#include "hc/haptics/device.hpp"
#include "hc/haptics/simulated_device.hpp"

#include "hc/common/error.hpp"
#include "test_paths.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <limits>
#include <numbers>

namespace hc::haptics {
namespace {

using Eigen::Vector3d;

ScriptedPath hold_path() {
  ScriptedPath p;
  p.kind = PathKind::kHold;
  return p;
}

TEST(HapticDevice, LifecycleClosedOpenArmedFault) {
  ManualClock clock;
  VirtualHand no_hand;
  no_hand.enabled = false;
  SimulatedDevice dev(clock, hold_path(), no_hand);
  DeviceReading r;
  EXPECT_EQ(dev.state(), DeviceState::kClosed);
  EXPECT_EQ(dev.read(r), DeviceStatus::kNotOpen);
  EXPECT_EQ(dev.write(Vector3d(1, 0, 0)), DeviceStatus::kNotOpen);
  EXPECT_FALSE(dev.arm());  // cannot arm a closed device
  dev.open();
  EXPECT_EQ(dev.state(), DeviceState::kOpen);
  EXPECT_EQ(dev.read(r), DeviceStatus::kOk);
  // Open: reads only; a force request sends zero.
  EXPECT_EQ(dev.write(Vector3d(1, 0, 0)), DeviceStatus::kOk);
  EXPECT_EQ(dev.last_force_n(), Vector3d::Zero());
  ASSERT_TRUE(dev.arm());
  EXPECT_EQ(dev.state(), DeviceState::kArmed);
  EXPECT_EQ(dev.write(Vector3d(1, 2, 0)), DeviceStatus::kOk);
  EXPECT_EQ(dev.last_force_n(), Vector3d(1, 2, 0));
  // Saturation keeps the direction.
  EXPECT_EQ(dev.write(Vector3d(0, 30, 40)), DeviceStatus::kOk);
  EXPECT_NEAR(dev.last_force_n().norm(), dev.info().max_force_n, 1e-12);
  EXPECT_NEAR(dev.last_force_n().normalized().dot(Vector3d(0, 0.6, 0.8)), 1.0, 1e-12);
  // A non-finite force faults the device and sends zero.
  EXPECT_EQ(dev.write(Vector3d(std::numeric_limits<double>::quiet_NaN(), 0, 0)), DeviceStatus::kFault);
  EXPECT_EQ(dev.state(), DeviceState::kFault);
  EXPECT_EQ(dev.last_force_n(), Vector3d::Zero());
  EXPECT_FALSE(dev.arm());                                      // Fault needs a reset
  EXPECT_EQ(dev.write(Vector3d(1, 0, 0)), DeviceStatus::kFault);  // zero until reset
  EXPECT_EQ(dev.last_force_n(), Vector3d::Zero());
  EXPECT_EQ(dev.read(r), DeviceStatus::kOk);                    // still reads
  EXPECT_TRUE(dev.reset_fault());
  EXPECT_EQ(dev.state(), DeviceState::kOpen);
  EXPECT_TRUE(dev.arm());
  dev.disarm();
  EXPECT_EQ(dev.state(), DeviceState::kOpen);
  dev.close();
  EXPECT_EQ(dev.state(), DeviceState::kClosed);
}

TEST(HapticDevice, InvalidCapabilitiesAreRejected) {
  ManualClock clock;
  DeviceInfo info = SimulatedDevice::default_info();
  info.max_force_n = -1;
  EXPECT_THROW(SimulatedDevice(clock, hold_path(), VirtualHand{}, info), ConfigError);
  info = SimulatedDevice::default_info();
  info.nominal_rate_hz = std::numeric_limits<double>::infinity();
  EXPECT_THROW(SimulatedDevice(clock, hold_path(), VirtualHand{}, info), ConfigError);
}

TEST(ScriptedPath, ShapesAndSpeed) {
  ScriptedPath p;
  p.centre_m = Vector3d(0.01, -0.02, 0.0);
  p.half_x_m = 0.02;
  p.half_y_m = 0.01;
  p.speed_m_per_s = 0.1;
  p.approach_s = 0.2;
  p.z_above_m = 0.01;
  p.z_contact_m = -0.003;
  p.raster_spacing_m = 0.005;
  for (PathKind kind : {PathKind::kLine, PathKind::kCircle, PathKind::kRaster}) {
    p.kind = kind;
    EXPECT_NO_THROW(p.validate());
    EXPECT_NEAR(p.position_at(0.0).z(), 0.01, 1e-12) << to_string(kind);
    EXPECT_NEAR(p.position_at(0.2).z(), -0.003, 1e-12) << to_string(kind);
    // Speed in the plane after the approach: the path length per unit time.
    double length = 0.0;
    Vector3d prev = p.position_at(0.3);
    for (int k = 1; k <= 10000; ++k) {
      const Vector3d q = p.position_at(0.3 + k * 1e-4);
      length += (q - prev).norm();
      prev = q;
      EXPECT_LE(std::fabs(q.x() - p.centre_m.x()), p.half_x_m + 1e-12) << to_string(kind);
      EXPECT_LE(std::fabs(q.y() - p.centre_m.y()), (kind == PathKind::kLine ? 0.0 : kind == PathKind::kCircle ? p.half_x_m : p.half_y_m) + 1e-12);
    }
    EXPECT_NEAR(length / 1.0, 0.1, 1e-3) << to_string(kind);
  }
  p.kind = PathKind::kCircle;
  EXPECT_NEAR((p.position_at(1.0) - Vector3d(0.01, -0.02, -0.003)).norm(), 0.02, 1e-12);
  // Raster visits every line: y takes the values −10, −5, 0, 5, 10 mm around the centre.
  p.kind = PathKind::kRaster;
  int seen[5] = {0, 0, 0, 0, 0};
  for (int k = 0; k < 20000; ++k) {
    const Vector3d q = p.position_at(0.2 + k * 1e-4);
    const double line = (q.y() - p.centre_m.y() + 0.01) / 0.005;
    if (std::fabs(line - std::round(line)) < 1e-9) ++seen[static_cast<int>(std::round(line))];
  }
  for (int s : seen) EXPECT_GT(s, 0);
  // Press-slide: down at the left, slide right at contact height, lift, fly back above.
  p.kind = PathKind::kPressSlide;
  EXPECT_TRUE(p.position_at(0.0).isApprox(Vector3d(-0.01, -0.02, 0.01)));
  EXPECT_TRUE(p.position_at(0.2 + 0.2).isApprox(Vector3d(-0.01 + 0.02, -0.02, -0.003)));
  EXPECT_NEAR(p.position_at(0.2 + 0.4 + 0.2 + 0.2).z(), 0.01, 1e-12);
  EXPECT_EQ(path_kind_from_string("press-slide"), PathKind::kPressSlide);
  EXPECT_THROW(path_kind_from_string("zigzag"), ConfigError);
  p.z_contact_m = 0.02;
  EXPECT_THROW(p.validate(), ConfigError);
}

TEST(SimulatedDevice, VirtualHandSettlesWhereItsSpringBalancesTheRenderedForce) {
  ManualClock clock;
  ScriptedPath path = hold_path();
  path.centre_m = Vector3d(0, 0, 0);
  path.z_contact_m = -0.01;
  path.approach_s = 0.1;
  VirtualHand hand;  // 200 N/m
  SimulatedDevice dev(clock, path, hand);
  dev.open();
  ASSERT_TRUE(dev.arm());
  DeviceReading r;
  for (int k = 0; k < 5000; ++k) {  // 5 s at 1 kHz with a constant 1 N upward force
    clock.advance_ns(1000000);
    ASSERT_EQ(dev.read(r), DeviceStatus::kOk);
    dev.write(Vector3d(0, 0, 1.0));
  }
  EXPECT_NEAR(r.position_m.z(), -0.01 + 1.0 / 200.0, 1e-5);
  EXPECT_EQ(r.time_ns, clock.now_ns());
  // Without the hand the end effector is on the target whatever the force.
  VirtualHand none;
  none.enabled = false;
  SimulatedDevice rigid(clock, path, none);
  rigid.open();
  clock.advance_ns(1000000000);  // set-up time before the first read does not count
  rigid.read(r);
  EXPECT_NEAR(r.position_m.z(), path.z_above_m, 1e-12);
  clock.advance_ns(1000000000);
  rigid.read(r);
  EXPECT_NEAR(r.position_m.z(), -0.01, 1e-12);
}

TEST(ReplayDevice, InterpolatesAndHoldsTheLastSample) {
  const auto dir = hc::test::temp_dir("replay");
  {
    std::ofstream f(dir / "session.csv");
    f << "t,x,y,z\n# comment\n0.0,0,0,0\n0.5,0.01,0,0\n1.0,0.01,0.02,-0.002\n";
  }
  ManualClock clock(123456789);
  ReplayDevice dev(clock, dir / "session.csv");
  dev.open();
  EXPECT_EQ(dev.sample_count(), 3U);
  EXPECT_DOUBLE_EQ(dev.duration_s(), 1.0);
  DeviceReading r;
  ASSERT_EQ(dev.read(r), DeviceStatus::kOk);  // first read starts the replay
  EXPECT_TRUE(r.position_m.isApprox(Vector3d::Zero()));
  clock.advance_ns(250000000);
  ASSERT_EQ(dev.read(r), DeviceStatus::kOk);
  EXPECT_TRUE(r.position_m.isApprox(Vector3d(0.005, 0, 0), 1e-12));
  clock.advance_ns(500000000);
  ASSERT_EQ(dev.read(r), DeviceStatus::kOk);
  EXPECT_TRUE(r.position_m.isApprox(Vector3d(0.01, 0.01, -0.001), 1e-12));
  clock.advance_ns(500000000);
  EXPECT_EQ(dev.read(r), DeviceStatus::kEndOfData);
  EXPECT_TRUE(r.position_m.isApprox(Vector3d(0.01, 0.02, -0.002)));
}

TEST(ReplayDevice, BadFilesNameTheLine) {
  const auto dir = hc::test::temp_dir("replay_bad");
  ManualClock clock;
  {
    std::ofstream f(dir / "bad.csv");
    f << "t,x,y,z\n0,0,0,0\n0.1,0,zero,0\n";
  }
  ReplayDevice bad(clock, dir / "bad.csv");
  try {
    bad.open();
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("bad.csv:3"), std::string::npos) << e.what();
  }
  EXPECT_EQ(bad.state(), DeviceState::kClosed);
  {
    std::ofstream f(dir / "order.csv");
    f << "0,0,0,0\n0.1,0,0,0\n0.1,0,0,0\n";
  }
  ReplayDevice order(clock, dir / "order.csv");
  EXPECT_THROW(order.open(), InputError);
  ReplayDevice missing(clock, dir / "missing.csv");
  EXPECT_THROW(missing.open(), InputError);
  {
    std::ofstream f(dir / "empty.csv");
    f << "t,x,y,z\n";
  }
  ReplayDevice empty(clock, dir / "empty.csv");
  EXPECT_THROW(empty.open(), InputError);
}

}  // namespace
}  // namespace hc::haptics
