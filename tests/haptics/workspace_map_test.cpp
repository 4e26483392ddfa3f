#include "hc/haptics/workspace_map.hpp"

#include "hc/common/error.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <numbers>
#include <random>

namespace hc::haptics {
namespace {

using Eigen::Vector3d;

TEST(WorkspaceMap, RoundTripAndKnownAnswers) {
  WorkspaceMap m;
  m.origin_m = Vector3d(0.1, -0.2, 0.03);
  m.scale = 2.0;
  m.rotation_rad = std::numbers::pi / 2;
  // Device +x becomes grid +y (90° about z), scaled by 2.
  const Vector3d g = m.to_grid(Vector3d(0.01, 0.0, 0.005));
  EXPECT_NEAR(g.x(), 0.1, 1e-12);
  EXPECT_NEAR(g.y(), -0.2 + 0.02, 1e-12);
  EXPECT_NEAR(g.z(), 0.03 + 0.01, 1e-12);
  for (const Vector3d& d : {Vector3d(0, 0, 0), Vector3d(0.03, -0.02, 0.01), Vector3d(-0.05, 0.05, -0.05)}) {
    EXPECT_TRUE(m.to_device(m.to_grid(d)).isApprox(d, 1e-12)) << d.transpose();
  }
  // Forces rotate back, never scale; z unchanged.
  const Vector3d f = m.force_to_device(Vector3d(0.0, 1.0, 2.0));
  EXPECT_NEAR(f.x(), 1.0, 1e-12);
  EXPECT_NEAR(f.y(), 0.0, 1e-12);
  EXPECT_NEAR(f.z(), 2.0, 1e-12);
  EXPECT_DOUBLE_EQ(m.stiffness_to_grid(1000.0), 500.0);
}

TEST(WorkspaceMap, ForceToGridKnownAnswers) {
  WorkspaceMap m;
  m.origin_m = Vector3d(0.4, -0.1, 0.02);  // origin and scale must not enter
  m.scale = 3.0;
  m.rotation_rad = std::numbers::pi / 6;  // 30°: cos = √3/2, sin = 1/2 (by hand)
  const Vector3d g = m.force_to_grid(Vector3d(1.0, 0.0, 2.0));
  EXPECT_NEAR(g.x(), std::sqrt(3.0) / 2, 1e-15);
  EXPECT_NEAR(g.y(), 0.5, 1e-15);
  EXPECT_EQ(g.z(), 2.0);
  const Vector3d h = m.force_to_grid(Vector3d(0.0, 4.0, -1.0));  // device +y → grid (−sin, cos)
  EXPECT_NEAR(h.x(), -2.0, 1e-15);
  EXPECT_NEAR(h.y(), 2.0 * std::sqrt(3.0), 1e-15);
  EXPECT_EQ(h.z(), -1.0);
  m.rotation_rad = std::numbers::pi / 2;  // device +x is grid +y (as for positions above)
  EXPECT_TRUE(m.force_to_grid(Vector3d(1.0, 0.0, 0.0)).isApprox(Vector3d(0.0, 1.0, 0.0), 1e-15));
  m.rotation_rad = 0.0;
  EXPECT_EQ(m.force_to_grid(Vector3d(0.3, -0.7, 0.1)), Vector3d(0.3, -0.7, 0.1));  // identity
}

TEST(WorkspaceMap, ForceToGridInvertsForceToDeviceAndFollowsThePositionMap) {
  std::mt19937_64 rng(20261121);
  std::uniform_real_distribution<double> angle(-4 * std::numbers::pi, 4 * std::numbers::pi);
  std::uniform_real_distribution<double> log_scale(std::log(1e-3), std::log(1e3));
  std::uniform_real_distribution<double> u(-5.0, 5.0);
  for (int k = 0; k < 1000; ++k) {
    WorkspaceMap m;
    m.rotation_rad = angle(rng);
    m.scale = std::exp(log_scale(rng));
    m.origin_m = Vector3d(u(rng), u(rng), u(rng));
    const Vector3d f_dev(u(rng), u(rng), u(rng));
    const Vector3d f_grid = m.force_to_grid(f_dev);
    // Round trips both ways.
    EXPECT_TRUE(m.force_to_device(f_grid).isApprox(f_dev, 1e-12)) << k;
    EXPECT_TRUE(m.force_to_grid(m.force_to_device(f_dev)).isApprox(f_dev, 1e-12)) << k;
    // A rotation about z: magnitude and z kept.
    EXPECT_NEAR(f_grid.norm(), f_dev.norm(), 1e-12 * f_dev.norm()) << k;
    EXPECT_NEAR(f_grid.z(), f_dev.z(), 1e-15) << k;
    // Oracle from the position map: the device displacement d = F·(1 m/N) along the force becomes
    // the grid displacement to_grid(d) − to_grid(0) = scale·R·d, so the grid force is that over
    // the scale.
    const Vector3d disp = (m.to_grid(f_dev) - m.to_grid(Vector3d::Zero())) / m.scale;
    EXPECT_TRUE(f_grid.isApprox(disp, 1e-9)) << k << ": " << f_grid.transpose() << " vs " << disp.transpose();
    // Same power in both frames: F_device·v_device = F_grid·v_grid / scale.
    const Vector3d v_dev(u(rng), u(rng), u(rng));
    const Vector3d v_grid = m.to_grid(v_dev) - m.to_grid(Vector3d::Zero());
    EXPECT_NEAR(f_dev.dot(v_dev), f_grid.dot(v_grid) / m.scale, 1e-9 * (1.0 + f_dev.norm() * v_dev.norm())) << k;
  }
}

TEST(WorkspaceMap, ForceFeltPerDeviceMetreIsTheDeviceStiffness) {
  // A grid displacement of scale·d for a device displacement d must give k_device·d newtons.
  WorkspaceMap m;
  m.scale = 0.25;  // zoomed in: 1 device metre = 0.25 grid metres
  const double k_dev = 800.0;
  const double d_dev = 0.004;
  const Vector3d grid_disp = m.to_grid(Vector3d(0, 0, -d_dev)) - m.to_grid(Vector3d::Zero());
  const double f = m.stiffness_to_grid(k_dev) * grid_disp.norm();
  EXPECT_NEAR(f, k_dev * d_dev, 1e-12);
}

TEST(WorkspaceMap, FitCentresAndScalesTheRegion) {
  const Vector3d half(0.05, 0.05, 0.05);
  const WorkspaceMap m = WorkspaceMap::fit(half, -0.1, 0.3, 0.0, 0.1, 0.02);
  EXPECT_NEAR(m.scale, 0.2 / 0.05, 1e-12);  // the long side (0.4 m) fills the box (0.1 m)
  EXPECT_TRUE(m.to_grid(Vector3d::Zero()).isApprox(Vector3d(0.1, 0.05, 0.02)));
  EXPECT_NEAR(m.to_grid(Vector3d(0.05, 0, 0)).x(), 0.3, 1e-12);
  const WorkspaceMap r = WorkspaceMap::fit(half, -0.1, 0.3, 0.0, 0.1, 0.0, std::numbers::pi / 2);
  EXPECT_NEAR(r.to_grid(Vector3d(0, 0.05, 0)).x(), 0.1 - 0.2, 1e-12);  // device y spans grid x
  EXPECT_THROW(WorkspaceMap::fit(half, 0.1, 0.1, 0.0, 0.1, 0.0), ConfigError);
  EXPECT_THROW(WorkspaceMap::fit(Vector3d(0, 1, 1), 0.0, 0.1, 0.0, 0.1, 0.0), ConfigError);
}

TEST(WorkspaceMap, Validity) {
  WorkspaceMap m;
  EXPECT_TRUE(m.valid());
  m.scale = 0.0;
  EXPECT_FALSE(m.valid());
  m.scale = 1.0;
  m.rotation_rad = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(m.valid());
}

}  // namespace
}  // namespace hc::haptics
