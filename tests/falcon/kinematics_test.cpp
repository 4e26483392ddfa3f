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

// The published Falcon geometry, as literal numbers (not the library's FalconGeometry), so that a
// wrong constant in the library fails the tests below. Source: libnifalcon (BSD, Kyle Machulis,
// Kevin Ouellet), include/falcon/core/FalconGeometry.h, values after the 2009 commit "Flipped r/s
// values for geometry based on advice from Steven Martin"; symbols after R. E. Stamper, "A
// three degree of freedom parallel manipulator with only translational degrees of freedom",
// PhD thesis, Univ. of Maryland, 1997 (diagram p. 30). Metres and radians.
struct Published {
  static constexpr double a = 0.060;     // leg base to knee (upper arm)
  static constexpr double b = 0.1025;    // shin parallelogram side
  static constexpr double c = 0.01443;   // shin joint to effector centre, u component
  static constexpr double d = 0.01125;   // shin to effector joint
  static constexpr double e = 0.01125;   // knee to shin joint (e = d)
  static constexpr double f = -0.025;    // shin joint to effector centre, v component
  static constexpr double r = 0.0400;    // frame origin to leg base, u component
  static constexpr double s = -0.02309;  // frame origin to leg base, v component
  // Leg angles: 90°, −30°, −150°, each plus the 15° offset of the axes from the desk plane.
  static constexpr double phi[3] = {kPi / 2 + kPi / 12, -kPi / 6 + kPi / 12, -5 * kPi / 6 + kPi / 12};
  static constexpr double theta_at_count_zero = 35 * kPi / 180;  // THETA_OFFSET_ANGLE
};

// Independent oracle for one leg's arm angle: the tangent-half-angle quadratic of the leg equation
// (a different derivation from the library's atan2/acos form), on the published numbers above.
double oracle_arm_angle(const Vector3d& x, int leg) {
  using P = Published;
  const double phi = P::phi[leg];
  const double u = std::cos(phi) * x.x() + std::sin(phi) * x.y() - P::r;
  const double v = -std::sin(phi) * x.x() + std::cos(phi) * x.y() - P::s;
  const double w = x.z();
  const double len = P::d + P::e + P::b * std::sin(std::acos((v + P::f) / P::b));
  // (u + c − a cos θ)² + (w − a sin θ)² = L², with t = tan(θ/2).
  const double k = (u + P::c) * (u + P::c) + w * w + P::a * P::a - len * len;
  const double q0 = k - 2 * P::a * (u + P::c);
  const double q1 = -4 * P::a * w;
  const double q2 = k + 2 * P::a * (u + P::c);
  const double t = (-q1 - std::sqrt(q1 * q1 - 4 * q0 * q2)) / (2 * q2);
  return 2 * std::atan(t);
}

TEST(FalconKinematics, DefaultGeometryIsThePublishedOne) {
  const FalconGeometry g = FalconKinematics().geometry();
  EXPECT_EQ(g.a_m, Published::a);
  EXPECT_EQ(g.b_m, Published::b);
  EXPECT_EQ(g.c_m, Published::c);
  EXPECT_EQ(g.d_m, Published::d);
  EXPECT_EQ(g.e_m, Published::e);
  EXPECT_EQ(g.f_m, Published::f);
  EXPECT_EQ(g.r_m, Published::r);
  EXPECT_EQ(g.s_m, Published::s);
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(g.leg_angle_rad[static_cast<std::size_t>(i)], Published::phi[i], 1e-12) << i;
  EXPECT_NEAR(g.angle_at_zero_count_rad, Published::theta_at_count_zero, 1e-15);
}

TEST(FalconKinematics, HandComputedPoses) {
  // On the z axis (x = y = 0) every leg sees u = −r = −0.04, v = −s = 0.02309, w = z, so
  //   L = d + e + √(b² − (v + f)²) = 0.0225 + √(0.01050625 − 0.00191²)
  //     = 0.0225 + √0.0105026019 = 0.0225 + 0.1024822 = 0.1249822 m,   L² = 0.01562055 m²,
  //   u + c = −0.04 + 0.01443 = −0.02557 m.
  // Pose 1, all arms at θ = 0: (u + c − a)² + z² = L² gives
  //   z = √(0.01562055 − 0.08557²) = √(0.01562055 − 0.00732222) = √0.00829833 = 0.0910951 m.
  const FalconKinematics kin;
  Vector3d x = FalconKinematics::workspace_centre_m();
  const FkResult r = kin.forward(Vector3d::Zero(), x, 50, 1e-12);
  ASSERT_TRUE(r.converged);
  EXPECT_NEAR(x.x(), 0.0, 1e-9);
  EXPECT_NEAR(x.y(), 0.0, 1e-9);
  EXPECT_NEAR(x.z(), 0.0910951, 2e-7);
  Vector3d th;
  ASSERT_TRUE(kin.inverse(Vector3d(0, 0, 0.0910951), th));
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(th[i], 0.0, 1e-5) << i;
  // Pose 2, the workspace centre z = 0.11 m: expanding (−0.02557 − 0.06 cos θ)² + (0.11 − 0.06 sin θ)²
  // = L² gives 0.01635382 + 0.0030684 cos θ − 0.0132 sin θ = 0.01562055, i.e.
  //   0.0132 sin θ − 0.0030684 cos θ = 0.00073327.
  // With R = √(0.0132² + 0.0030684²) = 0.0135519 and δ = atan(0.0030684 / 0.0132) = 13.0863°:
  //   sin(θ − δ) = 0.00073327 / 0.0135519 = 0.054108,  θ − δ = 3.1017°,  θ = 16.188°
  // (the other root, θ − δ = 176.9°, is the knee-in branch).
  ASSERT_TRUE(kin.inverse(Vector3d(0, 0, 0.11), th));
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(th[i] * 180 / kPi, 16.188, 0.002) << i;
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
    for (int i = 0; i < 3; ++i) EXPECT_NEAR(th[i], oracle_arm_angle(x, i), 1e-9);
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
      (oracle_arm_angle(Vector3d(0, 0, mid), 0) < th ? lo : hi) = mid;
    }
    Vector3d x = FalconKinematics::workspace_centre_m();
    const FkResult r = kin.forward(Vector3d::Constant(th), x, 50, 1e-12);
    ASSERT_TRUE(r.converged) << deg;
    EXPECT_NEAR(x.x(), 0.0, 1e-9);
    EXPECT_NEAR(x.y(), 0.0, 1e-9);
    EXPECT_NEAR(x.z(), 0.5 * (lo + hi), 1e-9) << deg;
  }
  // The workspace centre's arm angle (16.188°) is derived by hand in HandComputedPoses.
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
