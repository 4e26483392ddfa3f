#include "hc/common/format.hpp"
#include "hc/pipeline/preview.hpp"

#include "hc/common/error.hpp"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

namespace hc::pipeline {
namespace {

constexpr int kMinPreviewPx = 400;

/// Up-scales small images (nearest neighbour) and flips rows so +y points up.
cv::Mat present(const cv::Mat& img) {
  cv::Mat flipped;
  cv::flip(img, flipped, 0);
  const int long_side = std::max(img.rows, img.cols);
  if (long_side >= kMinPreviewPx) return flipped;
  const int factor = (kMinPreviewPx + long_side - 1) / long_side;
  cv::Mat big;
  cv::resize(flipped, big, cv::Size(), factor, factor, cv::INTER_NEAREST);
  return big;
}

void save(const cv::Mat& img, const std::filesystem::path& png) {
  bool ok = false;
  try {
    // Fast zlib level: previews are for people, a few % larger files save most of the write time.
    ok = cv::imwrite(png.string(), img, {cv::IMWRITE_PNG_COMPRESSION, 1});
  } catch (const cv::Exception& e) {
    throw InputError(png.string() + ": cannot write the preview: " + e.what());
  }
  if (!ok) throw InputError(png.string() + ": cannot write the preview");
}


}  // namespace

void write_colour_preview(const HeightField& layer, const std::filesystem::path& png,
                          const std::string& title, const std::string& unit, double scale) {
  std::vector<float> finite;
  finite.reserve(layer.values().size());
  for (float v : layer.values())
    if (std::isfinite(v)) finite.push_back(v);
  double lo = 0.0, hi = 1.0;
  if (!finite.empty()) {
    const auto k1 = finite.size() / 100, k99 = finite.size() - 1 - finite.size() / 100;
    std::nth_element(finite.begin(), finite.begin() + static_cast<std::ptrdiff_t>(k1), finite.end());
    lo = finite[k1];
    std::nth_element(finite.begin(), finite.begin() + static_cast<std::ptrdiff_t>(k99), finite.end());
    hi = finite[k99];
    if (!(hi > lo)) hi = lo + 1e-12;
  }
  cv::Mat idx(layer.rows(), layer.cols(), CV_8UC1);
  cv::Mat nodata(layer.rows(), layer.cols(), CV_8UC1, cv::Scalar(0));
  for (int r = 0; r < layer.rows(); ++r) {
    for (int c = 0; c < layer.cols(); ++c) {
      const float v = layer.at(r, c);
      if (!std::isfinite(v)) {
        nodata.at<std::uint8_t>(r, c) = 255;
        idx.at<std::uint8_t>(r, c) = 0;
      } else {
        idx.at<std::uint8_t>(r, c) =
            static_cast<std::uint8_t>(std::clamp((v - lo) / (hi - lo) * 255.0, 0.0, 255.0));
      }
    }
  }
  cv::Mat colour;
  cv::applyColorMap(idx, colour, cv::COLORMAP_TURBO);
  colour.setTo(cv::Scalar(90, 90, 90), nodata);
  const cv::Mat body = present(colour);

  // Legend: a vertical colour bar with min/max labels, and a title strip.
  const int bar_w = 24, margin = 90, title_h = 30;
  cv::Mat canvas(body.rows + title_h, body.cols + margin, CV_8UC3, cv::Scalar(255, 255, 255));
  body.copyTo(canvas(cv::Rect(0, title_h, body.cols, body.rows)));
  cv::Mat ramp(body.rows, 1, CV_8UC1);
  for (int r = 0; r < body.rows; ++r)
    ramp.at<std::uint8_t>(r, 0) = static_cast<std::uint8_t>(255 - (255 * r) / std::max(1, body.rows - 1));
  cv::Mat ramp_col;
  cv::applyColorMap(ramp, ramp_col, cv::COLORMAP_TURBO);
  cv::resize(ramp_col, ramp_col, cv::Size(bar_w, body.rows), 0, 0, cv::INTER_NEAREST);
  ramp_col.copyTo(canvas(cv::Rect(body.cols + 8, title_h, bar_w, body.rows)));
  const cv::Scalar black(0, 0, 0);
  cv::putText(canvas, hc::format_number(hi * scale, 3), {body.cols + 8 + bar_w + 4, title_h + 12}, cv::FONT_HERSHEY_SIMPLEX, 0.4, black, 1);
  cv::putText(canvas, hc::format_number(lo * scale, 3), {body.cols + 8 + bar_w + 4, title_h + body.rows - 4}, cv::FONT_HERSHEY_SIMPLEX, 0.4, black, 1);
  cv::putText(canvas, unit, {body.cols + 8 + bar_w + 4, title_h + body.rows / 2}, cv::FONT_HERSHEY_SIMPLEX, 0.45, black, 1);
  cv::putText(canvas, title + " (grey: no data; +y up)", {6, 20}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1);
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

void write_hillshade_preview(const HeightField& depth_m, const std::filesystem::path& png) {
  const cv::Mat grey = hillshade_grey(depth_m);
  cv::Mat shade(depth_m.rows(), depth_m.cols(), CV_8UC3, cv::Scalar(90, 90, 90));
  for (int r = 0; r < depth_m.rows(); ++r) {
    for (int c = 0; c < depth_m.cols(); ++c) {
      if (!std::isfinite(depth_m.at(r, c))) continue;
      const std::uint8_t g = grey.at<std::uint8_t>(r, c);
      shade.at<cv::Vec3b>(r, c) = cv::Vec3b(g, g, g);
    }
  }
  save(present(shade), png);
}

void write_rgb_preview(const HeightField& depth_m, const std::vector<std::uint8_t>& colour_rgb8,
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
  save(present(img), png);
}

}  // namespace hc::pipeline
