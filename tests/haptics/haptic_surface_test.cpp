#include "hc/haptics/haptic_surface.hpp"

#include "haptics_test_support.hpp"

#include "hc/common/error.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

namespace hc::haptics {
namespace {

using test::make_field;

TEST(HapticSurface, ReproducesDepthInsideTheGrid) {
  const HeightField depth = make_field(5, 7, 0.01, 0.1, -0.2, [](double x, double y) {
    return 0.5 * x - 0.25 * y + 0.01;  // a plane: bilinear reproduces it exactly
  });
  const auto s = test::make_surface(depth);
  // Strictly inside (a sample exactly on the first column may round into the padding cell).
  for (double x = 0.1001; x <= 0.16; x += 0.0037) {
    for (double y = -0.1999; y <= -0.16; y += 0.0041) {
      const SurfaceSample q = s->sample(x, y);
      EXPECT_NEAR(q.z_m, 0.5 * x - 0.25 * y + 0.01, 1e-7);
      EXPECT_NEAR(q.dz_dx, 0.5, 1e-5);
      EXPECT_NEAR(q.dz_dy, -0.25, 1e-5);
    }
  }
  EXPECT_EQ(s->geometry().rows, 7);
  EXPECT_EQ(s->geometry().cols, 9);
  EXPECT_EQ(s->no_data_count(), 0U);
}

TEST(HapticSurface, InlineSamplerMatchesBilinearSurface) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> z(-0.01, 0.01);
  HeightField depth = make_field(13, 17, 0.002, -0.01, 0.03, [&](double, double) { return z(rng); });
  depth.at(4, 4) = kNoData;
  const auto s = test::make_surface(depth);
  std::uniform_real_distribution<double> x(-0.02, 0.04), y(0.02, 0.07);
  for (int k = 0; k < 20000; ++k) {
    const double qx = k % 7 == 0 ? -0.01 + 0.002 * (k % 19) : x(rng);  // some exactly on nodes
    const double qy = k % 5 == 0 ? 0.03 + 0.002 * (k % 13) : y(rng);
    const SurfaceSample a = s->sample(qx, qy);
    const SurfaceSample b = s->bilinear().sample(qx, qy);
    ASSERT_TRUE(b.valid);
    ASSERT_NEAR(a.z_m, b.z_m, 1e-15);
    // Exactly on the padded grid's outer border, inside/outside may round either way (the
    // gradient there is one-sided by definition); compare gradients away from it.
    const GridGeometry& g = s->geometry();
    const double cu = g.col_of_x(qx), cv = g.row_of_y(qy);
    if (std::fabs(cu) > 1e-9 && std::fabs(cu - (g.cols - 1)) > 1e-9) {
      ASSERT_NEAR(a.dz_dx, b.dz_dx, 1e-9 * (1 + std::fabs(b.dz_dx)));
    }
    if (std::fabs(cv) > 1e-9 && std::fabs(cv - (g.rows - 1)) > 1e-9) {
      ASSERT_NEAR(a.dz_dy, b.dz_dy, 1e-9 * (1 + std::fabs(b.dz_dy)));
    }
  }
}

TEST(HapticSurface, HolesAndBorderBecomeTheFloor) {
  HeightField depth = make_field(6, 6, 0.001, 0.0, 0.0, [](double x, double) { return 0.01 + x; });
  depth.at(2, 3) = kNoData;
  depth.at(3, 3) = kNoData;
  SurfaceOptions opt;
  opt.floor_margin_m = 0.002;
  const auto s = test::make_surface(depth, opt);
  const double lowest = 0.01;  // column 0
  EXPECT_NEAR(s->floor_m(), lowest - 0.002, 1e-7);
  EXPECT_NEAR(s->min_height_m(), lowest, 1e-7);
  EXPECT_EQ(s->no_data_count(), 2U);
  // At the hole's samples: the floor.
  EXPECT_NEAR(s->height(0.003, 0.002), s->floor_m(), 1e-7);
  EXPECT_NEAR(s->height(0.003, 0.003), s->floor_m(), 1e-7);
  // One cell beyond the border and further out: exactly the floor; never NaN anywhere.
  EXPECT_NEAR(s->height(-0.001, 0.002), s->floor_m(), 1e-7);
  EXPECT_NEAR(s->height(-5.0, 7.0), s->floor_m(), 1e-7);
  EXPECT_NEAR(s->height(0.0025, 100.0), s->floor_m(), 1e-7);
  // Half a cell outside: halfway between the border sample and the floor.
  EXPECT_NEAR(s->height(0.0025, -0.0005), 0.5 * (0.0125 + s->floor_m()), 1e-7);
  for (double x = -0.01; x < 0.02; x += 0.00037) {
    for (double y = -0.01; y < 0.02; y += 0.00041) {
      const SurfaceSample q = s->sample(x, y);
      ASSERT_TRUE(q.valid);
      ASSERT_TRUE(std::isfinite(q.z_m) && std::isfinite(q.dz_dx) && std::isfinite(q.dz_dy));
      ASSERT_GE(q.z_m, s->floor_m() - 1e-9);
    }
  }
  const double inf = std::numeric_limits<double>::infinity();
  EXPECT_TRUE(std::isfinite(s->height(inf, 0.0)));
}

TEST(HapticSurface, TextureGainSwitchesTextureOnAndOff) {
  const HeightField env = make_field(4, 4, 0.01, 0, 0, [](double x, double) { return x; });
  const HeightField tex = make_field(4, 4, 0.01, 0, 0, [](double, double y) { return 0.1 * y; });
  HeightField depth = env;
  for (std::size_t k = 0; k < depth.values().size(); ++k) depth.values()[k] += tex.values()[k];
  for (double gain : {0.0, 1.0, 2.5}) {
    SurfaceOptions opt;
    opt.texture_gain = gain;
    // Envelope + texture given, texture only, envelope only: the same rendered height.
    SurfaceLayers both{&depth, &env, &tex, nullptr, nullptr, nullptr};
    SurfaceLayers tex_only{&depth, nullptr, &tex, nullptr, nullptr, nullptr};
    SurfaceLayers env_only{&depth, &env, nullptr, nullptr, nullptr, nullptr};
    for (const SurfaceLayers& l : {both, tex_only, env_only}) {
      const HapticSurface s(l, opt);
      EXPECT_NEAR(s.height(0.012, 0.017), 0.012 + gain * 0.1 * 0.017, 1e-6) << "gain " << gain;
    }
  }
  // Depth alone: the gain has nothing to scale.
  SurfaceOptions opt;
  opt.texture_gain = 0.0;
  EXPECT_NEAR(test::make_surface(depth, opt)->height(0.012, 0.017), 0.012 + 0.1 * 0.017, 1e-6);
}

TEST(HapticSurface, FrictionMapsInterpolateAndFallBackToDefaults) {
  const HeightField depth = make_field(3, 3, 0.01, 0, 0, [](double, double) { return 0.0; });
  HeightField mu_d = make_field(3, 3, 0.01, 0, 0, [](double x, double) { return 0.2 + 10 * x; });
  mu_d.at(2, 2) = kNoData;
  SurfaceOptions opt;
  opt.default_mu_d = 0.7;
  opt.default_mu_s = 0.4;
  const HapticSurface s(SurfaceLayers{&depth, nullptr, nullptr, &mu_d, nullptr, nullptr}, opt);
  EXPECT_NEAR(s.friction(0.005, 0.0).mu_d, 0.25, 1e-6);   // between 0.2 and 0.3
  EXPECT_NEAR(s.friction(0.02, 0.02).mu_d, 0.7, 1e-6);    // NaN node → default
  EXPECT_NEAR(s.friction(0.005, 0.0).mu_s, 0.4, 1e-12);   // no μ_s layer → default
  EXPECT_NEAR(s.friction(-1.0, -1.0).mu_d, 0.7, 1e-6);    // beyond the border → default
}

TEST(HapticSurface, RegionIdsByNearestSample) {
  const HeightField depth = make_field(3, 3, 0.01, 0, 0, [](double, double) { return 0.0; });
  HeightField ids = make_field(3, 3, 0.01, 0, 0, [](double x, double) { return x < 0.015 ? 3 : 7; });
  ids.at(0, 0) = kNoData;
  const HapticSurface s(SurfaceLayers{&depth, nullptr, nullptr, nullptr, nullptr, &ids}, {});
  EXPECT_EQ(s.region_id(0.011, 0.01), 3);
  EXPECT_EQ(s.region_id(0.019, 0.01), 7);
  EXPECT_EQ(s.region_id(0.001, 0.001), -1);
  EXPECT_EQ(s.region_id(5.0, 0.0), -1);
  EXPECT_EQ(test::make_surface(depth)->region_id(0.01, 0.01), -1);
}

TEST(HapticSurface, RejectsBadInput) {
  const HeightField depth = make_field(3, 3, 0.01, 0, 0, [](double, double) { return 0.0; });
  const HeightField other = make_field(3, 4, 0.01, 0, 0, [](double, double) { return 0.0; });
  EXPECT_THROW(HapticSurface(SurfaceLayers{}, {}), InputError);
  EXPECT_THROW(HapticSurface(SurfaceLayers{&depth, &other, nullptr, nullptr, nullptr, nullptr}, {}),
               InputError);
  HeightField empty(GridGeometry{3, 3, 0, 0, 0.01});
  EXPECT_THROW(test::make_surface(empty), DegenerateInputError);
  SurfaceOptions bad;
  bad.texture_gain = -1.0;
  EXPECT_THROW(test::make_surface(depth, bad), ConfigError);
  bad.texture_gain = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(test::make_surface(depth, bad), ConfigError);
}

TEST(HapticSurface, SingleSampleGridIsAPlateauAboveTheFloor) {
  const HeightField depth = make_field(1, 1, 0.01, 0, 0, [](double, double) { return 0.003; });
  SurfaceOptions opt;
  opt.floor_margin_m = 0.001;
  const auto s = test::make_surface(depth, opt);
  EXPECT_NEAR(s->height(0.0, 0.0), 0.003, 1e-7);
  EXPECT_NEAR(s->height(0.005, 0.0), 0.0025, 1e-7);
  EXPECT_NEAR(s->height(0.02, 0.0), 0.002, 1e-7);
}

}  // namespace
}  // namespace hc::haptics
