#include "hc/pipeline/synthetic.hpp"

#include "hc/common/error.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

namespace hc::pipeline {
namespace {

TEST(Synthetic, KindNamesRoundTrip) {
  for (SurfaceKind k : {SurfaceKind::kPlane, SurfaceKind::kTiltedPlane, SurfaceKind::kSphereCap,
                        SurfaceKind::kStep, SurfaceKind::kSinusoid}) {
    EXPECT_EQ(surface_kind_from_string(to_string(k)), k);
  }
  try {
    surface_kind_from_string("torus");
    FAIL() << "expected ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("torus"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("sinusoid"), std::string::npos);
  }
}

TEST(Synthetic, HeightsHaveKnownValues) {
  SyntheticSpec s;
  s.amplitude_m = 0.002;
  s.wavelength_m = 0.02;
  s.kind = SurfaceKind::kPlane;
  EXPECT_EQ(synthetic_height(s, 0.01, -0.02), 0.0);

  s.kind = SurfaceKind::kTiltedPlane;
  EXPECT_DOUBLE_EQ(synthetic_height(s, 0.01, -0.02), 0.2 * 0.01 + 0.1 * -0.02);

  s.kind = SurfaceKind::kSinusoid;
  EXPECT_NEAR(synthetic_height(s, 0.005, 0.005), 0.002, 1e-15);   // λ/4, λ/4: crest
  EXPECT_NEAR(synthetic_height(s, 0.005, -0.005), -0.002, 1e-15);  // trough
  EXPECT_NEAR(synthetic_height(s, 0.0, 0.0123), 0.0, 1e-15);       // node line x = 0

  s.kind = SurfaceKind::kSphereCap;
  s.sphere_radius_m = 0.08;
  EXPECT_NEAR(synthetic_height(s, 0.0, 0.0), 0.002, 1e-15);  // top of the cap
  // On the sphere: (x² + (z + R − A)²) = R².
  const double x = 0.01;
  EXPECT_NEAR(std::pow(synthetic_height(s, x, 0.0) + 0.08 - 0.002, 2) + x * x, 0.08 * 0.08, 1e-15);
  EXPECT_EQ(synthetic_height(s, 0.03, 0.0), 0.0);  // outside the footprint (radius ≈ 17.8 mm)

  s.kind = SurfaceKind::kStep;
  EXPECT_EQ(synthetic_height(s, -1e-9, 0.0), 0.0);
  EXPECT_EQ(synthetic_height(s, 0.0, 0.0), 0.002);
}

TEST(Synthetic, SamplesLieOnTheSurfaceInsideTheSquare) {
  SyntheticSpec s;
  s.kind = SurfaceKind::kSinusoid;
  s.half_extent_m = 0.01;
  s.density_per_m2 = 1e7;  // 4000 points
  const Cloud c = generate_surface(s);
  ASSERT_EQ(c.size(), 4000u);
  EXPECT_FALSE(c.has_scan_id());
  for (Eigen::Index i = 0; i < c.xyz.cols(); ++i) {
    ASSERT_LE(std::abs(c.xyz(0, i)), 0.01);
    ASSERT_LE(std::abs(c.xyz(1, i)), 0.01);
    ASSERT_EQ(c.xyz(2, i), synthetic_height(s, c.xyz(0, i), c.xyz(1, i)));
  }
  // Uniform positions: each quadrant holds about a quarter (binomial σ ≈ 27 points).
  int q = 0;
  for (Eigen::Index i = 0; i < c.xyz.cols(); ++i) q += c.xyz(0, i) < 0 && c.xyz(1, i) < 0 ? 1 : 0;
  EXPECT_NEAR(q, 1000, 150);
}

TEST(Synthetic, SeededAndNoiseHasTheRequestedSigma) {
  SyntheticSpec s;
  s.kind = SurfaceKind::kTiltedPlane;
  s.half_extent_m = 0.05;
  s.density_per_m2 = 2e6;  // 20000 points
  s.noise_sigma_m = 1e-4;
  s.seed = 7;
  const Cloud a = generate_surface(s);
  const Cloud b = generate_surface(s);
  EXPECT_TRUE(a.xyz == b.xyz);
  s.seed = 8;
  EXPECT_FALSE(a.xyz == generate_surface(s).xyz);

  double sum = 0.0, sum_sq = 0.0;
  for (Eigen::Index i = 0; i < a.xyz.cols(); ++i) {
    const double r = a.xyz(2, i) - synthetic_height(s, a.xyz(0, i), a.xyz(1, i));
    sum += r;
    sum_sq += r * r;
  }
  const double n = static_cast<double>(a.size());
  EXPECT_NEAR(sum / n, 0.0, 5 * 1e-4 / std::sqrt(n));
  EXPECT_NEAR(std::sqrt(sum_sq / n), 1e-4, 0.03e-4);  // σ of the sample σ ≈ 0.5 %
}

TEST(Synthetic, RejectsNonPositiveParameters) {
  SyntheticSpec s;
  s.half_extent_m = 0.0;
  EXPECT_THROW(generate_surface(s), ConfigError);
  s = SyntheticSpec{};
  s.density_per_m2 = -1.0;
  EXPECT_THROW(generate_surface(s), ConfigError);
  s = SyntheticSpec{};
  s.wavelength_m = 0.0;
  EXPECT_THROW(generate_surface(s), ConfigError);
  s = SyntheticSpec{};
  s.kind = SurfaceKind::kSphereCap;
  s.sphere_radius_m = -0.01;
  EXPECT_THROW(generate_surface(s), ConfigError);
  s = SyntheticSpec{};
  s.noise_sigma_m = std::nan("");
  EXPECT_THROW(generate_surface(s), ConfigError);
  s = SyntheticSpec{};
  s.density_per_m2 = 1e15;  // 10^13 points
  EXPECT_THROW(generate_surface(s), ConfigError);
}

}  // namespace
}  // namespace hc::pipeline
