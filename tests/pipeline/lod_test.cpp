// Levels of detail: the anti-aliased pyramid against analytic truth and a brute-force oracle,
// no-data handling, aliasing, per-level layers, windows and the LRU cache.

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/surface_layers.hpp"
#include "hc/pipeline/synthetic.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <numbers>
#include <random>
#include <vector>

namespace hc::pipeline {
namespace {

HeightField grid_of(int rows, int cols, double cell_m, const std::function<double(double, double)>& f,
                    double x0_m = -0.01, double y0_m = -0.02) {
  HeightField h(GridGeometry{rows, cols, x0_m, y0_m, cell_m});
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) h.at(r, c) = static_cast<float>(f(h.geometry().x_of_col(c), h.geometry().y_of_row(r)));
  }
  return h;
}

std::vector<double> kernel(double sigma) {
  const int radius = static_cast<int>(std::ceil(3.0 * sigma));
  std::vector<double> w;
  for (int k = -radius; k <= radius; ++k) w.push_back(std::exp(-0.5 * k * k / (sigma * sigma)));
  return w;
}

/// Brute-force oracle of downsample_2x: the 2-D normalised convolution written out directly.
HeightField oracle_downsample(const HeightField& fine, double sigma, double valid_fraction) {
  const std::vector<double> w = kernel(sigma);
  const int radius = static_cast<int>(w.size() / 2);
  const GridGeometry cg = lod_level_geometry(fine.geometry(), 1);
  HeightField out(cg);
  for (int r = 0; r < cg.rows; ++r) {
    for (int c = 0; c < cg.cols; ++c) {
      double s = 0, sw = 0, full = 0;
      for (int i = -radius; i <= radius; ++i) {
        for (int j = -radius; j <= radius; ++j) {
          const int fr = 2 * r + i, fc = 2 * c + j;
          if (fr < 0 || fr >= fine.rows() || fc < 0 || fc >= fine.cols()) continue;
          const double wk = w[static_cast<std::size_t>(i + radius)] * w[static_cast<std::size_t>(j + radius)];
          full += wk;
          if (!fine.valid(fr, fc)) continue;
          s += wk * fine.at(fr, fc);
          sw += wk;
        }
      }
      out.at(r, c) = sw > 0 && sw >= valid_fraction * full * (1 - 1e-6) ? static_cast<float>(s / sw) : kNoData;
    }
  }
  return out;
}

TEST(LodGeometry, OddAndEvenSizesHalveWithTheSameOrigin) {
  const GridGeometry g{101, 77, -0.3, 0.2, 0.001};
  const GridGeometry g1 = lod_level_geometry(g, 1);
  EXPECT_EQ(g1.rows, 51);
  EXPECT_EQ(g1.cols, 39);
  EXPECT_DOUBLE_EQ(g1.cell_size_m, 0.002);
  EXPECT_DOUBLE_EQ(g1.x0_m, g.x0_m);
  EXPECT_DOUBLE_EQ(g1.y0_m, g.y0_m);
  // Odd: the last coarse sample sits exactly on the last fine one.
  EXPECT_DOUBLE_EQ(g1.y_of_row(g1.rows - 1), g.y_of_row(g.rows - 1));
  const GridGeometry g3 = lod_level_geometry(g, 3);
  EXPECT_EQ(g3.rows, 13);  // 101 → 51 → 26 → 13
  EXPECT_EQ(g3.cols, 10);  // 77 → 39 → 20 → 10
  EXPECT_DOUBLE_EQ(g3.cell_size_m, 0.008);
  // min_cells bounds the longer side of the coarsest level.
  EXPECT_EQ(lod_level_count(g, 13), 4);   // 101, 51, 26, 13
  EXPECT_EQ(lod_level_count(g, 14), 3);
  EXPECT_EQ(lod_level_count(g, 200), 1);  // level 0 always exists
  EXPECT_THROW(lod_level_count(g, 1), ConfigError);
}

