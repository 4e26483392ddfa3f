// μ_d per level of detail on the shared scans (issue "A surface you can trust", friction part):
// at every level no more than half of the valid cells may sit at either clamp, so the map carries
// information. Oracle: the clamp counts are taken here directly from each level's μ_d layer
// against the run config's own μ_min and μ_max.

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/surface_layers.hpp"

#include "test_paths.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numbers>
#include <random>
#include <vector>
#include <memory>
#include <string>

namespace {

using namespace hc::pipeline;

struct ClampCounts {
  std::size_t valid = 0, at_min = 0, at_max = 0;
};

ClampCounts count_clamps(const hc::HeightField& mu_d, double mu_min, double mu_max) {
  ClampCounts c;
  for (float v : mu_d.values()) {
    if (std::isnan(v)) continue;
    ++c.valid;
    // μ_d is stored as float: a clamped cell holds float(μ_min) or float(μ_max).
    if (v <= static_cast<float>(mu_min)) ++c.at_min;
    if (v >= static_cast<float>(mu_max)) ++c.at_max;
  }
  return c;
}

/// Builds the scene of a config under configs/, then checks every level of its pyramid.
void expect_informative_friction_at_every_level(const std::string& config_name, const std::string& scan) {
  (void)hc::test::scan_path(scan);  // fails the test plainly when the scan is missing
  const std::filesystem::path config_path = std::filesystem::path(HC_SOURCE_DIR) / "configs" / config_name;
  const RunConfig config = load_run_config(config_path);
  BuiltScene built = build_scene(config);
  const double mu_min = built.scene.layer_options.mu_min;
  const double mu_max = built.scene.layer_options.mu_max;
  const hc::SurfaceLayerOptions layer_options = built.scene.layer_options;
  const hc::LodOptions lod = built.scene.lod;
  auto pyramid = LodPyramid::from_scene(std::move(built.scene), layer_options, lod);
  ASSERT_GE(pyramid->level_count(), 2) << config_name;
  for (int level = 0; level < pyramid->level_count(); ++level) {
    const auto lvl = pyramid->level(level);
    ASSERT_TRUE(lvl->has_layers);
    const ClampCounts c = count_clamps(lvl->mu_d, mu_min, mu_max);
    ASSERT_GT(c.valid, 0U) << config_name << " level " << level;
    const double f_min = static_cast<double>(c.at_min) / static_cast<double>(c.valid);
    const double f_max = static_cast<double>(c.at_max) / static_cast<double>(c.valid);
    EXPECT_LE(f_min, 0.5) << config_name << " level " << level << ": " << c.at_min << " of " << c.valid
                          << " valid cells at mu_min = " << mu_min;
    EXPECT_LE(f_max, 0.5) << config_name << " level " << level << ": " << c.at_max << " of " << c.valid
                          << " valid cells at mu_max = " << mu_max;
  }
}

hc::GridGeometry square_grid(int n, double cell_m) {
  hc::GridGeometry g;
  g.rows = n;
  g.cols = n;
  g.cell_size_m = cell_m;
  return g;
}

constexpr double kPi = std::numbers::pi;

// ---------------------------------------------------------------- device scale, by hand

TEST(FrictionLevels, DeviceScaleMapsTheWindowOntoTheWorkspaceDiameter) {
  // 200-sample window of 0.5 mm cells spans 199 · 0.5 mm = 99.5 mm; 2R = 100 mm.
  EXPECT_DOUBLE_EQ(device_scale(0.05, 200, 0.5e-3), 0.1 / 0.0995);
  // Level 3 of the same grid: cells 8× larger, the device sees them 8× smaller.
  EXPECT_DOUBLE_EQ(device_scale(0.05, 200, 4e-3), 0.1 / 0.796);
  EXPECT_DOUBLE_EQ(device_scale(0.02, 101, 1e-3), 0.04 / 0.1);
  EXPECT_THROW((void)device_scale(0.05, 1, 1e-3), hc::ConfigError);
  EXPECT_THROW((void)device_scale(0.0, 200, 1e-3), hc::ConfigError);
  EXPECT_THROW((void)device_scale(0.05, 200, 0.0), hc::ConfigError);
}

TEST(FrictionLevels, ScaleNamesRoundTripAndUnknownNamesAreRefused) {
  for (hc::FrictionScale s : {hc::FrictionScale::kScene, hc::FrictionScale::kDevice, hc::FrictionScale::kLevelMedian}) {
    EXPECT_EQ(friction_scale_from_string(to_string(s)), s);
  }
  try {
    (void)friction_scale_from_string("metres");
    FAIL() << "no exception";
  } catch (const hc::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("layers.friction.scale = 'metres'"), std::string::npos) << e.what();
  }
}

// ---------------------------------------------------------------- analytic texture, device units

