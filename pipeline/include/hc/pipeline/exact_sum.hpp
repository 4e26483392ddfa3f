#pragma once
// The exact sum of many floats, whatever their order (issue 14: a level's mean height summed
// tile by tile, in parallel, or fused into the pass that writes the level, and still the very
// bits the whole-grid sum gives).

#include <array>
#include <cstdint>

namespace hc::pipeline {

/// An exact accumulator of float values: every finite float is m · 2^e with an integer |m| <
/// 2^24 and e in [−149, 104] (IEEE 754-2019 §3.4, binary32), so the sum is kept as one signed
/// 64-bit integer count of m per exponent, exact and independent of the order of the additions
/// and of how the values are split between accumulators (merge). value() rounds the exact sum to
/// the nearest double, ties to even, once (a "superaccumulator"; the idea as in Kulisch's long
/// accumulator and Neal, "Fast exact summation using small and large superaccumulators", 2015).
///
/// Units: those of the values. Non-finite values are the caller's to skip; add() of an infinity
/// or NaN is std::invalid_argument. add() normalises the counts every 2^38 additions, so any
/// number of values is exact while |sum| stays below 2^166 (about 10^50; the float maximum is
/// about 2^128).
/// Cost: O(1) per add (a few integer operations), O(256) per merge and value().
class ExactFloatSum {
 public:
  /// Adds finite `v`. @throws std::invalid_argument for an infinity or NaN.
  void add(float v);
  /// Adds `other`'s sum (exact: the result is as if its values had been added here).
  void merge(const ExactFloatSum& other);
  /// The exact sum rounded to the nearest double (ties to even); +0 for no value or an exact 0.
  [[nodiscard]] double value() const;

 private:
  void normalise();
  // bins_[b]: the count of 2^(max(b, 1) − 150) units from floats with biased exponent b.
  std::array<std::int64_t, 256> bins_{};
  std::uint64_t since_normalised_ = 0;
};

}  // namespace hc::pipeline