TEST(LodDownsample, MatchesTheBruteForceOracleWithHolesOnOddGrids) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1e-3, 1e-3);
  std::bernoulli_distribution hole(0.2);
  for (const auto& [rows, cols] : {std::pair{37, 53}, std::pair{40, 41}, std::pair{2, 9}, std::pair{3, 3}}) {
    HeightField fine(GridGeometry{rows, cols, 0.0, 0.0, 0.0005});
    for (float& v : fine.values()) v = hole(rng) ? kNoData : static_cast<float>(0.1 + u(rng));
    for (const double sigma : {0.5, 1.0, 1.7}) {
      for (const double frac : {0.25, 0.5, 1.0}) {
        const HeightField got = downsample_2x(fine, sigma, frac);
        const HeightField want = oracle_downsample(fine, sigma, frac);
        ASSERT_EQ(got.geometry(), want.geometry());
        for (int r = 0; r < got.rows(); ++r) {
          for (int c = 0; c < got.cols(); ++c) {
            ASSERT_EQ(got.valid(r, c), want.valid(r, c)) << rows << "x" << cols << " sigma " << sigma << " frac " << frac
                                                         << " at " << r << "," << c;
            if (want.valid(r, c)) {
              ASSERT_NEAR(got.at(r, c), want.at(r, c), 1e-7);
            }
          }
        }
      }
    }
  }
}

TEST(LodDownsample, NoDataNeverLeaksAndEmptyFootprintsStayEmpty) {
  // Left half no data, right half a plane; a NaN island in the right half.
  HeightField fine = grid_of(61, 61, 0.001, [](double x, double y) { return 0.05 + 0.2 * x - 0.1 * y; }, 0.0, 0.0);
  for (int r = 0; r < 61; ++r) {
    for (int c = 0; c < 30; ++c) fine.at(r, c) = kNoData;
  }
  for (int r = 40; r < 50; ++r) {
    for (int c = 40; c < 50; ++c) fine.at(r, c) = kNoData;
  }
  for (const double frac : {0.01, 0.5, 0.99}) {
    const HeightField coarse = downsample_2x(fine, 1.0, frac);
    for (int r = 0; r < coarse.rows(); ++r) {
      for (int c = 0; c < coarse.cols(); ++c) {
        const float v = coarse.at(r, c);
        EXPECT_FALSE(std::isinf(v));
        if (2 * c <= 30 - 4) {
          EXPECT_TRUE(std::isnan(v)) << "coarse " << r << "," << c << " has no valid fine sample";
        }
        if (!std::isnan(v)) {
          // Normalised convolution of valid samples only: the value stays within the plane's
          // range over the kernel (never pulled towards 0 by missing data).
          const double x = coarse.geometry().x_of_col(c), y = coarse.geometry().y_of_row(r);
          EXPECT_NEAR(v, 0.05 + 0.2 * x - 0.1 * y, 0.3 * 4 * 0.001) << r << "," << c;
        }
      }
    }
  }
  // Far from holes and border a plane is reproduced exactly.
  const HeightField coarse = downsample_2x(fine, 1.0, 0.5);
  const int r = 10, c = 20;  // fine (20, 40): 10 samples from the hole edge and the island
  EXPECT_NEAR(coarse.at(r, c), 0.05 + 0.2 * coarse.geometry().x_of_col(c) - 0.1 * coarse.geometry().y_of_row(r), 1e-8);
}

TEST(LodPyramid, SinusoidMatchesTheSmoothedAnalyticTruthAtEveryLevel) {
  // z = A·sin(2πx/λ)·sin(2πy/λ) sampled on 513² nodes (λ = 24 cells). Each level's Gaussian
  // multiplies a sinusoid of wavenumber k by H_l(k) = Σ w_j cos(k·j·h_l) / Σ w_j (h_l the spacing
  // it runs on), so level L is A·Π H_l(k)² · sin·sin away from the border.
  SyntheticSpec spec;
  spec.kind = SurfaceKind::kSinusoid;
  spec.amplitude_m = 0.002;
  const double cell = 0.0005;
  spec.wavelength_m = 24 * cell;
  const int n = 513;
  LodLevel l0;
  l0.depth_m = grid_of(n, n, cell, [&](double x, double y) { return synthetic_height(spec, x, y); }, 0.0, 0.0);
  LodOptions opt;
  opt.min_cells = 32;
  opt.antialias_sigma_cells = 1.0;
  LodPyramid pyr(std::move(l0), SurfaceLayerOptions{}, opt);
  ASSERT_EQ(pyr.level_count(), 5);  // 513, 257, 129, 65, 33
  const std::vector<double> w = kernel(opt.antialias_sigma_cells);
  const int radius = static_cast<int>(w.size() / 2);
  const double k = 2 * std::numbers::pi / spec.wavelength_m;
  double gain = 1.0;     // Π H_l(k) along one axis
  double margin_m = 0.0; // the border's reach
  for (int level = 1; level < pyr.level_count(); ++level) {
    const double h = lod_level_geometry(pyr.geometry(0), level - 1).cell_size_m;
    double num = 0, den = 0;
    for (int j = -radius; j <= radius; ++j) {
      num += w[static_cast<std::size_t>(j + radius)] * std::cos(k * j * h);
      den += w[static_cast<std::size_t>(j + radius)];
    }
    gain *= num / den;
    margin_m += (radius + 1) * h;
    const auto lvl = pyr.depth_level(level);
    const GridGeometry& g = lvl->depth_m.geometry();
    double worst = 0.0;
    int checked = 0;
    for (int r = 0; r < g.rows; ++r) {
      for (int c = 0; c < g.cols; ++c) {
        const double x = g.x_of_col(c), y = g.y_of_row(r);
        const double extent = (n - 1) * cell;
        if (x < margin_m || y < margin_m || x > extent - margin_m || y > extent - margin_m) continue;
        const double truth = gain * gain * synthetic_height(spec, x, y);
        worst = std::max(worst, std::fabs(lvl->depth_m.at(r, c) - truth));
        ++checked;
      }
    }
    EXPECT_GT(checked, 0) << "level " << level;
    EXPECT_LT(worst, 2e-8) << "level " << level << " (attenuation " << gain * gain << ")";
  }
}

