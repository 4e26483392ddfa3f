#include "hc/haptics/workspace_map.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace hc::haptics {

bool WorkspaceMap::valid() const noexcept {
  return origin_m.allFinite() && std::isfinite(scale) && scale > 0.0 && std::isfinite(rotation_rad);
}

Eigen::Vector3d WorkspaceMap::to_grid(const Eigen::Vector3d& d) const noexcept {
  const double c = std::cos(rotation_rad), s = std::sin(rotation_rad);
  return origin_m + scale * Eigen::Vector3d(c * d.x() - s * d.y(), s * d.x() + c * d.y(), d.z());
}

Eigen::Vector3d WorkspaceMap::to_device(const Eigen::Vector3d& g) const noexcept {
  const double c = std::cos(rotation_rad), s = std::sin(rotation_rad);
  const Eigen::Vector3d v = (g - origin_m) / scale;
  return Eigen::Vector3d(c * v.x() + s * v.y(), -s * v.x() + c * v.y(), v.z());
}

Eigen::Vector3d WorkspaceMap::force_to_device(const Eigen::Vector3d& f) const noexcept {
  const double c = std::cos(rotation_rad), s = std::sin(rotation_rad);
  return Eigen::Vector3d(c * f.x() + s * f.y(), -s * f.x() + c * f.y(), f.z());
}

Eigen::Vector3d WorkspaceMap::force_to_grid(const Eigen::Vector3d& f) const noexcept {
  const double c = std::cos(rotation_rad), s = std::sin(rotation_rad);
  return Eigen::Vector3d(c * f.x() - s * f.y(), s * f.x() + c * f.y(), f.z());
}

WorkspaceMap WorkspaceMap::fit(const Eigen::Vector3d& half, double x_min, double x_max,
                               double y_min, double y_max, double z_centre, double rotation) {
  const bool ok = half.allFinite() && half.x() > 0 && half.y() > 0 && std::isfinite(x_min) &&
                  std::isfinite(x_max) && std::isfinite(y_min) && std::isfinite(y_max) &&
                  x_max > x_min && y_max > y_min && std::isfinite(z_centre) &&
                  std::isfinite(rotation);
  if (!ok) {
    std::ostringstream s;
    s << "workspace map: cannot fit grid region [" << x_min << ", " << x_max << "] x [" << y_min
      << ", " << y_max << "] m at z " << z_centre << " into a device box of half extents ("
      << half.transpose() << ") m; expected a non-empty finite region and positive extents";
    throw ConfigError(s.str());
  }
  // Half extents of the region seen in device axes (rotate the rectangle back by −θ).
  const double hx = 0.5 * (x_max - x_min), hy = 0.5 * (y_max - y_min);
  const double c = std::fabs(std::cos(rotation)), s = std::fabs(std::sin(rotation));
  const double dev_hx = c * hx + s * hy;
  const double dev_hy = s * hx + c * hy;
  WorkspaceMap m;
  m.scale = std::max(dev_hx / half.x(), dev_hy / half.y());
  m.rotation_rad = rotation;
  m.origin_m = Eigen::Vector3d(0.5 * (x_min + x_max), 0.5 * (y_min + y_max), z_centre);
  return m;
}

}  // namespace hc::haptics
