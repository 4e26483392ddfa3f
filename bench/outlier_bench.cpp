// The robust outlier filter against the exact statistical one (PCL's SOR, the baseline in the
// same run) on the merged Happy Buddha (1.1 M points, as configs/happy_buddha.yaml: k = 16,
// std_multiplier 2) with 2 % uniform outliers added in its bounding box (22 k points, fixed seed):
//   BM_ExactSor          remove_statistical_outliers (method statistical, scope all)
//   BM_RobustTest        remove_robust_outliers (the robust test alone)
//   BM_RobustOffSurface  the robust test with off_surface_ratio 0 (off), 1.5 and 2 (default)
//   BM_RobustAndFar/P    remove_outliers_robust (the robust test, then far-cluster removal: what
//                        build_scene runs with method robust) with P % clutter (0: the clean Buddha)
//   BM_PointStages/P     the same, then the isolated-point stage (the run's point stages before
//                        the grid)
//   BM_RunPointStages    build_scene with configs/happy_buddha.yaml on the 2 % cloud: every stage
//                        that removes points, the grid's despike step included (one run)
//   BM_MedianSpacing/M   median_point_spacing (the isolated stage's and the honest check's
//                        spacing) on a generated wall of M million points in random order (2 m ×
//                        1 m, 3 mm relief, 0.5 mm noise: bench/scale.py's walls), start edge 5 mm
//                        (twice the cell at N = 800); against BM_SpacingFloor/M, one pass that
//                        converts the same points to floats (the stage's first step)
// Counters: caught = injected outliers removed / injected; caught_beyond_2mm = the same for the
// injected points farther than 2 mm from every true point (clutter_beyond_2mm of them; the
// nearer ones lie within the scan's noise and spacing of its surface); lost = true points
// removed / true points; removed = points removed. Times: wall (UseRealTime) and process CPU over both threads
// (MeasureProcessCPUTime), 5 repetitions; read the medians. Not part of ctest.
// Run: build/<dir>/bench/outlier_bench [--benchmark_filter=...]

#include "hc/pipeline/config.hpp"
#include "hc/pipeline/filters.hpp"
#include "hc/pipeline/honest_check.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/robust_outliers.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/transform.hpp"

#include "generated_wall.hpp"

#include <benchmark/benchmark.h>
#include <nanoflann.hpp>

#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include <filesystem>
#include <memory>
#include <random>
#include <string>

namespace {

using hc::pipeline::Cloud;

std::filesystem::path buddha_path() {
  return std::filesystem::path(HC_SOURCE_DIR) / "data" / "scans" / "happy_buddha" / "happy_stand_merged_1099005pts.ply.gz";
}

/// The recentred Buddha plus `percent` % uniform outliers in its box (0 or 2), tagged intensity 1
/// (true points 0); nullptr if the scan is missing.
const Cloud* cluttered(int percent = 2) {
  static const auto make = [](double share) -> std::unique_ptr<Cloud> {
    if (!std::filesystem::exists(buddha_path())) return nullptr;
    auto loaded = hc::pipeline::load_cloud(buddha_path());
    Eigen::Vector3d offset;
    Cloud c = hc::pipeline::to_metres_and_recentre(std::move(loaded.value), 1.0, &offset).value;
    const auto n = c.xyz.cols();
    const auto extra = static_cast<Eigen::Index>(share * static_cast<double>(n));
    const Eigen::Vector3d lo = c.xyz.rowwise().minCoeff(), hi = c.xyz.rowwise().maxCoeff();
    auto out = std::make_unique<Cloud>();
    out->xyz.resize(3, n + extra);
    out->xyz.leftCols(n) = c.xyz;
    std::mt19937 rng(2);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (Eigen::Index i = 0; i < extra; ++i) {
      out->xyz.col(n + i) = lo + (hi - lo).cwiseProduct(Eigen::Vector3d(u(rng), u(rng), u(rng)));
    }
    out->intensity.assign(static_cast<std::size_t>(n), 0.0f);
    out->intensity.resize(static_cast<std::size_t>(n + extra), 1.0f);
    return out;
  };
  if (percent == 0) {
    static const std::unique_ptr<Cloud> clean = make(0.0);
    return clean.get();
  }
  static const std::unique_ptr<Cloud> two = make(0.02);
  return two.get();
}

bool have_buddha(benchmark::State& state) {
  if (cluttered() != nullptr) return true;
  state.SkipWithError(("missing " + buddha_path().string() + ": run data/get-data").c_str());
  return false;
}

/// Distance [m] from each listed point of `c` to the nearest true point (intensity 0) of the
/// cluttered Buddha: the oracle of which clutter stands off the surface.
class TrueSurface {
 public:
  TrueSurface() : tree_(3, *this, nanoflann::KDTreeSingleIndexAdaptorParams(16)) {}
  double distance(const Eigen::Vector3d& q) const {
    std::uint32_t index = 0;
    double d2 = 0.0;
    tree_.knnSearch(q.data(), 1, &index, &d2);
    return std::sqrt(d2);
  }
  // nanoflann's dataset interface.
  std::size_t kdtree_get_point_count() const { return truth().size(); }
  double kdtree_get_pt(std::size_t i, std::size_t dim) const { return truth()[i][static_cast<Eigen::Index>(dim)]; }
  template <class B>
  bool kdtree_get_bbox(B&) const {
    return false;
  }

