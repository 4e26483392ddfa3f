// Stages 2 and 3 tests: units and recentring under georeferenced offsets, rotation helpers
// against hand-computed matrices, and the view transform.

#include "hc/common/error.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/transform.hpp"
#include "test_paths.hpp"
#include "cloud_fixtures.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <numbers>

namespace hp = hc::pipeline;

namespace {

using hc::test::cloud_of;

Eigen::Matrix3d rx(double deg) {
  const double c = std::cos(deg * std::numbers::pi / 180), s = std::sin(deg * std::numbers::pi / 180);
  Eigen::Matrix3d m;
  m << 1, 0, 0, 0, c, -s, 0, s, c;
  return m;
}
Eigen::Matrix3d ry(double deg) {
  const double c = std::cos(deg * std::numbers::pi / 180), s = std::sin(deg * std::numbers::pi / 180);
  Eigen::Matrix3d m;
  m << c, 0, s, 0, 1, 0, -s, 0, c;
  return m;
}
Eigen::Matrix3d rz(double deg) {
  const double c = std::cos(deg * std::numbers::pi / 180), s = std::sin(deg * std::numbers::pi / 180);
  Eigen::Matrix3d m;
  m << c, -s, 0, s, c, 0, 0, 0, 1;
  return m;
}

double max_abs_diff(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) { return (a - b).cwiseAbs().maxCoeff(); }

}  // namespace

// A real scan moved by a georeferenced offset recentres to the same coordinates, to < 1 µm,
// both in memory and after a round trip through a double-precision PLY file.
TEST(Recentre, GeoreferencedOffsetGivesTheSameCoordinates) {
  const hp::Cloud scan = hp::load_cloud(hc::test::scan_path("bunny/bun000.ply")).value;
  const Eigen::Vector3d shift(4.5e5, 5.2e6, 310.0);
  hp::Cloud shifted = scan;
  shifted.xyz.colwise() += shift;

  Eigen::Vector3d off0, off1;
  const auto near = hp::to_metres_and_recentre(scan, 1.0, &off0);
  const auto far = hp::to_metres_and_recentre(shifted, 1.0, &off1);
  EXPECT_LT(max_abs_diff(near.value.xyz, far.value.xyz), 1e-6);
  EXPECT_LT((off1 - off0 - shift).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_EQ(far.report.count_in, scan.size());
  EXPECT_EQ(far.report.count_out, scan.size());

  // Through a file with double properties (the exact decimal digits survive the read).
  const auto dir = hc::test::temp_dir("geo");
  {
    std::ofstream out(dir / "geo.ply");
    out << "ply\nformat ascii 1.0\nelement vertex " << shifted.size()
        << "\nproperty double x\nproperty double y\nproperty double z\nend_header\n";
    char buf[128];
    for (Eigen::Index i = 0; i < shifted.xyz.cols(); ++i) {
      std::snprintf(buf, sizeof buf, "%.17g %.17g %.17g\n", shifted.xyz(0, i), shifted.xyz(1, i), shifted.xyz(2, i));
      out << buf;
    }
  }
  const hp::Cloud loaded = hp::load_cloud(dir / "geo.ply").value;
  EXPECT_EQ(loaded.xyz, shifted.xyz);
  const auto far2 = hp::to_metres_and_recentre(loaded, 1.0, nullptr);
  EXPECT_LT(max_abs_diff(near.value.xyz, far2.value.xyz), 1e-6);
}

TEST(Recentre, ScalesUnitsAndCentresTheBoundingBox) {
  const hp::Cloud mm = cloud_of({{1000, 2000, 3000}, {3000, 2000, 3000}, {1000, 4000, 5000}});
  Eigen::Vector3d off;
  const auto r = hp::to_metres_and_recentre(mm, 0.001, &off);
  EXPECT_TRUE(off.isApprox(Eigen::Vector3d(2, 3, 4)));
  EXPECT_TRUE(r.value.xyz.col(0).isApprox(Eigen::Vector3d(-1, -1, -1)));
  EXPECT_TRUE(r.value.xyz.col(1).isApprox(Eigen::Vector3d(1, -1, -1)));
  EXPECT_TRUE(r.value.xyz.col(2).isApprox(Eigen::Vector3d(-1, 1, 1)));
  EXPECT_EQ(r.report.stage, "recentre");
  EXPECT_GE(r.report.seconds, 0.0);
}

TEST(Recentre, IgnoresNonFinitePointsForTheBoxAndRejectsCloudsWithoutFinitePoints) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const auto r = hp::to_metres_and_recentre(cloud_of({{0, 0, 0}, {nan, 5, 5}, {2, 2, 2}}), 1.0, nullptr);
  EXPECT_EQ(r.value.xyz.col(2), Eigen::Vector3d(1, 1, 1));
  EXPECT_TRUE(std::isnan(r.value.xyz(0, 1)));
  EXPECT_THROW(hp::to_metres_and_recentre(cloud_of({{nan, nan, nan}}), 1.0, nullptr), hc::InputError);
  EXPECT_THROW(hp::to_metres_and_recentre(hp::Cloud{}, 1.0, nullptr), hc::InputError);
  EXPECT_THROW(hp::to_metres_and_recentre(cloud_of({{0, 0, 0}}), 0.0, nullptr), hc::ConfigError);
}

