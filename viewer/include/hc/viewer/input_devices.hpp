#pragma once
/// @file input_devices.hpp
/// Haptic devices for an exploration session without (or around) force-feedback hardware:
/// MouseDevice, a position-only device driven by the viewer's mouse (no force is felt), and
/// ButtonTap, a wrapper that forwards to another device and publishes its button mask so the
/// UI thread can turn device buttons into level/region commands.

#include "hc/haptics/device.hpp"
#include "hc/haptics/clock.hpp"
#include "hc/haptics/shared_state.hpp"
#include "hc/haptics/triple_buffer.hpp"

#include <Eigen/Core>

#include <atomic>
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

/// Forwards open/close/read/write to `inner` (which it opens and arms: the lifecycle and force
/// gating are this wrapper's own) and stores the button mask of every read in an atomic that
/// any thread may read. Real-time: read/write yes (one relaxed atomic store more than inner).
class ButtonTap final : public haptics::HapticDevice {
 public:
  /// `inner` must outlive the wrapper and be Closed. @throws what inner's constructor checks.
  explicit ButtonTap(haptics::HapticDevice& inner);
  /// Buttons of the latest read (bit mask). Thread-safe.
  std::uint32_t buttons() const noexcept { return buttons_.load(std::memory_order_relaxed); }
  haptics::HapticDevice& inner() noexcept { return inner_; }

 protected:
  /// Opens and arms `inner`. @throws what inner.open() throws.
  void do_open() override;
  void do_close() noexcept override { inner_.close(); }
  haptics::DeviceStatus do_read(haptics::DeviceReading& out) noexcept override;
  haptics::DeviceStatus do_write(const Eigen::Vector3d& force_n) noexcept override { return inner_.write(force_n); }

 private:
  haptics::HapticDevice& inner_;
  std::atomic<std::uint32_t> buttons_{0};
};

}  // namespace hc::viewer
