// reproject_after_removal (reproject.hpp): the grid made again only about removed points must be
// the grid reproject makes from the remaining points, bit for bit, with the same report figures.
// The oracle is reproject itself on the whole cloud after the removal (or on the same window).

#include "hc/pipeline/honest_check.hpp"
#include "hc/pipeline/reproject.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace reproject_after_removal_test {

using hc::pipeline::Cloud;
using hc::pipeline::DepthGrid;
using hc::pipeline::GridWindow;
using hc::pipeline::RemovedPoints;
using hc::pipeline::ReprojectOptions;
using hc::pipeline::SplatMode;
using hc::pipeline::StageReport;
using hc::pipeline::StageResult;

std::uint32_t bits(float v) { return std::bit_cast<std::uint32_t>(v); }

// A carved relief (1 m × 0.4775 m, two corner points fix the box) scanned at random positions
// with noise, colour and intensity:
// a back face 40 mm behind it seen through sparse gaps (see-through events), an empty disc in the
// middle (splat fills at its rim), stray points in front (spikes), and two non-finite points.
Cloud relief(std::size_t n, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> ux(0.0, 1.0), uy(0.0, 0.4775), u01(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.0005);
  // The box's corners, so that with n_long_side 602 the grid has 602 × 288 nodes: 601 and 287
  // intervals, multiples of neither 2 nor 3, so an upsampled scan has a coarse node past the
  // grid's last row and column.
  std::vector<double> xyz = {0.0, 0.0, 0.0, 1.0, 0.4775, 0.0};
  Cloud c;
  for (std::size_t i = 0; i < n; ++i) {
    const double x = ux(rng), y = uy(rng);
    if (std::hypot(x - 0.5, y - 0.24) < 0.04) continue;  // a hole
    double z = 0.01 * std::sin(20.0 * x) * std::cos(15.0 * y) + noise(rng);
    const double pick = u01(rng);
    if (pick < 0.03) z -= 0.04;        // the back face, through the front's gaps
    else if (pick < 0.0035 + 0.03) z += 0.02 + 0.03 * u01(rng);  // strays in front
    xyz.insert(xyz.end(), {x, y, z});
  }
  const std::size_t m = xyz.size() / 3;
  c.xyz.resize(3, static_cast<Eigen::Index>(m));
  std::memcpy(c.xyz.data(), xyz.data(), xyz.size() * sizeof(double));
  c.xyz(0, 7) = std::numeric_limits<double>::quiet_NaN();
  c.xyz(2, 11) = std::numeric_limits<double>::infinity();
  c.rgb.resize(3 * m);
  c.intensity.resize(m);
  for (std::size_t i = 0; i < m; ++i) {
    for (int ch = 0; ch < 3; ++ch) c.rgb[3 * i + static_cast<std::size_t>(ch)] = static_cast<std::uint8_t>(rng() & 0xff);
    c.intensity[i] = static_cast<float>(u01(rng));
  }
  return c;
}

// The cloud without the columns in `gone` (increasing), and those points as RemovedPoints.
Cloud without(const Cloud& c, const std::vector<std::size_t>& gone, RemovedPoints& removed) {
  removed = RemovedPoints{};
  std::vector<bool> keep(c.size(), true);
  for (const std::size_t i : gone) {
    keep[i] = false;
    removed.at.push_back(i);
    for (int a = 0; a < 3; ++a) removed.xyz.push_back(c.xyz(a, static_cast<Eigen::Index>(i)));
  }
  Cloud out = c;
  out.keep_if(keep);
  return out;
}

