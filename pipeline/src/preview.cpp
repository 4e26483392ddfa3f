#include "image_io.hpp"
#include "hc/common/format.hpp"
#include "hc/pipeline/preview.hpp"

#include "hc/common/error.hpp"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <stdexcept>
#include <cmath>
#include <cstdio>
#include <string>
#include <utility>
#include <vector>

namespace hc::pipeline {
namespace {

constexpr int kMinPreviewPx = 400;

/// The integer factor a preview body of rows x cols samples is enlarged by (nearest neighbour)
/// so that its long side reaches kMinPreviewPx; 1 when it does already. rows, cols >= 1.
int enlargement(int rows, int cols) {
  const int long_side = std::max(rows, cols);
  return long_side >= kMinPreviewPx ? 1 : (kMinPreviewPx + long_side - 1) / long_side;
}

/// Flips rows so +y points up and up-scales a small image (enlargement). The flip is made in
/// `img`'s own pixels (OpenCV's vertical flip swaps row pairs, so in place is exact): a large
/// preview holds no second copy of its body (issue 14: a 4096 x 2048 body is 25 MB, and two
/// previews are drawn at a time).
cv::Mat present(cv::Mat img) {
  cv::flip(img, img, 0);
  const int factor = enlargement(img.rows, img.cols);
  if (factor == 1) return img;
  cv::Mat big;
  cv::resize(img, big, cv::Size(), factor, factor, cv::INTER_NEAREST);
  return big;
}

/// Width [px] of `text` in OpenCV's Hershey simplex font at `scale`, thickness 1.
int text_width(const std::string& text, double scale) {
  int baseline = 0;
  return cv::getTextSize(text, cv::FONT_HERSHEY_SIMPLEX, scale, 1, &baseline).width;
}

/// `body` under a white strip of two lines, `title` (scale 0.5) and `legend` (scale 0.4),
/// widened (white on the right) when a line is wider than the body.
cv::Mat with_title(const cv::Mat& body, const std::string& title, const std::string& legend) {
  const int title_h = 44;
  const int width = std::max({body.cols, text_width(title, 0.5) + 12, text_width(legend, 0.4) + 12});
  cv::Mat canvas(body.rows + title_h, width, CV_8UC3, cv::Scalar(255, 255, 255));
  body.copyTo(canvas(cv::Rect(0, title_h, body.cols, body.rows)));
  cv::putText(canvas, title, {6, 18}, cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0), 1);
  cv::putText(canvas, legend, {6, 36}, cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0), 1);
  return canvas;
}

void save(const cv::Mat& img, const std::filesystem::path& png) {
  if (img.depth() != CV_8U || (img.channels() != 1 && img.channels() != 3)) {
    throw InputError(png.string() + ": cannot write the preview: not an 8-bit grey or colour image");
  }
  // Fast zlib level: previews are for people, a few % larger files save most of the write time.
  const std::string why = detail::write_png(png, img.ptr<std::uint8_t>(0), img.cols, img.rows,
                                            img.channels() == 1 ? detail::PixelFormat::kGray : detail::PixelFormat::kBgr,
                                            img.step[0], /*fast=*/true);
  if (!why.empty()) throw InputError(png.string() + ": cannot write the preview: " + why);
}


}  // namespace

