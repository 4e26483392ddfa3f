#pragma once
/// @file workspace_map.hpp
/// The map between the haptic device's workspace (a box in metres, device frame) and a region
/// of the scene (grid frame, metres): uniform scale, rotation about the view axis z, translation.
/// Paper Sec. 4.1 (rendering at different scales; region of interest chosen at run time).

#include <Eigen/Core>

namespace hc::haptics {

/// X_grid = origin + scale · R_z(θ) · X_device.
/// Device frame: the device's own axes with z towards the user/viewer, like the grid frame, so
/// that pressing "into" the device (−z) presses into the surface.
/// Forces: the proxy runs in the grid frame, so the servo loop renders with the grid-frame
/// stiffness k_grid = k_device / scale (and damping b_grid = b_device / scale): a displacement
/// of d device metres is scale·d grid metres and must still give k_device·d newtons. Forces are
/// rotated back with R_zᵀ and never scaled.
/// Plain value type; setting a new map at run time is a servo command (see shared_state.hpp).
struct WorkspaceMap {
  Eigen::Vector3d origin_m = Eigen::Vector3d::Zero();  ///< grid point at the device origin [m]
  double scale = 1.0;         ///< grid metres per device metre [-], > 0
  double rotation_rad = 0.0;  ///< rotation about +z from device to grid axes [rad]

  /// True when every field is finite and scale > 0. Real-time: yes.
  bool valid() const noexcept;

  /// Device point [m] → grid point [m]. Real-time: yes.
  Eigen::Vector3d to_grid(const Eigen::Vector3d& device_m) const noexcept;
  /// Grid point [m] → device point [m] (inverse of to_grid). Real-time: yes.
  Eigen::Vector3d to_device(const Eigen::Vector3d& grid_m) const noexcept;
  /// A grid-frame force [N] expressed in device axes: F_device = R_z(θ)ᵀ·F_grid (rotation
  /// only; origin and scale do not enter, forces are never scaled). Real-time: yes.
  Eigen::Vector3d force_to_device(const Eigen::Vector3d& force_grid_n) const noexcept;
  /// Inverse of force_to_device: a device-axes force [N] (e.g. the one sent to the device)
  /// expressed in grid axes, F_grid = R_z(θ)·F_device, θ = rotation_rad. Rotation only, like
  /// force_to_device: |F| and F_z are unchanged, origin and scale do not enter. A device-axes
  /// force points along the device displacement d that to_grid maps to the grid displacement
  /// scale·R_z(θ)·d, so F_grid is parallel to that displacement, and the power F·v is the same
  /// in both frames once the grid velocity is divided by the scale. Real-time: yes.
  Eigen::Vector3d force_to_grid(const Eigen::Vector3d& force_device_n) const noexcept;
  /// Device stiffness [N/m] → the grid-frame stiffness giving the same force per device metre.
  double stiffness_to_grid(double stiffness_device_n_per_m) const noexcept {
    return stiffness_device_n_per_m / scale;
  }

  /// The map that fits the grid rectangle [x_min, x_max] × [y_min, y_max] (rotated by
  /// rotation_rad) inside the device box of half extents `device_half_extent_m` (x, y used),
  /// centred, and places device z = 0 at grid height z_centre_m.
  /// @throws hc::ConfigError for an empty or non-finite rectangle or non-positive extents.
  /// Real-time: no.
  static WorkspaceMap fit(const Eigen::Vector3d& device_half_extent_m, double x_min_m,
                          double x_max_m, double y_min_m, double y_max_m, double z_centre_m,
                          double rotation_rad = 0.0);
};

}  // namespace hc::haptics
