#pragma once
/// @file falcon_config.hpp
/// Settings of the Novint Falcon driver as plain data (header only: Eigen and the standard
/// library), so that the run config (`falcon:` section, docs/config.md) is parsed straight into
/// it without linking the driver, and one function checks every range for both the config
/// reader and FalconDevice.

#include "hc/falcon/firmware.hpp"
#include "hc/falcon/kinematics.hpp"

#include <optional>
#include <sstream>
#include <string>

namespace hc::falcon {

struct FalconConfig {
  std::string firmware_path;        ///< "" → $HAPTICLOUD_FALCON_FIRMWARE (only needed to load)
  int device_index = 0;             ///< which attached Falcon to open (0 = the first found), [0, 63]
  /// Firmware start-up settings (attempts ≥ 1, probe counts, read time-out [ms], upload chunk
  /// [bytes]; firmware.hpp); used by open() and by every reconnection (the upload is skipped
  /// when the firmware already runs).
  FirmwareOptions firmware;
  double max_force_n = 8.0;         ///< force cap [N], (0, 10]
  /// Largest virtual-wall stiffness [N/m] the Falcon renders stably at nominal_rate_hz; reported
  /// in DeviceInfo for the haptic renderer to clamp to (not enforced by this class).
  double max_stable_stiffness_n_per_m = 2000.0;
  double nominal_rate_hz = 1000.0;  ///< servo rate [Hz], for the missed-tick watchdog
  int max_missed_ticks = 10;        ///< ticks without a read (armed) or stale reads tolerated, [1, 1000]
  int io_timeout_ms = 2;            ///< run-mode read time-out [ms] ≥ 1
  int fk_iterations = 3;            ///< Newton steps per tick (steady state), ≥ 1; no force on a tick whose solve did not converge
  int max_consecutive_io_errors = 5;  ///< transport errors in a row (kError) after which the link counts as down, ≥ 1
  std::int16_t max_motor_command = 32000;  ///< per-motor command limit (direction-preserving)
  /// Mechanism constants (lengths [m], leg angles [rad], encoder and motor scales); defaults are
  /// the stock Falcon's.
  FalconGeometry geometry;
  /// The device frame handed to the haptics (metres, z up, origin at the workspace centre) as a
  /// rotation and centre relative to the Falcon frame (kinematics.hpp); positions are reported
  /// and forces [N] are taken in this frame.
  DeviceFrame frame;
  bool supervisor_thread = true;    ///< run supervise() on a thread every supervisor_period_ms
  int supervisor_period_ms = 2;
  int reconnect_interval_ms = 500;  ///< between reconnection attempts [ms] ≥ 0
};

/// A setting out of range: `key` is its name under `falcon.` in the run config (or the struct
/// field), `message` says the value and what was expected ("= 20: expected a number in (0, 10]").
struct FalconConfigIssue {
  std::string key;
  std::string message;
};

/// Checks every range of `c`; the first violation, or nothing. The one place the Falcon's
/// settings are range-checked (the config reader and FalconDevice's constructor both call it).
inline std::optional<FalconConfigIssue> check_falcon_config(const FalconConfig& c) {
  const auto issue = [](const char* key, double v, const char* expected) {
    std::ostringstream s;
    s << "= " << v << ": expected " << expected;
    return FalconConfigIssue{key, s.str()};
  };
  if (c.device_index < 0 || c.device_index > 63) return issue("index", c.device_index, "an integer in [0, 63]");
  if (!(c.max_force_n > 0.0 && c.max_force_n <= 10.0)) return issue("max_force_n", c.max_force_n, "a number in (0, 10]");
  if (c.max_missed_ticks < 1 || c.max_missed_ticks > 1000) {
    return issue("max_missed_ticks", c.max_missed_ticks, "an integer in [1, 1000]");
  }
  if (!(c.nominal_rate_hz > 0.0 && c.nominal_rate_hz <= 10000.0)) {
    return issue("nominal_rate_hz", c.nominal_rate_hz, "a number in (0, 10000]");
  }
  if (c.io_timeout_ms < 1) return issue("io_timeout_ms", c.io_timeout_ms, ">= 1");
  if (c.fk_iterations < 1) return issue("fk_iterations", c.fk_iterations, ">= 1");
  if (c.max_motor_command < 1) return issue("max_motor_command", c.max_motor_command, "1..32767");
  if (c.supervisor_period_ms < 1) return issue("supervisor_period_ms", c.supervisor_period_ms, ">= 1");
  if (c.reconnect_interval_ms < 0) return issue("reconnect_interval_ms", c.reconnect_interval_ms, ">= 0");
  if (c.firmware.attempts < 1) return issue("firmware.attempts", c.firmware.attempts, ">= 1");
  if (c.max_consecutive_io_errors < 1) return issue("max_consecutive_io_errors", c.max_consecutive_io_errors, ">= 1");
  return std::nullopt;
}

}  // namespace hc::falcon
