// Speed against error of the gridding stages on the merged Happy Buddha (1.1 M points, front
// view: the file's frame after recentring, looking along −z, y up):
//   BM_Binning     one plain front-most binning pass over the points (geometry known): the
//                  baseline the reprojection is compared with;
//   BM_Reproject   the reprojection stage, naive (front-most only) and handled (splats and
//                  see-through test);
//   BM_FillHoles   hole filling of the handled grid;
//   BM_CrossCheck  the cross-check of the naive grid and of the handled, filled grid, with the
//                  error figures as counters so that speed sits beside error.
//   BM_ReprojectWall/M  plane splats (radius 1.2 cells, see-through 20 mm: bench/scale.py's
//                  options) at N = 800 on a generated wall of M million points in random order
//                  (generated_wall.hpp), against BM_BinningWall/M, the naive reprojection
//                  (front-most binning only) of the same points (the floor).
// Each at N = 200, 400, 800 and 1600 cells along the statue's height. Options are scaled so that
// they mean the same physical sizes at every N: splat radius 0.3 mm (just above the scans' point
// spacing; 1.2 cells at N = 800, none below 1 cell), see-through depth 2 mm over a ±0.75 mm
// window, holes up to 4 mm² filled (64 cells at N = 800), tolerance 0.5 mm, hidden band 2 mm.
// Wall time (UseRealTime), 5 repetitions; read the medians. Not part of ctest.
// Run: build/<dir>/bench/pipeline_bench [--benchmark_filter=...]

#include "hc/pipeline/cross_check.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/transform.hpp"

#include "generated_wall.hpp"

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <memory>
#include <string>
#include <vector>

