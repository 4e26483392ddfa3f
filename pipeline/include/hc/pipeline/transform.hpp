#pragma once
/// @file transform.hpp
/// Stages 2 and 3: units and recentring (double precision), then the user's orientation,
/// translation and uniform scale, giving the grid frame (the grid looks along −z).

#include "hc/pipeline/cloud.hpp"

#include <Eigen/Geometry>

#include <optional>

namespace hc::pipeline {

/// Default for `input.max_extent_m` [m]: the largest scan extent accepted (a whole site fits).
inline constexpr double kDefaultMaxExtentM = 10'000.0;

/// Scales a cloud from file units to metres and subtracts the centre of its bounding box,
/// all in double precision, so a scan with georeferenced offsets (10^5 to 10^6 m) gives the
/// same recentred coordinates, to well under 1 µm, as the same scan near the origin.
/// @param metres_per_unit  1, 0.01 or 0.001 for m, cm, mm (see hc::metres_per_unit)
/// @param offset_m         out: the subtracted centre [m], in the file frame scaled to metres
///                         (may be null). The box ignores non-finite points (they stay NaN).
/// @param max_extent_m     largest accepted bounding-box side after unit conversion [m]
///                         (`input.max_extent_m`, default 10 km): a finite but absurd
///                         coordinate (say z = 3e38) is refused here instead of overflowing
///                         single-precision arithmetic in later stages.
/// @throws hc::InputError if the cloud is empty, has no finite point, or its extent along an
///         axis exceeds max_extent_m (the message gives the axis, the extent and the key);
///         hc::ConfigError if metres_per_unit or max_extent_m is not finite and > 0.
StageResult<Cloud> to_metres_and_recentre(Cloud cloud, double metres_per_unit,
                                          Eigen::Vector3d* offset_m,
                                          double max_extent_m = kDefaultMaxExtentM);

/// The user's view: rotation (built by one of the helpers below), then uniform scale, then
/// translation [m]: p_grid = scale · R · p + t.
struct ViewTransform {
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
  Eigen::Vector3d translation_m = Eigen::Vector3d::Zero();
  double scale = 1.0;  ///< [-], > 0

  Eigen::Affine3d matrix() const;
  /// True when matrix() is exactly the identity (linear part I, translation 0: no turn, scale 1,
  /// no move), so that applying it would change no coordinate; apply_view_transform then makes
  /// no pass over the points, and the tiled run's plan takes the grid's box from the file's.
  bool is_identity() const;
};

/// Rotation of angle_deg about `axis` (any non-zero length). @throws hc::ConfigError on a zero axis.
Eigen::Quaterniond rotation_from_axis_angle(const Eigen::Vector3d& axis, double angle_deg);
/// Intrinsic Euler angles in degrees, applied in the order of `order` (a permutation such as
/// "xyz" or "zyx": R = R_a(first)·R_b(second)·R_c(third)). angles_deg[i] turns about axis
/// order[i]: first about the fixed axis order[0], then about the once-turned order[1], then about
/// the twice-turned order[2]; the same R read extrinsically applies the turns in reverse order
/// about fixed axes. @throws hc::ConfigError on a bad order (lower-case letters only).
Eigen::Quaterniond rotation_from_euler(const Eigen::Vector3d& angles_deg, const std::string& order);
/// Unit quaternion (w, x, y, z) normalised. @throws hc::ConfigError if its norm is near zero.
Eigen::Quaterniond rotation_from_quaternion(double w, double x, double y, double z);

/// Applies p ← scale·R·p + t to every point (and n ← R·n to normals). Real-time: no. Cost O(N);
/// none when the transform is exactly the identity (the points are then returned unchanged).
StageResult<Cloud> apply_view_transform(Cloud cloud, const ViewTransform& view);

}  // namespace hc::pipeline
