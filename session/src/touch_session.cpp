#include "hc/session/touch_session.hpp"

#include "hc/common/error.hpp"
#include "hc/common/format.hpp"
#include "hc/haptics/haptic_surface.hpp"
#include "hc/haptics/recording.hpp"
#include "hc/haptics/simulated_device.hpp"
#include "hc/pipeline/plot.hpp"
#include "hc/pipeline/synthetic.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <sstream>
#include <thread>

namespace hc::session {
namespace {

namespace fs = std::filesystem;
using haptics::HapticSurface;

/// Numbers in messages: 10 significant digits (hc::format_number).
std::string number_text(double v) { return format_number(v, 10); }

/// @throws hc::ConfigError naming `option` unless lo (<) v <= hi and v is finite.
void check_range(const char* option, double v, double lo, bool lo_open, double hi) {
  const bool ok = std::isfinite(v) && (lo_open ? v > lo : v >= lo) && v <= hi;
  if (!ok) {
    throw ConfigError(std::string("touch: ") + option + " " + number_text(v) + " is out of range (expected a number in " +
                      (lo_open ? "(" : "[") + number_text(lo) + ", " + number_text(hi) + "])");
  }
}

/// `v` rounded to 10 significant digits, as the summary has always printed its numbers (so a
/// capped force reads 8, not 8.000000000000002); non-finite values stay (written as null).
double sig10(double v) {
  if (!std::isfinite(v)) return v;
  return std::stod(number_text(v));
}

const HeightField* present(const HeightField& f) { return f.rows() > 0 ? &f : nullptr; }

haptics::SurfaceOptions surface_options(const TouchSessionOptions& o) {
  haptics::SurfaceOptions s;
  s.texture_gain = o.texture_gain;
  s.default_mu_d = o.mu_d;
  s.default_mu_s = o.mu_s;
  return s;
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

/// The summary figures of a finished session (trace, surface heights and events filled).
TouchFigures figures_of(const TouchSessionResult& r, std::uint64_t dropped) {
  TouchFigures f;
  double force_sum_contact = 0.0;
  for (std::size_t i = 0; i < r.trace.size(); ++i) {
    const haptics::TickRecord& t = r.trace[i];
    const double force = t.force_n.eigen().norm();
    f.max_force_n = std::max(f.max_force_n, force);
    f.deepest_m = std::max(f.deepest_m, r.surface_z_m[i] - t.proxy_m.z);
    f.contact_ticks += t.in_contact ? 1 : 0;
    force_sum_contact += t.in_contact ? force : 0.0;
  }
  f.mean_force_contact_n = f.contact_ticks ? force_sum_contact / static_cast<double>(f.contact_ticks) : 0.0;
  f.contact_fraction =
      r.trace.empty() ? 0.0 : static_cast<double>(f.contact_ticks) / static_cast<double>(r.trace.size());
  for (const haptics::ContactEvent& e : r.events) ++f.events_by_type[static_cast<std::size_t>(e.type)];
  f.events_dropped = dropped;
  f.p50_ns = r.stats.compute.percentile_ns(0.5);
  f.p99_ns = r.stats.compute.percentile_ns(0.99);
  f.p999_ns = r.stats.compute.percentile_ns(0.999);
  f.max_ns = static_cast<double>(r.stats.compute.max_ns());
  return f;
}

}  // namespace

void TouchSessionOptions::validate() const {
  (void)haptics::path_kind_from_string(path);
  const haptics::DeviceInfo info = haptics::SimulatedDevice::default_info();
  check_range("--seconds", seconds, 0.0, true, 3600.0);
  check_range("--rate", rate_hz, 0.0, true, 10000.0);
  check_range("--texture-gain", texture_gain, 0.0, false, 100.0);
  check_range("--mu-d", mu_d, 0.0, false, 10.0);
  check_range("--mu-s", mu_s, 0.0, false, 10.0);
  check_range("--stiffness", stiffness_n_per_m, 0.0, true, info.max_stable_stiffness_n_per_m);
  check_range("--max-force", max_force_n, 0.0, true, info.max_force_n);
  check_range("--rho", rho, 0.0, true, 1.0);
  check_range("--press", press_m, 0.0, false, 0.1);
  check_range("--speed", speed_m_per_s, 0.0, true, 10.0);
  if (level < -1) {
    throw ConfigError("touch: --level " + std::to_string(level) + ": expected -1 (the coarsest) or a level >= 0");
  }
  if (window_cells != 0 && !levels) {
    throw ConfigError("touch: --window-cells " + std::to_string(window_cells) +
                      " needs --level (or --window / --zoom-path): without levels of detail there is no window");
  }
  if (window_cells != 0 && (window_cells < 2 || window_cells > 4096)) {
    throw ConfigError("touch: --window-cells " + std::to_string(window_cells) + ": expected an integer in [2, 4096]");
  }
}

TouchSessionResult run_touch_session(const Scene& scene, const TouchSessionOptions& options, const TouchSessionHooks& hooks,
                                     std::shared_ptr<pipeline::LodPyramid> stored_levels) {
  options.validate();
  TouchSessionOptions o = options;
  if (stored_levels) o.levels = true;  // a stored scene is rendered through its windows
  const SceneLayers& sl = scene.layers;
  if (sl.depth.rows() == 0 && !stored_levels) throw InputError("touch: the scene has no depth layer");
  haptics::SurfaceLayers layers;
  layers.depth = &sl.depth;
  layers.envelope = present(sl.envelope);
  layers.texture = present(sl.texture);
  layers.mu_d = present(sl.mu_d);
  layers.mu_s = present(sl.mu_s);
  layers.region_id = hooks.region_id;
  const haptics::SurfaceOptions sopt = surface_options(o);
  const haptics::DeviceInfo info = haptics::SimulatedDevice::default_info();

  // Levels of detail (issue 4): the servo renders a window of a level; the LodSession publishes
  // it (and every scripted switch) with its workspace map through the surface mailbox.
  haptics::SharedState shared(o.levels ? nullptr : std::make_unique<HapticSurface>(layers, sopt));
  std::unique_ptr<LodSession> lod;
  TouchSessionResult res;
  double top_dev = 0.0;
  if (o.levels) {
    if (layers.region_id != nullptr) {
      throw ConfigError("touch: audio regions are not carried into level-of-detail windows yet; drop --level, "
                        "--window and --zoom-path, or the audio options");
    }
    LodOptions lod_options = scene.lod;
    if (o.window_cells != 0) lod_options.window_cells = o.window_cells;
    if (stored_levels) {
      lod = std::make_unique<LodSession>(stored_levels, sopt, info.workspace_half_extent_m, o.level, o.window_origin,
                                         o.zoom_path, shared);
    } else {
      lod = std::make_unique<LodSession>(sl, sopt, info.workspace_half_extent_m, o.level, o.window_origin, o.zoom_path,
                                         shared, scene.layer_options, lod_options);
    }
    res.map = lod->initial().map;
    top_dev = (lod->initial().max_height_m - res.map.origin_m.z()) / res.map.scale;
  } else {
    // Device and workspace: the grid's extent fills the device box, device z = 0 at mid height.
    const HapticSurface& surf = *shared.current_surface();
    const GridGeometry& g = surf.source_geometry();
    const double z_mid = 0.5 * (surf.min_height_m() + surf.max_height_m());
    res.map = haptics::WorkspaceMap::fit(info.workspace_half_extent_m, g.x0_m, g.x_of_col(g.cols - 1), g.y0_m,
                                         g.y_of_row(g.rows - 1), z_mid);
    top_dev = (surf.max_height_m() - z_mid) / res.map.scale;
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
  hand.enabled = o.hand;

  haptics::ServoConfig cfg;
  cfg.rate_hz = o.rate_hz;
  cfg.realtime = o.realtime ? haptics::RealtimeMode::kWarn : haptics::RealtimeMode::kOff;
  cfg.workspace = res.map;
  cfg.proxy.stiffness_n_per_m = o.stiffness_n_per_m;
  cfg.proxy.max_force_n = o.max_force_n;
  cfg.proxy.rho = o.rho;
  cfg.proxy.friction_enabled = o.friction;
  const double ticks_d = std::ceil(o.seconds * o.rate_hz);
  if (ticks_d > 5.0e7) {
    throw ResourceError("touch: " + number_text(ticks_d) +
                        " ticks requested (--seconds x --rate), at most 5e7 are traced");
  }
  const auto ticks = static_cast<std::uint64_t>(ticks_d);
  std::vector<haptics::TickRecord>& trace = res.trace;
  trace.assign(ticks + 16, haptics::TickRecord{});

  res.events.reserve(1 << 16);
  const auto drain = [&] {
    haptics::ContactEvent e;
    while (shared.events.try_pop(e)) {
      res.events.push_back(e);
      if (hooks.on_event) hooks.on_event(e);
    }
  };
  // The device: the scripted one or a replay, wrapped by a recorder when asked.
  struct Devices {
    std::unique_ptr<haptics::HapticDevice> base;
    std::unique_ptr<haptics::RecordingDevice> recorder;
    haptics::HapticDevice& active() { return recorder ? *recorder : *base; }
    // Closes the device after a normal end (an exception skips this: the destructors then
    // close it and the recording is not kept); a recording that could not be kept is an error.
    void close() {
      if (recorder) recorder->keep_on_close();
      active().close();
      if (recorder && !recorder->error().empty()) throw InputError("touch: " + recorder->error());
    }
  };
  const auto make_devices = [&](const haptics::Clock& clock) {
    Devices d;
    if (o.replay_file.empty()) {
      d.base = std::make_unique<haptics::SimulatedDevice>(clock, path, hand, info);
    } else {
      d.base = std::make_unique<haptics::TickReplayDevice>(clock, o.replay_file, info);
    }
    if (!o.record_file.empty()) {
      d.recorder = std::make_unique<haptics::RecordingDevice>(*d.base, o.record_file);
      d.recorder->watch(shared, o.rate_hz);  // the servo's commands and surface switches with their ticks
    }
    d.active().open();
    return d;
  };
  if (!o.realtime) {
    auto clock = std::make_unique<haptics::ManualClock>();
    Devices devices = make_devices(*clock);
    haptics::HapticDevice& dev = devices.active();
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
    res.stats = loop.stats();
    trace.resize(loop.trace_size());
    devices.close();
  } else {
    haptics::SteadyClock clock;
    Devices devices = make_devices(clock);
    haptics::HapticDevice& dev = devices.active();
    haptics::ServoLoop loop(dev, shared, clock, cfg);
    loop.set_trace(trace);
    shared.commands.try_push(haptics::Command::of(haptics::CommandType::kArm));
    res.realtime = loop.start();
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
    res.stats = loop.stats();
    trace.resize(std::min<std::size_t>(loop.trace_size(), ticks));
    devices.close();
  }

  // The rendered height under the proxy of every row, on the surface that row rendered.
  const HapticSurface& s = *shared.current_surface();
  res.surface_z_m.resize(trace.size());
  for (std::size_t i = 0; i < trace.size(); ++i) {
    const haptics::TickRecord& r = trace[i];
    res.surface_z_m[i] = (lod ? lod->surface_for(r.surface_tag) : s).height(r.proxy_m.x, r.proxy_m.y);
  }
  if (lod) {
    res.lod_json = lod->json();
    std::ostringstream text;
    lod->print(text);
    res.lod_text = text.str();
  }
  res.figures = figures_of(res, shared.counters.events_dropped.load());
  return res;
}

void write_touch_session(const TouchSessionResult& res, const TouchSessionOptions& o, const std::string& description,
                         const fs::path& out, const std::string& extra_json) {
  nlohmann::ordered_json extra = nlohmann::ordered_json::object();
  if (!extra_json.empty()) {
    extra = nlohmann::ordered_json::parse(extra_json, nullptr, false);
    if (!extra.is_object()) throw ConfigError("touch: the extra summary members are not a JSON object");
  }
  std::error_code ec;
  fs::create_directories(out, ec);
  if (ec) throw InputError("touch: cannot create the output folder '" + out.string() + "': " + ec.message());

  const std::vector<haptics::TickRecord>& trace = res.trace;
  std::ofstream csv(out / "trace.csv");
  if (!csv) throw InputError("touch: cannot write '" + (out / "trace.csv").string() + "'");
  csv << "t_s,hip_x_m,hip_y_m,hip_z_m,proxy_x_m,proxy_y_m,proxy_z_m,force_x_n,force_y_n,force_z_n,"
         "force_n,contact,sticking,mu_d,mu_s,beta_rad,iterations,compute_ns,surface_z_m,"
         "proxy_below_surface_m\n";
  const double t0 = trace.empty() ? 0.0 : trace.front().t_s;
  char row[512];
  for (std::size_t i = 0; i < trace.size(); ++i) {
    const haptics::TickRecord& r = trace[i];
    const double f = r.force_n.eigen().norm();
    const double zs = res.surface_z_m[i];
    const double below = zs - r.proxy_m.z;
    std::snprintf(row, sizeof row,
                  "%.6f,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.6g,%.6g,%.6g,%.6g,%d,%d,%.4g,%.4g,%.6g,%d,%d,%.9g,%.3g\n",
                  r.t_s - t0, r.hip_m.x, r.hip_m.y, r.hip_m.z, r.proxy_m.x, r.proxy_m.y, r.proxy_m.z,
                  r.force_n.x, r.force_n.y, r.force_n.z, f, r.in_contact ? 1 : 0, r.sticking ? 1 : 0,
                  static_cast<double>(r.mu_d), static_cast<double>(r.mu_s), static_cast<double>(r.beta_rad),
                  static_cast<int>(r.iterations), static_cast<int>(r.compute_ns), zs, below);
    csv << row;
  }
  csv.close();
  if (!csv) throw InputError("touch: cannot write '" + (out / "trace.csv").string() + "'");
  std::ofstream ev(out / "events.csv");
  ev << "t_s,type,region_id,x_m,y_m,z_m,force_n,speed_m_per_s\n";
  for (const haptics::ContactEvent& e : res.events) {
    static const char* kNames[4] = {"onset", "slide", "release", "press"};
    std::snprintf(row, sizeof row, "%.6f,%s,%d,%.9g,%.9g,%.9g,%.6g,%.6g\n", e.t_s - t0,
                  kNames[static_cast<std::size_t>(e.type)], static_cast<int>(e.region_id), e.position_m.x,
                  e.position_m.y, e.position_m.z, e.force_n.eigen().norm(), e.speed_m_per_s);
    ev << row;
  }
  ev.close();
  if (!ev) throw InputError("touch: cannot write '" + (out / "events.csv").string() + "'");

  // summary.json: numbers as JSON numbers (non-finite as null), strings escaped (invalid UTF-8
  // replaced), members in a fixed order.
  const TouchFigures& f = res.figures;
  const haptics::ServoStats& st = res.stats;
  nlohmann::ordered_json j;
  j["input"] = description;
  j["path"] = o.path;
  j["mode"] = o.realtime ? "realtime" : "as_fast_as_possible";
  j["rate_hz"] = sig10(o.rate_hz);
  j["texture_gain"] = sig10(o.texture_gain);
  j["friction"] = o.friction;
  j["ticks"] = st.ticks;
  j["overruns"] = st.overruns;
  j["compute_ns"] = {{"mean", sig10(st.compute.mean_ns())}, {"p50", sig10(f.p50_ns)}, {"p99", sig10(f.p99_ns)},
                     {"p99_9", sig10(f.p999_ns)}, {"max", sig10(f.max_ns)}};
  j["lateness_ns"] = {{"p99_9", sig10(st.lateness.percentile_ns(0.999))}, {"max", st.lateness.max_ns()}};
  j["max_force_n"] = sig10(f.max_force_n);
  j["deepest_proxy_below_surface_m"] = sig10(f.deepest_m);
  j["contact_fraction"] = sig10(f.contact_fraction);
  j["events"] = {{"onset", f.events_by_type[0]}, {"slide", f.events_by_type[1]}, {"release", f.events_by_type[2]},
                 {"press", f.events_by_type[3]}, {"dropped", f.events_dropped}};
  for (auto it = extra.begin(); it != extra.end(); ++it) j[it.key()] = it.value();
  if (!res.lod_json.empty()) j["lod"] = nlohmann::ordered_json::parse(res.lod_json);
  j["realtime"] = {{"fifo_granted", res.realtime.fifo_granted},
                   {"memory_locked", res.realtime.memory_locked},
                   {"cpu_latency_pinned", res.realtime.cpu_latency_pinned}};
  std::ofstream js(out / "summary.json");
  js << j.dump(2, ' ', false, nlohmann::ordered_json::error_handler_t::replace) << "\n";
  js.close();
  if (!js) throw InputError("touch: cannot write '" + (out / "summary.json").string() + "'");

  plot_sessions({{"", &trace}}, out / "proxy_z.png", out / "force.png", description + ", " + o.path);
}

void print_touch_session(std::ostream& out, const TouchSessionResult& res, const TouchSessionOptions& o,
                         const std::string& description, const fs::path& dir) {
  const TouchFigures& f = res.figures;
  out << "touch: " << description << ", path " << o.path << ", " << res.stats.ticks << " ticks at " << o.rate_hz
      << " Hz (" << (o.realtime ? "real time" : "as fast as possible") << ")\n"
      << "  overruns " << res.stats.overruns << "\n"
      << "  compute ns: p50 " << f.p50_ns << ", p99 " << f.p99_ns << ", p99.9 " << f.p999_ns << ", max " << f.max_ns
      << "\n"
      << "  max force " << f.max_force_n << " N; deepest proxy below the surface " << f.deepest_m << " m\n"
      << "  contact " << f.contact_ticks << " ticks; events: " << f.events_by_type[0] << " onset, "
      << f.events_by_type[1] << " slide, " << f.events_by_type[2] << " release, " << f.events_by_type[3]
      << " press\n"
      << "  wrote " << (dir / "trace.csv").string() << ", events.csv, summary.json, proxy_z.png, force.png\n"
      << res.lod_text;
}

std::pair<TouchSessionOptions, TouchSessionOptions> validation_options(const TouchSessionOptions& o) {
  TouchSessionOptions with = o, without = o;
  with.path = without.path = (o.path == "raster" ? std::string("press-slide") : o.path);
  without.texture_gain = 0.0;
  without.friction = false;
  return {with, without};
}

void write_validation_report(const TouchSessionResult& a, const TouchSessionResult& b, const std::string& path,
                             const std::string& description, const fs::path& out) {
  plot_sessions({{" (texture + friction)", &a.trace}, {" (neither)", &b.trace}}, out / "validation_proxy_z.png",
                out / "validation_force.png", "validation, " + path);
  std::ofstream md(out / "report.md");
  md << "# hapticloud touch: validation on " << description << "\n\n"
     << "The paper's validation (Sec. 5.1): the same scripted " << path
     << " rendered with surface texture and friction, and without either (texture gain 0, "
        "mu_s = mu_d = 0). Time axis from the first tick; z in the model frame.\n\n"
     << "| session | ticks | max force (N) | mean force in contact (N) | deepest proxy below surface (m) | "
        "compute p50 / p99.9 (ns) |\n|---|---|---|---|---|---|\n";
  const auto row = [&](const char* name, const TouchSessionResult& r) {
    const TouchFigures& f = r.figures;
    md << "| " << name << " | " << r.stats.ticks << " | " << f.max_force_n << " | " << f.mean_force_contact_n
       << " | " << f.deepest_m << " | " << f.p50_ns << " / " << f.p999_ns << " |\n";
  };
  row("texture + friction", a);
  row("neither", b);
  md << "\n![proxy z against time](validation_proxy_z.png)\n\n![force against time](validation_force.png)\n";
  md.close();
  if (!md) throw InputError("touch: cannot write '" + (out / "report.md").string() + "'");
}

Scene synthetic_sinusoid_scene(int n) {
  if (n < 2 || n > 8192) {
    throw ConfigError("touch: --cells " + std::to_string(n) + " is out of range (expected 2..8192)");
  }
  const double side = 0.1;
  const double cell = side / (n - 1);
  const GridGeometry g{n, n, -side / 2, -side / 2, cell};
  pipeline::SyntheticSpec env_spec, tex_spec;
  env_spec.kind = tex_spec.kind = pipeline::SurfaceKind::kSinusoid;
  env_spec.amplitude_m = 0.004;
  env_spec.wavelength_m = 0.04;
  tex_spec.amplitude_m = 0.0002;
  tex_spec.wavelength_m = 0.002;
  Scene scene;
  scene.geometry = g;
  HeightField env(g), tex(g), depth(g);
  for (int r = 0; r < n; ++r) {
    for (int c = 0; c < n; ++c) {
      const double x = g.x_of_col(c), y = g.y_of_row(r);
      const double e = pipeline::synthetic_height(env_spec, x, y);
      const double t = pipeline::synthetic_height(tex_spec, x, y);
      env.at(r, c) = static_cast<float>(e);
      tex.at(r, c) = static_cast<float>(t);
      depth.at(r, c) = static_cast<float>(e + t);
    }
  }
  scene.layers.depth = std::move(depth);
  scene.layers.envelope = std::move(env);
  scene.layers.texture = std::move(tex);
  scene.provenance.synthetic = "touch sinusoid " + std::to_string(n) + "x" + std::to_string(n);
  return scene;
}

}  // namespace hc::session
