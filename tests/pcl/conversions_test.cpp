// hc::pcl conversions (issue 18): every field both ways, bit for bit.
#include "hc/pcl/conversions.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>

namespace {

using hc::pipeline::Cloud;
using hc::pipeline::from_pcl;
using hc::pipeline::to_pcl;

std::uint32_t bits(float f) {
  std::uint32_t u = 0;
  std::memcpy(&u, &f, sizeof u);
  return u;
}

/// A cloud whose coordinates are exactly representable as float (float values widened), with
/// awkward values: negative zero, subnormal, the largest float, tiny and large magnitudes.
Cloud float_exact_cloud(std::size_t n) {
  std::mt19937 rng(18);
  std::uniform_real_distribution<float> u(-1000.0f, 1000.0f);
  std::uniform_int_distribution<int> byte(0, 255);
  Cloud c;
  c.xyz.resize(3, static_cast<Eigen::Index>(n));
  c.intensity.resize(n);
  c.rgb.resize(3 * n);
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) c.xyz(a, static_cast<Eigen::Index>(i)) = static_cast<double>(u(rng));
    c.intensity[i] = u(rng);
    for (int k = 0; k < 3; ++k) c.rgb[3 * i + static_cast<std::size_t>(k)] = static_cast<std::uint8_t>(byte(rng));
  }
  c.xyz(0, 0) = -0.0;
  c.xyz(1, 0) = static_cast<double>(std::numeric_limits<float>::denorm_min());
  c.xyz(2, 0) = static_cast<double>(std::numeric_limits<float>::max());
  c.intensity[0] = -0.0f;
  c.intensity[1] = std::numeric_limits<float>::denorm_min();
  return c;
}

template <class PointT>
void expect_xyz_bits(const Cloud& c, const pcl::PointCloud<PointT>& p) {
  ASSERT_EQ(p.size(), c.size());
  EXPECT_EQ(p.width, c.size());
  EXPECT_EQ(p.height, 1u);
  for (std::size_t i = 0; i < c.size(); ++i) {
    const auto col = static_cast<Eigen::Index>(i);
    ASSERT_EQ(bits(p[i].x), bits(static_cast<float>(c.xyz(0, col)))) << i;
    ASSERT_EQ(bits(p[i].y), bits(static_cast<float>(c.xyz(1, col)))) << i;
    ASSERT_EQ(bits(p[i].z), bits(static_cast<float>(c.xyz(2, col)))) << i;
  }
}

void expect_same_cloud_bits(const Cloud& a, const Cloud& b, bool intensity, bool rgb) {
  ASSERT_EQ(a.size(), b.size());
  // Bit-for-bit: memcmp of the double storage (so -0.0 and +0.0 differ).
  EXPECT_EQ(std::memcmp(a.xyz.data(), b.xyz.data(), sizeof(double) * static_cast<std::size_t>(a.xyz.size())), 0);
  if (intensity) {
    ASSERT_EQ(b.intensity.size(), a.size());
    EXPECT_EQ(std::memcmp(a.intensity.data(), b.intensity.data(), sizeof(float) * a.size()), 0);
  }
  if (rgb) {
    EXPECT_EQ(a.rgb, b.rgb);
  }
}

TEST(PclConversions, CloudToPclToCloudKeepsEveryCarriedFieldBitForBit) {
  const Cloud c = float_exact_cloud(5000);
  {
    pcl::PointCloud<pcl::PointXYZ> p;
    to_pcl(c, p);
    expect_xyz_bits(c, p);
    const Cloud back = from_pcl(p);
    expect_same_cloud_bits(c, back, false, false);
    EXPECT_FALSE(back.has_intensity());
    EXPECT_FALSE(back.has_rgb());
    EXPECT_TRUE(back.float32_xyz);
  }
  {
    pcl::PointCloud<pcl::PointXYZI> p;
    to_pcl(c, p);
    expect_xyz_bits(c, p);
    for (std::size_t i = 0; i < c.size(); ++i) ASSERT_EQ(bits(p[i].intensity), bits(c.intensity[i])) << i;
    const Cloud back = from_pcl(p);
    expect_same_cloud_bits(c, back, true, false);
    EXPECT_FALSE(back.has_rgb());
  }
  {
    pcl::PointCloud<pcl::PointXYZRGB> p;
    to_pcl(c, p);
    expect_xyz_bits(c, p);
    for (std::size_t i = 0; i < c.size(); ++i) {
      ASSERT_EQ(p[i].r, c.rgb[3 * i]);
      ASSERT_EQ(p[i].g, c.rgb[3 * i + 1]);
      ASSERT_EQ(p[i].b, c.rgb[3 * i + 2]);
      ASSERT_EQ(p[i].a, 255);
    }
    const Cloud back = from_pcl(p);
    expect_same_cloud_bits(c, back, false, true);
    EXPECT_FALSE(back.has_intensity());
  }
  {
    pcl::PointCloud<pcl::PointXYZRGBNormal> p;
    to_pcl(c, p);
    expect_xyz_bits(c, p);
    for (std::size_t i = 0; i < c.size(); ++i) {
      ASSERT_EQ(p[i].r, c.rgb[3 * i]);
      ASSERT_EQ(p[i].b, c.rgb[3 * i + 2]);
      ASSERT_EQ(p[i].normal_x, 0.0f);  // the Cloud has no normals: written as 0
      ASSERT_EQ(p[i].curvature, 0.0f);
    }
    const Cloud back = from_pcl(p);
    expect_same_cloud_bits(c, back, false, true);
  }
}

