/// Per-tick compute of the haptic renderer (proxy + friction + force, i.e. one step_proxy call)
/// on grids of 200², 800² and 4096² cells: the paper's validation sinusoid with a fine texture,
/// and the real Happy Buddha scan reprojected at the same sizes (data/scans, via the pipeline),
/// as depth alone (`buddha`) and with the surface stage's envelope, texture and μ_d / μ_s maps
/// (`buddha_layers`, what a session renders: every contact iteration reads the maps).
///
/// The HIP slides on a closed circle (r = 15 mm, 1 s per loop at 1 kHz), pressed 1.5 mm into the
/// surface, μ_d = 0.3, μ_s = 0.36, k = 800 N/m: a realistic servo-loop workload.
/// BM_StepProxy gives the mean; BM_StepProxyLatency times every call (CLOCK_MONOTONIC, whose own
/// cost is measured and reported as timer_ns) and reports p50 / p99 / p99.9 / max in ns.
/// BM_StepProxyBudget: the same with max_iterations = 2, 3, 4, 8 (the iteration budget per tick;
/// what is left is carried to the next tick), each call timed; every tick is also run, untimed,
/// from the same previous state with a budget of 1000 iterations (which converges): lag_um_* is
/// |X_p − X_p,converged| and force_mN_* is |F − F_converged| per tick (mean, p99, max), the
/// error the budget adds at that tick, against its time.
/// Aim (issue 3, issue 16): mean ≤ 0.2 µs, p99.9 ≤ 1 µs, no growth with the grid size.

#include "hc/haptics/haptic_surface.hpp"
#include "hc/haptics/proxy.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/surface_layers.hpp"

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <map>
#include <memory>
#include <numbers>
#include <string>
#include <vector>

namespace {

using hc::HeightField;
using hc::haptics::HapticSurface;
using hc::haptics::HipInput;
using hc::haptics::ProxyParams;
using hc::haptics::ProxyState;

double sinusoid(double x, double y) {
  const double k = 2 * std::numbers::pi / 0.04;   // λ = 40 mm, A = 4 mm
  const double kt = 2 * std::numbers::pi / 0.002; // texture λ = 2 mm, 0.2 mm
  return 0.004 * std::sin(k * x) * std::sin(k * y) + 0.0002 * std::sin(kt * x) * std::sin(kt * y);
}

struct Workload {
  std::unique_ptr<HeightField> depth;
  std::unique_ptr<hc::pipeline::SurfaceLayers> layers;  // buddha_layers: envelope, texture, μ_d, μ_s
  std::unique_ptr<HapticSurface> surface;
  std::vector<Eigen::Vector3d> hip;  // one closed loop, 1000 ticks
  std::string error;
};

void make_path(Workload& w, double cx, double cy) {
  w.hip.clear();
  for (int k = 0; k < 1000; ++k) {
    const double a = 2 * std::numbers::pi * k / 1000.0;
    const double x = cx + 0.015 * std::cos(a);
    const double y = cy + 0.015 * std::sin(a);
    w.hip.emplace_back(x, y, w.surface->height(x, y) - 0.0015);
  }
}

hc::haptics::SurfaceOptions friction_options() {
  hc::haptics::SurfaceOptions opt;
  opt.default_mu_d = 0.3;
  opt.default_mu_s = 0.36;
  return opt;
}

Workload make_sinusoid(int n) {
  Workload w;
  const double cell = 0.1 / (n - 1);
  w.depth = std::make_unique<HeightField>(hc::GridGeometry{n, n, -0.05, -0.05, cell});
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n; ++c)
      w.depth->at(r, c) = static_cast<float>(sinusoid(-0.05 + c * cell, -0.05 + r * cell));
  hc::haptics::SurfaceLayers layers;
  layers.depth = w.depth.get();
  w.surface = std::make_unique<HapticSurface>(layers, friction_options());
  make_path(w, 0.0, 0.0);
  return w;
}

