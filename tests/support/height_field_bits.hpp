#pragma once
// Bit-for-bit comparison of two height fields (tiled against in-core runs, tile jobs against the
// in-process run).

#include "hc/common/height_field.hpp"
#include "hc/common/scene.hpp"

#include <gtest/gtest.h>

#include <bit>
#include <cstddef>
#include <cstdint>

namespace hc::test {

/// Cells whose float bit patterns differ (NaN payloads included); a geometry mismatch fails the
/// calling test and counts every cell of both.
inline std::size_t differing_bits(const hc::HeightField& a, const hc::HeightField& b) {
  EXPECT_EQ(a.geometry(), b.geometry());
  if (a.values().size() != b.values().size()) return a.values().size() + b.values().size();
  std::size_t n = 0;
  for (std::size_t i = 0; i < a.values().size(); ++i) {
    n += std::bit_cast<std::uint32_t>(a.values()[i]) != std::bit_cast<std::uint32_t>(b.values()[i]) ? 1U : 0U;
  }
  return n;
}

/// Expects the surface layers of two scenes equal: depth, envelope, texture, μ_d and μ_s bit for
/// bit, the intensity and region layers bit for bit where either scene has them, and the flags
/// and colour bytes.
inline void expect_same_layers(const hc::SceneLayers& a, const hc::SceneLayers& b) {
  EXPECT_EQ(differing_bits(a.depth, b.depth), 0U);
  EXPECT_EQ(a.intensity.values().size(), b.intensity.values().size());
  if (!a.intensity.values().empty() && a.intensity.values().size() == b.intensity.values().size()) {
    EXPECT_EQ(differing_bits(a.intensity, b.intensity), 0U);
  }
  EXPECT_EQ(a.region_id.values().size(), b.region_id.values().size());
  if (!a.region_id.values().empty() && a.region_id.values().size() == b.region_id.values().size()) {
    EXPECT_EQ(differing_bits(a.region_id, b.region_id), 0U);
  }
  EXPECT_EQ(a.flags, b.flags);
  EXPECT_EQ(a.colour_rgb8, b.colour_rgb8);
  EXPECT_EQ(differing_bits(a.envelope, b.envelope), 0U);
  EXPECT_EQ(differing_bits(a.texture, b.texture), 0U);
  EXPECT_EQ(differing_bits(a.mu_d, b.mu_d), 0U);
  EXPECT_EQ(differing_bits(a.mu_s, b.mu_s), 0U);
}

}  // namespace hc::test
