#pragma once
/// @file height_field.hpp
/// The Monge grid z = f(x, y): the data contract between the offline pipeline and the online
/// haptic renderer (see docs/architecture.md, "Data contract").

#include "hc/common/cell_buffer.hpp"

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
/// The cells are on the heap, or in a scratch file's mapping (file_backed(); a tiled run's
/// level 0, docs/scale.md "Level 0 in a file"); a copy is on the heap.
/// Thread-safe for concurrent reads; not real-time to construct (allocates).
class HeightField {
 public:
  HeightField() = default;
  /// @param geometry rows, cols ≥ 1 and cell_size_m > 0 (asserted by callers that build grids).
  /// @param fill     initial value of every cell (default: no data).
  explicit HeightField(const GridGeometry& geometry, float fill = kNoData)
      : geometry_(geometry), z_m_(geometry.cell_count(), fill) {}
  /// The same, its cells in a ScratchMapping in `dir` (cell_buffer.hpp).
  /// @param what what the layer is, for the error message ("level 0's depth").
  /// @throws ResourceError naming `dir` where the file cannot be made, reserved or mapped.
  HeightField(const GridGeometry& geometry, float fill, const std::filesystem::path& dir, const std::string& what)
      : geometry_(geometry), z_m_(dir, geometry.cell_count(), fill, what) {}

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
  CellBuffer<float>& values() { return z_m_; }
  const CellBuffer<float>& values() const { return z_m_; }
  /// True where the cells are in a scratch file's mapping.
  bool file_backed() const { return z_m_.file_backed(); }

  /// Number of cells holding a finite height. A file-backed field's pages are given back as the
  /// count passes (CellBuffer::release_resident, every kReleaseEveryCells cells).
  std::size_t valid_count() const {
    std::size_t n = 0;
    const float* z = z_m_.data();
    for (std::size_t i = 0; i < z_m_.size(); i += kReleaseEveryCells) {
      const std::size_t end = i + kReleaseEveryCells < z_m_.size() ? i + kReleaseEveryCells : z_m_.size();
      for (std::size_t j = i; j < end; ++j) n += std::isnan(z[j]) ? 0U : 1U;
      z_m_.release_resident();
    }
    return n;
  }

  Eigen::Affine3d model_to_grid = Eigen::Affine3d::Identity();

 private:
  std::size_t index(int row, int col) const {
    return static_cast<std::size_t>(row) * static_cast<std::size_t>(geometry_.cols) +
           static_cast<std::size_t>(col);
  }
  GridGeometry geometry_{};
  CellBuffer<float> z_m_;
};

}  // namespace hc
