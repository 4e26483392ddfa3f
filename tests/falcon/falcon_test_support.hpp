#pragma once
/// @file falcon_test_support.hpp
/// Helpers for the hc::falcon tests: a fake firmware image and a FalconDevice on an emulator.

#include "hc/falcon/emulator.hpp"
#include "hc/falcon/falcon_device.hpp"

#include "test_paths.hpp"

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>
#include <numbers>
#include <vector>

namespace hc::falcon::test {

/// A made-up image (the real one is not ours to ship): n bytes of a fixed pattern.
inline std::vector<std::uint8_t> fake_image(std::size_t n = 1000) {
  std::vector<std::uint8_t> img(n);
  for (std::size_t i = 0; i < n; ++i) img[i] = static_cast<std::uint8_t>((i * 37 + 11) & 0xFF);
  return img;
}

inline std::filesystem::path write_fake_image(const std::string& name, std::size_t n = 1000) {
  const auto dir = hc::test::temp_dir(name);
  const auto path = dir / "falcon_firmware.bin";
  const auto img = fake_image(n);
  std::ofstream(path, std::ios::binary).write(reinterpret_cast<const char*>(img.data()), static_cast<std::streamsize>(img.size()));
  return path;
}

/// The homing gesture: from the centre pull the grip out 40 mm along Falcon z over 0.3 s and
/// push it back in over 0.3 s, then stay. Crosses every arm's index mark twice.
inline Eigen::Vector3d homing_gesture(double t_s, double t0_s = 0.0) {
  const Eigen::Vector3d c = FalconKinematics::workspace_centre_m();
  const double t = t_s - t0_s;
  double s = 0.0;
  if (t > 0 && t < 0.3) s = t / 0.3;
  else if (t >= 0.3 && t < 0.6) s = 1.0 - (t - 0.3) / 0.3;
  return c + Eigen::Vector3d(0, 0, 0.04 * s);
}

struct EmulatedFalcon {
  std::shared_ptr<FalconEmulator> emu;
  std::unique_ptr<FalconDevice> dev;
};

/// A FalconDevice without a supervisor thread (tests call supervise()) on a fresh emulator.
inline EmulatedFalcon make_emulated(const haptics::Clock& clock, const std::string& name, FalconConfig cfg = {},
                                    EmulatorOptions eo = {}) {
  EmulatedFalcon f;
  eo.expected_image_size = 1000;
  f.emu = std::make_shared<FalconEmulator>(eo);
  cfg.firmware_path = write_fake_image(name).string();
  cfg.supervisor_thread = false;
  cfg.reconnect_interval_ms = 0;
  f.dev = std::make_unique<FalconDevice>(clock, std::make_unique<EmulatorProvider>(f.emu), cfg);
  return f;
}

}  // namespace hc::falcon::test
