// Cost of the surface-layer stage (envelope, texture, curvature, friction maps) on a synthetic
// n × n sinusoid depth grid with a large disc hole and 2 % scattered single-cell holes.
// Counters give the seconds of each step from the stage report (means over iterations).

#include "hc/pipeline/surface_layers.hpp"

#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdint>
#include <numbers>
#include <string>

namespace {

hc::HeightField sinusoid_with_holes(int n) {
  hc::GridGeometry g;
  g.rows = n;
  g.cols = n;
  g.cell_size_m = 0.1 / n;  // a 100 mm square
  g.x0_m = -0.05;
  g.y0_m = -0.05;
  hc::HeightField f(g);
  const double k_shape = 2 * std::numbers::pi / 0.02, k_texture = 2 * std::numbers::pi / 0.002;
  std::uint32_t rng = 12345;
  for (int r = 0; r < n; ++r) {
    for (int c = 0; c < n; ++c) {
      const double x = g.x_of_col(c), y = g.y_of_row(r);
      rng = rng * 1664525u + 1013904223u;
      const bool scattered = (rng >> 8) % 100 < 2;
      if (scattered || (x - 0.02) * (x - 0.02) + y * y < 0.015 * 0.015) continue;
      f.at(r, c) = static_cast<float>(0.1 + 0.002 * std::sin(k_shape * x) * std::sin(k_shape * y) +
                                      0.00005 * std::sin(k_texture * x) * std::cos(k_texture * y));
    }
  }
  return f;
}

void BM_SurfaceLayers(benchmark::State& state) {
  const hc::HeightField f = sinusoid_with_holes(static_cast<int>(state.range(0)));
  hc::pipeline::SurfaceLayerOptions options;
  double fill = 0, bilateral = 0, curvature = 0, friction = 0;
  for (auto _ : state) {
    auto result = hc::pipeline::compute_surface_layers(f, options);
    benchmark::DoNotOptimize(result.value.mu_d.data());
    for (const auto& [name, value] : result.report.figures) {
      if (name == "hole_fill_seconds") fill += value;
      if (name == "bilateral_seconds") bilateral += value;
      if (name == "curvature_seconds") curvature += value;
      if (name == "friction_seconds") friction += value;
    }
  }
  const auto avg = benchmark::Counter::kAvgIterations;
  state.counters["fill_s"] = benchmark::Counter(fill, avg);
  state.counters["bilateral_s"] = benchmark::Counter(bilateral, avg);
  state.counters["curvature_s"] = benchmark::Counter(curvature, avg);
  state.counters["friction_s"] = benchmark::Counter(friction, avg);
  state.counters["cells"] = static_cast<double>(f.geometry().cell_count());
}
BENCHMARK(BM_SurfaceLayers)->Arg(800)->Arg(1600)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