/// with_layers: the surface stage's envelope, texture and μ_d / μ_s maps (default options), as a
/// session renders a scene; otherwise the depth alone with constant μ_d, μ_s.
Workload make_buddha(int n, bool with_layers) {
  Workload w;
  const auto path = std::filesystem::path(HC_SOURCE_DIR) / "data" / "scans" / "happy_buddha" /
                    "happy_stand_merged_1099005pts.ply.gz";
  try {
    const auto cloud = hc::pipeline::load_cloud(path).value;
    hc::pipeline::ReprojectOptions opt;
    opt.grid.n_long_side = n;
    // As configs/happy_buddha.yaml: finer than the scan, scan every K-th node and interpolate.
    opt.splat_radius_cells = 1.2;
    opt.see_through_depth_m = 0.002;
    opt.upsample_factor = 0;
    auto grid = hc::pipeline::reproject(cloud, opt).value;
    w.depth = std::make_unique<HeightField>(std::move(grid.depth));
    hc::haptics::SurfaceLayers layers;
    layers.depth = w.depth.get();
    if (with_layers) {
      w.layers = std::make_unique<hc::pipeline::SurfaceLayers>(
          hc::pipeline::compute_surface_layers(*w.depth, hc::pipeline::SurfaceLayerOptions{}).value);
      layers.envelope = &w.layers->envelope_m;
      layers.texture = &w.layers->texture_m;
      layers.mu_d = &w.layers->mu_d;
      layers.mu_s = &w.layers->mu_s;
    }
    w.surface = std::make_unique<HapticSurface>(layers, friction_options());
    const hc::GridGeometry& g = w.depth->geometry();
    // A circle on the statue's body, a little above the middle of the grid.
    make_path(w, g.x_of_col(0.5 * (g.cols - 1)), g.y_of_row(0.55 * (g.rows - 1)));
  } catch (const std::exception& e) {
    w.error = std::string("Buddha unavailable (run data/get-data): ") + e.what();
  }
  return w;
}

Workload& workload(const std::string& kind, int n) {
  static std::map<std::pair<std::string, int>, Workload> cache;
  auto it = cache.find({kind, n});
  if (it == cache.end()) {
    it = cache.emplace(std::make_pair(kind, n), kind == "sinusoid" ? make_sinusoid(n) : make_buddha(n, kind == "buddha_layers")).first;
  }
  return it->second;
}

ProxyState warm_up(const Workload& w, const ProxyParams& p) {
  ProxyState s;
  const Eigen::Vector3d above = w.hip[0] + Eigen::Vector3d(0, 0, 0.01);
  s = hc::haptics::step_proxy(s, HipInput{above, 1e-3, true}, w.surface.get(), p);
  for (int k = 0; k < 2000; ++k) {
    s = hc::haptics::step_proxy(s, HipInput{w.hip[static_cast<std::size_t>(k) % w.hip.size()], 1e-3, true},
                                w.surface.get(), p);
  }
  return s;
}

/// The workload of `kind` at n = state.range(0), or nullptr after marking the benchmark as an
/// error (for example a missing scan).
Workload* workload_for(benchmark::State& state, const std::string& kind) {
  Workload& w = workload(kind, static_cast<int>(state.range(0)));
  if (!w.error.empty()) {
    state.SkipWithError(w.error.c_str());
    return nullptr;
  }
  return &w;
}

void BM_StepProxy(benchmark::State& state, const std::string& kind) {
  Workload* wp = workload_for(state, kind);
  if (wp == nullptr) return;
  Workload& w = *wp;
  const ProxyParams p;
  ProxyState s = warm_up(w, p);
  std::size_t k = 0;
  double iterations = 0;
  for (auto _ : state) {
    s = hc::haptics::step_proxy(s, HipInput{w.hip[k], 1e-3, true}, w.surface.get(), p);
    benchmark::DoNotOptimize(s.force_n);
    iterations += s.iterations;
    k = k + 1 == w.hip.size() ? 0 : k + 1;
  }
  state.counters["rows"] = w.depth->rows();
  state.counters["cols"] = w.depth->cols();
  state.counters["iter_per_tick"] = iterations / static_cast<double>(state.iterations());
}

std::int64_t now_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

void BM_StepProxyLatency(benchmark::State& state, const std::string& kind) {
  Workload* wp = workload_for(state, kind);
  if (wp == nullptr) return;
  Workload& w = *wp;
  const ProxyParams p;
  ProxyState s = warm_up(w, p);
  // Cost of one timer read pair, subtracted from nothing: reported separately.
  std::vector<std::int64_t> empty(20000);
  for (auto& e : empty) {
    const std::int64_t t0 = now_ns();
    e = now_ns() - t0;
  }
  std::sort(empty.begin(), empty.end());
  std::vector<std::int64_t> samples;
  samples.reserve(4000000);
  std::size_t k = 0;
  for (auto _ : state) {
    const std::int64_t t0 = now_ns();
    s = hc::haptics::step_proxy(s, HipInput{w.hip[k], 1e-3, true}, w.surface.get(), p);
    const std::int64_t t1 = now_ns();
    benchmark::DoNotOptimize(s.force_n);
    if (samples.size() < samples.capacity()) samples.push_back(t1 - t0);
    k = k + 1 == w.hip.size() ? 0 : k + 1;
  }
  std::sort(samples.begin(), samples.end());
  const auto pct = [&](double q) {
    return static_cast<double>(samples[std::min(samples.size() - 1, static_cast<std::size_t>(q * static_cast<double>(samples.size())))]);
  };
  state.counters["p50_ns"] = pct(0.5);
  state.counters["p99_ns"] = pct(0.99);
  state.counters["p99.9_ns"] = pct(0.999);
  state.counters["max_ns"] = static_cast<double>(samples.back());
  state.counters["timer_ns"] = static_cast<double>(empty[empty.size() / 2]);
  state.counters["samples"] = static_cast<double>(samples.size());
}

