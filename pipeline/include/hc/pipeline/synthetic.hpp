#pragma once
/// @file synthetic.hpp
/// Analytic test surfaces with known answers: plane, tilted plane, sphere cap, step, and the
/// paper's validation sinusoid z = A·sin(2πx/λ)·sin(2πy/λ) (Sec. 5.1 of the paper).

#include "hc/pipeline/cloud.hpp"

#include <cstdint>
#include <string>

namespace hc::pipeline {

enum class SurfaceKind { kPlane, kTiltedPlane, kSphereCap, kStep, kSinusoid };

/// Parameters of an analytic surface over the square [−half_extent_m, half_extent_m]².
struct SyntheticSpec {
  SurfaceKind kind = SurfaceKind::kSinusoid;
  double half_extent_m = 0.05;     ///< half side of the sampled square [m]
  double density_per_m2 = 4e6;     ///< mean samples per square metre
  double noise_sigma_m = 0.0;      ///< Gaussian noise on z [m]
  std::uint64_t seed = 1;          ///< random seed (positions are uniform random)
  double amplitude_m = 0.002;      ///< sinusoid A, step height, sphere-cap depth [m]
  double wavelength_m = 0.02;      ///< sinusoid λ [m]
  double slope_x = 0.2, slope_y = 0.1;  ///< tilted plane gradient [-]
  double sphere_radius_m = 0.08;   ///< sphere cap radius [m]
};

/// Parses "plane", "tilted_plane", "sphere_cap", "step", "sinusoid".
/// @throws hc::ConfigError naming the value and the allowed set.
SurfaceKind surface_kind_from_string(const std::string& name);
std::string to_string(SurfaceKind kind);

/// Exact height z(x, y) [m] of the analytic surface (no noise).
double synthetic_height(const SyntheticSpec& spec, double x_m, double y_m);

/// Samples the surface at uniform random (x, y) with Gaussian noise on z.
/// @throws hc::ConfigError for non-positive extent, density, wavelength or radius.
Cloud generate_surface(const SyntheticSpec& spec);

}  // namespace hc::pipeline
