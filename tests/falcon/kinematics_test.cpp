#include "hc/falcon/kinematics.hpp"

#include <Eigen/LU>
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

namespace hc::falcon {
namespace {

using Eigen::Vector3d;
constexpr double kPi = std::numbers::pi;

// Independent oracle for one leg's arm angle: the tangent-half-angle quadratic of the leg equation
// (a different derivation from the library's atan2/acos form), on the geometry's own numbers.
double oracle_arm_angle(const FalconGeometry& g, const Vector3d& x, int leg) {
  const double phi = g.leg_angle_rad[static_cast<std::size_t>(leg)];
  const double u = std::cos(phi) * x.x() + std::sin(phi) * x.y() - g.r_m;
  const double v = -std::sin(phi) * x.x() + std::cos(phi) * x.y() - g.s_m;
  const double w = x.z();
  const double len = g.d_m + g.e_m + g.b_m * std::sin(std::acos((v + g.f_m) / g.b_m));
  // (u + c − a cos θ)² + (w − a sin θ)² = L², with t = tan(θ/2).
  const double k = (u + g.c_m) * (u + g.c_m) + w * w + g.a_m * g.a_m - len * len;
  const double q0 = k - 2 * g.a_m * (u + g.c_m);
  const double q1 = -4 * g.a_m * w;
  const double q2 = k + 2 * g.a_m * (u + g.c_m);
  const double t = (-q1 - std::sqrt(q1 * q1 - 4 * q0 * q2)) / (2 * q2);
  return 2 * std::atan(t);
}

std::vector<Vector3d> workspace_grid(double half, int n) {
  std::vector<Vector3d> pts;
  const Vector3d c = FalconKinematics::workspace_centre_m();
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      for (int k = 0; k < n; ++k) {
        const auto at = [&](int q) { return -half + 2 * half * q / (n - 1); };
        pts.push_back(c + Vector3d(at(i), at(j), at(k)));
      }
  return pts;
}

TEST(FalconKinematics, InverseMatchesAnIndependentOracle) {
  const FalconKinematics kin;
  for (const Vector3d& x : workspace_grid(0.04, 7)) {
    Vector3d th;
    ASSERT_TRUE(kin.inverse(x, th)) << x.transpose();
    for (int i = 0; i < 3; ++i) EXPECT_NEAR(th[i], oracle_arm_angle(kin.geometry(), x, i), 1e-9);
    EXPECT_LT(kin.residual(x, th).cwiseAbs().maxCoeff(), 1e-15);
  }
}

TEST(FalconKinematics, SymmetricPoseKnownAnswer) {
  // Equal arm angles put the effector on the z axis (three legs 120° apart); its height, found
  // by bisection on the oracle, matches forward kinematics.
  const FalconKinematics kin;
  for (double deg : {-10.0, 0.0, 16.0, 35.0, 60.0}) {
    const double th = deg * kPi / 180.0;
    double lo = 0.05, hi = 0.19;
    for (int k = 0; k < 200; ++k) {
      const double mid = 0.5 * (lo + hi);
      (oracle_arm_angle(kin.geometry(), Vector3d(0, 0, mid), 0) < th ? lo : hi) = mid;
    }
    Vector3d x = FalconKinematics::workspace_centre_m();
    const FkResult r = kin.forward(Vector3d::Constant(th), x, 50, 1e-12);
    ASSERT_TRUE(r.converged) << deg;
    EXPECT_NEAR(x.x(), 0.0, 1e-9);
    EXPECT_NEAR(x.y(), 0.0, 1e-9);
    EXPECT_NEAR(x.z(), 0.5 * (lo + hi), 1e-9) << deg;
  }
  // The workspace centre is the pose with all arms near 16°.
  Vector3d th;
  ASSERT_TRUE(kin.inverse(FalconKinematics::workspace_centre_m(), th));
  EXPECT_NEAR(th[0] * 180 / kPi, 16.19, 0.01);
}

TEST(FalconKinematics, ForwardInverseRoundTripFromColdStart) {
  const FalconKinematics kin;
  double worst = 0.0;
  for (const Vector3d& x : workspace_grid(0.045, 9)) {
    Vector3d th;
    ASSERT_TRUE(kin.inverse(x, th));
    Vector3d y = FalconKinematics::workspace_centre_m();
    const FkResult r = kin.forward(th, y, 30, 1e-10);
    ASSERT_TRUE(r.converged) << x.transpose();
    worst = std::max(worst, (y - x).norm());
  }
  EXPECT_LT(worst, 1e-9);
}

TEST(FalconKinematics, WarmStartedNewtonTracksMotionWithinThreeIterations) {
  // 1 kHz samples of fast motions (up to ~1 m/s) through the workspace: each tick starts from the
  // previous tick's solution with at most 3 Newton steps and must be better than 0.01 mm.
  const FalconKinematics kin;
  const Vector3d c = FalconKinematics::workspace_centre_m();
  Vector3d x_est = c + Vector3d(0.0, 0.035 * std::sin(1.0), 0.04 * std::sin(2.0));  // the first pose
  double worst = 0.0;
  int max_iter = 0;
  int max_conv = 0;
  for (int k = 0; k <= 20000; ++k) {
    const double t = k * 1e-3;
    const Vector3d x = c + Vector3d(0.04 * std::sin(2 * kPi * 1.3 * t), 0.035 * std::sin(2 * kPi * 2.1 * t + 1),
                                     0.04 * std::sin(2 * kPi * 3.7 * t + 2));
    Vector3d th;
    ASSERT_TRUE(kin.inverse(x, th));
    // Newton steps (one at a time, generous cap) until the estimate is within 0.01 mm.
    Vector3d y = x_est;
    int used = 0;
    while ((y - x).norm() >= 1e-5 && used < 50) {
      (void)kin.forward(th, y, 1);
      ++used;
    }
    max_iter = std::max(max_iter, used);
    worst = std::max(worst, (y - x).norm());
    // The device's tick: warm start, stopping at the tolerance; with a cap of 50 it must still
    // converge within 3 steps.
    const FkResult r = kin.forward(th, x_est, 50);
    ASSERT_TRUE(r.converged) << "tick " << k;
    max_conv = std::max(max_conv, r.iterations);
  }
  EXPECT_LT(worst, 1e-5);  // 0.01 mm
  EXPECT_LE(max_iter, 3);  // steps needed for 0.01 mm
  EXPECT_LE(max_conv, 3);  // steps needed to converge (last step < 1 µm)
}

TEST(FalconKinematics, EncoderAngleConversion) {
  const FalconKinematics kin;
  const FalconGeometry& g = kin.geometry();
  // 1280 counts per motor turn, capstan 14.25 : 110 mm.
  EXPECT_NEAR(g.rad_per_count, 2 * kPi / 1280 * 14.25 / 110, 1e-15);
  const Vector3d th = kin.angles_from_counts({0, 1000, -1000});
  EXPECT_NEAR(th[0], 35 * kPi / 180, 1e-12);
  EXPECT_NEAR(th[1] - th[0], 1000 * g.rad_per_count, 1e-12);
  for (int c : {-32768, -500, 0, 1, 777, 32767}) {
    EXPECT_EQ(kin.count_from_angle(kin.angles_from_counts({static_cast<std::int16_t>(c), 0, 0})[0]), c);
  }
  EXPECT_EQ(kin.count_from_angle(1e9), 32767);  // clamped, not wrapped
  EXPECT_EQ(kin.count_from_angle(-1e9), -32768);
}

TEST(FalconKinematics, JacobianMatchesFiniteDifferences) {
  const FalconKinematics kin;
  for (const Vector3d& x : workspace_grid(0.04, 5)) {
    Vector3d th;
    ASSERT_TRUE(kin.inverse(x, th));
    Eigen::Matrix3d j;
    ASSERT_TRUE(kin.jacobian(x, th, j));
    const double h = 1e-6;
    for (int col = 0; col < 3; ++col) {
      Vector3d tp = th, tm = th;
      tp[col] += h;
      tm[col] -= h;
      Vector3d xp = x, xm = x;
      ASSERT_TRUE(kin.forward(tp, xp, 20, 1e-13).converged);
      ASSERT_TRUE(kin.forward(tm, xm, 20, 1e-13).converged);
      const Vector3d fd = (xp - xm) / (2 * h);
      EXPECT_LT((j.col(col) - fd).norm(), 1e-6 * std::max(1.0, fd.norm()) + 1e-7) << x.transpose() << " col " << col;
    }
  }
}

TEST(FalconKinematics, TorquesDoTheSameWorkAsTheForce) {
  // Virtual work: τ·dθ = F·dx for any small motion.
  const FalconKinematics kin;
  const Vector3d x = FalconKinematics::workspace_centre_m() + Vector3d(0.01, -0.02, 0.015);
  Vector3d th;
  ASSERT_TRUE(kin.inverse(x, th));
  const Vector3d f(1.5, -2.0, 3.0);
  const Vector3d tau = kin.torques_for_force(x, th, f);
  const Vector3d dth(1e-6, -2e-6, 0.5e-6);
  Vector3d x2 = x;
  ASSERT_TRUE(kin.forward(th + dth, x2, 20, 1e-14).converged);
  EXPECT_NEAR(tau.dot(dth), f.dot(x2 - x), 1e-10);
  // And the emulator's inverse map gives the force back from the rounded commands.
  const MotorCommands m = kin.commands_for_force(x, th, f, 32767);
  EXPECT_FALSE(m.saturated);
  EXPECT_LT((kin.force_for_commands(x, th, m.counts) - f).norm(), 0.01);
}

TEST(FalconKinematics, SaturationKeepsDirectionAndNeverWraps) {
  const FalconKinematics kin;
  const Vector3d x = FalconKinematics::workspace_centre_m() + Vector3d(-0.02, 0.01, 0.02);
  Vector3d th;
  ASSERT_TRUE(kin.inverse(x, th));
  const Vector3d dir = Vector3d(0.3, -0.5, 0.8).normalized();
  const MotorCommands small = kin.commands_for_force(x, th, dir * 1.0, 32767);
  ASSERT_FALSE(small.saturated);
  for (double mag : {200.0, 1e3, 1e6, 1e12}) {
    for (std::int16_t limit : {std::int16_t{1000}, std::int16_t{32767}}) {
      const MotorCommands m = kin.commands_for_force(x, th, dir * mag, limit);
      EXPECT_TRUE(m.saturated);
      int peak = 0;
      for (int i = 0; i < 3; ++i) {
        const auto k = static_cast<std::size_t>(i);
        peak = std::max(peak, std::abs(static_cast<int>(m.counts[k])));
        // Same signs as the unsaturated command (no wrap-around).
        EXPECT_EQ(m.counts[k] > 0, small.counts[k] > 0);
      }
      EXPECT_EQ(peak, limit);
      // Same direction: the force the commands produce is parallel to dir.
      const Vector3d f = kin.force_for_commands(x, th, m.counts);
      EXPECT_GT(f.normalized().dot(dir), 0.9999) << mag << " " << limit;
    }
  }
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const MotorCommands z = kin.commands_for_force(x, th, Vector3d(nan, 0, 0), 32767);
  EXPECT_EQ(z.counts, (std::array<std::int16_t, 3>{0, 0, 0}));
}

TEST(FalconKinematics, OutOfReachIsRefused) {
  const FalconKinematics kin;
  Vector3d th(1, 2, 3);
  EXPECT_FALSE(kin.inverse(Vector3d(0, 0, 0.5), th));
  EXPECT_EQ(th, Vector3d(1, 2, 3));
}

TEST(FalconKinematics, DeviceFrameIsARotationAboutTheCentre) {
  const DeviceFrame f;
  EXPECT_NEAR(f.rotation.determinant(), 1.0, 1e-15);
  const Vector3d p(0.01, 0.02, 0.03);
  EXPECT_LT((f.to_device(f.to_falcon(p)) - p).norm(), 1e-15);
  EXPECT_LT(f.to_device(FalconKinematics::workspace_centre_m()).norm(), 1e-15);
  // Device z (up) is Falcon y.
  EXPECT_LT((f.vector_to_falcon(Vector3d::UnitZ()) - Vector3d::UnitY()).norm(), 1e-15);
}

}  // namespace
}  // namespace hc::falcon
