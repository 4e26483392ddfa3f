#include "hc/pipeline/exact_sum.hpp"

#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>

namespace hc::pipeline {

namespace {
constexpr std::uint64_t kNormaliseEvery = std::uint64_t{1} << 38;  // 2^38 · 2^24 < 2^63
constexpr int kTopBin = 254;                                       // the largest finite exponent
}  // namespace

void ExactFloatSum::add(float v) {
  std::uint32_t bits;
  std::memcpy(&bits, &v, sizeof bits);
  const std::uint32_t biased = (bits >> 23) & 0xFFu;
  if (biased == 0xFFu) {
    throw std::invalid_argument("ExactFloatSum::add: " + std::to_string(v) + " is not finite");
  }
  const std::int64_t m = static_cast<std::int64_t>(biased != 0 ? (bits & 0x7FFFFFu) | 0x800000u : bits & 0x7FFFFFu);
  // Subnormals (biased exponent 0) have the scale of exponent 1: 2^−149 per unit.
  bins_[biased != 0 ? biased : 1] += (bits >> 31) != 0 ? -m : m;
  if (++since_normalised_ == kNormaliseEvery) normalise();
}

// Carries every bin into the next, one bit at a time, so that bins 1 … 253 hold 0 or 1 and the
// top bin holds the signed rest. The represented sum does not change.
void ExactFloatSum::normalise() {
  for (int b = 1; b < kTopBin; ++b) {
    const std::int64_t q = bins_[static_cast<std::size_t>(b)] >> 1;  // floor division
    bins_[static_cast<std::size_t>(b)] -= 2 * q;
    bins_[static_cast<std::size_t>(b) + 1] += q;
  }
  since_normalised_ = 0;
}

void ExactFloatSum::merge(const ExactFloatSum& other) {
  normalise();
  ExactFloatSum o = other;
  o.normalise();
  // Bins 1 … 253 now hold at most 2; the top bins at most their sum: still far from 2^63 for
  // any realistic count (the top bin's unit is 2^104).
  for (std::size_t b = 0; b < bins_.size(); ++b) bins_[b] += o.bins_[b];
}

double ExactFloatSum::value() const {
  ExactFloatSum s = *this;
  s.normalise();
  bool negative = false;
  if (s.bins_[kTopBin] < 0) {
    // The sum is negative (the bins below add up to less than one top unit): take its magnitude.
    negative = true;
    for (std::int64_t& b : s.bins_) b = -b;
    s.normalise();
  }
  // The magnitude as bits in units of 2^−149: bin b (1 … 253) is bit b − 1; the top bin's count
  // is a non-negative integer at bit 253.
  constexpr int kBits = 253 + 64;
  std::array<std::uint8_t, kBits> bit{};
  for (int b = 1; b < kTopBin; ++b) bit[static_cast<std::size_t>(b - 1)] = static_cast<std::uint8_t>(s.bins_[static_cast<std::size_t>(b)]);
  const auto top = static_cast<std::uint64_t>(s.bins_[kTopBin]);
  for (int i = 0; i < 64; ++i) bit[static_cast<std::size_t>(253 + i)] = static_cast<std::uint8_t>((top >> i) & 1U);
  int h = kBits - 1;
  while (h >= 0 && bit[static_cast<std::size_t>(h)] == 0) --h;
  if (h < 0) return 0.0;
  std::uint64_t m = 0;
  int exponent = -149;  // of m's lowest bit
  if (h <= 52) {
    for (int i = h; i >= 0; --i) m = (m << 1) | bit[static_cast<std::size_t>(i)];
  } else {
    for (int i = h; i >= h - 52; --i) m = (m << 1) | bit[static_cast<std::size_t>(i)];
    const bool round = bit[static_cast<std::size_t>(h - 53)] != 0;
    bool sticky = false;
    for (int i = h - 54; i >= 0 && !sticky; --i) sticky = bit[static_cast<std::size_t>(i)] != 0;
    if (round && (sticky || (m & 1U) != 0)) ++m;  // to nearest, ties to even
    exponent += h - 52;
    if (m == (std::uint64_t{1} << 53)) {
      m >>= 1;
      ++exponent;
    }
  }
  const double magnitude = std::ldexp(static_cast<double>(m), exponent);
  return negative ? -magnitude : magnitude;
}

}  // namespace hc::pipeline
