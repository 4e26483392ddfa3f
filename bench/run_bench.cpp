// Every stage of the N = 800 run of configs/happy_buddha.yaml on the merged Happy Buddha
// (1.1 M points), each timed on its own input, plus the whole run (file to written scene,
// previews and report) and two baselines measured in the same process:
//   BM_Baseline_PclLoadPly        PCL's loadPLYFile on the decompressed PLY (the reference reader);
//   BM_Baseline_PclOutliers       PCL's StatisticalOutlierRemoval, k = 16, σ = 2 (the reference filter).
// Compare medians: BM_Stage_Ingest / BM_Baseline_PclLoadPly (our ingest includes gunzip) and
// BM_Stage_Outliers / BM_Baseline_PclOutliers. The floor (issue 16): BM_Floor_ReadAndBin, one
// read of the file as the run reads it (load_cloud: gunzip and parse) and one front-most binning
// pass of its points into the run's N; BM_WholeRun prints floor_ratio, its own median iteration
// over the floor's median measured in the same process just before. Wall time (UseRealTime), 5 repetitions; read the
// medians. Not part of ctest. Run: build/release/bench/run_bench [--benchmark_filter=...]

#include "hc/pipeline/config.hpp"
#include "hc/pipeline/cross_check.hpp"
#include "hc/pipeline/filters.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/session/level_timing.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/pipeline/surface_layers.hpp"
#include "hc/pipeline/transform.hpp"

#include <benchmark/benchmark.h>
#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_types.h>
#include <zlib.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <vector>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>