TEST(LodPyramid, FineTextureDoesNotAliasIntoALowFrequencyBump) {
  // A plane with a texture of wavelength 2.5 fine cells: above level 1's Nyquist (4 fine cells).
  // Sampling every other node would fold it to a wavelength of 10 fine cells with the full
  // amplitude; the smoothed pyramid must leave (almost) nothing of it on every coarser level.
  const double cell = 0.0002, a = 0.0005, lambda = 2.5 * cell;
  const auto plane = [](double x, double y) { return 0.01 + 0.05 * x + 0.02 * y; };
  LodLevel l0;
  l0.depth_m = grid_of(401, 401, cell,
                       [&](double x, double y) { return plane(x, y) + a * std::sin(2 * std::numbers::pi * x / lambda); }, 0.0, 0.0);
  // The naive decimation shows the false bump (so the test can tell the two apart).
  double naive_worst = 0.0;
  for (int r = 0; r < 401; r += 2) {
    for (int c = 0; c < 401; c += 2) {
      naive_worst = std::max(naive_worst, std::fabs(l0.depth_m.at(r, c) - plane(c * cell, r * cell)));
    }
  }
  EXPECT_GT(naive_worst, 0.9 * a);
  LodOptions opt;
  opt.min_cells = 20;
  LodPyramid pyr(std::move(l0), SurfaceLayerOptions{}, opt);
  for (int level = 1; level < pyr.level_count(); ++level) {
    const auto lvl = pyr.depth_level(level);
    const GridGeometry& g = lvl->depth_m.geometry();
    double worst = 0.0;
    const int m = 4;  // the one-sided border shifts a sloped plane by ~slope·σ; look inside
    for (int r = m; r < g.rows - m; ++r) {
      for (int c = m; c < g.cols - m; ++c) {
        worst = std::max(worst, std::fabs(lvl->depth_m.at(r, c) - plane(g.x_of_col(c), g.y_of_row(r))));
      }
    }
    EXPECT_LT(worst, 0.05 * a) << "level " << level;
  }
}

TEST(LodPyramid, LayersAreComputedForEachLevelNotDownsampled) {
  SyntheticSpec spec;
  spec.amplitude_m = 0.001;
  spec.wavelength_m = 0.004;
  LodLevel l0;
  l0.depth_m = grid_of(201, 161, 0.0001, [&](double x, double y) { return synthetic_height(spec, x, y); });
  SurfaceLayerOptions lo;
  lo.friction_model = FrictionModel::kCurvature;
  LodOptions opt;
  opt.min_cells = 40;
  LodPyramid pyr(std::move(l0), lo, opt);
  ASSERT_GE(pyr.level_count(), 3);
  const auto lvl = pyr.level(2);
  ASSERT_TRUE(lvl->has_layers);
  const SurfaceLayers direct = compute_surface_layers(lvl->depth_m, lo).value;
  ASSERT_EQ(lvl->mu_d.geometry(), lvl->depth_m.geometry());
  for (std::size_t i = 0; i < direct.mu_d.values().size(); ++i) {
    const float a = lvl->mu_d.values()[i], b = direct.mu_d.values()[i];
    ASSERT_TRUE((std::isnan(a) && std::isnan(b)) || a == b) << i;
    const float t = lvl->texture_m.values()[i], tb = direct.texture_m.values()[i];
    ASSERT_TRUE((std::isnan(t) && std::isnan(tb)) || t == tb) << i;
  }
  // Level 0 without layers in the input gets them computed on demand too.
  EXPECT_TRUE(pyr.level(0)->has_layers);
  EXPECT_GT(lvl->layers_seconds, 0.0);
}