 private:
  static const std::vector<Eigen::Vector3d>& truth() {
    static const std::vector<Eigen::Vector3d> t = [] {
      std::vector<Eigen::Vector3d> v;
      const Cloud& c = *cluttered(2);
      for (Eigen::Index i = 0; i < c.xyz.cols(); ++i) {
        if (c.intensity[static_cast<std::size_t>(i)] < 0.5f) v.emplace_back(c.xyz.col(i));
      }
      return v;
    }();
    return t;
  }
  nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, TrueSurface>, TrueSurface, 3, std::uint32_t> tree_;
};

// Clutter farther than this from every true point stands off the surface [m]; nearer clutter
// is indistinguishable from the scan's own noise and spacing (median k-NN distance 0.4 mm).
constexpr double kOffSurfaceM = 0.002;

void quality(benchmark::State& state, const Cloud& kept, int percent = 2) {
  const Cloud& in = *cluttered(percent);
  double injected = 0, truth = 0, kept_injected = 0, kept_truth = 0;
  for (const float t : in.intensity) (t > 0.5f ? injected : truth) += 1;
  for (const float t : kept.intensity) (t > 0.5f ? kept_injected : kept_truth) += 1;
  if (injected > 0) {
    state.counters["caught"] = (injected - kept_injected) / injected;
    // Of the clutter farther than kOffSurfaceM from the surface: the share removed.
    static const TrueSurface surface;
    static const double off = [&] {
      double n = 0;
      for (Eigen::Index i = 0; i < in.xyz.cols(); ++i) {
        if (in.intensity[static_cast<std::size_t>(i)] > 0.5f && surface.distance(in.xyz.col(i)) > kOffSurfaceM) n += 1;
      }
      return n;
    }();
    double kept_off = 0;
    for (Eigen::Index i = 0; i < kept.xyz.cols(); ++i) {
      if (kept.intensity[static_cast<std::size_t>(i)] > 0.5f && surface.distance(kept.xyz.col(i)) > kOffSurfaceM) kept_off += 1;
    }
    state.counters["caught_beyond_2mm"] = (off - kept_off) / off;
    state.counters["clutter_beyond_2mm"] = off;
    // The clutter's share within 0.5 and 1 mm of the surface (a few median k-NN distances): a
    // bound on what any point test can catch without taking true points.
    static const std::array<double, 2> near = [&] {
      std::array<double, 2> n{0.0, 0.0};
      for (Eigen::Index i = 0; i < in.xyz.cols(); ++i) {
        if (in.intensity[static_cast<std::size_t>(i)] < 0.5f) continue;
        const double d = surface.distance(in.xyz.col(i));
        n[0] += d <= 0.0005;
        n[1] += d <= 0.001;
      }
      return n;
    }();
    state.counters["clutter_within_0_5mm"] = near[0] / injected;
    state.counters["clutter_within_1mm"] = near[1] / injected;
    // Caught among the clutter farther than the Buddha config's cross-check tolerance (0.5 mm):
    // nearer clutter is on the surface by the cross-check's own measure.
    double kept_beyond_tol = 0;
    for (Eigen::Index i = 0; i < kept.xyz.cols(); ++i) {
      if (kept.intensity[static_cast<std::size_t>(i)] > 0.5f && surface.distance(kept.xyz.col(i)) > 0.0005) kept_beyond_tol += 1;
    }
    state.counters["caught_beyond_0_5mm"] = 1.0 - kept_beyond_tol / (injected - near[0]);
  }
  state.counters["lost"] = (truth - kept_truth) / truth;
  state.counters["removed"] = static_cast<double>(in.size() - kept.size());
}

void BM_ExactSor(benchmark::State& state) {
  if (!have_buddha(state)) return;
  Cloud kept;
  for (auto _ : state) kept = hc::pipeline::remove_statistical_outliers(*cluttered(), 16, 2.0).value;
  quality(state, kept);
}

void BM_RobustTest(benchmark::State& state) {
  if (!have_buddha(state)) return;
  Cloud kept;
  for (auto _ : state) kept = hc::pipeline::remove_robust_outliers(*cluttered(), {}).value;
  quality(state, kept);
}

// The robust test at off_surface_ratio = range(0) / 10 (0 = no off-surface test; the default
// is 2.0): outliers caught against true points lost, and the exact queries it costs.
void BM_RobustOffSurface(benchmark::State& state) {
  if (!have_buddha(state)) return;
  hc::pipeline::RobustOutlierOptions o;
  o.off_surface_ratio = static_cast<double>(state.range(0)) / 10.0;
  hc::pipeline::StageResult<Cloud> r;
  for (auto _ : state) r = hc::pipeline::remove_robust_outliers(*cluttered(), o);
  quality(state, r.value);
  for (const auto& [k, v] : r.report.figures) {
    if (k == "exact_queries" || k == "removed_off_surface") state.counters[k] = v;
  }
}

// Argument: the clutter added, in percent (0 = the clean Buddha, 2 = as the other benchmarks).
void BM_RobustAndFar(benchmark::State& state) {
  if (!have_buddha(state)) return;
  const auto percent = static_cast<int>(state.range(0));
  hc::pipeline::StageResult<Cloud> r;
  for (auto _ : state) r = hc::pipeline::remove_outliers_robust(*cluttered(percent), {}, {});
  quality(state, r.value, percent);
  for (const char* f : {"certified", "exact_queries", "local_tests", "grid_s", "sample_s", "certify_s", "exact_s", "local_s", "far_s"}) {
    for (const auto& [k, v] : r.report.figures) {
      if (k == f) state.counters[f] = v;
    }
  }
}

// The whole run's point stages on the cluttered Buddha (argument: percent, as BM_RobustAndFar):
// the robust test and far clusters, then the isolated-point stage (remove_isolated_points with
// the default honest-check options, as `hapticloud run`). The despike stage needs the grid and is
// not in it.
void BM_PointStages(benchmark::State& state) {
  if (!have_buddha(state)) return;
  const auto percent = static_cast<int>(state.range(0));
  Cloud kept;
  double isolated = 0;
  for (auto _ : state) {
    auto r = hc::pipeline::remove_outliers_robust(*cluttered(percent), {}, {});
    auto iso = hc::pipeline::remove_isolated_points(std::move(r.value), hc::pipeline::HonestCheckOptions{});
    isolated = static_cast<double>(iso.report.count_in - iso.report.count_out);
    kept = std::move(iso.value);
  }
  quality(state, kept, percent);
  state.counters["removed_isolated"] = isolated;
}

// Every point stage of the run, despike included: build_scene on the cluttered Buddha in memory
// with configs/happy_buddha.yaml (surface layers, cross-check and levels table off: they remove
// no points). The kept cloud is shifted back into the cluttered cloud's frame for the counters.
void BM_RunPointStages(benchmark::State& state) {
  if (!have_buddha(state)) return;
  hc::pipeline::RunConfig config = hc::pipeline::load_run_config(
      std::filesystem::path(HC_SOURCE_DIR) / "configs" / "happy_buddha.yaml",
      {"layers.enabled=false", "cross_check.enabled=false", "lod.report=false"});
  Cloud kept;
  double despiked = 0;
  for (auto _ : state) {
    hc::pipeline::BuiltScene b = hc::pipeline::build_scene(*cluttered(2), config, true);
    kept = std::move(*b.cloud);
    kept.xyz = b.scene.model_to_grid.inverse() * kept.xyz;  // back into the cluttered cloud's frame
    for (const auto& st : b.summary.stages)
      if (st.stage == "despike") despiked = static_cast<double>(st.count_in - st.count_out);
  }
  quality(state, kept, 2);
  state.counters["removed_despike"] = despiked;
}

using hc::bench::generated_wall;

void BM_MedianSpacing(benchmark::State& state) {
  const Eigen::Matrix3Xd& wall = generated_wall(static_cast<int>(state.range(0)));
  double spacing = 0.0;
  for (auto _ : state) spacing = hc::pipeline::median_point_spacing(wall, 5e-3);
  state.counters["spacing_mm"] = spacing * 1e3;
}

void BM_SpacingFloor(benchmark::State& state) {
  const Eigen::Matrix3Xd& wall = generated_wall(static_cast<int>(state.range(0)));
  for (auto _ : state) {
    std::vector<float> local(static_cast<std::size_t>(3 * wall.cols()));
    for (Eigen::Index i = 0; i < wall.cols(); ++i)
      for (int a = 0; a < 3; ++a) local[static_cast<std::size_t>(3 * i + a)] = static_cast<float>(wall(a, i));
    benchmark::DoNotOptimize(local.data());
  }
}

#define HC_OUTLIER_BENCH_SETTINGS \
  Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime()->Repetitions(5)->Iterations(1)

BENCHMARK(BM_ExactSor)->HC_OUTLIER_BENCH_SETTINGS;
BENCHMARK(BM_RobustTest)->HC_OUTLIER_BENCH_SETTINGS;
BENCHMARK(BM_RobustAndFar)->Arg(0)->Arg(2)->HC_OUTLIER_BENCH_SETTINGS;
BENCHMARK(BM_RobustOffSurface)->Arg(0)->Arg(15)->Arg(20)->HC_OUTLIER_BENCH_SETTINGS;
BENCHMARK(BM_PointStages)->Arg(0)->Arg(2)->HC_OUTLIER_BENCH_SETTINGS;
BENCHMARK(BM_RunPointStages)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);
BENCHMARK(BM_SpacingFloor)->Arg(1)->Arg(10)->HC_OUTLIER_BENCH_SETTINGS;
BENCHMARK(BM_MedianSpacing)->Arg(1)->Arg(10)->HC_OUTLIER_BENCH_SETTINGS;

}  // namespace

BENCHMARK_MAIN();
