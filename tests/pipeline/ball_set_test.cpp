// detail::BallSet (ball_set.hpp), the index of the tiled run's second look and of the robust
// test's tile check, against brute force over every ball: contains, margin and meets, on sets
// with small balls, balls too large for the fine grid, balls nested in others (which the index
// leaves out) and the same ball asked twice.

#include "ball_set.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

namespace ball_set_test {
namespace {

using hc::pipeline::detail::BallSet;
using Ball = BallSet::Ball;

bool brute_contains(const std::vector<Ball>& balls, const double* p) {
  return std::any_of(balls.begin(), balls.end(), [&](const Ball& b) {
    const double dx = p[0] - b[0], dy = p[1] - b[1], dz = p[2] - b[2];
    return dx * dx + dy * dy + dz * dz <= b[3] * b[3];
  });
}

// The largest R − |p − c| over the balls whose xy box holds p's xy; 0 when none (BallSet::margin).
double brute_margin(const std::vector<Ball>& balls, const double* p) {
  double best = 0.0;
  for (const Ball& b : balls) {
    if (std::abs(p[0] - b[0]) > b[3] || std::abs(p[1] - b[1]) > b[3]) continue;
    const double dx = p[0] - b[0], dy = p[1] - b[1], dz = p[2] - b[2];
    best = std::max(best, b[3] - std::sqrt(dx * dx + dy * dy + dz * dz));
  }
  return best;
}

bool brute_meets(const std::vector<Ball>& balls, const std::array<double, 6>& box) {
  return std::any_of(balls.begin(), balls.end(), [&](const Ball& s) {
    const double dx = std::max({box[0] - s[0], s[0] - box[1], 0.0}), dy = std::max({box[2] - s[1], s[1] - box[3], 0.0});
    const double dz = std::max({box[4] - s[2], s[2] - box[5], 0.0});
    return dx * dx + dy * dy + dz * dz <= s[3] * s[3];
  });
}

// Balls over a 1 m square: mostly small, some covering a quarter of it, each fourth one with
// balls nested inside it (as a stray's neighbours' balls lie inside its own), and repeats.
std::vector<Ball> random_balls(std::mt19937& rng, int n) {
  std::uniform_real_distribution<double> u(0.0, 1.0), z(-0.05, 0.05), small(0.002, 0.03), large(0.1, 0.3);
  std::vector<Ball> balls;
  for (int i = 0; i < n; ++i) {
    const Ball b{u(rng), u(rng), z(rng), i % 7 == 0 ? large(rng) : small(rng)};
    balls.push_back(b);
    if (i % 4 == 0) {
      std::uniform_real_distribution<double> f(0.0, 0.45);
      balls.push_back({b[0] + f(rng) * b[3], b[1] - f(rng) * b[3], b[2] + f(rng) * b[3], 0.5 * b[3]});
    }
    if (i % 9 == 0) balls.push_back(b);
  }
  return balls;
}

// The balls no other one holds (R + |c − c'| ≤ R'·(1 − 1e-12), or the same centre and a radius
// no larger), a repeated ball counted once: what BallSet keeps.
std::size_t brute_kept(const std::vector<Ball>& balls) {
  std::size_t n = 0;
  for (std::size_t j = 0; j < balls.size(); ++j) {
    const Ball& b = balls[j];
    bool inside = false;
    for (std::size_t i = 0; i < balls.size() && !inside; ++i) {
      if (i == j) continue;
      const Ball& a = balls[i];
      const double dx = b[0] - a[0], dy = b[1] - a[1], dz = b[2] - a[2];
      if (dx == 0.0 && dy == 0.0 && dz == 0.0) {
        inside = b[3] < a[3] || (b[3] == a[3] && i < j);
      } else {
        inside = b[3] + std::sqrt(dx * dx + dy * dy + dz * dz) <= a[3] * (1.0 - 1e-12);
      }
    }
    n += inside ? 0U : 1U;
  }
  return n;
}

// Every query against brute force, with the default budget of fine entries (every ball listed
// by fine cell in these sets), with none (every ball of more than 256 cells listed by coarse
// cell) and with one that runs out part way (the largest by fine cell, the rest by coarse).
TEST(BallSet, AgreesWithBruteForceAndLeavesOutBallsInsideOthers) {
  std::mt19937 rng(20261124);
  std::uniform_real_distribution<double> u(-0.1, 1.1), z(-0.2, 0.2), side(0.0, 0.05);
  for (int round = 0; round < 60; ++round) {
    const std::vector<Ball> balls = random_balls(rng, 10 + 15 * (round / 3));
    const BallSet set = round % 3 == 0 ? BallSet(balls) : BallSet(balls, round % 3 == 1 ? 0 : 3000);
    EXPECT_EQ(set.size(), brute_kept(balls)) << "the nested and repeated balls are left out";
    ASSERT_LT(brute_kept(balls), balls.size());
    for (int q = 0; q < 4000; ++q) {
      const double p[3] = {u(rng), u(rng), z(rng)};
      ASSERT_EQ(set.contains(p), brute_contains(balls, p)) << "round " << round << " query " << q;
      ASSERT_EQ(set.margin(p), brute_margin(balls, p)) << "round " << round << " query " << q;
    }
    // Points on the balls' own spheres (the boundary, where rounding decides): at the side, at
    // the poles (the z spans' ends) and in random directions, and just inside and outside them.
    std::normal_distribution<double> g(0.0, 1.0);
    for (const Ball& b : balls) {
      for (int d = 0; d < 12; ++d) {
        double v[3] = {1.0, 0.0, 0.0};
        if (d == 1 || d == 2) v[0] = 0.0, v[2] = d == 1 ? 1.0 : -1.0;
        if (d >= 3) v[0] = g(rng), v[1] = g(rng), v[2] = g(rng);
        const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        for (const double f : {1.0, 1.0 - 1e-15, 1.0 + 1e-15, 1.0 + 1e-9}) {
          const double p[3] = {b[0] + f * b[3] * v[0] / len, b[1] + f * b[3] * v[1] / len, b[2] + f * b[3] * v[2] / len};
          ASSERT_EQ(set.contains(p), brute_contains(balls, p)) << "round " << round << " direction " << d << " factor " << f;
        }
      }
    }
    const double inf = std::numeric_limits<double>::infinity();
    for (int q = 0; q < 500; ++q) {
      const double x = u(rng), y = u(rng);
      std::array<double, 4> box{x, x + side(rng), y, y + side(rng)};
      // Boxes of blocks and tiles at the grid's edge have infinite sides.
      if (q % 5 == 1) box[0] = -inf;
      if (q % 5 == 2) box[1] = inf;
      if (q % 5 == 3) box[2] = -inf;
      if (q % 5 == 4) box[3] = inf;
      ASSERT_EQ(set.meets(box), brute_meets(balls, {box[0], box[1], box[2], box[3], -inf, inf}));
      // A slab of the box (BlockCopies' blocks by z), open below or above now and then.
      const double z0 = z(rng);
      const std::array<double, 6> slab{box[0], box[1], box[2], box[3], q % 7 == 1 ? -inf : z0, q % 7 == 2 ? inf : z0 + side(rng)};
      ASSERT_EQ(set.meets(slab), brute_meets(balls, slab));
    }
  }
}

// The tiled run's gathering: a surface's small balls (about z = 0, the surface rippled) and
// strays' large balls behind it (centres 60 to 90 mm below, radii 40 to 80 mm), so that most
// cells list both and split them in z; some large balls reach through the surface. Queries on
// the surface, in the gap, behind it, and on the balls' spheres, against brute force.
TEST(BallSet, SplitsACellsBallsInZAndAgreesWithBruteForce) {
  std::mt19937 rng(20261128);
  std::uniform_real_distribution<double> u(0.0, 0.3), small(0.0008, 0.002), below(-0.09, -0.06), large(0.04, 0.08);
  std::normal_distribution<double> g(0.0, 1.0);
  const auto surface_z = [](double x, double y) { return 0.003 * std::sin(40.0 * x) * std::cos(30.0 * y); };
  for (int round = 0; round < 8; ++round) {
    std::vector<Ball> balls;
    for (int i = 0; i < 3000; ++i) {
      const double x = u(rng), y = u(rng);
      balls.push_back({x, y, surface_z(x, y) + 0.0005 * g(rng), small(rng)});
    }
    for (int i = 0; i < 20 + 10 * round; ++i) balls.push_back({u(rng), u(rng), below(rng), large(rng)});
    const BallSet set = round % 2 == 0 ? BallSet(balls) : BallSet(balls, 0);
    // With the default budget every ball is listed by fine cell, and a cell with both kinds splits; with
    // none the large balls go by coarse cell, and the fine lists hold the small ones alone.
    if (round % 2 == 0) {
      ASSERT_GT(set.cells_split(), 3000U) << "round " << round << ": cells with both kinds of ball split them in z";
    } else {
      ASSERT_LT(set.cells_split(), 200U) << "round " << round;
    }
    std::uniform_real_distribution<double> at(-0.02, 0.32), dz(-0.004, 0.004), deep(-0.2, 0.02);
    for (int q = 0; q < 40000; ++q) {
      const double x = at(rng), y = at(rng);
      const double p[3] = {x, y, q % 2 == 0 ? surface_z(x, y) + dz(rng) : deep(rng)};
      ASSERT_EQ(set.contains(p), brute_contains(balls, p)) << "round " << round << " query " << q;
      if (q % 8 == 0) {
        ASSERT_EQ(set.margin(p), brute_margin(balls, p)) << "round " << round << " query " << q;
      }
    }
    for (std::size_t k = 0; k < balls.size(); k += 7) {
      const Ball& b = balls[k];
      for (int d = 0; d < 6; ++d) {
        double v[3] = {g(rng), g(rng), g(rng)};
        if (d < 2) v[0] = 0.0, v[1] = 0.0, v[2] = d == 0 ? 1.0 : -1.0;  // the poles: a span's ends
        const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        for (const double f : {1.0, 1.0 - 1e-15, 1.0 + 1e-15}) {
          const double p[3] = {b[0] + f * b[3] * v[0] / len, b[1] + f * b[3] * v[1] / len, b[2] + f * b[3] * v[2] / len};
          ASSERT_EQ(set.contains(p), brute_contains(balls, p)) << "round " << round << " ball " << k << " direction " << d;
        }
      }
    }
  }
}

TEST(BallSet, OneBallAndNoBall) {
  const BallSet none(std::vector<Ball>{});
  const double p[3] = {0.0, 0.0, 0.0};
  EXPECT_TRUE(none.empty());
  EXPECT_FALSE(none.contains(p));
  EXPECT_EQ(none.margin(p), 0.0);
  const BallSet one(std::vector<Ball>{{0.0, 0.0, 0.0, 1.0}, {0.0, 0.0, 0.0, 1.0}});
  EXPECT_EQ(one.size(), 1U) << "the same ball twice is one";
  EXPECT_TRUE(one.contains(p));
  EXPECT_DOUBLE_EQ(one.margin(p), 1.0);
  const double out[3] = {0.8, 0.8, 0.0};
  EXPECT_FALSE(one.contains(out));
}

}  // namespace

}  // namespace ball_set_test