void BM_StepProxyBudget(benchmark::State& state, const std::string& kind) {
  Workload* wp = workload_for(state, kind);
  if (wp == nullptr) return;
  Workload& w = *wp;
  ProxyParams p;
  p.max_iterations = static_cast<int>(state.range(1));
  ProxyParams ref_p;
  ref_p.max_iterations = 1000;
  ref_p.max_step_cells = p.max_step_cells;
  ProxyState s = warm_up(w, ref_p);
  std::vector<std::int64_t> ns;
  std::vector<double> lag_um, force_mn;
  const auto n = static_cast<std::size_t>(state.max_iterations);
  ns.reserve(n);
  lag_um.reserve(n);
  force_mn.reserve(n);
  std::size_t k = 0;
  double iterations = 0;
  for (auto _ : state) {
    const HipInput in{w.hip[k], 1e-3, true};
    const ProxyState before = s;
    const std::int64_t t0 = now_ns();
    s = hc::haptics::step_proxy(s, in, w.surface.get(), p);
    const std::int64_t t1 = now_ns();
    benchmark::DoNotOptimize(s.force_n);
    state.SetIterationTime(static_cast<double>(t1 - t0) * 1e-9);
    const ProxyState ref = hc::haptics::step_proxy(before, in, w.surface.get(), ref_p);
    ns.push_back(t1 - t0);
    lag_um.push_back((s.proxy_m - ref.proxy_m).norm() * 1e6);
    force_mn.push_back((s.force_n - ref.force_n).norm() * 1e3);
    iterations += s.iterations;
    k = k + 1 == w.hip.size() ? 0 : k + 1;
  }
  const auto stats = [&](auto& v, const std::string& name) {
    std::sort(v.begin(), v.end());
    double sum = 0;
    for (const auto x : v) sum += static_cast<double>(x);
    state.counters[name + "_mean"] = sum / static_cast<double>(v.size());
    state.counters[name + "_p99"] = static_cast<double>(v[static_cast<std::size_t>(0.99 * static_cast<double>(v.size() - 1))]);
    state.counters[name + "_max"] = static_cast<double>(v.back());
  };
  stats(lag_um, "lag_um");
  stats(force_mn, "force_mN");
  std::sort(ns.begin(), ns.end());
  state.counters["p99.9_ns"] = static_cast<double>(ns[static_cast<std::size_t>(0.999 * static_cast<double>(ns.size() - 1))]);
  state.counters["iter_per_tick"] = iterations / static_cast<double>(state.iterations());
}

BENCHMARK_CAPTURE(BM_StepProxy, sinusoid, std::string("sinusoid"))->Arg(200)->Arg(800)->Arg(4096);
BENCHMARK_CAPTURE(BM_StepProxy, buddha, std::string("buddha"))->Arg(200)->Arg(800)->Arg(4096);
BENCHMARK_CAPTURE(BM_StepProxy, buddha_layers, std::string("buddha_layers"))->Arg(200)->Arg(800)->Arg(4096);
BENCHMARK_CAPTURE(BM_StepProxyLatency, sinusoid, std::string("sinusoid"))
    ->Arg(200)->Arg(800)->Arg(4096)->Iterations(1000000);
BENCHMARK_CAPTURE(BM_StepProxyLatency, buddha, std::string("buddha"))
    ->Arg(200)->Arg(800)->Arg(4096)->Iterations(1000000);
BENCHMARK_CAPTURE(BM_StepProxyLatency, buddha_layers, std::string("buddha_layers"))
    ->Arg(200)->Arg(800)->Arg(4096)->Iterations(1000000);

}  // namespace

BENCHMARK_CAPTURE(BM_StepProxyBudget, sinusoid, std::string("sinusoid"))
    ->ArgsProduct({{200, 800, 4096}, {2, 3, 4, 8}})->Iterations(300000)->UseManualTime()->Unit(benchmark::kNanosecond);
BENCHMARK_CAPTURE(BM_StepProxyBudget, buddha, std::string("buddha"))
    ->ArgsProduct({{200, 800, 4096}, {2, 3, 4, 8}})->Iterations(300000)->UseManualTime()->Unit(benchmark::kNanosecond);

BENCHMARK_MAIN();
