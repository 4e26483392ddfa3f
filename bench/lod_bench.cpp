// Levels of detail on the 1.1 M-point Happy Buddha (data/scans, configs/happy_buddha.yaml
// grid options) at N = 1600 and 4096 samples on the long side:
//  - BM_BuildLevel: time to build level L when first visited (smoothing + 2× decimation of every
//    level down to L that is not cached yet, then texture/μ_d/μ_s for L); counters split the last
//    decimation and the layers;
//  - BM_SwitchLatency: request (LodController::set_level / pan) to the first servo tick on the
//    new window, with the servo thread running at 1 kHz (levels cached; the request builds the
//    window's HapticSurface and publishes it with its map); counters: build_ms_mean = the
//    request's own work, adopt_ms_mean = publish → adopted (waits for the next tick, ≤ 1 period
//    plus scheduling delay: the servo thread is not SCHED_FIFO here); p50_ms / p99_ms / max_ms =
//    percentiles of request → first tick over the repetition's switches. The last argument
//    turns the servo's wake on a published surface (ServoConfig::wake_on_surface_min_period =
//    0.5) on (1) or off (0: adopt on deadlines only, the baseline in the same run).
// Medians of repetitions. Run: build/release/bench/lod_bench

#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/simulated_device.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/session/lod_controller.hpp"
#include "hc/pipeline/reproject.hpp"

#include <benchmark/benchmark.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <map>
#include <memory>
#include <thread>
#include <vector>