TEST(LodPyramid, WindowsAreClampedAtTheBorderAndCoverSmallLevelsWhole) {
  LodLevel l0;
  l0.depth_m = grid_of(301, 257, 0.001, [](double x, double y) { return x + 2 * y; });
  LodOptions opt;
  opt.min_cells = 40;
  LodPyramid pyr(std::move(l0), SurfaceLayerOptions{}, opt);
  // A window hanging over the bottom-right corner is moved inside and touches the border.
  auto w = pyr.window(0, 250, 240, 100, 100);
  EXPECT_EQ(w->row0, 201);
  EXPECT_EQ(w->col0, 157);
  EXPECT_EQ(w->depth_m.rows(), 100);
  EXPECT_EQ(w->depth_m.cols(), 100);
  const GridGeometry& g0 = pyr.geometry(0);
  EXPECT_DOUBLE_EQ(w->depth_m.geometry().x0_m, g0.x_of_col(157));
  EXPECT_DOUBLE_EQ(w->depth_m.geometry().y0_m, g0.y_of_row(201));
  EXPECT_FLOAT_EQ(w->depth_m.at(99, 99), pyr.depth_level(0)->depth_m.at(300, 256));
  w = pyr.window(0, -20, -5, 100, 100);
  EXPECT_EQ(w->row0, 0);
  EXPECT_EQ(w->col0, 0);
  // Level 2 (76 x 65) is smaller than a 100-sample window: the window is the whole level.
  w = pyr.window(2, 10, 10, 100, 100);
  EXPECT_EQ(w->depth_m.rows(), 76);
  EXPECT_EQ(w->depth_m.cols(), 65);
  EXPECT_EQ(w->row0, 0);
  EXPECT_TRUE(w->mu_d.geometry() == w->depth_m.geometry());
  EXPECT_THROW(pyr.window(pyr.level_count(), 0, 0, 10, 10), InputError);
  EXPECT_THROW(pyr.window(0, 0, 0, 1, 10), InputError);
}

TEST(LodPyramid, CacheStaysWithinItsBudgetAndRebuildsIdentically) {
  LodLevel l0;
  l0.depth_m = grid_of(513, 513, 0.0005, [](double x, double y) { return 0.01 * std::sin(300 * x) * std::cos(200 * y); });
  LodOptions opt;
  opt.min_cells = 16;
  // Level 1 with layers: 257² · 5 floats ≈ 1.3 MB; budget 1.5 MB holds about one level.
  opt.memory_budget_mb = 1.5;
  LodPyramid pyr(std::move(l0), SurfaceLayerOptions{}, opt);
  const CellBuffer<float> first = pyr.level(1)->depth_m.values();
  (void)pyr.level(3);
  (void)pyr.level(2);
  (void)pyr.window(2, 0, 0, 50, 50);
  const auto stats = pyr.cache_stats();
  EXPECT_GT(stats.evictions, 0U);
  EXPECT_LE(stats.bytes, stats.budget_bytes);
  EXPECT_FALSE(pyr.is_cached(1));
  EXPECT_EQ(pyr.level(1)->depth_m.values().size(), first.size());
  const CellBuffer<float> again = pyr.level(1)->depth_m.values();
  for (std::size_t i = 0; i < first.size(); ++i) ASSERT_TRUE(first[i] == again[i] || (std::isnan(first[i]) && std::isnan(again[i])));
  // Levels nobody asked for are never built.
  LodLevel big;
  big.depth_m = grid_of(1025, 1025, 0.0001, [](double x, double) { return x; });
  LodPyramid lazy(std::move(big), SurfaceLayerOptions{}, LodOptions{});
  EXPECT_EQ(lazy.cache_stats().levels_cached, 0);
  (void)lazy.depth_level(2);
  EXPECT_TRUE(lazy.is_cached(2, false));
  EXPECT_FALSE(lazy.is_cached(2, true));
  EXPECT_FALSE(lazy.is_cached(3, false));
}

