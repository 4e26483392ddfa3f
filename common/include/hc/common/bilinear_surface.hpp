#pragma once
/// @file bilinear_surface.hpp
/// The continuous Monge surface z = f(x, y) through the samples of a height field, by bilinear
/// interpolation (Sec. 3 of the paper: "bilinear interpolation is sufficient"). PCL-free and
/// allocation-free: the haptic servo loop evaluates it thousands of times a second.

#include "hc/common/height_field.hpp"

#include <Eigen/Core>

#include <cstddef>

namespace hc {

/// Non-owning read-only window (ROI) on a height field's samples.
/// `data` points at the window's sample (0, 0); `row_stride` is the distance in floats between
/// two rows of the underlying field (≥ geometry.cols). geometry describes the window itself
/// (x0_m, y0_m of its first sample). The viewed field must outlive the view.
struct HeightFieldView {
  const float* data = nullptr;
  GridGeometry geometry{};
  std::ptrdiff_t row_stride = 0;

  float at(int row, int col) const { return data[row * row_stride + col]; }

  /// Whole-field view. Real-time: yes.
  static HeightFieldView of(const HeightField& field) {
    return HeightFieldView{field.data(), field.geometry(), field.cols()};
  }
  /// Window of rows × cols samples starting at (row0, col0); the caller keeps it inside the field.
  static HeightFieldView window(const HeightField& field, int row0, int col0, int rows, int cols);
};

/// Value and first derivatives of f at one point.
struct SurfaceSample {
  double z_m = 0.0;    ///< f(x, y) [m]; NaN when `valid` is false
  double dz_dx = 0.0;  ///< ∂f/∂x [-]
  double dz_dy = 0.0;  ///< ∂f/∂y [-]
  bool valid = false;  ///< false when any of the four corner samples is no-data (NaN)
};

/// Bilinear interpolant over a HeightFieldView.
///
/// Inside cell (i, j) with local coordinates u, v ∈ [0, 1]:
///   f = (1−u)(1−v)·z00 + u(1−v)·z10 + (1−u)v·z01 + uv·z11,
/// so ∂f/∂x = ((1−v)(z10−z00) + v(z11−z01)) / cell and ∂f/∂y likewise.
/// Border: x and y are clamped to the window's extent, so f continues as a constant beyond it
/// and the clamped direction has zero slope there. On a shared cell edge the gradient is that
/// of the cell with the larger index, except on the last row/column (the gradient of a
/// bilinear surface jumps across cell edges; callers that need a smooth normal blend it).
/// No data: a cell with a NaN corner gives valid = false and NaN z; callers that must never
/// see NaN (the haptic renderer) evaluate a floor-filled field instead.
/// Requires rows ≥ 2 and cols ≥ 2. Real-time: yes (noexcept, no allocation). Thread-safe: yes.
class BilinearSurface {
 public:
  BilinearSurface() = default;
  explicit BilinearSurface(const HeightFieldView& view) : view_(view) {}

  /// f and its gradient at (x_m, y_m), grid frame, metres.
  SurfaceSample sample(double x_m, double y_m) const noexcept;

  /// f(x, y) [m] only (NaN where a corner is no-data).
  double height(double x_m, double y_m) const noexcept { return sample(x_m, y_m).z_m; }

  /// Upward unit normal (−f_x, −f_y, 1)/‖·‖ at (x_m, y_m); (0, 0, 1) where no data.
  Eigen::Vector3d normal(double x_m, double y_m) const noexcept;

  const HeightFieldView& view() const noexcept { return view_; }

 private:
  HeightFieldView view_{};
};

}  // namespace hc
