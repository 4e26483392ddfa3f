// The honest cross-check (issue "A surface you can trust", part 2): the five altered copies of
// the shared bunny scan that today's cross-check passed must each end in warn or fail with the
// right reason; the clean bunny and the Buddha configs pass. Plus oracle tests of the pieces.

#include "hc/pipeline/honest_check.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/preview.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/run.hpp"

#include "cloud_fixtures.hpp"
#include "kd_oracle.hpp"
#include "stage_figure.hpp"
#include "test_paths.hpp"
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <random>
#include <string>
#include <vector>

namespace hc::pipeline {
namespace {

namespace fs = std::filesystem;
using hc::test::cloud_of;

// ---------------------------------------------------------------------------------------------
// Variants of the shared bunny scan (configs/bunny.yaml reads bun000.ply).

const Cloud& bunny() {
  static const Cloud c = load_cloud(hc::test::scan_path("bunny/bun000.ply")).value;
  return c;
}

/// A real point of the scan near the middle of its x-y extent (a visible surface point).
Eigen::Vector3d middle_point(const Cloud& c) {
  const Eigen::Vector3d centre = 0.5 * (c.xyz.rowwise().minCoeff() + c.xyz.rowwise().maxCoeff());
  Eigen::Index best = 0;
  double best_d = 1e300;
  for (Eigen::Index i = 0; i < c.xyz.cols(); ++i) {
    const double d = (c.xyz.col(i).head<2>() - centre.head<2>()).norm();
    if (d < best_d) best_d = d, best = i;
  }
  return c.xyz.col(best);
}

Cloud with_points(const Cloud& base, const std::vector<Eigen::Vector3d>& extra) {
  Cloud c;
  c.xyz.resize(3, base.xyz.cols() + static_cast<Eigen::Index>(extra.size()));
  c.xyz.leftCols(base.xyz.cols()) = base.xyz;
  for (std::size_t i = 0; i < extra.size(); ++i) c.xyz.col(base.xyz.cols() + static_cast<Eigen::Index>(i)) = extra[i];
  return c;
}

/// Writes the cloud as XYZ text (17 significant digits: exact) and builds the scene with
/// configs/bunny.yaml, its input replaced by that file, plus `overrides`.
BuiltScene build_bunny_variant(const Cloud& c, const std::string& name, std::vector<std::string> overrides = {}) {
  const fs::path dir = hc::test::temp_dir(name);
  const fs::path file = dir / (name + ".xyz");
  std::FILE* f = std::fopen(file.c_str(), "w");
  EXPECT_NE(f, nullptr);
  for (Eigen::Index i = 0; f && i < c.xyz.cols(); ++i) {
    std::fprintf(f, "%.17g %.17g %.17g\n", c.xyz(0, i), c.xyz(1, i), c.xyz(2, i));
  }
  if (f) std::fclose(f);
  overrides.push_back("input.files=[" + file.string() + "]");
  const RunConfig config = load_run_config(fs::path(HC_SOURCE_DIR) / "configs" / "bunny.yaml", overrides);
  return build_scene(config);
}

std::string reasons_of(const Verdict& v) {
  std::string s = v.status + ":";
  for (const auto& r : v.reasons) s += "\n  " + r.level + " " + r.code + ": " + r.message;
  return s;
}

std::string reasons_of(const BuiltScene& b) {
  std::string s = reasons_of(*b.summary.verdict);
  if (const auto& in = b.summary.input_check) {
    s += "\n  input " + std::to_string(in->points) + ": removed " + std::to_string(in->removed) + ", on " +
         std::to_string(in->on_surface) + ", off " + std::to_string(in->off_surface) + ", hidden " +
         std::to_string(in->hidden) + ", no data " + std::to_string(in->no_data) + ", outside " +
         std::to_string(in->outside) + ", isolated " + std::to_string(in->isolated) + ", lost " +
         std::to_string(in->surface_lost) + ", in front " + std::to_string(in->removed_in_front) + ", kept spikes " +
         std::to_string(in->spikes_kept);
  }
  return s;
}

void expect_partition(const InputCheck& in) {
  EXPECT_EQ(in.removed + in.on_surface + in.off_surface + in.hidden + in.no_data + in.outside, in.points);
}

TEST(HonestCrossCheck, CleanBunnyPasses) {
  const BuiltScene b = build_bunny_variant(bunny(), "clean");
  ASSERT_TRUE(b.summary.verdict.has_value());
  EXPECT_EQ(b.summary.verdict->status, "pass") << reasons_of(b);
  ASSERT_TRUE(b.summary.input_check.has_value());
  const InputCheck& in = *b.summary.input_check;
  EXPECT_EQ(in.points, static_cast<std::size_t>(bunny().xyz.cols()));
  expect_partition(in);
  // The filter's removals, counted from the stage reports, are what the input check calls removed.
  std::size_t removed_by_stages = 0;
  for (const auto& s : b.summary.stages) {
    if (s.stage == "non_finite" || s.stage == "crop" || s.stage == "outliers" || s.stage == "isolated" || s.stage == "despike") {
      removed_by_stages += s.count_in - s.count_out;
    }
  }
  EXPECT_EQ(in.removed, removed_by_stages);
  EXPECT_EQ(in.far, 0u);
}

TEST(HonestCrossCheck, OnePointOneKilometreAwayWarnsOfFarPoints) {
  const Cloud c = with_points(bunny(), {middle_point(bunny()) + Eigen::Vector3d(1000.0, 0.0, 0.0)});
  const BuiltScene b = build_bunny_variant(c, "far_point");
  ASSERT_TRUE(b.summary.verdict.has_value());
  const Verdict& v = *b.summary.verdict;
  EXPECT_NE(v.status, "pass") << reasons_of(b);
  EXPECT_TRUE(v.has("far_points")) << reasons_of(b);
  // The one far point is 1000 m from the bunny: the farthest distance to the grid's box is
  // 1000 m minus the half-extent of the box along x (under 0.1 m).
  EXPECT_EQ(b.summary.input_check->far, 1u);
  EXPECT_NEAR(b.summary.input_check->far_max_distance_m, 1000.0, 0.1);
  expect_partition(*b.summary.input_check);
}

// The far_points warning advises cropping a far stray (filters.crop): cropped, it counts as
// removed and is neither far nor classified, as a tiled run (which drops it before its spill)
// counts it. Until 2026-11-30 the in-core check classified the points outside the crop, so the
// warning stayed after following its advice.
TEST(HonestCrossCheck, AFarPointCroppedAsTheWarningAdvisesIsRemovedAndNotFar) {
  const Cloud c = with_points(bunny(), {middle_point(bunny()) + Eigen::Vector3d(1000.0, 0.0, 0.0)});
  // Recentred on the box's centre (transform.hpp): the bunny lies near x = −500 m, the point
  // near +500 m.
  const BuiltScene b =
      build_bunny_variant(c, "far_point_cropped", {"filters.crop.min_m=[-1000, -5, -5]", "filters.crop.max_m=[0, 5, 5]"});
  ASSERT_TRUE(b.summary.verdict.has_value());
  EXPECT_FALSE(b.summary.verdict->has("far_points")) << reasons_of(b);
  const InputCheck& in = *b.summary.input_check;
  EXPECT_EQ(in.far, 0u);
  EXPECT_EQ(in.points, static_cast<std::size_t>(c.xyz.cols()));
  expect_partition(in);
  std::size_t cropped = 0, removed_by_stages = 0;
  for (const auto& st : b.summary.stages) {
    if (st.stage == "crop") cropped = st.count_in - st.count_out;
    if (st.stage == "non_finite" || st.stage == "crop" || st.stage == "outliers" || st.stage == "isolated" || st.stage == "despike") {
      removed_by_stages += st.count_in - st.count_out;
    }
  }
  EXPECT_EQ(cropped, 1u);
  EXPECT_EQ(in.removed, removed_by_stages);
  // The same run without the crop: the point is far and warned of (the test above).
}

TEST(HonestCrossCheck, TwoPercentUniformOutliersAreNotAPass) {
  const Cloud& base = bunny();
  const Eigen::Vector3d lo = base.xyz.rowwise().minCoeff(), hi = base.xyz.rowwise().maxCoeff();
  std::mt19937_64 rng(2024);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Eigen::Vector3d> noise;
  const auto n_noise = static_cast<std::size_t>(0.02 * static_cast<double>(base.xyz.cols()));
  for (std::size_t i = 0; i < n_noise; ++i) {
    noise.emplace_back(lo.x() + u(rng) * (hi.x() - lo.x()), lo.y() + u(rng) * (hi.y() - lo.y()),
                       lo.z() + u(rng) * (hi.z() - lo.z()));
  }
  const BuiltScene b = build_bunny_variant(with_points(base, noise), "uniform_outliers");
  const Verdict& v = *b.summary.verdict;
  EXPECT_NE(v.status, "pass") << reasons_of(b);
  // Either outliers reach the grid (spikes, cells kept only by isolated points, islands), or the
  // filters removed them and the verdict says how much of the input went (2 % > the 1 % limit).
  EXPECT_TRUE(v.has("grid_spikes") || v.has("spikes_kept") || v.has("islands") || v.has("removed_fraction")) << reasons_of(b);
  expect_partition(*b.summary.input_check);
}

TEST(HonestCrossCheck, FilterOffAndOnePointOneKilometreAboveFails) {
  // Today's report said: RMS 0.21 mm, 99.98 % supported, and no verdict: a pass.
  const Eigen::Vector3d top = middle_point(bunny()) + Eigen::Vector3d(0.0, 0.0, 1000.0);
  const BuiltScene b = build_bunny_variant(with_points(bunny(), {top}), "filter_off_spike",
                                           {"filters.outliers.enabled=false"});
  ASSERT_TRUE(b.summary.verdict.has_value());
  const Verdict& v = *b.summary.verdict;
  EXPECT_EQ(v.status, "fail") << reasons_of(b);
  EXPECT_TRUE(v.has("grid_spikes")) << reasons_of(b);
  EXPECT_TRUE(v.has("spikes_kept")) << reasons_of(b);
  // The worst spike stands ~1000 m above its neighbourhood (the bunny is < 0.2 m deep).
  ASSERT_FALSE(b.summary.grid_spikes->worst.empty());
  EXPECT_NEAR(b.summary.grid_spikes->worst.front().deviation_m, 1000.0, 0.2);
  EXPECT_GE(b.summary.input_check->spikes_kept, 1u);
  // The depth colour bar reads two different, finite numbers (today: -5e+05 at both ends).
  const ColourBar bar = colour_bar(b.scene.depth(), 1000.0);
  EXPECT_NE(bar.lo_label, bar.hi_label);
  EXPECT_TRUE(std::isfinite(std::stod(bar.lo_label)) && std::isfinite(std::stod(bar.hi_label)));
  EXPECT_LT(std::stod(bar.lo_label), std::stod(bar.hi_label));
  EXPECT_TRUE(bar.clipped_high);  // the spike is beyond the 99th percentile, and marked
  EXPECT_FALSE(bar.max_label.empty());
}

TEST(HonestCrossCheck, ThirtyPointClusterOneKilometreAwayNamesFarPoints) {
  std::vector<Eigen::Vector3d> cluster;
  const Eigen::Vector3d at = middle_point(bunny()) + Eigen::Vector3d(1000.0, 0.0, 0.0);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-0.005, 0.005);
  for (int i = 0; i < 30; ++i) cluster.push_back(at + Eigen::Vector3d(u(rng), u(rng), u(rng)));
  // Either the run stops with an error that names the far points (today's filters keep the
  // cluster and the grid degenerates), or it completes and the verdict names them.
  try {
    const BuiltScene b = build_bunny_variant(with_points(bunny(), cluster), "far_cluster");
    const Verdict& v = *b.summary.verdict;
    EXPECT_NE(v.status, "pass") << reasons_of(b);
    EXPECT_TRUE(v.has("far_points")) << reasons_of(b);
  } catch (const hc::Error& e) {
    const std::string what = e.what();
    EXPECT_TRUE(what.find("far") != std::string::npos || what.find("crop") != std::string::npos) << what;
  }
}

TEST(HonestCrossCheck, SparseRightHalfIsNotAPass) {
  // Right half (x above the median) at 3 % of the density of the left half.
  const Cloud& base = bunny();
  std::vector<double> xs;
  for (Eigen::Index i = 0; i < base.xyz.cols(); ++i) xs.push_back(base.xyz(0, i));
  std::nth_element(xs.begin(), xs.begin() + static_cast<std::ptrdiff_t>(xs.size() / 2), xs.end());
  const double x_mid = xs[xs.size() / 2];
  std::vector<Eigen::Vector3d> kept;
  std::size_t right = 0;
  for (Eigen::Index i = 0; i < base.xyz.cols(); ++i) {
    if (base.xyz(0, i) <= x_mid || right++ % 33 == 0) kept.push_back(base.xyz.col(i));
  }
  const BuiltScene b = build_bunny_variant(cloud_of(kept), "density_step");
  const Verdict& v = *b.summary.verdict;
  EXPECT_NE(v.status, "pass") << reasons_of(b);
  // The sparse half is either lost by the filters or reaches the grid without support.
  EXPECT_TRUE(v.has("surface_lost") || v.has("unsupported") || v.has("islands")) << reasons_of(b);
  expect_partition(*b.summary.input_check);
}

// Grid nodes (x, y, f) of valid cells farther than `limit_m` from every kept point of `b`, by a
// nanoflann k-d tree (not the project's searches), and how many of them hole filling made.
struct FarCells {
  std::size_t count = 0, filled = 0;
  double max_m = 0.0;
};
FarCells cells_far_from_the_points(const BuiltScene& b, double limit_m) {
  FarCells out;
  if (!b.cloud || b.scene.layers.flags.size() != b.scene.layers.depth.values().size()) {
    ADD_FAILURE() << "the run kept no cloud or no cell flags";
    return out;
  }
  const hc::test::KdOracle tree(b.cloud->xyz);
  const GridGeometry& g = b.scene.geometry;
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c) {
      const float z = b.scene.layers.depth.at(r, c);
      if (std::isnan(z)) continue;
      const double d = tree.nearest({g.x0_m + c * g.cell_size_m, g.y0_m + r * g.cell_size_m, double(z)});
      if (d <= limit_m) continue;
      ++out.count;
      out.max_m = std::max(out.max_m, d);
      out.filled += b.scene.layers.flags[static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(c)] ==
                    kCellFilled;
    }
  return out;
}

