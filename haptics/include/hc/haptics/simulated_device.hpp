#pragma once
/// @file simulated_device.hpp
/// Devices without hardware: a SimulatedDevice follows a scripted path, optionally through a
/// "virtual hand" (a spring-damper pulling the end effector towards the scripted target, so the
/// rendered force feeds back into the motion); a ReplayDevice plays back a recorded CSV session.
/// Both run on an injected Clock: real time (SteadyClock) or as fast as possible (ManualClock).

#include "hc/haptics/clock.hpp"
#include "hc/haptics/device.hpp"

#include <Eigen/Core>

#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace hc::haptics {

enum class PathKind : std::uint8_t { kHold = 0, kLine, kCircle, kRaster, kPressSlide };

/// Parses "hold", "line", "circle", "raster", "press-slide" (also "press_slide").
/// @throws hc::ConfigError naming the value and the allowed set.
PathKind path_kind_from_string(std::string_view name);
const char* to_string(PathKind kind) noexcept;

/// A scripted target trajectory in the device frame (metres, seconds).
/// All paths but press-slide first descend from z_above_m to z_contact_m at their start point
/// over approach_s (a smooth cubic), then move in the plane z = z_contact_m at speed_m_per_s:
///  - hold: stay at centre;
///  - line: back and forth along x between centre.x ± half_x_m (start at −);
///  - circle: radius half_x_m around centre, counter-clockwise from (centre.x + r, centre.y);
///  - raster: boustrophedon lines along x (length 2·half_x_m) spaced raster_spacing_m in y over
///    centre.y ± half_y_m, then the same lines backwards, repeated;
///  - press-slide: cycles of press down (approach_s) at centre.x − half_x_m, slide along +x over
///    2·half_x_m at z_contact_m, lift (approach_s), fly back at z_above_m.
struct ScriptedPath {
  PathKind kind = PathKind::kCircle;
  Eigen::Vector3d centre_m = Eigen::Vector3d::Zero();
  double half_x_m = 0.02;
  double half_y_m = 0.02;
  double z_above_m = 0.01;
  double z_contact_m = -0.005;
  double speed_m_per_s = 0.05;
  double raster_spacing_m = 0.004;
  double approach_s = 0.5;

  /// @throws hc::ConfigError naming the field for non-finite values, non-positive speed,
  ///         extents, spacing or approach time, or z_contact_m ≥ z_above_m.
  void validate() const;
  /// Target position [m], device frame, at time t_s ≥ 0 since the start. Real-time: yes.
  Eigen::Vector3d position_at(double t_s) const noexcept;
};

/// The spring-damper "hand" holding the device: m·a = k_h·(target − x) − b_h·v + F_device.
struct VirtualHand {
  bool enabled = true;                 ///< false: the end effector is exactly on the target
  double stiffness_n_per_m = 200.0;    ///< k_h > 0
  double damping_n_s_per_m = 6.0;      ///< b_h ≥ 0
  double mass_kg = 0.15;               ///< m > 0 (hand plus device)
};

/// Device following a ScriptedPath (see the file comment).
/// Time: the clock's time since the first read() after open() is the path time (so set-up
/// between open() and the first servo tick does not eat into the path). Each read() integrates the hand from
/// the previous read to now (semi-implicit Euler, sub-steps ≤ 0.25 ms, at most 4000 of them)
/// using the last force written. Real-time: read/write yes.
class SimulatedDevice final : public HapticDevice {
 public:
  /// @throws hc::ConfigError for an invalid path, hand or info.
  SimulatedDevice(const Clock& clock, const ScriptedPath& path, const VirtualHand& hand = {},
                  DeviceInfo info = default_info());
  /// Falcon-like capabilities: ±50 mm cube, 8.9 N, 2000 N/m, 20 N·s/m, 1 kHz.
  static DeviceInfo default_info();
  const ScriptedPath& path() const noexcept { return path_; }
  /// The target of the last read() [m], device frame.
  const Eigen::Vector3d& target_m() const noexcept { return target_m_; }

 protected:
  void do_open() override;
  void do_close() noexcept override {}
  DeviceStatus do_read(DeviceReading& out) noexcept override;
  DeviceStatus do_write(const Eigen::Vector3d& force_n) noexcept override;

 private:
  const Clock& clock_;
  ScriptedPath path_;
  VirtualHand hand_;
  bool started_ = false;
  std::int64_t start_ns_ = 0;
  double last_t_s_ = 0.0;
  Eigen::Vector3d x_m_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d v_m_per_s_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d force_n_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d target_m_ = Eigen::Vector3d::Zero();
};

/// Plays back positions recorded as CSV lines `t,x,y,z` (seconds, metres, device frame); an
/// optional header line is skipped, as are blank lines and lines starting with '#'.
/// Times must increase strictly. Between samples the position is interpolated linearly; the
/// clock's time since the first read() is the replay time; past the last sample the last
/// position is held and read() returns kEndOfData. Forces written are kept (last_force_n()).
class ReplayDevice final : public HapticDevice {
 public:
  /// The file is read by open(). @throws hc::ConfigError for an invalid info.
  ReplayDevice(const Clock& clock, std::filesystem::path csv, DeviceInfo info = SimulatedDevice::default_info());
  std::size_t sample_count() const noexcept { return t_s_.size(); }
  /// Time of the last sample minus the first [s] (0 before open()).
  double duration_s() const noexcept;

 protected:
  /// @throws hc::InputError naming the file and line for a missing/unreadable file, a line
  ///         that is not four finite numbers, times that do not increase, or no samples.
  void do_open() override;
  void do_close() noexcept override {}
  DeviceStatus do_read(DeviceReading& out) noexcept override;
  DeviceStatus do_write(const Eigen::Vector3d&) noexcept override { return DeviceStatus::kOk; }

 private:
  const Clock& clock_;
  std::filesystem::path csv_;
  std::vector<double> t_s_;
  std::vector<Eigen::Vector3d> p_m_;
  bool started_ = false;
  std::int64_t start_ns_ = 0;
  std::size_t cursor_ = 0;
};

}  // namespace hc::haptics
