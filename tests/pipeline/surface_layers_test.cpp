#include "hc/pipeline/surface_layers.hpp"

#include "hc/common/error.hpp"
#include "stage_figure.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <numbers>
#include <string>
#include <vector>

namespace hc::pipeline {
namespace {

using hc::test::figure;

constexpr double kPi = std::numbers::pi;

GridGeometry square_grid(int n, double cell_m, double x0_m = 0.0, double y0_m = 0.0) {
  GridGeometry g;
  g.rows = n;
  g.cols = n;
  g.cell_size_m = cell_m;
  g.x0_m = x0_m;
  g.y0_m = y0_m;
  return g;
}

/// A grid sampled from z(x, y); cells where hole(x, y) is true get no data.
HeightField sample(const GridGeometry& g, const std::function<double(double, double)>& z,
                   const std::function<bool(double, double)>& hole = {}) {
  HeightField f(g);
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      const double x = g.x_of_col(c), y = g.y_of_row(r);
      if (hole && hole(x, y)) continue;
      f.at(r, c) = static_cast<float>(z(x, y));
    }
  }
  return f;
}

void expect_nan_pattern(const HeightField& layer, const HeightField& depth, const char* what) {
  ASSERT_EQ(layer.geometry(), depth.geometry()) << what;
  for (int r = 0; r < depth.rows(); ++r) {
    for (int c = 0; c < depth.cols(); ++c) {
      if (depth.valid(r, c)) {
        ASSERT_TRUE(std::isfinite(layer.at(r, c))) << what << " at " << r << "," << c;
      } else {
        ASSERT_TRUE(std::isnan(layer.at(r, c))) << what << " at " << r << "," << c;
      }
    }
  }
}

TEST(SurfaceLayers, FrictionModelNamesRoundTrip) {
  EXPECT_EQ(friction_model_from_string("paper"), FrictionModel::kPaper);
  EXPECT_EQ(friction_model_from_string("curvature"), FrictionModel::kCurvature);
  EXPECT_EQ(to_string(FrictionModel::kPaper), "paper");
  EXPECT_EQ(to_string(FrictionModel::kCurvature), "curvature");
  try {
    friction_model_from_string("Paper ");
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("'Paper '"), std::string::npos) << msg;
    EXPECT_NE(msg.find("paper, curvature"), std::string::npos) << msg;
  }
}

TEST(SurfaceLayers, RejectsOutOfRangeOptionsNamingThem) {
  const HeightField f = sample(square_grid(8, 1e-3), [](double, double) { return 0.1; });
  struct Case {
    std::function<void(SurfaceLayerOptions&)> edit;
    std::string name;
  };
  const std::vector<Case> cases = {
      {[](SurfaceLayerOptions& o) { o.sigma_space_cells = 0.0; }, "sigma_space_cells"},
      {[](SurfaceLayerOptions& o) { o.sigma_space_cells = std::nan(""); }, "sigma_space_cells"},
      {[](SurfaceLayerOptions& o) { o.sigma_space_cells = 101.0; }, "sigma_space_cells"},
      {[](SurfaceLayerOptions& o) { o.sigma_range_m = -1e-3; }, "sigma_range_m"},
      {[](SurfaceLayerOptions& o) { o.mu_min = -0.1; }, "mu_min"},
      {[](SurfaceLayerOptions& o) { o.mu_max = o.mu_min / 2; }, "mu_max"},
      {[](SurfaceLayerOptions& o) { o.workspace_radius_m = 0.0; }, "workspace_radius_m"},
      {[](SurfaceLayerOptions& o) { o.curvature_gain_m = -1.0; }, "curvature_gain_m"},
      {[](SurfaceLayerOptions& o) { o.mu_s = std::numeric_limits<double>::infinity(); }, "mu_s"},
      {[](SurfaceLayerOptions& o) { o.mu_s_regions = {{0.0, 0.0, -1.0, 1.0, 0.3}}; }, "mu_s_regions[0].x_max_m"},
      {[](SurfaceLayerOptions& o) { o.mu_s_regions = {{0.0, 0.0, 1.0, 1.0, 0.3}, {0, 0, 1, 1, -2}}; },
       "mu_s_regions[1].mu_s"},
  };
  for (const Case& c : cases) {
    SurfaceLayerOptions o;
    c.edit(o);
    try {
      compute_surface_layers(f, o);
      ADD_FAILURE() << "expected ConfigError for " << c.name;
    } catch (const ConfigError& e) {
      const std::string msg = e.what();
      EXPECT_NE(msg.find(c.name), std::string::npos) << msg;
      EXPECT_NE(msg.find("expected"), std::string::npos) << msg;
    }
  }
}

