// Robust outlier removal (filters.outliers.method = robust) and far-cluster removal, on variants
// of the raw bunny scan (data/scans/bunny/bun000.ply, as configs/bunny.yaml) that the tests make
// themselves: a far point, a far cluster, uniform clutter, a density step and a gradient. The
// oracle is the set of injected points (tagged through the intensity attribute) and the clean
// run's grid. Some tests also run the exact statistical filter (PCL's SOR) to show that the case
// defeats it (the issue "A surface you can trust"); they fail if that ever stops being true, so
// the case keeps testing something.

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/filters.hpp"
#include "hc/pipeline/honest_check.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/robust_outliers.hpp"
#include "hc/pipeline/run.hpp"

#include <Eigen/Eigenvalues>
#include <gtest/gtest.h>

#include "kd_oracle.hpp"
#include "test_paths.hpp"
#include "stage_figure.hpp"

#include <array>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <sstream>
#include <functional>
#include <limits>
#include <map>
#include <numeric>
#include <tuple>
#include <algorithm>
#include <optional>
#include <random>
#include <set>
#include <iostream>
#include <string>
#include <vector>

namespace {

using hc::test::figure;

namespace fs = std::filesystem;
using namespace hc::pipeline;

const Cloud& bunny() {
  static const Cloud c = [] {
    Cloud b = load_cloud(hc::test::scan_path("bunny/bun000.ply")).value;
    b.intensity.assign(b.size(), 0.0f);  // 0 = a true point of the scan
    return b;
  }();
  return c;
}

// The bunny with `extra` appended, tagged intensity 1 (injected).
Cloud with_extra(const Cloud& base, const std::vector<Eigen::Vector3d>& extra) {
  Cloud c;
  c.xyz.resize(3, base.xyz.cols() + static_cast<Eigen::Index>(extra.size()));
  c.xyz.leftCols(base.xyz.cols()) = base.xyz;
  for (std::size_t i = 0; i < extra.size(); ++i) c.xyz.col(base.xyz.cols() + static_cast<Eigen::Index>(i)) = extra[i];
  c.intensity = base.intensity;
  c.intensity.resize(c.size(), 1.0f);
  return c;
}

// Binary little-endian PLY with double coordinates (exact round trip).
void write_ply(const Cloud& c, const fs::path& file) {
  std::ofstream out(file, std::ios::binary);
  // The tags travel as colour, red 255 = injected (the reader reads no intensity from PLY; the
  // filtered cloud keeps colour), so a run's kept points say which were injected.
  const bool tags = c.has_intensity();
  out << "ply\nformat binary_little_endian 1.0\nelement vertex " << c.size()
      << "\nproperty double x\nproperty double y\nproperty double z\n"
      << (tags ? "property uchar red\nproperty uchar green\nproperty uchar blue\n" : "") << "end_header\n";
  for (Eigen::Index i = 0; i < c.xyz.cols(); ++i) {
    const Eigen::Vector3d p = c.xyz.col(i);
    out.write(reinterpret_cast<const char*>(p.data()), 3 * sizeof(double));
    if (tags) {
      const unsigned char rgb[3] = {c.intensity[static_cast<std::size_t>(i)] > 0.5f ? std::uint8_t{255} : std::uint8_t{0}, 0, 0};
      out.write(reinterpret_cast<const char*>(rgb), 3);
    }
  }
  ASSERT_TRUE(out.good()) << file;
}

// configs/bunny.yaml's grid, without the layers and the cross-check (not under test here).
RunConfig bunny_config(const fs::path& ply, const std::string& outliers = "{enabled: true}") {
  return parse_run_config("input: {files: [" + ply.filename().string() + "]}\n"
                          "filters:\n  outliers: " + outliers + "\n"
                          "grid: {n: 300, splat_radius_cells: 1, see_through_depth_m: 0.003, hole_fill_max_cells: 32,\n"
                          "       hole_fill_max_step_m: 0.003}\n"
                          "cross_check: {enabled: false}\nlayers: {enabled: false}\n",
                          ply.parent_path() / "run.yaml");
}

BuiltScene run_on(const Cloud& c, const std::string& name, const std::string& outliers = "{enabled: true}") {
  const fs::path dir = hc::test::temp_dir(name);
  write_ply(c, dir / (name + ".ply"));
  return build_scene(bunny_config(dir / (name + ".ply"), outliers), true);
}

const StageReport& outlier_stage(const BuiltScene& b) {
  for (const auto& s : b.summary.stages) {
    if (s.stage == "outliers") return s;
  }
  static const StageReport none;
  ADD_FAILURE() << "no outliers stage";
  return none;
}

// Cells equal (NaN = NaN), same flags, same rows, cols and cell size; origin in the file frame
// (the recentring offset differs when a far point widens the box).
std::size_t cells_differing(const BuiltScene& a, const BuiltScene& b) {
  const auto& ga = a.scene.geometry;
  const auto& gb = b.scene.geometry;
  EXPECT_EQ(ga.rows, gb.rows);
  EXPECT_EQ(ga.cols, gb.cols);
  EXPECT_EQ(ga.cell_size_m, gb.cell_size_m);
  const Eigen::Vector3d oa = a.scene.provenance.recentre_offset_m, ob = b.scene.provenance.recentre_offset_m;
  EXPECT_NEAR(ga.x0_m + oa.x(), gb.x0_m + ob.x(), 1e-9);
  EXPECT_NEAR(ga.y0_m + oa.y(), gb.y0_m + ob.y(), 1e-9);
  if (ga.rows != gb.rows || ga.cols != gb.cols) return std::numeric_limits<std::size_t>::max();
  std::size_t differ = 0;
  const auto& va = a.scene.layers.depth.values();
  const auto& vb = b.scene.layers.depth.values();
  for (std::size_t i = 0; i < va.size(); ++i) {
    const double za = double(va[i]) + oa.z(), zb = double(vb[i]) + ob.z();
    const bool same = (std::isnan(va[i]) && std::isnan(vb[i])) || std::abs(za - zb) <= 1e-6;
    if (!same || a.scene.layers.flags[i] != b.scene.layers.flags[i]) ++differ;
  }
  return differ;
}

const BuiltScene& clean_run() {
  static const BuiltScene b = run_on(bunny(), "clean");
  return b;
}

// Counts of injected points and true points kept by a filtered cloud (intensity tags).
struct Kept {
  std::size_t injected = 0, truth = 0;
};
Kept kept_of(const Cloud& c) {
  Kept k;
  for (const float t : c.intensity) (t > 0.5f ? k.injected : k.truth) += 1;
  return k;
}

std::vector<Eigen::Vector3d> uniform_in_box(std::size_t count, std::uint32_t seed) {
  const Eigen::Vector3d lo = bunny().xyz.rowwise().minCoeff(), hi = bunny().xyz.rowwise().maxCoeff();
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Eigen::Vector3d> pts(count);
  for (auto& p : pts) p = lo + (hi - lo).cwiseProduct(Eigen::Vector3d(u(rng), u(rng), u(rng)));
  return pts;
}

TEST(RobustOutliers, CleanBunnyLosesAtMostHalfAPercent) {
  const auto r = remove_outliers_robust(bunny(), RobustOutlierOptions{}, FarClusterOptions{});
  const double lost = static_cast<double>(bunny().size() - r.value.size());
  EXPECT_LE(lost, 0.005 * static_cast<double>(bunny().size())) << "removed " << lost << " of " << bunny().size();
  // Every step's figure is there.
  for (const char* f : {"median_knn_distance_mm", "sigma_log_knn_distance", "global_threshold_mm", "removed_robust",
                        "removed_far_clusters", "far_clusters", "certified", "exact_queries"}) {
    EXPECT_FALSE(std::isnan(figure(r.report, f))) << f;
  }
}

TEST(RobustOutliers, CountingPassDecidesLikeTestingEveryPoint) {
  // Property: the removed set does not depend on how many points the counting pass settles. With
  // a huge sample every point gets an exact distance in step 1, so nothing is left to counting.
  // Both runs judge by the same scale: `all` draws it from every point, `fast` is given it (its
  // own sample, smaller than the cloud, could round to another). Clouds: the bunny with 800
  // points of clutter; and a plane with a sparse layer 1 cm in front of it (a quarter of the
  // points at a tenth of the density), whose points the counting pass leaves by the thousand.
  Cloud layered;
  {
    std::mt19937 rng(13);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::vector<Eigen::Vector3d> pts;
    for (int i = 0; i < 20000; ++i) pts.emplace_back(0.2 * u(rng), 0.2 * u(rng), 0.0002 * u(rng));
    for (int i = 0; i < 8000; ++i) pts.emplace_back(0.2 * u(rng), 0.2 * u(rng), 0.01 + 0.004 * u(rng));
    layered.xyz.resize(3, static_cast<Eigen::Index>(pts.size()));
    for (std::size_t i = 0; i < pts.size(); ++i) layered.xyz.col(static_cast<Eigen::Index>(i)) = pts[i];
  }
  for (const Cloud& c : {with_extra(bunny(), uniform_in_box(800, 3)), layered}) {
  RobustOutlierOptions fast, all;
  all.sample = c.size();
  std::vector<std::uint32_t> every(c.size());
  for (std::size_t i = 0; i < every.size(); ++i) every[i] = static_cast<std::uint32_t>(i);
  std::vector<double> logs;
  for (const double d : mean_knn_distances(c, every, fast.k)) {
    if (d > 0.0) logs.push_back(std::log(d));
  }
  fast.scale = robust_scale_of(std::move(logs), c.size());
  ASSERT_TRUE(fast.scale.has_value());
  const auto a = remove_robust_outliers(c, fast);
  const auto b = remove_robust_outliers(c, all);
  ASSERT_EQ(a.value.size(), b.value.size());
  EXPECT_EQ(a.value.xyz, b.value.xyz);
  EXPECT_GT(figure(a.report, "certified"), 0.7 * static_cast<double>(c.size()));
  EXPECT_EQ(figure(a.report, "median_knn_distance_mm"), figure(b.report, "median_knn_distance_mm"));
  EXPECT_EQ(figure(a.report, "mad_log_knn_distance"), figure(b.report, "mad_log_knn_distance"));
  }
}

Cloud cloud_of(const std::vector<Eigen::Vector3d>& pts);  // below

// The scan's spacing (RobustScale::spacing_m), which the isolated-point filter takes in both
// runs: the sampled points' nearest-point distances from the k-NN searches against brute force
// in double (float coordinates: 1e-5 relative); a point with one exact copy, and one with k + 2
// (left out of the search grid), at 0; a point listed twice gets its distance twice. Their
// median, rounded to a step of 1/128 in ln, against robust_scale_of; with every point sampled,
// the in-core test's figure is that number.
TEST(RobustOutliers, TheSamplesNearestDistancesGiveTheScansSpacing) {
  const int k = 16;
  std::vector<Eigen::Vector3d> pts;  // the bunny's positions (no attributes), then the copies
  for (Eigen::Index i = 0; i < bunny().xyz.cols(); ++i) pts.emplace_back(bunny().xyz.col(i));
  const std::size_t n0 = pts.size();
  pts.push_back(pts[7]);                                   // an exact copy of point 7
  for (int q = 0; q < k + 2; ++q) pts.push_back(pts[11]);  // k + 2 copies of point 11
  const Cloud c = cloud_of(pts);
  const auto has_copy = [&](std::uint32_t i) { return i == 7 || i == 11 || i >= n0; };
  std::vector<std::uint32_t> list;
  for (std::uint32_t i = 0; i < n0; i += 37) list.push_back(i);
  list.push_back(11);
  list.push_back(static_cast<std::uint32_t>(n0));
  list.push_back(static_cast<std::uint32_t>(n0) + 3);
  list.push_back(list[1]);  // listed twice
  std::vector<double> nearest;
  (void)mean_knn_distances(c, list, k, &nearest);
  ASSERT_EQ(nearest.size(), list.size());
  std::vector<double> logs;
  for (std::size_t q = 0; q < list.size(); ++q) {
    const Eigen::Vector3d p = c.xyz.col(list[q]);
    double best = std::numeric_limits<double>::infinity();
    for (Eigen::Index j = 0; j < c.xyz.cols(); ++j) {
      if (j != static_cast<Eigen::Index>(list[q])) best = std::min(best, (c.xyz.col(j) - p).norm());
    }
    if (has_copy(list[q])) {
      EXPECT_EQ(best, 0.0);
      EXPECT_EQ(nearest[q], 0.0) << "a point with a copy: " << list[q];
    } else {
      EXPECT_NEAR(nearest[q], best, 1e-5 * best + 1e-9) << list[q];
    }
    if (nearest[q] > 0.0) logs.push_back(std::log(nearest[q]));
  }
  std::vector<double> sorted = logs;
  std::sort(sorted.begin(), sorted.end());
  ASSERT_GT(sorted.size(), 2U);
  const std::size_t h = sorted.size() / 2;
  const double median = sorted.size() % 2 == 1 ? sorted[h] : 0.5 * (sorted[h - 1] + sorted[h]);
  const double want = std::exp(std::round(median * 128.0) / 128.0);
  const auto scale = robust_scale_of({std::log(0.001)}, list.size(), logs);
  ASSERT_TRUE(scale.has_value());
  EXPECT_EQ(scale->spacing_m, want);
  EXPECT_EQ(robust_scale_of({std::log(0.001)}, 1)->spacing_m, 0.0) << "no nearest distances: unknown";
  // The in-core test with every point sampled: its figure is the spacing of all points.
  RobustOutlierOptions all;
  all.sample = c.size();
  std::vector<std::uint32_t> every(c.size());
  for (std::size_t i = 0; i < every.size(); ++i) every[i] = static_cast<std::uint32_t>(i);
  std::vector<double> near_all, d_logs, near_logs;
  for (const double d : mean_knn_distances(c, every, all.k, &near_all)) {
    if (d > 0.0) d_logs.push_back(std::log(d));
  }
  for (const double d : near_all) {
    if (d > 0.0) near_logs.push_back(std::log(d));
  }
  const auto whole = robust_scale_of(std::move(d_logs), c.size(), std::move(near_logs));
  RobustScale used;
  EXPECT_EQ(figure(remove_robust_outliers(c, all, nullptr, &used).report, "sample_spacing_mm"), whole->spacing_m * 1e3);
  EXPECT_EQ(used.spacing_m, whole->spacing_m) << "the scale used, handed out";
  // A scale given is the one handed out; every sampled point with k copies: none, left as it was.
  RobustOutlierOptions given = all;
  given.scale = RobustScale{std::log(0.002), 0.25, 7, 0.0015};
  RobustScale out;
  (void)remove_robust_outliers(c, given, nullptr, &out);
  EXPECT_EQ(out.spacing_m, 0.0015);
  EXPECT_EQ(out.sample, 7U);
  std::vector<Eigen::Vector3d> copies(40, Eigen::Vector3d(0.1, 0.2, 0.3));
  RobustScale untouched{1.0, 2.0, 3, 4.0};
  (void)remove_robust_outliers(cloud_of(copies), RobustOutlierOptions{}, nullptr, &untouched);
  EXPECT_EQ(untouched.spacing_m, 4.0);
  EXPECT_EQ(untouched.sample, 3U);
}

// robust_scale_fixed (the tiled run's tile_scale: a window's k-NN searches bound d where they
// reach past it) against its definition: when it says the scale is fixed, robust_scale_of gives
// the same median, MAD and spacing for every concrete choice of values within the bounds. The
// oracle is robust_scale_of itself on 300 draws per case: every value at its lower end, at its
// upper end, at the end farthest from and at the point nearest to the case's median (the MAD's
// extremes), then at random (an unknown value absent, or anywhere). The cases put the values
// close to a rounding step and widen a random share of them downwards, as a window's truncated
// searches do; the test also requires both answers to occur, so it keeps testing something.
TEST(RobustScaleFixed, EveryDrawWithinTheBoundsGivesTheSameScaleWhenItSaysFixed) {
  using hc::pipeline::robust_scale_fixed;
  using hc::pipeline::robust_scale_of;
  using Bounds = std::vector<std::array<double, 2>>;
  std::mt19937_64 rng(20261125);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double inf = std::numeric_limits<double>::infinity();
  int fixed_cases = 0, open_cases = 0;
  for (int c = 0; c < 400; ++c) {
    const auto n = static_cast<std::size_t>(5 + rng() % 300);
    // Values about a step boundary (ln d = -7 + 0.5/128), spread by 0..3 steps.
    const double centre = -7.0 + 0.5 / 128.0 + (u(rng) - 0.5) * 0.02, spread = u(rng) * 3.0 / 128.0;
    const double widened = u(rng) * 0.3, unknown = u(rng) < 0.3 ? u(rng) * 0.05 : 0.0, depth = u(rng) * 4.0 / 128.0;
    const auto make = [&](double offset) {
      Bounds b(n);
      for (auto& x : b) {
        const double v = centre + offset + (u(rng) - 0.5) * spread + (u(rng) < 0.05 ? u(rng) * 2.0 : 0.0);  // a few strays
        if (u(rng) < unknown) {
          x = {-inf, inf};
        } else if (u(rng) < widened) {
          x = {v - u(rng) * depth, v};
        } else {
          x = {v, v};
        }
      }
      return b;
    };
    const Bounds d = make(0.0), near = make(-0.7);
    const bool fixed = robust_scale_fixed(d, near);
    (fixed ? fixed_cases : open_cases)++;
    if (!fixed) continue;
    // The median the scale takes when fixed (the upper ends' median, rounded as robust_scale_of
    // rounds it), for the MAD's extreme draws.
    std::vector<double> ends;
    for (const auto& x : d) ends.push_back(x[1]);
    std::nth_element(ends.begin(), ends.begin() + static_cast<std::ptrdiff_t>(ends.size() / 2), ends.end());
    const double m = robust_scale_of(ends, n)->median_log;
    // A draw: mode 0, each value at its lower end; 1, its upper end; 2, the end farther from m;
    // 3, the point nearest m; else at random between. An unknown value is left out or lies
    // anywhere in ±3 about the centre (modes 0-3: at ∓ or ±3, or left out).
    const auto draw = [&](const Bounds& b, int mode) {
      std::vector<double> v;
      for (const auto& x : b) {
        if (std::isinf(x[0])) {
          if (mode == 0 || mode == 2) v.push_back(centre - 3.0);
          if (mode == 1) v.push_back(centre + 3.0);
          if (mode >= 4 && u(rng) < 0.5) v.push_back(centre + (u(rng) - 0.5) * 6.0);
          continue;
        }
        if (mode == 2) {
          v.push_back(std::abs(x[0] - m) > std::abs(x[1] - m) ? x[0] : x[1]);
        } else if (mode == 3) {
          v.push_back(std::clamp(m, x[0], x[1]));
        } else {
          const double t = mode == 0 ? 0.0 : mode == 1 ? 1.0 : u(rng);
          v.push_back(x[0] + t * (x[1] - x[0]));
        }
      }
      return v;
    };
    std::optional<hc::pipeline::RobustScale> first;
    for (int k = 0; k < 300; ++k) {
      const int mode = std::min(k, 4);
      const auto s = robust_scale_of(draw(d, mode), n, draw(near, mode));
      ASSERT_TRUE(s.has_value());
      if (!first) {
        first = s;
        continue;
      }
      ASSERT_EQ(s->median_log, first->median_log) << "case " << c << ", draw " << k;
      ASSERT_EQ(s->mad_log, first->mad_log) << "case " << c << ", draw " << k;
      ASSERT_EQ(s->spacing_m, first->spacing_m) << "case " << c << ", draw " << k;
    }
  }
  EXPECT_GT(fixed_cases, 40);
  EXPECT_GT(open_cases, 40);
  // Bounds that are all points fix the scale; one NaN bound does not.
  EXPECT_TRUE(robust_scale_fixed({{-7.0, -7.0}, {-6.0, -6.0}, {-5.0, -5.0}}, {}));
  EXPECT_FALSE(robust_scale_fixed({{std::nan(""), -7.0}}, {}));
  EXPECT_FALSE(robust_scale_fixed({{-7.0, -7.0}, {-7.0, std::nan("")}, {-6.0, -6.0}}, {})) << "a NaN among others";
  // Half the values unknown: nothing is fixed.
  EXPECT_FALSE(robust_scale_fixed({{-7.0, -7.0}, {-inf, inf}}, {}));
}

// remove_isolated_points at a given spacing: a plane of 2 mm spacing and one point 5 cm above
// its middle. The radius is 0.9 × 10 × the spacing: at 1 mm (9 mm) the plane's points have
// dozens of neighbours and the point none, so it alone goes; at 1 cm (9 cm) it has the plane's
// points and stays; the figure is the spacing given (HonestCheckOptions::spacing_m). A spacing
// that is not finite, or negative, is refused.
TEST(RobustOutliers, TheIsolatedFilterTakesTheSpacingItIsGiven) {
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 30; ++i)
    for (int j = 0; j < 30; ++j) pts.emplace_back(0.002 * i, 0.002 * j, 0.0);
  pts.emplace_back(0.03, 0.03, 0.05);
  const Cloud c = cloud_of(pts);
  hc::pipeline::HonestCheckOptions o;
  ASSERT_EQ(o.isolation_radius_spacings, 10.0);
  o.spacing_m = 0.001;
  const auto fine = remove_isolated_points(c, o);
  EXPECT_EQ(figure(fine.report, "spacing_mm"), 1.0);
  EXPECT_EQ(fine.value.size(), 900U);
  for (Eigen::Index i = 0; i < fine.value.xyz.cols(); ++i) EXPECT_EQ(fine.value.xyz(2, i), 0.0);
  o.spacing_m = 0.01;
  const auto coarse = remove_isolated_points(c, o);
  EXPECT_EQ(figure(coarse.report, "spacing_mm"), 10.0);
  EXPECT_EQ(coarse.value.size(), 901U);
  o.spacing_m = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(remove_isolated_points(c, o), hc::ConfigError);
  o.spacing_m = -0.001;
  EXPECT_THROW(remove_isolated_points(c, o), hc::ConfigError);
}

