#include "hc/haptics/device.hpp"

#include "hc/common/error.hpp"

#include <cmath>
#include <sstream>
#include <utility>

namespace hc::haptics {

const char* to_string(DeviceState state) noexcept {
  switch (state) {
    case DeviceState::kClosed: return "closed";
    case DeviceState::kOpen: return "open";
    case DeviceState::kArmed: return "armed";
    case DeviceState::kFault: return "fault";
  }
  return "unknown";
}

const char* to_string(DeviceStatus status) noexcept {
  switch (status) {
    case DeviceStatus::kOk: return "ok";
    case DeviceStatus::kNotOpen: return "not_open";
    case DeviceStatus::kFault: return "fault";
    case DeviceStatus::kIoError: return "io_error";
    case DeviceStatus::kEndOfData: return "end_of_data";
    case DeviceStatus::kNoData: return "no_data";
  }
  return "unknown";
}

HapticDevice::HapticDevice(DeviceInfo info) : info_(std::move(info)) {
  const auto fail = [this](const char* field, double value, const char* expected) {
    std::ostringstream s;
    s << "device '" << info_.name << "': " << field << " = " << value << ", expected " << expected;
    throw ConfigError(s.str());
  };
  if (!info_.workspace_half_extent_m.allFinite() || !(info_.workspace_half_extent_m.minCoeff() > 0)) {
    fail("workspace_half_extent_m (smallest)", info_.workspace_half_extent_m.minCoeff(), "finite > 0");
  }
  if (!(info_.max_force_n > 0) || !std::isfinite(info_.max_force_n)) fail("max_force_n", info_.max_force_n, "finite > 0");
  if (!(info_.max_stable_stiffness_n_per_m > 0) || !std::isfinite(info_.max_stable_stiffness_n_per_m)) {
    fail("max_stable_stiffness_n_per_m", info_.max_stable_stiffness_n_per_m, "finite > 0");
  }
  if (!(info_.max_damping_n_s_per_m >= 0) || !std::isfinite(info_.max_damping_n_s_per_m)) {
    fail("max_damping_n_s_per_m", info_.max_damping_n_s_per_m, "finite >= 0");
  }
  if (!(info_.nominal_rate_hz > 0) || !std::isfinite(info_.nominal_rate_hz)) {
    fail("nominal_rate_hz", info_.nominal_rate_hz, "finite > 0");
  }
}

void HapticDevice::open() {
  if (state() != DeviceState::kClosed) return;
  do_open();
  state_.store(DeviceState::kOpen, std::memory_order_release);
}

void HapticDevice::close() noexcept {
  if (state() == DeviceState::kClosed) return;
  last_force_n_.setZero();
  (void)do_write(last_force_n_);
  do_close();
  state_.store(DeviceState::kClosed, std::memory_order_release);
}

bool HapticDevice::arm() noexcept {
  DeviceState expected = DeviceState::kOpen;
  return state_.compare_exchange_strong(expected, DeviceState::kArmed, std::memory_order_acq_rel);
}

void HapticDevice::disarm() noexcept {
  DeviceState expected = DeviceState::kArmed;
  state_.compare_exchange_strong(expected, DeviceState::kOpen, std::memory_order_acq_rel);
}

void HapticDevice::fault() noexcept {
  DeviceState s = state();
  while (s == DeviceState::kOpen || s == DeviceState::kArmed) {
    if (state_.compare_exchange_weak(s, DeviceState::kFault, std::memory_order_acq_rel)) break;
  }
  if (state() == DeviceState::kFault) {
    last_force_n_.setZero();
    (void)do_write(last_force_n_);
  }
}

bool HapticDevice::reset_fault() noexcept {
  DeviceState expected = DeviceState::kFault;
  return state_.compare_exchange_strong(expected, DeviceState::kOpen, std::memory_order_acq_rel);
}

DeviceStatus HapticDevice::read(DeviceReading& out) noexcept {
  if (state() == DeviceState::kClosed) return DeviceStatus::kNotOpen;
  return do_read(out);
}

DeviceStatus HapticDevice::write(const Eigen::Vector3d& force_n) noexcept {
  const DeviceState s = state();
  if (s == DeviceState::kClosed) return DeviceStatus::kNotOpen;
  Eigen::Vector3d f = Eigen::Vector3d::Zero();
  DeviceStatus status = s == DeviceState::kFault ? DeviceStatus::kFault : DeviceStatus::kOk;
  if (s == DeviceState::kArmed) {
    if (!force_n.allFinite()) {
      fault();
      return DeviceStatus::kFault;
    }
    f = force_n;
    const double mag = f.norm();
    if (mag > info_.max_force_n) f *= info_.max_force_n / mag;
  }
  last_force_n_ = f;
  const DeviceStatus hook = do_write(f);
  return hook != DeviceStatus::kOk ? hook : status;
}

}  // namespace hc::haptics
