// Previews: titles and colour-bar labels are never cut off, whatever their length. The oracle is
// the image itself: ink (any non-white pixel) never touches the right border of the canvas,
// and the title strip holds ink.

#include "hc/pipeline/preview.hpp"

#include "test_paths.hpp"
#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include <filesystem>
#include <string>

namespace hc::pipeline {
namespace {

namespace fs = std::filesystem;

bool column_is_white(const cv::Mat& img, int col, int row_begin, int row_end) {
  for (int r = row_begin; r < row_end; ++r) {
    const cv::Vec3b p = img.at<cv::Vec3b>(r, col);
    if (p[0] != 255 || p[1] != 255 || p[2] != 255) return false;
  }
  return true;
}

bool has_ink(const cv::Mat& img, int row_begin, int row_end) {
  for (int r = row_begin; r < row_end; ++r)
    for (int c = 0; c < img.cols; ++c) {
      const cv::Vec3b p = img.at<cv::Vec3b>(r, c);
      if (p[0] < 128 && p[1] < 128 && p[2] < 128) return true;
    }
  return false;
}

TEST(Previews, LongColourBarLabelsAndTitlesAreNeverCutOff) {
  // Values 1e6 m apart by 1 µm: the labels need all their digits (in mm, "1000000000.001"),
  // and one spike clips the bar (a "max" label and the footnote).
  HeightField h(GridGeometry{10, 10, 0.0, 0.0, 0.001});
  for (int i = 0; i < 100; ++i) h.values()[static_cast<std::size_t>(i)] = static_cast<float>(1e6 + 0.0625 * (i % 7));
  h.values()[0] = 5e6f;
  const fs::path png = hc::test::temp_dir("preview_labels") / "long.png";
  const std::string title(90, 'T');
  write_colour_preview(h, png, title, "mm", 1000.0);
  const cv::Mat img = cv::imread(png.string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(img.empty());
  EXPECT_TRUE(has_ink(img, 0, 30));
  EXPECT_TRUE(column_is_white(img, img.cols - 1, 0, img.rows));
  EXPECT_TRUE(column_is_white(img, img.cols - 2, 0, img.rows));
}

TEST(Previews, HillshadeHasATitleStripThatWidensTheImageWhenNeeded) {
  HeightField h(GridGeometry{8, 8, 0.0, 0.0, 0.001});
  for (int r = 0; r < 8; ++r)
    for (int c = 0; c < 8; ++c) h.at(r, c) = static_cast<float>(0.001 * r);
  const fs::path dir = hc::test::temp_dir("preview_hillshade");
  write_hillshade_preview(h, dir / "h.png", std::string(80, 'L'));
  const cv::Mat img = cv::imread((dir / "h.png").string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(img.empty());
  // The 8 × 8 grid is enlarged to 400 px (factor 50) under a 44 px title strip.
  EXPECT_EQ(img.rows, 400 + 44);
  EXPECT_GT(img.cols, 400);  // widened for the title
  EXPECT_TRUE(has_ink(img, 0, 44));
  EXPECT_TRUE(column_is_white(img, img.cols - 1, 0, img.rows));
}

}  // namespace
}  // namespace hc::pipeline