// remove_isolated_points' float frame (HonestCheckOptions::frame_centre_m): a tiled run's window
// given the run's frame rounds its searches as the whole cloud does. 1 800 pairs of points,
// each pair's two points a radius apart to within ±4e-5 of it (the rounding of float32
// coordinates about a metre out is about 1e-5 of the 9 mm radius), the pairs 5 cm apart over
// 3 m × 1.5 m; one neighbour wanted, so a point goes exactly when its partner rounds to farther
// than the radius. Oracle: the whole cloud's verdicts in its frame (centre given: the middle of
// the box) against those of the window x > 2 m (its own median 2.5 m out), with the frame given
// (every verdict equal) and without it (the window's median: some pairs round the other way,
// so the test sees the frame).
TEST(RobustOutliers, TheIsolatedFilterRoundsInTheFrameItIsGiven) {
  hc::pipeline::HonestCheckOptions o;
  o.spacing_m = 0.001;
  o.isolation_min_neighbours = 1;
  const double radius = 0.9 * o.isolation_radius_spacings * o.spacing_m;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> tweak(-4e-5, 4e-5), angle(0.0, 6.283185307179586);
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 60; ++i)
    for (int j = 0; j < 30; ++j) {
      const Eigen::Vector3d a(0.05 * i + 0.01, 0.05 * j + 0.01, 0.001 * (j % 7));
      const double d = radius * (1.0 + tweak(rng)), t = angle(rng);
      pts.push_back(a);
      pts.push_back(a + d * Eigen::Vector3d(std::cos(t), std::sin(t), 0.0));
    }
  ASSERT_EQ(pts.size(), 3600U);
  const Cloud whole = cloud_of(pts);
  o.frame_centre_m = std::array<double, 3>{1.5, 0.75, 0.0};
  hc::pipeline::RemovedPoints gone;
  (void)remove_isolated_points(whole, o, &gone);
  std::vector<std::uint8_t> whole_gone(pts.size(), 0);
  for (const std::size_t c : gone.at) whole_gone[c] = 1;
  const std::size_t n_gone = gone.at.size();
  ASSERT_GT(n_gone, 100U) << "about half the pairs round apart";
  ASSERT_LT(n_gone, pts.size() - 100U);
  // The window: the pairs whose first point lies at x > 2 m (both points inside it).
  std::vector<Eigen::Vector3d> win;
  std::vector<std::size_t> of;
  for (std::size_t p = 0; p < pts.size(); p += 2) {
    if (pts[p].x() <= 2.0) continue;
    for (std::size_t q = p; q < p + 2; ++q) {
      win.push_back(pts[q]);
      of.push_back(q);
    }
  }
  ASSERT_GT(win.size(), 600U);
  const auto differ = [&](const hc::pipeline::HonestCheckOptions& opt) {
    hc::pipeline::RemovedPoints w;
    (void)remove_isolated_points(cloud_of(win), opt, &w);
    std::vector<std::uint8_t> wg(win.size(), 0);
    for (const std::size_t c : w.at) wg[c] = 1;
    std::size_t n = 0;
    for (std::size_t i = 0; i < win.size(); ++i) n += wg[i] != whole_gone[of[i]] ? 1U : 0U;
    return n;
  };
  EXPECT_EQ(differ(o), 0U) << "the run's frame given: the window's verdicts are the whole cloud's";
  hc::pipeline::HonestCheckOptions own = o;
  own.frame_centre_m.reset();
  EXPECT_GT(differ(own), 0U) << "about its own median the window rounds some pairs the other way";
}

// The mean-distance bound of RobustVerdicts::near where it is tight: a point with k − 1 copies
// and one more point D away has d = D / k, so its (k − 1)-th nearest lies within k·d / 2 = D/2
// by the bound, and indeed at 0; at a radius of 0.9 D exactly its k − 1 copies count, and the
// bound gives k − 1 (one more would claim the point D away).
TEST(RobustOutliers, NearCountsFromTheMeanDistanceAreTightForCopiesAndOneFarNeighbour) {
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 100; ++i)
    for (int j = 0; j < 100; ++j) pts.emplace_back(0.001 * i, 0.001 * j, 0.0);
  const Eigen::Vector3d c(0.050, 0.050, 0.050);
  for (int i = 0; i < 16; ++i) pts.push_back(c);  // k = 16 points at one place
  pts.push_back(c + Eigen::Vector3d(0.005, 0.0, 0.0));  // D = 5 mm away
  RobustOutlierOptions o;
  ASSERT_EQ(o.k, 16);
  o.near_radius_m = 0.0045;
  hc::pipeline::RobustVerdicts v;
  const auto r = remove_robust_outliers(cloud_of(pts), o, &v);
  ASSERT_LT(figure(r.report, "certify_distance_mm"), 5.0) << "the copies are not settled by counting";
  for (std::size_t i = 10000; i < 10016; ++i) {
    EXPECT_EQ(v.verdict[i], 0) << "a copy is kept";
    EXPECT_EQ(int(v.near[i]), 15) << "copy " << i - 10000 << ": its 15 copies within 0.9 D, shown by d = D / 16";
  }
  EXPECT_EQ(int(v.near[10016]), 0) << "the point D away: its k nearest all lie D away";
}

