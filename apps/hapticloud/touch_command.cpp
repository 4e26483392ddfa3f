/// `hapticloud touch`: a headless scripted haptic session. A SimulatedDevice follows a scripted
/// path through a virtual hand, the servo loop renders the scene (as fast as possible on a
/// manual clock, or in real time on its own thread with --realtime), and the session is written
/// as trace.csv, events.csv, summary.json and PNG plots in --out, with a summary on stdout.
/// --validate reproduces the paper's validation (Sec. 5.1): the same press-and-slide with and
/// without texture and friction, proxy z and force against time, in one report.

#include "commands.hpp"
#include "hc/session/lod_session.hpp"
#include "hc/session/scene_source.hpp"

#include "hc/common/error.hpp"
#include "hc/haptics/haptic_surface.hpp"
#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/shared_state.hpp"
#include "hc/haptics/simulated_device.hpp"
#include "hc/haptics/workspace_map.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/lod_report.hpp"
#include "hc/pipeline/plot.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"

#ifdef HC_HAVE_AUDIO
#include "audio_setup.hpp"
#include "hc/audio/engine.hpp"
#include "hc/audio/offline.hpp"
#endif

#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <numbers>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace hc::app {
namespace {

namespace fs = std::filesystem;
using haptics::HapticSurface;
using session::LodSession;
using session::parse_window_origin;
using session::parse_zoom_path;
using session::ZoomAction;

struct TouchOptions {
  std::string input;
  std::string synthetic;
  std::string path = "raster";
  double seconds = 10.0;
  double rate_hz = 1000.0;
  bool realtime = false;
  std::string out = "touch-out";
  double texture_gain = 1.0;
  bool no_friction = false;
  double mu_d = 0.3;
  double mu_s = 0.4;
  double stiffness_n_per_m = 800.0;
  double max_force_n = 8.0;
  double rho = 0.9;
  int cells = 400;
  bool no_hand = false;
  double press_m = 0.01;
  double speed_m_per_s = 0.05;
  bool validate = false;
  std::string audio_out;     ///< offline render of the session's contact sounds (WAV)
  std::string audio_live;    ///< play live: "default", "loopback" or an OpenAL device name
  std::string audio_config;  ///< run config whose audio: section to use
  int level = -1;            ///< levels of detail: start level (−1 with a zoom path: the coarsest)
  std::string window;        ///< "X,Y": first column and row of the haptic window at that level
  std::string zoom_path;     ///< scripted level switches and pans (file or spec)
  int window_cells = 0;      ///< side of the haptic window [samples] (0: the scene's lod.window_cells)
  bool level_given = false;         ///< --level was on the command line (even -1)
  bool window_cells_given = false;  ///< --window-cells was on the command line
};

/// Levels of detail are on when --level, --window or --zoom-path is given.
bool lod_mode(const TouchOptions& o) { return o.level_given || !o.window.empty() || !o.zoom_path.empty(); }

/// The layers the session renders (owned here; HapticSurface copies what it needs).
struct SceneLayers {
  std::map<std::string, HeightField> layers;
  std::string description;
  pipeline::AudioSpec audio;  ///< the run config's audio: section (when the input is a config)
  pipeline::SurfaceLayerOptions layer_options;  ///< the scene's layers.* (levels ≥ 1 are computed with them)
  pipeline::LodOptions lod;                     ///< the scene's lod.*
};

/// The paper's validation sinusoid (Sec. 5.1) with a fine texture: envelope
/// A·sin(2πx/λ)·sin(2πy/λ), A = 4 mm, λ = 40 mm; texture a·sin(2πx/λt)·sin(2πy/λt), a = 0.2 mm,
/// λt = 2 mm; over a 100 mm square centred on the origin.
SceneLayers synthetic_sinusoid(int n) {
  if (n < 2 || n > 8192) {
    throw ConfigError("touch: --cells " + std::to_string(n) + " is out of range (expected 2..8192)");
  }
  const double side = 0.1;
  const double cell = side / (n - 1);
  const GridGeometry g{n, n, -side / 2, -side / 2, cell};
  HeightField env(g), tex(g), depth(g);
  const double k = 2 * std::numbers::pi / 0.04, kt = 2 * std::numbers::pi / 0.002;
  for (int r = 0; r < n; ++r) {
    for (int c = 0; c < n; ++c) {
      const double x = g.x_of_col(c), y = g.y_of_row(r);
      const double e = 0.004 * std::sin(k * x) * std::sin(k * y);
      const double t = 0.0002 * std::sin(kt * x) * std::sin(kt * y);
      env.at(r, c) = static_cast<float>(e);
      tex.at(r, c) = static_cast<float>(t);
      depth.at(r, c) = static_cast<float>(e + t);
    }
  }
  SceneLayers s;
  s.layers.emplace("depth", std::move(depth));
  s.layers.emplace("envelope", std::move(env));
  s.layers.emplace("texture", std::move(tex));
  s.description = "synthetic sinusoid " + std::to_string(n) + "x" + std::to_string(n);
  return s;
}

SceneLayers load_input(const TouchOptions& o) {
  if (!o.synthetic.empty()) {
    if (o.synthetic != "sinusoid") {
      throw ConfigError("touch: --synthetic '" + o.synthetic + "' is unknown (expected: sinusoid)");
    }
    return synthetic_sinusoid(o.cells);
  }
  if (o.input.empty()) {
    throw ConfigError("touch: give a scene folder (written by `hapticloud run`) or --synthetic sinusoid");
  }
  // A run config: its scene is built in memory; the run folder is written beside the session output.
  const fs::path p(o.input);
  session::SceneSourceOptions so;
  if (session::is_run_config(p)) {
    so.run_dir = fs::path(o.out) / "pipeline";
    std::cout << "touch: building the scene of " << p.string() << " into " << so.run_dir.string() << "\n";
  }
  session::OpenedScene opened = session::open_scene_or_config(p, so);
  SceneLayers s;
  Scene& scene = opened.scene;
  // Levels of detail compute their layers with the scene's own settings (its typed metadata).
  s.layer_options = scene.layer_options;
  s.lod = scene.lod;
  if (opened.config) s.audio = opened.config->audio;
  s.layers.emplace("depth", std::move(scene.layers.depth));
  for (auto [name, f] : {std::pair<const char*, HeightField*>{"envelope", &scene.layers.envelope},
                         {"texture", &scene.layers.texture}, {"mu_d", &scene.layers.mu_d}, {"mu_s", &scene.layers.mu_s}}) {
    if (f->rows() > 0) s.layers.emplace(name, std::move(*f));
  }
  s.description = opened.config ? opened.description : "scene " + p.string();
  return s;
}

const HeightField* layer(const SceneLayers& s, const char* name) {
  auto it = s.layers.find(name);
  return it == s.layers.end() ? nullptr : &it->second;
}

std::string json_number(double v) {
  if (!std::isfinite(v)) return "null";
  std::ostringstream s;
  s.precision(10);
  s << v;
  return s.str();
}

/// Draws proxy/HIP z and |F| against time for one or more sessions.
struct PlotInput {
  std::string label;
  const std::vector<haptics::TickRecord>* trace;
};

void plot_sessions(const std::vector<PlotInput>& runs, const fs::path& z_png, const fs::path& f_png,
                   const std::string& title) {
  pipeline::PlotSpec z{z_png, title + ": proxy height", "time", "s", "z (model frame)", "mm", {}};
  pipeline::PlotSpec f{f_png, title + ": force", "time", "s", "|F|", "N", {}};
  for (const PlotInput& run : runs) {
    pipeline::PlotSeries pz{"proxy z" + run.label, {}, {}}, hz{"HIP z" + run.label, {}, {}};
    pipeline::PlotSeries fz{"|F|" + run.label, {}, {}};
    const auto& tr = *run.trace;
    const std::size_t stride = std::max<std::size_t>(1, tr.size() / 4000);  // enough for a 900 px plot
    const double t0 = tr.empty() ? 0.0 : tr.front().t_s;
    for (std::size_t i = 0; i < tr.size(); i += stride) {
      const double t = tr[i].t_s - t0;
      pz.x.push_back(t);
      pz.y.push_back(tr[i].proxy_m.z * 1000.0);
      hz.x.push_back(t);
      hz.y.push_back(tr[i].hip_m.z * 1000.0);
      fz.x.push_back(t);
      fz.y.push_back(tr[i].force_n.eigen().norm());
    }
    z.series.push_back(std::move(pz));
    if (runs.size() == 1) z.series.push_back(std::move(hz));
    f.series.push_back(std::move(fz));
  }
  pipeline::plot_series(z);
  pipeline::plot_series(f);
}

struct SessionSummary {
  double max_force_n = 0.0;
  double deepest_m = 0.0;
  double mean_force_contact_n = 0.0;
  std::uint64_t ticks = 0, overruns = 0;
  double p50_ns = 0, p99_ns = 0, p999_ns = 0, max_ns = 0;
};

SessionSummary run_session(const TouchOptions& o, const SceneLayers& scene, const fs::path& out,
                           std::vector<haptics::TickRecord>& trace) {
  haptics::SurfaceLayers layers;
  layers.depth = layer(scene, "depth");
  layers.envelope = layer(scene, "envelope");
  layers.texture = layer(scene, "texture");
  layers.mu_d = layer(scene, "mu_d");
  layers.mu_s = layer(scene, "mu_s");
#ifdef HC_HAVE_AUDIO
  // Contact sounds (issue 7): clips decoded and regions rasterised BEFORE the session, so a bad
  // clip stops here; the region ids ride on the haptic surface into the contact events.
  std::shared_ptr<const audio::AudioScene> audio_scene;
  HeightField region_layer;
  if ((!o.audio_out.empty() || !o.audio_live.empty()) && layers.depth != nullptr) {
    const GridGeometry& grid = layers.depth->geometry();
    audio_scene = audio::build_audio_scene(audio_config_from(scene.audio), {&grid, layers.texture});
    if (!audio_scene->config.regions.empty()) {
      region_layer = audio_scene->regions.to_layer(grid);
      layers.region_id = &region_layer;
    }
    std::cout << "audio: " << audio_scene->config.regions.size() << " region(s)"
              << (scene.audio.present ? "" : " (the input has no audio: section; sliding sound only)") << "\n";
  }
#endif
  haptics::SurfaceOptions sopt;
  sopt.texture_gain = o.texture_gain;
  sopt.default_mu_d = o.mu_d;
  sopt.default_mu_s = o.mu_s;
  const haptics::DeviceInfo info = haptics::SimulatedDevice::default_info();
  // Levels of detail (issue 4): the servo renders a window of a level; the LodSession publishes
  // it (and every scripted switch) with its workspace map through the surface mailbox.
  const bool levels = lod_mode(o);
  haptics::SharedState shared(levels ? nullptr : std::make_unique<HapticSurface>(layers, sopt));
  std::unique_ptr<LodSession> lod;
  haptics::WorkspaceMap map;
  double top_dev = 0.0;
  if (levels) {
    if (layers.region_id != nullptr) {
      throw ConfigError("touch: audio regions are not carried into level-of-detail windows yet; drop --level, "
                        "--window and --zoom-path, or the audio options");
    }
    pipeline::LodOptions lod_options = scene.lod;
    if (o.window_cells_given) lod_options.window_cells = o.window_cells;
    lod = std::make_unique<LodSession>(
        scene.layers, sopt, info.workspace_half_extent_m, o.level,
        o.window.empty() ? std::nullopt : std::optional<std::pair<int, int>>(parse_window_origin(o.window)),
        o.zoom_path.empty() ? std::vector<ZoomAction>{} : parse_zoom_path(o.zoom_path), shared,
        scene.layer_options, lod_options);
    map = lod->initial().map;
    top_dev = (lod->initial().max_height_m - map.origin_m.z()) / map.scale;
  } else {
    // Device and workspace: the grid's extent fills the device box, device z = 0 at mid height.
    const HapticSurface& surf = *shared.current_surface();
    const GridGeometry& g = surf.source_geometry();
    const double z_mid = 0.5 * (surf.min_height_m() + surf.max_height_m());
    map = haptics::WorkspaceMap::fit(info.workspace_half_extent_m, g.x0_m, g.x_of_col(g.cols - 1), g.y0_m,
                                     g.y_of_row(g.rows - 1), z_mid);
    top_dev = (surf.max_height_m() - z_mid) / map.scale;
  }
  haptics::ScriptedPath path;
  path.kind = haptics::path_kind_from_string(o.path);
  path.centre_m = Eigen::Vector3d::Zero();
  path.half_x_m = 0.6 * info.workspace_half_extent_m.x();
  path.half_y_m = 0.6 * info.workspace_half_extent_m.y();
  path.raster_spacing_m = 0.1 * info.workspace_half_extent_m.y();
  path.z_above_m = top_dev + 0.01;
  path.z_contact_m = -o.press_m;  // the hand aims this far below mid height
  path.speed_m_per_s = o.speed_m_per_s;
  path.approach_s = std::min(0.5, 0.1 * o.seconds);
  haptics::VirtualHand hand;
  hand.enabled = !o.no_hand;

  haptics::ServoConfig cfg;
  cfg.rate_hz = o.rate_hz;
  cfg.realtime = o.realtime ? haptics::RealtimeMode::kWarn : haptics::RealtimeMode::kOff;
  cfg.workspace = map;
  cfg.proxy.stiffness_n_per_m = o.stiffness_n_per_m;
  cfg.proxy.max_force_n = o.max_force_n;
  cfg.proxy.rho = o.rho;
  cfg.proxy.friction_enabled = !o.no_friction;
  const double ticks_d = std::ceil(o.seconds * o.rate_hz);
  if (ticks_d > 5.0e7) {
    throw ResourceError("touch: " + json_number(ticks_d) + " ticks requested (--seconds x --rate), at most 5e7 are traced");
  }
  const auto ticks = static_cast<std::uint64_t>(ticks_d);
  trace.assign(ticks + 16, haptics::TickRecord{});

  std::error_code ec;
  fs::create_directories(out, ec);
  if (ec) throw InputError("touch: cannot create the output folder '" + out.string() + "': " + ec.message());

  std::vector<haptics::ContactEvent> events;
  events.reserve(1 << 16);
#ifdef HC_HAVE_AUDIO
  std::unique_ptr<audio::AudioEngine> live;
  if (!o.audio_live.empty()) {
    audio::EngineOptions eo;
    eo.loopback = o.audio_live == "loopback";
    if (o.audio_live != "default" && !eo.loopback) eo.device_name = o.audio_live;
    live = std::make_unique<audio::AudioEngine>(audio_scene, eo);
    const audio::EngineReport rep = live->start();  // events are forwarded by drain()
    std::cout << rep.detail << "\n";
  }
#endif
  const auto drain = [&] {
    haptics::ContactEvent e;
    while (shared.events.try_pop(e)) {
      events.push_back(e);
#ifdef HC_HAVE_AUDIO
      if (live) live->submit(e);
#endif
    }
  };
  haptics::RealtimeReport report;
  haptics::ServoStats stats;
  if (!o.realtime) {
    auto clock = std::make_unique<haptics::ManualClock>();
    haptics::SimulatedDevice dev(*clock, path, hand, info);
    dev.open();
    haptics::ServoLoop loop(dev, shared, *clock, cfg);
    loop.set_trace(trace);
    shared.commands.try_push(haptics::Command::of(haptics::CommandType::kArm));
    for (std::uint64_t done = 0; done < ticks;) {
      std::uint64_t n = std::min<std::uint64_t>(500, ticks - done);  // the event ring holds 1024
      if (lod) {
        // Scripted switches between ticks, anchored at the proxy of the last tick.
        const double t = static_cast<double>(done) / o.rate_hz;
        if (lod->next_time() <= t + 1e-12) {
          haptics::Snapshot snap;
          shared.snapshots.read(snap);
          lod->apply_due(t, snap.proxy_m.eigen());
          shared.collect_retired();
        }
        const double next_tick = std::ceil(lod->next_time() * o.rate_hz - 1e-9);
        if (next_tick > static_cast<double>(done) && next_tick < static_cast<double>(done + n)) {
          n = static_cast<std::uint64_t>(next_tick) - done;
        }
      }
      loop.run_ticks(n, *clock);
      drain();
      done += n;
    }
    stats = loop.stats();
    trace.resize(loop.trace_size());
    dev.close();
  } else {
    haptics::SteadyClock clock;
    haptics::SimulatedDevice dev(clock, path, hand, info);
    dev.open();
    haptics::ServoLoop loop(dev, shared, clock, cfg);
    loop.set_trace(trace);
    shared.commands.try_push(haptics::Command::of(haptics::CommandType::kArm));
    report = loop.start();
    std::cout << "realtime: SCHED_FIFO " << (report.fifo_granted ? "granted" : "not granted")
              << ", memory " << (report.memory_locked ? "locked" : "not locked") << "\n";
    if (!report.detail.empty()) std::cout << "realtime: " << report.detail << "\n";
    while (shared.counters.ticks.load(std::memory_order_relaxed) < ticks) {
      std::this_thread::sleep_for(std::chrono::milliseconds(lod ? 1 : 5));
      drain();
      if (lod) {
        const double t = static_cast<double>(shared.counters.ticks.load(std::memory_order_relaxed)) / o.rate_hz;
        if (lod->next_time() <= t) {
          haptics::Snapshot snap;
          shared.snapshots.read(snap);
          lod->apply_due(t, snap.proxy_m.eigen());
        }
        shared.collect_retired();
      }
    }
    loop.stop();
    drain();
    stats = loop.stats();
    trace.resize(std::min<std::size_t>(loop.trace_size(), ticks));
    dev.close();
  }

  // trace.csv, and the figures of the summary.
  const HapticSurface& s = *shared.current_surface();
  std::ofstream csv(out / "trace.csv");
  if (!csv) throw InputError("touch: cannot write '" + (out / "trace.csv").string() + "'");
  csv << "t_s,hip_x_m,hip_y_m,hip_z_m,proxy_x_m,proxy_y_m,proxy_z_m,force_x_n,force_y_n,force_z_n,"
         "force_n,contact,sticking,mu_d,mu_s,beta_rad,iterations,compute_ns,surface_z_m,"
         "proxy_below_surface_m\n";
  double max_force = 0.0, deepest = 0.0, t0 = trace.empty() ? 0.0 : trace.front().t_s;
  double force_sum_contact = 0.0;
  std::size_t contact_ticks = 0;
  char row[512];
  for (const haptics::TickRecord& r : trace) {
    const double f = r.force_n.eigen().norm();
    const double zs = (lod ? lod->surface_for(r.surface_tag) : s).height(r.proxy_m.x, r.proxy_m.y);
    const double below = zs - r.proxy_m.z;
    max_force = std::max(max_force, f);
    deepest = std::max(deepest, below);
    contact_ticks += r.in_contact ? 1 : 0;
    force_sum_contact += r.in_contact ? f : 0.0;
    std::snprintf(row, sizeof row,
                  "%.6f,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.6g,%.6g,%.6g,%.6g,%d,%d,%.4g,%.4g,%.6g,%d,%d,%.9g,%.3g\n",
                  r.t_s - t0, r.hip_m.x, r.hip_m.y, r.hip_m.z, r.proxy_m.x, r.proxy_m.y, r.proxy_m.z,
                  r.force_n.x, r.force_n.y, r.force_n.z, f, r.in_contact ? 1 : 0, r.sticking ? 1 : 0,
                  static_cast<double>(r.mu_d), static_cast<double>(r.mu_s), static_cast<double>(r.beta_rad),
                  static_cast<int>(r.iterations), static_cast<int>(r.compute_ns), zs, below);
    csv << row;
  }
  csv.close();
  std::ofstream ev(out / "events.csv");
  ev << "t_s,type,region_id,x_m,y_m,z_m,force_n,speed_m_per_s\n";
  std::size_t counts[4] = {0, 0, 0, 0};
  for (const haptics::ContactEvent& e : events) {
    static const char* kNames[4] = {"onset", "slide", "release", "press"};
    const auto type = static_cast<std::size_t>(e.type);
    ++counts[type];
    std::snprintf(row, sizeof row, "%.6f,%s,%d,%.9g,%.9g,%.9g,%.6g,%.6g\n", e.t_s - t0, kNames[type],
                  static_cast<int>(e.region_id), e.position_m.x, e.position_m.y, e.position_m.z,
                  e.force_n.eigen().norm(), e.speed_m_per_s);
    ev << row;
  }
  ev.close();

  std::string audio_json;
#ifdef HC_HAVE_AUDIO
  if (live) {
    std::this_thread::sleep_for(std::chrono::milliseconds(300));  // let the last notes start
    live->stop();
    const audio::EngineStats st = live->stats();
    audio_json += "  \"audio_live\": {\"device\": \"" + o.audio_live + "\", \"events\": " + std::to_string(st.events) +
                  ", \"onsets_played\": " + std::to_string(st.onsets_played) + ", \"underruns\": " +
                  std::to_string(st.underruns) + ", \"latency_median_ms\": " + json_number(st.latency_median_s * 1e3) +
                  ", \"latency_max_ms\": " + json_number(st.latency_max_s * 1e3) + "},\n";
    std::cout << "  audio live: " << st.onsets_played << " onsets played, event->first sample latency median "
              << st.latency_median_s * 1e3 << " ms (max " << st.latency_max_s * 1e3 << " ms), " << st.underruns
              << " underruns\n";
  }
  if (!o.audio_out.empty()) {
    // The same mixer as the live player, sample-accurate to the event times: sample
    // round((t - t0) * rate) with t0 the first tick, as in events.csv.
    audio::MixerStats ms;
    const std::vector<float> wav =
        audio::render_offline(audio_scene, events, t0, static_cast<double>(trace.size()) / o.rate_hz, 1.0, &ms);
    audio::write_wav(o.audio_out, wav, audio_scene->config.sample_rate_hz);
    float peak = 0.0F;
    for (float v : wav) peak = std::max(peak, std::abs(v));
    const double peak_dbfs = peak > 0.0F ? 20.0 * std::log10(static_cast<double>(peak)) : -200.0;
    audio_json += "  \"audio\": {\"file\": \"" + o.audio_out + "\", \"sample_rate_hz\": " +
                  std::to_string(audio_scene->config.sample_rate_hz) + ", \"seconds\": " +
                  json_number(static_cast<double>(wav.size()) / audio_scene->config.sample_rate_hz) +
                  ", \"regions\": " + std::to_string(audio_scene->config.regions.size()) +
                  ", \"onsets_played\": " + std::to_string(ms.onsets_played) + ", \"onsets_silent\": " +
                  std::to_string(ms.onsets_silent) + ", \"peak_dbfs\": " + json_number(peak_dbfs) +
                  ", \"limiter_min_gain\": " + json_number(ms.limiter_min_gain) +
                  ", \"latency_note\": \"live event-to-first-sample latency: bench/audio_bench (docs/audio.md)\"},\n";
    std::cout << "  audio: wrote " << o.audio_out << " (" << wav.size() << " samples, " << ms.onsets_played
              << " notes, peak " << peak_dbfs << " dBFS)\n";
  }
#endif

  const double p50 = stats.compute.percentile_ns(0.5), p99 = stats.compute.percentile_ns(0.99);
  const double p999 = stats.compute.percentile_ns(0.999);
  const double cmax = static_cast<double>(stats.compute.max_ns());
  std::ofstream js(out / "summary.json");
  js << "{\n"
     << "  \"input\": \"" << scene.description << "\",\n"
     << "  \"path\": \"" << o.path << "\",\n"
     << "  \"mode\": \"" << (o.realtime ? "realtime" : "as_fast_as_possible") << "\",\n"
     << "  \"rate_hz\": " << json_number(o.rate_hz) << ",\n"
     << "  \"texture_gain\": " << json_number(o.texture_gain) << ",\n"
     << "  \"friction\": " << (o.no_friction ? "false" : "true") << ",\n"
     << "  \"ticks\": " << stats.ticks << ",\n"
     << "  \"overruns\": " << stats.overruns << ",\n"
     << "  \"compute_ns\": {\"mean\": " << json_number(stats.compute.mean_ns()) << ", \"p50\": " << json_number(p50)
     << ", \"p99\": " << json_number(p99) << ", \"p99_9\": " << json_number(p999) << ", \"max\": " << json_number(cmax) << "},\n"
     << "  \"lateness_ns\": {\"p99_9\": " << json_number(stats.lateness.percentile_ns(0.999))
     << ", \"max\": " << stats.lateness.max_ns() << "},\n"
     << "  \"max_force_n\": " << json_number(max_force) << ",\n"
     << "  \"deepest_proxy_below_surface_m\": " << json_number(deepest) << ",\n"
     << "  \"contact_fraction\": " << json_number(trace.empty() ? 0.0 : static_cast<double>(contact_ticks) / static_cast<double>(trace.size())) << ",\n"
     << "  \"events\": {\"onset\": " << counts[0] << ", \"slide\": " << counts[1] << ", \"release\": " << counts[2] << ", \"press\": " << counts[3]
     << ", \"dropped\": " << shared.counters.events_dropped.load() << "},\n"
     << audio_json
     << (lod ? "  \"lod\": " + lod->json() + ",\n" : std::string())
     << "  \"realtime\": {\"fifo_granted\": " << (report.fifo_granted ? "true" : "false")
     << ", \"memory_locked\": " << (report.memory_locked ? "true" : "false") << "}\n"
     << "}\n";
  js.close();

  plot_sessions({{"", &trace}}, out / "proxy_z.png", out / "force.png", scene.description + ", " + o.path);
  std::cout << "touch: " << scene.description << ", path " << o.path << ", " << stats.ticks << " ticks at "
            << o.rate_hz << " Hz (" << (o.realtime ? "real time" : "as fast as possible") << ")\n"
            << "  overruns " << stats.overruns << "\n"
            << "  compute ns: p50 " << p50 << ", p99 " << p99 << ", p99.9 " << p999 << ", max " << cmax << "\n"
            << "  max force " << max_force << " N; deepest proxy below the surface " << deepest << " m\n"
            << "  contact " << contact_ticks << " ticks; events: " << counts[0] << " onset, " << counts[1]
            << " slide, " << counts[2] << " release, " << counts[3] << " press\n"
            << "  wrote " << (out / "trace.csv").string() << ", events.csv, summary.json, proxy_z.png, force.png\n";
  if (lod) lod->print(std::cout);
  SessionSummary sum;
  sum.max_force_n = max_force;
  sum.deepest_m = deepest;
  sum.mean_force_contact_n = contact_ticks ? force_sum_contact / static_cast<double>(contact_ticks) : 0.0;
  sum.ticks = stats.ticks;
  sum.overruns = stats.overruns;
  sum.p50_ns = p50;
  sum.p99_ns = p99;
  sum.p999_ns = p999;
  sum.max_ns = cmax;
  return sum;
}

void run_touch(const TouchOptions& o) {
  if (!(o.seconds > 0.0) || o.seconds > 3600.0) {
    throw ConfigError("touch: --seconds " + json_number(o.seconds) + " is out of range (expected (0, 3600])");
  }
  // Options checked before anything is written to --out.
  if (o.level < -1) {
    throw ConfigError("touch: --level " + std::to_string(o.level) + ": expected -1 (the coarsest) or a level >= 0");
  }
  if (o.window_cells_given && !lod_mode(o)) {
    throw ConfigError("touch: --window-cells " + std::to_string(o.window_cells) +
                      " needs --level (or --window / --zoom-path): without levels of detail there is no window");
  }
  if (o.window_cells_given && (o.window_cells < 2 || o.window_cells > 4096)) {
    throw ConfigError("touch: --window-cells " + std::to_string(o.window_cells) + ": expected an integer in [2, 4096]");
  }
  if (!o.window.empty()) (void)parse_window_origin(o.window);
  if (!o.zoom_path.empty()) (void)parse_zoom_path(o.zoom_path);
  const fs::path out(o.out);
  SceneLayers scene = load_input(o);
  // The session's levels and windows are checked against the scene's pyramid in run_session,
  // before its output folder is made.
  if (!o.audio_config.empty()) scene.audio = pipeline::load_run_config(o.audio_config).audio;
  if (o.validate && (!o.audio_out.empty() || !o.audio_live.empty())) {
    throw ConfigError("touch: --audio-out and --audio-live are for one session, not with --validate");
  }
#ifndef HC_HAVE_AUDIO
  if (!o.audio_out.empty() || !o.audio_live.empty()) {
    throw ConfigError("touch: this build has no audio module (hc::audio); --audio-out/--audio-live are unavailable");
  }
#endif
  // run_session makes its output folder once its level-of-detail session is set up (so a bad
  // level or window leaves nothing in --out).
  if (!o.validate) {
    std::vector<haptics::TickRecord> trace;
    run_session(o, scene, out, trace);
    return;
  }
  // The paper's validation (Sec. 5.1, Figs. of proxy z and force against time): one scripted
  // press-and-slide, rendered with texture and friction, and again without either.
  TouchOptions with = o, without = o;
  with.path = without.path = (o.path == "raster" ? std::string("press-slide") : o.path);
  without.texture_gain = 0.0;
  without.no_friction = true;
  std::vector<haptics::TickRecord> trace_with, trace_without;
  const SessionSummary a = run_session(with, scene, out / "with_texture_friction", trace_with);
  const SessionSummary b = run_session(without, scene, out / "without_texture_friction", trace_without);
  plot_sessions({{" (texture + friction)", &trace_with}, {" (neither)", &trace_without}},
                out / "validation_proxy_z.png", out / "validation_force.png", "validation, " + with.path);
  std::ofstream md(out / "report.md");
  md << "# hapticloud touch: validation on " << scene.description << "\n\n"
     << "The paper's validation (Sec. 5.1): the same scripted " << with.path
     << " rendered with surface texture and friction, and without either (texture gain 0, "
        "mu_s = mu_d = 0). Time axis from the first tick; z in the model frame.\n\n"
     << "| session | ticks | max force (N) | mean force in contact (N) | deepest proxy below surface (m) | "
        "compute p50 / p99.9 (ns) |\n|---|---|---|---|---|---|\n";
  const auto row = [&](const char* name, const SessionSummary& s) {
    md << "| " << name << " | " << s.ticks << " | " << s.max_force_n << " | " << s.mean_force_contact_n << " | "
       << s.deepest_m << " | " << s.p50_ns << " / " << s.p999_ns << " |\n";
  };
  row("texture + friction", a);
  row("neither", b);
  md << "\n![proxy z against time](validation_proxy_z.png)\n\n![force against time](validation_force.png)\n";
  std::cout << "touch: validation report " << (out / "report.md").string() << "\n";
}

}  // namespace