namespace {

namespace fs = std::filesystem;
using namespace hc::pipeline;

const fs::path kConfig = fs::path(HC_SOURCE_DIR) / "configs" / "happy_buddha.yaml";

/// Every intermediate result of one run, computed once (the config's own options).
struct Intermediates {
  RunConfig config;
  Cloud loaded, recentred, transformed, finite, filtered;
  DepthGrid grid, filled;
  SurfaceLayers layers;
};

const Intermediates& run_once() {
  static const std::unique_ptr<Intermediates> r = [] {
    auto i = std::make_unique<Intermediates>();
    i->config = load_run_config(kConfig);
    i->loaded = load_cloud(i->config.input.files.front()).value;
    Eigen::Vector3d offset;
    i->recentred = to_metres_and_recentre(i->loaded, 1.0, &offset).value;
    i->transformed = apply_view_transform(i->recentred, i->config.view).value;
    i->finite = remove_non_finite(i->transformed).value;
    i->filtered = remove_statistical_outliers(i->finite, i->config.filters.outliers.k,
                                              i->config.filters.outliers.std_multiplier).value;
    i->grid = reproject(i->filtered, i->config.grid.reproject).value;
    i->filled = fill_holes(i->grid, i->config.grid.hole_fill_max_cells).value;
    i->layers = compute_surface_layers(i->filled.depth, i->config.layers.options).value;
    return i;
  }();
  return *r;
}

#define HC_STAGE(name, body)                         \
  void name(benchmark::State& state) {               \
    const Intermediates& in = run_once();            \
    for (auto _ : state) {                           \
      auto out = body;                               \
      benchmark::DoNotOptimize(out);                 \
    }                                                \
  }

HC_STAGE(BM_Stage_Ingest, load_cloud(in.config.input.files.front()))
HC_STAGE(BM_Stage_Recentre, ([&] { Eigen::Vector3d o; return to_metres_and_recentre(in.loaded, 1.0, &o); }()))
HC_STAGE(BM_Stage_Transform, apply_view_transform(in.recentred, in.config.view))
HC_STAGE(BM_Stage_NonFinite, remove_non_finite(in.transformed))
HC_STAGE(BM_Stage_Outliers, remove_statistical_outliers(in.finite, 16, 2.0))
/// Outliers with scope front; counters: the grid cells (depth or flag) that differ from those of
/// scope all, the points tested, and the threshold's relative deviation from the full one.
void BM_Stage_OutliersFront(benchmark::State& state) {
  const Intermediates& in = run_once();
  StageResult<Cloud> front;
  for (auto _ : state) {
    front = remove_front_statistical_outliers(in.finite, 16, 2.0, in.config.grid.reproject);
    benchmark::DoNotOptimize(front);
  }
  const auto all = remove_statistical_outliers(in.finite, 16, 2.0);
  const DepthGrid a = reproject(all.value, in.config.grid.reproject).value;
  const DepthGrid f = reproject(front.value, in.config.grid.reproject).value;
  double differ = a.depth.geometry() == f.depth.geometry() ? 0.0 : -1.0;
  for (std::size_t i = 0; differ >= 0.0 && i < a.flags.size(); ++i) {
    const float x = a.depth.values()[i], y = f.depth.values()[i];
    if (!((std::isnan(x) && std::isnan(y)) || x == y) || a.flags[i] != f.flags[i]) differ += 1.0;
  }
  auto fig = [](const StageReport& r, const char* name) {
    for (const auto& [k, v] : r.figures) {
      if (k == name) return v;
    }
    return std::nan("");
  };
  state.counters["cells_differing"] = differ;  // -1: different geometry
  state.counters["tested"] = fig(front.report, "tested");
  state.counters["removed_front"] = fig(front.report, "removed");
  state.counters["removed_all"] = fig(all.report, "removed");
  state.counters["threshold_rel_err"] = fig(front.report, "threshold_mm") / fig(all.report, "threshold_mm") - 1.0;
}
HC_STAGE(BM_Stage_Reproject, reproject(in.filtered, in.config.grid.reproject))
HC_STAGE(BM_Stage_HoleFill, fill_holes(in.grid, in.config.grid.hole_fill_max_cells))
HC_STAGE(BM_Stage_SurfaceLayers, compute_surface_layers(in.filled.depth, in.config.layers.options))
HC_STAGE(BM_Stage_CrossCheck, cross_check(in.filtered, in.filled.depth, in.config.cross_check.tolerance_m))

void BM_Stage_WriteScene(benchmark::State& state) {
  const Intermediates& in = run_once();
  Scene scene;
  scene.geometry = in.filled.depth.geometry();
  scene.layers.depth = in.filled.depth;
  scene.layers.envelope = in.layers.envelope_m;
  scene.layers.texture = in.layers.texture_m;
  scene.layers.mu_d = in.layers.mu_d;
  scene.layers.mu_s = in.layers.mu_s;
  scene.layers.flags = in.filled.flags;
  const fs::path dir = fs::temp_directory_path() / "hapticloud-bench-scene";
  for (auto _ : state) {
    fs::remove_all(dir);
    write_scene(scene, dir);
  }
  fs::remove_all(dir);
}

/// The floor of a run: read the file as the run does, then bin every point's z front-most into
/// an N-cell grid over the points' x-y box (N = the config's grid.n on the longer side). [s]
double read_and_bin_seconds(const RunConfig& cfg) {
  const auto t0 = std::chrono::steady_clock::now();
  const Cloud c = load_cloud(cfg.input.files.front()).value;
  double x0 = INFINITY, x1 = -INFINITY, y0 = INFINITY, y1 = -INFINITY;
  const double* p = c.xyz.data();
  for (std::size_t i = 0; i < c.size(); ++i) {
    x0 = std::min(x0, p[3 * i]), x1 = std::max(x1, p[3 * i]);
    y0 = std::min(y0, p[3 * i + 1]), y1 = std::max(y1, p[3 * i + 1]);
  }
  const int n = cfg.grid.reproject.grid.n_long_side;
  const double cell = std::max(x1 - x0, y1 - y0) / (n - 1);
  const int cols = static_cast<int>((x1 - x0) / cell) + 1, rows = static_cast<int>((y1 - y0) / cell) + 1;
  std::vector<float> z(static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols), -INFINITY);
  for (std::size_t i = 0; i < c.size(); ++i) {
    const int col = static_cast<int>((p[3 * i] - x0) / cell + 0.5), row = static_cast<int>((p[3 * i + 1] - y0) / cell + 0.5);
    if (col < 0 || col >= cols || row < 0 || row >= rows) continue;
    float& v = z[static_cast<std::size_t>(row) * static_cast<std::size_t>(cols) + static_cast<std::size_t>(col)];
    v = std::max(v, static_cast<float>(p[3 * i + 2]));
  }
  benchmark::DoNotOptimize(z.data());
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

double median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

void BM_Floor_ReadAndBin(benchmark::State& state) {
  const RunConfig cfg = load_run_config(kConfig);
  for (auto _ : state) benchmark::DoNotOptimize(read_and_bin_seconds(cfg));
}

/// The whole run with the config's outlier scope, or scope all / front forced (for comparison).
void whole_run(benchmark::State& state, const std::vector<std::string>& overrides) {
  const RunConfig cfg = load_run_config(kConfig, overrides);
  const fs::path out = fs::temp_directory_path() / "hapticloud-bench-run";
  std::vector<double> floor_s, run_s;
  for (int i = 0; i < 3; ++i) floor_s.push_back(read_and_bin_seconds(cfg));
  double cross_rms = 0, cross_p95 = 0;
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    const RunSummary s = run_pipeline(cfg, out, {}, ExistingOutput::kRefuse, hc::session::servo_level_timing());
    run_s.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    cross_rms = s.cross_check->point_vertical.rms_mm;
    cross_p95 = s.cross_check->point_vertical.p95_mm;
  }
  state.counters["rms_mm"] = cross_rms;
  state.counters["p95_mm"] = cross_p95;
  state.counters["floor_ms"] = 1e3 * median(floor_s);
  state.counters["floor_ratio"] = median(run_s) / median(floor_s);
  fs::remove_all(out);
}
void BM_WholeRun(benchmark::State& state) { whole_run(state, {}); }
void BM_WholeRun_ScopeAll(benchmark::State& state) {
  whole_run(state, {"filters.outliers.method=statistical", "filters.outliers.scope=all"});  // exact SOR
}
void BM_WholeRun_ScopeFront(benchmark::State& state) {
  whole_run(state, {"filters.outliers.method=statistical", "filters.outliers.scope=front"});  // front: statistical only
}

