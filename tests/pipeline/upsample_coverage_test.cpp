// UpsampleCoverage (reproject.hpp) over a range of factors: the tiled run's plan decides factors
// 1 and 2 in one pass and reads the points again for 3 and more only when both fail. The oracle
// is reproject's own auto factor (auto_upsample_factor over the whole cloud in memory).

#include "hc/pipeline/reproject.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace upsample_coverage_test {

using hc::pipeline::Cloud;
using hc::pipeline::ReprojectOptions;
using hc::pipeline::UpsampleCoverage;

double figure(const hc::pipeline::StageReport& r, const std::string& name) {
  for (const auto& [k, v] : r.figures)
    if (k == name) return v;
  ADD_FAILURE() << "no figure " << name;
  return NAN;
}

TEST(UpsampleCoverage, TwoPassesOverRangesChooseReprojectsFactorAtEveryDensity) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int second_pass = 0;
  std::set<int> factors;
  for (const std::size_t n : {200000u, 40000u, 12000u, 5000u, 2500u, 1200u}) {
    Cloud c;
    c.xyz.resize(3, static_cast<Eigen::Index>(n));
    for (std::size_t i = 0; i < n; ++i) c.xyz.col(static_cast<Eigen::Index>(i)) << u(rng), 0.5 * u(rng), 0.01 * u(rng);
    ReprojectOptions o;
    o.grid.n_long_side = 301;
    o.upsample_factor = 0;
    const auto whole = hc::pipeline::reproject(c, o);
    const int want = static_cast<int>(figure(whole.report, "upsample_factor"));
    factors.insert(want);
    const hc::GridGeometry& g = whole.value.depth.geometry();
    // In chunks, as the plan streams them.
    const auto run = [&](int first, int last, double* coverage) {
      UpsampleCoverage cov(g, first, last);
      for (std::size_t at = 0; at < n; at += 777) cov.add(c.xyz.data() + 3 * at, std::min<std::size_t>(777, n - at));
      return cov.factor(coverage);
    };
    double coverage = 0.0;
    int got = run(1, 2, &coverage);
    if (got == 0) {
      ++second_pass;
      got = run(3, hc::pipeline::kMaxUpsampleFactor, &coverage);
    }
    EXPECT_EQ(got, want) << n << " points";
    EXPECT_EQ(coverage, figure(whole.report, "upsample_coverage")) << n << " points";
    double one_pass = 0.0;
    EXPECT_EQ(run(1, hc::pipeline::kMaxUpsampleFactor, &one_pass), want);
    EXPECT_EQ(one_pass, coverage);
  }
  EXPECT_GT(second_pass, 0);           // the second pass was needed and taken
  EXPECT_GE(factors.size(), 3U);       // factors 1, 2 and beyond among the densities
}

// The tiled run's far-cluster pass asks only whether the factor is still K (the plan's): the
// range 1..K answers K exactly when reproject's own auto factor (the oracle: the whole cloud in
// memory) is K, for every K, at densities whose factors are 1 to 16, and on a grid of 19 nodes
// across, where the sparsest clouds stop at a factor whose next one's grid is too small (12 and
// 25 points: without that rule, factor() answers 0 and this test fails).
TEST(UpsampleCoverage, FactorsOneToKAnswerKExactlyWhenTheWholeRangeDoes) {
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::set<int> seen;
  for (const int side : {301, 19}) {
    for (const std::size_t n : {200000u, 12000u, 2500u, 1200u, 300u, 60u, 25u, 12u}) {
      Cloud c;
      c.xyz.resize(3, static_cast<Eigen::Index>(n));
      for (std::size_t i = 0; i < n; ++i) c.xyz.col(static_cast<Eigen::Index>(i)) << u(rng), 0.5 * u(rng), 0.01 * u(rng);
      ReprojectOptions o;
      o.grid.n_long_side = side;
      o.upsample_factor = 0;
      const auto whole = hc::pipeline::reproject(c, o);
      const int want = static_cast<int>(figure(whole.report, "upsample_factor"));
      seen.insert(want);
      const hc::GridGeometry& g = whole.value.depth.geometry();
      for (int k = 1; k <= hc::pipeline::kMaxUpsampleFactor; ++k) {
        UpsampleCoverage cov(g, 1, k);
        cov.add(c.xyz.data(), n);
        double coverage = 0.0;
        const int got = cov.factor(&coverage);
        EXPECT_EQ(got == k, want == k) << side << " nodes, " << n << " points, range 1.." << k << ": " << got << ", whole " << want;
        if (want == k) {
          EXPECT_EQ(coverage, figure(whole.report, "upsample_coverage"));
        }
      }
    }
  }
  EXPECT_GE(seen.size(), 5U);  // factors 1, 3, 5 and beyond among the densities
}

