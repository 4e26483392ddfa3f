#pragma once
// Bit-for-bit comparison of two height fields (tiled against in-core runs, tile jobs against the
// in-process run).

#include "hc/common/height_field.hpp"

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

}  // namespace hc::test