TEST(SurfaceLayers, RejectsGridsWithoutData) {
  EXPECT_THROW(compute_surface_layers(HeightField(square_grid(5, 1e-3)), {}), InputError);
  HeightField f = sample(square_grid(5, 1e-3), [](double, double) { return 0.0; });
  f.at(2, 3) = std::numeric_limits<float>::infinity();
  try {
    compute_surface_layers(f, {});
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("(2, 3)"), std::string::npos) << e.what();
  }
}

// A tilted plane with a big hole (and the grid border): holes must not bias the envelope.
TEST(SurfaceLayers, EnvelopeOfPlaneIsExactNextToHolesAndBorder) {
  const GridGeometry g = square_grid(120, 0.5e-3, -0.03, -0.03);
  auto plane = [](double x, double y) { return 0.08 + 0.4 * x - 0.25 * y; };
  // Disc hole of radius 12 mm; "behind" it the scanned object would be 50 mm lower, but the
  // grid only knows it as no data.
  auto hole = [](double x, double y) { return x * x + y * y < 0.012 * 0.012; };
  const HeightField f = sample(g, plane, hole);
  ASSERT_LT(f.valid_count(), g.cell_count());
  SurfaceLayerOptions o;
  o.sigma_space_cells = 3.0;
  o.sigma_range_m = 0.002;
  const auto res = compute_surface_layers(f, o);
  const SurfaceLayers& L = res.value;
  expect_nan_pattern(L.envelope_m, f, "envelope");
  expect_nan_pattern(L.texture_m, f, "texture");
  double worst = 0.0;
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      if (!f.valid(r, c)) continue;
      worst = std::max(worst, std::abs(L.envelope_m.at(r, c) - plane(g.x_of_col(c), g.y_of_row(r))));
      // h is formed relative to the mean height (finer than float metres), hence NEAR.
      ASSERT_NEAR(L.texture_m.at(r, c), f.at(r, c) - L.envelope_m.at(r, c), 2e-8) << r << "," << c;
    }
  }
  // Float data of about 0.1 m: a few ULP (measured 1.1e-8 m); a zeroth-order fill (masked
  // average) would be off by ~0.8·slope·σ_s·cell ≈ 0.5 mm next to the hole.
  EXPECT_LT(worst, 5e-8);
  EXPECT_LT(figure(res.report, "texture_rms_mm"), 1e-4);
}

// Scattered single-cell holes and isolated valid cells: NaN never spreads, nothing is biased.
TEST(SurfaceLayers, ScatteredHolesAndIsolatedCellsStayFinite) {
  const GridGeometry g = square_grid(60, 1e-3);
  auto z = [](double x, double y) { return 0.05 + 0.002 * std::sin(300 * x) * std::cos(200 * y); };
  HeightField f = sample(g, z, [](double x, double y) {
    const int c = static_cast<int>(std::lround(x * 1e3)), r = static_cast<int>(std::lround(y * 1e3));
    return (r * 7 + c * 13) % 5 == 0 || (r > 40 && (r + c) % 2 == 0);
  });
  const auto res = compute_surface_layers(f, {});
  const SurfaceLayers& L = res.value;
  for (const HeightField* layer : {&L.envelope_m, &L.texture_m, &L.mean_curvature_per_m,
                                   &L.gaussian_curvature_per_m2, &L.mu_d, &L.mu_s}) {
    expect_nan_pattern(*layer, f, "layer");
  }
  // Valid cells without a valid 4-neighbour (the checkerboard rows) have no stencil: H = K = 0.
  int isolated = 0;
  for (int r = 42; r < g.rows - 1; ++r) {
    for (int c = 1; c < g.cols - 1; ++c) {
      if (!f.valid(r, c) || f.valid(r, c - 1) || f.valid(r, c + 1) || f.valid(r - 1, c) || f.valid(r + 1, c)) continue;
      ++isolated;
      EXPECT_EQ(L.mean_curvature_per_m.at(r, c), 0.0f);
      EXPECT_EQ(L.gaussian_curvature_per_m2.at(r, c), 0.0f);
    }
  }
  EXPECT_GT(isolated, 100);
  EXPECT_GT(figure(res.report, "curvature_zero_fallback_cells"), 0.0);
}