TEST(HonestCrossCheck, BuddhaConfigPassesAndNoCellStandsASpikeHeightFromTheKeptPoints) {
  // Oracle: a k-d tree over the kept points. With the shipped config (occlusion gaps left empty:
  // grid.hole_fill_max_step_m) every valid node lies within the spike height (2 mm) of a kept
  // point, and the grid's spike and pit test flags nothing the scan does not confirm. Without the
  // step limit, hole filling bridged occlusion gaps in the folds: measured 2026-11-23, 29
  // unconfirmed spike and pit cells and 175 nodes more than 2 mm (up to 22.7 mm) from every kept
  // point, all of them filled cells; the test checks both.
  hc::test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz");
  const fs::path yaml = fs::path(HC_SOURCE_DIR) / "configs" / "happy_buddha.yaml";
  const RunConfig config = load_run_config(yaml);
  const BuiltScene b = build_scene(config, true);
  ASSERT_TRUE(b.summary.verdict.has_value());
  EXPECT_EQ(b.summary.verdict->status, "pass") << reasons_of(b);
  expect_partition(*b.summary.input_check);
  const double spike_m = config.cross_check.honest.spike_min_height_m;
  const FarCells far = cells_far_from_the_points(b, spike_m);
  EXPECT_EQ(far.count, 0u) << "farthest " << far.max_m * 1e3 << " mm";
  ASSERT_TRUE(b.summary.grid_spikes.has_value());
  EXPECT_EQ(b.summary.grid_spikes->confirmed, b.summary.grid_spikes->spikes + b.summary.grid_spikes->pits);

  const BuiltScene bridged = build_scene(load_run_config(yaml, {"grid.hole_fill_max_step_m=0"}), true);
  const FarCells far_bridged = cells_far_from_the_points(bridged, spike_m);
  EXPECT_GT(far_bridged.count, 0u);
  EXPECT_EQ(far_bridged.filled, far_bridged.count);
  EXPECT_GT(far_bridged.max_m, 5.0 * spike_m);
  ASSERT_TRUE(bridged.summary.grid_spikes.has_value());
  EXPECT_LT(bridged.summary.grid_spikes->confirmed, bridged.summary.grid_spikes->spikes + bridged.summary.grid_spikes->pits);
}

// ---------------------------------------------------------------------------------------------
// The pieces against hand-made oracles.

TEST(GridSpikes, FindsExactlyThePlantedSpikeAndPitOnATiltedPlane) {
  GridGeometry g{40, 50, 0.0, 0.0, 0.001};
  HeightField h(g);
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c) h.at(r, c) = static_cast<float>(0.3 * g.x_of_col(c) + 0.1 * g.y_of_row(r));
  const float plane_10_10 = h.at(10, 10), plane_30_40 = h.at(30, 40);
  h.at(10, 10) += 0.010f;  // a 10 mm spike
  h.at(30, 40) -= 0.005f;  // a 5 mm pit
  HonestCheckOptions o;  // 2 mm and 6 MAD: the plane's window spread is < 2 mm
  const GridSpikes s = find_grid_spikes(h, o);
  EXPECT_EQ(s.spikes, 1u);
  EXPECT_EQ(s.pits, 1u);
  EXPECT_EQ(s.islands, 0u);
  ASSERT_EQ(s.worst.size(), 2u);
  EXPECT_EQ(s.worst[0].row, 10);
  EXPECT_EQ(s.worst[0].col, 10);
  // The window median of a plane is the plane at the centre (symmetric window): +10 mm.
  EXPECT_NEAR(s.worst[0].deviation_m, h.at(10, 10) - plane_10_10, 2e-4);
  EXPECT_EQ(s.worst[1].row, 30);
  EXPECT_EQ(s.worst[1].col, 40);
  EXPECT_NEAR(s.worst[1].deviation_m, h.at(30, 40) - plane_30_40, 2e-4);
}

// Spikes in both halves of the rows (the test runs them on two threads), two at the rows either
// side of the split, and heights either side of spike_min_height_m (2 mm): every cell is tested,
// the anomalies are exactly the planted ones above 2 mm, worst first.
TEST(GridSpikes, PlantedSpikesInBothHalvesAndAtTheSplitAreFoundExactlyOnce) {
  GridGeometry g{40, 50, 0.0, 0.0, 0.001};
  HeightField h(g);
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c) h.at(r, c) = static_cast<float>(0.3 * g.x_of_col(c) + 0.1 * g.y_of_row(r));
  struct Plant {
    int r, c;
    float dz;
    bool flagged;
  };
  // (The plane's window has a 1.4826·MAD of about 0.5 mm: 6 of them, about 3.1 mm, is the bar.)
  const Plant plants[] = {{5, 7, 0.0045f, true},   {19, 20, 0.0040f, true}, {20, 30, -0.0050f, true},
                          {35, 44, 0.0060f, true}, {10, 40, 0.0019f, false}, {30, 10, -0.0018f, false}};
  for (const Plant& p : plants) h.at(p.r, p.c) += p.dz;
  const GridSpikes s = find_grid_spikes(h, HonestCheckOptions{});
  EXPECT_EQ(s.tested, static_cast<std::size_t>(g.rows * g.cols));
  std::size_t spikes = 0, pits = 0;
  for (const Plant& p : plants) {
    spikes += p.flagged && p.dz > 0 ? 1U : 0U;
    pits += p.flagged && p.dz < 0 ? 1U : 0U;
  }
  EXPECT_EQ(s.spikes, spikes);
  EXPECT_EQ(s.pits, pits);
  ASSERT_EQ(s.worst.size(), 4u);
  const int want_rows[] = {35, 20, 5, 19}, want_cols[] = {44, 30, 7, 20};
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(s.worst[i].row, want_rows[i]) << i;
    EXPECT_EQ(s.worst[i].col, want_cols[i]) << i;
  }
  EXPECT_EQ(s.flagged.size(), 4u);
}

// Windows of 3, 5 and 7 cells on a tilted plane with holes (a fifth of the cells no data, some
// whole blocks of them) and isolated spikes and pits, some beside holes and on the border:
// `tested` and the spikes and pits found against a brute force over each cell's window (the
// valid neighbours, their median and MAD, the silhouette rule for pits). Isolated planted cells
// are no part of a larger surface, so the flood never spares one here.
TEST(GridSpikes, WindowsWithHolesAndBordersAgreeWithBruteForce) {
  std::mt19937 rng(20261128);
  for (const int window : {3, 5, 7}) {
    GridGeometry g{61, 77, 0.0, 0.0, 0.001};
    HeightField h(g);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (int r = 0; r < g.rows; ++r)
      for (int c = 0; c < g.cols; ++c) {
        const bool hole = u(rng) < 0.2 || (r / 9 == 3 && c / 11 == 4);
        h.at(r, c) = hole ? std::numeric_limits<float>::quiet_NaN() : static_cast<float>(0.2 * g.x_of_col(c) - 0.1 * g.y_of_row(r));
      }
    // Two valid cells amid the block of holes (rows 27..35, cols 44..54): fewer than 3 valid
    // neighbours in any of the windows.
    for (const int c : {49, 50}) h.at(31, c) = static_cast<float>(0.2 * g.x_of_col(c) - 0.1 * g.y_of_row(31));
    // Planted cells at least a window apart, so that no window holds two.
    std::vector<std::array<int, 2>> planted;
    for (int tries = 0; tries < 4000 && planted.size() < 60; ++tries) {
      const int r = static_cast<int>(u(rng) * g.rows), c = static_cast<int>(u(rng) * g.cols);
      if (std::isnan(h.at(r, c))) continue;
      if (std::any_of(planted.begin(), planted.end(), [&](const auto& q) { return std::abs(q[0] - r) <= window && std::abs(q[1] - c) <= window; })) continue;
      planted.push_back({r, c});
      h.at(r, c) += static_cast<float>((u(rng) < 0.5 ? -1.0 : 1.0) * (0.001 + 0.009 * u(rng)));  // 1 to 10 mm
    }
    HonestCheckOptions o;
    o.spike_window_cells = window;
    const GridSpikes s = find_grid_spikes(h, o);
    // The brute force.
    const int hw = window / 2;
    std::size_t tested = 0, spikes = 0, pits = 0, valid = 0;
    std::vector<std::array<int, 2>> flagged;
    for (int r = 0; r < g.rows; ++r)
      for (int c = 0; c < g.cols; ++c) {
        const float z = h.at(r, c);
        if (std::isnan(z)) continue;
        ++valid;
        std::vector<float> nb;
        bool edge = r - hw < 0 || r + hw >= g.rows || c - hw < 0 || c + hw >= g.cols;
        for (int rr = std::max(0, r - hw); rr <= std::min(g.rows - 1, r + hw); ++rr)
          for (int cc = std::max(0, c - hw); cc <= std::min(g.cols - 1, c + hw); ++cc) {
            if (rr == r && cc == c) continue;
            if (std::isnan(h.at(rr, cc))) {
              edge = true;
            } else {
              nb.push_back(h.at(rr, cc));
            }
          }
        if (nb.size() < 3) continue;
        ++tested;
        std::vector<float> sorted = nb;
        std::sort(sorted.begin(), sorted.end());
        const double median = sorted[sorted.size() / 2];
        std::vector<float> dev;
        for (const float v : nb) dev.push_back(std::abs(static_cast<float>(v - median)));
        std::sort(dev.begin(), dev.end());
        const double d = static_cast<double>(z) - median;
        if (std::abs(d) <= o.spike_min_height_m || std::abs(d) <= o.spike_mad_factor * 1.4826 * static_cast<double>(dev[dev.size() / 2])) continue;
        if (d < 0 && edge) continue;
        (d > 0 ? spikes : pits) += 1;
        flagged.push_back({r, c});
      }
    EXPECT_EQ(s.tested, tested) << "window " << window;
    EXPECT_EQ(s.spikes, spikes) << "window " << window;
    EXPECT_EQ(s.pits, pits) << "window " << window;
    std::vector<std::array<int, 2>> found = s.flagged;
    std::sort(found.begin(), found.end());
    EXPECT_EQ(found, flagged) << "window " << window;
    EXPECT_GE(spikes + pits, 10U) << "window " << window << ": planted cells over 2 mm are found";
    EXPECT_LT(tested, valid) << "window " << window << ": cells amid holes have fewer than 3 valid neighbours";
  }
}

