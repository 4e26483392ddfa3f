// Reprojecting a window of a grid (ReprojectOptions::window, issue 14): inside the window, away
// from its edge by the stages' reach, every node equals the whole grid's bit for bit, on the
// Buddha with the shipped config's splats, see-through test and upsampling.

#include "hc/pipeline/config.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/run.hpp"

#include "test_paths.hpp"

#include <gtest/gtest.h>

#include <array>
#include <bit>
#include <cmath>
#include <set>
#include <cstring>
#include <string>

namespace {

using hc::pipeline::DepthGrid;
using hc::pipeline::GridWindow;
using hc::pipeline::ReprojectOptions;

std::uint32_t bits(float v) { return std::bit_cast<std::uint32_t>(v); }

// Compares the window's nodes that lie `margin` or more nodes inside its edge (or on the whole
// grid's edge) with the whole grid's.
void expect_equal_inside(const DepthGrid& whole, const DepthGrid& part, const GridWindow& w, int margin) {
  std::size_t compared = 0, valid = 0;
  for (int r = 0; r < w.rows; ++r) {
    const int gr = w.row0 + r;
    if ((r < margin && w.row0 > 0) || (r >= w.rows - margin && w.row0 + w.rows < w.grid.rows)) continue;
    for (int c = 0; c < w.cols; ++c) {
      const int gc = w.col0 + c;
      if ((c < margin && w.col0 > 0) || (c >= w.cols - margin && w.col0 + w.cols < w.grid.cols)) continue;
      const std::size_t i = static_cast<std::size_t>(r) * w.cols + c;
      const std::size_t j = static_cast<std::size_t>(gr) * w.grid.cols + gc;
      ASSERT_EQ(bits(part.depth.data()[i]), bits(whole.depth.data()[j])) << "node " << gr << ", " << gc;
      ASSERT_EQ(part.flags[i], whole.flags[j]) << "node " << gr << ", " << gc;
      if (whole.has_colour()) {
        ASSERT_EQ(std::memcmp(part.colour_rgb8.data() + 3 * i, whole.colour_rgb8.data() + 3 * j, 3), 0);
      }
      ++compared;
      valid += std::isnan(whole.depth.data()[j]) ? 0U : 1U;
    }
  }
  EXPECT_GT(compared, 0U);
  EXPECT_GT(valid, 0U);
}

// The points whose node on the whole (fine) grid lies inside the window, in their order: what
// the tiled pipeline's spill file of a tile holds.
hc::pipeline::Cloud routed(const hc::pipeline::Cloud& cloud, const GridWindow& w) {
  const hc::GridGeometry& g = w.grid;
  std::vector<Eigen::Index> keep;
  for (Eigen::Index i = 0; i < cloud.xyz.cols(); ++i) {
    const long c = std::lround((cloud.xyz(0, i) - g.x0_m) / g.cell_size_m);
    const long r = std::lround((cloud.xyz(1, i) - g.y0_m) / g.cell_size_m);
    if (r >= w.row0 && r < w.row0 + w.rows && c >= w.col0 && c < w.col0 + w.cols) keep.push_back(i);
  }
  hc::pipeline::Cloud out;
  out.xyz.resize(3, static_cast<Eigen::Index>(keep.size()));
  for (std::size_t j = 0; j < keep.size(); ++j) out.xyz.col(static_cast<Eigen::Index>(j)) = cloud.xyz.col(keep[j]);
  for (const Eigen::Index i : keep)
    if (cloud.has_rgb()) out.rgb.insert(out.rgb.end(), cloud.rgb.begin() + 3 * i, cloud.rgb.begin() + 3 * i + 3);
  return out;
}

TEST(ReprojectWindow, EqualsTheWholeGridInsideTheHaloOnTheBuddha) {
  hc::test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz");
  hc::pipeline::RunConfig config = hc::pipeline::load_run_config(std::string(HC_SOURCE_DIR) + "/configs/happy_buddha.yaml");
  const hc::pipeline::Cloud cloud = hc::pipeline::prepare_points(config);
  std::set<int> factors;
  for (const int n : {800, 2400}) {
    ReprojectOptions o = config.grid.reproject;
    o.grid.n_long_side = n;
    auto whole = hc::pipeline::reproject(cloud, o);
    int k = 1;
    for (const auto& [name, v] : whole.report.figures)
      if (name == "upsample_factor") k = static_cast<int>(v);
    factors.insert(k);
    const hc::GridGeometry g = whole.value.depth.geometry();
    // The reach of the splats (plane fit, its reference disc), the see-through window and the
    // bilinear upsampling, in fine nodes.
    const int reach = hc::pipeline::reproject_reach_cells(o, k);
    const int s = n / 800;  // the same three windows of the statuette at both resolutions
    for (const auto& [r0, c0, rows, cols] : {std::array<int, 4>{0, 0, 96 * s, 96 * s}, std::array<int, 4>{64 * s, 128 * s, 160 * s, 128 * s},
                                             std::array<int, 4>{g.rows - 100 * s, 40 * s, 100 * s, 200 * s}}) {
      GridWindow w{g, r0 - r0 % k, c0 - c0 % k, 0, 0};
      w.rows = std::min(rows, g.rows - w.row0);
      w.cols = std::min(cols, g.cols - w.col0);
      ReprojectOptions ow = o;
      ow.upsample_factor = k;
      ow.window = w;
      const DepthGrid part = hc::pipeline::reproject(cloud, ow).value;
      ASSERT_EQ(part.depth.rows(), w.rows);
      EXPECT_DOUBLE_EQ(part.depth.geometry().x0_m, g.x_of_col(w.col0));
      SCOPED_TRACE("N = " + std::to_string(n) + ", K = " + std::to_string(k) + ", window at " + std::to_string(w.row0) +
                   ", " + std::to_string(w.col0));
      expect_equal_inside(whole.value, part, w, reach);
      // Given only the points whose node lies in the window (a tile's spill file): the same.
      const DepthGrid from_routed = hc::pipeline::reproject(routed(cloud, w), ow).value;
      expect_equal_inside(whole.value, from_routed, w, reach);
    }
  }
  EXPECT_EQ(factors.size(), 2U) << "both K = 1 and an upsampled grid are covered";
}

}  // namespace
