#pragma once
/// @file viewer_fixture.hpp
/// Helpers of the viewer tests: analytic scenes, pixel statistics of captured frames.
/// The tests run under Xvfb with Mesa's software OpenGL (scripts/test starts it).

#include "hc/common/height_field.hpp"
#include "hc/haptics/workspace_map.hpp"
#include "hc/viewer/viewer.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <numbers>

namespace hc::test {

/// The paper's sinusoid z = A·sin(2πx/λ)·sin(2πy/λ), A = 4 mm, λ = 40 mm, over a square of
/// side `side_m` centred on (cx, cy), n × n samples.
inline HeightField sinusoid_field(int n, double side_m = 0.1, double cx = 0.0, double cy = 0.0) {
  const double cell = side_m / (n - 1);
  const GridGeometry g{n, n, cx - side_m / 2, cy - side_m / 2, cell};
  HeightField f(g);
  const double k = 2 * std::numbers::pi / 0.04;
  for (int r = 0; r < n; ++r) {
    for (int c = 0; c < n; ++c) {
      f.at(r, c) = static_cast<float>(0.004 * std::sin(k * g.x_of_col(c)) * std::sin(k * g.y_of_row(r)));
    }
  }
  return f;
}

/// The cells of `f` inside [x0, x1] × [y0, y1] (a window).
inline HeightField crop(const HeightField& f, int r0, int c0, int rows, int cols) {
  const GridGeometry& g = f.geometry();
  HeightField w(GridGeometry{rows, cols, g.x_of_col(c0), g.y_of_row(r0), g.cell_size_m});
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) w.at(r, c) = f.at(r0 + r, c0 + c);
  w.model_to_grid = f.model_to_grid;
  return w;
}

/// Display scene of a window with the whole field as overview; workspace fitted to the window.
inline std::shared_ptr<viewer::DisplayScene> display_scene(HeightField window, HeightField overview, int level = 0,
                                                           int levels = 1) {
  auto s = std::make_shared<viewer::DisplayScene>();
  const GridGeometry& g = window.geometry();
  double lo = 1e9, hi = -1e9;
  for (float v : window.values())
    if (std::isfinite(v)) lo = std::min(lo, static_cast<double>(v)), hi = std::max(hi, static_cast<double>(v));
  s->workspace = haptics::WorkspaceMap::fit(Eigen::Vector3d(0.05, 0.05, 0.05), g.x0_m, g.x_of_col(g.cols - 1), g.y0_m,
                                            g.y_of_row(g.rows - 1), 0.5 * (lo + hi));
  s->window = std::move(window);
  s->overview = std::move(overview);
  s->level = level;
  s->level_count = levels;
  s->description = "test scene";
  return s;
}

/// Luminance statistics of the pixels of `rect` that differ from the background colour.
struct RegionStats {
  std::size_t pixels = 0;       ///< pixels in the rectangle
  std::size_t foreground = 0;   ///< pixels that are not background
  double mean_luma = 0.0;       ///< over foreground pixels [0, 255]
  double stddev_luma = 0.0;
  int distinct_luma = 0;        ///< distinct integer luminance values among foreground pixels
  double centroid_x = 0.0, centroid_y = 0.0;  ///< of the foreground pixels
};

inline double luma(const viewer::Image& img, int x, int y) {
  return 0.299 * img.at(x, y, 0) + 0.587 * img.at(x, y, 1) + 0.114 * img.at(x, y, 2);
}

/// Background is the viewer's clear colour (0.08, 0.09, 0.11) → (20, 23, 28).
inline bool is_background(const viewer::Image& img, int x, int y) {
  return std::abs(img.at(x, y, 0) - 20) <= 3 && std::abs(img.at(x, y, 1) - 23) <= 3 && std::abs(img.at(x, y, 2) - 28) <= 3;
}

inline RegionStats region_stats(const viewer::Image& img, const viewer::PixelRect& rect) {
  RegionStats s;
  double sum = 0, sum2 = 0, sx = 0, sy = 0;
  bool seen[256] = {};
  for (int y = rect.y; y < rect.y + rect.height; ++y) {
    for (int x = rect.x; x < rect.x + rect.width; ++x) {
      ++s.pixels;
      if (is_background(img, x, y)) continue;
      ++s.foreground;
      const double l = luma(img, x, y);
      sum += l;
      sum2 += l * l;
      sx += x;
      sy += y;
      seen[static_cast<int>(l)] = true;
    }
  }
  if (s.foreground > 0) {
    const auto n = static_cast<double>(s.foreground);
    s.mean_luma = sum / n;
    s.stddev_luma = std::sqrt(std::max(0.0, sum2 / n - s.mean_luma * s.mean_luma));
    s.centroid_x = sx / n;
    s.centroid_y = sy / n;
  }
  s.distinct_luma = static_cast<int>(std::count(std::begin(seen), std::end(seen), true));
  return s;
}

/// Centroid of the pixels selected by `pick(r, g, b)`; count in `n`.
template <class Pick>
Eigen::Vector2d centroid_where(const viewer::Image& img, const viewer::PixelRect& rect, Pick pick, std::size_t& n) {
  double sx = 0, sy = 0;
  n = 0;
  for (int y = rect.y; y < rect.y + rect.height; ++y) {
    for (int x = rect.x; x < rect.x + rect.width; ++x) {
      if (pick(img.at(x, y, 0), img.at(x, y, 1), img.at(x, y, 2))) {
        sx += x;
        sy += y;
        ++n;
      }
    }
  }
  return n ? Eigen::Vector2d(sx / static_cast<double>(n), sy / static_cast<double>(n)) : Eigen::Vector2d(-1, -1);
}

/// Fraction of pixels of `rect` that differ (any channel by more than `tol`) between a and b.
inline double fraction_changed(const viewer::Image& a, const viewer::Image& b, const viewer::PixelRect& rect, int tol = 8) {
  std::size_t changed = 0, total = 0;
  for (int y = rect.y; y < rect.y + rect.height; ++y) {
    for (int x = rect.x; x < rect.x + rect.width; ++x) {
      ++total;
      for (int ch = 0; ch < 3; ++ch) {
        if (std::abs(a.at(x, y, ch) - b.at(x, y, ch)) > tol) {
          ++changed;
          break;
        }
      }
    }
  }
  return total ? static_cast<double>(changed) / static_cast<double>(total) : 0.0;
}

inline viewer::ViewerOptions test_options() {
  viewer::ViewerOptions o;
  o.width_px = 800;
  o.height_px = 500;
  o.visible = false;
  o.vsync = false;
  o.max_fps = 0.0;
  o.show_panel = false;
  return o;
}

}  // namespace hc::test
