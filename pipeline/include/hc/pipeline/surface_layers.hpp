#pragma once
/// @file surface_layers.hpp
/// Surface layers for haptic rendering (Sec. 3.1–3.2 of the paper): envelope f_b (bilateral
/// filter of the depth grid), texture h = f − f_b, curvature of h (H, K), and friction maps
/// μ_d (from curvature) and μ_s (from the config).

#include "hc/common/height_field.hpp"
#include "hc/common/scene.hpp"
#include "hc/pipeline/cloud.hpp"

#include <cstddef>
#include <string>
#include <vector>

namespace hc::pipeline {

// FrictionModel, StaticFrictionRegion and SurfaceLayerOptions are part of the scene contract
// (hc/common/scene.hpp); the pipeline uses them under its own namespace too.
using hc::FrictionModel;
using hc::FrictionScale;
using hc::StaticFrictionRegion;
using hc::SurfaceLayerOptions;

/// @throws hc::ConfigError naming the value and the allowed set ("paper", "curvature").
FrictionModel friction_model_from_string(const std::string& name);
std::string to_string(FrictionModel model);
/// @throws hc::ConfigError naming the value and the allowed set ("scene", "device", "level_median").
FrictionScale friction_scale_from_string(const std::string& name);
std::string to_string(FrictionScale scale);

/// Device metres per grid metre σ_L of a level of cell size `cell_size_m` whose haptic window of
/// `window_cells` samples spans the diameter 2R of the workspace's inscribed sphere:
/// σ_L = 2R / ((window_cells − 1)·cell_size_m) [-]. The same scale as the LodController's map
/// (session/src/lod_controller.cpp, level_scale) when the device box's smaller x/y half extent is
/// R (the defaults: 0.05 m both). Source: paper Sec. 3.2 (R) and Sec. 4.1 (200 × 200 haptic space).
/// @throws hc::ConfigError for window_cells < 2 or a non-positive R or cell size.
double device_scale(double workspace_radius_m, int window_cells, double cell_size_m);

/// Histogram of a μ_d layer over its valid cells: cells at the clamps (μ ≤ μ_min, μ ≥ μ_max as
/// stored in float) and, for the others, `bins` equal bins of (μ_min, μ_max).
struct FrictionHistogram {
  std::size_t valid = 0;               ///< valid (non-NaN) cells
  std::size_t at_min = 0, at_max = 0;  ///< cells at the lower / upper clamp
  std::vector<std::size_t> bins;       ///< cells strictly between the clamps, bin k covers
                                       ///< μ_min + (k, k+1]·(μ_max − μ_min)/bins
  double at_min_fraction() const noexcept { return valid ? static_cast<double>(at_min) / static_cast<double>(valid) : 0.0; }
  double at_max_fraction() const noexcept { return valid ? static_cast<double>(at_max) / static_cast<double>(valid) : 0.0; }
};
/// @param mu_d a μ_d layer (NaN = no data) @param bins ≥ 1. Real-time: no (allocates).
/// @throws hc::ConfigError for bins < 1 or mu_max < mu_min.
FrictionHistogram friction_histogram(const HeightField& mu_d, double mu_min, double mu_max, int bins = 10);

/// All layers share the depth grid's geometry; NaN exactly where the depth grid has no data.
struct SurfaceLayers {
  HeightField envelope_m;              ///< f_b [m]
  HeightField texture_m;               ///< h = f − f_b [m]
  HeightField mean_curvature_per_m;    ///< H of h [1/m]
  HeightField gaussian_curvature_per_m2;  ///< K of h [1/m²]
  HeightField mu_d;                    ///< dynamic friction [-] in [μ_min, μ_max]
  HeightField mu_s;                    ///< static friction [-]
  FrictionModel friction_model = FrictionModel::kPaper;
};

/// Mean curvature H [1/m] and Gaussian curvature K [1/m²] of a height field (paper, Sec. 3.2):
///   H = (h_xx(1+h_y²) + h_yy(1+h_x²) − 2h_xy·h_x·h_y) / (2(1+h_x²+h_y²)^{3/2}),
///   K = (h_xx·h_yy − h_xy²) / (1+h_x²+h_y²)².
/// Derivatives by finite differences with the real cell size: central where both neighbours
/// along an axis are valid, second-order one-sided (3 cells) where only one side is, and
/// h_xy from the derivative of h_x along y (averaged with that of h_y along x when both exist).
/// A valid cell where some derivative has no stencil (grid border or no-data on both sides,
/// grids narrower than 3 cells) gets H = K = 0; no-data cells get NaN.
/// Output geometry = input geometry. Not real-time (allocates). See docs/friction.md.
struct Curvature {
  HeightField mean_per_m;        ///< H [1/m]
  HeightField gaussian_per_m2;   ///< K [1/m²]
  std::size_t zero_fallback_cells = 0;  ///< valid cells set to 0 for lack of a stencil
};
Curvature compute_curvature(const HeightField& surface_m);

/// Computes the layers from a depth grid (metres, NaN = no data).
/// No-data cells neither spread NaN nor bias their valid neighbours: before cv::bilateralFilter
/// (window radius ⌈2σ_s⌉ cells) every no-data cell, and a margin of that width around the grid,
/// gets the first-order extrapolation f(p) + ∇f(p)·(q − p) from its nearest valid cell p (filter
/// input only), so a locally planar surface is filtered without bias up to holes and the border
/// and a depth step is not blended; finite differences use valid cells only.
/// The report carries counts, seconds per step and figures (texture_rms_mm, mu_d_min/median/max,
/// ...); its notes state the friction model and scale. Not real-time; OpenCV threads (default count).
/// μ_d uses √(H² + K²) in the units of options.friction_scale (docs/friction.md): for `device`
/// and `level_median` the grid is taken as one level of detail whose haptic window has
/// `window_cells` samples (lod.window_cells), so σ = device_scale(R, window_cells, cell size).
/// @throws hc::ConfigError on out-of-range options (names the option, its config key and range);
///         hc::InputError if the grid is empty, has no valid cell or holds ±inf.
/// Source: paper Eq. (bilateral f_b, h = f − f_b, H, K, μ_d); Tomasi & Manduchi 1998.
StageResult<SurfaceLayers> compute_surface_layers(const HeightField& depth_m,
                                                  const SurfaceLayerOptions& options,
                                                  int window_cells = hc::LodOptions{}.window_cells);

}  // namespace hc::pipeline