void expect_same(const StageResult<DepthGrid>& got, const StageResult<DepthGrid>& want, const std::string& what) {
  SCOPED_TRACE(what);
  const DepthGrid& a = got.value;
  const DepthGrid& b = want.value;
  ASSERT_TRUE(a.depth.geometry() == b.depth.geometry());
  ASSERT_EQ(a.flags.size(), b.flags.size());
  std::size_t depth_diff = 0, flag_diff = 0, colour_diff = 0, intensity_diff = 0;
  for (std::size_t i = 0; i < a.flags.size(); ++i) {
    depth_diff += bits(a.depth.data()[i]) != bits(b.depth.data()[i]) ? 1U : 0U;
    flag_diff += a.flags[i] != b.flags[i] ? 1U : 0U;
    colour_diff += std::memcmp(a.colour_rgb8.data() + 3 * i, b.colour_rgb8.data() + 3 * i, 3) != 0 ? 1U : 0U;
    intensity_diff += bits(a.intensity.data()[i]) != bits(b.intensity.data()[i]) ? 1U : 0U;
  }
  EXPECT_EQ(depth_diff, 0U);
  EXPECT_EQ(flag_diff, 0U);
  EXPECT_EQ(colour_diff, 0U);
  EXPECT_EQ(intensity_diff, 0U);
  EXPECT_EQ(got.report.count_in, want.report.count_in);
  EXPECT_EQ(got.report.count_out, want.report.count_out);
  std::vector<std::pair<std::string, double>> fa = got.report.figures, fb = want.report.figures;
  std::sort(fa.begin(), fa.end());
  std::sort(fb.begin(), fb.end());
  EXPECT_EQ(fa, fb);
}

bool made_locally(const StageReport& r) {
  return std::any_of(r.notes.begin(), r.notes.end(),
                     [](const std::string& s) { return s.rfind("made again only about", 0) == 0; });
}

ReprojectOptions options(SplatMode mode, int upsample) {
  ReprojectOptions o;
  o.grid.n_long_side = 602;
  o.splat_radius_cells = 1.5;
  o.splat_mode = mode;
  o.see_through_depth_m = 0.02;
  o.see_through_window_cells = 3;
  o.upsample_factor = upsample;
  return o;
}

// Columns to remove: `count` random finite points away from the box's extremes, plus a cluster
// of points near one of them, plus points binned on the grid's first and last rows and columns.
std::vector<std::size_t> pick(const Cloud& c, std::size_t count, std::uint32_t seed, const hc::GridGeometry& g,
                              bool cluster_and_border = true) {
  std::mt19937 rng(seed);
  std::set<std::size_t> gone;
  double x_lo = 1e9, x_hi = -1e9, y_lo = 1e9, y_hi = -1e9;
  for (Eigen::Index i = 0; i < c.xyz.cols(); ++i) {
    if (!c.xyz.col(i).allFinite()) continue;
    x_lo = std::min(x_lo, c.xyz(0, i));
    x_hi = std::max(x_hi, c.xyz(0, i));
    y_lo = std::min(y_lo, c.xyz(1, i));
    y_hi = std::max(y_hi, c.xyz(1, i));
  }
  const auto ok = [&](std::size_t i) {
    const auto p = c.xyz.col(static_cast<Eigen::Index>(i));
    return p.allFinite() && p[0] > x_lo && p[0] < x_hi && p[1] > y_lo && p[1] < y_hi;  // the box stays
  };
  std::uniform_int_distribution<std::size_t> any(0, c.size() - 1);
  while (gone.size() < count) {
    const std::size_t i = any(rng);
    if (ok(i)) gone.insert(i);
  }
  if (!cluster_and_border) return {gone.begin(), gone.end()};
  // A cluster: every point within 3 cells of the first pick.
  const auto first = c.xyz.col(static_cast<Eigen::Index>(*gone.begin()));
  for (std::size_t i = 0; i < c.size(); ++i) {
    if (ok(i) && (c.xyz.col(static_cast<Eigen::Index>(i)).head<2>() - first.head<2>()).norm() < 3 * g.cell_size_m) gone.insert(i);
  }
  // Points on the border rows and columns.
  int border = 0;
  for (std::size_t i = 0; i < c.size() && border < 6; ++i) {
    if (!ok(i)) continue;
    const double fx = (c.xyz(0, static_cast<Eigen::Index>(i)) - g.x0_m) / g.cell_size_m;
    const double fy = (c.xyz(1, static_cast<Eigen::Index>(i)) - g.y0_m) / g.cell_size_m;
    if (fx < 1.0 || fy < 1.0 || fx > g.cols - 2.0 || fy > g.rows - 2.0) {
      gone.insert(i);
      ++border;
    }
  }
  return {gone.begin(), gone.end()};
}