TEST(GridSpikes, IslandsAreSmallGroupsApartFromTheSurface) {
  GridGeometry g{30, 30, 0.0, 0.0, 0.001};
  HeightField h(g);
  for (int r = 0; r < 20; ++r)
    for (int c = 0; c < 20; ++c) h.at(r, c) = 0.0f;
  h.at(25, 25) = 0.0f;  // one lone cell
  h.at(27, 5) = h.at(27, 6) = h.at(28, 5) = 0.0f;  // a group of 3
  HonestCheckOptions o;
  o.island_max_cells = 3;
  GridSpikes s = find_grid_spikes(h, o);
  EXPECT_EQ(s.islands, 2u);
  EXPECT_EQ(s.island_cells, 4u);
  o.island_max_cells = 2;  // the group of 3 is no longer an island
  s = find_grid_spikes(h, o);
  EXPECT_EQ(s.islands, 1u);
  EXPECT_EQ(s.island_cells, 1u);
  // Without the surface the group of 3 is the grid's largest: spared (a small grid's whole
  // surface is no island), unless spare_largest_group is off (a tiled run's windows).
  for (int r = 0; r < 20; ++r)
    for (int c = 0; c < 20; ++c) h.at(r, c) = std::numeric_limits<float>::quiet_NaN();
  o.island_max_cells = 3;
  s = find_grid_spikes(h, o);
  EXPECT_EQ(s.islands, 1u);
  EXPECT_EQ(s.island_cells, 1u);
  o.spare_largest_group = false;
  s = find_grid_spikes(h, o);
  EXPECT_EQ(s.islands, 2u);
  EXPECT_EQ(s.island_cells, 4u);
}

// detail::island_cells labels the grid in bands of rows with max_cells rows above and below;
// the oracle is a breadth-first flood fill of the whole grid (8-neighbours, no OpenCV): the
// cells of every group of at most max_cells cells. Random grids of 25 % valid cells (groups of
// many sizes, many across the band edges) with a cross of a full row and a full column planted
// (one group through every band, thin enough that a band's window holds little of it), bands
// of 1 row up to the whole grid; the cross is larger than max_cells, so the largest is spared
// or not alike. Then a grid of specks only (every group small: the largest spared, found by
// one labelling of the whole grid).
std::vector<std::vector<std::size_t>> flood_groups(const HeightField& h) {
  const int rows = h.rows(), cols = h.cols();
  std::vector<int> seen(static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols), 0);
  std::vector<std::vector<std::size_t>> groups;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) {
      const std::size_t i = static_cast<std::size_t>(r) * static_cast<std::size_t>(cols) + static_cast<std::size_t>(c);
      if (seen[i] || std::isnan(h.at(r, c))) continue;
      std::vector<std::size_t> group{i};
      seen[i] = 1;
      for (std::size_t k = 0; k < group.size(); ++k) {
        const int gr = static_cast<int>(group[k] / static_cast<std::size_t>(cols)), gc = static_cast<int>(group[k] % static_cast<std::size_t>(cols));
        for (int dr = -1; dr <= 1; ++dr)
          for (int dc = -1; dc <= 1; ++dc) {
            const int nr = gr + dr, nc = gc + dc;
            if (nr < 0 || nr >= rows || nc < 0 || nc >= cols || std::isnan(h.at(nr, nc))) continue;
            const std::size_t j = static_cast<std::size_t>(nr) * static_cast<std::size_t>(cols) + static_cast<std::size_t>(nc);
            if (!seen[j]) {
              seen[j] = 1;
              group.push_back(j);
            }
          }
      }
      groups.push_back(std::move(group));
    }
  return groups;
}

TEST(GridSpikes, IslandCellsLabelledInBandsEqualAFloodFillOfTheWholeGrid) {
  std::mt19937 rng(20261129);
  std::bernoulli_distribution valid(0.25);
  for (const int max_cells : {1, 3, 16}) {
    GridGeometry g{61, 47, 0.0, 0.0, 0.001};
    HeightField h(g);
    for (int r = 0; r < g.rows; ++r)
      for (int c = 0; c < g.cols; ++c)
        if (valid(rng) || r == 30 || c == 20) h.at(r, c) = 0.0f;
    std::vector<std::size_t> expected;
    std::size_t expected_groups = 0, largest = 0;
    for (const auto& group : flood_groups(h)) {
      largest = std::max(largest, group.size());
      if (group.size() > static_cast<std::size_t>(max_cells)) continue;
      ++expected_groups;
      expected.insert(expected.end(), group.begin(), group.end());
    }
    std::sort(expected.begin(), expected.end());
    ASSERT_GT(largest, static_cast<std::size_t>(max_cells)) << "a group larger than max_cells";
    ASSERT_GT(expected_groups, 20U);
    for (const int band : {1, 2, 3, 5, 8, 13, 60, 61, 0}) {
      for (const bool spare : {true, false}) {
        SCOPED_TRACE("max_cells " + std::to_string(max_cells) + ", band " + std::to_string(band) + (spare ? ", spare" : ""));
        std::size_t groups = 0;
        const auto cells = detail::island_cells(h, max_cells, &groups, spare, band);
        EXPECT_EQ(cells, expected);
        EXPECT_EQ(groups, expected_groups);
      }
    }
  }
  // Specks only: groups of 1, 2 and 4 cells (the 4 the largest, alone of its size), some across
  // the edges of 2-row bands; the largest is spared unless spare is off.
  GridGeometry g{12, 12, 0.0, 0.0, 0.001};
  HeightField h(g);
  for (const auto& rc : std::vector<std::array<int, 2>>{{0, 0}, {1, 5}, {2, 5}, {3, 9}, {4, 9}, {5, 10}, {6, 10}, {9, 2}, {11, 11}}) {
    h.at(rc[0], rc[1]) = 0.0f;
  }
  std::size_t groups = 0;
  const auto spared = detail::island_cells(h, 4, &groups, true, 2);
  EXPECT_EQ(groups, 4U);  // {0,0}, the pair at column 5, {9,2}, {11,11}; the group of 4 spared
  const std::vector<std::size_t> want = {0, 1 * 12 + 5, 2 * 12 + 5, 9 * 12 + 2, 11 * 12 + 11};
  EXPECT_EQ(spared, want);
  const auto all = detail::island_cells(h, 4, &groups, false, 2);
  EXPECT_EQ(groups, 5U);
  EXPECT_EQ(all.size(), 9U);
  EXPECT_THROW((void)detail::island_cells(h, 0, &groups, true), std::invalid_argument);
}

// remove_spike_points on a construction whose strays are known: a tilted plane sampled every
// 0.25 mm (1 mm cells) carrying a dense Gaussian hill 6 mm high, σ 1.5 mm (relief: its top
// stands about 4 mm above its window's plane, and is joined to the plane by samples), 3 stray points 3–5 mm in front of the plane, one stray point alone in
// the background (an island), and one stray 1 mm in front (below the 2 mm spike height: not
// judged). Oracle: the construction; exactly the 4 judged strays go.
// The construction below: the surface's points, then the 4 judged strays, then the shallow one.
struct DespikeScene {
  Cloud cloud;
  std::size_t n_surface = 0;
  Eigen::Vector3d shallow;
  DepthGrid grid;
};
DespikeScene despike_scene() {
  auto plane = [](double x, double y) { return 0.2 * x + 0.1 * y; };
  auto hill = [](double x, double y) {
    const double d2 = (x - 0.030) * (x - 0.030) + (y - 0.020) * (y - 0.020);
    return 0.006 * std::exp(-d2 / (2.0 * 0.0015 * 0.0015));
  };
  std::vector<Eigen::Vector3d> pts;
  for (int j = 0; j <= 160; ++j)
    for (int i = 0; i <= 200; ++i) {
      const double x = 0.00025 * i, y = 0.00025 * j;
      pts.emplace_back(x, y, plane(x, y) + hill(x, y));
    }
  DespikeScene d;
  d.n_surface = pts.size();
  const std::vector<Eigen::Vector3d> judged = {{0.010, 0.010, plane(0.010, 0.010) + 0.003},
                                               {0.045, 0.030, plane(0.045, 0.030) + 0.005},
                                               {0.015, 0.035, plane(0.015, 0.035) + 0.004},
                                               {0.049, 0.045, plane(0.049, 0.045)}};  // background
  d.shallow = Eigen::Vector3d(0.040, 0.008, plane(0.040, 0.008) + 0.001);
  pts.insert(pts.end(), judged.begin(), judged.end());
  pts.push_back(d.shallow);
  // The background point lies beyond the sampled y range (0–40 mm): move it there.
  pts[d.n_surface + 3].y() = 0.049;
  ReprojectOptions ro;
  ro.grid.cell_size_m = 0.001;
  ro.splat_radius_cells = 1.0;
  d.cloud = cloud_of(pts);
  d.grid = reproject(d.cloud, ro).value;
  return d;
}

