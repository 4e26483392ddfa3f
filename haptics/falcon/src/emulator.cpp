// The Falcon emulator (device-side protocol facts from libnifalcon (BSD), re-derived).
#include "hc/falcon/emulator.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cmath>

namespace hc::falcon {
namespace {

constexpr double kWallStiffness = 3000.0;  // soft stop at the edge of the reachable box [N/m]
constexpr double kWallHalfExtent = 0.065;  // [m] around the workspace centre

}  // namespace

FalconEmulator::FalconEmulator(EmulatorOptions options) : o_(std::move(options)), kin_(o_.geometry) {
  x_m_ = o_.start_m;
  theta_rad_ = Eigen::Vector3d::Zero();
  if (!kin_.inverse(x_m_, theta_rad_)) throw ConfigError("falcon emulator: start_m is out of the mechanism's reach");
  if (o_.firmware_preloaded) mode_ = Mode::kRunning;
}

std::uint64_t FalconEmulator::connect() {
  std::lock_guard lock(m_);
  return plugged_ ? connection_ : 0;
}

void FalconEmulator::on_baud_locked(std::uint16_t divisor) {
  baud_ = divisor;
  if (mode_ == Mode::kRunning) return;
  if (divisor == ftdi::kBaudBootProbe) {
    mode_ = Mode::kBootIdle;
    probe_buf_.clear();
  } else if (divisor == ftdi::kBaudRun && mode_ == Mode::kUploading) {
    const bool complete = o_.expected_image_size == 0 || uploaded_ == o_.expected_image_size;
    mode_ = complete ? Mode::kRunning : Mode::kBootIdle;
    if (complete) in_.reset();
  }
}

IoStatus FalconEmulator::control(std::uint64_t connection, std::uint8_t request, std::uint16_t value) {
  std::lock_guard lock(m_);
  if (!plugged_ || connection != connection_) return IoStatus::kDisconnected;
  switch (request) {
    case ftdi::kReset:
      if (value == ftdi::kPurgeRx) out_.clear();
      if (value == ftdi::kPurgeTx) in_.reset();
      break;
    case ftdi::kModemControl:
      if (value == ftdi::kDtrHigh) dtr_ = true;
      if (value == ftdi::kDtrLow) dtr_ = false;
      break;
    case ftdi::kSetBaudRate: on_baud_locked(value); break;
    case ftdi::kSetData:
    case ftdi::kSetFlowControl:
    case ftdi::kSetLatencyTimer: break;
    default: return IoStatus::kError;
  }
  return IoStatus::kOk;
}

IoStatus FalconEmulator::write(std::uint64_t connection, std::span<const std::uint8_t> bytes) {
  std::lock_guard lock(m_);
  if (!plugged_ || connection != connection_) return IoStatus::kDisconnected;
  if (faults_.io_errors && mode_ == Mode::kRunning) return IoStatus::kError;
  for (const std::uint8_t b : bytes) {
    switch (mode_) {
      case Mode::kRunning: {
        if (in_.push(std::span<const std::uint8_t>(&b, 1)) > 0) {
          Frame f{};
          CommandFrame c;
          if (in_.take(f) && decode_command(f, c)) {
            cmd_ = c;
            ++frames_;
            step_locked();
            if (!(faults_.silent_every > 0 && frames_ % static_cast<std::uint64_t>(faults_.silent_every) == 0)) {
              answer_locked();
            }
          }
        }
        break;
      }
      case Mode::kBootIdle:
        if (baud_ != ftdi::kBaudBootProbe || !dtr_) break;  // the boot loader is not listening
        probe_buf_.push_back(b);
        if (probe_buf_.size() >= kBootProbe.size() &&
            std::equal(kBootProbe.begin(), kBootProbe.end(), probe_buf_.end() - static_cast<std::ptrdiff_t>(kBootProbe.size()))) {
          probe_buf_.clear();
          if (!faults_.ignore_probe) {
            out_.insert(out_.end(), kBootProbeReply.begin(), kBootProbeReply.end());
            mode_ = Mode::kBootProbed;
          }
        }
        break;
      case Mode::kBootProbed:
        if (baud_ == ftdi::kBaudUpload && !dtr_ && b == kBootStart) {
          out_.push_back(b);
          mode_ = Mode::kUploading;
          uploaded_ = 0;
          ++attempts_;
        }
        break;
      case Mode::kUploading: {
        const int idx = static_cast<int>(uploaded_++);
        if (attempts_ <= faults_.drop_attempts && faults_.drop_echo_after >= 0 && idx > faults_.drop_echo_after) break;
        const bool corrupt = attempts_ <= faults_.corrupt_attempts && idx == faults_.corrupt_echo_at;
        out_.push_back(corrupt ? static_cast<std::uint8_t>(b ^ 0x5A) : b);
        break;
      }
    }
  }
  return IoStatus::kOk;
}

IoStatus FalconEmulator::read(std::uint64_t connection, std::span<std::uint8_t> out, std::size_t& received) {
  std::lock_guard lock(m_);
  received = 0;
  if (!plugged_ || connection != connection_) return IoStatus::kDisconnected;
  if (faults_.io_errors && mode_ == Mode::kRunning) return IoStatus::kError;
  while (received < out.size() && !out_.empty()) {
    out[received++] = out_.front();
    out_.pop_front();
  }
  return received > 0 ? IoStatus::kOk : IoStatus::kTimeout;
}

void FalconEmulator::step_locked() {
  const double dt = o_.dt_s;
  motor_force_n_ = kin_.force_for_commands(x_m_, theta_rad_, cmd_.motor);
  Eigen::Vector3d f = motor_force_n_ - o_.damping_n_s_per_m * v_m_per_s_;
  if (has_hand_ && hand_.target_m) {
    f += hand_.stiffness_n_per_m * (hand_.target_m(t_s_) - x_m_) - hand_.damping_n_s_per_m * v_m_per_s_;
  }
  const Eigen::Vector3d rel = x_m_ - FalconKinematics::workspace_centre_m();
  for (int i = 0; i < 3; ++i) {
    const double over = std::abs(rel[i]) - kWallHalfExtent;
    if (over > 0) f[i] -= kWallStiffness * over * (rel[i] > 0 ? 1.0 : -1.0);
  }
  v_m_per_s_ += f / o_.mass_kg * dt;
  const Eigen::Vector3d x_new = x_m_ + v_m_per_s_ * dt;
  Eigen::Vector3d th_new;
  if (x_new.allFinite() && kin_.inverse(x_new, th_new)) {
    if (cmd_.homing) {
      for (int i = 0; i < 3; ++i) {
        const double a = theta_rad_[i] - o_.index_angle_rad;
        const double b = th_new[i] - o_.index_angle_rad;
        if (a * b <= 0.0 && a != b) homed_ = static_cast<std::uint8_t>(homed_ | (1U << i));
      }
    }
    x_m_ = x_new;
    theta_rad_ = th_new;
  } else {
    v_m_per_s_.setZero();  // hit the end of the mechanism's reach
  }
  t_s_ += dt;
}

void FalconEmulator::answer_locked() {
  StatusFrame s;
  for (int i = 0; i < 3; ++i) {
    const auto k = static_cast<std::size_t>(i);
    int c = kin_.count_from_angle(theta_rad_[i]);
    if ((homed_ & (1U << i)) == 0) c += o_.unhomed_offset[k];
    s.encoder[k] = static_cast<std::int16_t>(std::clamp(c, -32768, 32767));
  }
  s.buttons = buttons_;
  s.homed_mask = homed_;
  const Frame f = encode_status(s);
  if (faults_.garbage_every > 0 && frames_ % static_cast<std::uint64_t>(faults_.garbage_every) == 0) {
    const std::uint8_t junk[] = {0x00, '>', 0x41, '<', 0x7f, 0x13};
    out_.insert(out_.end(), std::begin(junk), std::end(junk));
  }
  if (faults_.short_every > 0 && frames_ % static_cast<std::uint64_t>(faults_.short_every) == 0) {
    out_.insert(out_.end(), f.begin(), f.begin() + 9);
    return;
  }
  out_.insert(out_.end(), f.begin(), f.end());
}

void FalconEmulator::unplug() {
  std::lock_guard lock(m_);
  plugged_ = false;
  ++connection_;
  mode_ = Mode::kBootIdle;
  homed_ = 0;
  cmd_ = CommandFrame{};
  motor_force_n_.setZero();
  out_.clear();
  in_.reset();
}

void FalconEmulator::plug() {
  std::lock_guard lock(m_);
  plugged_ = true;
  ++connection_;
  mode_ = o_.firmware_preloaded ? Mode::kRunning : Mode::kBootIdle;
  dtr_ = false;
  baud_ = 0;
}

bool FalconEmulator::plugged() const {
  std::lock_guard lock(m_);
  return plugged_;
}
void FalconEmulator::set_hand(EmulatedHand hand) {
  std::lock_guard lock(m_);
  hand_ = std::move(hand);
  has_hand_ = true;
}
void FalconEmulator::clear_hand() {
  std::lock_guard lock(m_);
  has_hand_ = false;
}
void FalconEmulator::set_buttons(std::uint8_t buttons) {
  std::lock_guard lock(m_);
  buttons_ = static_cast<std::uint8_t>(buttons & 0xF);
}
bool FalconEmulator::firmware_running() const {
  std::lock_guard lock(m_);
  return mode_ == Mode::kRunning;
}
std::uint8_t FalconEmulator::homed_mask() const {
  std::lock_guard lock(m_);
  return homed_;
}
std::uint8_t FalconEmulator::leds() const {
  std::lock_guard lock(m_);
  return cmd_.leds;
}
bool FalconEmulator::homing_requested() const {
  std::lock_guard lock(m_);
  return cmd_.homing;
}
std::array<std::int16_t, 3> FalconEmulator::last_motor() const {
  std::lock_guard lock(m_);
  return cmd_.motor;
}
Eigen::Vector3d FalconEmulator::position_m() const {
  std::lock_guard lock(m_);
  return x_m_;
}
Eigen::Vector3d FalconEmulator::motor_force_n() const {
  std::lock_guard lock(m_);
  return kin_.force_for_commands(x_m_, theta_rad_, cmd_.motor);
}
std::uint64_t FalconEmulator::frames_received() const {
  std::lock_guard lock(m_);
  return frames_;
}
int FalconEmulator::upload_attempts() const {
  std::lock_guard lock(m_);
  return attempts_;
}
double FalconEmulator::time_s() const {
  std::lock_guard lock(m_);
  return t_s_;
}

EmulatedTransport::EmulatedTransport(std::shared_ptr<FalconEmulator> emulator)
    : emu_(std::move(emulator)), connection_(emu_->connect()) {}

IoStatus EmulatedTransport::control(std::uint8_t request, std::uint16_t value) noexcept {
  return emu_->control(connection_, request, value);
}
IoStatus EmulatedTransport::write(std::span<const std::uint8_t> bytes, int) noexcept {
  return emu_->write(connection_, bytes);
}
IoStatus EmulatedTransport::read(std::span<std::uint8_t> buffer, std::size_t& received, int) noexcept {
  return emu_->read(connection_, buffer, received);
}
std::string EmulatedTransport::describe() const { return "emulated Falcon (connection " + std::to_string(connection_) + ")"; }

std::unique_ptr<Transport> EmulatorProvider::open() {
  if (!emu_->plugged()) throw ResourceError("falcon: the emulated Falcon is unplugged");
  return std::make_unique<EmulatedTransport>(emu_);
}

}  // namespace hc::falcon