TEST(ReprojectAfterRemoval, EqualsAWholeReprojectForPlaneAndDiscSplatsAtEveryUpsampleFactor) {
  const Cloud cloud = relief(500000, 3);
  int local_runs = 0;
  for (const SplatMode mode : {SplatMode::kPlane, SplatMode::kDisc}) {
    for (const int upsample : {1, 2, 3, 0}) {
      const ReprojectOptions o = options(mode, upsample);
      const auto before = hc::pipeline::reproject(cloud, o);
      const hc::GridGeometry& g = before.value.depth.geometry();
      ASSERT_EQ(g.cols, 602);
      ASSERT_EQ(g.rows, 288);
      for (const std::size_t count : {std::size_t{1}, std::size_t{8}}) {
        const std::string what = std::string(mode == SplatMode::kPlane ? "plane" : "disc") + ", upsample " +
                                 std::to_string(upsample) + ", " + std::to_string(count) + " random points";
        RemovedPoints removed;
        const Cloud after = without(cloud, pick(cloud, count, 17 + static_cast<std::uint32_t>(count), before.value.depth.geometry()), removed);
        ASSERT_GT(removed.size(), count);  // the cluster and the border points too
        const auto got = hc::pipeline::reproject_after_removal(after, removed, before, o);
        expect_same(got, hc::pipeline::reproject(after, o), what);
        // The cluster's windows cover over a third of this small grid on the coarser scans.
        if (upsample == 1 || (count == 1 && upsample != 3)) {
          EXPECT_TRUE(made_locally(got.report)) << what;
          ++local_runs;
        }
      }
    }
  }
  EXPECT_EQ(local_runs, 8);
}

// The points are gathered into the windows on two threads, each a half of the remaining points
// with the removed points that stood among them: removed points just before, at and after the
// split (a run of 9 about the middle, which puts removed points on both sides of it and one
// exactly at it) and the cloud's last point (one past every remaining point).
TEST(ReprojectAfterRemoval, PointsRemovedAtTheThreadSplitAndAtTheEndMatch) {
  Cloud cloud = relief(400000, 5);
  const std::size_t c = cloud.size();
  ASSERT_GE(c, std::size_t{1} << 18);  // the two-thread gathering (2^18 points and more)
  std::vector<std::size_t> gone;
  for (std::size_t i = c / 2 - 8; i <= c / 2 + 8; i += 2) gone.push_back(i);
  gone.push_back(c - 1);
  for (const std::size_t i : gone) ASSERT_TRUE(cloud.xyz.col(static_cast<Eigen::Index>(i)).allFinite());
  // Every removed point a stray 30 mm in front (raised before the grid before the removal is
  // made, as a removal's caller must give them): their splats make events (cells they fill or
  // occlude) that the grid before counted, so a removed point left out of a window's scan before
  // the removal, or counted in two, changes the figures.
  for (const std::size_t i : gone) cloud.xyz(2, static_cast<Eigen::Index>(i)) += 0.03;
  const ReprojectOptions o = options(SplatMode::kPlane, 1);
  const auto before = hc::pipeline::reproject(cloud, o);
  RemovedPoints removed;
  const Cloud after = without(cloud, gone, removed);
  // The split is at half the remaining points; some removed points stood before it, one at it.
  const std::size_t mid = after.size() / 2;
  std::size_t below = 0, at = 0, above = 0;
  for (std::size_t r = 0; r < removed.size(); ++r) {
    const std::size_t stood_before = removed.at[r] - r;
    below += stood_before < mid ? 1U : 0U;
    at += stood_before == mid ? 1U : 0U;
    above += stood_before > mid ? 1U : 0U;
  }
  EXPECT_GT(below, 0U);
  EXPECT_EQ(at, 1U);
  EXPECT_GT(above, 1U);
  const auto got = hc::pipeline::reproject_after_removal(after, removed, before, o);
  EXPECT_TRUE(made_locally(got.report));
  expect_same(got, hc::pipeline::reproject(after, o), "removed about the split and at the end");
}