TEST(Rotation, AxisAngleMatchesHandComputedMatrices) {
  Eigen::Matrix3d z90;
  z90 << 0, -1, 0, 1, 0, 0, 0, 0, 1;
  EXPECT_TRUE(hp::rotation_from_axis_angle({0, 0, 5}, 90).toRotationMatrix().isApprox(z90, 1e-12));
  // 120° about (1, 1, 1) permutes the axes: x -> y -> z -> x.
  Eigen::Matrix3d perm;
  perm << 0, 0, 1, 1, 0, 0, 0, 1, 0;
  EXPECT_TRUE(hp::rotation_from_axis_angle({1, 1, 1}, 120).toRotationMatrix().isApprox(perm, 1e-12));
  EXPECT_TRUE(hp::rotation_from_axis_angle({1, 0, 0}, -30).toRotationMatrix().isApprox(rx(-30), 1e-12));
  EXPECT_THROW(hp::rotation_from_axis_angle({0, 0, 0}, 10), hc::ConfigError);
}

// Euler order semantics: angles_deg[i] turns about axis order[i]; R = R_order[0] · R_order[1] ·
// R_order[2]. Read intrinsically: first about the fixed first axis, then about the new second
// axis, then about the newest third axis (equivalently, extrinsic in reverse order).
TEST(Rotation, EulerOrderSemantics) {
  const Eigen::Vector3d a(30, -45, 60);
  EXPECT_TRUE(hp::rotation_from_euler(a, "xyz").toRotationMatrix().isApprox(rx(30) * ry(-45) * rz(60), 1e-12));
  EXPECT_TRUE(hp::rotation_from_euler(a, "zyx").toRotationMatrix().isApprox(rz(30) * ry(-45) * rx(60), 1e-12));
  EXPECT_TRUE(hp::rotation_from_euler(a, "yzx").toRotationMatrix().isApprox(ry(30) * rz(-45) * rx(60), 1e-12));
  // Hand-computed: "xyz" with (90, 0, 90) is Rx(90)·Rz(90), which maps x to z, y to -x, z to -y.
  Eigen::Matrix3d m;
  m << 0, -1, 0, 0, 0, -1, 1, 0, 0;
  EXPECT_TRUE(hp::rotation_from_euler({90, 0, 90}, "xyz").toRotationMatrix().isApprox(m, 1e-12));
  for (const char* bad : {"xxy", "xy", "abc", "xyzz", "XYZ"}) {
    EXPECT_THROW(hp::rotation_from_euler(a, bad), hc::ConfigError) << bad;
  }
}

TEST(Rotation, QuaternionIsWxyzAndNormalised) {
  const double h = std::sqrt(0.5);
  EXPECT_TRUE(hp::rotation_from_quaternion(h, 0, 0, h).toRotationMatrix().isApprox(rz(90), 1e-12));
  EXPECT_TRUE(hp::rotation_from_quaternion(2, 0, 0, 0).toRotationMatrix().isApprox(Eigen::Matrix3d::Identity()));
  EXPECT_TRUE(hp::rotation_from_quaternion(0, 3, 0, 0).toRotationMatrix().isApprox(rx(180), 1e-12));
  EXPECT_THROW(hp::rotation_from_quaternion(0, 0, 0, 0), hc::ConfigError);
}

TEST(ViewTransform, RotatesThenScalesThenTranslates) {
  hp::ViewTransform v;
  v.rotation = hp::rotation_from_axis_angle({0, 0, 1}, 90);
  v.scale = 2.0;
  v.translation_m = {0.5, 0, -1};
  const Eigen::Vector3d p(1, 0, 3);
  EXPECT_TRUE((v.matrix() * p).isApprox(Eigen::Vector3d(0.5, 2, 5), 1e-12));
  const auto r = hp::apply_view_transform(cloud_of({{1, 0, 3}, {0, 1, 0}}), v);
  EXPECT_TRUE(r.value.xyz.col(0).isApprox(Eigen::Vector3d(0.5, 2, 5), 1e-12));
  EXPECT_TRUE(r.value.xyz.col(1).isApprox(Eigen::Vector3d(-1.5, 0, -1), 1e-12));
  EXPECT_EQ(r.report.count_in, 2u);
  EXPECT_EQ(r.report.count_out, 2u);
  v.scale = 0.0;
  EXPECT_THROW(hp::apply_view_transform(cloud_of({{1, 0, 3}}), v), hc::ConfigError);
}

TEST(ViewTransform, TheIdentityLeavesEveryPointAsItIsAndATinyTurnDoesNot) {
  const hp::Cloud in = cloud_of({{1.25, -0.0, 3e-300}, {0.1, std::numeric_limits<double>::infinity(), 2}});
  hp::ViewTransform v;
  v.rotation = hp::rotation_from_axis_angle({0, 1, 0}, 0);  // the Buddha config's front view
  const auto r = hp::apply_view_transform(in, v);
  // Bit for bit, the −0 and the point beside an infinity included.
  EXPECT_EQ(std::memcmp(r.value.xyz.data(), in.xyz.data(), sizeof(double) * 6), 0);
  v.rotation = hp::rotation_from_axis_angle({0, 0, 1}, 1e-3);
  const auto t = hp::apply_view_transform(in, v);
  EXPECT_NE(t.value.xyz(1, 0), 0.0);  // x turns into y: the transform ran
  EXPECT_NEAR(t.value.xyz(1, 0), 1.25 * std::sin(1e-3 * std::acos(-1.0) / 180.0), 1e-18);
}