TEST(DespikeGrid, RemovesStraysInFrontAndInTheBackgroundAndKeepsDenseRelief) {
  const DespikeScene d = despike_scene();
  const Cloud& cloud = d.cloud;
  const std::size_t n_surface = d.n_surface;
  const Eigen::Vector3d& shallow = d.shallow;
  const DepthGrid& grid = d.grid;
  const auto r = remove_spike_points(cloud, grid.depth, HonestCheckOptions{}, 1.0, 0.00025);
  ASSERT_EQ(r.value.size(), cloud.size() - 4) << "removed " << cloud.size() - r.value.size();
  // Every surface point and the shallow stray are kept, in order; the 4 judged strays are gone.
  for (std::size_t i = 0; i < n_surface; ++i)
    ASSERT_EQ(r.value.xyz.col(static_cast<Eigen::Index>(i)), cloud.xyz.col(static_cast<Eigen::Index>(i))) << i;
  EXPECT_EQ(Eigen::Vector3d(r.value.xyz.col(static_cast<Eigen::Index>(n_surface))), shallow);
  EXPECT_EQ(hc::test::figure(r.report, "removed_spike_points"), 4.0);
  EXPECT_GE(hc::test::figure(r.report, "island_cells"), 1.0);
  // The hill's top cells are judged (spikes of their window's plane) and kept: their points
  // have neighbours within half their height.
  EXPECT_GT(hc::test::figure(r.report, "spike_cells"), 4.0);
}

// A window of the grid given as such (remove_spike_points' `window`) bins each point where the
// whole grid does, so that its verdicts are the whole grid's. The construction makes a point's
// verdict hang on its node: on a ramp of −1 mm a column (cells of 1.6889 mm, an origin that is
// no round number), spike cells 8 mm above it at columns c − 1 and c + 2 of a row, and a stray
// S on the boundary between the nodes c and c + 1 with three neighbours 3.6 mm from it. Binned
// to node c, S is a candidate of the spike at c − 1 only, 4.5 mm above its plane: its radius is
// ρ_lo = 3.378 mm and it has no neighbour within it (removed); binned to c + 1, of the spike at
// c + 2 only, 7.5 mm above: ρ = 3.75 mm and three neighbours (kept); controls a hundredth of
// a cell off the boundary show both. 72 such strays, each on
// a node boundary as the grid computes it (x_of_col(c + 0.5)), where a window's own origin (the
// whole grid's plus col0 cells) rounds some of them to the other node. The oracle is the whole
// grid's call: every point whose node lies more than 10 cells inside a window (the spikes'
// planes and the count's rings held) gets the whole grid's verdict. TiledDifferential seed 308
// (sixty-fourth session, 2026-11-30): a tile kept a stray the in-core run removed.
TEST(DespikeGrid, AWindowGivenAsSuchBinsItsPointsAsTheWholeGridAndJudgesThemAlike) {
  GridGeometry g;
  g.rows = 40;
  g.cols = 200;
  g.x0_m = -0.29640000000000001;
  g.y0_m = -0.23644444444444446;
  g.cell_size_m = 0.0016888888888888889;
  HeightField grid(g);
  const auto ramp = [](double c) { return -0.001 * c; };
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c) grid.at(r, c) = static_cast<float>(ramp(c));
  std::vector<Eigen::Vector3d> pts;
  std::vector<std::size_t> strays;    // on node boundaries
  std::vector<std::size_t> controls;  // a hundredth of a cell before a boundary, then after it
  for (const int r : {5, 10, 15, 20, 25, 35}) {
    for (int c = 10; c < 190; c += 10) {
      grid.at(r, c - 1) = static_cast<float>(ramp(c - 1) + 0.008);
      grid.at(r, c + 2) = static_cast<float>(ramp(c + 2) + 0.008);
      const bool control = r == 10 || r == 20;
      const double at = c + 0.5 + (control ? (r == 10 ? -0.01 : 0.01) : 0.0);
      const Eigen::Vector3d s(g.x_of_col(at), g.y_of_row(r), ramp(c + 0.5) + 0.006);
      (control ? controls : strays).push_back(pts.size());
      pts.push_back(s);
      for (const Eigen::Vector3d& d : {Eigen::Vector3d(0, 1, 0), Eigen::Vector3d(0, -1, 0), Eigen::Vector3d(0, 0, 1)}) pts.push_back(s + 0.0036 * d);
    }
  }
  const Cloud cloud = cloud_of(pts);
  HonestCheckOptions o;
  o.spike_min_height_m = 0.004;
  const auto verdicts = [&](const HeightField& field, const GridWindow* w) {
    RemovedPoints removed;
    (void)remove_spike_points(cloud, field, o, 1.0, 0.0, 1.0, &removed, w);
    std::vector<std::uint8_t> gone(cloud.size(), 0);
    for (const std::size_t i : removed.at) gone[i] = 1;
    return gone;
  };
  const std::vector<std::uint8_t> whole = verdicts(grid, nullptr);
  // The construction: a stray binned to node c goes, one binned to c + 1 stays.
  for (const std::size_t i : controls) {
    const bool before = g.col_of_x(pts[i].x()) - std::floor(g.col_of_x(pts[i].x())) < 0.5;
    EXPECT_EQ(whole[i], before ? 1 : 0) << "control stray " << i << " at column " << g.col_of_x(pts[i].x());
  }
  std::size_t compared = 0;
  for (const int col0 : {1, 3, 7, 11, 13, 29, 37, 53, 61, 77, 90}) {
    GridWindow w;
    w.grid = g;
    w.row0 = 0;
    w.col0 = col0;
    w.rows = g.rows;
    w.cols = std::min(g.cols - col0, 97);
    GridGeometry wg = g;
    wg.x0_m = g.x_of_col(col0);
    wg.cols = w.cols;
    HeightField part(wg);
    for (int r = 0; r < wg.rows; ++r)
      for (int c = 0; c < wg.cols; ++c) part.at(r, c) = grid.at(r, c + col0);
    const std::vector<std::uint8_t> got = verdicts(part, &w);
    for (const std::size_t i : strays) {
      const double c = g.col_of_x(pts[i].x());
      if (c < col0 + 10 || c > col0 + w.cols - 11) continue;
      for (std::size_t j = i; j < i + 4; ++j) EXPECT_EQ(got[j], whole[j]) << "window from column " << col0 << ", point " << j << " (stray " << i << ")";
      compared += 4;
    }
  }
  EXPECT_GT(compared, 400U);
  // A window that does not fit its height field is refused.
  GridWindow bad;
  bad.grid = g;
  bad.rows = g.rows;
  bad.cols = 10;
  EXPECT_THROW((void)remove_spike_points(cloud, grid, o, 1.0, 0.0, 1.0, nullptr, &bad), std::invalid_argument);
}

// despike_grid_reach_cells, which sizes the tiled run's halo (a tile's window gives the
// despike the whole grid only that near the points whose verdicts it keeps): a point's verdict
// reads the grid only within D = ⌈reach⌉ + spike_window_cells / 2 cells (Chebyshev) of its node.
// Oracle: the verdicts on the whole grid of the construction above, against those on grids
// equal within D of one point's node and changed beyond it (every valid cell past D moved by
// up to ±8 mm, far more than the spike height, in five random draws; validity kept, so no rim
// or island moves: islands can reach farther, and the function's comment says so), for each
// judged stray and for 40 surface points about them and the hill. At D − 2 (inside the plane
// window of a stray's own spike cell) the same changes move verdicts, so the test sees the
// grid's reads; at D − 1 none moves here: no point of the construction is a candidate only
// through a neighbouring spike cell, the ⌈reach⌉ term, which the derivation alone covers.
TEST(DespikeGrid, AVerdictReadsTheGridOnlyWithinItsGridReach) {
  const DespikeScene d = despike_scene();
  const HonestCheckOptions options;
  const double reach_cells = 1.0, spacing_m = 0.00025;
  const int reach = despike_grid_reach_cells(options, reach_cells);
  ASSERT_EQ(reach, 1 + options.spike_window_cells / 2);
  const HeightField& whole = d.grid.depth;
  const GridGeometry& g = whole.geometry();
  auto removed_of = [&](const HeightField& grid) {
    RemovedPoints removed;
    (void)remove_spike_points(d.cloud, grid, options, reach_cells, spacing_m, 1.0, &removed);
    std::vector<std::uint8_t> gone(d.cloud.size(), 0);
    for (const std::size_t c : removed.at) gone[c] = 1;
    return gone;
  };
  const std::vector<std::uint8_t> base = removed_of(whole);
  ASSERT_EQ(std::count(base.begin(), base.end(), std::uint8_t{1}), 4);
  // The points looked at: the judged strays, and surface points at and about the strays and the
  // hill's top (candidates among them: relief near spike cells).
  std::vector<std::size_t> looked;
  for (std::size_t i = d.n_surface; i < d.n_surface + 4; ++i) looked.push_back(i);
  std::mt19937 pick(7);
  for (const auto& c : {std::array{0.010, 0.010}, std::array{0.045, 0.030}, std::array{0.015, 0.035}, std::array{0.030, 0.020}}) {
    std::uniform_real_distribution<double> off(-0.002, 0.002);
    for (int n = 0; n < 10; ++n) {
      const double x = c[0] + off(pick), y = c[1] + off(pick);
      const int i = std::clamp(static_cast<int>(std::lround(x / 0.00025)), 0, 200), j = std::clamp(static_cast<int>(std::lround(y / 0.00025)), 0, 160);
      looked.push_back(static_cast<std::size_t>(j) * 201 + static_cast<std::size_t>(i));
    }
  }
  std::size_t moved_inside = 0;  // verdicts moved by changes past D − 2
  for (const int claim : {reach, reach - 2}) {
    for (const std::size_t p : looked) {
      const auto col = d.cloud.xyz.col(static_cast<Eigen::Index>(p));
      // Its node, nearest as the grid bins points (ties up).
      const int pr = static_cast<int>(std::floor((col.y() - g.y0_m) * (1.0 / g.cell_size_m) + 0.5));
      const int pc = static_cast<int>(std::floor((col.x() - g.x0_m) * (1.0 / g.cell_size_m) + 0.5));
      for (int draw = 0; draw < 5; ++draw) {
        std::mt19937 rng(static_cast<unsigned>(1000 * draw + p));
        std::uniform_real_distribution<float> bump(-0.008f, 0.008f);
        HeightField changed = whole;
        for (int r = 0; r < g.rows; ++r)
          for (int c = 0; c < g.cols; ++c) {
            if (std::max(std::abs(r - pr), std::abs(c - pc)) <= claim || std::isnan(changed.at(r, c))) continue;
            changed.at(r, c) += bump(rng);
          }
        const bool same = removed_of(changed)[p] == base[p];
        if (claim == reach) {
          EXPECT_TRUE(same) << "point " << p << " (node " << pr << ", " << pc << "), draw " << draw;
        } else {
          moved_inside += same ? 0U : 1U;
        }
      }
    }
  }
  EXPECT_GT(moved_inside, 0U) << "changes two cells nearer than D move no verdict: the test cannot see the grid's reads";
}