// remove_isolated_points with known_near (the tiled run passes the robust test's near flags):
// the points flagged are kept without a search, the rest searched in a hash of only the voxels
// about them. Oracles: the same filter without the flags (a hash of every point), and every
// removed point's neighbours counted by brute force.
TEST(RobustOutliers, TheIsolatedFilterWithKnownNeighboursRemovesWhatTheFullFilterRemoves) {
  const Cloud c = with_extra(bunny(), uniform_in_box(800, 3));
  hc::pipeline::HonestCheckOptions io;
  io.spacing_m = 0.0004;
  const double radius = hc::pipeline::isolated_filter_radius_m(io, io.spacing_m);
  RobustOutlierOptions ro;
  ro.near_radius_m = 0.99 * radius;
  hc::pipeline::RobustVerdicts v;
  (void)remove_robust_outliers(c, ro, &v);
  ASSERT_EQ(v.near.size(), c.size());
  for (auto& m : v.near) m = m >= io.isolation_min_neighbours ? 1 : 0;  // the counts as flags
  const auto flagged = static_cast<std::size_t>(std::count(v.near.begin(), v.near.end(), std::uint8_t{1}));
  ASSERT_GT(flagged, c.size() / 2) << "the bunny's points settled by counting";
  hc::pipeline::RemovedPoints full_removed, near_removed;
  const auto full = remove_isolated_points(c, io, &full_removed);
  const auto spared = remove_isolated_points(c, io, &near_removed, &v.near);
  EXPECT_TRUE(spared.value.xyz == full.value.xyz);
  EXPECT_EQ(near_removed.at, full_removed.at);
  EXPECT_GT(full_removed.at.size(), 300U) << "most of the clutter is isolated";
  EXPECT_EQ(figure(full.report, "points_tested"), static_cast<double>(c.size()));
  EXPECT_EQ(figure(spared.report, "points_tested"), static_cast<double>(c.size() - flagged));
  for (const std::size_t i : full_removed.at) {
    int within = 0;
    for (Eigen::Index j = 0; j < c.xyz.cols(); ++j) {
      if (static_cast<std::size_t>(j) != i && (c.xyz.col(j) - c.xyz.col(static_cast<Eigen::Index>(i))).norm() <= radius) ++within;
    }
    EXPECT_LT(within, io.isolation_min_neighbours) << "column " << i;
  }
  // A flag on a point 1 km from the rest: the filter's own coordinates then reach past 10^3
  // radii, the flags are not used, and the far point is searched and removed.
  Cloud far = with_extra(c, {Eigen::Vector3d(1000.0, 0.0, 0.0)});
  std::vector<std::uint8_t> near_far = v.near;
  near_far.push_back(1);
  const auto far_run = remove_isolated_points(far, io, nullptr, &near_far);
  EXPECT_EQ(figure(far_run.report, "points_tested"), static_cast<double>(far.size()));
  EXPECT_EQ(far_run.value.size(), full.value.size());
  near_far.pop_back();
  EXPECT_THROW(remove_isolated_points(far, io, nullptr, &near_far), std::invalid_argument) << "a flag per point";
}

// The cluttered bunny (800 uniform points in its box), the options with the scale of its whole
// test given, and that test's verdict for every point (the oracle of the tile tests below).
struct JudgedBunny {
  Cloud c;
  RobustOutlierOptions o;
  hc::pipeline::RobustVerdicts whole;
};
JudgedBunny judged_cluttered_bunny() {
  JudgedBunny b{with_extra(bunny(), uniform_in_box(800, 3)), {}, {}};
  const auto first = remove_robust_outliers(b.c, b.o);
  b.o.scale = hc::pipeline::RobustScale{std::log(figure(first.report, "median_knn_distance_mm") * 1e-3),
                                        figure(first.report, "mad_log_knn_distance"), b.o.sample};
  // The scale as the report rounds it can differ from the one used in its last digits: the
  // oracle is the whole test with the very scale given.
  (void)remove_robust_outliers(b.c, b.o, &b.whole);
  return b;
}

// judge_only (the tiled run's second look): each listed point gets the verdict the whole test
// gives it; the oracle is the whole test's verdict vector on the same cloud and scale, over a
// list of removed and kept points, certified ones among them.
TEST(RobustOutliers, JudgingListedPointsGivesTheWholeTestsVerdicts) {
  auto [c, o, whole] = judged_cluttered_bunny();
  std::vector<std::uint32_t> removed, kept;
  for (std::uint32_t i = 0; i < whole.verdict.size(); ++i) (whole.verdict[i] != 0 ? removed : kept).push_back(i);
  ASSERT_GT(removed.size(), 100U);
  for (std::size_t i = 0; i < removed.size(); i += 3) o.judge_only.push_back(removed[i]);
  for (std::size_t i = 0; i < kept.size(); i += 97) o.judge_only.push_back(kept[i]);
  std::sort(o.judge_only.begin(), o.judge_only.end());
  hc::pipeline::RobustVerdicts part;
  const auto judged = remove_robust_outliers(c, o, &part);
  EXPECT_EQ(judged.value.size(), c.size()) << "judging leaves the cloud as it was";
  std::size_t listed_removed = 0;
  std::vector<bool> listed(c.size(), false);
  for (const std::uint32_t j : o.judge_only) {
    listed[j] = true;
    EXPECT_EQ(part.verdict[j], whole.verdict[j]) << "column " << j;
    listed_removed += whole.verdict[j] != 0 ? 1U : 0U;
  }
  EXPECT_GT(listed_removed, 30U);
  for (std::size_t j = 0; j < c.size(); ++j) {
    if (!listed[j]) {
      ASSERT_EQ(part.verdict[j], 0) << "an unlisted point is not judged";
    }
  }
  o.judge_only = {static_cast<std::uint32_t>(c.size())};
  EXPECT_THROW(remove_robust_outliers(c, o), hc::InputError);
  o.judge_only = {0};
  o.scale.reset();
  EXPECT_THROW(remove_robust_outliers(c, o), hc::ConfigError);
}

// judge_mask (the tiled run's first look at a window whose points other tiles of its band own):
// each marked point gets the verdict and the near count the whole test gives it, the counting
// pass settling the points it can; an unmarked point gets 0 and 0. With a tile, the marked points
// whose searches could leave the window are among the whole test's. Oracle: the whole test on
// the same cloud, scale and tile, over marks that take every third point, removed and kept alike.
TEST(RobustOutliers, JudgingMarkedPointsGivesTheWholeTestsVerdictsAndNearCounts) {
  auto [c, o, whole_plain] = judged_cluttered_bunny();
  o.near_radius_m = 4.0 * std::exp(o.scale->median_log);
  // A window narrower than the cloud along x (its searches near the cut may leave it), deciding
  // all of it.
  const double x_mid = 0.5 * (c.xyz.row(0).minCoeff() + c.xyz.row(0).maxCoeff());
  const double inf = std::numeric_limits<double>::infinity();
  o.tile = RobustOutlierOptions::TileBounds{{-inf, x_mid, -inf, inf}, {-inf, x_mid, -inf, inf}, {}};
  hc::pipeline::RobustVerdicts whole;
  const auto full = remove_robust_outliers(c, o, &whole);
  o.judge_mask.assign(c.size(), 0);
  std::size_t marked_removed = 0, marked_certified_near = 0;
  for (std::size_t j = 0; j < c.size(); j += 3) {
    o.judge_mask[j] = 1;
    marked_removed += whole.verdict[j] != 0 ? 1U : 0U;
    marked_certified_near += whole.near[j] == std::min(o.k, 255) ? 1U : 0U;
  }
  ASSERT_GT(marked_removed, 30U);
  ASSERT_GT(marked_certified_near, 100U) << "points settled by counting among the marked";
  hc::pipeline::RobustVerdicts part;
  const auto judged = remove_robust_outliers(c, o, &part);
  EXPECT_EQ(judged.value.size(), c.size()) << "judging leaves the cloud as it was";
  ASSERT_EQ(part.verdict.size(), c.size());
  ASSERT_EQ(part.near.size(), c.size());
  for (std::size_t j = 0; j < c.size(); ++j) {
    if (o.judge_mask[j]) {
      EXPECT_EQ(part.verdict[j], whole.verdict[j]) << "column " << j;
      EXPECT_EQ(part.near[j], whole.near[j]) << "column " << j;
    } else {
      ASSERT_EQ(part.verdict[j], 0) << "an unmarked point is not judged";
      ASSERT_EQ(part.near[j], 0) << "an unmarked point is not counted";
    }
  }
  EXPECT_LT(figure(judged.report, "exact_queries"), figure(full.report, "exact_queries")) << "the unmarked are not searched";
  ASSERT_FALSE(whole.past_halo.empty()) << "the cut leaves searches past the window";
  std::size_t past_marked = 0;
  for (const std::uint32_t j : whole.past_halo) past_marked += o.judge_mask[j];
  EXPECT_GT(past_marked, 0U);
  for (const std::uint32_t j : part.past_halo) {
    EXPECT_EQ(o.judge_mask[j], 1) << "column " << j << ": listed past the window, not marked";
    EXPECT_TRUE(std::binary_search(whole.past_halo.begin(), whole.past_halo.end(), j)) << "column " << j;
  }
  EXPECT_FALSE(part.past_halo.empty());
  // Marking every point is the whole test.
  o.judge_mask.assign(c.size(), 1);
  hc::pipeline::RobustVerdicts every;
  (void)remove_robust_outliers(c, o, &every);
  EXPECT_EQ(every.verdict, whole.verdict);
  EXPECT_EQ(every.near, whole.near);
  EXPECT_EQ(every.past_halo, whole.past_halo);
  o.judge_mask.pop_back();
  EXPECT_THROW(remove_robust_outliers(c, o), hc::ConfigError) << "a byte a point";
  o.judge_mask.push_back(1);
  o.judge_only = {0};
  EXPECT_THROW(remove_robust_outliers(c, o), hc::ConfigError) << "judge_only and judge_mask together";
  o.judge_only.clear();
  o.scale.reset();
  EXPECT_THROW(remove_robust_outliers(c, o), hc::ConfigError) << "no scale given";
  (void)whole_plain;
}

// verdicts_only (the tiled run keeps a window's points for its second look): the cloud comes back
// as given, bit for bit, with the verdicts of the whole test; applying them gives the test's own
// result, and count_out is the number kept. Oracle: the same test without the option.
TEST(RobustOutliers, VerdictsOnlyGivesTheCloudBackAndTheTestsVerdicts) {
  auto [c, o, whole] = judged_cluttered_bunny();
  const auto filtered = remove_robust_outliers(c, o);
  ASSERT_LT(filtered.value.size() + 100, c.size());
  o.verdicts_only = true;
  hc::pipeline::RobustVerdicts v;
  const auto back = remove_robust_outliers(c, o, &v);
  EXPECT_TRUE(back.value.xyz == c.xyz);
  EXPECT_EQ(v.verdict, whole.verdict);
  EXPECT_EQ(back.report.count_out, filtered.value.size());
  std::vector<bool> keep(v.verdict.size());
  for (std::size_t i = 0; i < keep.size(); ++i) keep[i] = v.verdict[i] == 0;
  hc::pipeline::Cloud applied = back.value;
  applied.keep_if(keep);
  EXPECT_TRUE(applied.xyz == filtered.value.xyz);
  EXPECT_THROW(remove_robust_outliers(c, o), hc::ConfigError) << "verdicts_only without verdicts";
}