namespace {

using Clock = std::chrono::steady_clock;
using hc::pipeline::LodLevel;
using hc::pipeline::LodPyramid;

std::filesystem::path buddha_path() {
  return std::filesystem::path(HC_SOURCE_DIR) / "data" / "scans" / "happy_buddha" / "happy_stand_merged_1099005pts.ply.gz";
}

/// Level 0 of the Buddha at N (depth and its layers), made once per N.
const LodLevel* finest(int n) {
  static std::map<int, std::unique_ptr<LodLevel>> cache;
  auto it = cache.find(n);
  if (it != cache.end()) return it->second.get();
  if (!std::filesystem::exists(buddha_path())) return nullptr;
  static const hc::pipeline::Cloud cloud = hc::pipeline::load_cloud(buddha_path()).value;
  hc::pipeline::ReprojectOptions opt;  // as configs/happy_buddha.yaml
  opt.grid.n_long_side = n;
  opt.splat_radius_cells = 1.2;
  opt.see_through_depth_m = 0.002;
  opt.upsample_factor = 0;
  auto l0 = std::make_unique<LodLevel>();
  l0->depth_m = hc::pipeline::reproject(cloud, opt).value.depth;
  auto layers = hc::pipeline::compute_surface_layers(l0->depth_m, hc::pipeline::SurfaceLayerOptions{}).value;
  l0->envelope_m = std::move(layers.envelope_m);
  l0->texture_m = std::move(layers.texture_m);
  l0->mu_d = std::move(layers.mu_d);
  l0->mu_s = std::move(layers.mu_s);
  l0->has_layers = true;
  return cache.emplace(n, std::move(l0)).first->second.get();
}

hc::pipeline::LodOptions lod_options() {
  hc::pipeline::LodOptions o;
  o.memory_budget_mb = 4096;
  return o;
}

void BM_BuildLevel(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const int level = static_cast<int>(state.range(1));
  const LodLevel* l0 = finest(n);
  if (l0 == nullptr) {
    state.SkipWithError(("missing " + buddha_path().string() + ": run data/get-data").c_str());
    return;
  }
  if (level >= hc::pipeline::lod_level_count(l0->depth_m.geometry(), lod_options().min_cells)) {
    state.SkipWithError("no such level at this N");
    return;
  }
  double depth_ms = 0, layers_ms = 0;
  for (auto _ : state) {
    state.PauseTiming();
    LodLevel copy = *l0;
    LodPyramid pyramid(std::move(copy), hc::pipeline::SurfaceLayerOptions{}, lod_options());
    state.ResumeTiming();
    const auto lvl = pyramid.level(level);
    benchmark::DoNotOptimize(lvl->mu_d.data());
    depth_ms = lvl->depth_seconds * 1e3;
    layers_ms = lvl->layers_seconds * 1e3;
    state.counters["rows"] = lvl->depth_m.rows();
    state.counters["cols"] = lvl->depth_m.cols();
    state.counters["cell_mm"] = lvl->depth_m.cell_size_m() * 1e3;
  }
  state.counters["last_decimation_ms"] = depth_ms;
  state.counters["layers_ms"] = layers_ms;
}

void BM_SwitchLatency(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const int level = static_cast<int>(state.range(1));
  const bool pan = state.range(2) != 0;
  const bool wake = state.range(3) != 0;
  const LodLevel* l0 = finest(n);
  if (l0 == nullptr) {
    state.SkipWithError(("missing " + buddha_path().string() + ": run data/get-data").c_str());
    return;
  }
  auto pyramid = std::make_shared<LodPyramid>(*l0, hc::pipeline::SurfaceLayerOptions{}, lod_options());
  if (level + 1 >= pyramid->level_count()) {
    state.SkipWithError("no such level at this N");
    return;
  }
  (void)pyramid->level(level);  // levels cached: the switch builds only the window
  (void)pyramid->level(level + 1);
  const hc::haptics::DeviceInfo info = hc::haptics::SimulatedDevice::default_info();
  hc::haptics::SharedState shared;
  hc::session::LodControllerOptions co;
  co.device_half_extent_m = info.workspace_half_extent_m;
  co.prefetch_neighbours = false;  // the levels are cached above; no background work while timing
  hc::session::LodController lod(pyramid, shared, co);
  const hc::GridGeometry& g = pyramid->geometry(level);
  const hc::session::HapticWindow start =
      lod.centre_window(level, g.x_of_col(0.5 * (g.cols - 1)), g.y_of_row(0.55 * (g.rows - 1)));
  hc::haptics::SteadyClock clock;
  hc::haptics::ScriptedPath path;
  path.kind = hc::haptics::PathKind::kCircle;
  path.half_x_m = 0.01;
  path.z_above_m = (start.max_height_m - start.map.origin_m.z()) / start.map.scale + 0.01;
  path.z_contact_m = -0.005;
  hc::haptics::SimulatedDevice dev(clock, path, hc::haptics::VirtualHand{}, info);
  dev.open();
  hc::haptics::ServoConfig cfg;
  cfg.rate_hz = 1000.0;
  cfg.realtime = hc::haptics::RealtimeMode::kOff;
  cfg.workspace = start.map;
  cfg.wake_on_surface_min_period = wake ? 0.5 : 1.0;
  hc::haptics::ServoLoop loop(dev, shared, clock, cfg);
  shared.commands.try_push(hc::haptics::Command::of(hc::haptics::CommandType::kArm));
  loop.start();
  while (!lod.adopted()) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // in contact
  double adopt_sum_ms = 0.0, build_sum_ms = 0.0;
  std::vector<double> latency_ms;
  latency_ms.reserve(static_cast<std::size_t>(state.max_iterations));
  int dir = 1;
  std::uint64_t jitter = 12345;
  for (auto _ : state) {
    // Alternate: pan back and forth on `level`, or switch level ↔ level + 1 around the proxy.
    hc::haptics::Snapshot snap;
    shared.snapshots.read(snap);
    const auto t0 = Clock::now();
    const std::uint64_t tag = pan ? lod.pan(0, 8 * dir).tag  // the statue is tall: pan along y
                                  : lod.set_level(lod.window().level == level ? level + 1 : level, snap.proxy_m.eigen()).tag;
    const auto t1 = Clock::now();
    while (shared.counters.surface_tag.load(std::memory_order_acquire) != tag) std::this_thread::yield();
    const auto t2 = Clock::now();
    state.SetIterationTime(std::chrono::duration<double>(t2 - t0).count());
    latency_ms.push_back(std::chrono::duration<double, std::milli>(t2 - t0).count());
    adopt_sum_ms += std::chrono::duration<double, std::milli>(t2 - t1).count();
    build_sum_ms += std::chrono::duration<double, std::milli>(t1 - t0).count();
    dir = -dir;
    shared.collect_retired();
    // Let the proxy settle, and request at a random phase of the 1 ms tick.
    jitter = jitter * 6364136223846793005ULL + 1442695040888963407ULL;
    std::this_thread::sleep_for(std::chrono::microseconds(3000 + static_cast<int>((jitter >> 33) % 1000)));
  }
  loop.stop();
  state.counters["adopt_ms_mean"] = adopt_sum_ms / static_cast<double>(state.iterations());
  state.counters["build_ms_mean"] = build_sum_ms / static_cast<double>(state.iterations());
  std::sort(latency_ms.begin(), latency_ms.end());
  const auto pct = [&](double q) {
    return latency_ms.empty() ? 0.0 : latency_ms[static_cast<std::size_t>(q * static_cast<double>(latency_ms.size() - 1) + 0.5)];
  };
  state.counters["p50_ms"] = pct(0.5);
  state.counters["p99_ms"] = pct(0.99);
  state.counters["max_ms"] = latency_ms.empty() ? 0.0 : latency_ms.back();
  state.counters["wake_ticks"] = static_cast<double>(loop.stats().surface_wake_ticks);
  state.counters["window"] = lod.window_cells();
  state.counters["overruns"] = static_cast<double>(loop.stats().overruns);
}

#define HC_LOD_SETTINGS Unit(benchmark::kMillisecond)->Repetitions(5)->DisplayAggregatesOnly(true)

// N, level: levels 1.. (level 0 is the scene itself); 1600 has 5 levels (64-sample minimum),
// 4096 has 7.
BENCHMARK(BM_BuildLevel)
    ->ArgsProduct({{1600}, {1, 2, 3, 4}})
    ->ArgsProduct({{4096}, {1, 2, 3, 4, 5, 6}})
    ->Iterations(1)
    ->UseRealTime()
    ->HC_LOD_SETTINGS;
// N, level, pan (0: switch level ↔ level + 1 around the proxy; 1: pan by 8 samples along y),
// wake (0: surfaces adopted on deadlines only; 1: the servo wakes for a published surface).
BENCHMARK(BM_SwitchLatency)
    ->ArgsProduct({{1600, 4096}, {0, 2}, {0, 1}, {0, 1}})
    ->Iterations(200)
    ->UseManualTime()
    ->Unit(benchmark::kMillisecond)
    ->Repetitions(3)
    ->DisplayAggregatesOnly(true);

}  // namespace

BENCHMARK_MAIN();