// Edge preservation: a 20 mm step with σ_r = 1 mm stays in the envelope, not in the texture.
TEST(SurfaceLayers, EnvelopeKeepsAStepMuchHigherThanSigmaRange) {
  const GridGeometry g = square_grid(40, 1e-3);
  const HeightField f = sample(g, [](double x, double) { return x < 0.0195 ? 0.10 : 0.12; });
  SurfaceLayerOptions o;
  o.sigma_range_m = 0.001;
  const auto res = compute_surface_layers(f, o);
  float worst = 0.0f;
  for (float h : res.value.texture_m.values()) worst = std::max(worst, std::abs(h));
  EXPECT_LT(worst, 1e-6f);
}

// Without holes and away from the border the envelope is the textbook bilateral filter
// (Tomasi & Manduchi): brute-force oracle over the circular window of radius ⌈2σ_s⌉.
TEST(SurfaceLayers, EnvelopeMatchesBruteForceBilateralInTheInterior) {
  const GridGeometry g = square_grid(40, 0.5e-3);
  auto z = [](double x, double y) {
    return 0.2 + 0.05 * x + 0.0007 * std::sin(2100 * x + 300 * y) + 0.0004 * std::cos(3700 * y);
  };
  const HeightField f = sample(g, z);
  SurfaceLayerOptions o;
  o.sigma_space_cells = 2.0;
  o.sigma_range_m = 0.0005;
  const auto res = compute_surface_layers(f, o);
  const int rad = 4;
  double worst = 0.0;
  for (int r = rad; r < g.rows - rad; ++r) {
    for (int c = rad; c < g.cols - rad; ++c) {
      double num = 0.0, den = 0.0;
      const double f0 = f.at(r, c);
      for (int dr = -rad; dr <= rad; ++dr) {
        for (int dc = -rad; dc <= rad; ++dc) {
          if (std::sqrt(dr * dr + dc * dc) > rad) continue;
          const double v = f.at(r + dr, c + dc);
          const double w = std::exp(-0.5 * (dr * dr + dc * dc) / (o.sigma_space_cells * o.sigma_space_cells)) *
                           std::exp(-0.5 * (v - f0) * (v - f0) / (o.sigma_range_m * o.sigma_range_m));
          num += w * v;
          den += w;
        }
      }
      worst = std::max(worst, std::abs(res.value.envelope_m.at(r, c) - num / den));
    }
  }
  // OpenCV tabulates the range kernel (4096 steps over the data range): sub-micrometre agreement.
  EXPECT_LT(worst, 5e-8);
}

// Fine sinusoidal texture on a slope: the texture layer recovers it (rms A/2 for A·sin·sin).
TEST(SurfaceLayers, TextureRecoversFineSinusoidOnASlope) {
  const GridGeometry g = square_grid(100, 0.25e-3);
  const double A = 0.1e-3, lambda = 1e-3;  // 4 cells per period
  const double k = 2 * kPi / lambda;
  const HeightField f =
      sample(g, [&](double x, double y) { return 0.1 + 0.3 * x + A * std::sin(k * x) * std::sin(k * y); });
  SurfaceLayerOptions o;
  o.sigma_space_cells = 3.0;
  o.sigma_range_m = 0.01;  // ≫ A: close to a Gaussian low-pass
  const auto res = compute_surface_layers(f, o);
  EXPECT_NEAR(figure(res.report, "texture_rms_mm"), 1e3 * A / 2, 0.1 * 1e3 * A / 2);
}

