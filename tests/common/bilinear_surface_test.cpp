#include "hc/common/bilinear_surface.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace {

hc::HeightField plane_field(int rows, int cols, double cell, double a, double b, double c) {
  hc::HeightField f(hc::GridGeometry{rows, cols, -0.01, 0.02, cell});
  for (int r = 0; r < rows; ++r)
    for (int col = 0; col < cols; ++col)
      f.at(r, col) = static_cast<float>(a * f.geometry().x_of_col(col) + b * f.geometry().y_of_row(r) + c);
  return f;
}

TEST(BilinearSurface, ReproducesAPlaneAndItsGradientExactly) {
  const auto field = plane_field(7, 9, 0.001, 0.3, -0.2, 0.05);
  const hc::BilinearSurface s(hc::HeightFieldView::of(field));
  for (double x : {-0.0095, -0.004, -0.0021, -0.003}) {
    for (double y : {0.0201, 0.023, 0.025}) {
      const auto q = s.sample(x, y);
      ASSERT_TRUE(q.valid);
      EXPECT_NEAR(q.z_m, 0.3 * x - 0.2 * y + 0.05, 1e-7);
      EXPECT_NEAR(q.dz_dx, 0.3, 1e-3);
      EXPECT_NEAR(q.dz_dy, -0.2, 1e-3);
    }
  }
  const Eigen::Vector3d n = s.normal(-0.004, 0.023);
  EXPECT_NEAR(n.norm(), 1.0, 1e-12);
  EXPECT_NEAR(n.x() / n.z(), -0.3, 1e-3);
}

TEST(BilinearSurface, InterpolatesBilinearlyInsideACell) {
  hc::HeightField f(hc::GridGeometry{2, 2, 0.0, 0.0, 1.0});
  f.at(0, 0) = 0.0f; f.at(0, 1) = 1.0f; f.at(1, 0) = 2.0f; f.at(1, 1) = 5.0f;
  const hc::BilinearSurface s(hc::HeightFieldView::of(f));
  const auto q = s.sample(0.25, 0.5);
  // (1-u)(1-v)0 + u(1-v)1 + (1-u)v2 + uv5 with u=0.25, v=0.5
  EXPECT_DOUBLE_EQ(q.z_m, 0.25 * 0.5 * 1 + 0.75 * 0.5 * 2 + 0.25 * 0.5 * 5);
  EXPECT_DOUBLE_EQ(q.dz_dx, 0.5 * 1 + 0.5 * 3);
  EXPECT_DOUBLE_EQ(q.dz_dy, 0.75 * 2 + 0.25 * 4);
}

TEST(BilinearSurface, ClampsBeyondTheBorderWithZeroSlopeAcrossIt) {
  const auto field = plane_field(4, 4, 0.5, 1.0, 0.0, 0.0);
  const hc::BilinearSurface s(hc::HeightFieldView::of(field));
  const auto outside = s.sample(100.0, 0.5 + 0.02);
  ASSERT_TRUE(outside.valid);
  EXPECT_NEAR(outside.z_m, field.geometry().x_of_col(3), 1e-6);
  EXPECT_EQ(outside.dz_dx, 0.0);
}

TEST(BilinearSurface, NoDataCornerGivesInvalidSampleAndUpNormal) {
  auto field = plane_field(3, 3, 1.0, 0.0, 0.0, 1.0);
  field.at(1, 1) = hc::kNoData;
  const hc::BilinearSurface s(hc::HeightFieldView::of(field));
  const auto q = s.sample(-0.01 + 0.5, 0.02 + 0.5);
  EXPECT_FALSE(q.valid);
  EXPECT_TRUE(std::isnan(q.z_m));
  EXPECT_EQ(s.normal(-0.01 + 0.5, 0.02 + 0.5), Eigen::Vector3d::UnitZ());
  EXPECT_FALSE(s.sample(std::nan(""), 0.0).valid);
}

TEST(BilinearSurface, WindowViewMatchesTheWholeField) {
  const auto field = plane_field(10, 12, 0.01, 0.7, 0.4, 0.0);
  const auto win = hc::HeightFieldView::window(field, 3, 4, 5, 6);
  const hc::BilinearSurface whole(hc::HeightFieldView::of(field));
  const hc::BilinearSurface part(win);
  const double x = win.geometry.x_of_col(2.3), y = win.geometry.y_of_row(1.7);
  EXPECT_DOUBLE_EQ(whole.height(x, y), part.height(x, y));
}

// cell_address (what prefetch fetches) names the cell sample() reads away from cell edges, and
// never a sample outside the view (nor the row below it) however far, huge or odd the point:
// the oracle is bilinear_cell and the view's own bounds.
TEST(BilinearSurface, CellAddressIsTheSampledCellAndStaysInsideTheView) {
  const auto field = plane_field(10, 12, 0.01, 0.7, 0.4, 0.0);
  for (const auto& view : {hc::HeightFieldView::of(field), hc::HeightFieldView::window(field, 3, 4, 5, 6)}) {
    const hc::BilinearSurface s(view);
    const hc::GridGeometry& g = view.geometry;
    // Cell centres: no edge near, so the multiplication and the division agree.
    for (int r = 0; r + 1 < g.rows; ++r) {
      for (int c = 0; c + 1 < g.cols; ++c) {
        const double x = g.x_of_col(c + 0.5), y = g.y_of_row(r + 0.5);
        const hc::BilinearCell cell = hc::bilinear_cell(g, x, y);
        EXPECT_EQ(s.cell_address(x, y), view.data + cell.j * view.row_stride + cell.i) << r << ", " << c;
      }
    }
    const double big = 1e300, inf = std::numeric_limits<double>::infinity();
    for (double x : {-big, -inf, -1.0, g.x0_m, g.x_of_col(g.cols - 1), 1.0, big, inf}) {
      for (double y : {-big, -inf, -1.0, g.y0_m, g.y_of_row(g.rows - 1), 1.0, big, inf}) {
        const float* top = s.cell_address(x, y);
        ASSERT_NE(top, nullptr);
        const std::ptrdiff_t off = top - view.data;
        const std::ptrdiff_t row = off / view.row_stride, col = off % view.row_stride;
        EXPECT_GE(row, 0);
        EXPECT_LE(row, g.rows - 2);  // its row and the one below are the view's
        EXPECT_GE(col, 0);
        EXPECT_LE(col, g.cols - 2);
        s.prefetch(x, y);  // no fault, no effect
      }
    }
    EXPECT_EQ(s.cell_address(std::nan(""), 0.0), nullptr);
    EXPECT_EQ(s.cell_address(0.0, std::nan("")), nullptr);
  }
  EXPECT_EQ(hc::BilinearSurface().cell_address(0.0, 0.0), nullptr);  // no data
}

}  // namespace