TEST(ReprojectAfterRemoval, RemovingStraysChangesTheGridAndStillMatches) {
  // Guards against a test that passes because nothing changed: the strays in front make cells
  // that their removal changes.
  const Cloud cloud = relief(500000, 5);
  const ReprojectOptions o = options(SplatMode::kPlane, 1);
  const auto before = hc::pipeline::reproject(cloud, o);
  std::vector<std::size_t> strays;
  for (Eigen::Index i = 0; i < cloud.xyz.cols() && strays.size() < 12; ++i) {
    if (cloud.xyz.col(i).allFinite() && cloud.xyz(2, i) > 0.019 && cloud.xyz(0, i) > 0.01 && cloud.xyz(0, i) < 0.99 &&
        cloud.xyz(1, i) > 0.01 && cloud.xyz(1, i) < 0.49) {
      strays.push_back(static_cast<std::size_t>(i));
    }
  }
  RemovedPoints removed;
  const Cloud after = without(cloud, strays, removed);
  const auto want = hc::pipeline::reproject(after, o);
  std::size_t changed = 0;
  for (std::size_t i = 0; i < want.value.flags.size(); ++i)
    changed += bits(want.value.depth.data()[i]) != bits(before.value.depth.data()[i]) ? 1U : 0U;
  EXPECT_GT(changed, 12U);
  const auto got = hc::pipeline::reproject_after_removal(after, removed, before, o);
  EXPECT_TRUE(made_locally(got.report));
  expect_same(got, want, "strays");
}

TEST(ReprojectAfterRemoval, EqualsTheWindowsOwnReprojectInATile) {
  const Cloud cloud = relief(500000, 9);
  for (const int k : {1, 2, 3}) {
    SCOPED_TRACE("upsample " + std::to_string(k));
    ReprojectOptions o = options(SplatMode::kPlane, k);
    const auto whole = hc::pipeline::reproject(cloud, o);
    GridWindow w;
    w.grid = whole.value.depth.geometry();
    // With k = 3, a "whole grid" 40 columns short of the points: points (and removed points)
    // beyond its last column, which a window skips but does not clamp.
    if (k == 3) w.grid.cols -= 40;
    w.row0 = k == 3 ? 0 : 20 * k;  // with k = 3 the whole (short) grid: a window of it would be
    w.col0 = k == 3 ? 0 : 30 * k;  // mostly halo at that reach, and fall back
    w.rows = std::min(200, w.grid.rows - w.row0);
    w.cols = w.grid.cols - w.col0;  // reaches the grid's last column
    o.window = w;
    const auto before = hc::pipeline::reproject(cloud, o);
    RemovedPoints removed;
    // Random points, and points near the window's edges (inside and outside).
    std::vector<std::size_t> gone = pick(cloud, k == 3 ? 1 : 3, 23, w.grid, false);
    for (std::size_t i = 0; i < cloud.size() && gone.size() < (k == 3 ? 2U : 6U); ++i) {
      const auto p = cloud.xyz.col(static_cast<Eigen::Index>(i));
      const double fr = (p[1] - w.grid.y0_m) / w.grid.cell_size_m - w.row0;
      if (p.allFinite() && std::abs(fr) < 2.0 && p[0] > w.grid.x_of_col(w.col0 + 10) && p[0] < 0.99) gone.push_back(i);
    }
    if (k == 3) {  // two points beyond the whole grid's last column
      int beyond = 0;
      for (std::size_t i = 0; i < cloud.size() && beyond < 2; ++i) {
        const auto p = cloud.xyz.col(static_cast<Eigen::Index>(i));
        if (p.allFinite() && p[0] > w.grid.x_of_col(w.grid.cols + 5) && p[0] < 0.99 && p[1] > 0.01 && p[1] < 0.46) {
          gone.push_back(i);
          ++beyond;
        }
      }
      ASSERT_EQ(beyond, 2);
    }
    std::sort(gone.begin(), gone.end());
    gone.erase(std::unique(gone.begin(), gone.end()), gone.end());
    const Cloud after = without(cloud, gone, removed);
    const auto got = hc::pipeline::reproject_after_removal(after, removed, before, o);
    EXPECT_TRUE(made_locally(got.report));
    expect_same(got, hc::pipeline::reproject(after, o), "window, upsample " + std::to_string(k));
  }
}