// window_islands (the tiled run's despike): a window whose cells equal the whole grid's only
// inside its exact region (the rest drawn at random, as a window's halo grid can differ) gives
// the whole grid's island labels (find_grid_spikes' marked cells on a flat grid: islands only)
// to every valid cell of the needed region whenever it reports no undecided group, with
// spare_largest_group off (the whole grid's largest group, a 400-cell block, is larger than
// island_max_cells). Oracles: the whole grid's labels, and a flood fill of the test's own
// (4-way loops over the 8 neighbours) for the undecided groups and the largest group. Over
// 300 random windows of a grid of random walks of 1 to 24 cells both cases occur, and some window
// that reports undecided groups does label a needed cell differently: the report is needed.
TEST(DespikeGrid, AWindowGivesTheWholeGridsIslandsWhereItReportsNoUndecidedGroup) {
  const GridGeometry g{90, 110, 0.0, 0.0, 0.001};
  HeightField whole(g);
  for (float& v : whole.values()) v = std::numeric_limits<float>::quiet_NaN();
  std::mt19937 rng(53);
  for (int r = 35; r < 55; ++r)
    for (int c = 45; c < 65; ++c) whole.at(r, c) = 0.0f;
  for (int w = 0; w < 260; ++w) {
    int r = std::uniform_int_distribution<int>(0, g.rows - 1)(rng), c = std::uniform_int_distribution<int>(0, g.cols - 1)(rng);
    const int len = std::uniform_int_distribution<int>(1, 24)(rng);
    for (int k = 0; k < len; ++k) {
      whole.at(r, c) = 0.0f;
      r = std::clamp(r + std::uniform_int_distribution<int>(-1, 1)(rng), 0, g.rows - 1);
      c = std::clamp(c + std::uniform_int_distribution<int>(-1, 1)(rng), 0, g.cols - 1);
    }
  }
  HonestCheckOptions options;  // island_max_cells 16
  const int m = options.island_max_cells;
  auto islands_of = [](const HeightField& h, const HonestCheckOptions& o) {
    const GridSpikes s = find_grid_spikes(h, o);
    EXPECT_EQ(s.spikes + s.pits, 0U) << "a flat grid";
    EXPECT_LT(s.marked.size(), 1000U) << "marked is cut at 1000 cells";
    std::vector<std::uint8_t> mask(h.geometry().cell_count(), 0);
    for (const auto& rc : s.marked) mask[static_cast<std::size_t>(rc[0]) * static_cast<std::size_t>(h.geometry().cols) + static_cast<std::size_t>(rc[1])] = 1;
    return mask;
  };
  const std::vector<std::uint8_t> truth = islands_of(whole, options);
  HonestCheckOptions in_window = options;
  in_window.spare_largest_group = false;
  std::size_t decided_windows = 0, undecided_windows = 0, undecided_and_wrong = 0;
  for (int draw = 0; draw < 300; ++draw) {
    auto pick = [&](int lo, int hi) { return std::uniform_int_distribution<int>(lo, hi)(rng); };
    const int h = pick(20, 60), w = pick(20, 60);
    const int r0 = pick(-10, g.rows - h + 10), c0 = pick(-10, g.cols - w + 10);  // the window, clipped to the grid
    const int wr0 = std::max(0, r0), wr1 = std::min(g.rows, r0 + h), wc0 = std::max(0, c0), wc1 = std::min(g.cols, c0 + w);
    const int a = pick(2, 7), b = pick(0, 5);
    // exact: the window less a cells where the grid goes on; needed: exact less b more.
    const std::array<int, 4> ex{wr0 > 0 ? a : 0, wr1 < g.rows ? (wr1 - wr0) - a : wr1 - wr0, wc0 > 0 ? a : 0,
                                wc1 < g.cols ? (wc1 - wc0) - a : wc1 - wc0};
    if (ex[1] - ex[0] < 2 * b + 1 || ex[3] - ex[2] < 2 * b + 1) continue;
    const std::array<int, 4> need{ex[0] + b, ex[1] - b, ex[2] + b, ex[3] - b};
    const std::array<bool, 4> open{wr0 + ex[0] > 0, wr0 + ex[1] < g.rows, wc0 + ex[2] > 0, wc0 + ex[3] < g.cols};
    HeightField win(GridGeometry{wr1 - wr0, wc1 - wc0, g.x_of_col(wc0), g.y_of_row(wr0), g.cell_size_m});
    std::bernoulli_distribution valid(0.3);
    for (int r = 0; r < win.rows(); ++r)
      for (int c = 0; c < win.cols(); ++c) {
        const bool inside = r >= ex[0] && r < ex[1] && c >= ex[2] && c < ex[3];
        win.at(r, c) = inside ? whole.at(wr0 + r, wc0 + c) : (valid(rng) ? 0.0f : std::numeric_limits<float>::quiet_NaN());
      }
    const WindowIslands wi = window_islands(win, m, ex, need, open);
    // The oracle's groups of exact's valid cells.
    const int er = ex[1] - ex[0], ec = ex[3] - ex[2];
    std::vector<int> label(static_cast<std::size_t>(er * ec), -1);
    std::size_t groups_undecided = 0, cells_undecided = 0, largest = 0;
    for (int s0 = 0; s0 < er * ec; ++s0) {
      if (label[static_cast<std::size_t>(s0)] >= 0 || std::isnan(win.at(ex[0] + s0 / ec, ex[2] + s0 % ec))) continue;
      std::vector<int> stack{s0}, cells;
      label[static_cast<std::size_t>(s0)] = s0;
      while (!stack.empty()) {
        const int q = stack.back();
        stack.pop_back();
        cells.push_back(q);
        for (int dr = -1; dr <= 1; ++dr)
          for (int dc = -1; dc <= 1; ++dc) {
            const int rr = q / ec + dr, cc = q % ec + dc;
            if (rr < 0 || rr >= er || cc < 0 || cc >= ec) continue;
            const int nq = rr * ec + cc;
            if (label[static_cast<std::size_t>(nq)] >= 0 || std::isnan(win.at(ex[0] + rr, ex[2] + cc))) continue;
            label[static_cast<std::size_t>(nq)] = s0;
            stack.push_back(nq);
          }
      }
      largest = std::max(largest, cells.size());
      bool touches = false, in_need = false;
      for (const int q : cells) {
        const int rr = q / ec, cc = q % ec;
        touches = touches || (open[0] && rr == 0) || (open[1] && rr == er - 1) || (open[2] && cc == 0) || (open[3] && cc == ec - 1);
        const int wr = ex[0] + rr, wc = ex[2] + cc;
        in_need = in_need || (wr >= need[0] && wr < need[1] && wc >= need[2] && wc < need[3]);
      }
      if (cells.size() <= static_cast<std::size_t>(m) && touches && in_need) ++groups_undecided, cells_undecided += cells.size();
    }
    EXPECT_EQ(wi.undecided_groups, groups_undecided) << "draw " << draw;
    EXPECT_EQ(wi.undecided_cells, cells_undecided) << "draw " << draw;
    EXPECT_EQ(wi.largest_exact_group, largest) << "draw " << draw;
    // The labels the window gives its needed cells against the whole grid's.
    const std::vector<std::uint8_t> seen = islands_of(win, in_window);
    std::size_t wrong = 0;
    for (int r = need[0]; r < need[1]; ++r)
      for (int c = need[2]; c < need[3]; ++c) {
        if (std::isnan(win.at(r, c))) continue;
        const std::uint8_t t = truth[static_cast<std::size_t>(wr0 + r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(wc0 + c)];
        wrong += seen[static_cast<std::size_t>(r) * static_cast<std::size_t>(win.cols()) + static_cast<std::size_t>(c)] != t ? 1U : 0U;
      }
    if (wi.undecided_groups == 0) {
      ++decided_windows;
      EXPECT_EQ(wrong, 0U) << "draw " << draw << ": a window with no undecided group labels a needed cell unlike the whole grid";
    } else {
      ++undecided_windows;
      undecided_and_wrong += wrong > 0 ? 1U : 0U;
    }
  }
  EXPECT_GT(decided_windows, 50U);
  EXPECT_GT(undecided_windows, 20U);
  // A window that holds only small groups, all inside its exact region (a tile beyond a
  // silhouette): every one is an island, as in the whole grid, its largest too.
  {
    HeightField w2(GridGeometry{30, 30, 0.0, 0.0, 0.001});
    for (float& v : w2.values()) v = std::numeric_limits<float>::quiet_NaN();
    for (const auto& rc : {std::array{10, 10}, std::array{10, 11}, std::array{11, 10}, std::array{20, 20}, std::array{15, 22}}) w2.at(rc[0], rc[1]) = 0.0f;
    const WindowIslands wi = window_islands(w2, m, {3, 27, 3, 27}, {6, 24, 6, 24}, {true, true, true, true});
    EXPECT_EQ(wi.undecided_groups, 0U);
    EXPECT_EQ(wi.largest_exact_group, 3U);
    const std::vector<std::uint8_t> seen = islands_of(w2, in_window);
    EXPECT_EQ(std::count(seen.begin(), seen.end(), std::uint8_t{1}), 5) << "the largest group (3 cells) is an island too";
  }
  EXPECT_GT(undecided_and_wrong, 0U) << "no undecided window labelled a cell wrongly: the test cannot see what the report guards";
  // The arguments' checks.
  EXPECT_THROW((void)window_islands(whole, 0, {0, 10, 0, 10}, {0, 5, 0, 5}, {}), std::invalid_argument);
  EXPECT_THROW((void)window_islands(whole, m, {0, 10, 0, 200}, {0, 5, 0, 5}, {}), std::invalid_argument);
  EXPECT_THROW((void)window_islands(whole, m, {5, 10, 5, 10}, {0, 8, 5, 8}, {}), std::invalid_argument);
}

TEST(DespikeGrid, RemovesAStrayJustBeyondASilhouetteAtEverySplatRadius) {
  // A tilted plane sampled every 0.25 mm on x in [0, 30] and [45, 50] mm (the gap between is no
  // data) and one stray 1.3 cells (0.65 mm) beyond the silhouette at x = 30 mm, 2.5 mm behind
  // the plane: 2.58 mm from every surface point, beyond ρ_hi (4 cells = 2 mm). It stands above
  // nothing, so no spike test sees it; it extends the surface into the gap. At every splat
  // radius it goes and every surface point stays. With only a rim cell's own points judged, it
  // stayed from a radius of 1.5 cells on (its disc covers its cell's 8 neighbours).
  auto plane = [](double x, double y) { return 0.1 * x + 0.05 * y; };
  std::vector<Eigen::Vector3d> pts;
  for (int j = 0; j <= 120; ++j)
    for (int i = 0; i <= 200; ++i) {
      const double x = 0.00025 * i;
      if (x > 0.030 + 1e-9 && x < 0.045 - 1e-9) continue;
      const double y = 0.00025 * j;
      pts.emplace_back(x, y, plane(x, y));
    }
  const std::size_t n_surface = pts.size();
  pts.emplace_back(0.03065, 0.015, plane(0.03065, 0.015) - 0.0025);
  const Cloud cloud = cloud_of(pts);
  for (const double radius : {1.0, 1.2, 1.5, 2.0, 3.0}) {
    ReprojectOptions ro;
    ro.grid.cell_size_m = 0.0005;
    ro.splat_radius_cells = radius;
    const DepthGrid grid = reproject(cloud, ro).value;
    const auto r = remove_spike_points(cloud, grid.depth, HonestCheckOptions{}, std::max(1.0, radius), 0.00025);
    ASSERT_EQ(r.value.size(), n_surface) << "radius " << radius << ": removed " << cloud.size() - r.value.size();
    EXPECT_EQ(r.value.xyz, cloud.xyz.leftCols(static_cast<Eigen::Index>(n_surface))) << radius;
    EXPECT_GT(hc::test::figure(r.report, "rim_cells"), 0.0) << radius;
  }
  ReprojectOptions ro;
  ro.grid.cell_size_m = 0.0005;
  const DepthGrid grid = reproject(cloud, ro).value;
  EXPECT_THROW(remove_spike_points(cloud, grid.depth, HonestCheckOptions{}, 1.0, 0.00025, 0.5), std::invalid_argument);
}

TEST(InputCheck, ClassesOnAFlatGridMatchTheirConstruction) {
  // A flat grid (z = 0, nodes every 1 mm over 20 x 20 mm) with a no-data corner (nodes 15..20
  // in both axes), points at the cell centres ((c + ½), (r + ½)) mm, and known extras.
  GridGeometry g{21, 21, 0.0, 0.0, 0.001};
  HeightField h(g, 0.0f);
  for (int r = 15; r < 21; ++r)
    for (int c = 15; c < 21; ++c) h.at(r, c) = kNoData;
  std::vector<Eigen::Vector3d> all;
  for (int r = 0; r < 20; ++r)
    for (int c = 0; c < 20; ++c) all.emplace_back(0.001 * (c + 0.5), 0.001 * (r + 0.5), 0.0);
  const std::size_t lattice = all.size();
  all.emplace_back(0.0055, 0.0055, -0.003);  // hidden: 3 mm behind (kept)
  all.emplace_back(0.0065, 0.0035, 0.0015);  // off the surface: 1.5 mm in front (kept)
  all.emplace_back(0.0055, 0.0055, 0.02);    // isolated, 20 mm in front: removed
  all.emplace_back(0.021, 0.0105, 0.0);      // outside the grid, 1 mm beyond x = 20 mm (kept)
  // The filter also "removed" two lattice points over no data: surface lost.
  const std::size_t lost_a = 19 * 20 + 19, lost_b = 19 * 20 + 18;
  std::vector<Eigen::Vector3d> kept_pts;
  for (std::size_t i = 0; i < lattice; ++i)
    if (i != lost_a && i != lost_b) kept_pts.push_back(all[i]);
  kept_pts.push_back(all[lattice]);
  kept_pts.push_back(all[lattice + 1]);
  kept_pts.push_back(all[lattice + 3]);
  const Cloud as_read = cloud_of(all), kept = cloud_of(kept_pts);
  HonestCheckOptions o;
  o.tolerance_m = 0.0005;
  o.hidden_band_m = 0.002;
  // The classes by construction, however the removed points are found.
  const auto expect_classes = [&](const InputCheck& c, const char* how) {
    SCOPED_TRACE(how);
    EXPECT_EQ(c.points, all.size());
    EXPECT_EQ(c.removed, 3u);
    EXPECT_EQ(c.hidden, 1u);
    EXPECT_EQ(c.off_surface, 1u);
    EXPECT_EQ(c.outside, 1u);
    // No data: the bilinear cell of a centre point (c + ½, r + ½) has corners c, c + 1 and r, r + 1,
    // so it touches the corner when c ≥ 14 and r ≥ 14: 6 x 6 points, minus the two removed ones.
    EXPECT_EQ(c.no_data, 6u * 6u - 2u);
    EXPECT_EQ(c.on_surface, lattice - 36u);
    expect_partition(c);
    EXPECT_EQ(c.isolated, 1u);
    EXPECT_EQ(c.surface_lost, 2u);
    // The lost point (19.5, 19.5) mm is binned to node (20, 20); the nearest valid nodes are
    // (14, 20) and (20, 14): 6 mm.
    EXPECT_NEAR(c.surface_lost_max_gap_m, 0.006, 1e-5);
    EXPECT_EQ(c.far, 0u);
    EXPECT_EQ(c.spikes_kept, 0u);
  };
  const InputCheck in = check_input(as_read.xyz, kept, h, o);
  expect_classes(in, "kept points matched in order");
  EXPECT_NEAR(in.spacing_m, 0.001, 1e-6);

  // The same kept points in reverse order, as a stage that reorders would leave them: the
  // in-order match cannot pair them, the multiset match decides, and the classes are the same.
  const std::vector<Eigen::Vector3d> reversed(kept_pts.rbegin(), kept_pts.rend());
  expect_classes(check_input(as_read.xyz, cloud_of(reversed), h, o), "kept points reversed: the multiset match");

  // The removed points flagged instead (InputCheckScope::removed, a tiled run's kept-point
  // mask), no kept points given, one tile owning every point over the whole grid: the same
  // classes. The scope's box of valid samples is the grid's, nodes (0, 0) to (20, 20) less the
  // no-data corner: x and y 0 to 20 mm, z 0.
  std::vector<std::uint8_t> owned(all.size(), 1), removed(all.size(), 0);
  removed[lost_a] = removed[lost_b] = removed[lattice + 2] = 1;
  hc::pipeline::InputCheckScope scope;
  scope.owned = &owned;
  scope.removed = &removed;
  scope.cells = {0, g.rows, 0, g.cols};
  scope.spacing_m = in.spacing_m;
  scope.valid_lo = Eigen::Vector3d(0.0, 0.0, 0.0);
  scope.valid_hi = Eigen::Vector3d(0.020, 0.020, 0.0);
  expect_classes(check_input(as_read.xyz, Cloud{}, h, o, 0.0, nullptr, nullptr, &scope), "removed points flagged");
  std::vector<std::uint8_t> short_flags(all.size() - 1, 0);
  scope.removed = &short_flags;
  EXPECT_THROW(check_input(as_read.xyz, Cloud{}, h, o, 0.0, nullptr, nullptr, &scope), std::invalid_argument)
      << "a removed flag per point";
}

// InputCheckScope::near (a tiled run's kept-point mask marks the points its filters saw with
// neighbours): the point test then searches only about the other points and hashes only the
// voxels its searches (and the spike searches) visit. Oracles: the same check without the flags
// (one hash of every point), and a brute-force count of each point's neighbours.
TEST(InputCheck, NearFlagsSpareTestsButNotOneFigure) {
  // A rough surface over 40 × 40 mm (nodes every 1 mm), points every 0.5 mm with 0.05 mm of
  // noise; strays above it (some removed, some kept: one kept 30 mm up made its cell a spike);
  // a hollow 10 mm below; points removed along a strip (surface lost over no-data cells).
  GridGeometry g{41, 41, 0.0, 0.0, 0.001};
  HeightField h(g, 0.0f);
  auto surf = [](double x, double y) { return 0.002 * std::sin(300.0 * x) * std::cos(200.0 * y); };
  for (int r = 0; r < 41; ++r)
    for (int c = 0; c < 41; ++c) h.at(r, c) = static_cast<float>(surf(0.001 * c, 0.001 * r));
  for (int r = 30; r < 41; ++r)
    for (int c = 0; c < 5; ++c) h.at(r, c) = kNoData;
  std::mt19937 rng(11);
  std::normal_distribution<double> noise(0.0, 0.00005);
  std::uniform_real_distribution<double> u(0.0, 0.040), up(0.003, 0.030);
  std::vector<Eigen::Vector3d> pts;
  std::vector<std::uint8_t> removed;
  for (int r = 0; r < 80; ++r)
    for (int c = 0; c < 80; ++c) {
      const double x = 0.0005 * c + 0.00025, y = 0.0005 * r + 0.00025;
      pts.emplace_back(x + noise(rng), y + noise(rng), surf(x, y) + noise(rng));
      removed.push_back(x < 0.004 && y > 0.031 ? 1 : 0);  // over the no-data corner: lost
    }
  for (int k = 0; k < 300; ++k) {
    const double x = u(rng), y = u(rng);
    pts.emplace_back(x, y, surf(x, y) + up(rng));
    removed.push_back(k % 3 == 0 ? 0 : 1);
  }
  for (int k = 0; k < 4; ++k) {  // a small clump in front (not isolated), removed
    pts.emplace_back(0.020 + 0.0002 * k, 0.010, 0.012);
    removed.push_back(1);
  }
  pts.emplace_back(0.030, 0.030, 0.030);  // a kept stray that made cell (30, 30)
  removed.push_back(0);
  h.at(30, 30) = 0.030f;
  // Cell (37, 37) raised 15 mm to S, with a kept point A 0.45 mm above S that has only two
  // others within the test's radius (isolated), and D1 0.45 mm below S that has three (A, D2,
  // D3): D1 confirms the cell, which is then no spike kept. In the check's frame (centred at
  // z = 14 mm) S lies 0.2 mm above a voxel boundary and D1 below it: the spike search must reach
  // the next voxel.
  const Eigen::Vector3d s_cell(0.037, 0.037, 0.0142);
  h.at(37, 37) = static_cast<float>(s_cell.z());
  for (const Eigen::Vector3d& d : {Eigen::Vector3d(0.0, 0.0, 0.00045), Eigen::Vector3d(0.0, 0.0, -0.00045),
                                   Eigen::Vector3d(-0.0001, 0.0, -0.00045), Eigen::Vector3d(0.0, 0.0, -0.0015)}) {
    pts.push_back(s_cell + d);
    removed.push_back(0);
  }
  const Cloud c = cloud_of(pts);
  const std::size_t n = pts.size();
  HonestCheckOptions o;
  o.isolation_radius_spacings = 3.0;  // R = 1.5 mm at the 0.5 mm spacing
  o.confirm_footprint_m = 0.0015;
  std::vector<std::uint8_t> owned(n, 1);
  CellBuffer<std::uint8_t> flags(g.cell_count(), kCellMeasured);
  InputCheckScope scope;
  scope.owned = &owned;
  scope.removed = &removed;
  scope.cells = {0, g.rows, 0, g.cols};
  scope.spacing_m = 0.0005;
  scope.valid_lo = Eigen::Vector3d(0.0, 0.0, -0.002);
  scope.valid_hi = Eigen::Vector3d(0.040, 0.040, 0.030);
  const double radius = o.isolation_radius_spacings * scope.spacing_m;
  const double filter = isolated_filter_radius_m(o, scope.spacing_m);
  ASSERT_NEAR(filter, 0.9 * radius, 1e-12);
  // Brute force: others within the filter's radius (the flag's promise) and within the test's.
  std::vector<std::uint8_t> near(n, 0);
  std::size_t isolated = 0, promised = 0;
  for (std::size_t i = 0; i < n; ++i) {
    int within_filter = 0, within = 0;
    for (std::size_t j = 0; j < n; ++j) {
      if (j == i) continue;
      const double d = (pts[i] - pts[j]).norm();
      within_filter += d <= filter * (1.0 - 1e-6) ? 1 : 0;
      within += d <= radius ? 1 : 0;
    }
    isolated += within < o.isolation_min_neighbours ? 1U : 0U;
    // Most points that have them flagged (every seventh left to its test, as a removed point
    // whose neighbours no filter saw).
    if (within_filter >= o.isolation_min_neighbours && i % 7 != 0) {
      near[i] = 1;
      ++promised;
    }
  }
  ASSERT_GT(isolated, 100U) << "the strays high above are isolated";
  ASSERT_GT(promised, n / 2);
  // With the grid's spikes confirmed (step 5) and without (step 4's searches alone hash their
  // voxels then).
  for (const bool with_spikes : {true, false}) {
    SCOPED_TRACE(with_spikes ? "spikes confirmed" : "no spike confirmation");
    GridSpikes full_spikes = find_grid_spikes(h, o), near_spikes = full_spikes;
    ASSERT_FALSE(full_spikes.flagged.empty()) << "the raised cells";
    scope.near = nullptr;
    const InputCheck full = check_input(c.xyz, Cloud{}, h, o, 0.0, with_spikes ? &full_spikes : nullptr, &flags, &scope);
    scope.near = &near;
    const InputCheck spared = check_input(c.xyz, Cloud{}, h, o, 0.0, with_spikes ? &near_spikes : nullptr, &flags, &scope);
    EXPECT_EQ(full.isolated, isolated) << "the brute-force count";
    for (const auto& [name, x, y] : {std::tuple{"removed", full.removed, spared.removed}, std::tuple{"on_surface", full.on_surface, spared.on_surface},
                                     std::tuple{"off_surface", full.off_surface, spared.off_surface}, std::tuple{"hidden", full.hidden, spared.hidden},
                                     std::tuple{"no_data", full.no_data, spared.no_data}, std::tuple{"outside", full.outside, spared.outside},
                                     std::tuple{"isolated", full.isolated, spared.isolated}, std::tuple{"spikes_kept", full.spikes_kept, spared.spikes_kept},
                                     std::tuple{"surface_lost", full.surface_lost, spared.surface_lost},
                                     std::tuple{"removed_in_front", full.removed_in_front, spared.removed_in_front},
                                     std::tuple{"far", full.far, spared.far}}) {
      EXPECT_EQ(y, x) << name;
    }
    // Cell (30, 30) stands on the isolated stray alone; cell (37, 37) is confirmed by D1.
    EXPECT_EQ(full.spikes_kept_cells, (std::vector<std::array<int, 2>>{{30, 30}}));
    EXPECT_EQ(spared.spikes_kept_cells, full.spikes_kept_cells);
    EXPECT_EQ(near_spikes.confirmed, full_spikes.confirmed);
    EXPECT_GT(full.surface_lost, 0U) << "the strip over no data";
    // The work: every point tested and hashed without the flags; with them only the unflagged
    // tested, and the points about them (and about the spike searches) hashed.
    EXPECT_EQ(full.isolation_tested, n);
    EXPECT_EQ(full.isolation_hashed, n);
    EXPECT_EQ(spared.isolation_tested, n - promised);
  }

  // One point 1 km away: the local frame's coordinates reach past 10^4 test radii, where the
  // float rounding of the filters' frames is not known to stay inside the margin; the flags are
  // not used, and the figures are still the full test's.
  std::vector<Eigen::Vector3d> with_far = pts;
  with_far.emplace_back(1000.0, 0.0, 0.0);
  std::vector<std::uint8_t> owned2(n + 1, 1), removed2 = removed, near2 = near;
  removed2.push_back(1);
  near2.push_back(0);
  const Cloud c2 = cloud_of(with_far);
  InputCheckScope scope2 = scope;
  scope2.owned = &owned2;
  scope2.removed = &removed2;
  scope2.near = &near2;
  const InputCheck far_near = check_input(c2.xyz, Cloud{}, h, o, 0.0, nullptr, &flags, &scope2);
  EXPECT_EQ(far_near.isolation_tested, n + 1);
  EXPECT_EQ(far_near.isolated, isolated + 1);
  std::vector<std::uint8_t> short_near(n - 1, 0);
  scope.near = &short_near;
  EXPECT_THROW(check_input(c.xyz, Cloud{}, h, o, 0.0, nullptr, &flags, &scope), std::invalid_argument) << "a near flag per point";
}

// A few points left to the point test, the rest flagged near (as a tiled run's filters flag the
// points they saw with neighbours; every flag here a true promise): strays above a surface, each
// beside a clump of four points (flagged) on its low-x side, 1.2 mm away for half of them (then
// not isolated) and 1.7 mm for the rest (isolated), at offsets that sweep a voxel's width, so
// that the clump lies in the voxels (and the x-y columns, which the hash's pass tests first)
// before the stray's own. The spared check hashes only the voxels about the tested strays and
// must still count the clumps. Oracles: the check without the flags (every point hashed) and a
// brute-force count.
TEST(InputCheck, SparseTestsCountNeighboursInTheColumnsBeforeTheirOwn) {
  GridGeometry g{41, 41, 0.0, 0.0, 0.001};
  HeightField h(g, 0.0f);
  std::vector<Eigen::Vector3d> pts;
  std::vector<std::uint8_t> near;
  for (int r = 0; r < 80; ++r)
    for (int c = 0; c < 80; ++c) {
      pts.emplace_back(0.0005 * c + 0.00025, 0.0005 * r + 0.00025, 0.0);
      near.push_back(1);  // 8 others within 0.9 × 1.5 mm at the least (a corner)
    }
  HonestCheckOptions o;
  o.isolation_radius_spacings = 3.0;  // R = 1.5 mm at the 0.5 mm spacing
  std::vector<std::size_t> strays;
  for (int i = 0; i < 24; ++i) {
    // Strays 6 mm above the surface (some beyond its x-y extent), 12 mm apart (so that the
    // columns about them cover under half of their range, and the hash's pass uses the column
    // table), their x-y offsets sweeping a voxel's width (1.5 mm) in steps of about 0.13 mm.
    const Eigen::Vector3d p(0.003 + 0.012 * (i % 6) + 0.00013 * i, 0.004 + 0.012 * (i / 6) + 0.00011 * i, 0.006);
    strays.push_back(pts.size());
    pts.push_back(p);
    near.push_back(0);
    const Eigen::Vector3d clump = p + Eigen::Vector3d(i % 2 == 0 ? -0.0012 : -0.0017, 0.0, 0.0);
    for (const Eigen::Vector3d& d : {Eigen::Vector3d(0.0001, 0.0, 0.0), Eigen::Vector3d(-0.0001, 0.0, 0.0),
                                     Eigen::Vector3d(0.0, 0.0001, 0.0), Eigen::Vector3d(0.0, -0.0001, 0.0)}) {
      pts.push_back(clump + d);
      near.push_back(1);  // three others within 0.2 mm
    }
  }
  const std::size_t n = pts.size();
  const double radius = o.isolation_radius_spacings * 0.0005;
  std::size_t expected_isolated = 0, strays_isolated = 0;
  for (std::size_t i = 0; i < n; ++i) {
    int within = 0;
    for (std::size_t j = 0; j < n; ++j) within += j != i && (pts[i] - pts[j]).norm() <= radius ? 1 : 0;
    const bool isolated = within < o.isolation_min_neighbours;
    expected_isolated += isolated ? 1U : 0U;
    if (std::find(strays.begin(), strays.end(), i) != strays.end()) strays_isolated += isolated ? 1U : 0U;
    if (near[i] != 0) {
      ASSERT_GE(within, o.isolation_min_neighbours) << "a near flag is a promise, point " << i;
    }
  }
  ASSERT_EQ(strays_isolated, 12U) << "the strays 1.7 mm from their clumps";
  ASSERT_EQ(expected_isolated, 12U);
  const Cloud c = cloud_of(pts);
  std::vector<std::uint8_t> owned(n, 1), removed(n, 0);
  CellBuffer<std::uint8_t> flags(g.cell_count(), kCellMeasured);
  InputCheckScope scope;
  scope.owned = &owned;
  scope.removed = &removed;
  scope.cells = {0, g.rows, 0, g.cols};
  scope.spacing_m = 0.0005;
  scope.valid_lo = Eigen::Vector3d(0.0, 0.0, 0.0);
  scope.valid_hi = Eigen::Vector3d(0.040, 0.040, 0.0);
  const InputCheck full = check_input(c.xyz, Cloud{}, h, o, 0.0, nullptr, &flags, &scope);
  scope.near = &near;
  const InputCheck spared = check_input(c.xyz, Cloud{}, h, o, 0.0, nullptr, &flags, &scope);
  EXPECT_EQ(full.isolated, expected_isolated) << "the brute-force count";
  EXPECT_EQ(spared.isolated, expected_isolated) << "the spared check";
  EXPECT_EQ(spared.isolation_tested, strays.size());
  EXPECT_LT(spared.isolation_hashed, 1000U) << "only the voxels about the tested strays hashed";
}

/// Points at every node of an n × n grid of `pitch` [m] at z = 0.
std::vector<Eigen::Vector3d> node_lattice(int n, double pitch) {
  std::vector<Eigen::Vector3d> pts;
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n; ++c) pts.emplace_back(pitch * c, pitch * r, 0.0);
  return pts;
}

