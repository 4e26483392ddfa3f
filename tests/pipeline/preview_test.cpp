// Previews: titles and colour-bar labels are never cut off, whatever their length. The oracle is
// the image itself: ink (any non-white pixel) never touches the right border of the canvas,
// and the title strip holds ink.

#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/preview.hpp"

#include "hc/common/error.hpp"
#include "test_paths.hpp"
#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <sys/resource.h>

#include <array>
#include <cmath>
#include <csignal>
#include <cstdint>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

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

TEST(Previews, MarksMoveToTheNearestSampleOfALevel) {
  // Oracle: brute force over the level's samples j, whose level-0 index is j * 2^k
  // (lod_level_geometry), the least |j * 2^k - i|, a tie to the larger j.
  const GridGeometry g0{301, 517, -0.2, 0.1, 0.001};
  std::mt19937 rng(5);
  std::vector<std::array<int, 2>> marks = {{0, 0}, {300, 516}, {1, 1}, {2, 3}, {299, 515}};
  for (int i = 0; i < 200; ++i) marks.push_back({static_cast<int>(rng() % 301), static_cast<int>(rng() % 517)});
  EXPECT_EQ(marks_on_level(marks, 0, g0), marks);
  for (int k = 1; k <= 5; ++k) {
    const GridGeometry gk = lod_level_geometry(g0, k);
    const auto nearest = [&](int i, int n) {
      int best = 0;
      for (int j = 1; j < n; ++j) {
        if (std::abs(j * (1 << k) - i) <= std::abs(best * (1 << k) - i)) best = j;
      }
      return best;
    };
    const auto at = marks_on_level(marks, k, gk);
    ASSERT_EQ(at.size(), marks.size());
    for (std::size_t m = 0; m < marks.size(); ++m) {
      EXPECT_EQ(at[m][0], nearest(marks[m][0], gk.rows)) << "level " << k << " row " << marks[m][0];
      EXPECT_EQ(at[m][1], nearest(marks[m][1], gk.cols)) << "level " << k << " col " << marks[m][1];
    }
  }
  EXPECT_THROW(marks_on_level(marks, 31, g0), std::invalid_argument);
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

/// A 301 × 700 grid (wider than the preview minimum, so not scaled; an odd width, so no row
/// padding) with a no-data cell in every 13th, and its colour layer: noise in the left half,
/// flat runs in the right (about 300 kB as a preview).
struct ColourGrid {
  static constexpr int rows = 301, cols = 700;
  HeightField depth{GridGeometry{rows, cols, 0.0, 0.0, 0.001}};
  std::vector<std::uint8_t> rgb = std::vector<std::uint8_t>(static_cast<std::size_t>(rows * cols * 3));
  ColourGrid() {
    std::mt19937 rng(3);
    std::uniform_int_distribution<int> byte(0, 255);
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c) {
        const std::size_t k = static_cast<std::size_t>(r * cols + c);
        depth.values()[k] = (r * 7 + c) % 13 == 0 ? std::nanf("") : 0.0f;
        for (int ch = 0; ch < 3; ++ch) rgb[3 * k + static_cast<std::size_t>(ch)] = static_cast<std::uint8_t>(c < 350 ? byte(rng) : r % 256);
      }
  }
};

TEST(Previews, TheFastPngWriterKeepsEveryPixel) {
  // Oracle: the colour layer itself, read back by OpenCV's PNG decoder. write_rgb_preview draws
  // a cell's colour unchanged (not shaded) and no-data cells grey (90), flipped so that row 0 is
  // at the bottom. The previews' writer (zlib level 1, no row filters, libpng's full API) must
  // round-trip it, noise and flat runs alike.
  const ColourGrid grid;
  const int rows = ColourGrid::rows, cols = ColourGrid::cols;
  const HeightField& depth = grid.depth;
  const std::vector<std::uint8_t>& rgb = grid.rgb;
  const fs::path png = hc::test::temp_dir("preview_roundtrip") / "rgb.png";
  write_rgb_preview(depth, rgb, png, false);
  const cv::Mat img = cv::imread(png.string(), cv::IMREAD_COLOR);
  ASSERT_EQ(img.rows, rows);
  ASSERT_EQ(img.cols, cols);
  std::size_t wrong = 0;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const std::size_t k = static_cast<std::size_t>(r * cols + c);
      const cv::Vec3b p = img.at<cv::Vec3b>(rows - 1 - r, c);
      const bool grey = std::isnan(depth.values()[k]);
      const cv::Vec3b want = grey ? cv::Vec3b(90, 90, 90) : cv::Vec3b(rgb[3 * k + 2], rgb[3 * k + 1], rgb[3 * k]);
      wrong += p != want;
    }
  EXPECT_EQ(wrong, 0u);
}

