#pragma once
/// @file cross_check.hpp
/// Stage 7: kd-tree cross-check of the bilinear surface against the input points.

#include "hc/common/bilinear_surface.hpp"
#include "hc/common/height_field.hpp"
#include "hc/pipeline/cloud.hpp"

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace hc::pipeline {

/// Distribution of absolute errors, in millimetres.
struct ErrorStats {
  std::size_t count = 0;
  double rms_mm = 0.0, p50_mm = 0.0, p95_mm = 0.0, p99_mm = 0.0, max_mm = 0.0;
};

/// Summary statistics of |values| given in metres. Empty input gives count 0 and zeros.
/// Percentiles use the nearest-rank rule: p_q is the ⌈q·n⌉-th smallest value (partial
/// selection with std::nth_element, O(n); no full sort).
/// @throws hc::InputError if a value is NaN or infinite.
ErrorStats error_stats_mm(std::vector<double> abs_errors_m);
/// error_stats_mm for float values, without a double copy (half the memory; the tiled cross-check's
/// cells). Equal to error_stats_mm of the values converted to double: every float is a double,
/// the squares are summed in double in the same order and the ranks select the same values.
ErrorStats error_stats_mm_of_floats(std::vector<float> abs_errors_m);

/// Adds `prefix`_count, _rms_mm, _p50_mm, _p95_mm, _p99_mm and _max_mm to a stage report (the
/// cross-check's figures, in core and tiled).
void add_error_stats_figures(StageReport& report, const std::string& prefix, const ErrorStats& stats);

struct CrossCheck {
  /// (a) input points inside the grid whose bilinear cell is valid: |z_p − f(x_p, y_p)|.
  ErrorStats point_vertical;
  /// (a) the same points: distance along the surface normal, |z_p − f|·n_z.
  ErrorStats point_normal;
  /// (b) every valid grid sample: 3-D distance to its nearest input point.
  ErrorStats cell_to_point;
  /// Points considered in (a) and points skipped because their cell is no data.
  std::size_t points_on_surface = 0, points_off_surface = 0;
  /// Points skipped in (a) because they lie more than hidden_band_m BELOW the surface (hidden
  /// behind it, e.g. the back of a statue: not part of a Monge surface seen along −z), and
  /// finite points outside the grid's x-y extent. Points above the surface always count.
  std::size_t points_hidden = 0, points_outside = 0;
  double hidden_band_m = 0.0;
  /// Fraction of valid cells whose nearest input point is within tolerance_m [-]: the error
  /// map's float value ≤ tolerance_m (since 2026-11-30; the tiled run counts the same way from
  /// its merged map, so the scene's cell_error layer gives the figure back).
  double supported_fraction = 0.0;
  double tolerance_m = 0.0;
  /// Per-cell error map [m]: (b)'s distance per valid cell, NaN elsewhere. Empty in a tiled
  /// run's RunSummary: there it is the scene's cell_error layer (moved, not copied; run.hpp).
  HeightField cell_error_m;
};

/// Part (a) of cross_check for one finite point (x, y, z) [m, grid frame] against the bilinear
/// surface of a grid of geometry g: outside the grid's x-y extent; off the surface (a no-data
/// corner); hidden (more than hidden_band_m below f); or on it, with |z − f| and |z − f|·n_z
/// (n_z = 1/√(1 + f_x² + f_y²)) as float, exactly as cross_check computes them (it calls this).
struct PointResidual {
  enum Kind : std::uint8_t { kOutside, kOffSurface, kHidden, kOnSurface } kind = kOutside;
  float vertical_m = 0.0f, normal_m = 0.0f;  ///< set for kOnSurface
};
/// The PointResidual of a point at height z_m [m] whose bilinear surface sample (at its x-y,
/// inside the grid's extent) is `s`: off the surface, hidden (more than hidden_band_m > 0 [m]
/// below), or on it with |z − f| and |z − f|·n_z: what point_residual and
/// point_residual_of_part compute after sampling. No errors. Source: as point_residual.
inline PointResidual point_residual_of_sample(const SurfaceSample& s, double z_m, double hidden_band_m) noexcept;

/// point_residual: the PointResidual of (x_m, y_m, z_m) as described above; g is the geometry of
/// the grid `surface` views, hidden_band_m > 0 [m]. No errors (a non-finite point is outside or
/// off the surface). Inline, as BilinearSurface::sample: the cross-check's (a) and the tiled
/// run's evaluate it at every interior point.
inline PointResidual point_residual(const BilinearSurface& surface, const GridGeometry& g, double x_m, double y_m,
                                    double z_m, double hidden_band_m) noexcept {
  if (x_m < g.x0_m || x_m > g.x_of_col(g.cols - 1) || y_m < g.y0_m || y_m > g.y_of_row(g.rows - 1)) return {};
  return point_residual_of_sample(surface.sample(x_m, y_m), z_m, hidden_band_m);
}

/// point_residual of (x_m, y_m, z_m) against the whole grid of geometry g, read from a part of
/// it (bilinear_sample_of_part: `data` from grid sample (row0, col0), `row_stride` floats a row,
/// covering the point's cell and its far corners): bit for bit point_residual on the whole
/// grid. No errors. Source: as point_residual.
inline PointResidual point_residual_of_part(const float* data, std::ptrdiff_t row_stride, int row0, int col0,
                                            const GridGeometry& g, double x_m, double y_m, double z_m,
                                            double hidden_band_m) noexcept {
  if (x_m < g.x0_m || x_m > g.x_of_col(g.cols - 1) || y_m < g.y0_m || y_m > g.y_of_row(g.rows - 1)) return {};
  return point_residual_of_sample(bilinear_sample_of_part(data, row_stride, row0, col0, g, x_m, y_m), z_m, hidden_band_m);
}

inline PointResidual point_residual_of_sample(const SurfaceSample& s, double z_m, double hidden_band_m) noexcept {
  PointResidual r;
  if (!s.valid) {
    r.kind = PointResidual::kOffSurface;
    return r;
  }
  const double residual = z_m - s.z_m;
  if (residual < -hidden_band_m) {
    r.kind = PointResidual::kHidden;
    return r;
  }
  r.kind = PointResidual::kOnSurface;
  const double n_z = 1.0 / std::sqrt(1.0 + s.dz_dx * s.dz_dx + s.dz_dy * s.dz_dy);
  r.vertical_m = static_cast<float>(std::abs(residual));
  r.normal_m = static_cast<float>(std::abs(residual) * n_z);
  return r;
}

/// Cross-check (b)'s supported fraction alone: the fraction of valid samples of `grid` (node
/// (r, c) at (x_of_col(c), y_of_row(r), f(r, c)), grid frame [m]) with a finite point of
/// `points_m` within tolerance_m in 3-D, without the distances. Each point marks the samples
/// within tolerance_m of it (those in the square of half-width tolerance_m around it in x-y),
/// so the cost is O(N·(1 + 2·tolerance_m/cell)²) with no search structure (beyond 4 cells of
/// tolerance it calls cross_check instead, whose N points must then be finite): the levels table
/// (lod_report.hpp) measures every level's support with it. Equals cross_check's
/// supported_fraction up to rounding at exactly tolerance_m (cross_check compares in float in a
/// recentred frame, this in double).
/// @param tolerance_m  > 0 and finite [m]
/// @throws hc::ConfigError for a bad tolerance_m; hc::InputError if the grid has no valid sample.
/// Real-time: no. Threads: 2. Memory: two bytes per grid sample.
double supported_fraction(const Cloud& points_m, const HeightField& grid, double tolerance_m);

/// Cross-checks the grid against the points that made it (same grid frame, metres).
/// (b) is an exact nearest-neighbour search over all finite points: the points are bucketed by
/// grid node and searched ring by ring in grid order, with a nanoflann kd-tree over each
/// bucket's front-most point giving the bound for samples far from every point (filled holes).
/// (a) hidden points: see hidden_band_m; no-data cells: points_off_surface.
/// @param tolerance_m    a cell is "supported" if an input point lies within this distance.
/// @param hidden_band_m  (a) uses a point only if z_p ≥ f(x_p, y_p) − hidden_band_m [m].
/// @throws hc::InputError if the grid has no valid cell, is smaller than 2 × 2, or the cloud has
///         no finite point; hc::ConfigError for tolerance_m or hidden_band_m not > 0.
/// Real-time: no. Threads: 2. Cost: O(N + cells) for grids made from the points (plus a kd-tree
/// build over at most one point per cell, and over all points when many samples lie far from
/// every point).
StageResult<CrossCheck> cross_check(const Cloud& points_m, const HeightField& grid,
                                    double tolerance_m, double hidden_band_m = 0.002);

}  // namespace hc::pipeline