/// Decompresses the .ply.gz once into a temporary .ply for PCL's reader.
fs::path plain_ply() {
  static const fs::path p = [] {
    const fs::path out = fs::temp_directory_path() / "hapticloud-bench-buddha.ply";
    gzFile in = gzopen(run_once().config.input.files.front().c_str(), "rb");
    std::ofstream o(out, std::ios::binary);
    char buf[1 << 16];
    for (int n; (n = gzread(in, buf, sizeof buf)) > 0;) o.write(buf, n);
    gzclose(in);
    return out;
  }();
  return p;
}

void BM_Baseline_PclLoadPly(benchmark::State& state) {
  const fs::path p = plain_ply();
  for (auto _ : state) {
    pcl::PointCloud<pcl::PointXYZ> cloud;
    pcl::io::loadPLYFile(p.string(), cloud);
    benchmark::DoNotOptimize(cloud.size());
  }
}

void BM_Baseline_PclOutliers(benchmark::State& state) {
  const Cloud& c = run_once().finite;
  auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  cloud->resize(c.size());
  for (std::size_t i = 0; i < c.size(); ++i) {
    const auto col = c.xyz.col(static_cast<Eigen::Index>(i)).cast<float>();
    (*cloud)[i] = pcl::PointXYZ(col.x(), col.y(), col.z());
  }
  for (auto _ : state) {
    pcl::StatisticalOutlierRemoval<pcl::PointXYZ> sor;
    sor.setInputCloud(cloud);
    sor.setMeanK(16);
    sor.setStddevMulThresh(2.0);
    pcl::PointCloud<pcl::PointXYZ> out;
    sor.filter(out);
    benchmark::DoNotOptimize(out.size());
  }
}

#define HC_SETTINGS UseRealTime()->Unit(benchmark::kMillisecond)->Repetitions(5)->ReportAggregatesOnly(true)
BENCHMARK(BM_Stage_Ingest)->HC_SETTINGS;
BENCHMARK(BM_Stage_Recentre)->HC_SETTINGS;
BENCHMARK(BM_Stage_Transform)->HC_SETTINGS;
BENCHMARK(BM_Stage_NonFinite)->HC_SETTINGS;
BENCHMARK(BM_Stage_Outliers)->HC_SETTINGS;
BENCHMARK(BM_Stage_OutliersFront)->HC_SETTINGS;
BENCHMARK(BM_Stage_Reproject)->HC_SETTINGS;
BENCHMARK(BM_Stage_HoleFill)->HC_SETTINGS;
BENCHMARK(BM_Stage_SurfaceLayers)->HC_SETTINGS;
BENCHMARK(BM_Stage_CrossCheck)->HC_SETTINGS;
BENCHMARK(BM_Stage_WriteScene)->HC_SETTINGS;
BENCHMARK(BM_Floor_ReadAndBin)->HC_SETTINGS;
BENCHMARK(BM_WholeRun)->HC_SETTINGS;
BENCHMARK(BM_WholeRun_ScopeAll)->HC_SETTINGS;
BENCHMARK(BM_WholeRun_ScopeFront)->HC_SETTINGS;
BENCHMARK(BM_Baseline_PclLoadPly)->HC_SETTINGS;
BENCHMARK(BM_Baseline_PclOutliers)->Iterations(1)->HC_SETTINGS;

}  // namespace

BENCHMARK_MAIN();
