#include "hc/common/bilinear_surface.hpp"

#include <cassert>

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

Eigen::Vector3d BilinearSurface::normal(double x_m, double y_m) const noexcept {
  const SurfaceSample s = sample(x_m, y_m);
  if (!s.valid) return Eigen::Vector3d::UnitZ();
  return Eigen::Vector3d(-s.dz_dx, -s.dz_dy, 1.0).normalized();
}

}  // namespace hc