// Paraboloid h = a·x² + b·y² + c·x·y: the finite differences are exact for quadratics, including
// the one-sided stencils at the border and next to holes.
TEST(SurfaceLayers, CurvatureOfParaboloidIsExactEverywhere) {
  const GridGeometry g = square_grid(41, 0.5e-3, -0.01, -0.008);
  const double a = 20.0, b = -12.0, c = 7.0;  // [1/m]
  auto h = [&](double x, double y) { return a * x * x + b * y * y + c * x * y; };
  auto hole = [](double x, double y) { return std::abs(x - 0.002) < 0.0016 && std::abs(y) < 0.0011; };
  const HeightField f = sample(g, h, hole);
  const Curvature cv = compute_curvature(f);
  EXPECT_EQ(cv.zero_fallback_cells, 0U);
  double worst_h = 0.0, worst_k = 0.0, max_h = 0.0, max_k = 0.0;
  for (int r = 0; r < g.rows; ++r) {
    for (int col = 0; col < g.cols; ++col) {
      if (!f.valid(r, col)) {
        EXPECT_TRUE(std::isnan(cv.mean_per_m.at(r, col)));
        EXPECT_TRUE(std::isnan(cv.gaussian_per_m2.at(r, col)));
        continue;
      }
      const double x = g.x_of_col(col), y = g.y_of_row(r);
      const double hx = 2 * a * x + c * y, hy = 2 * b * y + c * x, hxx = 2 * a, hyy = 2 * b, hxy = c;
      const double q = 1 + hx * hx + hy * hy;
      const double H = (hxx * (1 + hy * hy) + hyy * (1 + hx * hx) - 2 * hxy * hx * hy) / (2 * std::pow(q, 1.5));
      const double K = (hxx * hyy - hxy * hxy) / (q * q);
      worst_h = std::max(worst_h, std::abs(cv.mean_per_m.at(r, col) - H));
      worst_k = std::max(worst_k, std::abs(cv.gaussian_per_m2.at(r, col) - K));
      max_h = std::max(max_h, std::abs(H));
      max_k = std::max(max_k, std::abs(K));
    }
  }
  EXPECT_LT(worst_h, 2e-3 * max_h);
  EXPECT_LT(worst_k, 2e-3 * max_k);
}

// Sinusoidal texture h = A·sin(kx)·sin(ky) (the paper's validation surface), 40 cells per period:
// H and K within a few % of the exact values away from the border.
TEST(SurfaceLayers, CurvatureOfSinusoidMatchesAnalyticValues) {
  const GridGeometry g = square_grid(120, 0.25e-3);
  const double A = 0.5e-3, lambda = 40 * 0.25e-3, k = 2 * kPi / lambda;
  const HeightField f = sample(g, [&](double x, double y) { return A * std::sin(k * x) * std::sin(k * y); });
  const Curvature cv = compute_curvature(f);
  double worst_h = 0.0, worst_k = 0.0, max_h = 0.0, max_k = 0.0;
  for (int r = 2; r < g.rows - 2; ++r) {
    for (int col = 2; col < g.cols - 2; ++col) {
      const double x = g.x_of_col(col), y = g.y_of_row(r);
      const double sx = std::sin(k * x), cx = std::cos(k * x), sy = std::sin(k * y), cy = std::cos(k * y);
      const double hx = A * k * cx * sy, hy = A * k * sx * cy;
      const double hxx = -A * k * k * sx * sy, hyy = hxx, hxy = A * k * k * cx * cy;
      const double q = 1 + hx * hx + hy * hy;
      const double H = (hxx * (1 + hy * hy) + hyy * (1 + hx * hx) - 2 * hxy * hx * hy) / (2 * std::pow(q, 1.5));
      const double K = (hxx * hyy - hxy * hxy) / (q * q);
      worst_h = std::max(worst_h, std::abs(cv.mean_per_m.at(r, col) - H));
      worst_k = std::max(worst_k, std::abs(cv.gaussian_per_m2.at(r, col) - K));
      max_h = std::max(max_h, std::abs(H));
      max_k = std::max(max_k, std::abs(K));
    }
  }
  ASSERT_GT(max_h, 100.0);  // A·k² ≈ 197 /m: a real test, not a flat one
  EXPECT_LT(worst_h, 0.03 * max_h);
  EXPECT_LT(worst_k, 0.03 * max_k);
}

TEST(SurfaceLayers, CurvatureUsesTheRealCellSize) {
  // The same samples on a grid twice as coarse: h_xx quarters, so H quarters (small slopes).
  const auto make = [](double cell) {
    HeightField f(square_grid(21, cell));
    for (int r = 0; r < 21; ++r)
      for (int c = 0; c < 21; ++c) f.at(r, c) = static_cast<float>(1e-7 * ((c - 10) * (c - 10) + (r - 10) * (r - 10)));
    return compute_curvature(f);
  };
  const Curvature fine = make(1e-3), coarse = make(2e-3);
  EXPECT_NEAR(fine.mean_per_m.at(10, 10), 0.2, 1e-4);  // H = (h_xx + h_yy)/2 = 2e-7/Δ²
  EXPECT_NEAR(coarse.mean_per_m.at(10, 10), 0.05, 1e-4);
}

