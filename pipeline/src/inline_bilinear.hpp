#pragma once
/// @file inline_bilinear.hpp
/// BilinearSurface::sample's arithmetic inline, for the loops that evaluate the grid's surface
/// at every input point (the cross-check's (a) residuals, in core and per tile; the honest
/// check's classes). Internal to hc::pipeline (not installed).
///
/// sample() is an out-of-line call returning a 32-byte struct, and it computes the gradient
/// whether or not the caller reads it. At 10^8 points the cross-check and the honest check
/// evaluate it about 2 × 10^8 times (2026-11-27: 4.4 % of the tiled run's CPU with
/// point_residual). Here the same operations run in the same order on the same doubles, so
/// every value is sample()'s bit for bit (test InlineBilinear.EqualsBilinearSurfaceBitForBit,
/// against sample() itself over the border, outside, NaN corners and non-finite input); only
/// the call and, for at<false>, the gradient are left out.

#include "hc/common/bilinear_surface.hpp"
#include "hc/pipeline/cross_check.hpp"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>

namespace hc::pipeline::detail {

/// The bilinear surface over a HeightFieldView (grid frame, metres), evaluated inline.
/// Shapes and rules: BilinearSurface (hc/common/bilinear_surface.hpp): rows, cols ≥ 2; x and y
/// clamped to the grid's extent; a NaN corner gives valid = false and NaN z.
/// Real-time: yes (noexcept, no allocation). Thread-safe: yes (read only).
class InlineBilinear {
 public:
  explicit InlineBilinear(const HeightFieldView& view)
      : data_(view.data), stride_(view.row_stride), g_(view.geometry),
        max_u_(static_cast<double>(view.geometry.cols - 1)), max_v_(static_cast<double>(view.geometry.rows - 1)) {}

  /// f at (x_m, y_m), and with kGradient its gradient [-] (zero across a clamped border), as
  /// BilinearSurface::sample returns them; without it dz_dx = dz_dy = 0.
  template <bool kGradient>
  SurfaceSample at(double x_m, double y_m) const noexcept {
    double cu = (x_m - g_.x0_m) / g_.cell_size_m;
    double cv = (y_m - g_.y0_m) / g_.cell_size_m;
    if (!(cu == cu) || !(cv == cv)) return SurfaceSample{std::numeric_limits<double>::quiet_NaN(), 0, 0, false};
    const bool outside_u = cu < 0.0 || cu > max_u_;
    const bool outside_v = cv < 0.0 || cv > max_v_;
    cu = std::clamp(cu, 0.0, max_u_);
    cv = std::clamp(cv, 0.0, max_v_);
    const int i = std::min(static_cast<int>(cu), g_.cols - 2);
    const int j = std::min(static_cast<int>(cv), g_.rows - 2);
    const double u = cu - i;
    const double v = cv - j;
    const float* row0 = data_ + static_cast<std::ptrdiff_t>(j) * stride_ + i;
    const float* row1 = row0 + stride_;
    const double z00 = row0[0], z10 = row0[1], z01 = row1[0], z11 = row1[1];
    SurfaceSample s;
    s.z_m = (1 - u) * (1 - v) * z00 + u * (1 - v) * z10 + (1 - u) * v * z01 + u * v * z11;
    s.valid = !std::isnan(s.z_m);
    if (!kGradient || !s.valid) return s;
    const double inv = 1.0 / g_.cell_size_m;
    s.dz_dx = outside_u ? 0.0 : ((1 - v) * (z10 - z00) + v * (z11 - z01)) * inv;
    s.dz_dy = outside_v ? 0.0 : ((1 - u) * (z01 - z00) + u * (z11 - z10)) * inv;
    return s;
  }

  const GridGeometry& geometry() const noexcept { return g_; }

 private:
  const float* data_;
  std::ptrdiff_t stride_;
  GridGeometry g_;
  double max_u_, max_v_;
};

/// point_residual (cross_check.hpp) inline: the class and residuals of a point (x, y, z) [m,
/// grid frame] against the bilinear surface of `view`, whose geometry is the grid's own.
/// The same arithmetic as point_residual (which calls this), so the same floats bit for bit.
class InlineResidual {
 public:
  explicit InlineResidual(const HeightFieldView& view)
      : surface_(view), x_hi_(view.geometry.x_of_col(view.geometry.cols - 1)),
        y_hi_(view.geometry.y_of_row(view.geometry.rows - 1)) {}

  PointResidual operator()(double x, double y, double z, double hidden_band_m) const noexcept {
    PointResidual r;
    const GridGeometry& g = surface_.geometry();
    if (x < g.x0_m || x > x_hi_ || y < g.y0_m || y > y_hi_) return r;
    const SurfaceSample s = surface_.at<true>(x, y);
    if (!s.valid) {
      r.kind = PointResidual::kOffSurface;
      return r;
    }
    const double residual = z - s.z_m;
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

 private:
  InlineBilinear surface_;
  double x_hi_, y_hi_;
};

}  // namespace hc::pipeline::detail
