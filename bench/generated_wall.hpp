#pragma once
// A generated carved wall for the benchmarks: M million points on 2 m × 1 m (x, y uniform;
// z = 3 mm relief + 0.5 mm Gaussian noise), in random order, as bench/scale.py's generated scans
// come (the worst order for a cache: neighbours in space are far apart in memory). Fixed seed;
// built once per M and kept for the program's life.

#include <Eigen/Core>

#include <cmath>
#include <memory>
#include <random>
#include <utility>
#include <vector>

namespace hc::bench {

inline const Eigen::Matrix3Xd& generated_wall(int millions) {
  static std::vector<std::pair<int, std::unique_ptr<Eigen::Matrix3Xd>>> cache;
  for (const auto& [m, w] : cache)
    if (m == millions) return *w;
  const auto n = static_cast<Eigen::Index>(millions) * 1000000;
  auto w = std::make_unique<Eigen::Matrix3Xd>(3, n);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> ux(-1.0, 1.0), uy(-0.5, 0.5);
  std::normal_distribution<double> noise(0.0, 0.5e-3);
  for (Eigen::Index i = 0; i < n; ++i) {
    const double x = ux(rng), y = uy(rng);
    (*w)(0, i) = x, (*w)(1, i) = y, (*w)(2, i) = 3e-3 * std::sin(40.0 * x) * std::cos(30.0 * y) + noise(rng);
  }
  cache.emplace_back(millions, std::move(w));
  return *cache.back().second;
}

}  // namespace hc::bench