template <class PointT>
void fill_xyz(pcl::PointCloud<PointT>& p, std::size_t n, std::mt19937& rng) {
  std::uniform_real_distribution<float> u(-50.0f, 50.0f);
  p.resize(n);
  for (auto& q : p) {
    q.x = u(rng);
    q.y = u(rng);
    q.z = u(rng);
  }
}

TEST(PclConversions, PclToCloudToPclKeepsEveryCarriedFieldBitForBit) {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> byte(0, 255);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  pcl::PointCloud<pcl::PointXYZI> pi;
  fill_xyz(pi, 3000, rng);
  for (auto& q : pi) q.intensity = u(rng);
  pi[5].x = std::numeric_limits<float>::quiet_NaN();  // kept: the pipeline's non_finite stage drops it
  pcl::PointCloud<pcl::PointXYZI> pi2;
  to_pcl(from_pcl(pi), pi2);
  ASSERT_EQ(pi2.size(), pi.size());
  EXPECT_FALSE(pi2.is_dense);
  for (std::size_t i = 0; i < pi.size(); ++i) {
    if (i == 5) {
      EXPECT_TRUE(std::isnan(pi2[i].x));
    } else {
      ASSERT_EQ(bits(pi2[i].x), bits(pi[i].x));
    }
    ASSERT_EQ(bits(pi2[i].y), bits(pi[i].y));
    ASSERT_EQ(bits(pi2[i].z), bits(pi[i].z));
    ASSERT_EQ(bits(pi2[i].intensity), bits(pi[i].intensity));
  }

  pcl::PointCloud<pcl::PointXYZRGBNormal> pn;
  fill_xyz(pn, 3000, rng);
  std::normal_distribution<float> g(0.0f, 1.0f);
  for (auto& q : pn) {
    q.r = static_cast<std::uint8_t>(byte(rng));
    q.g = static_cast<std::uint8_t>(byte(rng));
    q.b = static_cast<std::uint8_t>(byte(rng));
    q.normal_x = g(rng);  // any float (not unit, not re-estimated): carried as given
    q.normal_y = g(rng);
    q.normal_z = g(rng);
    q.curvature = u(rng) / 3.0f;
  }
  pcl::PointCloud<pcl::PointXYZRGBNormal> pn2;
  to_pcl(from_pcl(pn), pn2);
  ASSERT_EQ(pn2.size(), pn.size());
  EXPECT_TRUE(pn2.is_dense);
  for (std::size_t i = 0; i < pn.size(); ++i) {
    ASSERT_EQ(bits(pn2[i].x), bits(pn[i].x));
    ASSERT_EQ(bits(pn2[i].y), bits(pn[i].y));
    ASSERT_EQ(bits(pn2[i].z), bits(pn[i].z));
    ASSERT_EQ(pn2[i].rgba, pn[i].rgba);  // r, g, b and a = 255 (PCL's default alpha)
    ASSERT_EQ(bits(pn2[i].normal_x), bits(pn[i].normal_x));
    ASSERT_EQ(bits(pn2[i].normal_y), bits(pn[i].normal_y));
    ASSERT_EQ(bits(pn2[i].normal_z), bits(pn[i].normal_z));
    ASSERT_EQ(bits(pn2[i].curvature), bits(pn[i].curvature));
  }

  // Organised PCL clouds are read row-major.
  pcl::PointCloud<pcl::PointXYZ> org(4, 3);
  for (std::size_t i = 0; i < org.size(); ++i) org[i] = pcl::PointXYZ(static_cast<float>(i), 0.5f, -1.0f);
  const Cloud c = from_pcl(org);
  ASSERT_EQ(c.size(), 12u);
  for (Eigen::Index i = 0; i < 12; ++i) EXPECT_EQ(c.xyz(0, i), static_cast<double>(i));
}

TEST(PclConversions, AbsentAttributesBecomeZeroAndDoublesRoundToNearestFloat) {
  Cloud c;
  c.xyz.resize(3, 2);
  c.xyz << 0.1, 1e6 + 0.3, 0.2, -2.0, 0.3, 7.0;
  pcl::PointCloud<pcl::PointXYZI> pi;
  to_pcl(c, pi);
  EXPECT_EQ(pi[0].intensity, 0.0f);
  EXPECT_EQ(pi[0].x, 0.1f);  // nearest float, as static_cast
  EXPECT_EQ(pi[1].x, static_cast<float>(1e6 + 0.3));
  pcl::PointCloud<pcl::PointXYZRGB> pr;
  to_pcl(c, pr);
  EXPECT_EQ(pr[1].r, 0);
  EXPECT_EQ(pr[1].a, 255);
}

}  // namespace
