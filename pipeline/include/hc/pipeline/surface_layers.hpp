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

/// A block of samples of a grid: rows × cols starting at sample (row0, col0).
struct SampleWindow {
  int row0 = 0, col0 = 0, rows = 0, cols = 0;
};

/// s = √(H² + K²) with H [1/m] and K [1/m²] taken in units of σ device metres per grid metre
/// (H/σ, K/σ²): the curvature magnitude the friction maps read (paper Sec. 3.2, docs/friction.md).
double friction_s(float mean_per_m, float gaussian_per_m2, double sigma);
/// σ of friction_s: 1 for friction_scale `scene`, else device_scale(R, window_cells, cell size).
/// @throws hc::ConfigError as device_scale.
double friction_sigma(const SurfaceLayerOptions& options, int window_cells, double cell_size_m);
/// The flatness floor of `level_median`'s reference, 1/(R·μ_max) [device units] (0 for μ_max = 0).
double friction_s_floor(const SurfaceLayerOptions& options);
/// μ_d [-] of one cell from its s and, for `level_median`, the level's reference s_ref =
/// max(median of s over the cells with s > 0, friction_s_floor) (else unused): the paper's
/// 1/(R·s) or the curvature model, clamped to [μ_min, μ_max] (docs/friction.md).
double friction_mu_d(double s, double s_ref, const SurfaceLayerOptions& options);
/// μ_s [-] at grid-frame point (x, y) [m]: options.mu_s, or the last of mu_s_regions holding it.
double friction_mu_s(double x_m, double y_m, const SurfaceLayerOptions& options);

/// The level-wide values compute_surface_layers takes from its whole grid, which a block of the
/// grid (surface_layers_block) cannot see. For a block to equal the whole grid's layers bit for
/// bit (the streaming level builder, level_builder.hpp) they must be the whole grid's.
struct SurfaceLayerLevelValues {
  /// Mean of the valid depths [m]: their exact sum (ExactFloatSum) rounded, over their count (as
  /// compute_surface_layers).
  double ref_m = 0.0;
  /// {min, max} over the valid cells of float(depth − ref_m) [m].
  float band_m[2] = {0.0f, 0.0f};
  /// {min, max} of the bilateral filter's whole filled input (depth − ref_m) [m]: the reduction
  /// of every block's fill_min_m / fill_max_m from a first pass with fill_only.
  float fill_range_m[2] = {0.0f, 0.0f};
};

/// What surface_layers_block computes for its inner block.
struct SurfaceLayerBlock {
  int rows = 0, cols = 0;                 ///< the inner block
  std::vector<float> envelope_m, texture_m;  ///< rows·cols, row-major [m], NaN = no data
  /// rows·cols values of friction_s (σ of the level, ≥ 0), −1 = no data; μ_d follows from them and the
  /// level's s_ref (friction_mu_d).
  std::vector<double> s;
  /// fill_only: {min, max} [m, relative to ref_m] of the filled input over the cells the block
  /// owns (its inner cells, and the filter's padding beside them at the level's edges), at
  /// least band_m.
  float fill_min_m = 0.0f, fill_max_m = 0.0f;
};

/// Halo [cells] around a block that surface_layers_block needs for its inner cells to equal the
/// whole grid's: the curvature stencils, the bilateral window ⌈2σ_s⌉ and the reach of the hole
/// fill's nearest-cell search. @throws hc::ConfigError for invalid options.
int surface_layers_halo_cells(const SurfaceLayerOptions& options);
/// The bilateral window's radius ⌈2σ_s⌉ (at least 1) [cells]: the padding of its input.
int surface_layers_radius_cells(const SurfaceLayerOptions& options);

/// compute_surface_layers on a block of a larger grid (issue 14, a level built tile by tile):
/// `depth_m` holds window.rows × window.cols samples (row-major, NaN = no data) of the level at
/// (window.row0, window.col0); `level` is the level's geometry; `inner` lies in the window, at
/// least surface_layers_halo_cells from every window edge that is not the level's edge. The
/// inner block's envelope, texture and s then equal compute_surface_layers' on the whole level
/// bit for bit, provided `values` are the whole level's and the window's first column is a
/// multiple of 64 with its padded width (cols + 2⌈2σ_s⌉) a multiple of 64 unless it ends at the
/// level's right edge (OpenCV's SIMD loops then treat every inner column as the whole grid's
/// run does). With `fill_only` only the fill range of the owned cells is computed (a first pass
/// for values.fill_range_m). Not real-time; OpenCV threads.
/// @throws std::invalid_argument for blocks outside the level; hc::ConfigError for options;
///         hc::InputError when fill_range_m spans more than the bilateral envelope can filter.
SurfaceLayerBlock surface_layers_block(const float* depth_m, const SampleWindow& window, const GridGeometry& level,
                                       const SampleWindow& inner, const SurfaceLayerLevelValues& values,
                                       bool fill_only, const SurfaceLayerOptions& options, int window_cells);

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
