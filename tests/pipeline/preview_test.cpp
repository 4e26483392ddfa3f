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

TEST(Previews, LongLabelsUnderAShortTitleAndAShortWideLayerKeepTheLegendReadable) {
  // A short title: only the labels can widen the canvas (the old fixed 110 px margin cut them).
  HeightField h(GridGeometry{10, 10, 0.0, 0.0, 0.001});
  for (int i = 0; i < 100; ++i) h.values()[static_cast<std::size_t>(i)] = static_cast<float>(1e6 + 0.0625 * (i % 7));
  h.values()[0] = 5e6f;
  const fs::path dir = hc::test::temp_dir("preview_short_title");
  write_colour_preview(h, dir / "a.png", "z", "mm", 1000.0);
  const cv::Mat a = cv::imread((dir / "a.png").string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(a.empty());
  EXPECT_TRUE(column_is_white(a, a.cols - 1, 0, a.rows));
  EXPECT_TRUE(column_is_white(a, a.cols - 2, 0, a.rows));
  // 1000 × 3 cells: 1000 px wide and 3 px high before the legend; the canvas makes room for
  // the legend, so no ink touches the bottom row either.
  HeightField w(GridGeometry{3, 1000, 0.0, 0.0, 0.001});
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 1000; ++c) w.at(r, c) = static_cast<float>(0.001 * c);
  w.at(0, 0) = 10.0f;  // clipped: the extreme labels are drawn too
  write_colour_preview(w, dir / "w.png", "wide", "mm", 1000.0);
  const cv::Mat b = cv::imread((dir / "w.png").string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(b.empty());
  EXPECT_GE(b.rows, 30 + 100 + 20);
  bool bottom_white = true;
  for (int c = 0; c < b.cols; ++c) {
    const cv::Vec3b p = b.at<cv::Vec3b>(b.rows - 1, c);
    bottom_white = bottom_white && p[0] == 255 && p[1] == 255 && p[2] == 255;
  }
  EXPECT_TRUE(bottom_white);
  EXPECT_TRUE(column_is_white(b, b.cols - 1, 0, b.rows));
}

TEST(Previews, SideBySideLevelsKeepFullSizeTitlesWhenReduced) {
  HeightField big(GridGeometry{1200, 1200, 0.0, 0.0, 0.001});
  for (int r = 0; r < 1200; ++r)
    for (int c = 0; c < 1200; ++c) big.at(r, c) = static_cast<float>(0.0001 * ((r + c) % 50));
  HeightField small(GridGeometry{600, 600, 0.0, 0.0, 0.002});
  for (int r = 0; r < 600; ++r)
    for (int c = 0; c < 600; ++c) small.at(r, c) = 0.0f;
  const fs::path png = hc::test::temp_dir("preview_levels") / "levels.png";
  write_hillshades_side_by_side({&big, &small}, {"level 0", "level 1"}, png, 600);
  const cv::Mat img = cv::imread(png.string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(img.empty());
  EXPECT_EQ(img.rows, 600 + 44);  // the 1200 px level reduced to 600, the strip not
  EXPECT_TRUE(has_ink(img, 0, 44));
  EXPECT_THROW(write_hillshades_side_by_side({&big}, {}, png, 600), std::invalid_argument);
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
