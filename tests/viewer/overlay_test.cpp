// The viewer's polish (issue 17): audio-region outlines (geometry and overlay), the proxy
// ball's size on screen, and a panel whose labels are never clipped. Xvfb + Mesa llvmpipe.

#include "viewer_fixture.hpp"

#include "hc/haptics/shared_state.hpp"
#include "hc/viewer/viewer.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <numbers>
#include <string>
#include <vector>

namespace hc {
namespace {

using viewer::Image;
using viewer::RegionSegment;
using viewer::Viewer;

/// region_id of `rows` × `cols` samples (cell 1 mm, origin 0) with `id` on [r0, r1) × [c0, c1).
HeightField region_raster(int rows, int cols) {
  HeightField f(GridGeometry{rows, cols, 0.0, 0.0, 0.001});
  for (float& v : f.values()) v = std::numeric_limits<float>::quiet_NaN();
  return f;
}
void paint(HeightField& f, int r0, int r1, int c0, int c1, float id) {
  for (int r = r0; r < r1; ++r)
    for (int c = c0; c < c1; ++c) f.at(r, c) = id;
}

double total_length(const std::vector<RegionSegment>& s, std::int32_t region) {
  double l = 0.0;
  for (const RegionSegment& g : s)
    if (g.region == region) l += std::hypot(g.x1_m - g.x0_m, g.y1_m - g.y0_m);
  return l;
}

TEST(RegionOutline, ABoxIsFourSegmentsOnItsCellBoundaries) {
  HeightField f = region_raster(20, 30);
  paint(f, 4, 10, 5, 17, 0.0F);  // 6 rows × 12 columns of samples
  const std::vector<RegionSegment> s = viewer::region_outline_segments(f);
  ASSERT_EQ(s.size(), 4U);
  // Cell boundaries half a cell outside the outer nodes: x ∈ [4.5, 16.5] mm, y ∈ [3.5, 9.5] mm.
  double x_lo = 1, x_hi = -1, y_lo = 1, y_hi = -1;
  for (const RegionSegment& g : s) {
    EXPECT_EQ(g.region, 0);
    EXPECT_TRUE(g.x0_m == g.x1_m || g.y0_m == g.y1_m) << "segments are axis-parallel";
    x_lo = std::min({x_lo, g.x0_m, g.x1_m}), x_hi = std::max({x_hi, g.x0_m, g.x1_m});
    y_lo = std::min({y_lo, g.y0_m, g.y1_m}), y_hi = std::max({y_hi, g.y0_m, g.y1_m});
  }
  EXPECT_NEAR(x_lo, 0.0045, 1e-12);
  EXPECT_NEAR(x_hi, 0.0165, 1e-12);
  EXPECT_NEAR(y_lo, 0.0035, 1e-12);
  EXPECT_NEAR(y_hi, 0.0095, 1e-12);
  EXPECT_NEAR(total_length(s, 0), 2 * (0.012 + 0.006), 1e-12);
}

TEST(RegionOutline, NeighboursAreEachClosedAndTheRasterEdgeClosesARegion) {
  HeightField f = region_raster(10, 10);
  paint(f, 0, 10, 0, 4, 0.0F);   // region 0 touches three raster edges
  paint(f, 0, 10, 4, 10, 1.0F);  // region 1 fills the rest: the shared boundary x = 3.5 mm
  const std::vector<RegionSegment> s = viewer::region_outline_segments(f);
  EXPECT_NEAR(total_length(s, 0), 2 * (0.004 + 0.010), 1e-12);
  EXPECT_NEAR(total_length(s, 1), 2 * (0.006 + 0.010), 1e-12);
  int shared = 0;
  for (const RegionSegment& g : s) shared += std::abs(g.x0_m - 0.0035) < 1e-12 && g.x0_m == g.x1_m ? 1 : 0;
  EXPECT_EQ(shared, 2) << "the boundary between regions 0 and 1 is drawn once for each";
  // An L-shaped region: 6 straight runs, and its perimeter.
  HeightField l = region_raster(10, 10);
  paint(l, 0, 6, 0, 2, 2.0F);
  paint(l, 0, 2, 2, 6, 2.0F);
  const std::vector<RegionSegment> ls = viewer::region_outline_segments(l);
  EXPECT_EQ(ls.size(), 6U);
  EXPECT_NEAR(total_length(ls, 2), 0.024, 1e-12);
  // No region, or NaN everywhere: nothing.
  EXPECT_TRUE(viewer::region_outline_segments(region_raster(5, 5)).empty());
  EXPECT_TRUE(viewer::region_outline_segments(HeightField{}).empty());
}

TEST(RegionColour, NeighbouringIndicesGetDistinctBrightColours) {
  for (int i = 0; i < 12; ++i) {
    const Eigen::Vector3f a = viewer::region_colour(i);
    EXPECT_GE(a.maxCoeff(), 0.99F);
    for (int j = i + 1; j < 12; ++j) EXPECT_GT((a - viewer::region_colour(j)).norm(), 0.08F) << i << " vs " << j;
  }
}

class OverlayTest : public ::testing::Test {
 protected:
  haptics::SharedState shared_;
};

/// Pixels within 40 (per channel) of a colour in [0, 1] drawn unlit.
std::size_t pixels_near(const Image& img, const viewer::PixelRect& r, const Eigen::Vector3f& c) {
  std::size_t n = 0;
  for (int y = r.y; y < r.y + r.height; ++y)
    for (int x = r.x; x < r.x + r.width; ++x)
      if (std::abs(img.at(x, y, 0) - 255.0 * c.x()) < 40 && std::abs(img.at(x, y, 1) - 255.0 * c.y()) < 40 &&
          std::abs(img.at(x, y, 2) - 255.0 * c.z()) < 40)
        ++n;
  return n;
}

TEST_F(OverlayTest, RegionOutlinesAreDrawnWhereTheRegionsAreOnlyWhenShown) {
  const HeightField f = test::sinusoid_field(101);  // 0.1 m square about the origin, cell 1 mm
  auto scene = test::display_scene(f, f);
  // A box region over columns 20..59 and rows 30..69 (grid frame −30 .. 9 mm, −20 .. 19 mm).
  HeightField ids(f.geometry());
  for (float& v : ids.values()) v = std::numeric_limits<float>::quiet_NaN();
  paint(ids, 30, 70, 20, 60, 0.0F);
  scene->region_id = std::make_shared<const HeightField>(ids);
  scene->region_names = {"pillar"};
  Viewer v(shared_, test::test_options());
  v.set_scene(scene);
  const Eigen::Vector3f colour = viewer::region_colour(0);
  const Image off = v.capture();
  v.set_show_regions(true);
  const Image on = v.capture();
  const viewer::PixelRect main = v.main_view();
  EXPECT_LT(pixels_near(off, main, colour), 20U) << "the stone and the background are not the overlay's colour";
  // On: the outline's pixels lie on the box's boundary as projected (at the window's top height).
  const GridGeometry& g = f.geometry();
  const double h = 0.5 * g.cell_size_m, z = 0.004;
  const double xa = g.x_of_col(20) - h, xb = g.x_of_col(59) + h, ya = g.y_of_row(30) - h, yb = g.y_of_row(69) + h;
  std::size_t on_line = 0, elsewhere = 0;
  for (int y = main.y; y < main.y + main.height; ++y) {
    for (int x = main.x; x < main.x + main.width; ++x) {
      const bool c = std::abs(on.at(x, y, 0) - 255.0 * colour.x()) < 40 && std::abs(on.at(x, y, 1) - 255.0 * colour.y()) < 40 &&
                     std::abs(on.at(x, y, 2) - 255.0 * colour.z()) < 40;
      if (!c) continue;
      // Distance in pixels to the projected box outline.
      double best = 1e9;
      const Eigen::Vector3d corners[4] = {{xa, ya, z}, {xb, ya, z}, {xb, yb, z}, {xa, yb, z}};
      for (int k = 0; k < 4; ++k) {
        const Eigen::Vector2d p = v.project(corners[k]), q = v.project(corners[(k + 1) % 4]);
        const Eigen::Vector2d d = q - p, w = Eigen::Vector2d(x + 0.5, y + 0.5) - p;
        const double t = std::clamp(w.dot(d) / d.squaredNorm(), 0.0, 1.0);
        best = std::min(best, (w - t * d).norm());
      }
      (best < 2.5 ? on_line : elsewhere)++;
    }
  }
  // The box's perimeter on screen is about 2·(40 + 40) cells; at ≥ 3 px per cell that is
  // hundreds of pixels.
  const double px_per_cell = (v.project({0.001, 0, z}) - v.project({0, 0, z})).norm();
  EXPECT_GT(static_cast<double>(on_line), 0.6 * 160 * px_per_cell);
  EXPECT_LT(elsewhere, on_line / 20 + 10) << "overlay pixels away from the region's outline";
  // The navigation view shows the outline too.
  EXPECT_GT(pixels_near(on, v.navigation_view(), colour), 40U);
  EXPECT_LT(pixels_near(off, v.navigation_view(), colour), 10U);
}

bool is_ball_blue(int r, int g, int b) { return b > r + 25 && b > g + 15; }

TEST_F(OverlayTest, TheProxyBallKeepsItsSizeOnScreenWhateverTheWindowExtent) {
  // Two windows of the same sinusoid, 0.1 m and 0.02 m across, at two view sizes: the ball's
  // radius in pixels follows proxy_ball_radius_px of the view height only.
  for (const int height : {400, 800}) {
    for (const double side : {0.1, 0.02}) {
      viewer::ViewerOptions o = test::test_options();
      o.width_px = static_cast<int>(1.6 * height);
      o.height_px = height;
      Viewer v(shared_, o);
      const HeightField f = test::sinusoid_field(101, side);
      v.set_scene(test::display_scene(f, f));
      haptics::Snapshot s;
      s.tick = 10;
      s.proxy_m = haptics::Vec3::of(Eigen::Vector3d(0.1 * side, 0.1 * side, 0.0045));
      s.hip_m = haptics::Vec3::of(Eigen::Vector3d(0.1 * side, 0.1 * side, 0.0045 + 0.2 * side));  // off the ball
      shared_.snapshots.write(s);
      const Image img = v.capture();
      std::size_t n = 0;
      (void)test::centroid_where(img, v.main_view(), is_ball_blue, n);
      const double radius_px = std::sqrt(static_cast<double>(n) / std::numbers::pi);
      const double expected = Viewer::proxy_ball_radius_px(v.main_view().height);
      EXPECT_NEAR(radius_px, expected, 0.2 * expected + 1.0) << "view height " << height << ", window side " << side;
    }
  }
  EXPECT_EQ(Viewer::proxy_ball_radius_px(100), 5.0);
  EXPECT_EQ(Viewer::proxy_ball_radius_px(1600), 20.0);
}

TEST_F(OverlayTest, ThePanelFitsEveryLabelAtTheDefaultAndTheTestSizes) {
  const HeightField f = test::sinusoid_field(65);
  auto scene = test::display_scene(f, f);
  HeightField ids(f.geometry());
  for (float& v : ids.values()) v = std::numeric_limits<float>::quiet_NaN();
  paint(ids, 10, 30, 10, 30, 0.0F);
  paint(ids, 30, 50, 30, 50, 1.0F);
  scene->region_id = std::make_shared<const HeightField>(ids);
  scene->region_names = {"main pillar", "north frieze", "lintel"};
  for (const auto& [w, h] : {std::pair{1280, 800}, std::pair{1100, 700}}) {
    viewer::ViewerOptions o = test::test_options();
    o.width_px = w;
    o.height_px = h;
    o.show_panel = true;
    o.show_regions = true;
    Viewer v(shared_, o);
    v.set_scene(scene);
    v.capture();  // ImGui lays its windows out on the first frame
    v.capture();
    EXPECT_EQ(v.panel_overflow_px(), 0.0) << w << "x" << h;
  }
}

}  // namespace
}  // namespace hc