/// Response of OpenCV's bilateral spatial kernel (disc of radius ⌈2σ_s⌉ cells, Gaussian weights;
/// the range kernel is 1 when σ_r ≫ the relief) to sin(kx)·sin(ky), by brute force:
/// g = Σ w·cos(k·i·Δ)·cos(k·j·Δ) / Σ w.
double bilateral_gain(double sigma_cells, double k_per_cell) {
  const int radius = static_cast<int>(std::ceil(2.0 * sigma_cells));
  double num = 0.0, den = 0.0;
  for (int i = -radius; i <= radius; ++i) {
    for (int j = -radius; j <= radius; ++j) {
      if (i * i + j * j > radius * radius) continue;
      const double w = std::exp(-0.5 * (i * i + j * j) / (sigma_cells * sigma_cells));
      num += w * std::cos(k_per_cell * i) * std::cos(k_per_cell * j);
      den += w;
    }
  }
  return num / den;
}

TEST(FrictionLevels, DeviceUnitsOnAnAnalyticSinusoidFollowThePaperAndCurvatureFormulas) {
  // f = A·sin(kx)·sin(ky), λ = 40 cells of 0.5 mm, A = 1 mm; σ_r = 10 m ≫ A, so the envelope is a
  // Gaussian-weighted mean and the texture is the exact sinusoid (1 − g)·f. At a crest
  // (x = y = λ/4): h_x = h_y = h_xy = 0, h_xx = h_yy = −A'k², so H = −A'k² [1/m], K = A'²k⁴ [1/m²].
  // In device units with σ device m per grid m: H_dev = H/σ, K_dev = K/σ².
  const double cell = 0.5e-3, lambda = 40 * cell, amp = 1e-3, k = 2 * kPi / lambda;
  const int n = 161;  // four periods
  hc::HeightField f(square_grid(n, cell));
  for (int r = 0; r < n; ++r) {
    for (int c = 0; c < n; ++c) f.at(r, c) = static_cast<float>(amp * std::sin(k * c * cell) * std::sin(k * r * cell));
  }
  hc::SurfaceLayerOptions o;
  o.sigma_space_cells = 8.0;
  o.sigma_range_m = 10.0;
  o.mu_min = 0.001;
  o.mu_max = 5.0;
  o.workspace_radius_m = 0.05;
  o.curvature_gain_m = 1e-3;
  o.friction_scale = hc::FrictionScale::kDevice;
  const int window_cells = 101;  // σ = 0.1 / (100 · 0.5 mm) = 2
  const double sigma = 2.0;
  const double a_tex = (1.0 - bilateral_gain(o.sigma_space_cells, k * cell)) * amp;
  const double H_dev = -a_tex * k * k / sigma, K_dev = a_tex * a_tex * k * k * k * k / (sigma * sigma);
  const double s_dev = std::hypot(H_dev, K_dev);
  const int crest = 50;  // x = y = 50 cells = 1.25 λ: sin = 1, interior
  for (hc::FrictionModel model : {hc::FrictionModel::kPaper, hc::FrictionModel::kCurvature}) {
    o.friction_model = model;
    const auto L = compute_surface_layers(f, o, window_cells).value;
    const double expected = model == hc::FrictionModel::kPaper ? 1.0 / (o.workspace_radius_m * s_dev)
                                                               : o.mu_min + o.curvature_gain_m * s_dev;
    ASSERT_GT(expected, o.mu_min * 1.5);
    ASSERT_LT(expected, o.mu_max / 1.5);
    // Finite differences at 40 cells per period: second derivatives within (kΔ)²/12 ≈ 0.2 %.
    EXPECT_NEAR(L.mu_d.at(crest, crest), expected, 0.015 * expected) << to_string(model);
    // Scene units would be a different number (σ = 2 enters as 1/σ and 1/σ²).
    const double s_scene = std::hypot(H_dev * sigma, K_dev * sigma * sigma);
    const double scene_value = model == hc::FrictionModel::kPaper ? 1.0 / (o.workspace_radius_m * s_scene)
                                                                  : o.mu_min + o.curvature_gain_m * s_scene;
    EXPECT_GT(std::abs(scene_value - expected), 0.2 * expected) << to_string(model);
  }
}