namespace {

using hc::pipeline::Cloud;
using hc::pipeline::DepthGrid;
using hc::pipeline::ReprojectOptions;

constexpr double kSplatRadiusM = 0.3e-3;
constexpr double kSeeThroughDepthM = 2e-3;
constexpr double kSeeThroughHalfWindowM = 0.75e-3;
constexpr double kMaxHoleAreaM2 = 4e-6;
constexpr double kToleranceM = 0.5e-3;
constexpr double kHiddenBandM = 2e-3;

std::filesystem::path buddha_path() {
  return std::filesystem::path(HC_SOURCE_DIR) / "data" / "scans" / "happy_buddha" /
         "happy_stand_merged_1099005pts.ply.gz";
}

/// The recentred Buddha, loaded once; nullptr (and an error for the caller) if it is missing.
const Cloud* buddha() {
  static const std::unique_ptr<Cloud> cloud = []() -> std::unique_ptr<Cloud> {
    if (!std::filesystem::exists(buddha_path())) return nullptr;
    auto loaded = hc::pipeline::load_cloud(buddha_path());
    Eigen::Vector3d offset;
    auto recentred = hc::pipeline::to_metres_and_recentre(std::move(loaded.value), 1.0, &offset);
    return std::make_unique<Cloud>(std::move(recentred.value));
  }();
  return cloud.get();
}

bool have_buddha(benchmark::State& state) {
  if (buddha() != nullptr) return true;
  state.SkipWithError(("missing " + buddha_path().string() + ": run data/get-data").c_str());
  return false;
}

ReprojectOptions naive_options(int n) {
  ReprojectOptions o;
  o.grid.n_long_side = n;
  return o;
}

/// Cell size [m] of the grid at N (the statue's height is the longer side).
double cell_size_m(int n) {
  static std::vector<std::pair<int, double>> cache;
  for (const auto& [k, v] : cache) {
    if (k == n) return v;
  }
  const double cell = hc::pipeline::reproject(*buddha(), naive_options(n)).value.depth.cell_size_m();
  cache.emplace_back(n, cell);
  return cell;
}

ReprojectOptions handled_options(int n) {
  ReprojectOptions o = naive_options(n);
  const double cell = cell_size_m(n);
  o.splat_radius_cells = kSplatRadiusM / cell;
  o.see_through_depth_m = kSeeThroughDepthM;
  o.see_through_window_cells = std::max(1, static_cast<int>(std::lround(kSeeThroughHalfWindowM / cell)));
  return o;
}

int max_hole_cells(int n) {
  const double cell = cell_size_m(n);
  return std::max(1, static_cast<int>(std::lround(kMaxHoleAreaM2 / (cell * cell))));
}

double figure(const hc::pipeline::StageReport& r, const std::string& name) {
  for (const auto& [k, v] : r.figures) {
    if (k == name) return v;
  }
  return std::numeric_limits<double>::quiet_NaN();
}

void BM_Binning(benchmark::State& state) {
  if (!have_buddha(state)) return;
  const Cloud& cloud = *buddha();
  const hc::GridGeometry g =
      hc::pipeline::reproject(cloud, naive_options(static_cast<int>(state.range(0)))).value.depth.geometry();
  std::vector<float> depth(g.cell_count());
  for (auto _ : state) {
    std::fill(depth.begin(), depth.end(), -std::numeric_limits<float>::infinity());
    const double inv = 1.0 / g.cell_size_m;
    const double cx = 0.5 - g.x0_m * inv, cy = 0.5 - g.y0_m * inv;
    const double* p = cloud.xyz.data();
    for (std::size_t i = 0; i < cloud.size(); ++i, p += 3) {
      const auto c = static_cast<std::size_t>(p[0] * inv + cx);
      const auto r = static_cast<std::size_t>(p[1] * inv + cy);
      float& cell = depth[r * static_cast<std::size_t>(g.cols) + c];
      cell = std::max(cell, static_cast<float>(p[2]));
    }
    benchmark::DoNotOptimize(depth.data());
    benchmark::ClobberMemory();
  }
  state.counters["cells"] = static_cast<double>(g.cell_count());
  state.counters["points"] = static_cast<double>(cloud.size());
}

void BM_Reproject(benchmark::State& state) {
  if (!have_buddha(state)) return;
  const int n = static_cast<int>(state.range(0));
  const bool handled = state.range(1) != 0;
  const ReprojectOptions o = handled ? handled_options(n) : naive_options(n);
  hc::pipeline::StageResult<DepthGrid> r;
  for (auto _ : state) {
    r = hc::pipeline::reproject(*buddha(), o);
    benchmark::DoNotOptimize(r.value.depth.data());
  }
  state.SetLabel(handled ? "handled" : "naive");
  state.counters["cells_valid"] = figure(r.report, "cells_valid");
  state.counters["see_through"] = figure(r.report, "cells_see_through");
  state.counters["splatted"] = figure(r.report, "cells_splatted");
}

void BM_FillHoles(benchmark::State& state) {
  if (!have_buddha(state)) return;
  const int n = static_cast<int>(state.range(0));
  const DepthGrid grid = hc::pipeline::reproject(*buddha(), handled_options(n)).value;
  const int max_hole = max_hole_cells(n);
  hc::pipeline::StageResult<DepthGrid> r;
  double stage_s = 0.0;
  for (auto _ : state) {
    r = hc::pipeline::fill_holes(grid, max_hole);  // includes copying the grid in
    stage_s += r.report.seconds;
    benchmark::DoNotOptimize(r.value.depth.data());
  }
  state.counters["stage_ms"] = benchmark::Counter(stage_s * 1e3, benchmark::Counter::kAvgIterations);
  state.counters["max_hole"] = max_hole;
  state.counters["filled"] = figure(r.report, "cells_filled");
}

void BM_CrossCheck(benchmark::State& state) {
  if (!have_buddha(state)) return;
  const int n = static_cast<int>(state.range(0));
  const bool handled = state.range(1) != 0;
  const hc::HeightField grid =
      handled ? hc::pipeline::fill_holes(hc::pipeline::reproject(*buddha(), handled_options(n)).value,
                                         max_hole_cells(n))
                    .value.depth
              : hc::pipeline::reproject(*buddha(), naive_options(n)).value.depth;
  hc::pipeline::StageResult<hc::pipeline::CrossCheck> r;
  for (auto _ : state) {
    r = hc::pipeline::cross_check(*buddha(), grid, kToleranceM, kHiddenBandM);
    benchmark::DoNotOptimize(r.value.cell_error_m.data());
  }
  const hc::pipeline::CrossCheck& c = r.value;
  state.SetLabel(handled ? "handled+filled" : "naive");
  state.counters["vert_rms_mm"] = c.point_vertical.rms_mm;
  state.counters["vert_p95_mm"] = c.point_vertical.p95_mm;
  state.counters["vert_max_mm"] = c.point_vertical.max_mm;
  state.counters["norm_rms_mm"] = c.point_normal.rms_mm;
  state.counters["cell_rms_mm"] = c.cell_to_point.rms_mm;
  state.counters["cell_p95_mm"] = c.cell_to_point.p95_mm;
  state.counters["supported"] = c.supported_fraction;
  state.counters["pts_used"] = static_cast<double>(c.points_on_surface);
}

void grid_sizes(benchmark::internal::Benchmark* b) {
  for (int n : {200, 400, 800, 1600}) b->Arg(n);
}

void grid_sizes_and_modes(benchmark::internal::Benchmark* b) {
  for (int n : {200, 400, 800, 1600}) {
    b->Args({n, 0});
    b->Args({n, 1});
  }
}

/// The generated wall as a Cloud (points only), cached per M.
const Cloud& wall_cloud(int millions) {
  static std::vector<std::pair<int, std::unique_ptr<Cloud>>> cache;
  for (const auto& [m, c] : cache)
    if (m == millions) return *c;
  auto c = std::make_unique<Cloud>();
  c->xyz = hc::bench::generated_wall(millions);
  cache.emplace_back(millions, std::move(c));
  return *cache.back().second;
}

void BM_ReprojectWall(benchmark::State& state) {
  const Cloud& wall = wall_cloud(static_cast<int>(state.range(0)));
  ReprojectOptions o = naive_options(800);
  o.splat_radius_cells = 1.2;
  o.splat_mode = hc::pipeline::SplatMode::kPlane;
  o.see_through_depth_m = 0.02;
  hc::pipeline::StageResult<DepthGrid> r;
  for (auto _ : state) {
    r = hc::pipeline::reproject(wall, o);
    benchmark::DoNotOptimize(r.value.depth.data());
  }
  state.counters["cells_valid"] = figure(r.report, "cells_valid");
}

void BM_BinningWall(benchmark::State& state) {
  const Cloud& wall = wall_cloud(static_cast<int>(state.range(0)));
  const ReprojectOptions o = naive_options(800);
  hc::pipeline::StageResult<DepthGrid> r;
  for (auto _ : state) {
    r = hc::pipeline::reproject(wall, o);
    benchmark::DoNotOptimize(r.value.depth.data());
  }
  state.counters["cells_valid"] = figure(r.report, "cells_valid");
}

#define HC_BENCH_SETTINGS \
  Unit(benchmark::kMillisecond)->UseRealTime()->Repetitions(5)->DisplayAggregatesOnly(true)

BENCHMARK(BM_Binning)->Apply(grid_sizes)->HC_BENCH_SETTINGS;
BENCHMARK(BM_Reproject)->Apply(grid_sizes_and_modes)->HC_BENCH_SETTINGS;
BENCHMARK(BM_FillHoles)->Apply(grid_sizes)->HC_BENCH_SETTINGS;
BENCHMARK(BM_CrossCheck)->Apply(grid_sizes_and_modes)->HC_BENCH_SETTINGS;
BENCHMARK(BM_BinningWall)->Arg(1)->Arg(10)->HC_BENCH_SETTINGS->MeasureProcessCPUTime();
BENCHMARK(BM_ReprojectWall)->Arg(1)->Arg(10)->HC_BENCH_SETTINGS->MeasureProcessCPUTime();

}  // namespace

BENCHMARK_MAIN();