TEST(LodPyramid, RejectsBadOptionsNamingTheKey) {
  LodLevel l0;
  l0.depth_m = grid_of(10, 10, 0.001, [](double, double) { return 0.0; });
  LodOptions opt;
  opt.valid_fraction = 0.0;
  try {
    LodPyramid p(l0, SurfaceLayerOptions{}, opt);
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("lod.valid_fraction"), std::string::npos) << e.what();
  }
  opt = LodOptions{};
  opt.window_cells = 1;
  EXPECT_THROW(LodPyramid(l0, SurfaceLayerOptions{}, opt), ConfigError);
  LodLevel empty;
  empty.depth_m = HeightField(GridGeometry{10, 10, 0, 0, 0.001});
  EXPECT_THROW(LodPyramid(std::move(empty), SurfaceLayerOptions{}, LodOptions{}), InputError);
}

TEST(LodPyramid, CrossCheckErrorGoesDownWithTheDepthAndIntoWindows) {
  // Level 0: a plane with a square hole; the cross-check error is 2 mm on every valid sample
  // plus a ramp of 1 µm per column. Normalised smoothing of the same mask keeps the mask (the
  // error is valid exactly where the depth is), reproduces the constant and, away from the hole
  // and the border, the ramp: error_L(r, c) = 2 mm + 1 µm · 2^L · c.
  LodLevel l0;
  l0.depth_m = grid_of(64, 64, 0.001, [](double, double) { return 0.0; });
  l0.cell_error_m = HeightField(l0.depth_m.geometry());
  for (int r = 0; r < 64; ++r) {
    for (int c = 0; c < 64; ++c) {
      if (r >= 20 && r < 40 && c >= 20 && c < 40) {
        l0.depth_m.at(r, c) = kNoData;
      } else {
        l0.cell_error_m.at(r, c) = static_cast<float>(0.002 + 1e-6 * c);
      }
    }
  }
  LodOptions lo;
  lo.min_cells = 8;
  LodPyramid pyramid(std::move(l0), SurfaceLayerOptions{}, lo);
  ASSERT_GE(pyramid.level_count(), 3);
  const int reach = static_cast<int>(std::ceil(3.0 * lo.antialias_sigma_cells));
  for (int level = 1; level < 3; ++level) {
    const auto lvl = pyramid.depth_level(level);
    ASSERT_EQ(lvl->cell_error_m.geometry(), lvl->depth_m.geometry()) << "level " << level;
    const int step = 1 << level;
    std::size_t checked = 0;
    for (int r = 0; r < lvl->depth_m.rows(); ++r) {
      for (int c = 0; c < lvl->depth_m.cols(); ++c) {
        ASSERT_EQ(std::isnan(lvl->cell_error_m.at(r, c)), std::isnan(lvl->depth_m.at(r, c))) << level << ": " << r << "," << c;
        const int fr = r * step, fc = c * step, margin = (step - 1) * reach + 1;
        const bool clear = fr >= margin && fc >= margin && fr < 64 - margin && fc < 64 - margin &&
                           (fr < 20 - margin || fr >= 40 + margin || fc < 20 - margin || fc >= 40 + margin);
        if (!clear) continue;
        ++checked;
        EXPECT_NEAR(lvl->cell_error_m.at(r, c), 0.002 + 1e-6 * fc, 2e-7) << level << ": " << r << "," << c;
      }
    }
    EXPECT_GT(checked, 0U) << "level " << level;
  }
  const auto win = pyramid.window(1, 3, 5, 8, 9);
  const auto lvl1 = pyramid.depth_level(1);
  ASSERT_EQ(win->cell_error_m.rows(), 8);
  ASSERT_EQ(win->cell_error_m.cols(), 9);
  for (int r = 0; r < 8; ++r) {
    for (int c = 0; c < 9; ++c) {
      const float a = win->cell_error_m.at(r, c), b = lvl1->cell_error_m.at(3 + r, 5 + c);
      EXPECT_TRUE((std::isnan(a) && std::isnan(b)) || a == b) << r << "," << c;
    }
  }
  // A map of another size is refused, naming the layer.
  LodLevel bad;
  bad.depth_m = grid_of(10, 10, 0.001, [](double, double) { return 0.0; });
  bad.cell_error_m = grid_of(9, 10, 0.001, [](double, double) { return 0.0; });
  try {
    LodPyramid p(std::move(bad), SurfaceLayerOptions{}, LodOptions{});
    FAIL() << "expected an InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("cell_error"), std::string::npos) << e.what();
  }
}