TEST(InputCheck, ACellKeptOnlyByAnIsolatedPointIsASpikeKept) {
  GridGeometry g{21, 21, 0.0, 0.0, 0.001};
  HeightField h(g, 0.0f);
  std::vector<Eigen::Vector3d> pts = node_lattice(21, 0.001);
  pts.emplace_back(0.010, 0.010, 0.040);  // 40 mm above the node (10, 10)
  h.at(10, 10) = 0.040f;                  // which the grid kept
  const Cloud c = cloud_of(pts);
  HonestCheckOptions o;
  const InputCheck in = check_input(c.xyz, c, h, o);
  EXPECT_EQ(in.isolated, 1u);
  EXPECT_EQ(in.spikes_kept, 1u);
  ASSERT_EQ(in.spikes_kept_cells.size(), 1u);
  EXPECT_EQ(in.spikes_kept_cells[0][0], 10);
  EXPECT_EQ(in.spikes_kept_cells[0][1], 10);
}

TEST(InputCheck, ASpikeDrawnFromAGenuinePointsDiscIsConfirmedOnlyAtThatPointsHeight) {
  // Airborne lidar at about one point per cell: a tree top 40 mm up, 3.5 mm from the node in
  // x-y, made cell (10, 10) through its splat disc. Grid: 5 mm cells, a flat lattice of points at
  // every node; the tree top is four points 0.1 mm apart (not isolated).
  GridGeometry g{21, 21, 0.0, 0.0, 0.005};
  HeightField h(g, 0.0f);
  std::vector<Eigen::Vector3d> pts = node_lattice(21, 0.005);
  for (int k = 0; k < 4; ++k) pts.emplace_back(0.0535 + 0.0001 * (k % 2), 0.050 + 0.0001 * (k / 2), 0.040);
  const Cloud c = cloud_of(pts);
  CellBuffer<std::uint8_t> flags(g.cell_count(), kCellMeasured);
  auto confirmed_with = [&](float cell_z_m, double footprint_m, std::uint8_t flag = kCellSplatted,
                            const Cloud* kept = nullptr) {
    HeightField grid = h;
    grid.at(10, 10) = cell_z_m;
    flags[10 * 21 + 10] = flag;
    HonestCheckOptions o;  // tolerance 0.5 mm, spike_min_height 2 mm: 3-D confirmation reach 2 mm
    o.confirm_footprint_m = footprint_m;
    GridSpikes s = find_grid_spikes(grid, o);
    EXPECT_EQ(s.spikes, 1u);
    const InputCheck in = check_input(c.xyz, kept ? *kept : c, grid, o, 0.0, &s, &flags);
    EXPECT_EQ(in.isolated, 0u);
    return s.confirmed;
  };
  // 3.5 mm away in x-y: beyond the 2 mm of the 3-D test, so unconfirmed without a footprint.
  EXPECT_EQ(confirmed_with(0.040f, 0.0), 0u);
  // A 1.5-cell disc (7.5 mm) reaches it, at the cell's height: confirmed.
  EXPECT_EQ(confirmed_with(0.040f, 0.0075), 1u);
  // 1.5 mm higher than the tree top: still within 2 mm, confirmed; 5 mm higher: not.
  EXPECT_EQ(confirmed_with(0.0415f, 0.0075), 1u);
  EXPECT_EQ(confirmed_with(0.045f, 0.0075), 0u);
  // A disc of 3 mm does not reach 3.5 mm.
  EXPECT_EQ(confirmed_with(0.040f, 0.003), 0u);
  // A hole-filled cell was made by no disc: only the 3-D test may confirm it.
  EXPECT_EQ(confirmed_with(0.040f, 0.0075, kCellFilled), 0u);
  EXPECT_EQ(confirmed_with(0.040f, 0.0075, kCellMeasured), 1u);
  // Tree-top points the filters removed made no cell: they do not confirm it.
  std::vector<Eigen::Vector3d> lattice(pts.begin(), pts.end() - 4);
  const Cloud without_top = cloud_of(lattice);
  EXPECT_EQ(confirmed_with(0.040f, 0.0075, kCellSplatted, &without_top), 0u);
  HonestCheckOptions bad;
  bad.confirm_footprint_m = -1.0;
  EXPECT_THROW(find_grid_spikes(h, bad), ConfigError);
}