TEST(UpsampleCoverage, AGridTooSmallForFactorThreeIsDecidedInTheFirstPass) {
  // 40 × 4 nodes: factor 3's grid has 2 rows, so reproject stops at factor 2 whatever the
  // coverage; the first pass must say so instead of asking for a second one.
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Cloud c;
  c.xyz.resize(3, 12);
  c.xyz.col(0) << 0.0, 0.0, 0.0;
  c.xyz.col(1) << 1.0, 0.075, 0.0;
  for (Eigen::Index i = 2; i < 12; ++i) c.xyz.col(i) << u(rng), 0.075 * u(rng), 0.0;
  ReprojectOptions o;
  o.grid.n_long_side = 40;
  o.upsample_factor = 0;
  const auto whole = hc::pipeline::reproject(c, o);
  const hc::GridGeometry& g = whole.value.depth.geometry();
  ASSERT_EQ(g.rows, 4);
  const int want = static_cast<int>(figure(whole.report, "upsample_factor"));
  ASSERT_EQ(want, 2);  // sparse: neither 1 nor 2 reaches the coverage, 3 is too small
  UpsampleCoverage first(g, 1, 2);
  first.add(c.xyz.data(), 12);
  double coverage = 0.0;
  EXPECT_EQ(first.factor(&coverage), want);
  EXPECT_EQ(coverage, figure(whole.report, "upsample_coverage"));
}

TEST(UpsampleCoverage, RejectsAnEmptyOrReversedRange) {
  hc::GridGeometry g{100, 100, 0.0, 0.0, 0.01};
  EXPECT_THROW(UpsampleCoverage(g, 0, 2), std::invalid_argument);
  EXPECT_THROW(UpsampleCoverage(g, 3, 2), std::invalid_argument);
  EXPECT_THROW(UpsampleCoverage(g, 1, hc::pipeline::kMaxUpsampleFactor + 1), std::invalid_argument);
}

// The bound the tiled run skips its read of the kept points by (tiled_run.cpp,
// factor_may_change): removing m of the points a factor's counts (O hit nodes off the border, I
// of them with their 4 neighbours hit) were taken from keeps its coverage within
// [(I − 5m) / (O − m), I / (O − m)]. The oracle: the kept points' coverage counted afresh
// (UpsampleCoverage over them, which the tests above hold to reproject's own choice). Random
// clouds at densities about the 0.9 threshold; m from 1 point to a fifth,
// removed at random and in a block (a hole: many nodes un-hit together). counts() equals
// coverage's figures: I / O is the coverage factor() reports.
TEST(UpsampleCoverage, RemovingPointsKeepsEachFactorsCoverageWithinTheBoundOfItsCounts) {
  std::mt19937 rng(13);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::size_t checked = 0, moved = 0;
  for (const std::size_t n : {60000u, 20000u, 9000u, 4000u}) {
    std::vector<double> xyz(3 * n);
    for (std::size_t i = 0; i < n; ++i) {
      xyz[3 * i] = u(rng);
      xyz[3 * i + 1] = 0.5 * u(rng);
      xyz[3 * i + 2] = 0.01 * u(rng);
    }
    Cloud c;
    c.xyz = Eigen::Map<const Eigen::Matrix3Xd>(xyz.data(), 3, static_cast<Eigen::Index>(n));
    ReprojectOptions o;
    o.grid.n_long_side = 301;
    o.upsample_factor = 0;
    const hc::GridGeometry g = hc::pipeline::reproject(c, o).value.depth.geometry();
    UpsampleCoverage all(g, 1, 4);
    all.add(xyz.data(), n);
    EXPECT_EQ(all.points(), n);
    for (const std::size_t m : {std::size_t{1}, n / 100, n / 20, n / 5}) {
      for (const bool block : {false, true}) {
        // The kept points: all but m, the removed ones at random or the m nearest x = 0.3.
        std::vector<std::size_t> order(n);
        for (std::size_t i = 0; i < n; ++i) order[i] = i;
        if (block) {
          std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return std::abs(xyz[3 * a] - 0.3) < std::abs(xyz[3 * b] - 0.3); });
        } else {
          std::shuffle(order.begin(), order.end(), rng);
        }
        std::vector<double> kept;
        for (std::size_t j = m; j < n; ++j) kept.insert(kept.end(), xyz.begin() + 3 * order[j], xyz.begin() + 3 * order[j] + 3);
        UpsampleCoverage now(g, 1, 4);
        now.add(kept.data(), kept.size() / 3);
        for (int k = 1; k <= 4; ++k) {
          const auto before = all.counts(k), after = now.counts(k);
          ASSERT_TRUE(before && after) << "factor " << k;
          const double oc = static_cast<double>((*before)[0]), ic = static_cast<double>((*before)[1]);
          const double md = static_cast<double>(m);
          const double cov = (*after)[0] == 0 ? 0.0 : static_cast<double>((*after)[1]) / static_cast<double>((*after)[0]);
          if (!(oc - md > 0.0)) continue;  // more removed than nodes hit: no bound (factor_may_change reads the points)
          EXPECT_GE(cov, (ic - 5.0 * md) / (oc - md) - 1e-12) << n << " points, m " << m << ", factor " << k << (block ? ", a block" : "");
          EXPECT_LE(cov, ic / (oc - md) + 1e-12) << n << " points, m " << m << ", factor " << k << (block ? ", a block" : "");
          moved += std::abs(cov - ic / oc) > 1e-3 ? 1U : 0U;
          ++checked;
        }
      }
    }
    // counts() behind factor(): the chosen factor's I / O is the coverage it reports.
    double coverage = 0.0;
    const int k = all.factor(&coverage);
    if (k >= 1 && k <= 4) {
      EXPECT_EQ(static_cast<double>((*all.counts(k))[1]) / static_cast<double>((*all.counts(k))[0]), coverage);
    }
  }
  EXPECT_GT(checked, 100U);  // of 128 (4 densities, 4 removals, 2 ways, 4 factors)
  EXPECT_GT(moved, 20U) << "the removals moved the coverages";
}

}  // namespace upsample_coverage_test