ColourBar colour_bar(const HeightField& layer, double scale) {
  ColourBar bar;
  std::vector<float> finite;
  finite.reserve(layer.values().size());
  for (float v : layer.values())
    if (std::isfinite(v)) finite.push_back(v);
  if (finite.empty()) {
    bar.lo_label = format_number(bar.lo * scale, 3);
    bar.hi_label = format_number(bar.hi * scale, 3);
    return bar;
  }
  const auto [mn, mx] = std::minmax_element(finite.begin(), finite.end());
  bar.min = *mn;
  bar.max = *mx;
  const auto k1 = finite.size() / 100, k99 = finite.size() - 1 - finite.size() / 100;
  std::nth_element(finite.begin(), finite.begin() + static_cast<std::ptrdiff_t>(k1), finite.end());
  bar.lo = finite[k1];
  std::nth_element(finite.begin(), finite.begin() + static_cast<std::ptrdiff_t>(k99), finite.end());
  bar.hi = finite[k99];
  if (!(bar.hi > bar.lo)) {
    // A flat range: widen it by a relative step float can represent.
    bar.hi = bar.lo + std::max(1e-12, 1e-6 * std::abs(bar.lo));
  }
  bar.clipped_low = bar.min < bar.lo;
  bar.clipped_high = bar.max > bar.hi;
  for (int digits = 3; digits <= 12; ++digits) {
    bar.lo_label = format_number(bar.lo * scale, digits);
    bar.hi_label = format_number(bar.hi * scale, digits);
    if (bar.lo_label != bar.hi_label) break;
  }
  if (bar.clipped_low) bar.min_label = "min " + format_number(bar.min * scale, 3);
  if (bar.clipped_high) bar.max_label = "max " + format_number(bar.max * scale, 3);
  return bar;
}