TEST(SurfaceLayers, FlatTextureGivesMuMaxInPaperAndMuMinInCurvatureModel) {
  const GridGeometry g = square_grid(30, 1e-3);
  for (auto z : std::vector<std::function<double(double, double)>>{
           [](double, double) { return 0.1; }, [](double x, double y) { return 0.1 + 0.5 * x - 0.2 * y; }}) {
    const HeightField f = sample(g, z, [](double x, double y) { return x > 0.02 && y > 0.02; });
    SurfaceLayerOptions o;
    o.mu_min = 0.1;
    o.mu_max = 0.7;
    o.friction_model = FrictionModel::kPaper;
    const auto paper = compute_surface_layers(f, o);
    o.friction_model = FrictionModel::kCurvature;
    const auto curv = compute_surface_layers(f, o);
    EXPECT_EQ(paper.value.friction_model, FrictionModel::kPaper);
    EXPECT_EQ(curv.value.friction_model, FrictionModel::kCurvature);
    expect_nan_pattern(paper.value.mu_d, f, "mu_d paper");
    expect_nan_pattern(curv.value.mu_d, f, "mu_d curvature");
    for (std::size_t i = 0; i < g.cell_count(); ++i) {
      if (std::isnan(f.values()[i])) continue;
      EXPECT_FLOAT_EQ(paper.value.mu_d.values()[i], 0.7f);
      // The tilted plane leaves float rounding (~1 nm) in h: |H| up to ~0.05 /m, μ within 1e-3.
      EXPECT_NEAR(curv.value.mu_d.values()[i], 0.1f, 1e-3f);
    }
    EXPECT_FLOAT_EQ(static_cast<float>(figure(paper.report, "mu_d_median")), 0.7f);
  }
  // μ_min = μ_max = 0 in the paper model: no division by zero.
  const HeightField flat = sample(g, [](double, double) { return 0.0; });
  SurfaceLayerOptions o;
  o.mu_min = o.mu_max = 0.0;
  const auto zero = compute_surface_layers(flat, o);
  for (float mu : zero.value.mu_d.values()) EXPECT_EQ(mu, 0.0f);
}

// On a textured surface both models follow their formula cell by cell, clamped, and move in
// opposite directions with the curvature magnitude.
TEST(SurfaceLayers, DynamicFrictionFollowsEitherModelFormula) {
  const GridGeometry g = square_grid(80, 0.25e-3);
  const double k = 2 * kPi / 4e-3;
  const HeightField f = sample(
      g, [&](double x, double y) { return 0.1 + 0.04e-3 * std::sin(k * x) * std::sin(k * y) + 0.01 * x; },
      [](double x, double y) { return x > 0.012 && x < 0.015 && y > 0.005; });
  for (FrictionModel model : {FrictionModel::kPaper, FrictionModel::kCurvature}) {
    SurfaceLayerOptions o;
    o.friction_model = model;
    o.sigma_space_cells = 4.0;
    o.sigma_range_m = 0.01;
    o.mu_min = 0.05;
    o.mu_max = 0.8;
    o.workspace_radius_m = 0.05;
    o.curvature_gain_m = 1e-5;
    o.friction_scale = FrictionScale::kScene;  // the formulas in scene metres (device units: friction_levels_test)
    const auto res = compute_surface_layers(f, o);
    const SurfaceLayers& L = res.value;
    std::vector<std::pair<double, double>> s_mu;
    for (std::size_t i = 0; i < g.cell_count(); ++i) {
      if (std::isnan(f.values()[i])) continue;
      const double H = L.mean_curvature_per_m.values()[i], K = L.gaussian_curvature_per_m2.values()[i];
      const double s = std::sqrt(H * H + K * K);
      const double raw = model == FrictionModel::kPaper ? 1.0 / (o.workspace_radius_m * s)
                                                        : o.mu_min + o.curvature_gain_m * s;
      const double expected = std::clamp(raw, o.mu_min, o.mu_max);
      const float mu = L.mu_d.values()[i];
      ASSERT_NEAR(mu, expected, 1e-5 * expected) << "cell " << i << " model " << to_string(model);
      s_mu.emplace_back(s, mu);
    }
    // Some cells must be strictly inside the clamp range, or the test proves nothing.
    const auto inside = std::count_if(s_mu.begin(), s_mu.end(),
                                      [&](const auto& p) { return p.second > o.mu_min + 1e-3 && p.second < o.mu_max - 1e-3; });
    EXPECT_GT(inside, static_cast<std::ptrdiff_t>(s_mu.size() / 10)) << to_string(model);
    std::sort(s_mu.begin(), s_mu.end());
    for (std::size_t i = 1; i < s_mu.size(); ++i) {
      if (model == FrictionModel::kPaper) {
        ASSERT_LE(s_mu[i].second, s_mu[i - 1].second + 1e-6);
      } else {
        ASSERT_GE(s_mu[i].second, s_mu[i - 1].second - 1e-6);
      }
    }
    EXPECT_GE(figure(res.report, "mu_d_min"), o.mu_min - 1e-6);
    EXPECT_LE(figure(res.report, "mu_d_max"), o.mu_max + 1e-6);
    const auto& notes = res.report.notes;
    EXPECT_TRUE(std::any_of(notes.begin(), notes.end(), [&](const std::string& n) {
      return n.find("friction.model = " + to_string(model)) != std::string::npos;
    })) << to_string(model);
  }
}

