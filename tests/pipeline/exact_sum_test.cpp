// ExactFloatSum (issue 14): the exact sum of floats, rounded once to the nearest double.
// Oracle: Shewchuk's exact summation by non-overlapping partials with a correctly rounded final
// step (J. R. Shewchuk, "Adaptive precision floating-point arithmetic and fast robust geometric
// predicates", 1997; the half-way correction as Python's math.fsum documents it), an
// independent algorithm in double arithmetic, written here from the paper; and values whose exact
// sums are known by construction.

#include "hc/pipeline/exact_sum.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

namespace exact_sum_test {

using hc::pipeline::ExactFloatSum;

/// Correctly rounded sum of `values` (as doubles) by Shewchuk's partials.
double shewchuk_sum(const std::vector<float>& values) {
  std::vector<double> partials;
  for (const float f : values) {
    double x = f;
    std::size_t i = 0;
    for (double y : partials) {
      if (std::fabs(x) < std::fabs(y)) std::swap(x, y);
      const double hi = x + y;
      const double lo = y - (hi - x);
      if (lo != 0.0) partials[i++] = lo;
      x = hi;
    }
    partials.resize(i);
    partials.push_back(x);
  }
  // The partials are non-overlapping and increasing in magnitude: sum from the top, then correct
  // a result that lies exactly half-way between two doubles by the sign of what remains.
  std::size_t n = partials.size();
  if (n == 0) return 0.0;
  double hi = partials[--n], lo = 0.0;
  while (n > 0) {
    const double x = hi, y = partials[--n];
    hi = x + y;
    lo = y - (hi - x);
    if (lo != 0.0) break;
  }
  if (n > 0 && ((lo < 0.0 && partials[n - 1] < 0.0) || (lo > 0.0 && partials[n - 1] > 0.0))) {
    const double y = lo * 2.0, x = hi + y;
    if (y == x - hi) hi = x;
  }
  return hi;
}

double exact_of(const std::vector<float>& values) {
  ExactFloatSum s;
  for (const float v : values) s.add(v);
  return s.value();
}

std::uint64_t bits_of(double d) {
  std::uint64_t b;
  std::memcpy(&b, &d, sizeof b);
  return b;
}

/// `n` floats with random signs and magnitudes spread log-uniformly over 10^lo … 10^hi.
std::vector<float> random_floats(std::size_t n, double lo, double hi, double negative_share, std::uint32_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> e(lo, hi), u(0.0, 1.0);
  std::vector<float> v(n);
  for (float& x : v) {
    x = static_cast<float>(std::pow(10.0, e(rng)));
    if (u(rng) < negative_share) x = -x;
  }
  return v;
}

TEST(ExactFloatSum, EqualsTheCorrectlyRoundedSumOverTheWholeFloatRange) {
  // Magnitudes from subnormal to near the float maximum, signs mixed: massive cancellation.
  for (std::uint32_t seed = 1; seed <= 6; ++seed) {
    const std::vector<float> v = random_floats(20000, -44.0, 37.0, 0.5, seed);
    EXPECT_EQ(bits_of(exact_of(v)), bits_of(shewchuk_sum(v))) << "seed " << seed;
  }
  // Heights in metres as a level holds them: a naive double sum of these differs in its last bits.
  for (std::uint32_t seed = 7; seed <= 10; ++seed) {
    std::vector<float> v = random_floats(200000, -4.0, 1.0, seed % 2 == 0 ? 0.0 : 0.3, seed);
    const double exact = shewchuk_sum(v);
    EXPECT_EQ(bits_of(exact_of(v)), bits_of(exact)) << "seed " << seed;
  }
}

TEST(ExactFloatSum, TheOrderAndTheSplitBetweenAccumulatorsDoNotChangeABit) {
  std::vector<float> v = random_floats(50000, -6.0, 3.0, 0.4, 42);
  const double whole = exact_of(v);
  double naive_forward = 0.0, naive_backward = 0.0;
  for (const float x : v) naive_forward += x;
  for (auto it = v.rbegin(); it != v.rend(); ++it) naive_backward += *it;
  // The naive sums depend on the order here (otherwise this test would show nothing).
  ASSERT_NE(bits_of(naive_forward), bits_of(naive_backward));
  std::mt19937 rng(3);
  for (int round = 0; round < 5; ++round) {
    std::shuffle(v.begin(), v.end(), rng);
    // Split into 7 uneven parts, summed apart and merged in a scrambled order.
    std::vector<ExactFloatSum> parts(7);
    for (std::size_t i = 0; i < v.size(); ++i) parts[(i * i + 3 * i) % 7].add(v[i]);
    ExactFloatSum merged;
    for (const std::size_t p : {4U, 0U, 6U, 2U, 5U, 1U, 3U}) merged.merge(parts[p]);
    EXPECT_EQ(bits_of(merged.value()), bits_of(whole)) << "round " << round;
    EXPECT_EQ(bits_of(exact_of(v)), bits_of(whole)) << "round " << round;
  }
}

TEST(ExactFloatSum, HardCasesWithKnownSums) {
  // Cancellation a double sum loses: 10^30 + 1 − 10^30 is 1 (naively 0).
  EXPECT_EQ(exact_of({1e30f, 1.0f, -1e30f}), 1.0);
  // Ties to even: 2^53 + 1 lies half-way between 2^53 and 2^53 + 2.
  const float two53 = std::ldexp(1.0f, 53);
  EXPECT_EQ(exact_of({two53, 1.0f}), std::ldexp(1.0, 53));
  EXPECT_EQ(exact_of({two53, 1.0f, 2.0f}), std::ldexp(1.0, 53) + 4.0);  // 2^53 + 3: tie, to even (… + 4)
  // Just above the tie rounds up: 2^53 + 1 + 2^−20.
  EXPECT_EQ(exact_of({two53, 1.0f, std::ldexp(1.0f, -20)}), std::ldexp(1.0, 53) + 2.0);
  // Just below it rounds down: 2^53 + 1 − 2^−20.
  EXPECT_EQ(exact_of({two53, 1.0f, -std::ldexp(1.0f, -20)}), std::ldexp(1.0, 53));
  // Subnormals: three of the smallest float are exactly 3 · 2^−149.
  const float tiny = std::numeric_limits<float>::denorm_min();
  EXPECT_EQ(exact_of({tiny, tiny, tiny}), 3.0 * std::ldexp(1.0, -149));
  // A negative sum, and one below a top unit (2^104) of magnitude.
  EXPECT_EQ(exact_of({-3.5f, 1.25f}), -2.25);
  EXPECT_EQ(exact_of({std::numeric_limits<float>::max(), std::numeric_limits<float>::max(), -tiny}),
            2.0 * static_cast<double>(std::numeric_limits<float>::max()));  // rounded: 2^−149 is far below the ulp
  // Nothing, and an exact zero: +0.
  EXPECT_EQ(bits_of(exact_of({})), bits_of(0.0));
  EXPECT_EQ(bits_of(exact_of({2.5f, -2.5f, -0.0f})), bits_of(0.0));
  // Integers (colours as floats): the plain sum is exact, whatever the order.
  std::vector<float> bytes;
  for (int i = 0; i < 100000; ++i) bytes.push_back(static_cast<float>((i * 37) % 256));
  double plain = 0.0;
  for (const float b : bytes) plain += b;
  EXPECT_EQ(exact_of(bytes), plain);
}

TEST(ExactFloatSum, RefusesNonFiniteValues) {
  ExactFloatSum s;
  EXPECT_THROW(s.add(std::numeric_limits<float>::quiet_NaN()), std::invalid_argument);
  EXPECT_THROW(s.add(-std::numeric_limits<float>::infinity()), std::invalid_argument);
  s.add(1.5f);
  EXPECT_EQ(s.value(), 1.5);
}

}  // namespace exact_sum_test