TEST(Verdict, LevelsFollowTheLimitsAndTheStageFigures) {
  InputCheck in;
  in.points = 1000;
  in.on_surface = 1000;
  in.spacing_m = 0.0005;
  GridSpikes sp;
  HonestCheckOptions o;
  EXPECT_EQ(decide_verdict(in, sp, 1.0, {}, o).status, "pass");
  // A far-cluster figure from the outlier stage alone makes a warning.
  StageReport outliers;
  outliers.stage = "outliers";
  outliers.figure("removed_far_clusters", 30);
  outliers.figure("threshold_mm", 9993.0);  // 20 000 spacings
  Verdict v = decide_verdict(in, sp, 1.0, {outliers}, o);
  EXPECT_EQ(v.status, "warn");
  EXPECT_TRUE(v.has("far_points"));
  EXPECT_TRUE(v.has("filter_threshold"));
  sp.spikes = 1;
  v = decide_verdict(in, sp, 1.0, {}, o);
  EXPECT_EQ(v.status, "fail");
  EXPECT_TRUE(v.has("grid_spikes"));
  o.max_spike_cells = 1;
  EXPECT_EQ(decide_verdict(in, sp, 1.0, {}, o).status, "pass");
  EXPECT_EQ(decide_verdict(in, sp, 0.5, {}, o).status, "warn");  // unsupported
}

