#pragma once
/// @file falcon_device.hpp
/// FalconDevice: the Novint Falcon as an hc::haptics::HapticDevice (docs/architecture.md,
/// "hc::falcon"). Layers: a Transport (libusb or the emulator) → firmware load and the run-mode
/// frame protocol → pure kinematics → this class (homing, safety, reconnection).
///
/// Threads: read()/write() run on the servo thread (one frame out, one frame in per tick, no
/// allocation, no exceptions). An optional supervisor thread (or supervise() called by the
/// owner) is the watchdog and reconnects after an unplug; the two share the transport through
/// an atomic token, never a lock held by the servo thread.
///
/// Safety: the force is capped (DeviceInfo::max_force_n, default 8 N) and is zero: until all
/// three arms are homed; on a tick whose read brought no fresh frame; on a tick whose forward
/// kinematics did not converge (a cold solve from the workspace centre, after open, reconnection,
/// a homing change or an encoder jump, may use up to 30 Newton steps in one tick; a steady-state
/// tick uses at most fk_iterations; the force stays zero until a solve converges); after more than
/// max_missed_ticks ticks without a read while armed (the watchdog sends zero frames and the
/// next read reports kIoError, so the servo loop faults the device); after SIGINT/SIGTERM once
/// install_stop_signal_handlers() was called; when the device is unplugged (reads return
/// kIoError), also after max_consecutive_io_errors transport errors in a row (then the link is
/// taken down and the supervisor reconnects as after an unplug); on close() and destruction. Homing: the homing bit is sent and the LED is red until
/// the firmware reports all arms homed, then green; homing_message() says what to do.

#include "hc/falcon/falcon_config.hpp"
#include "hc/falcon/firmware.hpp"
#include "hc/falcon/kinematics.hpp"
#include "hc/falcon/protocol.hpp"
#include "hc/falcon/transport.hpp"
#include "hc/haptics/clock.hpp"
#include "hc/haptics/device.hpp"
#include "hc/haptics/stop_signal.hpp"

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

namespace hc::falcon {

/// USB link state: kUp while a primed transport exists and the servo may use it; kDown after an
/// unplug, repeated transport errors or close() (the supervisor then reconnects).
enum class LinkState : std::uint8_t { kUp = 0, kDown };
/// "up" or "down" (static strings). Real-time: yes.
const char* to_string(LinkState state) noexcept;

/// Counters and flags, readable from any thread.
struct FalconStatus {
  LinkState link = LinkState::kDown;
  std::uint8_t homed_mask = 0;     ///< bit i: arm i homed
  std::uint32_t buttons = 0;
  std::uint64_t frames = 0;        ///< good status frames received
  std::uint64_t bad_frames = 0;    ///< malformed 16-byte runs
  std::uint64_t skipped_bytes = 0; ///< garbage bytes between frames
  std::uint64_t stale_reads = 0;   ///< reads that brought no fresh frame
  std::uint64_t io_errors = 0;
  std::uint64_t watchdog_trips = 0;
  std::uint64_t reconnections = 0;
  std::uint64_t saturated_ticks = 0;  ///< motor commands scaled down
};

// The process-wide stop request (hc/haptics/stop_signal.hpp): once SIGINT/SIGTERM arrived,
// every FalconDevice sends zero force.
using haptics::clear_stop_request;
using haptics::install_stop_signal_handlers;
using haptics::request_stop;
using haptics::stop_requested;

class FalconDevice final : public haptics::HapticDevice {
 public:
  /// `clock` stamps the readings and drives the watchdog; `provider` opens (and re-opens) the
  /// transport. @throws hc::ConfigError naming the field for an invalid config.
  FalconDevice(const haptics::Clock& clock, std::unique_ptr<TransportProvider> provider, FalconConfig config = {});
  ~FalconDevice() override;

  /// Capabilities for a config: ±50 mm box, the force cap, 2000 N/m, 20 N·s/m, the rate.
  static haptics::DeviceInfo info_for(const FalconConfig& config, const std::string& name);

  /// One watchdog and reconnection step (what the supervisor thread runs). Non-real-time;
  /// never throws (reconnection errors are kept in last_reconnect_error()).
  void supervise() noexcept;