// near_radius_m (the tiled run's isolated-point filter and honest check need not search about a
// point whose neighbours the test already saw): each point's count is a lower bound of its
// neighbours within the radius, and a removed candidate's is exact up to k (its k nearest
// counted). Oracle: every point's neighbours counted by brute force in double; the verdicts
// unchanged.
TEST(RobustOutliers, NearCountsAreLowerBoundsOfTheNeighboursWithinTheRadius) {
  auto [c, o, whole] = judged_cluttered_bunny();
  const double r = 4.0 * std::exp(o.scale->median_log);  // four times the median k-NN distance
  o.near_radius_m = r;
  hc::pipeline::RobustVerdicts v;
  (void)remove_robust_outliers(c, o, &v);
  EXPECT_EQ(v.verdict, whole.verdict) << "the counts change no verdict";
  ASSERT_EQ(v.near.size(), c.size());
  std::size_t exact = 0, at_k = 0, removed_some = 0, removed_none = 0;
  // Oracle: every pair, pruned only by x (a pair farther apart in x than r(1 + 1e-6) is neither
  // within r nor a tie), so that the sweep costs a slab per point instead of the whole cloud
  // (the all-pairs loop took 114 s under ASan in CI, 2026-11-29).
  std::vector<std::size_t> by_x(c.size());
  for (std::size_t i = 0; i < c.size(); ++i) by_x[i] = i;
  std::sort(by_x.begin(), by_x.end(), [&](std::size_t a, std::size_t b) {
    return c.xyz(0, static_cast<Eigen::Index>(a)) < c.xyz(0, static_cast<Eigen::Index>(b));
  });
  const double slab = r * (1.0 + 1e-6);
  for (std::size_t s = 0; s < by_x.size(); ++s) {
    const std::size_t i = by_x[s];
    const Eigen::Vector3d pi = c.xyz.col(static_cast<Eigen::Index>(i));
    int within = 0;
    bool tie = false;
    const auto visit = [&](std::size_t j) {
      const double d = (pi - c.xyz.col(static_cast<Eigen::Index>(j))).norm();
      within += d <= r ? 1 : 0;
      tie = tie || std::abs(d - r) < 1e-6 * r;
    };
    for (std::size_t t = s; t-- > 0 && pi.x() - c.xyz(0, static_cast<Eigen::Index>(by_x[t])) <= slab;) visit(by_x[t]);
    for (std::size_t t = s + 1; t < by_x.size() && c.xyz(0, static_cast<Eigen::Index>(by_x[t])) - pi.x() <= slab; ++t) visit(by_x[t]);
    if (tie) continue;
    EXPECT_LE(int(v.near[i]), within) << "column " << i << ", verdict " << int(v.verdict[i]);
    at_k += v.near[i] == o.k ? 1U : 0U;
    if (v.verdict[i] != 0) {  // a candidate: its k nearest counted
      EXPECT_EQ(int(v.near[i]), std::min(within, o.k)) << "column " << i << ", verdict " << int(v.verdict[i]);
      ++exact;
      (v.near[i] > 0 ? removed_some : removed_none) += 1;
    }
  }
  EXPECT_GT(at_k, c.size() / 2) << "the bunny's points settled by counting: k within D_cert";
  EXPECT_GT(removed_some, 10U) << "removed points beside the surface";
  EXPECT_GT(removed_none, 10U) << "removed clutter far from everything";
  // Claimed while the recentred coordinates stay within 10^4 radii (a distance's float rounding
  // then stays under about 2e-3 of the radius): with one more point 5 000 radii out the counts
  // stand, 20 000 radii out none is claimed. (10^3 until 2026-11-28, when a tiled run's windows
  // took the in-core run's float frame, whose coordinates reach as far as the scan does.)
  for (const auto& [radii, claimed] : {std::pair{5e3, true}, std::pair{2e4, false}}) {
    const Cloud far = with_extra(c, {Eigen::Vector3d(radii * r, 0.0, 0.0)});
    hc::pipeline::RobustVerdicts fv;
    (void)remove_robust_outliers(far, o, &fv);
    const auto counted = static_cast<std::size_t>(std::count_if(fv.near.begin(), fv.near.end(), [](std::uint8_t m) { return m > 0; }));
    if (claimed) {
      EXPECT_GT(counted, c.size() / 2) << radii << " radii out";
    } else {
      EXPECT_EQ(counted, 0U) << radii << " radii out";
    }
  }
  // Bad values refused by name; not asked, no counts.
  o.near_radius_m = -1.0;
  EXPECT_THROW(remove_robust_outliers(c, o, &v), hc::ConfigError);
  o.near_radius_m = 0.0;
  (void)remove_robust_outliers(c, o, &v);
  EXPECT_TRUE(v.near.empty()) << "not asked";
}

// The tile check's promise (RobustOutlierOptions::tile): a point in decides_m whose verdict
// over the window's points alone differs from the whole cloud's is listed in past_halo. Oracle:
// the whole test over the whole cloud with the same scale. Windows of several sizes and
// margins over the cluttered bunny (its clutter: points whose searches reach far).
TEST(RobustOutliers, ATilesVerdictThatDiffersFromTheWholeCloudsIsListedAsPastItsHalo) {
  const auto [c, o, whole] = judged_cluttered_bunny();
  const Eigen::Vector3d lo = c.xyz.rowwise().minCoeff(), hi = c.xyz.rowwise().maxCoeff(), ext = hi - lo;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::size_t differing = 0, decided = 0, listed_total = 0;
  for (int trial = 0; trial < 200; ++trial) {
    const double x0 = lo.x() + 0.8 * ext.x() * u(rng), y0 = lo.y() + 0.8 * ext.y() * u(rng);
    const double x1 = x0 + ext.x() * (0.1 + 0.3 * u(rng)), y1 = y0 + ext.y() * (0.1 + 0.3 * u(rng));
    const double m = ext.x() * (0.002 + 0.02 * u(rng));
    RobustOutlierOptions to = o;
    to.tile = RobustOutlierOptions::TileBounds{{x0, x1, y0, y1}, {x0 + m, x1 - m, y0 + m, y1 - m}, {}};
    std::vector<bool> in(c.size());
    std::vector<std::uint32_t> of;  // the window's points' columns in c
    for (std::size_t i = 0; i < c.size(); ++i) {
      const auto p = c.xyz.col(static_cast<Eigen::Index>(i));
      in[i] = p.x() >= x0 && p.x() < x1 && p.y() >= y0 && p.y() < y1;
      if (in[i]) of.push_back(static_cast<std::uint32_t>(i));
    }
    Cloud window = c;
    window.keep_if(in);
    if (window.size() < 100) continue;
    hc::pipeline::RobustVerdicts part;
    (void)remove_robust_outliers(window, to, &part);
    const std::set<std::uint32_t> listed(part.past_halo.begin(), part.past_halo.end());
    listed_total += listed.size();
    for (std::size_t i = 0; i < window.size(); ++i) {
      const auto p = window.xyz.col(static_cast<Eigen::Index>(i));
      if (!(p.x() >= x0 + m && p.x() < x1 - m && p.y() >= y0 + m && p.y() < y1 - m)) continue;
      ++decided;
      if (part.verdict[i] == whole.verdict[of[i]]) continue;
      ++differing;
      EXPECT_TRUE(listed.count(static_cast<std::uint32_t>(i))) << "trial " << trial << ": point " << of[i] << " ("
                                                                << p.transpose() << ") differs but is not listed";
    }
  }
  std::cout << "[ info ] decided " << decided << ", differing " << differing << ", listed " << listed_total << "\n";
  EXPECT_GT(differing, 0U) << "no window changed a verdict: the test would not see a broken check";
}

// The hand-built cases below: points given in millimetres, as a cloud in metres; and the test
// they share, k = 4 with the scale given (d_med = 1 mm, a global threshold of about 140 m: only
// the local test acts) and no off-surface test.
Cloud cloud_of_mm(const std::vector<Eigen::Vector3d>& mm) {
  std::vector<Eigen::Vector3d> m;
  for (const Eigen::Vector3d& p : mm) m.push_back(p * 1e-3);
  return cloud_of(m);
}
RobustOutlierOptions local_test_only_k4() {
  RobustOutlierOptions o;
  o.k = 4;
  o.off_surface_ratio = 0.0;
  o.scale = hc::pipeline::RobustScale{std::log(1e-3), 1.0, 100};
  return o;
}

// The check's neighbour term, on a case built by hand (mm below; the cloud in metres). k = 4,
// the scale given (d_med = 1 mm, a global threshold of about 140 m: only the local test acts),
// no off-surface test: a point i is removed when d_i > 3·max(median of its neighbours' d, 1 mm).
// The window is x < 0. i = (-20, 0, 0); its 4 nearest, J = (-2, ±1.5, 0) and (-2, ±4.5, 0), lie
// 18.06 and 18.55 mm away (d_i = 18.3 mm; r_i = 18.55 inside its 20 mm margin). In the window
// each j of J has the other three and i as its 4 nearest (d_j 7.5 and 9.1 mm): 18.3 < 3·8.3,
// i is kept. Past the window, 25 points at x = 0.5, y = -6..6 step 0.5 bring each j's 4 nearest
// within about 2.7 mm (median d_j about 2.6): over the whole cloud 18.3 > 3·2.6, i is removed,
// with the same 4 neighbours (the row is 20.5 mm from it). Only the neighbours' searches leave
// the window: the check must list i for them. A far point (-200, 0, 0) makes the window 6 points.
TEST(RobustOutliers, ANeighboursSearchPastTheWindowListsThePoint) {
  std::vector<Eigen::Vector3d> mm = {{-20, 0, 0}, {-2, 1.5, 0}, {-2, -1.5, 0}, {-2, 4.5, 0}, {-2, -4.5, 0}, {-200, 0, 0}};
  const std::size_t in_window = mm.size();
  for (int a = 0; a <= 24; ++a) mm.emplace_back(0.5, -6.0 + 0.5 * a, 0.0);
  const Cloud whole = cloud_of_mm(mm);
  const RobustOutlierOptions o = local_test_only_k4();
  hc::pipeline::RobustVerdicts all;
  (void)remove_robust_outliers(whole, o, &all);
  ASSERT_EQ(all.verdict[0], 2) << "over the whole cloud i is a local outlier (hand computation above)";

  Cloud window = whole;
  std::vector<bool> in(whole.size(), false);
  for (std::size_t i = 0; i < in_window; ++i) in[i] = true;
  window.keep_if(in);
  const double inf = std::numeric_limits<double>::infinity();
  RobustOutlierOptions to = o;
  to.tile = RobustOutlierOptions::TileBounds{{-inf, 0.0, -inf, inf}, {-inf, -0.010, -inf, inf}, {}};
  hc::pipeline::RobustVerdicts part;
  const auto r = remove_robust_outliers(window, to, &part);
  ASSERT_EQ(part.verdict[0], 0) << "over the window alone i is kept (hand computation above)";
  EXPECT_TRUE(std::find(part.past_halo.begin(), part.past_halo.end(), 0U) != part.past_halo.end())
      << "i's verdict differs from the whole cloud's through its neighbours' searches, but it is not listed";
  // Among the balls: i's own (r_i = |(18, 4.5)| = 18.55 mm) and each neighbour's (its 4th nearest
  // here, i, 18.06 or 18.55 mm away).
  auto ball_at = [&](const Eigen::Vector3d& c_mm) {
    for (const auto& b : part.reach_m) {
      if ((Eigen::Vector3d(b[0], b[1], b[2]) - c_mm * 1e-3).norm() < 1e-9) return b[3];
    }
    return -1.0;
  };
  EXPECT_NEAR(ball_at(mm[0]), std::hypot(18.0, 4.5) * 1e-3, 0.01e-3);
  EXPECT_NEAR(ball_at(mm[1]), std::hypot(18.0, 1.5) * 1e-3, 0.01e-3);
  EXPECT_NEAR(ball_at(mm[3]), std::hypot(18.0, 4.5) * 1e-3, 0.01e-3);
  EXPECT_GT(figure(r.report, "halo_shortfall_mm"), 15.0);

  // Complete in balls that hold the row past the window (the second look's set), i is removed.
  RobustOutlierOptions again = o;
  again.tile = RobustOutlierOptions::TileBounds{{}, {}, {{-20e-3, 0.0, 0.0, 40e-3}}};
  again.judge_only = {0};
  hc::pipeline::RobustVerdicts second;
  (void)remove_robust_outliers(whole, again, &second);
  EXPECT_EQ(second.verdict[0], 2);
  EXPECT_TRUE(second.past_halo.empty()) << "every search of i and its neighbours lies inside the 40 mm ball";
}

// The check's shortcut for points far inside the window (k·d_i bounds the point's k-th
// distance, and a neighbour's search reaches at most 2·r_i past it) must not skip a point a
// neighbour's search lists. Built so that k·d_i is almost r_i: k = 4, the local test only (as
// above), i with three points 0.01 mm from it and its fourth neighbour j = i + (20, 0, 0) mm,
// toward the window's open side x = 0 (r_i = 20.0 mm, d_i = 5.0075 mm > 3 mm: a candidate of the
// local test). j's own 4 nearest are i's cluster, 20 mm away, so its search reaches 20 mm: past
// its margin when i lies at x = −38 mm (j's margin 18 mm; i listed), inside it at x = −42 mm
// (j's margin 22 mm; i's own search, 20 mm, inside its 42 mm; not listed). Oracle: that hand
// computation. A far point at x = −300 mm makes the six points k = 4 needs. A shortcut that
// trusted a bound under 1.9·r_i skips i at −38 mm.
TEST(RobustOutliers, APointFarInsideItsWindowIsListedWhenANeighboursSearchLeavesIt) {
  for (const double xi_mm : {-38.0, -42.0}) {
    const std::vector<Eigen::Vector3d> mm = {{xi_mm, 0, 0},    {xi_mm, 0.01, 0},     {xi_mm, -0.01, 0},
                                             {xi_mm, 0, 0.01}, {xi_mm + 20.0, 0, 0}, {-300, 0, 0}};
    const Cloud window = cloud_of_mm(mm);
    RobustOutlierOptions o = local_test_only_k4();
    const double inf = std::numeric_limits<double>::infinity();
    o.tile = RobustOutlierOptions::TileBounds{{-inf, 0.0, -inf, inf}, {-inf, -0.010, -inf, inf}, {}};
    hc::pipeline::RobustVerdicts part;
    (void)remove_robust_outliers(window, o, &part);
    const bool listed = std::find(part.past_halo.begin(), part.past_halo.end(), 0U) != part.past_halo.end();
    EXPECT_EQ(listed, xi_mm > -40.0) << "i at x = " << xi_mm << " mm: j's search reaches " << (xi_mm > -40.0 ? "past" : "inside")
                                     << " its margin";
  }
}

TEST(RobustOutliers, UniformClutterOfOneToFivePercentGoesAndTruePointsStay) {
  // Oracle: the tags of the injected points. Clutter uniform in the bunny's bounding box at 1, 2
  // and 5 %: at least 95 % of it goes, at most 0.5 % of the scan's points. Without the
  // off-surface test more than 5 % stays (clutter within a few spacings of the surface, whose
  // neighbours are surface points), so the case keeps testing that test.
  for (const double share : {0.01, 0.02, 0.05}) {
    const auto count = static_cast<std::size_t>(share * static_cast<double>(bunny().size()));
    const Cloud c = with_extra(bunny(), uniform_in_box(count, 5));
    const auto r = remove_outliers_robust(c, {}, {});
    const Kept k = kept_of(r.value);
    EXPECT_LE(static_cast<double>(k.injected), 0.05 * static_cast<double>(count)) << share << ": " << k.injected << " of " << count << " kept";
    EXPECT_GE(static_cast<double>(k.truth), 0.995 * static_cast<double>(bunny().size())) << share;
    EXPECT_GT(figure(r.report, "removed_off_surface"), 0.0) << share;
    RobustOutlierOptions without;
    without.off_surface_ratio = 0.0;
    EXPECT_GT(static_cast<double>(kept_of(remove_outliers_robust(c, without, {}).value).injected), 0.05 * static_cast<double>(count))
        << share;
  }
}