TEST(SurfaceLayers, StaticFrictionRegionsOverrideInOrder) {
  const GridGeometry g = square_grid(10, 1e-3);  // x, y in [0, 9 mm]
  const HeightField f = sample(g, [](double, double) { return 0.0; }, [](double x, double y) {
    return x > 0.0085 && y > 0.0085;
  });
  SurfaceLayerOptions o;
  o.mu_s = 0.2;
  o.mu_s_regions = {{0.0, 0.0, 0.0045, 0.0045, 0.5}, {0.0025, 0.0025, 0.0065, 0.0065, 0.9}};
  const auto res = compute_surface_layers(f, o);
  const HeightField& mu = res.value.mu_s;
  EXPECT_FLOAT_EQ(mu.at(0, 0), 0.5f);
  EXPECT_FLOAT_EQ(mu.at(4, 4), 0.9f);  // both boxes: the later one wins
  EXPECT_FLOAT_EQ(mu.at(2, 2), 0.5f);
  EXPECT_FLOAT_EQ(mu.at(6, 6), 0.9f);
  EXPECT_FLOAT_EQ(mu.at(7, 2), 0.2f);
  EXPECT_TRUE(std::isnan(mu.at(9, 9)));
}

TEST(SurfaceLayers, ReportAndGeometry) {
  GridGeometry g = square_grid(50, 0.4e-3, 0.01, -0.02);
  HeightField f = sample(g, [](double x, double y) { return 0.3 + 0.001 * std::sin(3000 * x + 1000 * y); },
                         [](double x, double) { return x < 0.0105; });
  f.model_to_grid.translate(Eigen::Vector3d(1, 2, 3));
  const auto res = compute_surface_layers(f, {});
  EXPECT_EQ(res.report.stage, "surface_layers");
  EXPECT_EQ(res.report.count_in, f.valid_count());
  EXPECT_EQ(res.report.count_out, f.valid_count());
  EXPECT_GT(res.report.seconds, 0.0);
  EXPECT_GT(figure(res.report, "texture_rms_mm"), 0.0);
  EXPECT_LE(figure(res.report, "mu_d_min"), figure(res.report, "mu_d_median"));
  EXPECT_LE(figure(res.report, "mu_d_median"), figure(res.report, "mu_d_max"));
  EXPECT_EQ(figure(res.report, "bilateral_diameter_cells"), 13.0);  // 2·⌈2·3⌉ + 1
  for (const HeightField* layer : {&res.value.envelope_m, &res.value.texture_m, &res.value.mean_curvature_per_m,
                                   &res.value.gaussian_curvature_per_m2, &res.value.mu_d, &res.value.mu_s}) {
    EXPECT_EQ(layer->geometry(), g);
    EXPECT_TRUE(layer->model_to_grid.isApprox(f.model_to_grid));
  }
}

}  // namespace
}  // namespace hc::pipeline
