#pragma once
/// @file input_devices.hpp
/// Haptic devices for an exploration session without (or around) force-feedback hardware:
/// MouseDevice, a position-only device driven by the viewer's mouse (no force is felt).

#include "hc/haptics/device.hpp"
#include "hc/haptics/clock.hpp"
#include "hc/haptics/shared_state.hpp"
#include "hc/haptics/triple_buffer.hpp"

#include <Eigen/Core>

#include <cstdint>

namespace hc::viewer {

/// A device whose end effector is wherever the UI thread last put it (set_position, e.g. the
/// mouse through Viewer::mouse_target). Forces written are kept (last_force_n) and otherwise
/// dropped: a mouse pushes nothing back. Capabilities: those of SimulatedDevice::default_info()
/// with the name "mouse".
/// Threads: set_position from one UI thread; read/write from the servo thread (a triple buffer
/// between them, so neither waits). Real-time: read/write yes.
class MouseDevice final : public haptics::HapticDevice {
 public:
  explicit MouseDevice(const haptics::Clock& clock);
  /// The end effector [m], device frame; non-finite values are ignored. Real-time: yes.
  void set_position(const Eigen::Vector3d& device_m) noexcept;

 protected:
  void do_open() override {}
  void do_close() noexcept override {}
  haptics::DeviceStatus do_read(haptics::DeviceReading& out) noexcept override;
  haptics::DeviceStatus do_write(const Eigen::Vector3d&) noexcept override { return haptics::DeviceStatus::kOk; }

 private:
  const haptics::Clock& clock_;
  haptics::TripleBuffer<haptics::Vec3> position_;
  haptics::Vec3 last_{};
};

}  // namespace hc::viewer
