#pragma once
/// @file device.hpp
/// The haptic device interface and its lifecycle (docs/architecture.md, "Devices"):
/// Closed → Open (reads only) → Armed (forces on; the proxy's small-force gate and ramp apply)
/// → Fault (zero force until an explicit reset). Non-real-time open/close/info; real-time
/// read/write that return a status and never throw.

#include <Eigen/Core>

#include <atomic>
#include <cstdint>
#include <string>

namespace hc::haptics {

enum class DeviceState : std::uint8_t { kClosed = 0, kOpen, kArmed, kFault };

/// "closed", "open", "armed", "fault". Real-time: yes.
const char* to_string(DeviceState state) noexcept;

/// Result of a real-time device call.
enum class DeviceStatus : std::uint8_t {
  kOk = 0,
  kNotOpen,    ///< the device is Closed
  kFault,      ///< the device is in Fault (reads still work) or a non-finite force was refused
  kIoError,    ///< transport error; the supervisor decides (the servo loop faults the device)
  kEndOfData,  ///< a replay ran out of samples (the last position is held)
  kNoData,     ///< no position yet (a network device before its first pose): the servo loop
               ///< renders no force and keeps the contact gate closed, without faulting
};

/// "ok", "not_open", "fault", "io_error", "end_of_data", "no_data". Real-time: yes.
const char* to_string(DeviceStatus status) noexcept;

/// Capabilities as data, in SI units.
struct DeviceInfo {
  std::string name;
  Eigen::Vector3d workspace_half_extent_m = Eigen::Vector3d(0.05, 0.05, 0.05);  ///< box [m]
  double max_force_n = 8.0;                    ///< continuous force limit [N] > 0
  double max_stable_stiffness_n_per_m = 2000;  ///< stiffness rendered without vibration [N/m]
  double max_damping_n_s_per_m = 20.0;         ///< damping limit [N·s/m]
  double nominal_rate_hz = 1000.0;             ///< servo rate the device expects [Hz]
};

/// One position sample.
struct DeviceReading {
  Eigen::Vector3d position_m = Eigen::Vector3d::Zero();  ///< end effector, device frame [m]
  std::int64_t time_ns = 0;                              ///< clock time of the sample [ns]
  std::uint32_t buttons = 0;                             ///< bit mask of pressed buttons
};

/// Base of every device. The lifecycle is implemented here (non-virtual interface); concrete
/// devices implement the do_* hooks. Thread-safety: the state is atomic, so state() and
/// arm()/disarm()/reset_fault() may be called from any thread; read/write/fault are for the
/// servo thread; open/close only while no servo loop runs. While a servo loop runs, change the
/// lifecycle through its commands (shared_state.hpp).
class HapticDevice {
 public:
  virtual ~HapticDevice() = default;
  HapticDevice(const HapticDevice&) = delete;
  HapticDevice& operator=(const HapticDevice&) = delete;

  /// Closed → Open (no-op in any other state). @throws what do_open() throws (hc::InputError,
  /// hc::ResourceError naming what to check); the state stays Closed then. Real-time: no.
  void open();
  /// Any state → Closed, after writing a zero force. Real-time: no.
  void close() noexcept;
  /// Open → Armed. @return false in any other state (Fault needs reset_fault()). Real-time: yes.
  bool arm() noexcept;
  /// Armed → Open (forces off). Real-time: yes.
  void disarm() noexcept;
  /// Open/Armed → Fault, and a zero force is written. Real-time: yes.
  void fault() noexcept;
  /// Fault → Open. @return false in any other state. Real-time: yes.
  bool reset_fault() noexcept;
  DeviceState state() const noexcept { return state_.load(std::memory_order_acquire); }
  /// Capabilities (fixed at construction). Real-time: yes (no copy).
  const DeviceInfo& info() const noexcept { return info_; }

  /// Reads the position. kNotOpen when Closed; otherwise the hook's status (Fault still reads).
  /// Real-time: yes (noexcept, no allocation).
  DeviceStatus read(DeviceReading& out) noexcept;
  /// Sends a force [N], device frame. Armed: its magnitude is clamped to info().max_force_n
  /// keeping the direction; a non-finite force sends zero, faults the device and returns kFault.
  /// Open/Fault: zero is sent instead (status kOk / kFault). Closed: kNotOpen, nothing sent.
  /// Real-time: yes.
  DeviceStatus write(const Eigen::Vector3d& force_n) noexcept;
  /// The last force actually sent [N] (servo thread, or after the servo stopped).
  const Eigen::Vector3d& last_force_n() const noexcept { return last_force_n_; }

 protected:
  /// @throws hc::ConfigError naming the field when `info` is out of range.
  explicit HapticDevice(DeviceInfo info);
  virtual void do_open() = 0;
  virtual void do_close() noexcept = 0;
  virtual DeviceStatus do_read(DeviceReading& out) noexcept = 0;
  virtual DeviceStatus do_write(const Eigen::Vector3d& force_n) noexcept = 0;

 private:
  DeviceInfo info_;
  std::atomic<DeviceState> state_{DeviceState::kClosed};
  Eigen::Vector3d last_force_n_ = Eigen::Vector3d::Zero();
};

}  // namespace hc::haptics
