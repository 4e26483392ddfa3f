/// MouseDevice (input_devices.hpp).

#include "hc/viewer/input_devices.hpp"

#include "hc/haptics/simulated_device.hpp"

#include <cmath>

namespace hc::viewer {

namespace {
haptics::DeviceInfo mouse_info() {
  haptics::DeviceInfo info = haptics::SimulatedDevice::default_info();
  info.name = "mouse";
  return info;
}
}  // namespace

MouseDevice::MouseDevice(const haptics::Clock& clock) : HapticDevice(mouse_info()), clock_(clock) {}

void MouseDevice::set_position(const Eigen::Vector3d& device_m) noexcept {
  if (!device_m.allFinite()) return;
  position_.write(haptics::Vec3::of(device_m));
}

haptics::DeviceStatus MouseDevice::do_read(haptics::DeviceReading& out) noexcept {
  haptics::Vec3 p;
  if (position_.read(p)) last_ = p;
  out.position_m = last_.eigen();
  out.time_ns = clock_.now_ns();
  out.buttons = 0;
  return haptics::DeviceStatus::kOk;
}

}  // namespace hc::viewer
