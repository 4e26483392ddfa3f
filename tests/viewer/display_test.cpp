// Display modes of the viewer (issue 12): the scan's colour, shaded grey and the layer map, drawn
// on synthetic scenes whose colours and layers are known, read back as pixels. Oracles: the
// input colours (red left, blue right), R = G = B for grey, and the known order of a ramp.

#include "viewer_fixture.hpp"

#include "hc/common/error.hpp"
#include "hc/viewer/viewer.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

namespace hc {
namespace {

using viewer::DisplayChoice;
using viewer::DisplayMode;
using viewer::Image;
using viewer::MapLayer;
using viewer::Viewer;

constexpr int kN = 101;  // samples per side of the synthetic window (100 mm square)

/// A flat 100 mm window (z = 0) that is its own overview, with the given per-sample layers.
std::shared_ptr<viewer::DisplayScene> flat_scene(const viewer::DisplayLayers& layers) {
  const HeightField flat(GridGeometry{kN, kN, -0.05, -0.05, 0.1 / (kN - 1)}, 0.0F);
  auto s = test::display_scene(flat, HeightField());
  s->window_layers = layers;
  return s;
}

/// Colour layer: columns c < 50 pure red, columns c ≥ 50 pure blue.
std::vector<std::uint8_t> red_left_blue_right() {
  std::vector<std::uint8_t> rgb(3 * kN * kN, 0);
  for (int r = 0; r < kN; ++r) {
    for (int c = 0; c < kN; ++c) {
      const std::size_t k = 3 * (static_cast<std::size_t>(r) * kN + static_cast<std::size_t>(c));
      rgb[k + (c < 50 ? 0 : 2)] = 255;
    }
  }
  return rgb;
}

/// A layer ramp along the columns: v(c) = a + (b − a)·c / (kN − 1).
HeightField column_ramp(double a, double b) {
  HeightField f(GridGeometry{kN, kN, -0.05, -0.05, 0.1 / (kN - 1)});
  for (int r = 0; r < kN; ++r)
    for (int c = 0; c < kN; ++c) f.at(r, c) = static_cast<float>(a + (b - a) * c / (kN - 1.0));
  return f;
}

struct Rgb {
  int r = 0, g = 0, b = 0;
};

/// The pixel under grid point (x, y, 0) in the main view (or the navigation view), averaged over
/// a 3 × 3 block.
Rgb pixel_at(const Image& img, const Eigen::Vector2d& px) {
  Rgb out;
  const int x0 = static_cast<int>(std::lround(px.x())), y0 = static_cast<int>(std::lround(px.y()));
  for (int dy = -1; dy <= 1; ++dy) {
    for (int dx = -1; dx <= 1; ++dx) {
      out.r += img.at(x0 + dx, y0 + dy, 0);
      out.g += img.at(x0 + dx, y0 + dy, 1);
      out.b += img.at(x0 + dx, y0 + dy, 2);
    }
  }
  out.r /= 9;
  out.g /= 9;
  out.b /= 9;
  return out;
}

double x_of_col(int c) { return -0.05 + 0.1 * c / (kN - 1.0); }

/// The t ∈ [0, 1] of the colour map whose chromaticity (each channel over the sum, which the
/// shading's one scale factor does not change) is nearest to the pixel's.
double nearest_map_t(const Rgb& p) {
  const double sum = std::max(1, p.r + p.g + p.b);
  const Eigen::Vector3d q(p.r / sum, p.g / sum, p.b / sum);
  double best_t = -1.0, best_d = 1e9;
  for (int i = 0; i <= 1000; ++i) {
    const Eigen::Vector3d c = viewer::layer_colour_map(i / 1000.0).cast<double>();
    const double d = (c / c.sum() - q).squaredNorm();
    if (d < best_d) best_d = d, best_t = i / 1000.0;
  }
  return best_t;
}

class DisplayTest : public ::testing::Test {
 protected:
  haptics::SharedState shared_;
};

TEST(DisplayChoice, NamesRoundTripAndABadValueNamesTheOptionAndTheChoices) {
  for (const std::string name : {"colour", "grey", "texture", "mu_d", "error"}) {
    EXPECT_EQ(viewer::to_string(viewer::display_choice_from_string(name, "--display")), name);
  }
  EXPECT_EQ(viewer::display_choice_from_string("mu_d", "--display"), (DisplayChoice{DisplayMode::kLayerMap, MapLayer::kMuD}));
  EXPECT_EQ(viewer::display_choice_from_string("grey", "--display").mode, DisplayMode::kGrey);
  for (const std::string bad : {"purple", "", "Colour", "mu-d"}) {
    try {
      (void)viewer::display_choice_from_string(bad, "explore: --display");
      FAIL() << "expected a ConfigError for '" << bad << "'";
    } catch (const ConfigError& e) {
      const std::string m = e.what();
      EXPECT_NE(m.find("--display '" + bad + "'"), std::string::npos) << m;
      EXPECT_NE(m.find("colour, grey, texture, mu_d or error"), std::string::npos) << m;
    }
  }
}

TEST(LayerColourMap, StopsAreTheDocumentedOnesAndTheEndsClamp) {
  const auto near = [](const Eigen::Vector3f& a, const Eigen::Vector3f& b) { return (a - b).cwiseAbs().maxCoeff() < 1e-6F; };
  EXPECT_TRUE(near(viewer::layer_colour_map(0.0), Eigen::Vector3f(0.23F, 0.18F, 0.75F)));
  EXPECT_TRUE(near(viewer::layer_colour_map(0.5), Eigen::Vector3f(0.20F, 0.78F, 0.55F)));
  EXPECT_TRUE(near(viewer::layer_colour_map(1.0), Eigen::Vector3f(0.85F, 0.15F, 0.10F)));
  EXPECT_TRUE(near(viewer::layer_colour_map(-3.0), viewer::layer_colour_map(0.0)));
  EXPECT_TRUE(near(viewer::layer_colour_map(7.0), viewer::layer_colour_map(1.0)));
  // Halfway between two stops: their mean.
  EXPECT_TRUE(near(viewer::layer_colour_map(0.125), Eigen::Vector3f(0.19F, 0.365F, 0.825F)));
  EXPECT_TRUE(near(viewer::layer_colour_map(std::nan("")), Eigen::Vector3f(0.5F, 0.5F, 0.5F)));
}

TEST(LayerRange, PercentileRulesPerLayer) {
  // 0, 1, ..., 100 (and a no-data sample): the 2nd and 98th percentiles are 2 and 98.
  HeightField f(GridGeometry{1, 102, 0, 0, 0.001});
  for (int c = 0; c <= 100; ++c) f.at(0, c) = static_cast<float>(c);
  f.at(0, 101) = kNoData;
  const viewer::LayerRange mu = viewer::layer_range(f, MapLayer::kMuD);
  EXPECT_DOUBLE_EQ(mu.lo, 2.0);
  EXPECT_DOUBLE_EQ(mu.hi, 98.0);
  EXPECT_DOUBLE_EQ(mu.t(50.0), 0.5);
  EXPECT_DOUBLE_EQ(mu.t(-10.0), 0.0);
  EXPECT_DOUBLE_EQ(mu.t(1e9), 1.0);
  const viewer::LayerRange err = viewer::layer_range(f, MapLayer::kError);
  EXPECT_DOUBLE_EQ(err.lo, 0.0);
  EXPECT_DOUBLE_EQ(err.hi, 98.0);
  // Texture: symmetric about 0 from |h| (here −100 ... 0 gives ±98), so h = 0 is the middle.
  for (int c = 0; c <= 100; ++c) f.at(0, c) = static_cast<float>(-c);
  const viewer::LayerRange tex = viewer::layer_range(f, MapLayer::kTexture);
  EXPECT_DOUBLE_EQ(tex.lo, -98.0);
  EXPECT_DOUBLE_EQ(tex.hi, 98.0);
  EXPECT_DOUBLE_EQ(tex.t(0.0), 0.5);
  // No finite sample: an empty but valid range.
  const viewer::LayerRange none = viewer::layer_range(HeightField(GridGeometry{2, 2, 0, 0, 0.001}), MapLayer::kMuD);
  EXPECT_GT(none.hi, none.lo);
  // A constant layer: texture 0 everywhere and μ_d 0.3 everywhere draw in the middle of the map;
  // an error of 0 everywhere at its bottom (no error is the best colour).
  HeightField flat(GridGeometry{3, 3, 0, 0, 0.001}, 0.0f);
  EXPECT_DOUBLE_EQ(viewer::layer_range(flat, MapLayer::kTexture).t(0.0), 0.5);
  EXPECT_DOUBLE_EQ(viewer::layer_range(flat, MapLayer::kError).t(0.0), 0.0);
  HeightField mu_flat(GridGeometry{3, 3, 0, 0, 0.001}, 0.3f);
  const viewer::LayerRange mu_c = viewer::layer_range(mu_flat, MapLayer::kMuD);
  EXPECT_GT(mu_c.hi, mu_c.lo);
  EXPECT_NEAR(mu_c.t(static_cast<double>(0.3f)), 0.5, 1e-6);
}

TEST_F(DisplayTest, ColourModeDrawsTheScansColoursAndGreyModeIsNeutral) {
  viewer::DisplayLayers layers;
  layers.colour_rgb8 = red_left_blue_right();
  viewer::ViewerOptions o = test::test_options();
  ASSERT_EQ(o.display.mode, DisplayMode::kColour);  // the scan's colours by default
  Viewer v(shared_, o);
  v.set_scene(flat_scene(layers));
  const Image colour = v.capture();
  EXPECT_TRUE(v.display_note().empty()) << v.display_note();
  // Main view and navigation view, a quarter of the width in from each side.
  const Eigen::Vector2d left = v.project(Eigen::Vector3d(x_of_col(20), 0.0, 0.0));
  const Eigen::Vector2d right = v.project(Eigen::Vector3d(x_of_col(80), 0.0, 0.0));
  const Eigen::Vector2d nav_left = v.project_navigation(Eigen::Vector3d(x_of_col(20), 0.01, 0.0));
  const Eigen::Vector2d nav_right = v.project_navigation(Eigen::Vector3d(x_of_col(80), 0.01, 0.0));
  for (const auto& [where, px] : {std::pair{"main", left}, std::pair{"navigation", nav_left}}) {
    const Rgb p = pixel_at(colour, px);
    EXPECT_GT(p.r, 100) << where;
    EXPECT_GT(p.r, 4 * std::max(p.g, p.b) + 10) << where << ": " << p.r << " " << p.g << " " << p.b;
  }
  for (const auto& [where, px] : {std::pair{"main", right}, std::pair{"navigation", nav_right}}) {
    const Rgb p = pixel_at(colour, px);
    EXPECT_GT(p.b, 100) << where;
    EXPECT_GT(p.b, 4 * std::max(p.r, p.g) + 10) << where << ": " << p.r << " " << p.g << " " << p.b;
  }

  // Grey: every drawn pixel of both views has R ≈ G ≈ B, and the surface is still lit.
  v.set_display({DisplayMode::kGrey, MapLayer::kTexture});
  const Image grey = v.capture();
  for (const viewer::PixelRect& rect : {v.main_view(), v.navigation_view()}) {
    std::size_t foreground = 0, coloured = 0;
    for (int y = rect.y; y < rect.y + rect.height; ++y) {
      for (int x = rect.x; x < rect.x + rect.width; ++x) {
        if (test::is_background(grey, x, y)) continue;
        const int r = grey.at(x, y, 0), g = grey.at(x, y, 1), b = grey.at(x, y, 2);
        if (r > 200 && g > 170 && b < 80) continue;  // the navigation view's yellow window outline
        if (r < 30 && g < 30 && b < 40) continue;    // the navigation view's own (dark) background
        ++foreground;
        if (std::abs(r - g) > 3 || std::abs(g - b) > 3) ++coloured;
      }
    }
    EXPECT_GT(foreground, static_cast<std::size_t>(rect.width) * static_cast<std::size_t>(rect.height) / 4);
    EXPECT_EQ(coloured, 0U);
  }
  const Rgb g = pixel_at(grey, left);
  EXPECT_GT(g.r, 100);
  // The same grey on both halves (up to the specular highlight, which moves with the view).
  EXPECT_NEAR(g.r, pixel_at(grey, right).r, 8);

  // The cycle of key C: grey → layer map → colour.
  v.cycle_display_mode();
  EXPECT_EQ(v.display().mode, DisplayMode::kLayerMap);
  v.cycle_display_mode();
  EXPECT_EQ(v.display().mode, DisplayMode::kColour);
  const Rgb back = pixel_at(v.capture(), left);
  EXPECT_GT(back.r, 4 * std::max(back.g, back.b) + 10);
}

TEST_F(DisplayTest, ColourModeWithoutAColourLayerFallsBackToGreyAndSaysSo) {
  Viewer v(shared_, test::test_options());
  v.set_scene(flat_scene(viewer::DisplayLayers{}));
  const Image img = v.capture();
  EXPECT_NE(v.display_note().find("no colour"), std::string::npos) << v.display_note();
  const Rgb p = pixel_at(img, v.project(Eigen::Vector3d(0.0, 0.0, 0.0)));
  EXPECT_GT(p.r, 100);
  EXPECT_LE(std::abs(p.r - p.g), 3);
  EXPECT_LE(std::abs(p.g - p.b), 3);
}

TEST_F(DisplayTest, LayerMapColoursFollowTheColourMapAlongAKnownRamp) {
  viewer::DisplayLayers layers;
  layers.texture_m = column_ramp(-0.001, 0.001);  // −1 mm (left) ... +1 mm (right)
  layers.mu_d = column_ramp(0.9, 0.1);            // falls from left to right
  layers.colour_rgb8 = red_left_blue_right();     // present, but not what a layer map shows
  viewer::ViewerOptions o = test::test_options();
  o.display = viewer::display_choice_from_string("texture", "--display");
  Viewer v(shared_, o);
  v.set_scene(flat_scene(layers));
  const auto map_ts = [&](const Image& img) {
    std::vector<double> ts;
    for (int c = 5; c <= 95; c += 10) ts.push_back(nearest_map_t(pixel_at(img, v.project(Eigen::Vector3d(x_of_col(c), 0.0, 0.0)))));
    return ts;
  };
  const std::vector<double> tex = map_ts(v.capture());
  EXPECT_TRUE(v.display_note().empty()) << v.display_note();
  // Range: ±(98th percentile of |h|) ≈ ±0.98 mm.
  EXPECT_NEAR(v.window_range().lo, -0.00098, 2e-5);
  EXPECT_NEAR(v.window_range().hi, 0.00098, 2e-5);
  // The ramp rises left to right: the map position of the pixels rises with it, from the low
  // end to the high end, and matches the value's place in the range.
  for (std::size_t i = 0; i < tex.size(); ++i) {
    const int c = 5 + 10 * static_cast<int>(i);
    const double want = v.window_range().t(-0.001 + 0.002 * c / 100.0);
    EXPECT_NEAR(tex[i], want, 0.05) << "column " << c;
    if (i > 0) {
      EXPECT_GT(tex[i], tex[i - 1]) << "column " << c;
    }
  }
  EXPECT_LT(tex.front(), 0.15);
  EXPECT_GT(tex.back(), 0.85);

  // μ_d falls left to right: so do the map positions (the layer map follows the chosen layer).
  v.cycle_map_layer();  // L: texture → μ_d
  ASSERT_EQ(v.display(), (DisplayChoice{DisplayMode::kLayerMap, MapLayer::kMuD}));
  const std::vector<double> mu = map_ts(v.capture());
  for (std::size_t i = 1; i < mu.size(); ++i) {
    EXPECT_LT(mu[i], mu[i - 1]) << i;
  }
  EXPECT_NEAR(v.window_range().lo, 0.1 + 0.8 * 0.02, 1e-3);  // 2nd and 98th percentiles
  EXPECT_NEAR(v.window_range().hi, 0.1 + 0.8 * 0.98, 1e-3);

  // No cross-check error layer in this scene: grey, and the panel says so.
  v.cycle_map_layer();  // μ_d → error
  const Image none = v.capture();
  EXPECT_NE(v.display_note().find("no cross-check error"), std::string::npos) << v.display_note();
  const Rgb p = pixel_at(none, v.project(Eigen::Vector3d(0.0, 0.0, 0.0)));
  EXPECT_LE(std::abs(p.r - p.g), 3);
  EXPECT_LE(std::abs(p.g - p.b), 3);
}

TEST_F(DisplayTest, CrossCheckErrorMapShowsWhereTheErrorIsLarge) {
  // Error 0 everywhere except a 2 mm band over columns 60..80: those pixels take the map's high
  // end, the others its low end.
  viewer::DisplayLayers layers;
  layers.cell_error_m = column_ramp(0.0, 0.0);
  for (int r = 0; r < kN; ++r)
    for (int c = 60; c <= 80; ++c) layers.cell_error_m.at(r, c) = 0.002F;
  viewer::ViewerOptions o = test::test_options();
  o.display = {DisplayMode::kLayerMap, MapLayer::kError};
  Viewer v(shared_, o);
  v.set_scene(flat_scene(layers));
  const Image img = v.capture();
  EXPECT_TRUE(v.display_note().empty()) << v.display_note();
  EXPECT_DOUBLE_EQ(v.window_range().lo, 0.0);
  EXPECT_NEAR(v.window_range().hi, 0.002, 1e-9);
  EXPECT_LT(nearest_map_t(pixel_at(img, v.project(Eigen::Vector3d(x_of_col(30), 0.0, 0.0)))), 0.1);
  EXPECT_GT(nearest_map_t(pixel_at(img, v.project(Eigen::Vector3d(x_of_col(70), 0.0, 0.0)))), 0.9);
}

TEST_F(DisplayTest, HelpListsTheDisplayKeys) {
  bool c = false, l = false;
  for (const std::string& line : viewer::controls_help()) {
    c |= line.rfind("C ", 0) == 0 && line.find("grey") != std::string::npos;
    l |= line.rfind("L ", 0) == 0 && line.find("cross-check error") != std::string::npos;
  }
  EXPECT_TRUE(c);
  EXPECT_TRUE(l);
}

}  // namespace
}  // namespace hc