TEST(LodConfig, KeysAreReadValidatedAndResolved) {
  const std::string base = "input: {synthetic: {surface: plane}}\n";
  const RunConfig d = parse_run_config(base, "lod.yaml");
  EXPECT_EQ(d.lod.window_cells, 200);
  EXPECT_EQ(d.lod.min_cells, 64);
  EXPECT_FALSE(d.lod.report) << "the levels table is made by request";
  EXPECT_TRUE(d.lod.report_cross_check);
  EXPECT_NE(d.resolved_yaml.find("memory_budget_mb"), std::string::npos);
  const RunConfig c = parse_run_config(base + "lod: {min_cells: 32, valid_fraction: 0.75, antialias_sigma_cells: 1.5, "
                                              "memory_budget_mb: 64, window_cells: 150, report: true, report_cross_check: false}\n",
                                       "lod.yaml");
  EXPECT_EQ(c.lod.min_cells, 32);
  EXPECT_DOUBLE_EQ(c.lod.valid_fraction, 0.75);
  EXPECT_DOUBLE_EQ(c.lod.antialias_sigma_cells, 1.5);
  EXPECT_DOUBLE_EQ(c.lod.memory_budget_mb, 64.0);
  EXPECT_EQ(c.lod.window_cells, 150);
  EXPECT_TRUE(c.lod.report);
  EXPECT_FALSE(c.lod.report_cross_check);
  for (const char* bad : {"lod: {valid_fraction: 0}", "lod: {valid_fraction: 1.5}", "lod: {window_cells: 1}",
                          "lod: {min_cells: 1}", "lod: {memory_budget_mb: 0}", "lod: {antialias_sigma_cells: 9}",
                          "lod: {levels: 3}"}) {
    try {
      parse_run_config(base + bad + "\n", "lod.yaml");
      FAIL() << bad;
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("lod."), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace hc::pipeline

namespace hc::pipeline {
namespace {

// --window of `hapticloud export`: the nodes inside [X0, X1] × [Y0, Y1], by hand on a 6 × 8 grid
// of 0.5 m cells whose node (0, 0) is at (1, −2).
TEST(ExportWindow, NodesInsideTheExtentAndClearErrorsOutside) {
  const GridGeometry g{6, 8, 1.0, -2.0, 0.5};
  // x in [1.2, 2.6]: columns 1 (x = 1.5) to 3 (x = 2.5); y in [−2, −0.5]: rows 0 to 3.
  SampleWindow w = window_of_extent(g, 1.2, -2.0, 2.6, -0.5);
  EXPECT_EQ(w.col0, 1);
  EXPECT_EQ(w.cols, 3);
  EXPECT_EQ(w.row0, 0);
  EXPECT_EQ(w.rows, 4);
  // Beyond the grid: clipped to it.
  w = window_of_extent(g, -100.0, -100.0, 100.0, 100.0);
  EXPECT_EQ(w.row0, 0);
  EXPECT_EQ(w.col0, 0);
  EXPECT_EQ(w.rows, 6);
  EXPECT_EQ(w.cols, 8);
  EXPECT_THROW(window_of_extent(g, 2.0, 0.0, 1.0, 1.0), ConfigError);   // X0 > X1
  EXPECT_THROW(window_of_extent(g, 1.1, -2.0, 1.4, 0.0), ConfigError);  // no node column inside
  try {
    window_of_extent(g, 10.0, 10.0, 11.0, 11.0);
    FAIL() << "expected hc::ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("spans x 1 .. 4.5, y -2 .. 0.5 m"), std::string::npos) << e.what();
  }
  // The crop: values and geometry of the block.
  HeightField f(g);
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c) f.at(r, c) = static_cast<float>(10 * r + c);
  const HeightField cut = crop_height_field(f, 2, 3, 2, 4);
  EXPECT_EQ(cut.rows(), 2);
  EXPECT_EQ(cut.cols(), 4);
  EXPECT_DOUBLE_EQ(cut.geometry().x0_m, 2.5);
  EXPECT_DOUBLE_EQ(cut.geometry().y0_m, -1.0);
  EXPECT_EQ(cut.at(1, 3), 36.0f);
  EXPECT_THROW(crop_height_field(f, 5, 0, 2, 2), std::invalid_argument);
}

}  // namespace
}  // namespace hc::pipeline