TEST(RobustOutliers, FarPointLeavesTheGridIdenticalToTheCleanRun) {
  const Eigen::Vector3d lo = bunny().xyz.rowwise().minCoeff(), hi = bunny().xyz.rowwise().maxCoeff();
  const Cloud c = with_extra(bunny(), {Eigen::Vector3d(hi.x() + 1000.0, 0.5 * (lo.y() + hi.y()), 0.5 * (lo.z() + hi.z()))});
  const BuiltScene far = run_on(c, "far_point");
  EXPECT_EQ(cells_differing(clean_run(), far), 0u);
  EXPECT_EQ(far.cloud->size(), clean_run().cloud->size());
  EXPECT_EQ(kept_of(remove_outliers_robust(c, {}, {}).value).injected, 0u);
}

// Kept as a witness that the case defeats the exact SOR (its threshold jumps to metres).
TEST(RobustOutliers, FarPointFoolsTheStatisticalMethod) {
  const Eigen::Vector3d lo = bunny().xyz.rowwise().minCoeff(), hi = bunny().xyz.rowwise().maxCoeff();
  const Cloud c = with_extra(bunny(), {Eigen::Vector3d(hi.x() + 1000.0, 0.5 * (lo.y() + hi.y()), 0.5 * (lo.z() + hi.z()))});
  const std::string sor = "{enabled: true, method: statistical}";
  const BuiltScene clean = run_on(bunny(), "clean_sor", sor);
  const BuiltScene far = run_on(c, "far_point_sor", sor);
  // The SOR threshold jumps to metres: it keeps points it removed before, and the grid changes.
  EXPECT_GT(far.cloud->size(), clean.cloud->size());
  EXPECT_NE(clean.scene.geometry, far.scene.geometry);
}

std::vector<Eigen::Vector3d> far_cluster(std::size_t count, double spread_m) {
  const Eigen::Vector3d hi = bunny().xyz.rowwise().maxCoeff();
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-0.5 * spread_m, 0.5 * spread_m);
  std::vector<Eigen::Vector3d> pts(count);
  for (auto& p : pts) p = hi + Eigen::Vector3d(1000.0, 0.0, 0.5) + Eigen::Vector3d(u(rng), u(rng), u(rng));
  return pts;
}

TEST(RobustOutliers, FarClusterIsDroppedAndTheRunSucceeds) {
  // 30 points within 3 mm of each other, 1 km away: as dense as the bunny, so only far-cluster
  // removal can tell them from the object.
  const Cloud c = with_extra(bunny(), far_cluster(30, 0.003));
  const BuiltScene b = run_on(c, "far_cluster");
  EXPECT_EQ(b.cloud->size(), clean_run().cloud->size());
  EXPECT_EQ(figure(outlier_stage(b), "removed_far_clusters"), 30.0);
  EXPECT_EQ(figure(outlier_stage(b), "far_clusters"), 1.0);
  EXPECT_EQ(cells_differing(clean_run(), b), 0u);
  bool named = false;
  for (const auto& n : outlier_stage(b).notes) named = named || n.find("removed far cluster: 30 points") != std::string::npos;
  EXPECT_TRUE(named);
}

TEST(RobustOutliers, FarClusterDefeatsTheStatisticalMethod) {
  const Cloud c = with_extra(bunny(), far_cluster(30, 0.003));
  EXPECT_THROW(run_on(c, "far_cluster_sor", "{enabled: true, method: statistical}"), hc::DegenerateInputError);
}

TEST(RobustOutliers, KeptFarClusterIsNamedInTheDegenerateGridError) {
  const Cloud c = with_extra(bunny(), far_cluster(30, 0.003));
  try {
    run_on(c, "far_cluster_kept", "{enabled: true, far_clusters: {enabled: false}}");
    FAIL() << "the grid over 1 km should be degenerate";
  } catch (const hc::DegenerateInputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("30 points lie far from the main body"), std::string::npos) << what;
    EXPECT_NE(what.find("filters.crop"), std::string::npos) << what;
  }
}

// The bunny with the points right of the median x kept with probability keep(x) (deterministic).
Cloud thinned(const std::function<double(double)>& keep_at, std::size_t* thinned_count) {
  const Cloud& b = bunny();
  std::vector<double> xs(b.size());
  for (std::size_t i = 0; i < b.size(); ++i) xs[i] = b.xyz(0, static_cast<Eigen::Index>(i));
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<bool> keep(b.size());
  Cloud c = b;
  std::size_t kept_sparse = 0;
  for (std::size_t i = 0; i < b.size(); ++i) {
    const double p = keep_at(xs[i]);
    keep[i] = u(rng) < p;
    if (p < 1.0 && keep[i]) {
      c.intensity[i] = 1.0f;  // tag: a point of the thinned part
      ++kept_sparse;
    }
  }
  c.keep_if(keep);
  *thinned_count = kept_sparse;
  return c;
}

double median_x() {
  std::vector<double> xs(bunny().size());
  for (std::size_t i = 0; i < xs.size(); ++i) xs[i] = bunny().xyz(0, static_cast<Eigen::Index>(i));
  std::nth_element(xs.begin(), xs.begin() + static_cast<std::ptrdiff_t>(xs.size() / 2), xs.end());
  return xs[xs.size() / 2];
}

TEST(RobustOutliers, DensityStepKeepsTheSparseHalf) {
  const double mx = median_x();
  std::size_t sparse = 0;
  const Cloud c = thinned([&](double x) { return x > mx ? 0.03 : 1.0; }, &sparse);
  ASSERT_GT(sparse, 400u);
  const auto r = remove_outliers_robust(c, RobustOutlierOptions{}, FarClusterOptions{});
  EXPECT_GE(static_cast<double>(kept_of(r.value).injected), 0.95 * static_cast<double>(sparse))
      << kept_of(r.value).injected << " of " << sparse;
  // The dense half keeps its points too.
  EXPECT_GE(static_cast<double>(kept_of(r.value).truth), 0.995 * static_cast<double>(c.size() - sparse));
}

TEST(RobustOutliers, DensityStepDefeatsTheStatisticalMethod) {
  const double mx = median_x();
  std::size_t sparse = 0;
  const Cloud c = thinned([&](double x) { return x > mx ? 0.03 : 1.0; }, &sparse);
  const auto r = remove_statistical_outliers(c, 16, 2.0);
  EXPECT_LT(static_cast<double>(kept_of(r.value).injected), 0.95 * static_cast<double>(sparse));
}

TEST(RobustOutliers, DensityGradientKeepsItsPoints) {
  const Eigen::Vector3d lo = bunny().xyz.rowwise().minCoeff(), hi = bunny().xyz.rowwise().maxCoeff();
  std::size_t sparse = 0;
  // Density falls linearly from 100 % at the left edge to 3 % at the right edge.
  const Cloud c = thinned([&](double x) { return 1.0 - 0.97 * (x - lo.x()) / (hi.x() - lo.x()) - 1e-12; }, &sparse);
  const auto r = remove_outliers_robust(c, RobustOutlierOptions{}, FarClusterOptions{});
  const double lost = static_cast<double>(c.size() - r.value.size());
  EXPECT_LE(lost, 0.005 * static_cast<double>(c.size())) << lost << " of " << c.size();
}

// The median as the rule defines it: the middle value, or the mean of the two middle ones.
double median_value(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t h = v.size() / 2;
  return v.size() % 2 ? v[h] : 0.5 * (v[h - 1] + v[h]);
}

// Oracle: the rule of robust_outliers.hpp evaluated by brute force in double precision (every
// pairwise distance, neighbours ordered by distance then input index), on a cloud made to take
// every search path: a wavy surface (4 000 points, 0.1 mm noise), a coherent patch at 3 %
// density beside it, 200 points of clutter in the box around both and, with `far_points`, three
// points 10 m away (their neighbours lie only on the far side of empty space; the grid then has
// many cells per point: sorted keys and binary searches; without them a dense key table and a
// counting sort).
void expect_rule_by_brute_force(bool far_points) {
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 1e-4);
  std::vector<Eigen::Vector3d> pts;
  auto surface = [](double x, double y) { return 0.01 * std::sin(20.0 * x) * std::cos(15.0 * y); };
  for (int i = 0; i < 4000; ++i) {
    const double x = 0.2 * u(rng), y = 0.2 * u(rng);
    pts.emplace_back(x, y, surface(x, y) + noise(rng));
  }
  for (int i = 0; i < 120; ++i) {
    const double x = 0.2 + 0.2 * u(rng), y = 0.2 * u(rng);
    pts.emplace_back(x, y, surface(x, y) + noise(rng));
  }
  for (int i = 0; i < 200; ++i) pts.emplace_back(0.4 * u(rng), 0.2 * u(rng), -0.05 + 0.1 * u(rng));
  if (far_points) {
    for (int i = 0; i < 3; ++i) pts.emplace_back(10.0 + 2.0 * i, -7.0 * i, 3.0);
  }
  Cloud c;
  c.xyz.resize(3, static_cast<Eigen::Index>(pts.size()));
  for (std::size_t i = 0; i < pts.size(); ++i) c.xyz.col(static_cast<Eigen::Index>(i)) = pts[i];
  c.intensity.resize(pts.size());
  for (std::size_t i = 0; i < pts.size(); ++i) c.intensity[i] = static_cast<float>(i);  // input index

  RobustOutlierOptions o;  // k 16, local_ratio 3, mad_multiplier 8, max_surface_variation 0.05
  o.sample = pts.size();   // the median and MAD over every point
  const auto r = remove_robust_outliers(c, o);

  const std::size_t n = pts.size(), k = static_cast<std::size_t>(o.k);
  std::vector<std::vector<std::size_t>> nb(n);
  std::vector<double> d(n);
  std::vector<std::pair<double, std::size_t>> all(n - 1);
  for (std::size_t i = 0; i < n; ++i) {
    all.clear();
    for (std::size_t j = 0; j < n; ++j) {
      if (j != i) all.emplace_back((pts[i] - pts[j]).squaredNorm(), j);
    }
    std::partial_sort(all.begin(), all.begin() + static_cast<std::ptrdiff_t>(k), all.end());
    double sum = 0.0;
    for (std::size_t q = 0; q < k; ++q) {
      sum += std::sqrt(all[q].first);
      nb[i].push_back(all[q].second);
    }
    d[i] = sum / static_cast<double>(k);
  }
  std::vector<double> logs;
  for (const double v : d) {
    if (v > 0.0) logs.push_back(std::log(v));
  }
  const auto step = [](double v) { return std::round(v * 128.0) / 128.0; };
  const double med = step(median_value(logs));
  for (double& v : logs) v = std::abs(v - med);
  const double sigma = 1.4826 * step(median_value(logs));
  const double d_med = std::exp(med);
  const double d_glob = std::max(std::exp(med + o.mad_multiplier * sigma), o.local_ratio * d_med);
  EXPECT_NEAR(figure(r.report, "median_knn_distance_mm"), d_med * 1e3, 1e-9);
  EXPECT_NEAR(figure(r.report, "global_threshold_mm"), d_glob * 1e3, 1e-9);

  // Above D_glob: "scattered" when the point and its neighbours are not a surface (their surface
  // variation exceeds the limit).
  std::vector<bool> scattered(n, false);
  for (std::size_t i = 0; i < n; ++i) {
    if (!(d[i] > d_glob)) continue;
    Eigen::Vector3d mean = pts[i];
    for (const std::size_t j : nb[i]) mean += pts[j];
    mean /= static_cast<double>(k + 1);
    Eigen::Matrix3d cov = (pts[i] - mean) * (pts[i] - mean).transpose();
    for (const std::size_t j : nb[i]) cov += (pts[j] - mean) * (pts[j] - mean).transpose();
    const Eigen::Vector3d ev = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov).eigenvalues();
    scattered[i] = ev.sum() > 0.0 && std::max(ev(0), 0.0) / ev.sum() > o.max_surface_variation;
  }
  std::vector<bool> removed(n, false);
  std::size_t n_global = 0, n_local = 0, n_off = 0, clutter_removed = 0, n_among = 0;
  for (std::size_t i = 0; i < n; ++i) {
    bool global = false, off = false;
    if (d[i] > d_glob) {
      // Not on a surface: scattered itself, or more than half of its k nearest are.
      std::size_t among = 0;
      for (const std::size_t j : nb[i]) among += scattered[j] ? 1u : 0u;
      global = scattered[i] || 2 * among > k;
      n_among += !scattered[i] && 2 * among > k ? 1u : 0u;
    } else if (d[i] > o.off_surface_ratio * d_med) {
      // Off surface: the neighbours alone form a surface and the point stands off their
      // least-squares plane by more than d_i / 2.
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      for (const std::size_t j : nb[i]) mean += pts[j];
      mean /= static_cast<double>(k);
      Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
      for (const std::size_t j : nb[i]) cov += (pts[j] - mean) * (pts[j] - mean).transpose();
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(cov);
      const Eigen::Vector3d ev = es.eigenvalues();
      const double variation = ev.sum() > 0.0 ? std::max(ev(0), 0.0) / ev.sum() : 0.0;
      off = variation <= o.max_surface_variation && std::abs(es.eigenvectors().col(0).dot(pts[i] - mean)) > 0.5 * d[i];
    }
    std::vector<double> nd;
    for (const std::size_t j : nb[i]) nd.push_back(d[j]);
    const bool local = !global && !off && d[i] > o.local_ratio * std::max(median_value(nd), d_med);
    removed[i] = global || local || off;
    n_global += global ? 1u : 0u;
    n_local += local ? 1u : 0u;
    n_off += off ? 1u : 0u;
    clutter_removed += removed[i] && i >= 4120 ? 1u : 0u;
  }
  // The case is not trivial: each of the three tests removes points, and most clutter goes.
  EXPECT_GT(n_global, 100u);
  EXPECT_GT(n_local, 0u);
  EXPECT_GT(n_off, 0u);
  EXPECT_GT(clutter_removed, 150u);
  EXPECT_GT(n_among, 0u);  // clutter on a chance plane among clutter: the neighbours' rule applies
  EXPECT_EQ(figure(r.report, "removed_global"), static_cast<double>(n_global));
  EXPECT_EQ(figure(r.report, "planar_among_scattered"), static_cast<double>(n_among));
  EXPECT_EQ(figure(r.report, "removed_local"), static_cast<double>(n_local));
  EXPECT_EQ(figure(r.report, "removed_off_surface"), static_cast<double>(n_off));
  std::vector<bool> kept(n, false);
  for (const float t : r.value.intensity) kept[static_cast<std::size_t>(t)] = true;
  std::size_t mismatches = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (kept[i] != removed[i]) continue;  // kept exactly when the rule keeps it
    if (++mismatches <= 5) ADD_FAILURE() << "point " << i << (removed[i] ? " kept, the rule removes it" : " removed, the rule keeps it");
  }
  EXPECT_EQ(mismatches, 0u);
}