TEST(Previews, AColourPreviewsBodyIsTheLayerColourMappedAndFlipped) {
  // Oracle: OpenCV's turbo map of the indices the documented rule gives. The lower half of the
  // rows is 0, the upper half 1, so the 1st and 99th percentiles are 0 and 1 and the cells map to
  // indices 0 and 255; one no-data cell (row 0, column 0) is grey (90). The layer is wider than
  // the preview minimum, so it is not enlarged, and has an odd number of rows (the flip's middle
  // row stays). Its body sits under a 30 px title strip with row 0 at the bottom (+y up).
  const int rows = 451, cols = 500;
  HeightField layer(GridGeometry{rows, cols, 0.0, 0.0, 0.001});
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) layer.at(r, c) = r < rows / 2 ? 0.0f : 1.0f;
  layer.at(0, 0) = std::nanf("");
  const fs::path png = hc::test::temp_dir("preview_colour_body") / "c.png";
  write_colour_preview(layer, png, "t", "m", 1.0);
  const cv::Mat img = cv::imread(png.string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(img.empty());
  cv::Mat ends(1, 2, CV_8UC1);
  ends.at<std::uint8_t>(0, 0) = 0;
  ends.at<std::uint8_t>(0, 1) = 255;
  cv::Mat turbo;
  cv::applyColorMap(ends, turbo, cv::COLORMAP_TURBO);
  const int title_h = 30;
  ASSERT_GE(img.rows, title_h + rows);
  ASSERT_GT(img.cols, cols);
  std::size_t wrong = 0;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const cv::Vec3b want = (r == 0 && c == 0) ? cv::Vec3b(90, 90, 90) : turbo.at<cv::Vec3b>(0, r < rows / 2 ? 0 : 1);
      wrong += img.at<cv::Vec3b>(title_h + rows - 1 - r, c) != want;
    }
  EXPECT_EQ(wrong, 0u);
}

TEST(Previews, AnEmptyLayersColourPreviewIsRefusedNamingTheFile) {
  // Before, an empty layer reached OpenCV (or a division by its zero size): now the file and
  // the layer's size are named, and nothing is written.
  const fs::path png = hc::test::temp_dir("preview_empty") / "e.png";
  for (const GridGeometry g : {GridGeometry{0, 5, 0.0, 0.0, 0.001}, GridGeometry{3, 0, 0.0, 0.0, 0.001}}) {
    const HeightField empty(g);
    try {
      write_colour_preview(empty, png, "t", "m", 1.0);
      FAIL() << "an empty layer was drawn";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(png.string()), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("empty"), std::string::npos) << e.what();
    }
    EXPECT_FALSE(fs::exists(png));
  }
}

TEST(Previews, AnUnwritablePreviewIsNamedInTheError) {
  HeightField depth(GridGeometry{4, 4, 0.0, 0.0, 0.001});
  const std::vector<std::uint8_t> rgb(48, 7);
  const fs::path png = hc::test::temp_dir("preview_unwritable") / "no_such_folder" / "rgb.png";
  try {
    write_rgb_preview(depth, rgb, png, false);
    FAIL() << "written into a missing folder";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find(png.string()), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("No such file"), std::string::npos) << e.what();
  }
}

TEST(Previews, AFailedWriteLeavesNoFile) {
  // A file-size limit of 2 000 bytes, with SIGXFSZ ignored, makes write(2) fail with EFBIG part
  // way through the ColourGrid's preview (about 300 kB): libpng reports the short write, and the
  // half-written file must be gone (as png_image_write_to_file removes its own). The limit is
  // this test process's alone (ctest runs each test in its own process) and is restored.
  const ColourGrid grid;
  const fs::path png = hc::test::temp_dir("preview_fails") / "rgb.png";
  rlimit old{};
  ASSERT_EQ(getrlimit(RLIMIT_FSIZE, &old), 0);
  const auto old_handler = std::signal(SIGXFSZ, SIG_IGN);
  rlimit small = old;
  small.rlim_cur = 2000;
  ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &small), 0);
  std::string error;
  try {
    write_rgb_preview(grid.depth, grid.rgb, png, false);
  } catch (const std::exception& e) {
    error = e.what();
  }
  setrlimit(RLIMIT_FSIZE, &old);
  std::signal(SIGXFSZ, old_handler);
  EXPECT_NE(error.find(png.string()), std::string::npos) << "no error naming the file: " << error;
  EXPECT_FALSE(fs::exists(png)) << "a half-written preview was left";
}

}  // namespace
}  // namespace hc::pipeline
