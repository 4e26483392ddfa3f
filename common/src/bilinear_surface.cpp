#include "hc/common/bilinear_surface.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>

namespace hc {

HeightFieldView HeightFieldView::window(const HeightField& field, int row0, int col0, int rows,
                                        int cols) {
  assert(row0 >= 0 && col0 >= 0 && rows >= 1 && cols >= 1);
  assert(row0 + rows <= field.rows() && col0 + cols <= field.cols());
  GridGeometry g = field.geometry();
  g.x0_m = g.x_of_col(col0);
  g.y0_m = g.y_of_row(row0);
  g.rows = rows;
  g.cols = cols;
  return HeightFieldView{field.data() + static_cast<std::ptrdiff_t>(row0) * field.cols() + col0, g,
                         field.cols()};
}

SurfaceSample BilinearSurface::sample(double x_m, double y_m) const noexcept {
  const GridGeometry& g = view_.geometry;
  assert(g.rows >= 2 && g.cols >= 2 && g.cell_size_m > 0.0);
  const double max_u = static_cast<double>(g.cols - 1);
  const double max_v = static_cast<double>(g.rows - 1);
  double cu = (x_m - g.x0_m) / g.cell_size_m;
  double cv = (y_m - g.y0_m) / g.cell_size_m;
  // NaN coordinates would make the index arithmetic undefined: treat as no data.
  if (!(cu == cu) || !(cv == cv)) return SurfaceSample{std::numeric_limits<double>::quiet_NaN(), 0, 0, false};
  const bool outside_u = cu < 0.0 || cu > max_u;  // beyond the border: constant extension
  const bool outside_v = cv < 0.0 || cv > max_v;
  cu = std::clamp(cu, 0.0, max_u);
  cv = std::clamp(cv, 0.0, max_v);
  const int i = std::min(static_cast<int>(cu), g.cols - 2);
  const int j = std::min(static_cast<int>(cv), g.rows - 2);
  const double u = cu - i;
  const double v = cv - j;
  const float* row0 = view_.data + static_cast<std::ptrdiff_t>(j) * view_.row_stride + i;
  const float* row1 = row0 + view_.row_stride;
  const double z00 = row0[0], z10 = row0[1], z01 = row1[0], z11 = row1[1];
  SurfaceSample s;
  s.z_m = (1 - u) * (1 - v) * z00 + u * (1 - v) * z10 + (1 - u) * v * z01 + u * v * z11;
  s.valid = !std::isnan(s.z_m);
  if (!s.valid) return s;
  const double inv = 1.0 / g.cell_size_m;
  s.dz_dx = outside_u ? 0.0 : ((1 - v) * (z10 - z00) + v * (z11 - z01)) * inv;
  s.dz_dy = outside_v ? 0.0 : ((1 - u) * (z01 - z00) + u * (z11 - z10)) * inv;
  return s;
}

Eigen::Vector3d BilinearSurface::normal(double x_m, double y_m) const noexcept {
  const SurfaceSample s = sample(x_m, y_m);
  if (!s.valid) return Eigen::Vector3d::UnitZ();
  return Eigen::Vector3d(-s.dz_dx, -s.dz_dy, 1.0).normalized();
}

}  // namespace hc
