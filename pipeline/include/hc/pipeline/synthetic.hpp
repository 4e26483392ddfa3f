#pragma once
/// @file synthetic.hpp
/// Analytic test surfaces with known answers: plane, tilted plane, sphere cap, step, the
/// paper's validation sinusoid z = A·sin(2πx/λ)·sin(2πy/λ) (Sec. 5.1 of the paper), and a
/// temple relief with seven musical pillars (the audio demo, Sec. 4.4 of the paper).

#include "hc/pipeline/cloud.hpp"

#include <array>
#include <cstdint>
#include <vector>
#include <string>

namespace hc::pipeline {

enum class SurfaceKind { kPlane, kTiltedPlane, kSphereCap, kStep, kSinusoid, kTempleRelief };

/// Parameters of an analytic surface over the square [−half_extent_m, half_extent_m]².
struct SyntheticSpec {
  SurfaceKind kind = SurfaceKind::kSinusoid;
  double half_extent_m = 0.05;     ///< half side of the sampled square [m]
  double density_per_m2 = 4e6;     ///< mean samples per square metre
  double noise_sigma_m = 0.0;      ///< Gaussian noise on z [m]
  std::uint64_t seed = 1;          ///< random seed (positions are uniform random)
  double amplitude_m = 0.002;      ///< sinusoid A, step height, sphere-cap depth, pillar relief [m]
  double wavelength_m = 0.02;      ///< sinusoid λ [m]
  double slope_x = 0.2, slope_y = 0.1;  ///< tilted plane gradient [-]
  double sphere_radius_m = 0.08;   ///< sphere cap radius [m]
};

/// Parses "plane", "tilted_plane", "sphere_cap", "step", "sinusoid", "temple_relief".
/// @throws hc::ConfigError naming the value and the allowed set.
SurfaceKind surface_kind_from_string(const std::string& name);
std::string to_string(SurfaceKind kind);

/// Exact height z(x, y) [m] of the analytic surface (no noise).
double synthetic_height(const SyntheticSpec& spec, double x_m, double y_m);

/// Temple relief: seven fluted pillars standing out amplitude_m from a wall of stone courses,
/// side by side along x, each a raised-cosine profile A·cos²(πu/2) across its width (so a probe
/// sliding at constant depth climbs over it). Pillar i (0..6, Sa..Ni in the audio demo) is
/// centred at x = (i − 3)·s with s = 2·half_extent_m/9, half-width 0.45·s, spanning
/// |y| ≤ 0.75·half_extent_m (tapering to the wall over 0.1·half_extent_m beyond);
/// @return the footprint [x_min, y_min, x_max, y_max] [m] of each pillar (for audio regions).
std::vector<std::array<double, 4>> temple_pillar_boxes(const SyntheticSpec& spec);

/// Samples the surface at uniform random (x, y) with Gaussian noise on z.
/// @throws hc::ConfigError for non-positive extent, density, wavelength or radius.
Cloud generate_surface(const SyntheticSpec& spec);

}  // namespace hc::pipeline