TEST(RobustOutliers, RemovedSetIsTheRuleAppliedToEveryPointByBruteForce) { expect_rule_by_brute_force(true); }

TEST(RobustOutliers, RemovedSetIsTheRuleByBruteForceOnACompactBox) { expect_rule_by_brute_force(false); }

TEST(RobustOutliers, BadOptionsAreConfigErrors) {
  RobustOutlierOptions o;
  o.local_ratio = 1.0;
  EXPECT_THROW(remove_robust_outliers(bunny(), o), hc::ConfigError);
  o = {};
  o.k = 0;
  EXPECT_THROW(remove_robust_outliers(bunny(), o), hc::ConfigError);
  o = {};
  o.off_surface_ratio = 1.0;  // 0 (off) or above 1
  EXPECT_THROW(remove_robust_outliers(bunny(), o), hc::ConfigError);
  EXPECT_THROW(remove_far_clusters(bunny(), 0.0, FarClusterOptions{}), hc::ConfigError);
  const fs::path dir = hc::test::temp_dir("cfg");
  try {
    parse_run_config("input: {files: [x.ply]}\nfilters: {outliers: {method: sor}}\n", dir / "run.yaml");
    FAIL() << "method sor accepted";
  } catch (const hc::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("filters.outliers.method"), std::string::npos) << e.what();
  }
  EXPECT_THROW(parse_run_config("input: {files: [x.ply]}\nfilters: {outliers: {scope: front}}\n", dir / "run.yaml"),
               hc::ConfigError);
  EXPECT_THROW(parse_run_config("input: {files: [x.ply]}\nfilters: {outliers: {off_surface_ratio: 0.5}}\n", dir / "run.yaml"),
               hc::ConfigError);
  EXPECT_EQ(parse_run_config("input: {files: [x.ply]}\nfilters: {outliers: {off_surface_ratio: 0}}\n", dir / "run.yaml")
                .filters.outliers.off_surface_ratio,
            0.0);
  EXPECT_THROW(parse_run_config("input: {files: [x.ply]}\nfilters: {outliers: {far_clusters: {max_fraction: 2}}}\n",
                                dir / "run.yaml"),
               hc::ConfigError);
}

// A cloud of the given points (no attributes).
Cloud cloud_of(const std::vector<Eigen::Vector3d>& pts) {
  Cloud c;
  c.xyz.resize(3, static_cast<Eigen::Index>(pts.size()));
  for (std::size_t i = 0; i < pts.size(); ++i) c.xyz.col(static_cast<Eigen::Index>(i)) = pts[i];
  return c;
}

// The known answer of both far-cluster cases: a 10 cm square of 300 points at x, y in [0, 0.1] m
// (the main body), 5 points `gap_m` from it (far: listed first among the others and removed)
// and 3 points above it (not far: kept). remove_far_clusters keeps 303 points, none at x >= 0.2.
void expect_body_far_five_and_three_above(const Cloud& c, const FarClusterOptions& o, double gap_m) {
  const FarClusters fc = find_far_clusters(c, 0.02, o);
  EXPECT_EQ(fc.main_body.count, 300u);
  ASSERT_EQ(fc.others.size(), 2u);
  EXPECT_EQ(fc.others[0].count, 5u);
  EXPECT_TRUE(fc.others[0].removed);
  EXPECT_NEAR(fc.others[0].gap_m, gap_m, 0.01);
  EXPECT_EQ(fc.others[1].count, 3u);
  EXPECT_FALSE(fc.others[1].removed);  // not far at o.far_distance_m
  hc::pipeline::RemovedPoints removed;
  const auto r = remove_far_clusters(c, 0.02, o, nullptr, 0, &removed);
  ASSERT_EQ(r.value.size(), 303u);
  for (Eigen::Index i = 0; i < r.value.xyz.cols(); ++i) EXPECT_LT(r.value.xyz(0, i), 0.2) << i;  // the far five went
  // The removed points as listed: the five columns at x >= 0.2 (found here by coordinate), in
  // order, with their coordinates; the cloud less them is the result.
  std::vector<std::size_t> far_columns;
  for (Eigen::Index i = 0; i < c.xyz.cols(); ++i) {
    if (c.xyz(0, i) >= 0.2) far_columns.push_back(static_cast<std::size_t>(i));
  }
  ASSERT_EQ(far_columns.size(), 5u);
  EXPECT_EQ(removed.at, far_columns);
  ASSERT_EQ(removed.xyz.size(), 15u);
  for (std::size_t j = 0; j < 5; ++j) {
    for (Eigen::Index a = 0; a < 3; ++a) EXPECT_EQ(removed.xyz[3 * j + static_cast<std::size_t>(a)], c.xyz(a, static_cast<Eigen::Index>(far_columns[j])));
  }
  std::vector<bool> keep(c.size(), true);
  for (const std::size_t i : far_columns) keep[i] = false;
  Cloud rest = c;
  rest.keep_if(keep);
  EXPECT_TRUE(rest.xyz == r.value.xyz);
}

TEST(FarClusters, ComponentsMatchBruteForceSingleLinkage) {
  // Known answer: a 10 cm square of 300 points (mean spacing 6 mm, linked at 2 cm), 5 points 5 m
  // away and 3 points 15 cm above it.
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 300; ++i) pts.emplace_back(u(rng) * 0.1, u(rng) * 0.1, 0.0);        // main body
  for (int i = 0; i < 5; ++i) pts.emplace_back(5.0 + 0.001 * i, 0.0, 0.0);                 // 5 m away
  for (int i = 0; i < 3; ++i) pts.emplace_back(0.05, 0.05, 0.0 + 0.15 + 0.001 * i);        // 10 cm above
  const Cloud c = cloud_of(pts);
  FarClusterOptions o;
  o.far_distance_m = 1.0;  // the 3 points 15 cm above: not far
  expect_body_far_five_and_three_above(c, o, 5.0 - 0.1);
}

TEST(FarClusters, CompactBoxGivesTheSameKnownAnswer) {
  // The same known answer in a box of few cells per point (40 × 10 × 5.5 cm at 2 cm: 504 cells
  // for 308 points), where the cells are found in a dense table instead of sorted keys: a 10 cm
  // square of 300 points, 5 points 30 cm away (far at far_distance_m = 0.2) and 3 points 5 cm
  // above it (not far). Listed first in the input: the far points, so component order by first
  // point differs from order by size.
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 5; ++i) pts.emplace_back(0.4 - 0.001 * i, 0.0, 0.0);                 // 30 cm away
  for (int i = 0; i < 300; ++i) pts.emplace_back(u(rng) * 0.1, u(rng) * 0.1, 0.0);        // main body
  for (int i = 0; i < 3; ++i) pts.emplace_back(0.05, 0.05, 0.05 + 0.001 * i);             // 5 cm above
  const Cloud c = cloud_of(pts);
  FarClusterOptions o;
  o.far_distance_m = 0.2;
  expect_body_far_five_and_three_above(c, o, 0.4 - 0.004 - 0.1);
  EXPECT_NEAR(find_far_clusters(c, 0.02, o).others.at(0).centroid_m.x(), 0.398, 1e-12);
}

// RemovedPoints::cluster: the points of one removed cluster share a number, those of two
// clusters do not, numbered 0, 1, ... by each cluster's first point in the cloud (the tiled run
// counts a cluster once, by the tile owning its least point). Oracle: the clusters as built.
TEST(FarClusters, RemovedPointsNameTheirClusterInTheOrderOfItsFirstPoint) {
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Eigen::Vector3d> pts;
  std::vector<int> built;  // -1 main body, else the far cluster (0: Q at z = 0.5, 1: R at x = 0.4)
  const auto add = [&](const Eigen::Vector3d& p, int c) {
    pts.push_back(p);
    built.push_back(c);
  };
  for (int i = 0; i < 400; ++i) {
    // R's first point comes before Q's: the numbers follow the cloud's order, not the building's.
    if (i == 100) add(Eigen::Vector3d(0.4, 0.05, 0.0), 1);
    if (i == 150) add(Eigen::Vector3d(0.05, 0.05, 0.5), 0);
    if (i > 150 && i % 50 == 7) add(Eigen::Vector3d(0.05 + 0.001 * (i % 7), 0.06, 0.5), 0);
    if (i > 100 && i % 60 == 9) add(Eigen::Vector3d(0.4, 0.05 + 0.002 * (i % 5), 0.001), 1);
    add(Eigen::Vector3d(u(rng) * 0.1, u(rng) * 0.1, 0.0), -1);
  }
  FarClusterOptions o;
  o.far_distance_m = 0.1;
  RemovedPoints removed;
  const auto r = remove_far_clusters(cloud_of(pts), 0.02, o, nullptr, 0, &removed);
  ASSERT_EQ(removed.cluster.size(), removed.size());
  std::size_t far = 0;
  for (const int c : built) far += c >= 0 ? 1U : 0U;
  ASSERT_EQ(removed.size(), far) << "Q and R removed, the main body kept";
  EXPECT_EQ(r.value.size(), pts.size() - far);
  for (std::size_t i = 0; i < removed.size(); ++i) {
    const int b = built[removed.at[i]];
    ASSERT_GE(b, 0);
    EXPECT_EQ(removed.cluster[i], b == 1 ? 0U : 1U) << "R's first point is the cloud's first far point";
  }
}

// A part of a scan (FarClusterScope): a 10 cm square of 300 points (z = 0, the part's largest
// component), 5 points 50 cm above its middle (P) and 5 points 20 cm beside it (Q, x 0.3 to
// 0.304). Linked at 2 cm, far beyond 10 cm. The known answers by construction:
// - alone (no scope) P and Q are far from the square, the part's main body: both removed;
// - with the whole scan's main body box holding all three (a statue whose other parts link
//   them outside the part), nothing is far: all kept; every point lies within far − 2√3 cell
//   edges of the box, so none is linked and no component listed (find_far_clusters);
// - with a main body box that is the square's, both far; Q's box grown by two cell edges (4 cm)
//   reaches x = 0.344, so a complete box ending at x = 0.33 leaves Q undecided (kept) and P
//   removed; one ending at x = 0.36 removes both;
// - N of the size limit is the scope's: max_points 4, max_fraction 0.01 and 1000 points give 10
//   (both small: removed); 100 points give 4 (both too large: kept far).
TEST(FarClusters, AScopeJudgesTheLinkedComponentsAgainstTheWholeScansMainBodyAndRemovesOnlyCompleteOnes) {
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 300; ++i) pts.emplace_back(u(rng) * 0.1, u(rng) * 0.1, 0.0);
  for (int i = 0; i < 5; ++i) pts.emplace_back(0.05, 0.05 + 0.001 * i, 0.5);   // P
  for (int i = 0; i < 5; ++i) pts.emplace_back(0.3 + 0.001 * i, 0.05, 0.0);   // Q
  const Cloud c = cloud_of(pts);
  FarClusterOptions o;
  o.far_distance_m = 0.1;
  const auto kept_points = [&](const FarClusterScope* s) { return remove_far_clusters(c, 0.02, o, s).value.size(); };
  EXPECT_EQ(kept_points(nullptr), 300U);

  FarClusterScope whole;
  whole.main_body_min_m = Eigen::Vector3d(0.0, 0.0, 0.0);
  whole.main_body_max_m = Eigen::Vector3d(1.0, 1.0, 1.0);
  whole.points = 100000;
  const FarClusters in_body = find_far_clusters(c, 0.02, o, &whole);
  EXPECT_TRUE(in_body.others.empty()) << "every point within far - 2 sqrt(3) edges of the main body box: none linked";
  EXPECT_EQ(in_body.points_near_main_body, 310U);
  EXPECT_EQ(in_body.main_body.count, 0U);
  EXPECT_EQ(in_body.main_body.max_m, whole.main_body_max_m);
  EXPECT_EQ(kept_points(&whole), 310U);

  FarClusterScope square = whole;
  square.main_body_min_m = Eigen::Vector3d(0.0, 0.0, -0.01);
  square.main_body_max_m = Eigen::Vector3d(0.1, 0.1, 0.01);
  square.complete_xy_m = {-1.0, 0.33, -1.0, 1.0};
  const auto r = remove_far_clusters(c, 0.02, o, &square);
  EXPECT_EQ(r.value.size(), 305U);
  for (Eigen::Index i = 0; i < r.value.xyz.cols(); ++i) EXPECT_LT(r.value.xyz(2, i), 0.4) << "P went";
  EXPECT_EQ(figure(r.report, "far_clusters"), 1.0);
  EXPECT_EQ(figure(r.report, "undecided_far_clusters"), 1.0);
  EXPECT_EQ(figure(r.report, "kept_far_clusters"), 0.0);
  const FarClusters at_edge = find_far_clusters(c, 0.02, o, &square);
  ASSERT_EQ(at_edge.others.size(), 2U) << "P and Q; the square lies in the main body box, not linked";
  EXPECT_EQ(at_edge.points_near_main_body, 300U);
  std::size_t undecided = 0;
  for (const PointCluster& pc : at_edge.others) {
    if (!pc.undecided) continue;
    ++undecided;
    EXPECT_NEAR(pc.min_m.x(), 0.3, 1e-12) << "Q is the undecided one";
    EXPECT_FALSE(pc.removed);
  }
  EXPECT_EQ(undecided, 1U);
  square.complete_xy_m[1] = 0.36;
  EXPECT_EQ(kept_points(&square), 300U);
  EXPECT_EQ(figure(remove_far_clusters(c, 0.02, o, &square).report, "undecided_far_clusters"), 0.0);

  o.max_points = 4;
  square.points = 1000;
  EXPECT_EQ(kept_points(&square), 300U) << "10 points are small";
  square.points = 100;
  const auto large = remove_far_clusters(c, 0.02, o, &square);
  EXPECT_EQ(large.value.size(), 310U) << "4 points are small: P and Q are not";
  EXPECT_EQ(figure(large.report, "kept_far_clusters"), 2.0);
}