void add_touch_command(CLI::App& app) {
  auto opts = std::make_shared<TouchOptions>();
  CLI::App* cmd = app.add_subcommand(
      "touch", "Headless scripted haptic session: a simulated hand explores a scene; writes trace.csv and a summary.");
  cmd->add_option("SCENE_OR_CONFIG", opts->input,
                  "Scene folder written by `hapticloud run`, or a run config (its scene is built first)");
  cmd->add_option("--synthetic", opts->synthetic, "Built-in scene instead of a folder: sinusoid (the paper's validation surface)");
  cmd->add_option("--path", opts->path, "Scripted path: raster | circle | line | press-slide | hold")->capture_default_str();
  cmd->add_option("--seconds", opts->seconds, "Session length [s]")->capture_default_str();
  cmd->add_option("--rate", opts->rate_hz, "Servo rate [Hz], up to 10000")->capture_default_str();
  cmd->add_flag("--realtime", opts->realtime, "Run the servo thread in real time (tries SCHED_FIFO; realtime: warn)");
  cmd->add_option("--out", opts->out, "Output folder")->capture_default_str();
  cmd->add_option("--texture-gain", opts->texture_gain, "Texture gain (0 renders the envelope only)")->capture_default_str();
  cmd->add_flag("--no-friction", opts->no_friction, "Render without friction (mu_d = mu_s = 0)");
  cmd->add_option("--mu-d", opts->mu_d, "mu_d where the scene has no mu_d layer")->capture_default_str();
  cmd->add_option("--mu-s", opts->mu_s, "mu_s where the scene has no mu_s layer")->capture_default_str();
  cmd->add_option("--stiffness", opts->stiffness_n_per_m, "Stiffness k [N/m] (device frame)")->capture_default_str();
  cmd->add_option("--max-force", opts->max_force_n, "Force cap [N]")->capture_default_str();
  cmd->add_option("--rho", opts->rho, "Proxy step factor rho of Eq. 4-5, (0, 1]")->capture_default_str();
  cmd->add_option("--cells", opts->cells, "Grid size of the synthetic scene (N x N)")->capture_default_str();
  cmd->add_option("--press", opts->press_m, "How far below mid height the hand aims [m] (device frame)")->capture_default_str();
  cmd->add_option("--speed", opts->speed_m_per_s, "Path speed [m/s] (device frame)")->capture_default_str();
  cmd->add_flag("--validate", opts->validate,
                "Paper's validation: the session with and without texture and friction, plots and report.md");
  cmd->add_flag("--no-hand", opts->no_hand, "Drive the device exactly along the path (no virtual hand)");
  cmd->add_option("--audio-out", opts->audio_out,
                  "Write the session's contact sounds to this WAV file (offline, sample-accurate to the events)");
  cmd->add_option("--audio-live", opts->audio_live,
                  "Play the contact sounds while the session runs: default | loopback | an OpenAL device name");
  cmd->add_option("--audio-config", opts->audio_config,
                  "Run config whose audio: section to use (default: the input config's own)");
  CLI::Option* level_opt = cmd->add_option(
      "--level", opts->level,
      "Levels of detail: render a window of this level (0 = finest; each level halves the resolution; -1 = coarsest)");
  cmd->add_option("--window", opts->window,
                  "X,Y: first column and row of the haptic window at --level (default: centred)");
  CLI::Option* cells_opt = cmd->add_option("--window-cells", opts->window_cells,
                                           "Side of the haptic window [samples], 2..4096 (default: the scene's "
                                           "lod.window_cells, else 200); needs --level, --window or --zoom-path");
  cmd->add_option("--zoom-path", opts->zoom_path,
                  "Scripted level switches and pans: a file (one 'T ACTION ARGS' per line) or a spec like "
                  "'1:in,2.5:pan:20:-10,4:out,5:level:2,6:window:1:0:40' (T in seconds; zooms keep the proxy)");
  cmd->callback([opts, level_opt, cells_opt] {
    opts->level_given = level_opt->count() > 0;
    opts->window_cells_given = cells_opt->count() > 0;
    run_touch(*opts);
  });
}

}  // namespace hc::app