void write_colour_preview(const HeightField& layer, const std::filesystem::path& png,
                          const std::string& title, const std::string& unit, double scale,
                          const std::vector<std::array<int, 2>>& marks) {
  if (layer.rows() < 1 || layer.cols() < 1) {
    throw InputError(png.string() + ": cannot write the preview: the layer is empty (" + std::to_string(layer.cols()) +
                     " x " + std::to_string(layer.rows()) + " samples; expected at least 1 x 1)");
  }
  const ColourBar bar = colour_bar(layer, scale);
  const double lo = bar.lo, hi = bar.hi;
  // The body's size as present() makes it: the layer's, or enlarged by an integer factor.
  const int factor = enlargement(layer.rows(), layer.cols());
  const cv::Size body_size(layer.cols() * factor, layer.rows() * factor);
  // Legend: a vertical colour bar with range labels (clipped ends: a triangle and the true
  // extreme), and a title strip. The margin and the width fit the longest label and the title,
  // so no text is ever cut off.
  const int bar_w = 24, title_h = 30, foot_h = 20;
  const std::string full_title = title + " (grey: no data; +y up)";
  const std::string foot = "colours span the 1st-99th percentile; triangles: values beyond it";
  const bool clipped = bar.clipped_low || bar.clipped_high;
  int label_w = std::max({text_width(bar.hi_label, 0.35), text_width(bar.lo_label, 0.35), text_width(unit, 0.45)});
  if (!bar.max_label.empty()) label_w = std::max(label_w, text_width(bar.max_label, 0.3));
  if (!bar.min_label.empty()) label_w = std::max(label_w, text_width(bar.min_label, 0.3));
  const int margin = std::max(110, 8 + bar_w + 4 + label_w + 8);
  const int width = std::max({body_size.width + margin, text_width(full_title, 0.5) + 12, clipped ? text_width(foot, 0.4) + 12 : 0});
  // The legend needs about 100 px of height (range, extreme and unit labels): a short, wide
  // layer gets white space below it rather than overlapping labels.
  const int legend_h = 100;
  const int body_h = std::max(body_size.height, legend_h + 20);
  cv::Mat canvas(body_h + title_h + foot_h, width, CV_8UC3, cv::Scalar(255, 255, 255));
  // The body: each cell's turbo colour (OpenCV's map of its 8-bit index, the same as
  // cv::applyColorMap on the index image) and grey (90) for no data, drawn straight into the
  // canvas with rows flipped (+y up), so that no full-size index, mask or colour image is held
  // beside the canvas (issue 14: at 4096 x 2048 samples those were 67 MB a preview, two previews
  // drawn at a time); an enlarged body is drawn small and then enlarged into the canvas.
  cv::Mat lut;
  {
    cv::Mat ramp(1, 256, CV_8UC1);
    for (int i = 0; i < 256; ++i) ramp.at<std::uint8_t>(0, i) = static_cast<std::uint8_t>(i);
    cv::applyColorMap(ramp, lut, cv::COLORMAP_TURBO);
  }
  cv::Mat body = canvas(cv::Rect(0, title_h, body_size.width, body_size.height));
  {
    cv::Mat small;
    if (factor > 1) small.create(layer.rows(), layer.cols(), CV_8UC3);
    cv::Mat& to = factor > 1 ? small : body;
    const cv::Vec3b grey(90, 90, 90);
    const cv::Vec3b* turbo = lut.ptr<cv::Vec3b>(0);
    for (int r = 0; r < layer.rows(); ++r) {
      auto* row = to.ptr<cv::Vec3b>(layer.rows() - 1 - r);
      for (int c = 0; c < layer.cols(); ++c) {
        const float v = layer.at(r, c);
        if (!std::isfinite(v)) {
          row[c] = grey;
        } else {
          const auto i = static_cast<std::uint8_t>(std::clamp((v - lo) / (hi - lo) * 255.0, 0.0, 255.0));
          row[c] = turbo[i];
        }
      }
    }
    // Into the canvas's own pixels: the destination already has the size and type asked for.
    if (factor > 1) cv::resize(small, body, body_size, 0, 0, cv::INTER_NEAREST);
  }
  if (!marks.empty()) {
    // Rows flipped and enlarged by an integer factor: map (row, col) the same way. Circles are
    // clipped at the body's edge (body is a view of the canvas with its own bounds).
    const double f = factor;
    const int radius = std::max(4, static_cast<int>(std::lround(3.0 * f)));
    for (const auto& m : marks) {
      const cv::Point centre(static_cast<int>((m[1] + 0.5) * f), static_cast<int>((layer.rows() - 1 - m[0] + 0.5) * f));
      cv::circle(body, centre, radius, cv::Scalar(255, 0, 255), 1, cv::LINE_AA);
    }
  }
  const int bar_top = title_h + 10, bar_h = body_h - 20;
  cv::Mat ramp(bar_h, 1, CV_8UC1);
  for (int r = 0; r < bar_h; ++r)
    ramp.at<std::uint8_t>(r, 0) = static_cast<std::uint8_t>(255 - (255 * r) / std::max(1, bar_h - 1));
  cv::Mat ramp_col;
  cv::applyColorMap(ramp, ramp_col, cv::COLORMAP_TURBO);
  cv::resize(ramp_col, ramp_col, cv::Size(bar_w, bar_h), 0, 0, cv::INTER_NEAREST);
  const int bar_x = body_size.width + 8;
  ramp_col.copyTo(canvas(cv::Rect(bar_x, bar_top, bar_w, bar_h)));
  const cv::Scalar black(0, 0, 0);
  auto triangle = [&](int tip_y, int base_y) {
    const std::vector<cv::Point> pts{{bar_x + bar_w / 2, tip_y}, {bar_x, base_y}, {bar_x + bar_w, base_y}};
    cv::fillConvexPoly(canvas, pts, black, cv::LINE_AA);
  };
  if (bar.clipped_high) triangle(bar_top - 9, bar_top - 1);
  if (bar.clipped_low) triangle(bar_top + bar_h + 9, bar_top + bar_h + 1);
  const int text_x = bar_x + bar_w + 4;
  cv::putText(canvas, bar.hi_label, {text_x, bar_top + 8}, cv::FONT_HERSHEY_SIMPLEX, 0.35, black, 1);
  cv::putText(canvas, bar.lo_label, {text_x, bar_top + bar_h}, cv::FONT_HERSHEY_SIMPLEX, 0.35, black, 1);
  if (!bar.max_label.empty()) cv::putText(canvas, bar.max_label, {text_x, bar_top + 22}, cv::FONT_HERSHEY_SIMPLEX, 0.3, black, 1);
  if (!bar.min_label.empty()) cv::putText(canvas, bar.min_label, {text_x, bar_top + bar_h - 14}, cv::FONT_HERSHEY_SIMPLEX, 0.3, black, 1);
  cv::putText(canvas, unit, {text_x, bar_top + bar_h / 2}, cv::FONT_HERSHEY_SIMPLEX, 0.45, black, 1);
  cv::putText(canvas, full_title, {6, 20}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1);
  if (clipped) cv::putText(canvas, foot, {6, title_h + body_h + 14}, cv::FONT_HERSHEY_SIMPLEX, 0.4, black, 1);
  save(canvas, png);
}