struct FarComp {
    std::size_t count = 0;
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    bool removed = false, undecided = false;
  auto key() const { return std::tuple(count, lo.x(), lo.y(), lo.z(), hi.x(), hi.y(), hi.z(), removed, undecided); }
};
// The far-cluster oracle: every finite point pair linked when their cells (edge
// max(link, extent / 2097150), on multiples of it in the frame) differ by at most one per axis, then
// the rules of FarClusterScope and remove_far_clusters on the components. Returns the far
// components (gap > far) in key order; `removed` gets the removed points' indices.
std::vector<FarComp> far_oracle(const std::vector<Eigen::Vector3d>& p, double link, double far, const FarClusterOptions& o,
                                const FarClusterScope& scope, std::vector<std::size_t>& removed) {
  Eigen::Vector3d lo = p[0], hi = p[0];
  for (const auto& q : p) {
    lo = lo.cwiseMin(q);
    hi = hi.cwiseMax(q);
  }
  const double edge = std::max({link, (hi.x() - lo.x()) / 2097150.0, (hi.y() - lo.y()) / 2097150.0, (hi.z() - lo.z()) / 2097150.0});
  std::vector<std::array<std::int64_t, 3>> cell(p.size());
  for (std::size_t i = 0; i < p.size(); ++i) {
    for (int a = 0; a < 3; ++a) cell[i][a] = static_cast<std::int64_t>(std::floor(p[i][a] * (1.0 / edge)));
  }
  std::vector<std::size_t> up(p.size());
  std::iota(up.begin(), up.end(), std::size_t{0});
  std::function<std::size_t(std::size_t)> root = [&](std::size_t i) { return up[i] == i ? i : up[i] = root(up[i]); };
  for (std::size_t i = 0; i < p.size(); ++i) {
    for (std::size_t j = i + 1; j < p.size(); ++j) {
      if (std::abs(cell[i][0] - cell[j][0]) <= 1 && std::abs(cell[i][1] - cell[j][1]) <= 1 && std::abs(cell[i][2] - cell[j][2]) <= 1) {
        up[root(i)] = root(j);
      }
    }
  }
  std::map<std::size_t, FarComp> comps;
  for (std::size_t i = 0; i < p.size(); ++i) {
    FarComp& c = comps[root(i)];
    ++c.count;
    c.lo = c.lo.cwiseMin(p[i]);
    c.hi = c.hi.cwiseMax(p[i]);
  }
  const double small = std::max(static_cast<double>(o.max_points), o.max_fraction * static_cast<double>(scope.points));
  const double reach = 2.0 * edge * (1.0 + 1e-6);
  std::vector<FarComp> far_comps;
  for (auto& [r, c] : comps) {
    const double gap = (scope.main_body_min_m - c.hi).cwiseMax(c.lo - scope.main_body_max_m).cwiseMax(0.0).norm();
    if (!(gap > far)) continue;
    if (static_cast<double>(c.count) <= small) {
      const auto& b = scope.complete_xy_m;
      const bool complete = c.lo.x() - reach >= b[0] && c.hi.x() + reach <= b[1] && c.lo.y() - reach >= b[2] && c.hi.y() + reach <= b[3];
      c.removed = complete;
      c.undecided = !complete;
    }
    far_comps.push_back(c);
  }
  removed.clear();
  for (std::size_t i = 0; i < p.size(); ++i)
    if (comps[root(i)].removed) removed.push_back(i);
  std::sort(far_comps.begin(), far_comps.end(), [](const FarComp& a, const FarComp& b) { return a.key() < b.key(); });
  return far_comps;
}

// With a scope, far-cluster removal links only the points farther than far − 2√3 cell edges
// from the main body box (find_far_clusters). The oracle links every finite point pair by pair
// (no cell table, no union of cells: two points are joined when their cells, edge
// max(link, extent / 2097150) from the box's low corner, differ by at most one per axis, the
// linking find_far_clusters documents) and applies the removal rules to the components. The
// clouds are built to cross the cut: a slab (the main body) with chains of points 1.5 cm apart
// running out of it past `far`, their outer parts small enough to be removed were they cut off
// (leaving out the points within `far` instead of far − 2√3 edges fails here), clusters just
// inside and just past `far`, an L-shaped cluster whose box comes nearer than its points, and
// scattered points; main body boxes that hold the slab or only part of it, complete boxes
// that cut some clusters off. Each case: the removed points (their columns), and the far
// components (count, box, removed, undecided) equal the oracle's.
TEST(FarClusters, AScopeLinksOnlyThePointsThatCouldBeFarAndFindsTheFarClustersOfLinkingEveryPoint) {
  const double link = 0.02;
  std::size_t cases = 0, removed_total = 0, kept_far_total = 0, left_out_total = 0;
  for (const unsigned seed : {1u, 2u, 3u, 4u, 5u, 6u}) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::vector<Eigen::Vector3d> pts;
    for (int i = 0; i < 1500; ++i) pts.emplace_back(u(rng), 0.5 * u(rng), 0.02 * u(rng));  // the slab
    const double far = seed % 2 == 0 ? 0.1 : 0.2;
    // Chains from inside the slab out past `far` in x, y and z, 1.5 cm steps (linked: adjacent
    // cells), their outer parts 3 to 8 points.
    for (int chain = 0; chain < 6; ++chain) {
      const Eigen::Vector3d dir = chain % 3 == 0 ? Eigen::Vector3d(1, 0, 0) : chain % 3 == 1 ? Eigen::Vector3d(0, 1, 0) : Eigen::Vector3d(0, 0, 1);
      const Eigen::Vector3d from = chain % 3 == 0 ? Eigen::Vector3d(0.95, 0.1 + 0.06 * chain, 0.01)
                                 : chain % 3 == 1 ? Eigen::Vector3d(0.1 + 0.13 * chain, 0.45, 0.01)
                                                  : Eigen::Vector3d(0.1 + 0.13 * chain, 0.1 + 0.05 * chain, 0.015);
      const int steps = static_cast<int>((far + 0.05 + 0.015 * (chain % 4)) / 0.015) + 3;
      for (int k = 0; k < steps; ++k) pts.push_back(from + 0.015 * k * dir);
    }
    // Clusters of 4 points 1 cm apart: at gaps far − 3 cm to far + 3 cm from the slab in -x,
    // and one in +y; an L beyond the slab's corner whose box reaches nearer than its points.
    for (int d = -3; d <= 3; ++d) {
      const double gap = far + 0.01 * d + 0.001 * seed;
      for (int k = 0; k < 4; ++k) pts.emplace_back(-gap - 0.01 * k, 0.05 + 0.06 * (d + 3), 0.01);
      for (int k = 0; k < 4; ++k) pts.emplace_back(0.05 + 0.12 * (d + 3), 0.5 + gap + 0.01 * k, 0.01);
    }
    // The L: two arms of 3 points 1.5 cm apart off the slab's (1, 0.5) corner, its box's near
    // corner (0.7 far out in x and y: a gap of 0.99 far) empty, every point more than far out.
    for (int k = 0; k < 3; ++k) pts.emplace_back(1.0 + 0.7 * far + 0.015 * k, 0.5 + 0.7 * far + 0.03, 0.01);
    for (int k = 0; k < 3; ++k) pts.emplace_back(1.0 + 0.7 * far + 0.03, 0.5 + 0.7 * far + 0.015 * k, 0.01);
    // And a cluster too large to remove (12 points) well past far.
    for (int k = 0; k < 12; ++k) pts.emplace_back(1.0 + 2.0 * far + 0.01 * k, 0.25, 0.01);
    for (int i = 0; i < 60; ++i) pts.emplace_back(-0.5 + 2.0 * u(rng), -0.5 + 1.5 * u(rng), -0.3 + 0.6 * u(rng));
    const Cloud c = cloud_of(pts);
    FarClusterOptions o;
    o.far_distance_m = far;
    o.max_points = 7;
    o.max_fraction = 0.0;
    for (int box = 0; box < 3; ++box) {
      FarClusterScope scope;
      scope.points = 100000;
      scope.main_body_min_m = Eigen::Vector3d(0.0, 0.0, 0.0);
      scope.main_body_max_m = box == 1 ? Eigen::Vector3d(0.6, 0.5, 0.02) : Eigen::Vector3d(1.0, 0.5, 0.02);
      if (box == 2) scope.complete_xy_m = {-0.25, 1.1, -1.0, 0.62};
      std::vector<std::size_t> want_removed;
      const std::vector<FarComp> want = far_oracle(pts, link, far, o, scope, want_removed);
      RemovedPoints got_removed;
      const auto r = remove_far_clusters(c, link, o, &scope, 0, &got_removed);
      const std::vector<std::size_t> got_at(got_removed.at.begin(), got_removed.at.end());
      EXPECT_EQ(got_at, want_removed) << "seed " << seed << ", box " << box;
      const FarClusters fc = find_far_clusters(c, link, o, &scope);
      std::vector<FarComp> got;
      for (const PointCluster& pc : fc.others) {
        if (!(pc.gap_m > far)) continue;
        FarComp g;
        g.count = pc.count;
        g.lo = pc.min_m;
        g.hi = pc.max_m;
        g.removed = pc.removed;
        g.undecided = pc.undecided;
        got.push_back(g);
      }
      std::sort(got.begin(), got.end(), [](const FarComp& a, const FarComp& b) { return a.key() < b.key(); });
      ASSERT_EQ(got.size(), want.size()) << "seed " << seed << ", box " << box;
      for (std::size_t i = 0; i < got.size(); ++i) EXPECT_EQ(got[i].key(), want[i].key()) << "seed " << seed << ", box " << box << ", far component " << i;
      EXPECT_GT(fc.points_near_main_body, 0U);
      EXPECT_EQ(figure(r.report, "points_near_main_body"), static_cast<double>(fc.points_near_main_body));
      ++cases;
      removed_total += want_removed.size();
      for (const FarComp& w : want) kept_far_total += w.removed ? 0 : 1;
      left_out_total += fc.points_near_main_body;
    }
  }
  // The cases are not empty: points left out, far clusters removed and kept.
  EXPECT_EQ(cases, 18U);
  EXPECT_GT(removed_total, 100U);
  EXPECT_GT(kept_far_total, 10U);
  EXPECT_GT(left_out_total, 18U * 800U);
}

