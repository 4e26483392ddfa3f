#include "hc/pipeline/synthetic.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <sstream>

namespace hc::pipeline {

namespace {

void require_positive(double value, const char* name) {
  if (!(value > 0.0) || !std::isfinite(value)) {
    std::ostringstream msg;
    msg << "synthetic surface: " << name << " = " << value << " (expected a finite value > 0)";
    throw ConfigError(msg.str());
  }
}

}  // namespace

SurfaceKind surface_kind_from_string(const std::string& name) {
  if (name == "plane") return SurfaceKind::kPlane;
  if (name == "tilted_plane") return SurfaceKind::kTiltedPlane;
  if (name == "sphere_cap") return SurfaceKind::kSphereCap;
  if (name == "step") return SurfaceKind::kStep;
  if (name == "sinusoid") return SurfaceKind::kSinusoid;
  if (name == "temple_relief") return SurfaceKind::kTempleRelief;
  throw ConfigError("unknown synthetic surface '" + name +
                    "' (expected one of: plane, tilted_plane, sphere_cap, step, sinusoid, temple_relief)");
}

std::string to_string(SurfaceKind kind) {
  switch (kind) {
    case SurfaceKind::kPlane: return "plane";
    case SurfaceKind::kTiltedPlane: return "tilted_plane";
    case SurfaceKind::kSphereCap: return "sphere_cap";
    case SurfaceKind::kStep: return "step";
    case SurfaceKind::kSinusoid: return "sinusoid";
    case SurfaceKind::kTempleRelief: return "temple_relief";
  }
  return "unknown";
}

double synthetic_height(const SyntheticSpec& spec, double x_m, double y_m) {
  switch (spec.kind) {
    case SurfaceKind::kPlane:
      return 0.0;
    case SurfaceKind::kTiltedPlane:
      return spec.slope_x * x_m + spec.slope_y * y_m;
    case SurfaceKind::kSphereCap: {
      // Cap of a sphere of radius R whose top is amplitude_m above the z = 0 plane; flat (z = 0)
      // outside the cap's footprint.
      const double r2 = x_m * x_m + y_m * y_m;
      const double rr = spec.sphere_radius_m * spec.sphere_radius_m;
      if (r2 >= rr) return 0.0;
      return std::max(0.0, std::sqrt(rr - r2) - (spec.sphere_radius_m - spec.amplitude_m));
    }
    case SurfaceKind::kStep:
      // Height amplitude_m for x ≥ 0, zero for x < 0.
      return x_m >= 0.0 ? spec.amplitude_m : 0.0;
    case SurfaceKind::kSinusoid: {
      const double k = 2.0 * std::numbers::pi / spec.wavelength_m;
      return spec.amplitude_m * std::sin(k * x_m) * std::sin(k * y_m);
    }
    case SurfaceKind::kTempleRelief: {
      const double h = spec.half_extent_m, a = spec.amplitude_m;
      const double s = 2.0 * h / 9.0, r = 0.45 * s, half_len = 0.75 * h;
      // Wall: shallow grooves (mortar lines) every 0.2·h along y.
      const double course = 0.2 * h;
      const double d = y_m - course * std::round(y_m / course);
      double z = -0.08 * a * std::exp(-(d * d) / (0.0004 * 0.0004));
      const double i = std::clamp(std::round(x_m / s), -3.0, 3.0);
      const double u = (x_m - i * s) / r;
      if (std::abs(u) < 1.0) {
        // Shaft: a raised-cosine profile across x (no step at its edges, so a sliding probe
        // climbs it) with shallow flutes, tapering to the wall over 0.1·h beyond |y| = 0.75·h.
        const double across = std::cos(0.5 * std::numbers::pi * u);
        const double over = std::max(0.0, std::abs(y_m) - half_len) / (0.1 * h);
        const double along = over >= 1.0 ? 0.0 : std::cos(0.5 * std::numbers::pi * over);
        const double shaft = a * across * across * (1.0 + 0.04 * std::cos(7.0 * std::numbers::pi * u)) * along * along;
        z = std::max(z, shaft);
      }
      return z;
    }
  }
  return 0.0;
}

std::vector<std::array<double, 4>> temple_pillar_boxes(const SyntheticSpec& spec) {
  const double h = spec.half_extent_m;
  const double s = 2.0 * h / 9.0, r = 0.45 * s, half_len = 0.75 * h;
  std::vector<std::array<double, 4>> boxes;
  for (int i = -3; i <= 3; ++i) boxes.push_back({i * s - r, -half_len, i * s + r, half_len});
  return boxes;
}

Cloud generate_surface(const SyntheticSpec& spec) {
  require_positive(spec.half_extent_m, "half_extent_m");
  require_positive(spec.density_per_m2, "density_per_m2");
  if (spec.kind == SurfaceKind::kSinusoid) require_positive(spec.wavelength_m, "wavelength_m");
  if (spec.kind == SurfaceKind::kSphereCap) require_positive(spec.sphere_radius_m, "sphere_radius_m");
  if (!(spec.noise_sigma_m >= 0.0) || !std::isfinite(spec.noise_sigma_m)) {
    std::ostringstream msg;
    msg << "synthetic surface: noise_sigma_m = " << spec.noise_sigma_m
        << " (expected a finite value >= 0)";
    throw ConfigError(msg.str());
  }
  const double side = 2.0 * spec.half_extent_m;
  const double expected = spec.density_per_m2 * side * side;
  constexpr double kMaxPoints = 2.0e8;  // 4.8 GB of doubles: far beyond any test surface
  if (expected > kMaxPoints) {
    std::ostringstream msg;
    msg << "synthetic surface: density_per_m2 = " << spec.density_per_m2 << " over a "
        << side << " m square asks for " << expected << " points (at most " << kMaxPoints << ")";
    throw ConfigError(msg.str());
  }
  const auto n = static_cast<Eigen::Index>(std::llround(expected));

  std::mt19937_64 rng(spec.seed);
  std::uniform_real_distribution<double> uniform(-spec.half_extent_m, spec.half_extent_m);
  std::normal_distribution<double> noise(0.0, spec.noise_sigma_m > 0.0 ? spec.noise_sigma_m : 1.0);
  Cloud cloud;
  cloud.xyz.resize(3, n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const double x = uniform(rng);
    const double y = uniform(rng);
    double z = synthetic_height(spec, x, y);
    if (spec.noise_sigma_m > 0.0) z += noise(rng);
    cloud.xyz(0, i) = x;
    cloud.xyz(1, i) = y;
    cloud.xyz(2, i) = z;
  }
  return cloud;
}

}  // namespace hc::pipeline