TEST(ColourBar, LabelsDifferAndMarkClippedEnds) {
  GridGeometry g{10, 10, 0.0, 0.0, 0.001};
  HeightField h(g);
  for (int i = 0; i < 100; ++i) h.values()[static_cast<std::size_t>(i)] = static_cast<float>(-500.0 + 1e-4 * i);
  h.values()[0] = 500.0f;  // one spike far above
  const ColourBar bar = colour_bar(h, 1000.0);
  EXPECT_NE(bar.lo_label, bar.hi_label);
  EXPECT_LT(std::stod(bar.lo_label), std::stod(bar.hi_label));
  EXPECT_TRUE(bar.clipped_high);
  EXPECT_EQ(bar.max_label, "max 5e+05");
}

TEST(HonestCheckConfig, KeysAreReadAndCheckedByName) {
  const fs::path origin = fs::path(HC_SOURCE_DIR) / "configs" / "x.yaml";
  const RunConfig c = parse_run_config(
      "input: {files: [a.ply]}\ncross_check: {spike_window_cells: 7, max_removed_fraction: 0.2, tolerance_m: 0.001}\n", origin);
  EXPECT_EQ(c.cross_check.honest.spike_window_cells, 7);
  EXPECT_DOUBLE_EQ(c.cross_check.honest.max_removed_fraction, 0.2);
  EXPECT_DOUBLE_EQ(c.cross_check.honest.tolerance_m, 0.001);
  try {
    parse_run_config("input: {files: [a.ply]}\ncross_check: {spike_window_cells: 4}\n", origin);
    ADD_FAILURE() << "an even window was accepted";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("cross_check.spike_window_cells"), std::string::npos) << e.what();
  }
}


// median_point_spacing against brute force: the same strided sample (every ⌈N / 4096⌉-th finite
// point: every 2nd of the plane's 9000, every 9th of the cube's 40 000), each one's nearest
// neighbour over all points by a full scan, the median as nth_element places it. Clouds: a
// noisy plane with clutter, and the same with a point 1 km away (cells beyond the voxel keys'
// clamp limit); a 0.1 m cube filled at random, where the pilot's guess at a 0.05 m start edge
// (which assumes a surface, spacing ≈ edge / √count: 1.4 mm) is below the spacing (1.6 mm) and
// the edge must grow after it. Start edges far below the spacing (the edge must grow) and far
// above it (the pilot shrinks it); a pair out of reach of every edge, and start edges that are
// not lengths.
TEST(MedianPointSpacing, EqualsTheBruteForceMedianOfTheStridedSample) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Eigen::Vector3d> plane, cube;
  for (int i = 0; i < 8900; ++i) plane.emplace_back(0.1 * u(rng), 0.1 * u(rng), 0.0005 * u(rng));
  for (int i = 0; i < 99; ++i) plane.emplace_back(0.1 * u(rng), 0.1 * u(rng), 0.05 * u(rng));
  for (int i = 0; i < 40000; ++i) cube.emplace_back(0.1 * u(rng), 0.1 * u(rng), 0.1 * u(rng));
  struct Case {
    std::vector<Eigen::Vector3d> pts;
    std::string name;
  };
  std::vector<Case> cases;
  plane.emplace_back(0.05, 0.05, 0.01);
  cases.push_back({plane, "plane"});
  plane.back() = Eigen::Vector3d(1000.0, 0.05, 0.01);
  cases.push_back({plane, "plane and a point 1 km away"});
  cases.push_back({cube, "cube"});
  for (const auto& [pts, name] : cases) {
    Eigen::Matrix3Xd xyz(3, static_cast<Eigen::Index>(pts.size()));
    for (std::size_t i = 0; i < pts.size(); ++i) xyz.col(static_cast<Eigen::Index>(i)) = pts[i];
    const std::size_t stride = std::max<std::size_t>(1, pts.size() / 4096);
    std::vector<double> nn;
    for (std::size_t i = 0; i < pts.size(); i += stride) {
      double best = std::numeric_limits<double>::infinity();
      for (std::size_t j = 0; j < pts.size(); ++j) {
        if (j != i) best = std::min(best, (pts[i] - pts[j]).squaredNorm());
      }
      nn.push_back(std::sqrt(best));
    }
    auto mid = nn.begin() + static_cast<std::ptrdiff_t>(nn.size() / 2);
    std::nth_element(nn.begin(), mid, nn.end());
    for (const double start : {1e-6, 1e-4, 0.05, 0.1}) {
      // The function works in floats about the points' mean (at most about 0.12 m away here,
      // the far point aside): agreement to float rounding, 1e-8 m.
      EXPECT_NEAR(median_point_spacing(xyz, start), *mid, 1e-7) << name << ", start edge " << start;
    }
  }
  // Out of reach: two points 1 km apart from a 2 mm start edge. The median (1 km) never fits
  // within 2 mm · 4⁷ = 32.8 m, and the documented lower bound 2 mm · 4⁸ = 131 m comes back.
  Eigen::Matrix3Xd pair(3, 2);
  pair << 0.0, 1000.0, 0.0, 0.0, 0.0, 0.0;
  EXPECT_DOUBLE_EQ(median_point_spacing(pair, 0.002), 0.002 * 65536.0);
  // A start edge that is not a finite length > 0 is refused by name (a NaN edge never fits).
  for (const double bad : {0.0, -1.0, std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity()}) {
    try {
      (void)median_point_spacing(pair, bad);
      ADD_FAILURE() << "start edge " << bad << " was accepted";
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("start_edge_m"), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace hc::pipeline

namespace hc::pipeline {
namespace {

// InputCheckScope::whole: a tile's points classified on the whole grid, as in core. The window's
// own origin (the whole grid's plus c0 cells, rounded) puts its last column's x a float step
// off the whole grid's; a point exactly on the whole grid's last column (the point that set its
// box) then falls outside the window's extent. The oracle: check_input on the whole grid without
// a scope (the in-core classes), and the window's x-y extent computed independently.
TEST(HonestCrossCheck, AWindowsPointsAreClassifiedOnTheWholeGridWhenTheScopeGivesIt) {
  GridGeometry g;
  g.rows = 12;
  g.cols = 40;
  g.cell_size_m = 0.0047468682685932;  // as a generated wall's: no short binary fraction
  g.x0_m = -0.678796619176864;
  g.y0_m = -0.194621599012321;
  HeightField whole(g);
  for (float& z : whole.values()) z = 0.01f;
  // A window of the last columns whose own last x is below the whole grid's.
  int c0 = -1;
  for (int c = 1; c < g.cols - 2 && c0 < 0; ++c) {
    const double window_x0 = g.x_of_col(c);
    if (window_x0 + static_cast<double>(g.cols - 1 - c) * g.cell_size_m < g.x_of_col(g.cols - 1)) c0 = c;
  }
  ASSERT_GE(c0, 0) << "no window whose last x rounds below the whole grid's: pick another cell size";
  GridGeometry wg = g;
  wg.cols = g.cols - c0;
  wg.x0_m = g.x_of_col(c0);
  HeightField window(wg);
  for (float& z : window.values()) z = 0.01f;
  // Points on the whole grid's last column, on the surface; one inside for contrast.
  const double x_last = g.x_of_col(g.cols - 1);
  std::vector<Eigen::Vector3d> pts;
  for (int r = 0; r < g.rows; ++r) pts.emplace_back(x_last, g.y_of_row(r), 0.01);
  pts.emplace_back(g.x_of_col(g.cols - 3), g.y_of_row(5), 0.01);
  const Cloud cloud = hc::test::cloud_of(pts);
  HonestCheckOptions o;
  o.tolerance_m = 0.001;
  o.spacing_m = g.cell_size_m;
  const InputCheck in_core = check_input(cloud.xyz, cloud, whole, o);
  ASSERT_EQ(in_core.outside, 0U);
  ASSERT_EQ(in_core.on_surface, pts.size());
  std::vector<std::uint8_t> owned(pts.size(), 1), removed(pts.size(), 0);
  InputCheckScope scope;
  scope.owned = &owned;
  scope.removed = &removed;
  scope.cells = {0, wg.rows, 0, wg.cols};
  scope.spacing_m = g.cell_size_m;
  scope.valid_lo = Eigen::Vector3d(g.x0_m, g.y0_m, 0.01);
  scope.valid_hi = Eigen::Vector3d(x_last, g.y_of_row(g.rows - 1), 0.01);
  // Without the whole grid: the window's extent leaves the last column's points outside.
  const InputCheck windowed = check_input(cloud.xyz, Cloud{}, window, o, 0.0, nullptr, nullptr, &scope);
  EXPECT_EQ(windowed.outside, static_cast<std::size_t>(g.rows)) << "the window's own extent (the case the scope's grid fixes)";
  scope.whole = &whole;
  const InputCheck tiled = check_input(cloud.xyz, Cloud{}, window, o, 0.0, nullptr, nullptr, &scope);
  EXPECT_EQ(tiled.outside, in_core.outside);
  EXPECT_EQ(tiled.on_surface, in_core.on_surface);
  EXPECT_EQ(tiled.off_surface, in_core.off_surface);
  EXPECT_EQ(tiled.hidden, in_core.hidden);
  EXPECT_EQ(tiled.no_data, in_core.no_data);
  // A whole grid of another cell size is the caller's error.
  GridGeometry other = g;
  other.cell_size_m *= 2.0;
  const HeightField wrong(other);
  scope.whole = &wrong;
  EXPECT_THROW(check_input(cloud.xyz, Cloud{}, window, o, 0.0, nullptr, nullptr, &scope), std::invalid_argument);
}

}  // namespace
}  // namespace hc::pipeline