// The longest link crosses the cut: a small cluster P past `far` off the main body box's
// corner, joined to the box by one step across two cell diagonals (opposite corners of
// diagonally adjacent cells, 1.96 edges per axis: 3.4 edges) to a point q, which a chain of
// short steps joins to the box. q lies beyond far − 2√3 edges (linked) but within far − 2
// edges and far − 2√3 links: leaving out the points within either of those instead (δ too
// short, or taken from the link where the cell edge is longer) cuts P off, and P, small and
// far, would be removed; linking every point (the oracle) keeps it, joined to the main body.
// Two scales: the cell edge the link (2 cm), and an edge of 4.8 cm set by a point 100 km away.
TEST(FarClusters, AClusterOneLongLinkFromAPointNearTheCutIsKeptWithTheMainBody) {
  for (const bool long_edge : {false, true}) {
    const double link = 0.02, far = long_edge ? 0.3 : 0.1;
    const int k = long_edge ? 2 : 1;  // q's cell: k cells out from the corner's, per axis
    std::vector<Eigen::Vector3d> pts;
    pts.emplace_back(-0.5, -0.5, -0.5);  // the box's low corner (a far point: removed)
    if (long_edge) pts.emplace_back(1e5, 0.0, 0.0);
    const double extent = long_edge ? 1e5 + 0.5 : 0.0;
    const double edge = std::max(link, extent / 2097150.0);
    ASSERT_EQ(edge > link, long_edge);
    // The main body box's high corner c on a cell corner (a multiple of the edge in the frame)
    // near (1, 0.5, 0.02); the slab under it.
    Eigen::Vector3d c;
    for (int a = 0; a < 3; ++a) c[a] = edge * std::round(Eigen::Vector3d(1.0, 0.5, 0.02)[a] / edge);
    for (double x = 0.0; x <= c.x(); x += 0.01)
      for (double y = 0.0; y <= c.y(); y += 0.01) pts.emplace_back(x, y, 0.5 * c.z());
    pts.push_back(c);
    const Eigen::Vector3d one(1.0, 1.0, 1.0);
    const Eigen::Vector3d q = c + edge * (k + 0.02) * one;
    for (double t = 0.01; t < edge * (k + 0.02); t += 0.01) pts.push_back(c + t * one);  // the chain to q
    pts.push_back(q);
    const Eigen::Vector3d p = c + edge * (k + 1 + 0.98) * one;
    const std::size_t p_at = pts.size();
    pts.push_back(p);
    pts.push_back(p - Eigen::Vector3d(0.001, 0.0, 0.0));
    pts.push_back(p - Eigen::Vector3d(0.0, 0.001, 0.0));
    const double dq = (q - c).norm(), dp = (p - Eigen::Vector3d(0.001, 0.0, 0.0) - c).norm();
    const double cut = far - 2.0 * std::sqrt(3.0) * edge;
    ASSERT_GT(dq, cut + 1e-4) << "q is linked";
    ASSERT_LT(dq, far - (long_edge ? 2.0 * std::sqrt(3.0) * link : 2.0 * edge)) << "q lies within the wrong cuts";
    ASSERT_GT(dp, far) << "P is far";

    FarClusterScope scope;
    scope.points = 100000;
    scope.main_body_min_m = Eigen::Vector3d::Zero();
    scope.main_body_max_m = c;
    FarClusterOptions o;
    o.far_distance_m = far;
    o.max_points = 7;
    o.max_fraction = 0.0;
    std::vector<std::size_t> want_removed;
    const std::vector<FarComp> want = far_oracle(pts, link, far, o, scope, want_removed);
    EXPECT_EQ(std::count(want_removed.begin(), want_removed.end(), p_at), 0) << "the oracle keeps P, joined to the main body";
    EXPECT_EQ(std::count(want_removed.begin(), want_removed.end(), std::size_t{0}), 1) << "and removes the corner point";
    RemovedPoints got;
    (void)remove_far_clusters(cloud_of(pts), link, o, &scope, 0, &got);
    EXPECT_EQ(std::vector<std::size_t>(got.at.begin(), got.at.end()), want_removed) << (long_edge ? "long edge" : "edge = link");
    EXPECT_GT(find_far_clusters(cloud_of(pts), link, o, &scope).points_near_main_body, pts.size() / 2);
  }
}

// A tile of a scan links its points as the whole scan does (the tiled run's far clusters per
// tile, FarClusterScope): sparse random points (mean spacing about the link, so that many pairs
// lie between one link and 2√3 cell edges apart, where the cells decide) in a 1 m × 0.6 m slab;
// parts: the points inside random x-y boxes, which start at no multiple of the edge. Every
// component of a part whose box, grown by two cell edges, lies inside the part's x-y box must
// be a component of the whole scan: the same count and box. With every point far from the
// main body box (10 m away), every point is linked and every component listed. Until the
// sixty-fourth session the cells started at each cloud's own box, and a part linked otherwise
// (seed 331 of TiledDifferential: a point alone in a tile joined the back face in core).
TEST(FarClusters, APartOfTheScanInTheSameFrameLinksItsPointsAsTheWholeScan) {
  const double link = 0.02;
  std::size_t checked = 0, single = 0;
  for (const unsigned seed : {1u, 2u, 3u, 4u}) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::vector<Eigen::Vector3d> pts;
    for (int i = 0; i < 450; ++i) pts.emplace_back(0.013 + u(rng), 0.007 + 0.6 * u(rng), 0.001 + 0.015 * u(rng));
    FarClusterOptions o;
    o.far_distance_m = 0.2;
    o.max_points = 1000000;
    FarClusterScope scope;
    scope.points = pts.size();
    scope.main_body_min_m = Eigen::Vector3d(10.0, 10.0, 10.0);
    scope.main_body_max_m = Eigen::Vector3d(10.1, 10.1, 10.1);
    const auto key = [](const PointCluster& pc) {
      return std::tuple(pc.count, pc.min_m.x(), pc.min_m.y(), pc.min_m.z(), pc.max_m.x(), pc.max_m.y(), pc.max_m.z());
    };
    std::set<decltype(key(PointCluster{}))> whole;
    const FarClusters all = find_far_clusters(cloud_of(pts), link, o, &scope);
    ASSERT_EQ(all.points_near_main_body, 0U);
    for (const PointCluster& pc : all.others) whole.insert(key(pc));
    ASSERT_GT(whole.size(), 60U) << "sparse enough to leave many components";
    for (int part = 0; part < 8; ++part) {
      const double x0 = 0.4 * u(rng), y0 = 0.15 * u(rng);
      const std::array<double, 4> box{x0, x0 + 0.3 + 0.3 * u(rng), y0, y0 + 0.25 + 0.2 * u(rng)};
      std::vector<Eigen::Vector3d> in;
      for (const auto& q : pts) {
        if (q.x() >= box[0] && q.x() <= box[1] && q.y() >= box[2] && q.y() <= box[3]) in.push_back(q);
      }
      ASSERT_GT(in.size(), 20U);
      const double reach = 2.0 * link * (1.0 + 1e-6);
      for (const PointCluster& pc : find_far_clusters(cloud_of(in), link, o, &scope).others) {
        if (pc.min_m.x() - reach < box[0] || pc.max_m.x() + reach > box[1] || pc.min_m.y() - reach < box[2] || pc.max_m.y() + reach > box[3]) continue;
        EXPECT_EQ(whole.count(key(pc)), 1U) << "seed " << seed << ", part " << part << ": a component of " << pc.count << " points at ("
                                            << pc.min_m.x() << ", " << pc.min_m.y() << ") is not one of the whole scan's";
        ++checked;
        single += pc.count == 1 ? 1U : 0U;
      }
    }
  }
  EXPECT_GT(checked, 200U);
  EXPECT_GT(single, 20U);
}

}  // namespace
namespace {

// Cells of b more than 2 mm above the clean run's grid (both valid), split by what stands there:
// `clutter` when a kept injected point (red 255) whose nearest node is within one cell of the cell
// stands more than 2 mm above the clean grid there, else `scan` (the scan's own points); and
// `extra`, cells valid in b where the clean grid has none. Same geometry required (clutter inside
// the bunny's box keeps it). `proud`: valid cells of b whose node (x, y, f) lies more than 2 mm
// from every point of the clean scan (a k-d tree over bun000, not the project's searches): a
// spike measured off the surface, not vertically. On a steep flank a cell can stand 2 mm above
// the clean grid while its node lies well within 2 mm of the scan (a slope of 3 turns a 0.5 mm
// offset along the normal into 1.6 mm vertically).
struct Above {
  std::size_t clutter = 0, scan = 0, extra = 0, proud = 0;
  std::size_t total() const { return clutter + scan; }
};
Above cells_above(const BuiltScene& clean, const BuiltScene& b) {
  const auto& va = clean.scene.layers.depth.values();
  const auto& vb = b.scene.layers.depth.values();
  EXPECT_EQ(va.size(), vb.size());
  if (va.size() != vb.size() || !b.cloud || b.cloud->rgb.size() != 3 * b.cloud->size()) {
    ADD_FAILURE() << "the runs differ in geometry (" << va.size() << " and " << vb.size()
                  << " cells), or the kept cloud carries no colour tags";
    return {va.size(), va.size(), va.size()};
  }
  // Heights in the clean run's frame: b's plus dz.
  const double dz = b.scene.provenance.recentre_offset_m.z() - clean.scene.provenance.recentre_offset_m.z();
  const auto& g = b.scene.geometry;
  std::vector<std::uint8_t> clutter_stands(va.size(), 0);
  for (Eigen::Index i = 0; i < b.cloud->xyz.cols(); ++i) {
    if (b.cloud->rgb[3 * static_cast<std::size_t>(i)] != 255) continue;
    const Eigen::Vector3d p = b.cloud->xyz.col(i);
    const long col = std::lround(std::floor((p.x() - g.x0_m) / g.cell_size_m + 0.5));
    const long row = std::lround(std::floor((p.y() - g.y0_m) / g.cell_size_m + 0.5));
    for (long r = row - 1; r <= row + 1; ++r)
      for (long c = col - 1; c <= col + 1; ++c) {
        if (r < 0 || c < 0 || r >= g.rows || c >= g.cols) continue;
        const std::size_t k = static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(c);
        if (!std::isnan(va[k]) && p.z() + dz - double(va[k]) > 0.002) clutter_stands[k] = 1;
      }
  }
  static const hc::test::KdOracle scan(bunny().xyz);
  const Eigen::Affine3d grid_to_file = b.scene.model_to_grid.inverse();
  Above out;
  for (std::size_t i = 0; i < va.size(); ++i) {
    if (std::isnan(vb[i])) continue;
    const auto row = static_cast<double>(i / static_cast<std::size_t>(g.cols)), col = static_cast<double>(i % static_cast<std::size_t>(g.cols));
    const Eigen::Vector3d node(g.x0_m + col * g.cell_size_m, g.y0_m + row * g.cell_size_m, double(vb[i]));
    if (scan.nearest(grid_to_file * node) > 0.002) ++out.proud;
    if (std::isnan(va[i])) {
      ++out.extra;
    } else if (double(vb[i]) + dz - double(va[i]) > 0.002) {
      ++(clutter_stands[i] ? out.clutter : out.scan);
    }
  }
  return out;
}

TEST(RobustOutliers, DespikeRemovesClutterThatTheNeighbourTestsKeepInFrontOfTheSurface) {
  // Oracle: the clean run's grid, the clean scan's points and the injected points' tags. Clutter
  // that survives the point tests stands in front of the surface with surface points among its
  // neighbours; the grid-level step removes what reaches the grid. Measured (bun000, N = 300,
  // 2026-11-23) at 1 / 2 / 5 % clutter:
  //  - cells whose node lies more than 2 mm from every scan point: 4 / 15 / 34 without the step,
  //    0 / 0 / 0 with it (before rim cells were judged: 4 / 4 / 6 with it, strays just beyond a
  //    silhouette; this test fails there);
  //  - cells > 2 mm above the clean grid where clutter stands: 3 / 10 / 31 without, 0 / 0 / 1
  //    with (before the trimmed plane and the lone peaks: 0 / 2 / 6).
  // The one such cell left at 5 % (row 90, col 269) lies on a steep flank (slope about 3) at a
  // depth edge: a stray 0.4 mm from a scan point (about 0.45 mm from the surface along its
  // normal) fills an empty cell, and its disc hides the measured cell beside it, 4.7 mm higher
  // vertically, while that node stays 1.0 mm from the scan. Each run against the clean scan run
  // the same way.
  const BuiltScene& clean = clean_run();
  const BuiltScene clean_off = run_on(bunny(), "clean_despike_off", "{enabled: true, despike: false}");
  EXPECT_EQ(cells_above(clean, clean).proud, 0u);  // the clean grid itself lies on the scan
  EXPECT_EQ(cells_above(clean_off, clean_off).proud, 0u);
  for (const double share : {0.01, 0.02, 0.05}) {
    const auto count = static_cast<std::size_t>(share * static_cast<double>(bunny().size()));
    const Cloud c = with_extra(bunny(), uniform_in_box(count, 5));
    const Above with = cells_above(clean, run_on(c, "despike_on"));
    const Above without = cells_above(clean_off, run_on(c, "despike_off", "{enabled: true, despike: false}"));
    EXPECT_GT(without.clutter, 0u) << share << ": the case no longer tests the step";
    EXPECT_GT(without.proud, 0u) << share << ": the case no longer tests the step";
    EXPECT_EQ(with.proud, 0u) << share;  // no spike off the surface reaches the grid
    if (share <= 0.02) {
      EXPECT_EQ(with.clutter, 0u) << share;
    } else {
      EXPECT_LE(with.clutter, without.clutter / 10) << share;  // at least 90 % of the spikes go
    }
    EXPECT_LE(with.total(), without.total() / 3) << share;
    EXPECT_LE(with.extra, without.extra) << share;
    const std::string pc = std::to_string(int(share * 100));
    RecordProperty("above_clutter_with_" + pc, std::to_string(with.clutter));
    RecordProperty("above_scan_with_" + pc, std::to_string(with.scan));
    RecordProperty("above_clutter_without_" + pc, std::to_string(without.clutter));
    RecordProperty("above_scan_without_" + pc, std::to_string(without.scan));
    RecordProperty("proud_with_" + pc, std::to_string(with.proud));
    RecordProperty("proud_without_" + pc, std::to_string(without.proud));
  }
  // The clean scan: the step ran and removed at most 0.5 % of it.
  std::size_t despike_stages = 0;
  for (const auto& st : clean.summary.stages) {
    if (st.stage != "despike") continue;
    ++despike_stages;
    EXPECT_LE(figure(st, "removed_spike_points"), 0.005 * static_cast<double>(bunny().size()));
  }
  EXPECT_EQ(despike_stages, 1u);
}

}  // namespace