namespace {

/// Hillshade grey level per cell (40 + 215 · Lambert, 8 bit), 0 where the depth is no data.
cv::Mat hillshade_grey(const HeightField& depth_m) {
  const int rows = depth_m.rows(), cols = depth_m.cols();
  const double cell = depth_m.cell_size_m();
  const double azimuth = 315.0 * M_PI / 180.0, altitude = 45.0 * M_PI / 180.0;
  // Light direction in the grid frame (x east, y north, z up): from the north-west.
  const double lx = std::cos(altitude) * std::sin(azimuth), ly = std::cos(altitude) * std::cos(azimuth);
  const double lz = std::sin(altitude);
  cv::Mat grey(rows, cols, CV_8UC1, cv::Scalar(0));
  auto z = [&](int r, int c, float centre) {
    r = std::clamp(r, 0, rows - 1);
    c = std::clamp(c, 0, cols - 1);
    const float v = depth_m.at(r, c);
    return std::isfinite(v) ? static_cast<double>(v) : static_cast<double>(centre);
  };
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      const float zc = depth_m.at(r, c);
      if (!std::isfinite(zc)) continue;
      // Horn's 3×3 weighted differences.
      const double dzdx = ((z(r - 1, c + 1, zc) + 2 * z(r, c + 1, zc) + z(r + 1, c + 1, zc)) -
                           (z(r - 1, c - 1, zc) + 2 * z(r, c - 1, zc) + z(r + 1, c - 1, zc))) / (8 * cell);
      const double dzdy = ((z(r + 1, c - 1, zc) + 2 * z(r + 1, c, zc) + z(r + 1, c + 1, zc)) -
                           (z(r - 1, c - 1, zc) + 2 * z(r - 1, c, zc) + z(r - 1, c + 1, zc))) / (8 * cell);
      const double norm = std::sqrt(dzdx * dzdx + dzdy * dzdy + 1.0);
      const double lambert = std::max(0.0, (-dzdx * lx - dzdy * ly + lz) / norm);
      grey.at<std::uint8_t>(r, c) = static_cast<std::uint8_t>(std::clamp(40.0 + 215.0 * lambert, 0.0, 255.0));
    }
  }
  return grey;
}

}  // namespace

namespace {

constexpr const char* kHillshadeLegend = "light from the north-west; grey: no data; +y up";

/// The hillshade image of write_hillshade_preview without its title strip (flipped, enlarged).
cv::Mat hillshade_body(const HeightField& depth_m) {
  cv::Mat grey = hillshade_grey(depth_m);
  cv::Mat shade(depth_m.rows(), depth_m.cols(), CV_8UC3, cv::Scalar(90, 90, 90));
  for (int r = 0; r < depth_m.rows(); ++r) {
    for (int c = 0; c < depth_m.cols(); ++c) {
      if (!std::isfinite(depth_m.at(r, c))) continue;
      const std::uint8_t g = grey.at<std::uint8_t>(r, c);
      shade.at<cv::Vec3b>(r, c) = cv::Vec3b(g, g, g);
    }
  }
  grey.release();
  return present(std::move(shade));
}

}  // namespace

void write_hillshade_preview(const HeightField& depth_m, const std::filesystem::path& png, const std::string& title) {
  save(with_title(hillshade_body(depth_m), title, kHillshadeLegend), png);
}

