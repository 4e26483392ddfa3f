// Falcon kinematics (geometry facts from libnifalcon (BSD), re-derived; equations in kinematics.hpp).
#include "hc/falcon/kinematics.hpp"

#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <limits>

namespace hc::falcon {

FalconKinematics::FalconKinematics(const FalconGeometry& geometry) noexcept : g_(geometry) {
  for (std::size_t i = 0; i < 3; ++i) {
    const double c = std::cos(g_.leg_angle_rad[i]);
    const double s = std::sin(g_.leg_angle_rad[i]);
    rot_[i] << c, s, 0, -s, c, 0, 0, 0, 1;
  }
}

Eigen::Vector3d FalconKinematics::angles_from_counts(const std::array<std::int16_t, 3>& counts) const noexcept {
  Eigen::Vector3d t;
  for (int i = 0; i < 3; ++i) t[i] = g_.angle_at_zero_count_rad + g_.rad_per_count * counts[static_cast<std::size_t>(i)];
  return t;
}

std::int16_t FalconKinematics::count_from_angle(double theta_rad) const noexcept {
  const double c = (theta_rad - g_.angle_at_zero_count_rad) / g_.rad_per_count;
  if (!std::isfinite(c)) return 0;
  return static_cast<std::int16_t>(std::clamp(std::round(c), -32768.0, 32767.0));
}

bool FalconKinematics::partials(const Eigen::Vector3d& x, const Eigen::Vector3d& theta, Eigen::Vector3d& h,
                                Eigen::Matrix3d& hx, Eigen::Vector3d& htheta) const noexcept {
  for (int i = 0; i < 3; ++i) {
    const Eigen::Vector3d p = rot_[static_cast<std::size_t>(i)] * x - Eigen::Vector3d(g_.r_m, g_.s_m, 0.0);
    const double vf = p.y() + g_.f_m;
    const double q2 = g_.b_m * g_.b_m - vf * vf;
    if (!(q2 > 0.0)) return false;
    const double q = std::sqrt(q2);
    const double len = g_.d_m + g_.e_m + q;
    const double ct = std::cos(theta[i]);
    const double st = std::sin(theta[i]);
    const double du = p.x() + g_.c_m - g_.a_m * ct;
    const double dw = p.z() - g_.a_m * st;
    h[i] = du * du + dw * dw - len * len;
    // dh/dP = (2 du, 2 L (v + f) / q, 2 dw); dP/dx = R_i.
    const Eigen::RowVector3d dp(2.0 * du, 2.0 * len * vf / q, 2.0 * dw);
    hx.row(i) = dp * rot_[static_cast<std::size_t>(i)];
    htheta[i] = 2.0 * g_.a_m * ((p.x() + g_.c_m) * st - p.z() * ct);
  }
  return true;
}

Eigen::Vector3d FalconKinematics::residual(const Eigen::Vector3d& x, const Eigen::Vector3d& theta) const noexcept {
  Eigen::Vector3d h = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
  Eigen::Matrix3d hx;
  Eigen::Vector3d ht;
  (void)partials(x, theta, h, hx, ht);
  return h;
}

bool FalconKinematics::inverse(const Eigen::Vector3d& x, Eigen::Vector3d& theta) const noexcept {
  Eigen::Vector3d out;
  for (int i = 0; i < 3; ++i) {
    const Eigen::Vector3d p = rot_[static_cast<std::size_t>(i)] * x - Eigen::Vector3d(g_.r_m, g_.s_m, 0.0);
    const double vf = p.y() + g_.f_m;
    const double q2 = g_.b_m * g_.b_m - vf * vf;
    if (!(q2 > 0.0)) return false;
    const double len = g_.d_m + g_.e_m + std::sqrt(q2);
    // A cos θ + B sin θ = C.
    const double uc = p.x() + g_.c_m;
    const double A = 2.0 * g_.a_m * uc;
    const double B = 2.0 * g_.a_m * p.z();
    const double C = uc * uc + p.z() * p.z() + g_.a_m * g_.a_m - len * len;
    const double rho = std::hypot(A, B);
    if (!(rho > 0.0) || std::abs(C) > rho) return false;
    out[i] = std::atan2(B, A) - std::acos(C / rho);
  }
  if (!out.allFinite()) return false;
  theta = out;
  return true;
}

FkResult FalconKinematics::forward(const Eigen::Vector3d& theta, Eigen::Vector3d& x_inout, int max_iterations,
                                   double tolerance_m) const noexcept {
  FkResult r;
  Eigen::Vector3d x = x_inout;
  Eigen::Vector3d h, ht;
  Eigen::Matrix3d hx;
  for (int k = 0; k < max_iterations; ++k) {
    if (!partials(x, theta, h, hx, ht)) break;
    const double det = hx.determinant();
    if (!(std::abs(det) > 1e-18)) break;
    const Eigen::Vector3d step = hx.inverse() * h;
    if (!step.allFinite()) break;
    // Damp wild first steps from a poor start (stay inside the mechanism's reach).
    const double n = step.norm();
    x -= n > 0.02 ? (step * (0.02 / n)).eval() : step;
    ++r.iterations;
    r.last_step_m = std::min(n, 0.02);
    if (n < tolerance_m) {
      r.converged = true;
      break;
    }
  }
  if (x.allFinite()) x_inout = x;
  return r;
}

bool FalconKinematics::jacobian(const Eigen::Vector3d& x, const Eigen::Vector3d& theta, Eigen::Matrix3d& j) const noexcept {
  Eigen::Vector3d h, ht;
  Eigen::Matrix3d hx;
  if (!partials(x, theta, h, hx, ht)) return false;
  const double det = hx.determinant();
  if (!(std::abs(det) > 1e-18)) return false;
  j = -(hx.inverse() * ht.asDiagonal());
  return j.allFinite();
}

Eigen::Vector3d FalconKinematics::torques_for_force(const Eigen::Vector3d& x, const Eigen::Vector3d& theta,
                                                    const Eigen::Vector3d& force_n) const noexcept {
  Eigen::Matrix3d j;
  if (!force_n.allFinite() || !jacobian(x, theta, j)) return Eigen::Vector3d::Zero();
  return j.transpose() * force_n;
}

MotorCommands FalconKinematics::commands_for_force(const Eigen::Vector3d& x, const Eigen::Vector3d& theta,
                                                   const Eigen::Vector3d& force_n,
                                                   std::int16_t max_command) const noexcept {
  MotorCommands out;
  Eigen::Vector3d c = torques_for_force(x, theta, force_n) * (g_.command_sign * g_.command_per_newton_metre);
  if (!c.allFinite()) return out;
  const double limit = std::clamp(static_cast<double>(max_command), 0.0, 32767.0);
  const double peak = c.cwiseAbs().maxCoeff();
  if (peak > limit) {
    c *= peak > 0.0 ? limit / peak : 0.0;
    out.saturated = true;
  }
  for (int i = 0; i < 3; ++i) {
    out.counts[static_cast<std::size_t>(i)] = static_cast<std::int16_t>(std::clamp(std::round(c[i]), -limit, limit));
  }
  return out;
}

Eigen::Vector3d FalconKinematics::force_for_commands(const Eigen::Vector3d& x, const Eigen::Vector3d& theta,
                                                     const std::array<std::int16_t, 3>& counts) const noexcept {
  Eigen::Matrix3d j;
  if (!jacobian(x, theta, j)) return Eigen::Vector3d::Zero();
  const double det = j.determinant();
  if (!(std::abs(det) > 1e-18)) return Eigen::Vector3d::Zero();
  const Eigen::Vector3d tau(counts[0], counts[1], counts[2]);
  const Eigen::Vector3d f = j.transpose().inverse() * (tau / (g_.command_sign * g_.command_per_newton_metre));
  return f.allFinite() ? f : Eigen::Vector3d::Zero();
}

}  // namespace hc::falcon
