// Scan-line corrugation against the point-to-surface error, per gridding mode, on the Happy
// Buddha at N = 800 (0.25 mm cells), with the example configs' other settings, layers off:
//   merged  configs/happy_buddha.yaml (1.1 M points of 15 registered views, unorganised):
//           grid.splat_mode disc (the grid before plane splats), interpolate, plane (the
//           config's mode)
//   raw     configs/buddha_raw_scans.yaml (the 15 range scans with their poses):
//           grid.organised splat (discs) and mesh (the config's mode)
// Counters (from the run's report): corrugation_um2 = max over x, y of the mean squared second
// difference of z (mesh_raster.hpp, corrugation()); normal_rms_mm = points-to-surface RMS along
// the normal (cross_check point_normal); cell_rms_mm = grid-to-points RMS; supported_pct; and
// reproject_s, the gridding stages' own wall time (summed: despike may grid twice). The benchmark time is the whole build_scene
// (read, filters, grid, cross-checks), wall and process CPU, 3 repetitions: read the medians.
// Not part of ctest. Run: build/<dir>/bench/corrugation_bench [--benchmark_filter=...]

#include "hc/pipeline/config.hpp"
#include "hc/pipeline/run.hpp"

#include <benchmark/benchmark.h>

#include <array>
#include <filesystem>
#include <string>
#include <vector>

namespace {

struct Case {
  const char* label;
  const char* config;  // under configs/
  const char* data;    // a file the config reads, under data/scans/
  std::vector<std::string> overrides;
};

const std::array<Case, 5>& cases() {
  static const std::array<Case, 5> all = {{
      {"merged/disc", "happy_buddha.yaml", "happy_buddha/happy_stand_merged_1099005pts.ply.gz", {"grid.splat_mode=disc"}},
      {"merged/interpolate", "happy_buddha.yaml", "happy_buddha/happy_stand_merged_1099005pts.ply.gz",
       {"grid.splat_mode=interpolate"}},
      {"merged/plane", "happy_buddha.yaml", "happy_buddha/happy_stand_merged_1099005pts.ply.gz", {"grid.splat_mode=plane"}},
      {"raw/splat", "buddha_raw_scans.yaml", "happy_buddha/raw_scans/happyStandRight.conf", {"grid.organised=splat"}},
      {"raw/mesh", "buddha_raw_scans.yaml", "happy_buddha/raw_scans/happyStandRight.conf", {"grid.organised=mesh"}},
  }};
  return all;
}

double figure_of(const hc::pipeline::BuiltScene& b, const std::string& stage, const std::string& name) {
  for (const auto& s : b.summary.stages) {
    if (s.stage != stage) continue;
    for (const auto& [k, v] : s.figures)
      if (k == name) return v;
  }
  return -1.0;
}

void BM_Corrugation(benchmark::State& state) {
  const Case& c = cases()[static_cast<std::size_t>(state.range(0))];
  state.SetLabel(c.label);
  const std::filesystem::path root(HC_SOURCE_DIR);
  if (!std::filesystem::exists(root / "data" / "scans" / c.data)) {
    state.SkipWithError(("missing data/scans/" + std::string(c.data) + ": run data/get-data").c_str());
    return;
  }
  std::vector<std::string> overrides = c.overrides;
  overrides.emplace_back("layers.enabled=false");
  const hc::pipeline::RunConfig config = hc::pipeline::load_run_config(root / "configs" / c.config, overrides);
  hc::pipeline::BuiltScene built;
  for (auto _ : state) built = hc::pipeline::build_scene(config);
  state.counters["corrugation_um2"] = figure_of(built, "corrugation", "corrugation_um2");
  state.counters["reproject_s"] = [&] {  // every gridding (a second one follows despike)
    double seconds = 0.0;
    for (const auto& s : built.summary.stages)
      if (s.stage == "reproject") seconds += s.seconds;
    return seconds;
  }();
  if (built.summary.cross_check) {
    state.counters["normal_rms_mm"] = built.summary.cross_check->point_normal.rms_mm;
    state.counters["cell_rms_mm"] = built.summary.cross_check->cell_to_point.rms_mm;
    state.counters["supported_pct"] = built.summary.cross_check->supported_fraction * 100.0;
  }
}

BENCHMARK(BM_Corrugation)
    ->DenseRange(0, 4)
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime()
    ->Repetitions(3)
    ->Iterations(1);

}  // namespace

BENCHMARK_MAIN();
