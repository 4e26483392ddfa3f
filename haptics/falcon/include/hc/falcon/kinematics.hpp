#pragma once
/// @file kinematics.hpp
/// Kinematics of the Falcon's delta-type parallel mechanism, pure functions on Eigen types.
/// Geometry constants, leg angles, the encoder-to-angle conversion and the torque-to-command
/// scale are facts from libnifalcon (BSD), re-derived (it follows R. E. Stamper's 1997 thesis on
/// the Maryland delta); the equations below are our own formulation.
///
/// "Falcon frame": metres, origin at the centre of the three leg bases, z along the grip's axis
/// away from the base (the grip sits at z ≈ 0.11 m in the middle of the workspace).
/// Leg i (angle φ_i about z) sees the end effector at P_i = R(φ_i)·x + (−r, −s, 0) = (u, v, w).
/// Its upper arm (length a, angle θ_i) puts the knee at (a cos θ, ·, a sin θ) in the u-w plane;
/// the parallelogram (length b, plus the joint offsets d + e) reaches the effector offset (c, f):
///     h_i(x, θ_i) = (u + c − a cos θ)² + (w − a sin θ)² − L(v)² = 0,
///     L(v) = d + e + √(b² − (v + f)²).
/// Forward kinematics solves h(x, θ) = 0 for x by Newton's method, inverse kinematics solves it
/// for each θ_i in closed form, and the Jacobian is dx/dθ = −(∂h/∂x)⁻¹ ∂h/∂θ.

#include <Eigen/Core>

#include <array>
#include <cstdint>

namespace hc::falcon {

/// Mechanism constants (SI). Defaults: libnifalcon's Falcon measurements.
struct FalconGeometry {
  double a_m = 0.060;     ///< upper arm length
  double b_m = 0.1025;    ///< parallelogram length
  double c_m = 0.01443;   ///< effector offset, u component
  double d_m = 0.01125;   ///< parallelogram to effector joint
  double e_m = 0.01125;   ///< knee to parallelogram joint
  double f_m = -0.025;    ///< effector offset, v component
  double r_m = 0.0400;    ///< leg base from the centre, u component
  double s_m = -0.02309;  ///< leg base from the centre, v component
  /// Leg angles about z: 90°, −30°, −150°, each plus the 15° tilt of the legs [rad].
  std::array<double, 3> leg_angle_rad{1.8325957145940461, -0.2617993877991494, -2.3561944901923448};
  /// Arm angle per encoder count [rad]: 2π / (320 slots · 4 edges) times the capstan ratio
  /// motor shaft 14.25 mm : arm drum 110 mm.
  double rad_per_count = 2.0 * 3.14159265358979323846 / 1280.0 * (0.01425 / 0.110);
  double angle_at_zero_count_rad = 35.0 * 3.14159265358979323846 / 180.0;  ///< θ at count 0 (homed)
  /// Motor command units per N·m of arm torque, and its sign (libnifalcon scales by 10⁴ and
  /// negates).
  double command_per_newton_metre = 10000.0;
  double command_sign = -1.0;
};

/// Result of forward kinematics.
struct FkResult {
  int iterations = 0;     ///< Newton steps taken
  double last_step_m = 0; ///< size of the last step [m] (an error bound once it is small)
  bool converged = false; ///< last step below the tolerance and the result finite
};

/// Motor commands for a force, with whether they had to be scaled down.
struct MotorCommands {
  /// Raw motor command per arm as sent in the command frame (signed int16 units of the
  /// firmware, not encoder counts): command_per_newton_metre · command_sign · arm torque [N·m],
  /// rounded and limited to ±max_command.
  std::array<std::int16_t, 3> counts{};
  bool saturated = false;
};

class FalconKinematics {
 public:
  explicit FalconKinematics(const FalconGeometry& geometry = {}) noexcept;
  const FalconGeometry& geometry() const noexcept { return g_; }

  /// Encoder counts → arm angles [rad]. Real-time: yes.
  Eigen::Vector3d angles_from_counts(const std::array<std::int16_t, 3>& counts) const noexcept;
  /// Arm angle [rad] → nearest encoder count, clamped to the int16 range. Real-time: yes.
  std::int16_t count_from_angle(double theta_rad) const noexcept;