void write_hillshades_side_by_side(const std::vector<const HeightField*>& fields, const std::vector<std::string>& titles,
                                   const std::filesystem::path& png, int max_height_px) {
  if (fields.empty() || fields.size() != titles.size()) {
    throw std::invalid_argument("write_hillshades_side_by_side: " + std::to_string(fields.size()) + " fields, " +
                                std::to_string(titles.size()) + " titles (expected as many, at least one)");
  }
  std::vector<cv::Mat> bodies;
  for (const HeightField* f : fields) bodies.push_back(hillshade_body(*f));
  const int height = std::min(max_height_px, bodies.front().rows);
  std::vector<cv::Mat> row;
  for (std::size_t i = 0; i < bodies.size(); ++i) {
    cv::Mat scaled;
    const double f = static_cast<double>(height) / bodies[i].rows;
    cv::resize(bodies[i], scaled, cv::Size(std::max(1, static_cast<int>(std::lround(bodies[i].cols * f))), height), 0, 0,
               f >= 1.0 ? cv::INTER_NEAREST : cv::INTER_AREA);
    // The strip at full size after scaling: every title stays readable.
    const cv::Mat panel = with_title(scaled, titles[i], i == 0 ? kHillshadeLegend : "");
    if (!row.empty()) row.push_back(cv::Mat(panel.rows, 8, CV_8UC3, cv::Scalar(255, 255, 255)));
    row.push_back(panel);
  }
  cv::Mat composite;
  cv::hconcat(row, composite);
  save(composite, png);
}

void write_rgb_preview(const HeightField& depth_m, std::span<const std::uint8_t> colour_rgb8,
                       const std::filesystem::path& png, bool shaded) {
  const int rows = depth_m.rows(), cols = depth_m.cols();
  const std::size_t cells = static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols);
  if (colour_rgb8.size() != 3 * cells) {
    throw InputError(png.string() + ": the colour layer holds " + std::to_string(colour_rgb8.size()) +
                     " bytes for a " + std::to_string(cols) + " x " + std::to_string(rows) + " grid (expected " +
                     std::to_string(3 * cells) + ")");
  }
  cv::Mat grey;
  if (shaded) grey = hillshade_grey(depth_m);
  cv::Mat img(rows, cols, CV_8UC3, cv::Scalar(90, 90, 90));
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      if (!std::isfinite(depth_m.at(r, c))) continue;
      const std::uint8_t* rgb = colour_rgb8.data() + 3 * (static_cast<std::size_t>(r) * static_cast<std::size_t>(cols) +
                                                          static_cast<std::size_t>(c));
      const double f = shaded ? grey.at<std::uint8_t>(r, c) / 255.0 : 1.0;
      auto ch = [&](std::uint8_t v) { return static_cast<std::uint8_t>(std::lround(v * f)); };
      img.at<cv::Vec3b>(r, c) = cv::Vec3b(ch(rgb[2]), ch(rgb[1]), ch(rgb[0]));  // OpenCV is BGR
    }
  }
  grey.release();
  save(present(std::move(img)), png);
}

std::vector<std::array<int, 2>> marks_on_level(const std::vector<std::array<int, 2>>& marks, int level,
                                               const GridGeometry& level_grid) {
  if (level < 0 || level > 30) throw std::invalid_argument("marks_on_level: level " + std::to_string(level) + " outside [0, 30]");
  std::vector<std::array<int, 2>> at;
  at.reserve(marks.size());
  const long long half = level == 0 ? 0 : 1LL << (level - 1);
  for (const auto& m : marks) {
    // (i + 2^(k-1)) >> k rounds i / 2^k to the nearest integer, a half up.
    const auto near = [&](int i, int last) { return static_cast<int>(std::min<long long>(last, (i + half) >> level)); };
    at.push_back({near(m[0], level_grid.rows - 1), near(m[1], level_grid.cols - 1)});
  }
  return at;
}

}  // namespace hc::pipeline