  /// A snapshot of the link state, homing mask, buttons and counters (each field read
  /// atomically; the fields are not mutually consistent to the tick). Any thread; real-time: yes.
  FalconStatus status() const noexcept;
  bool homed() const noexcept { return homed_mask_.load(std::memory_order_acquire) == kAllAxesHomed; }
  /// What the user should do now (homing guidance, unplugged, fault). Real-time: no.
  std::string homing_message() const;
  /// The message of the last failed reconnection attempt ("" after a successful one or before any
  /// attempt). Any thread; takes a mutex, real-time: no.
  std::string last_reconnect_error() const;
  const FirmwareReport& firmware_report() const noexcept { return firmware_report_; }
  /// Effector position from the last good frame [m], Falcon frame (servo thread / stopped).
  const Eigen::Vector3d& falcon_position_m() const noexcept { return x_m_; }
  /// Arm angles from the last good frame [rad] (servo thread / stopped).
  const Eigen::Vector3d& arm_angles_rad() const noexcept { return theta_rad_; }
  /// Newton steps used by the last read (servo thread / stopped).
  int last_fk_iterations() const noexcept { return last_fk_.iterations; }
  /// Whether the last forward-kinematics solve converged (forces need it; servo thread / stopped).
  bool last_fk_converged() const noexcept { return last_fk_.converged; }
  const FalconConfig& config() const noexcept { return config_; }

 protected:
  void do_open() override;
  void do_close() noexcept override;
  haptics::DeviceStatus do_read(haptics::DeviceReading& out) noexcept override;
  haptics::DeviceStatus do_write(const Eigen::Vector3d& force_n) noexcept override;

 private:
  bool acquire() noexcept;
  void release() noexcept { io_busy_.store(false, std::memory_order_release); }
  /// Counts a kError from the transport; after max_consecutive_io_errors in a row takes the link
  /// down and returns true. Caller holds the token.
  bool note_transport_error() noexcept;
  /// Sends zero motors, the homing bit while not homed and the LEDs. Caller holds the token.
  IoStatus send_idle_frame() noexcept;
  /// Applies a decoded status frame (counts → angles → FK). Servo side or under the token.
  void apply_status(const StatusFrame& s, bool cold) noexcept;
  /// Zero frame and replies until a status frame arrives (open / reconnection). @throws ResourceError.
  void prime(Transport& t);
  std::unique_ptr<Transport> connect();
  void start_supervisor();
  void stop_supervisor() noexcept;

  const haptics::Clock& clock_;
  std::unique_ptr<TransportProvider> provider_;
  FalconConfig config_;
  FalconKinematics kin_;
  std::int64_t period_ns_;
  std::unique_ptr<Transport> transport_;
  FirmwareReport firmware_report_;
  FrameAssembler assembler_;

  // Servo-side state (or under the token while the servo does not run).
  Eigen::Vector3d x_m_ = FalconKinematics::workspace_centre_m();
  Eigen::Vector3d theta_rad_ = Eigen::Vector3d::Zero();
  FkResult last_fk_{};
  int stale_ = 1;  // reads since the last fresh frame
  int consecutive_errors_ = 0;  // transport kError results in a row
  bool cold_fk_ = true;
  std::uint8_t leds_ = kLedRed;

  // Shared with the supervisor and readers.
  std::atomic<bool> io_busy_{false};
  std::atomic<LinkState> link_{LinkState::kDown};
  std::atomic<std::uint8_t> homed_mask_{0};
  std::atomic<std::uint32_t> buttons_{0};
  std::atomic<std::int64_t> last_read_ns_{0};
  std::atomic<bool> have_read_{false};
  std::atomic<bool> watchdog_tripped_{false};
  std::atomic<bool> stall_handled_{false};
  std::atomic<std::uint64_t> frames_{0}, stale_reads_{0}, io_errors_{0}, watchdog_trips_{0}, reconnections_{0},
      saturated_{0}, bad_frames_{0}, skipped_bytes_{0};

  // Supervisor.
  std::thread supervisor_;
  std::atomic<bool> supervisor_stop_{false};
  std::int64_t last_attempt_ns_ = 0;
  mutable std::mutex error_mutex_;
  std::string reconnect_error_;
};

}  // namespace hc::falcon
