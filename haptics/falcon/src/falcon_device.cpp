// FalconDevice: homing, safety and reconnection on top of the transport, protocol and kinematics.
// (Homing procedure and LED meaning: facts from libnifalcon (BSD), re-derived.)
#include "hc/falcon/falcon_device.hpp"

#include "hc/common/error.hpp"

#include <array>
#include <chrono>
#include <cmath>
#include <sstream>

namespace hc::falcon {
namespace {

using haptics::DeviceState;
using haptics::DeviceStatus;

// Newton steps allowed on a cold solve (start from the workspace centre: open, reconnection,
// homing change, encoder jump). Forces stay off until a solve converges (do_write).
constexpr int kColdIterations = 30;
constexpr double kJumpRad = 0.05;  // encoder jump that calls for a cold FK solve [rad]

}  // namespace

const char* to_string(LinkState state) noexcept { return state == LinkState::kUp ? "up" : "down"; }

haptics::DeviceInfo FalconDevice::info_for(const FalconConfig& c, const std::string& name) {
  haptics::DeviceInfo info;
  info.name = name;
  info.workspace_half_extent_m = Eigen::Vector3d(0.05, 0.05, 0.05);
  info.max_force_n = c.max_force_n;
  info.max_stable_stiffness_n_per_m = c.max_stable_stiffness_n_per_m;
  info.max_damping_n_s_per_m = 20.0;
  info.nominal_rate_hz = c.nominal_rate_hz;
  return info;
}

FalconDevice::FalconDevice(const haptics::Clock& clock, std::unique_ptr<TransportProvider> provider, FalconConfig config)
    : HapticDevice(info_for(config, "Novint Falcon (" + (provider ? provider->describe() : std::string("none")) + ")")),
      clock_(clock),
      provider_(std::move(provider)),
      config_(std::move(config)),
      kin_(config_.geometry),
      period_ns_(std::llround(1e9 / config_.nominal_rate_hz)) {
  if (!provider_) throw ConfigError("falcon: no transport provider given");
  if (const auto issue = check_falcon_config(config_)) {
    throw ConfigError("falcon config: " + issue->key + " " + issue->message);
  }
  (void)kin_.inverse(x_m_, theta_rad_);
}

FalconDevice::~FalconDevice() {
  close();  // zero force, stops the supervisor
  stop_supervisor();
}

bool FalconDevice::acquire() noexcept {
  bool expected = false;
  return io_busy_.compare_exchange_strong(expected, true, std::memory_order_acq_rel);
}

std::unique_ptr<Transport> FalconDevice::connect() {
  auto t = provider_->open();
  firmware_report_ = ensure_firmware(
      *t, [this] { return read_firmware_image(resolve_firmware_path(config_.firmware_path)); }, config_.firmware);
  prime(*t);
  return t;
}

void FalconDevice::prime(Transport& t) {
  assembler_.reset();
  const Frame idle = encode_command(CommandFrame{{0, 0, 0}, kLedRed, true});
  std::array<std::uint8_t, 64> buf{};
  for (int k = 0; k < 20; ++k) {
    if (t.write(idle, config_.firmware.timeout_ms) != IoStatus::kOk) break;
    std::size_t n = 0;
    const IoStatus s = t.read(buf, n, config_.firmware.timeout_ms);
    if (s == IoStatus::kDisconnected) break;
    if (s == IoStatus::kOk) assembler_.push(std::span<const std::uint8_t>(buf.data(), n));
    Frame f{};
    StatusFrame st;
    if (assembler_.take(f) && decode_status(f, st)) {
      apply_status(st, true);
      stale_ = 0;
      return;
    }
  }
  throw ResourceError("falcon " + t.describe() +
                      ": the firmware runs but no status frame came back; replug the Falcon's USB and power");
}

void FalconDevice::do_open() {
  auto t = connect();
  transport_ = std::move(t);
  have_read_.store(false, std::memory_order_release);
  watchdog_tripped_.store(false, std::memory_order_release);
  link_.store(LinkState::kUp, std::memory_order_release);
  start_supervisor();
}

void FalconDevice::do_close() noexcept {
  stop_supervisor();
  while (!acquire()) std::this_thread::yield();  // a servo tick in flight finishes first
  link_.store(LinkState::kDown, std::memory_order_release);
  transport_.reset();
  release();
}

void FalconDevice::start_supervisor() {
  if (!config_.supervisor_thread || supervisor_.joinable()) return;
  supervisor_stop_.store(false, std::memory_order_release);
  supervisor_ = std::thread([this] {
    while (!supervisor_stop_.load(std::memory_order_acquire)) {
      supervise();
      std::this_thread::sleep_for(std::chrono::milliseconds(config_.supervisor_period_ms));
    }
  });
}

void FalconDevice::stop_supervisor() noexcept {
  if (!supervisor_.joinable()) return;
  supervisor_stop_.store(true, std::memory_order_release);
  supervisor_.join();
}

void FalconDevice::apply_status(const StatusFrame& s, bool cold) noexcept {
  const Eigen::Vector3d theta = kin_.angles_from_counts(s.encoder);
  const std::uint8_t homed_before = homed_mask_.load(std::memory_order_relaxed);
  cold = cold || cold_fk_ || s.homed_mask != homed_before || (theta - theta_rad_).cwiseAbs().maxCoeff() > kJumpRad;
  Eigen::Vector3d x = cold ? FalconKinematics::workspace_centre_m() : x_m_;
  last_fk_ = kin_.forward(theta, x, cold ? kColdIterations : config_.fk_iterations);
  if (x.allFinite()) {
    x_m_ = x;
    theta_rad_ = theta;
    cold_fk_ = !last_fk_.converged && cold;
  } else {
    cold_fk_ = true;
  }
  homed_mask_.store(s.homed_mask, std::memory_order_release);
  buttons_.store(s.buttons, std::memory_order_relaxed);
  frames_.fetch_add(1, std::memory_order_relaxed);
}

DeviceStatus FalconDevice::do_read(haptics::DeviceReading& out) noexcept {
  const std::int64_t now = clock_.now_ns();
  out.time_ns = now;
  // Link down: the supervisor owns the transport and the kinematic state (reconnection).
  if (link_.load(std::memory_order_acquire) != LinkState::kUp) return DeviceStatus::kIoError;
  if (!acquire()) return DeviceStatus::kIoError;  // the supervisor holds the transport
  // Re-check under the token: the supervisor may have taken the link down (and be reconnecting)
  // between the check above and acquire().
  if (link_.load(std::memory_order_acquire) != LinkState::kUp || transport_ == nullptr) {
    release();
    return DeviceStatus::kIoError;
  }
  DeviceStatus status = DeviceStatus::kOk;
  const std::int64_t limit = period_ns_ * (config_.max_missed_ticks + 1);
  if (state() == DeviceState::kArmed && have_read_.load(std::memory_order_relaxed) &&
      now - last_read_ns_.load(std::memory_order_relaxed) > limit && !stall_handled_.load(std::memory_order_relaxed)) {
    watchdog_trips_.fetch_add(1, std::memory_order_relaxed);
    status = DeviceStatus::kIoError;
  }
  last_read_ns_.store(now, std::memory_order_relaxed);
  have_read_.store(true, std::memory_order_release);
  stall_handled_.store(false, std::memory_order_relaxed);

  std::array<std::uint8_t, 64> buf{};
  bool fresh = false;
  for (int k = 0; k < 2 && !fresh; ++k) {
    std::size_t n = 0;
    const IoStatus s = transport_->read(buf, n, config_.io_timeout_ms);
    if (s == IoStatus::kDisconnected) {
      link_.store(LinkState::kDown, std::memory_order_release);
      io_errors_.fetch_add(1, std::memory_order_relaxed);
      homed_mask_.store(0, std::memory_order_release);
      release();
      return DeviceStatus::kIoError;
    }
    if (s == IoStatus::kError) {
      io_errors_.fetch_add(1, std::memory_order_relaxed);
      status = DeviceStatus::kIoError;
      if (note_transport_error()) {
        release();
        return DeviceStatus::kIoError;
      }
      break;
    }
    if (s != IoStatus::kOk) break;
    consecutive_errors_ = 0;
    if (assembler_.push(std::span<const std::uint8_t>(buf.data(), n)) > 0) {
      Frame f{};
      StatusFrame st;
      if (assembler_.take(f) && decode_status(f, st)) {
        apply_status(st, false);
        fresh = true;
      }
    }
  }
  bad_frames_.store(assembler_.bad_frames(), std::memory_order_relaxed);
  skipped_bytes_.store(assembler_.skipped_bytes(), std::memory_order_relaxed);
  if (fresh) {
    stale_ = 0;
  } else {
    ++stale_;
    stale_reads_.fetch_add(1, std::memory_order_relaxed);
    if (stale_ > config_.max_missed_ticks) status = DeviceStatus::kIoError;
  }
  release();
  if (watchdog_tripped_.exchange(false, std::memory_order_acq_rel)) status = DeviceStatus::kIoError;
  out.position_m = config_.frame.to_device(x_m_);
  out.buttons = buttons_.load(std::memory_order_relaxed);
  return status;
}

IoStatus FalconDevice::send_idle_frame() noexcept {
  const bool homed_now = homed();
  const Frame f = encode_command(CommandFrame{{0, 0, 0}, homed_now ? kLedGreen : kLedRed, !homed_now});
  return transport_ ? transport_->write(f, config_.io_timeout_ms) : IoStatus::kDisconnected;
}

bool FalconDevice::note_transport_error() noexcept {
  if (++consecutive_errors_ < config_.max_consecutive_io_errors) return false;
  // A transport that keeps failing is treated like an unplug: the supervisor reconnects.
  consecutive_errors_ = 0;
  link_.store(LinkState::kDown, std::memory_order_release);
  homed_mask_.store(0, std::memory_order_release);
  return true;
}

DeviceStatus FalconDevice::do_write(const Eigen::Vector3d& force_n) noexcept {
  if (link_.load(std::memory_order_acquire) != LinkState::kUp) return DeviceStatus::kIoError;
  if (!acquire()) return DeviceStatus::kIoError;
  // Re-check under the token (see do_read): nothing is sent on a link being reconnected.
  if (link_.load(std::memory_order_acquire) != LinkState::kUp || transport_ == nullptr) {
    release();
    return DeviceStatus::kIoError;
  }
  const bool homed_now = homed();
  CommandFrame c;
  c.homing = !homed_now;
  c.leds = homed_now ? kLedGreen : kLedRed;
  if (stop_requested()) c.leds = kLedBlue;
  // Forces only from a fresh frame whose forward kinematics converged (a cold start may take
  // several ticks; until then x_m_ is not trustworthy and the force is zero).
  const bool forces_allowed =
      homed_now && stale_ == 0 && last_fk_.converged && !stop_requested() && state() == DeviceState::kArmed;
  if (forces_allowed && force_n.allFinite() && force_n.squaredNorm() > 0.0) {
    const MotorCommands m =
        kin_.commands_for_force(x_m_, theta_rad_, config_.frame.vector_to_falcon(force_n), config_.max_motor_command);
    c.motor = m.counts;
    if (m.saturated) saturated_.fetch_add(1, std::memory_order_relaxed);
  }
  const IoStatus s = transport_->write(encode_command(c), config_.io_timeout_ms);
  if (s == IoStatus::kDisconnected) {
    link_.store(LinkState::kDown, std::memory_order_release);
    homed_mask_.store(0, std::memory_order_release);
  }
  if (s != IoStatus::kOk) io_errors_.fetch_add(1, std::memory_order_relaxed);
  if (s == IoStatus::kError) {
    (void)note_transport_error();
  } else if (s == IoStatus::kOk) {
    consecutive_errors_ = 0;
  }
  release();
  return s == IoStatus::kOk ? DeviceStatus::kOk : DeviceStatus::kIoError;
}

void FalconDevice::supervise() noexcept {
  if (state() == DeviceState::kClosed) return;
  if (link_.load(std::memory_order_acquire) == LinkState::kUp) {
    const std::int64_t now = clock_.now_ns();
    const std::int64_t limit = period_ns_ * (config_.max_missed_ticks + 1);
    const bool stalled = state() == DeviceState::kArmed && have_read_.load(std::memory_order_acquire) &&
                         now - last_read_ns_.load(std::memory_order_relaxed) > limit;
    if ((stalled && !stall_handled_.load(std::memory_order_relaxed)) || stop_requested()) {
      if (acquire()) {
        const IoStatus s = send_idle_frame();
        if (s == IoStatus::kDisconnected) link_.store(LinkState::kDown, std::memory_order_release);
        if (stalled && !stall_handled_.load(std::memory_order_relaxed)) {
          stall_handled_.store(true, std::memory_order_relaxed);
          watchdog_tripped_.store(true, std::memory_order_release);
          watchdog_trips_.fetch_add(1, std::memory_order_relaxed);
        }
        release();
      }
    }
    return;
  }
  // Link down: try to reconnect (the servo thread no longer touches the transport).
  const std::int64_t mono = haptics::monotonic_now_ns();
  if (last_attempt_ns_ != 0 && mono - last_attempt_ns_ < std::int64_t{config_.reconnect_interval_ms} * 1000000) return;
  last_attempt_ns_ = mono;
  // The token is held for the whole reconnection (connect() also resets the frame assembler and
  // the kinematic state): the servo side sees either no transport or a primed one, never a
  // half-made one, and meanwhile its reads and writes return kIoError.
  if (!acquire()) return;
  transport_.reset();
  try {
    transport_ = connect();
  } catch (const std::exception& e) {
    transport_.reset();
    release();
    std::lock_guard lock(error_mutex_);
    reconnect_error_ = e.what();
    return;
  }
  stale_ = 1;
  cold_fk_ = true;
  consecutive_errors_ = 0;
  have_read_.store(false, std::memory_order_release);
  reconnections_.fetch_add(1, std::memory_order_relaxed);
  link_.store(LinkState::kUp, std::memory_order_release);
  release();
  std::lock_guard lock(error_mutex_);
  reconnect_error_.clear();
}

FalconStatus FalconDevice::status() const noexcept {
  FalconStatus s;
  s.link = link_.load(std::memory_order_acquire);
  s.homed_mask = homed_mask_.load(std::memory_order_acquire);
  s.buttons = buttons_.load(std::memory_order_relaxed);
  s.frames = frames_.load(std::memory_order_relaxed);
  s.bad_frames = bad_frames_.load(std::memory_order_relaxed);
  s.skipped_bytes = skipped_bytes_.load(std::memory_order_relaxed);
  s.stale_reads = stale_reads_.load(std::memory_order_relaxed);
  s.io_errors = io_errors_.load(std::memory_order_relaxed);
  s.watchdog_trips = watchdog_trips_.load(std::memory_order_relaxed);
  s.reconnections = reconnections_.load(std::memory_order_relaxed);
  s.saturated_ticks = saturated_.load(std::memory_order_relaxed);
  return s;
}

std::string FalconDevice::last_reconnect_error() const {
  std::lock_guard lock(error_mutex_);
  return reconnect_error_;
}

std::string FalconDevice::homing_message() const {
  if (state() == DeviceState::kClosed) return "closed";
  if (link_.load(std::memory_order_acquire) != LinkState::kUp) {
    return "unplugged: forces are off; plug the Falcon back in (USB and power), it reconnects by itself";
  }
  const std::uint8_t m = homed_mask_.load(std::memory_order_acquire);
  if (m == kAllAxesHomed) {
    return state() == DeviceState::kFault ? "homed (LED green); the device is in fault: reset it to continue"
                                          : "homed (LED green): forces may be enabled";
  }
  std::string arms;
  for (int i = 0; i < 3; ++i) {
    arms += " arm " + std::to_string(i + 1) + ((m >> i) & 1 ? " homed;" : " not homed;");
  }
  return "not homed (LED red, forces off): pull the grip all the way out towards you, then push it straight all the "
         "way in;" + arms;
}

}  // namespace hc::falcon
