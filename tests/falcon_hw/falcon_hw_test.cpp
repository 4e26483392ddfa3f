// The real-hardware check (ctest label `hw`, excluded by scripts/test). It runs only when a Novint
// Falcon is attached; otherwise (no Falcon, or no USB access at all: libusb_init fails, as in a
// container) it is reported as SKIPPED (never as passed) with a message saying that it did not run.
// No force is ever commanded: the device stays Open (reads only).
#include "hc/common/error.hpp"
#include "hc/falcon/falcon_device.hpp"
#include "hc/falcon/usb_transport.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <iostream>
#include <thread>

namespace hc::falcon {
namespace {

TEST(FalconHardware, ReadsFramesFromAnAttachedFalcon) {
  std::vector<UsbFalconInfo> found;
  try {
    found = list_usb_falcons();
  } catch (const ResourceError& e) {
    // No USB access at all (libusb_init fails in a container without /dev/bus/usb).
    GTEST_SKIP() << "USB is not available (" << e.what() << "): the hardware test did NOT run";
  }
  if (found.empty()) {
    GTEST_SKIP() << "no Novint Falcon attached (USB 0403:cb48): the hardware test did NOT run";
  }
  ASSERT_TRUE(found[0].accessible) << "Falcon at " << found[0].port_path << ": " << found[0].problem;
  haptics::SteadyClock clock;
  FalconConfig cfg;  // firmware from $HAPTICLOUD_FALCON_FIRMWARE if it is not running yet
  cfg.max_missed_ticks = 200;
  cfg.supervisor_thread = false;
  FalconDevice dev(clock, std::make_unique<UsbFalconProvider>(0), cfg);
  dev.open();
  std::cout << "firmware: " << (dev.firmware_report().already_running ? "already running" : dev.firmware_report().log)
            << "\n" << dev.homing_message() << "\n";
  int ok = 0;
  haptics::DeviceReading r;
  for (int k = 0; k < 1000; ++k) {
    if (dev.read(r) == haptics::DeviceStatus::kOk) ++ok;
    ASSERT_EQ(dev.write(Eigen::Vector3d::Zero()), haptics::DeviceStatus::kOk);
    ASSERT_TRUE(r.position_m.allFinite());
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  const FalconStatus s = dev.status();
  std::cout << "frames " << s.frames << ", stale reads " << s.stale_reads << ", bad frames " << s.bad_frames
            << ", position (device frame) " << r.position_m.transpose() << " m, buttons " << r.buttons << "\n";
  EXPECT_GT(ok, 900);
  EXPECT_GT(s.frames, 900U);
  dev.close();
}

}  // namespace
}  // namespace hc::falcon