TEST(FrictionLevels, DeviceUnitsEqualSceneUnitsOfTheSurfaceScaledIntoTheWorkspace) {
  // Property: μ_d in device units on grid G equals μ_d in scene units on G scaled by σ
  // (cell size and heights × σ, σ_r × σ so the envelope is the same shape).
  const double cell = 0.4e-3;
  const int n = 90, window_cells = 51;
  const double sigma = device_scale(0.05, window_cells, cell);
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 20e-6);
  hc::HeightField f(square_grid(n, cell)), fs(square_grid(n, cell * sigma));
  for (int r = 0; r < n; ++r) {
    for (int c = 0; c < n; ++c) {
      const double z = 0.01 + 0.05 * c * cell + 0.2e-3 * std::sin(c * 0.5) * std::cos(r * 0.3) + noise(rng);
      f.at(r, c) = static_cast<float>(z);
      fs.at(r, c) = static_cast<float>(z * sigma);
    }
  }
  f.at(40, 40) = hc::kNoData;
  fs.at(40, 40) = hc::kNoData;
  for (hc::FrictionModel model : {hc::FrictionModel::kPaper, hc::FrictionModel::kCurvature}) {
    hc::SurfaceLayerOptions od;
    od.friction_model = model;
    od.sigma_range_m = 1e-3;
    od.curvature_gain_m = 1e-4;
    od.friction_scale = hc::FrictionScale::kDevice;
    hc::SurfaceLayerOptions os = od;
    os.friction_scale = hc::FrictionScale::kScene;
    os.sigma_range_m = od.sigma_range_m * sigma;
    const auto Ld = compute_surface_layers(f, od, window_cells).value;
    const auto Ls = compute_surface_layers(fs, os, window_cells).value;
    std::size_t inside = 0;
    for (std::size_t i = 0; i < f.values().size(); ++i) {
      const float a = Ld.mu_d.values()[i], b = Ls.mu_d.values()[i];
      if (std::isnan(a) || std::isnan(b)) {
        ASSERT_TRUE(std::isnan(a) && std::isnan(b)) << i;
        continue;
      }
      // Float rounding of the scaled heights and OpenCV's range table: measured ≤ 0.4 %. Scene
      // units on the unscaled grid would differ by the factor σ = 5 in H and 25 in K.
      ASSERT_NEAR(a, b, 1e-2 * b) << "cell " << i << " " << to_string(model);
      inside += (a > od.mu_min * 1.01 && a < od.mu_max * 0.99) ? 1U : 0U;
    }
    EXPECT_GT(inside, f.values().size() / 10) << to_string(model) << ": too few unclamped cells to prove anything";
  }
}

TEST(FrictionLevels, LevelMedianPutsTheMedianCellMidRangeAndKeepsBothClampsUnderHalf) {
  // A rough surface whose curvature spans decades; the level_median scale must leave at most half
  // of the cells at either clamp, and (the paper model falls with s) the median μ_d must be the
  // geometric mid √(μ_min·μ_max), the curvature model's the arithmetic mid.
  const int n = 120;
  std::mt19937 rng(3);
  std::lognormal_distribution<double> amp(std::log(30e-6), 1.5);
  hc::HeightField f(square_grid(n, 0.5e-3));
  for (int r = 0; r < n; ++r) {
    for (int c = 0; c < n; ++c) {
      const double a = amp(rng);
      f.at(r, c) = static_cast<float>(0.02 + a * std::sin(0.7 * c + 0.2 * r) * std::sin(0.4 * r));
    }
  }
  for (hc::FrictionModel model : {hc::FrictionModel::kPaper, hc::FrictionModel::kCurvature}) {
    hc::SurfaceLayerOptions o;
    o.friction_model = model;
    o.friction_scale = hc::FrictionScale::kLevelMedian;
    o.workspace_radius_m = 0.05;
    const auto res = compute_surface_layers(f, o, 200);
    const SurfaceLayers& L = res.value;
    // The texture's median curvature must lie above the flatness floor 1/(R·μ_max), or the floor
    // (not the median) sets the scale.
    double s_median = 0.0, s_reference = 0.0;
    for (const auto& [key, v] : res.report.figures) {
      if (key == "friction_s_median") s_median = v;
      if (key == "friction_s_reference") s_reference = v;
    }
    ASSERT_GT(s_median, 1.0 / (o.workspace_radius_m * o.mu_max));
    ASSERT_EQ(s_reference, s_median);
    const ClampCounts c = count_clamps(L.mu_d, o.mu_min, o.mu_max);
    EXPECT_LE(static_cast<double>(c.at_min) / static_cast<double>(c.valid), 0.5) << to_string(model);
    EXPECT_LE(static_cast<double>(c.at_max) / static_cast<double>(c.valid), 0.5) << to_string(model);
    std::vector<float> mu(L.mu_d.values().begin(), L.mu_d.values().end());
    std::nth_element(mu.begin(), mu.begin() + static_cast<std::ptrdiff_t>(mu.size() / 2), mu.end());
    const double median = mu[mu.size() / 2];
    const double mid = model == hc::FrictionModel::kPaper ? std::sqrt(o.mu_min * o.mu_max) : 0.5 * (o.mu_min + o.mu_max);
    EXPECT_NEAR(median, mid, 0.01 * mid) << to_string(model);
    const FrictionHistogram h = friction_histogram(L.mu_d, o.mu_min, o.mu_max);
    EXPECT_EQ(h.valid, c.valid);
    EXPECT_EQ(h.at_min, c.at_min);
    EXPECT_EQ(h.at_max, c.at_max);
    std::size_t binned = 0;
    for (std::size_t b : h.bins) binned += b;
    EXPECT_EQ(binned + h.at_min + h.at_max, h.valid);
  }
}

// ---------------------------------------------------------------- the shared scans

TEST(FrictionLevels, BunnyAtMostHalfTheCellsAtEitherClampOnEveryLevel) {
  expect_informative_friction_at_every_level("bunny.yaml", "bunny/bun000.ply");
}

TEST(FrictionLevels, HappyBuddhaAtMostHalfTheCellsAtEitherClampOnEveryLevel) {
  expect_informative_friction_at_every_level("happy_buddha.yaml", "happy_buddha/happy_stand_merged_1099005pts.ply.gz");
}

}  // namespace
