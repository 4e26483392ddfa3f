#pragma once
/// @file height_field.hpp
/// The Monge grid z = f(x, y): the data contract between the offline pipeline and the online
/// haptic renderer (see docs/architecture.md, "Data contract").

#include <Eigen/Geometry>

#include <cmath>
#include <cstddef>
#include <limits>
#include <vector>

namespace hc {

/// Placement of a regular grid in the grid frame.
/// Sample (row r, col c) sits at x = x0_m + c·cell_size_m, y = y0_m + r·cell_size_m
/// (node-centred samples; row 0 has the smallest y). z points towards the viewer: larger z is
/// nearer, and the grid looks along −z.
struct GridGeometry {
  int rows = 0;             ///< number of samples along y [-]
  int cols = 0;             ///< number of samples along x [-]
  double x0_m = 0.0;        ///< x of column 0 [m], grid frame
  double y0_m = 0.0;        ///< y of row 0 [m], grid frame
  double cell_size_m = 0.0; ///< spacing between neighbouring samples [m], > 0

  /// x [m] of column c (c may be fractional). Source: definition above.
  double x_of_col(double c) const { return x0_m + c * cell_size_m; }
  /// y [m] of row r (r may be fractional).
  double y_of_row(double r) const { return y0_m + r * cell_size_m; }
  /// Fractional column index of x [m].
  double col_of_x(double x_m) const { return (x_m - x0_m) / cell_size_m; }
  /// Fractional row index of y [m].
  double row_of_y(double y_m) const { return (y_m - y0_m) / cell_size_m; }
  /// rows·cols.
  std::size_t cell_count() const { return static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols); }
  bool operator==(const GridGeometry&) const = default;
};

/// Quiet NaN as a float: the no-data value of every layer.
inline constexpr float kNoData = std::numeric_limits<float>::quiet_NaN();

/// Owning rows × cols grid of float heights in metres, row-major, NaN = no data.
/// `model_to_grid` is the rigid-plus-uniform-scale transform that took a model point (metres,
/// after units and recentring) into this grid's frame, so a grid point can be mapped back.
/// Thread-safe for concurrent reads; not real-time to construct (allocates).
class HeightField {
 public:
  HeightField() = default;
  /// @param geometry rows, cols ≥ 1 and cell_size_m > 0 (asserted by callers that build grids).
  /// @param fill     initial value of every cell (default: no data).
  explicit HeightField(const GridGeometry& geometry, float fill = kNoData)
      : geometry_(geometry), z_m_(geometry.cell_count(), fill) {}

  const GridGeometry& geometry() const { return geometry_; }
  int rows() const { return geometry_.rows; }
  int cols() const { return geometry_.cols; }
  double cell_size_m() const { return geometry_.cell_size_m; }

  /// Height [m] at (row, col); no bounds check in release builds.
  float& at(int row, int col) { return z_m_[index(row, col)]; }
  float at(int row, int col) const { return z_m_[index(row, col)]; }
  bool valid(int row, int col) const { return !std::isnan(at(row, col)); }

  float* data() { return z_m_.data(); }
  const float* data() const { return z_m_.data(); }
  std::vector<float>& values() { return z_m_; }
  const std::vector<float>& values() const { return z_m_; }

  /// Number of cells holding a finite height.
  std::size_t valid_count() const {
    std::size_t n = 0;
    for (float v : z_m_) n += std::isnan(v) ? 0U : 1U;
    return n;
  }

  Eigen::Affine3d model_to_grid = Eigen::Affine3d::Identity();

 private:
  std::size_t index(int row, int col) const {
    return static_cast<std::size_t>(row) * static_cast<std::size_t>(geometry_.cols) +
           static_cast<std::size_t>(col);
  }
  GridGeometry geometry_{};
  std::vector<float> z_m_;
};

}  // namespace hc