TEST(ReprojectAfterRemoval, FallsBackToTheWholeGridWhenTheBoxChangesOrSplatsInterpolate) {
  const Cloud cloud = relief(200000, 11);
  {
    const ReprojectOptions o = options(SplatMode::kPlane, 1);
    const auto before = hc::pipeline::reproject(cloud, o);
    std::size_t lowest = 0;
    for (Eigen::Index i = 0; i < cloud.xyz.cols(); ++i) {
      if (cloud.xyz.col(i).allFinite() && (!cloud.xyz.col(static_cast<Eigen::Index>(lowest)).allFinite() ||
                                           cloud.xyz(0, i) < cloud.xyz(0, static_cast<Eigen::Index>(lowest)))) {
        lowest = static_cast<std::size_t>(i);
      }
    }
    RemovedPoints removed;
    const Cloud after = without(cloud, {lowest}, removed);
    const auto got = hc::pipeline::reproject_after_removal(after, removed, before, o);
    EXPECT_FALSE(made_locally(got.report));
    expect_same(got, hc::pipeline::reproject(after, o), "box changed");
  }
  {
    const ReprojectOptions o = options(SplatMode::kInterpolate, 1);
    const auto before = hc::pipeline::reproject(cloud, o);
    RemovedPoints removed;
    const Cloud after = without(cloud, pick(cloud, 5, 29, before.value.depth.geometry()), removed);
    const auto got = hc::pipeline::reproject_after_removal(after, removed, before, o);
    EXPECT_FALSE(made_locally(got.report));
    expect_same(got, hc::pipeline::reproject(after, o), "interpolating splats");
  }
}

TEST(ReprojectAfterRemoval, RejectsMalformedRemovedPoints) {
  const Cloud cloud = relief(20000, 13);
  const ReprojectOptions o = options(SplatMode::kPlane, 1);
  const auto before = hc::pipeline::reproject(cloud, o);
  RemovedPoints removed;
  const Cloud after = without(cloud, {100, 200}, removed);
  RemovedPoints unordered = removed;
  std::swap(unordered.at[0], unordered.at[1]);
  EXPECT_THROW(hc::pipeline::reproject_after_removal(after, unordered, before, o), std::invalid_argument);
  RemovedPoints short_xyz = removed;
  short_xyz.xyz.pop_back();
  EXPECT_THROW(hc::pipeline::reproject_after_removal(after, short_xyz, before, o), std::invalid_argument);
  RemovedPoints beyond = removed;
  beyond.at[1] = cloud.size();
  EXPECT_THROW(hc::pipeline::reproject_after_removal(after, beyond, before, o), std::invalid_argument);
}

TEST(ReprojectAfterRemoval, RemoveSpikePointsListsExactlyThePointsItRemoved) {
  const Cloud cloud = relief(500000, 17);
  const ReprojectOptions o = options(SplatMode::kPlane, 1);
  const auto grid = hc::pipeline::reproject(cloud, o);
  hc::pipeline::HonestCheckOptions h;
  RemovedPoints removed;
  const auto ds = hc::pipeline::remove_spike_points(cloud, grid.value.depth, h, 1.5, 0.0, 1.0, &removed);
  ASSERT_GT(removed.size(), 0U);
  ASSERT_EQ(removed.size() + ds.value.size(), cloud.size());
  // Walking the cloud: each column is either the next kept point or the next removed one.
  std::size_t kept = 0;
  for (std::size_t i = 0, r = 0; i < cloud.size(); ++i) {
    const auto p = cloud.xyz.col(static_cast<Eigen::Index>(i));
    if (r < removed.size() && removed.at[r] == i) {
      for (int a = 0; a < 3; ++a) EXPECT_EQ(removed.xyz[3 * r + static_cast<std::size_t>(a)], p[a]);
      ++r;
      continue;
    }
    const auto q = ds.value.xyz.col(static_cast<Eigen::Index>(kept++));
    ASSERT_TRUE(p.cwiseEqual(q).all() || !p.allFinite()) << "column " << i;
  }
  EXPECT_EQ(kept, ds.value.size());
  // And the grid made again from them equals a whole reproject.
  expect_same(hc::pipeline::reproject_after_removal(ds.value, removed, grid, o), hc::pipeline::reproject(ds.value, o), "despike");
}

}  // namespace reproject_after_removal_test
