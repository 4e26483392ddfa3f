#pragma once
/// @file emulator.hpp
/// A Falcon without hardware: FalconEmulator plays the device's side of the USB link (FTDI line
/// settings, the boot loader's handshake with echoes, the firmware's run-mode frames) around a
/// simple dynamic model of the mechanism: the motor commands become arm torques, the torques a
/// force on a point mass at the effector (through the Jacobian), an optional scripted "hand"
/// pulls on it, and the arm angles come back as encoder counts. One simulated step of dt_s per
/// command frame received (the servo loop's period). Faults can be injected (echo errors,
/// time-outs, garbage and short frames, unplugging). Thread-safe (one internal mutex; it is a test
/// fake, not real-time code).

#include "hc/falcon/kinematics.hpp"
#include "hc/falcon/protocol.hpp"
#include "hc/falcon/transport.hpp"

#include <Eigen/Core>

#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <vector>

namespace hc::falcon {

struct EmulatorOptions {
  FalconGeometry geometry;
  double dt_s = 0.001;                 ///< simulated time per command frame [s]
  double mass_kg = 0.15;               ///< effector plus hand mass [kg]
  double damping_n_s_per_m = 2.0;      ///< mechanism damping [N·s/m]
  bool firmware_preloaded = false;     ///< starts in run mode (firmware already running)
  std::size_t expected_image_size = 0; ///< > 0: boot only after exactly that many bytes
  std::array<std::int16_t, 3> unhomed_offset{417, -263, 151};  ///< count offsets before homing
  double index_angle_rad = 35.0 * 3.14159265358979323846 / 180.0;  ///< homing mark of each arm
  Eigen::Vector3d start_m = FalconKinematics::workspace_centre_m();  ///< effector at power-on
};

/// Injected faults (all off by default).
struct EmulatorFaults {
  int corrupt_echo_at = -1;     ///< upload byte whose echo is altered ...
  int corrupt_attempts = 0;     ///< ... in this many upload attempts (then echoes are right)
  int drop_echo_after = -1;     ///< upload bytes after this one are not echoed ...
  int drop_attempts = 0;        ///< ... in this many attempts
  bool ignore_probe = false;    ///< the boot loader never answers the probe
  int garbage_every = 0;        ///< > 0: junk bytes before every n-th status frame
  int short_every = 0;          ///< > 0: every n-th status frame cut to 9 bytes
  int silent_every = 0;         ///< > 0: every n-th command frame gets no answer
  bool io_errors = false;       ///< run-mode reads and writes fail with kError (a flaky link)
};

/// A scripted hand holding the grip: spring-damper towards target(t) [m], Falcon frame.
struct EmulatedHand {
  std::function<Eigen::Vector3d(double t_s)> target_m;
  double stiffness_n_per_m = 300.0;
  double damping_n_s_per_m = 8.0;
};

class FalconEmulator {
 public:
  explicit FalconEmulator(EmulatorOptions options = {});

  // ---- device side (used by EmulatedTransport) ----
  IoStatus control(std::uint64_t connection, std::uint8_t request, std::uint16_t value);
  IoStatus write(std::uint64_t connection, std::span<const std::uint8_t> bytes);
  IoStatus read(std::uint64_t connection, std::span<std::uint8_t> out, std::size_t& received);
  /// A new connection id (plugged), or 0 when unplugged.
  std::uint64_t connect();

  // ---- test side ----
  /// Pulls the cable: every transport fails with kDisconnected; power, firmware and homing lost.
  void unplug();
  /// Plugs it back (boot loader, not homed, arms where they were).
  void plug();
  bool plugged() const;
  void set_hand(EmulatedHand hand);
  void clear_hand();
  void set_buttons(std::uint8_t buttons);
  EmulatorFaults& faults() { return faults_; }  ///< change only while no I/O runs
  bool firmware_running() const;
  std::uint8_t homed_mask() const;
  std::uint8_t leds() const;
  bool homing_requested() const;
  std::array<std::int16_t, 3> last_motor() const;
  Eigen::Vector3d position_m() const;  ///< true effector position, Falcon frame
  Eigen::Vector3d motor_force_n() const;  ///< force the motors apply now [N], Falcon frame
  std::uint64_t frames_received() const;
  int upload_attempts() const;
  double time_s() const;

 private:
  enum class Mode : std::uint8_t { kBootIdle, kBootProbed, kUploading, kRunning };
  void step_locked();
  void answer_locked();
  void on_baud_locked(std::uint16_t divisor);

  mutable std::mutex m_;
  EmulatorOptions o_;
  FalconKinematics kin_;
  EmulatorFaults faults_;
  bool plugged_ = true;
  std::uint64_t connection_ = 1;
  Mode mode_ = Mode::kBootIdle;
  bool dtr_ = false;
  std::uint16_t baud_ = 0;
  std::size_t uploaded_ = 0;
  int attempts_ = 0;
  std::vector<std::uint8_t> probe_buf_;
  std::deque<std::uint8_t> out_;
  FrameAssembler in_{FrameAssembler::Direction::kFromHost};
  CommandFrame cmd_{};
  std::uint8_t buttons_ = 0;
  std::uint8_t homed_ = 0;
  std::uint64_t frames_ = 0;
  double t_s_ = 0.0;
  Eigen::Vector3d x_m_, v_m_per_s_ = Eigen::Vector3d::Zero(), theta_rad_;
  Eigen::Vector3d motor_force_n_ = Eigen::Vector3d::Zero();
  bool has_hand_ = false;
  EmulatedHand hand_;
};

/// The emulator seen through one USB connection; dead (kDisconnected) after an unplug.
class EmulatedTransport final : public Transport {
 public:
  explicit EmulatedTransport(std::shared_ptr<FalconEmulator> emulator);
  IoStatus control(std::uint8_t request, std::uint16_t value) noexcept override;
  IoStatus write(std::span<const std::uint8_t> bytes, int timeout_ms) noexcept override;
  IoStatus read(std::span<std::uint8_t> buffer, std::size_t& received, int timeout_ms) noexcept override;
  std::string describe() const override;

 private:
  std::shared_ptr<FalconEmulator> emu_;
  std::uint64_t connection_;
};

/// Opens EmulatedTransports to one emulator. @throws hc::ResourceError while it is unplugged.
class EmulatorProvider final : public TransportProvider {
 public:
  explicit EmulatorProvider(std::shared_ptr<FalconEmulator> emulator) : emu_(std::move(emulator)) {}
  std::unique_ptr<Transport> open() override;
  std::string describe() const override { return "emulated Falcon"; }

 private:
  std::shared_ptr<FalconEmulator> emu_;
};

}  // namespace hc::falcon
