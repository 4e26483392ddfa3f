#include "hc/haptics/workspace_map.hpp"

#include "hc/common/error.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <numbers>

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
