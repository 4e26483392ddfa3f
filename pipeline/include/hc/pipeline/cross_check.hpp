#pragma once
/// @file cross_check.hpp
/// Stage 7: kd-tree cross-check of the bilinear surface against the input points.

#include "hc/common/height_field.hpp"
#include "hc/pipeline/cloud.hpp"

#include <cstddef>

namespace hc::pipeline {

/// Distribution of absolute errors, in millimetres.
struct ErrorStats {
  std::size_t count = 0;
  double rms_mm = 0.0, p50_mm = 0.0, p95_mm = 0.0, p99_mm = 0.0, max_mm = 0.0;
};

/// Summary statistics of |values| given in metres. Empty input gives count 0 and zeros.
ErrorStats error_stats_mm(std::vector<double> abs_errors_m);

struct CrossCheck {
  /// (a) input points inside the grid whose bilinear cell is valid: |z_p − f(x_p, y_p)|.
  ErrorStats point_vertical;
  /// (a) the same points: distance along the surface normal, |z_p − f|·n_z.
  ErrorStats point_normal;
  /// (b) every valid grid sample: 3-D distance to its nearest input point.
  ErrorStats cell_to_point;
  /// Points considered in (a) and points skipped because their cell is no data.
  std::size_t points_on_surface = 0, points_off_surface = 0;
  /// Fraction of valid cells whose nearest input point is within tolerance_m [-].
  double supported_fraction = 0.0;
  double tolerance_m = 0.0;
  /// Per-cell error map [m]: (b)'s distance per valid cell, NaN elsewhere.
  HeightField cell_error_m;
};

/// Cross-checks the grid against the points that made it (same grid frame, metres).
/// Nearest neighbours by a kd-tree over the points (nanoflann); queries run in grid order.
/// @param tolerance_m  a cell is "supported" if an input point lies within this distance.
/// @throws hc::InputError if the grid has no valid cell or the cloud is empty.
/// Real-time: no. Cost: O(N log N) build + O(cells · log N).
StageResult<CrossCheck> cross_check(const Cloud& points_m, const HeightField& grid,
                                    double tolerance_m);

}  // namespace hc::pipeline
