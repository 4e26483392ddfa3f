// Stages 2 and 3: units and recentring in double precision, then the user's view transform.

#include "hc/common/format.hpp"
#include "stage_util.hpp"
#include "hc/pipeline/transform.hpp"

#include "hc/common/error.hpp"

#include <chrono>
#include <cmath>
#include <limits>
#include <numbers>
#include <sstream>
#include <string>

namespace hc::pipeline {

namespace {

using hc::format_number;

using detail::Clock;
using detail::seconds_since;

double radians(double deg) { return deg * std::numbers::pi / 180.0; }

}  // namespace

StageResult<Cloud> to_metres_and_recentre(Cloud cloud, double metres_per_unit, Eigen::Vector3d* offset_m,
                                          double max_extent_m) {
  const auto t0 = Clock::now();
  if (!(metres_per_unit > 0.0) || !std::isfinite(metres_per_unit)) {
    throw ConfigError("to_metres_and_recentre: metres_per_unit = " + format_number(metres_per_unit) +
                      ", expected a finite value > 0 (1 for m, 0.01 for cm, 0.001 for mm)");
  }
  if (!(max_extent_m > 0.0) || !std::isfinite(max_extent_m)) {
    throw ConfigError("input.max_extent_m = " + format_number(max_extent_m) + ": expected a finite value > 0 [m]");
  }
  if (cloud.size() == 0) throw InputError("to_metres_and_recentre: the cloud is empty");

  // Bounding box of the finite points, in file units (double).
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  std::size_t finite = 0;
  for (Eigen::Index i = 0; i < cloud.xyz.cols(); ++i) {
    const auto p = cloud.xyz.col(i);
    if (!p.allFinite()) continue;
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
    ++finite;
  }
  if (finite == 0) {
    throw InputError("to_metres_and_recentre: none of the " + std::to_string(cloud.size()) +
                     " points has finite coordinates");
  }
  // Absurd extents (finite floats near ±3.4e38, a unit mix-up) are refused before any stage can
  // overflow float arithmetic on them. Computed in double: hi − lo cannot overflow there.
  const Eigen::Vector3d box_m = (hi - lo) * metres_per_unit;
  for (int a = 0; a < 3; ++a) {
    if (!(box_m[a] <= max_extent_m)) {
      const char axis = static_cast<char>('x' + a);
      std::ostringstream msg;
      msg << "the points span " << box_m[a] << " m along " << axis << " (from " << lo[a] * metres_per_unit
          << " to " << hi[a] * metres_per_unit << " m): more than input.max_extent_m = " << max_extent_m
          << " m; expected a scan of at most that size (far outliers or wrong input.units? crop them with "
             "filters.crop or raise input.max_extent_m)";
      throw InputError(msg.str());
    }
  }
  // Centre in file units; subtract before scaling so large offsets cancel exactly first.
  const Eigen::Vector3d centre = 0.5 * (lo + hi);
  cloud.xyz.colwise() -= centre;
  if (metres_per_unit != 1.0) cloud.xyz *= metres_per_unit;
  const Eigen::Vector3d centre_m = centre * metres_per_unit;
  if (offset_m) *offset_m = centre_m;

  StageReport report;
  report.stage = "recentre";
  report.count_in = cloud.size();
  report.count_out = cloud.size();
  report.figure("metres_per_unit", metres_per_unit);
  report.figure("offset_x_m", centre_m.x());
  report.figure("offset_y_m", centre_m.y());
  report.figure("offset_z_m", centre_m.z());
  report.figure("extent_x_m", box_m.x());
  report.figure("extent_y_m", box_m.y());
  report.figure("extent_z_m", box_m.z());
  if (finite != cloud.size()) {
    report.notes.push_back(std::to_string(cloud.size() - finite) + " non-finite points left for remove_non_finite");
  }
  report.seconds = seconds_since(t0);
  return {std::move(cloud), std::move(report)};
}

Eigen::Affine3d ViewTransform::matrix() const {
  Eigen::Affine3d m = Eigen::Affine3d::Identity();
  m.linear() = scale * rotation.normalized().toRotationMatrix();
  m.translation() = translation_m;
  return m;
}

bool ViewTransform::is_identity() const {
  const Eigen::Affine3d m = matrix();
  return m.linear() == Eigen::Matrix3d::Identity() && m.translation() == Eigen::Vector3d::Zero();
}

Eigen::Quaterniond rotation_from_axis_angle(const Eigen::Vector3d& axis, double angle_deg) {
  const double n = axis.norm();
  if (!std::isfinite(n) || n < 1e-12) {
    throw ConfigError("rotation axis (" + format_number(axis.x()) + ", " + format_number(axis.y()) + ", " +
                      format_number(axis.z()) + ") is zero or not finite: expected a non-zero axis");
  }
  if (!std::isfinite(angle_deg)) throw ConfigError("rotation angle_deg is not finite");
  return Eigen::Quaterniond(Eigen::AngleAxisd(radians(angle_deg), axis / n));
}

Eigen::Quaterniond rotation_from_euler(const Eigen::Vector3d& angles_deg, const std::string& order) {
  const bool ok = order.size() == 3 && order.find_first_not_of("xyz") == std::string::npos &&
                  order[0] != order[1] && order[0] != order[2] && order[1] != order[2];
  if (!ok) {
    throw ConfigError("Euler order '" + order +
                      "' is invalid: expected a permutation of x, y, z (xyz, xzy, yxz, yzx, zxy or zyx)");
  }
  if (!angles_deg.allFinite()) throw ConfigError("Euler angles (degrees) are not finite");
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
  for (int i = 0; i < 3; ++i) {
    const Eigen::Vector3d axis = order[static_cast<std::size_t>(i)] == 'x'   ? Eigen::Vector3d::UnitX()
                                 : order[static_cast<std::size_t>(i)] == 'y' ? Eigen::Vector3d::UnitY()
                                                                             : Eigen::Vector3d::UnitZ();
    q = q * Eigen::Quaterniond(Eigen::AngleAxisd(radians(angles_deg[i]), axis));
  }
  return q.normalized();
}

Eigen::Quaterniond rotation_from_quaternion(double w, double x, double y, double z) {
  const Eigen::Quaterniond q(w, x, y, z);
  const double n = q.norm();
  if (!std::isfinite(n) || n < 1e-9) {
    throw ConfigError("quaternion (w, x, y, z) = (" + format_number(w) + ", " + format_number(x) + ", " +
                      format_number(y) + ", " + format_number(z) + ") has norm " + format_number(n) +
                      ": expected a finite, non-zero norm");
  }
  return q.normalized();
}

StageResult<Cloud> apply_view_transform(Cloud cloud, const ViewTransform& view) {
  const auto t0 = Clock::now();
  if (!(view.scale > 0.0) || !std::isfinite(view.scale)) {
    throw ConfigError("apply_view_transform: scale = " + format_number(view.scale) + ", expected a finite value > 0");
  }
  if (!view.translation_m.allFinite()) throw ConfigError("apply_view_transform: translation_m is not finite");
  const Eigen::Affine3d m = view.matrix();
  // The identity (the default view, or a 0° turn) leaves every point as it is: no pass over the
  // points (15 ms of the merged Buddha's run). The product would turn a coordinate of −0 into
  // +0, and one beside an infinite coordinate into NaN; the non_finite stage drops such points
  // either way.
  if (!view.is_identity()) {
    cloud.xyz = (m.linear() * cloud.xyz).colwise() + m.translation();
    if (cloud.has_normals()) {
      // Normals turn with the rotation only (the scale is uniform and the translation moves
      // positions): n' = R·n, in float as stored.
      const Eigen::Matrix3f r = view.rotation.normalized().toRotationMatrix().cast<float>();
      Eigen::Map<Eigen::Matrix3Xf> nrm(cloud.normal.data(), 3, static_cast<Eigen::Index>(cloud.normal.size() / 3));
      nrm = r * nrm;
    }
  }
  StageReport report;
  report.stage = "transform";
  report.count_in = cloud.size();
  report.count_out = cloud.size();
  report.figure("scale", view.scale);
  report.seconds = seconds_since(t0);
  return {std::move(cloud), std::move(report)};
}

}  // namespace hc::pipeline