  /// Leg constraint residuals h_i(x, θ_i) [m²] (zero when x and θ agree). Real-time: yes.
  Eigen::Vector3d residual(const Eigen::Vector3d& x_m, const Eigen::Vector3d& theta_rad) const noexcept;
  /// Inverse kinematics: arm angles [rad] for an effector position [m], Falcon frame (the
  /// mechanism's knee-out branch). @return false (theta untouched) if x is out of reach.
  /// Real-time: yes.
  bool inverse(const Eigen::Vector3d& x_m, Eigen::Vector3d& theta_rad) const noexcept;
  /// Forward kinematics: Newton's method on h(x, θ) = 0 starting from x_inout (warm start: the
  /// previous tick's solution) for at most max_iterations steps, stopping when a step is below
  /// tolerance_m. x_inout is left unchanged if a step turns singular or non-finite.
  /// Real-time: yes (no allocation).
  FkResult forward(const Eigen::Vector3d& theta_rad, Eigen::Vector3d& x_inout, int max_iterations = 3,
                   double tolerance_m = 1e-6) const noexcept;
  /// dx/dθ [m/rad] at a consistent (x, θ). @return false when singular. Real-time: yes.
  bool jacobian(const Eigen::Vector3d& x_m, const Eigen::Vector3d& theta_rad, Eigen::Matrix3d& j) const noexcept;
  /// Arm torques [N·m] producing force_n [N] at the effector: τ = Jᵀ F. Zero if singular.
  Eigen::Vector3d torques_for_force(const Eigen::Vector3d& x_m, const Eigen::Vector3d& theta_rad,
                                    const Eigen::Vector3d& force_n) const noexcept;
  /// Force [N] → motor commands. Non-finite input gives zeros. If any command would exceed
  /// max_command in magnitude, all three are scaled by the same factor (the force keeps its
  /// direction) and `saturated` is set; never wraps int16. Real-time: yes.
  MotorCommands commands_for_force(const Eigen::Vector3d& x_m, const Eigen::Vector3d& theta_rad,
                                   const Eigen::Vector3d& force_n, std::int16_t max_command) const noexcept;
  /// The force [N] that motor commands produce at (x, θ) (the inverse map, for the emulator
  /// and tests). Zero if singular.
  Eigen::Vector3d force_for_commands(const Eigen::Vector3d& x_m, const Eigen::Vector3d& theta_rad,
                                     const std::array<std::int16_t, 3>& counts) const noexcept;

  /// Middle of the workspace [m], Falcon frame (all arms at the same angle, ≈ 16°).
  static Eigen::Vector3d workspace_centre_m() noexcept { return Eigen::Vector3d(0.0, 0.0, 0.11); }

 private:
  /// ∂h/∂x (rows per leg) and ∂h/∂θ (diagonal) at (x, θ); false if out of reach.
  bool partials(const Eigen::Vector3d& x_m, const Eigen::Vector3d& theta_rad, Eigen::Vector3d& h,
                Eigen::Matrix3d& hx, Eigen::Vector3d& htheta) const noexcept;
  FalconGeometry g_;
  std::array<Eigen::Matrix3d, 3> rot_;  // R(φ_i)
};

/// The device frame handed to the haptics (z up, like the height fields) and its relation to the
/// Falcon frame: x_device = rotation · (x_falcon − centre). Default: device x = Falcon x,
/// device y = −(Falcon z − 0.11 m) (away from the user), device z = Falcon y (up).
struct DeviceFrame {
  Eigen::Matrix3d rotation = (Eigen::Matrix3d() << 1, 0, 0, 0, 0, -1, 0, 1, 0).finished();
  Eigen::Vector3d centre_m = FalconKinematics::workspace_centre_m();
  Eigen::Vector3d to_device(const Eigen::Vector3d& x_falcon_m) const noexcept { return rotation * (x_falcon_m - centre_m); }
  Eigen::Vector3d to_falcon(const Eigen::Vector3d& x_device_m) const noexcept {
    return rotation.transpose() * x_device_m + centre_m;
  }
  /// A vector (force) from device axes to Falcon axes.
  Eigen::Vector3d vector_to_falcon(const Eigen::Vector3d& v) const noexcept { return rotation.transpose() * v; }
};

}  // namespace hc::falcon
