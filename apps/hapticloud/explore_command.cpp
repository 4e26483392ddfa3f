/// `hapticloud explore`: the interactive session of the paper. The scene (built from a run
/// config, or loaded from a scene folder) goes into a level-of-detail pyramid; a LodController
/// publishes the haptic window to the servo loop (its own thread, 1 kHz); the viewer (this,
/// the UI thread) draws snapshots, sends level/region and parameter commands, and asks for
/// re-scans, which run the pipeline on a worker thread and replace the scene without a restart
/// while the device is disarmed (zero force). Devices: the Falcon (hc::falcon), the mouse, or a
/// scripted path (sim). Audio through hc::audio when it is built.
///
/// Threads (docs/architecture.md): servo (SCHED_FIFO when granted), UI (this thread, nice +10
/// once the servo runs, and every thread it starts inherits that: Mesa's, the workers'),
/// re-scan / rebuild workers (std::async), audio (hc::audio's own).

#include "commands.hpp"

#include "hc/common/error.hpp"
#include "hc/common/units.hpp"
#include "hc/haptics/clock.hpp"
#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/stop_signal.hpp"
#include "hc/haptics/shared_state.hpp"
#include "hc/haptics/simulated_device.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/session/lod_controller.hpp"
#include "hc/session/scene_source.hpp"
#include "hc/pipeline/lod_report.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/pipeline/surface_layers.hpp"
#include "hc/pipeline/synthetic.hpp"
#include "hc/pipeline/transform.hpp"

#ifdef HC_HAVE_VIEWER
#include "hc/viewer/input_devices.hpp"
#include "hc/viewer/viewer.hpp"
#endif
#ifdef HC_HAVE_FALCON
#include "hc/falcon/falcon_device.hpp"
#include "hc/falcon/usb_transport.hpp"
#endif
#ifdef HC_HAVE_AUDIO
#include "audio_setup.hpp"
#include "hc/audio/engine.hpp"
#include "hc/audio/mixer.hpp"
#endif

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <future>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

namespace hc::app {
namespace {

namespace fs = std::filesystem;

struct ExploreOptions {
  std::string input;
  std::string device = "mouse";
  std::string path = "raster";
  double speed_m_per_s = 0.03;
  std::string screenshot;
  int frames = 0;
  double seconds = 0.0;
  std::string summary;
  std::string out = "explore-out";
  int width = 1280, height = 800;
  bool stereo = false;
  bool hidden = false;
  bool no_audio = false;
  double stiffness_n_per_m = 800.0;
  double rho = 0.9;
  int window_cells = 0;  ///< 0: the config's lod.window_cells (200 for a scene folder)
  std::string realtime = "warn";
  std::string script;  ///< scripted actions "FRAME ACTION ARGS; ..." (tests, demos; see --help)
};

/// One scripted action: at frame `frame`, what a key, the panel or the orientation tool would do.
struct ScriptStep {
  int frame = 0;
  std::string action;          ///< finer | coarser | level | pan | centre | texture | mu_s | model | rescan | stereo
  std::vector<std::string> args;
};

/// Parses "FRAME ACTION [ARGS...]; ..." (frames ascending). @throws hc::ConfigError naming the step.
std::vector<ScriptStep> parse_script(const std::string& text) {
  static const std::map<std::string, std::size_t> kArity = {
      {"finer", 0}, {"coarser", 0}, {"level", 1}, {"pan", 2}, {"centre", 2}, {"texture", 1},
      {"mu_s", 1}, {"model", 1}, {"rescan", 3}, {"stereo", 1}};
  std::vector<ScriptStep> steps;
  std::stringstream all(text);
  std::string item;
  while (std::getline(all, item, ';')) {
    std::stringstream words(item);
    ScriptStep st;
    std::string frame;
    if (!(words >> frame)) continue;  // empty item
    const auto bad = [&](const std::string& why) {
      return ConfigError("explore: --script step '" + item + "': " + why +
                         " (expected FRAME ACTION ARGS with ACTION one of finer, coarser, level N, pan DX DY, "
                         "centre X_M Y_M, texture on|off, mu_s V, model paper|curvature, rescan AX AY AZ, stereo on|off)");
    };
    try {
      std::size_t used = 0;
      st.frame = std::stoi(frame, &used);
      if (used != frame.size() || st.frame < 1) throw std::invalid_argument("frame");
    } catch (const std::exception&) {
      throw bad("the frame must be an integer ≥ 1");
    }
    if (!(words >> st.action) || kArity.count(st.action) == 0) throw bad("unknown action");
    for (std::string w; words >> w;) st.args.push_back(w);
    if (st.args.size() != kArity.at(st.action)) throw bad("wrong number of arguments");
    if (!steps.empty() && st.frame < steps.back().frame) throw bad("frames must not decrease");
    steps.push_back(std::move(st));
  }
  return steps;
}

double script_number(const ScriptStep& st, std::size_t i) {
  try {
    return std::stod(st.args[i]);
  } catch (const std::exception&) {
    throw ConfigError("explore: --script step at frame " + std::to_string(st.frame) + ": '" + st.args[i] +
                      "' is not a number");
  }
}

#ifdef HC_HAVE_VIEWER

std::string fmt(double v, int precision = 4) {
  std::ostringstream s;
  s.precision(precision);
  s << v;
  return s.str();
}

/// A scene ready to explore: level 0 with its layers (kept for rebuilds) and its pyramid.
struct Built {
  Scene base;  ///< level-0 layers (depth, envelope, texture, mu_d, mu_s)
  std::shared_ptr<pipeline::LodPyramid> pyramid;
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
  std::string description;
  bool disarm = true;    ///< a new object (re-scan): zero force while it swaps
  bool keep_window = false;
};

/// Level 0 of a scene with only what a pyramid and a rebuild need (no cross-check or flags).
Scene copy_layers(const Scene& s) {
  Scene c;
  c.geometry = s.geometry;
  c.model_to_grid = s.model_to_grid;
  c.layers.depth = s.layers.depth;
  c.layers.envelope = s.layers.envelope;
  c.layers.texture = s.layers.texture;
  c.layers.mu_d = s.layers.mu_d;
  c.layers.mu_s = s.layers.mu_s;
  c.friction_model = s.friction_model;
  return c;
}

std::shared_ptr<Built> build(Scene scene, const pipeline::SurfaceLayerOptions& layer_options,
                             const pipeline::LodOptions& lod_options, bool recompute_layers) {
  auto b = std::make_shared<Built>();
  if (recompute_layers) {
    pipeline::SurfaceLayers l = pipeline::compute_surface_layers(scene.depth(), layer_options).value;
    scene.layers.envelope = std::move(l.envelope_m);
    scene.layers.texture = std::move(l.texture_m);
    scene.layers.mu_d = std::move(l.mu_d);
    scene.layers.mu_s = std::move(l.mu_s);
    scene.friction_model = l.friction_model;
  }
  b->base = copy_layers(scene);
  b->pyramid = pipeline::LodPyramid::from_scene(std::move(scene), layer_options, lod_options);
  return b;
}

/// The filtered cloud of a run, back in the recentred model frame (before the view transform:
/// the orientation tool turns it), subsampled to at most `max_points`, as float triplets.
std::vector<float> cloud_preview(const pipeline::Cloud& grid_frame_cloud, const pipeline::ViewTransform& view,
                                 std::size_t max_points) {
  const Eigen::Affine3d to_model = view.matrix().inverse();
  const std::size_t n = grid_frame_cloud.size();
  const std::size_t stride = std::max<std::size_t>(1, (n + max_points - 1) / max_points);
  std::vector<float> out;
  out.reserve(3 * (n / stride + 1));
  for (std::size_t i = 0; i < n; i += stride) {
    const Eigen::Vector3d p = to_model * grid_frame_cloud.xyz.col(static_cast<Eigen::Index>(i));
    if (!p.allFinite()) continue;
    for (int k = 0; k < 3; ++k) out.push_back(static_cast<float>(p[k]));
  }
  return out;
}

/// The interactive session (UI-thread side).
class Session {
 public:
  explicit Session(const ExploreOptions& o) : o_(o) {}

  void run();

 private:
  void load_input();
  void start_device();
  void show_window();
  void on_region(const viewer::RegionCommand& c);
  void on_rescan(const Eigen::Quaterniond& q);
  void on_surface_settings(const viewer::SurfaceSettings& s);
  void on_frame();
  void adopt(const std::shared_ptr<Built>& b);
  void run_step(const ScriptStep& st);
  session::LodControllerOptions controller_options() const;
  std::optional<Eigen::Vector3d> anchor() const;
  void write_summary(const haptics::ServoStats& stats, const haptics::RealtimeReport& rt) const;

  ExploreOptions o_;
  std::optional<pipeline::RunConfig> config_;
  std::vector<float> cloud_;
  pipeline::SurfaceLayerOptions layer_options_;
  pipeline::LodOptions lod_options_;
  std::shared_ptr<Built> built_;
  std::string description_;
  bool texture_enabled_ = true;

  haptics::SteadyClock clock_;
  haptics::SharedState shared_;
  std::unique_ptr<session::LodController> lod_;
  std::unique_ptr<haptics::HapticDevice> device_;
  viewer::MouseDevice* mouse_ = nullptr;
  std::unique_ptr<haptics::ServoLoop> loop_;
  std::unique_ptr<viewer::Viewer> viewer_;

  // Re-scan / rebuild on a worker thread, then the swap (UI thread).
  std::future<std::shared_ptr<Built>> job_;
  std::shared_ptr<Built> incoming_;
  enum class Swap { kIdle, kWaitDisarm, kWaitAdopt } swap_ = Swap::kIdle;
  std::uint64_t mark_ = 0;
  bool disarm_sent_ = false;          ///< the swap's disarm is in the command ring
  std::uint64_t disarm_tick_ = 0;     ///< a snapshot newer than this tick counts (set once the ring drained)
  bool disarm_drained_ = false;       ///< the command ring was empty after the disarm was pushed
  bool arm_pending_ = false;          ///< an arm to push (retried while the ring is full)
  bool drain_events_ = true;          ///< nothing else (no sound engine) reads shared_.events
  bool stopped_by_signal_ = false;
  int rescans_ = 0;
  std::string status_;
  // What a swap looked like from the UI thread (summary): swaps completed, the largest device
  // force and whether the device was ever seen Armed between the disarm and the re-arm.
  int swaps_done_ = 0;
  double swap_max_force_n_ = 0.0;
  bool swap_seen_armed_ = false;
};

session::LodControllerOptions Session::controller_options() const {
  session::LodControllerOptions c;
  c.device_half_extent_m = device_ ? device_->info().workspace_half_extent_m : Eigen::Vector3d(0.05, 0.05, 0.05);
  c.surface.texture_gain = texture_enabled_ ? 1.0 : 0.0;
  c.surface.default_mu_s = layer_options_.mu_s;
  return c;
}

void Session::load_input() {
  const fs::path p(o_.input);
  session::SceneSourceOptions so;
  if (session::is_run_config(p)) {
    // Levels are built on demand by the session's pyramid: no levels table in the run report
    // (it would build every level of every scan before the session starts).
    so.lod_report = false;
    so.keep_cloud = true;  // the orientation tool's preview
    so.run_dir = fs::path(o_.out) / "scan-0";
    std::cout << "explore: building the scene of " << p.string() << " into " << so.run_dir.string() << "\n";
  }
  session::OpenedScene opened = session::open_scene_or_config(p, so);
  // The scene's own layers.* and lod.* (as `hapticloud run` built it); --window-cells still wins.
  const int cells = lod_options_.window_cells;
  layer_options_ = opened.scene.layer_options;
  lod_options_ = opened.scene.lod;
  if (o_.window_cells > 0) lod_options_.window_cells = cells;
  if (opened.config) {
    config_ = std::move(opened.config);
    config_->lod.report = false;
    cloud_ = cloud_preview(*opened.cloud, config_->view, 150000);
  }
  built_ = build(std::move(opened.scene), layer_options_, lod_options_, false);
  if (config_) built_->orientation = config_->view.rotation;
  built_->description = config_ ? config_->name : p.filename().string();
}

std::optional<Eigen::Vector3d> Session::anchor() const {
  const haptics::Snapshot& s = viewer_->snapshot();
  if (s.tick == 0) return std::nullopt;
  return s.proxy_m.eigen();
}

/// The level whose whole grid fits in one window (else the coarsest), and the overview level.
int fitting_level(const session::LodController& lod, int cells) {
  for (int l = 0; l < lod.level_count(); ++l) {
    const GridGeometry& g = lod.level_geometry(l);
    if (std::max(g.rows, g.cols) <= cells) return l;
  }
  return lod.level_count() - 1;
}

void Session::show_window() {
  const session::HapticWindow& w = lod_->window();
  auto layers = lod_->pyramid().window(w.level, w.row0, w.col0, w.rows, w.cols);
  auto d = std::make_shared<viewer::DisplayScene>();
  d->window = (!texture_enabled_ && layers->envelope_m.rows() > 0) ? layers->envelope_m : layers->depth_m;
  const int ov = fitting_level(*lod_, 256);
  d->overview = lod_->pyramid().depth_level(ov)->depth_m;
  d->workspace = w.map;
  d->level = w.level;
  d->level_count = lod_->level_count();
  d->cloud_xyz_m = cloud_;
  d->orientation = built_->orientation;
  d->description = built_->description + ": level " + std::to_string(w.level) + " (levels 0.." +
                   std::to_string(lod_->level_count() - 1) + "), window " + std::to_string(w.cols) + "x" +
                   std::to_string(w.rows) + " samples, cell " + fmt(1e3 * w.geometry.cell_size_m, 3) + " mm";
  if (viewer_) viewer_->set_scene(std::move(d));
}

void Session::on_region(const viewer::RegionCommand& c) {
  if (!lod_ || swap_ != Swap::kIdle) return;
  const session::HapticWindow& w = lod_->window();
  switch (c.type) {
    case viewer::RegionCommandType::kFiner: lod_->zoom_in(anchor()); break;
    case viewer::RegionCommandType::kCoarser: lod_->zoom_out(anchor()); break;
    case viewer::RegionCommandType::kSetLevel:
      lod_->set_level(std::clamp(c.level, 0, lod_->level_count() - 1), anchor());
      break;
    case viewer::RegionCommandType::kPan:
      lod_->pan(static_cast<int>(std::lround(c.dx * w.cols)), static_cast<int>(std::lround(c.dy * w.rows)));
      break;
    case viewer::RegionCommandType::kCentreAt: lod_->centre_window(w.level, c.x_m, c.y_m); break;
  }
  show_window();
}

void Session::on_rescan(const Eigen::Quaterniond& q) {
  if (!config_ || job_.valid() || swap_ != Swap::kIdle) return;
  pipeline::RunConfig cfg = *config_;
  cfg.view.rotation = q.normalized();
  cfg.layers.options = layer_options_;  // the friction model and μ_s chosen in the session
  cfg.lod.report = false;               // levels are built on demand by the pyramid
  const fs::path dir = fs::path(o_.out) / ("scan-" + std::to_string(++rescans_));
  const pipeline::SurfaceLayerOptions layers = layer_options_;
  const pipeline::LodOptions lod = lod_options_;
  const std::string name = config_->name;
  status_ = "re-scanning in " + dir.string() + " ...";
  job_ = std::async(std::launch::async, [cfg, dir, layers, lod, name] {
    pipeline::BuiltScene scan = pipeline::build_scene(cfg);
    pipeline::write_run(scan, cfg, dir);
    auto b = build(std::move(scan.scene), layers, lod, false);
    b->orientation = cfg.view.rotation;
    b->description = name + " (re-scanned)";
    b->disarm = true;
    return b;
  });
}

void Session::on_surface_settings(const viewer::SurfaceSettings& s) {
  if (swap_ != Swap::kIdle) return;
  const pipeline::FrictionModel model = pipeline::friction_model_from_string(s.friction_model);
  if (s.texture_enabled != texture_enabled_) {
    // Same pyramid, new surface options: republish the window in place.
    texture_enabled_ = s.texture_enabled;
    const session::HapticWindow w = lod_->window();
    lod_ = std::make_unique<session::LodController>(built_->pyramid, shared_, controller_options());
    lod_->set_window(w.level, w.col0, w.row0);
    show_window();
  }
  if ((model != layer_options_.friction_model || s.mu_s != layer_options_.mu_s) && !job_.valid()) {
    // Friction layers of every level change: rebuild the pyramid on a worker.
    layer_options_.friction_model = model;
    layer_options_.mu_s = s.mu_s;
    Scene base = copy_layers(built_->base);
    const pipeline::SurfaceLayerOptions layers = layer_options_;
    const pipeline::LodOptions lod = lod_options_;
    const Eigen::Quaterniond q = built_->orientation;
    const std::string name = built_->description;
    status_ = "rebuilding the friction layers ...";
    job_ = std::async(std::launch::async, [base = std::move(base), layers, lod, q, name]() mutable {
      auto b = build(std::move(base), layers, lod, true);
      b->orientation = q;
      b->description = name;
      b->disarm = false;
      b->keep_window = true;
      return b;
    });
  }
}

void Session::adopt(const std::shared_ptr<Built>& b) {
  std::optional<session::HapticWindow> old;
  if (lod_ && lod_->has_window()) old = lod_->window();
  built_ = b;
  lod_ = std::make_unique<session::LodController>(built_->pyramid, shared_, controller_options());
  if (b->keep_window && old) {
    lod_->set_window(old->level, old->col0, old->row0);
  } else {
    const GridGeometry& g = lod_->level_geometry(0);
    lod_->centre_window(fitting_level(*lod_, lod_->window_cells()), g.x_of_col(0.5 * (g.cols - 1)),
                        g.y_of_row(0.5 * (g.rows - 1)));
  }
  show_window();
}

void Session::on_frame() {
  if (mouse_ != nullptr) {
    Eigen::Vector3d p;
    if (viewer_->mouse_target(p)) mouse_->set_position(p);
  }
  shared_.collect_retired();
  if (drain_events_) {
    // No sound engine reads the contact events (no audio module, --no-audio): drop them here so
    // the servo never finds the ring full (events_dropped).
    haptics::ContactEvent e;
    while (shared_.events.try_pop(e)) {
    }
  }
  if (arm_pending_ && shared_.commands.try_push(haptics::Command::of(haptics::CommandType::kArm))) {
    arm_pending_ = false;
  }
  if (job_.valid() && job_.wait_for(std::chrono::seconds(0)) == std::future_status::ready) {
    try {
      incoming_ = job_.get();
    } catch (const std::exception& e) {
      status_ = std::string("failed: ") + e.what();
      incoming_.reset();
    }
    if (incoming_) {
      if (incoming_->disarm) {
        arm_pending_ = false;  // a pending arm must not follow the disarm
        disarm_sent_ = shared_.commands.try_push(haptics::Command::of(haptics::CommandType::kDisarm));
        disarm_drained_ = false;
        swap_ = Swap::kWaitDisarm;
        status_ = "swapping the scene (forces off) ...";
      } else {
        adopt(incoming_);
        incoming_.reset();
        status_.clear();
      }
    }
  }
  if (swap_ != Swap::kIdle) {
    const haptics::Snapshot& sn = viewer_->snapshot();
    if (swap_ == Swap::kWaitAdopt) {
      swap_max_force_n_ = std::max(swap_max_force_n_, sn.device_force_n.eigen().norm());
      swap_seen_armed_ = swap_seen_armed_ || sn.device_state == static_cast<std::uint8_t>(haptics::DeviceState::kArmed);
    }
  }
  if (swap_ == Swap::kWaitDisarm && !disarm_sent_) {
    // The command ring was full: retry every frame until the disarm is in.
    disarm_sent_ = shared_.commands.try_push(haptics::Command::of(haptics::CommandType::kDisarm));
  }
  bool disarmed = false;
  if (swap_ == Swap::kWaitDisarm && disarm_sent_) {
    // The disarm is applied once the servo has emptied the ring; a snapshot of a later tick that
    // shows the device Open means zero force (not merely "some command was applied").
    haptics::Snapshot sn;
    shared_.snapshots.read(sn);
    if (!disarm_drained_ && shared_.commands.size_approx() == 0) {
      disarm_drained_ = true;
      disarm_tick_ = sn.tick;
    } else if (disarm_drained_ && sn.tick > disarm_tick_ &&
               sn.device_state == static_cast<std::uint8_t>(haptics::DeviceState::kOpen)) {
      disarmed = true;
    }
  }
  if (swap_ == Swap::kWaitDisarm && disarmed) {
    // The device is Open: zero force. Publish the new scene and wait until the servo has it.
    mark_ = shared_.counters.surfaces_adopted.load();
    adopt(incoming_);
    incoming_.reset();
    swap_ = Swap::kWaitAdopt;
  }
  if (swap_ == Swap::kWaitAdopt && shared_.counters.surfaces_adopted.load() > mark_ && !shared_.surface_pending()) {
    // Re-arm (retried next frames while the ring is full).
    arm_pending_ = !shared_.commands.try_push(haptics::Command::of(haptics::CommandType::kArm));
    swap_ = Swap::kIdle;
    ++swaps_done_;
    status_ = "new scene in place";
  }
}

void Session::run_step(const ScriptStep& st) {
  using viewer::RegionCommandType;
  const std::string& a = st.action;
  if (a == "finer") viewer_->issue({RegionCommandType::kFiner});
  if (a == "coarser") viewer_->issue({RegionCommandType::kCoarser});
  if (a == "level") viewer_->issue({RegionCommandType::kSetLevel, static_cast<int>(script_number(st, 0))});
  if (a == "pan") viewer_->issue({RegionCommandType::kPan, 0, script_number(st, 0), script_number(st, 1)});
  if (a == "centre") {
    viewer::RegionCommand c{RegionCommandType::kCentreAt};
    c.x_m = script_number(st, 0);
    c.y_m = script_number(st, 1);
    viewer_->issue(c);
  }
  if (a == "texture" || a == "mu_s" || a == "model") {
    viewer::SurfaceSettings s;
    s.texture_enabled = texture_enabled_;
    s.mu_s = layer_options_.mu_s;
    s.friction_model = pipeline::to_string(layer_options_.friction_model);
    if (a == "texture") s.texture_enabled = st.args[0] == "on";
    if (a == "mu_s") s.mu_s = script_number(st, 0);
    if (a == "model") s.friction_model = st.args[0];
    on_surface_settings(s);
  }
  if (a == "rescan") {
    on_rescan(pipeline::rotation_from_euler(
        Eigen::Vector3d(script_number(st, 0), script_number(st, 1), script_number(st, 2)), "xyz"));
  }
  if (a == "stereo") viewer_->set_stereo(st.args[0] == "on");
}

void Session::start_device() {
  if (o_.device == "mouse") {
    auto m = std::make_unique<viewer::MouseDevice>(clock_);
    mouse_ = m.get();
    device_ = std::move(m);
  } else if (o_.device == "sim") {
    // Made in run() once the first window's heights are known (the path's heights need them).
  } else if (o_.device == "falcon") {
#ifdef HC_HAVE_FALCON
    // The run config's falcon: section when there is one (firmware, which device, force cap).
    const pipeline::FalconSpec spec = config_ ? config_->falcon : pipeline::FalconSpec{};
    falcon::FalconConfig fc;
    fc.firmware_path = spec.firmware.string();
    fc.max_force_n = spec.max_force_n;
    fc.max_missed_ticks = spec.max_missed_ticks;
    device_ = std::make_unique<falcon::FalconDevice>(clock_, std::make_unique<falcon::UsbFalconProvider>(spec.index), fc);
#else
    throw ConfigError("explore: --device falcon: this build has no Falcon driver (hc::falcon was not built)");
#endif
  } else {
    throw ConfigError("explore: --device '" + o_.device + "' is unknown (expected falcon, mouse or sim)");
  }
}

void Session::write_summary(const haptics::ServoStats& stats, const haptics::RealtimeReport& rt) const {
  const viewer::FrameStats& f = viewer_->frame_stats();
  const auto& c = shared_.counters;
  std::cout << "explore: " << stats.ticks << " servo ticks, " << stats.overruns << " overruns; compute p50 "
            << stats.compute.percentile_ns(0.5) << " ns, p99.9 " << stats.compute.percentile_ns(0.999) << " ns, max "
            << stats.compute.max_ns() << " ns; lateness p99.9 " << stats.lateness.percentile_ns(0.999) << " ns, max "
            << stats.lateness.max_ns() << " ns\n"
            << "explore: " << f.frames << " frames, mean " << fmt(1e3 * f.mean_frame_s) << " ms, max "
            << fmt(1e3 * f.max_frame_s) << " ms (excluding the frame-rate cap)\n";
  if (o_.summary.empty()) return;
  std::ofstream js(o_.summary);
  if (!js) throw InputError("explore: cannot write the summary '" + o_.summary + "'");
  // Built with nlohmann::json: the status text (an exception's message, a path) is escaped.
  nlohmann::ordered_json j;
  j["device"] = o_.device;
  j["ticks"] = stats.ticks;
  j["overruns"] = stats.overruns;
  j["compute_ns"] = {{"p50", stats.compute.percentile_ns(0.5)},
                     {"p99", stats.compute.percentile_ns(0.99)},
                     {"p99_9", stats.compute.percentile_ns(0.999)},
                     {"max", stats.compute.max_ns()}};
  j["lateness_ns"] = {{"p50", stats.lateness.percentile_ns(0.5)},
                      {"p99_9", stats.lateness.percentile_ns(0.999)},
                      {"max", stats.lateness.max_ns()}};
  j["device_errors"] = c.device_errors.load();
  j["commands_applied"] = c.commands_applied.load();
  j["commands_rejected"] = c.commands_rejected.load();
  j["surfaces_adopted"] = c.surfaces_adopted.load();
  j["events_dropped"] = c.events_dropped.load();
  j["frames"] = f.frames;
  j["frame_mean_s"] = f.mean_frame_s;
  j["frame_max_s"] = f.max_frame_s;
  j["fifo_granted"] = rt.fifo_granted;
  j["memory_locked"] = rt.memory_locked;
  j["mesh_quads"] = viewer_->mesh_quads();
  j["level"] = lod_ && lod_->has_window() ? lod_->window().level : -1;
  j["level_count"] = lod_ ? lod_->level_count() : 0;
  if (lod_ && lod_->has_window()) {
    const session::HapticWindow& w = lod_->window();
    j["window"] = {{"col0", w.col0}, {"row0", w.row0}, {"cols", w.cols}, {"rows", w.rows}};
  }
  j["texture"] = texture_enabled_;
  j["mu_s"] = layer_options_.mu_s;
  j["friction_model"] = pipeline::to_string(layer_options_.friction_model);
  j["rescans"] = rescans_;
  j["swaps"] = swaps_done_;
  j["swap_max_device_force_n"] = swap_max_force_n_;
  j["swap_seen_armed"] = swap_seen_armed_;
  j["stopped_by_signal"] = stopped_by_signal_;
  j["status"] = status_;
  js << j.dump(2) << "\n";
}

void Session::run() {
  if (o_.frames < 0) throw ConfigError("explore: --frames " + std::to_string(o_.frames) + " must be ≥ 0");
  if (!(o_.seconds >= 0.0) || o_.seconds > 86400.0) {
    throw ConfigError("explore: --seconds " + fmt(o_.seconds) + " is out of range (expected [0, 86400])");
  }
  if (!o_.screenshot.empty() && o_.frames == 0 && o_.seconds == 0.0) o_.frames = 1;
  const std::vector<ScriptStep> script = parse_script(o_.script);
  std::size_t next_step = 0;
  if (o_.device != "falcon" && o_.device != "mouse" && o_.device != "sim") {
    throw ConfigError("explore: --device '" + o_.device + "' is unknown (expected falcon, mouse or sim)");
  }
  if (o_.window_cells != 0 && (o_.window_cells < 2 || o_.window_cells > 4096)) {
    throw ConfigError("explore: --window-cells " + std::to_string(o_.window_cells) +
                      ": expected an integer in [2, 4096] (or 0: the scene's lod.window_cells)");
  }
  if (o_.window_cells > 0) lod_options_.window_cells = o_.window_cells;
  // Before anything is built: a Ctrl-C from here on ends the session between frames, and a
  // Falcon sends zero force at once (one process-wide flag, hc/haptics/stop_signal.hpp).
  haptics::clear_stop_request();
  haptics::install_stop_signal_handlers();
  std::error_code ec;
  fs::create_directories(o_.out, ec);
  if (ec) throw InputError("explore: cannot create the output folder '" + o_.out + "': " + ec.message());
  load_input();
  start_device();

  // First window, then the device and the servo loop.
  lod_ = std::make_unique<session::LodController>(built_->pyramid, shared_, controller_options());
  {
    const GridGeometry& g = lod_->level_geometry(0);
    lod_->centre_window(fitting_level(*lod_, lod_->window_cells()), g.x_of_col(0.5 * (g.cols - 1)),
                        g.y_of_row(0.5 * (g.rows - 1)));
  }
  const session::HapticWindow& w0 = lod_->window();
  if (o_.device == "sim") {
    const haptics::DeviceInfo info = haptics::SimulatedDevice::default_info();
    const double mid = 0.5 * (w0.min_height_m + w0.max_height_m);
    haptics::ScriptedPath path;
    path.kind = haptics::path_kind_from_string(o_.path);
    path.half_x_m = 0.6 * info.workspace_half_extent_m.x();
    path.half_y_m = 0.6 * info.workspace_half_extent_m.y();
    path.raster_spacing_m = 0.1 * info.workspace_half_extent_m.y();
    path.z_above_m = (w0.max_height_m - mid) / w0.map.scale + 0.01;
    path.z_contact_m = -0.01;
    path.speed_m_per_s = o_.speed_m_per_s;
    device_ = std::make_unique<haptics::SimulatedDevice>(clock_, path, haptics::VirtualHand{}, info);
  }
  device_->open();
  haptics::ServoConfig cfg;
  cfg.realtime = haptics::realtime_mode_from_string(o_.realtime);
  cfg.workspace = w0.map;
  cfg.proxy.stiffness_n_per_m = o_.stiffness_n_per_m;
  cfg.proxy.rho = o_.rho;
  cfg.proxy.max_force_n = std::min(cfg.proxy.max_force_n, device_->info().max_force_n);
  loop_ = std::make_unique<haptics::ServoLoop>(*device_, shared_, clock_, cfg);
  const haptics::RealtimeReport rt = loop_->start();
  std::cout << "explore: device " << device_->info().name << "; servo " << cfg.rate_hz << " Hz, SCHED_FIFO "
            << (rt.fifo_granted ? "granted" : "not granted") << "\n";
  if (!rt.detail.empty()) std::cout << "explore: " << rt.detail << "\n";
  // The UI thread and everything it starts (Mesa's threads, workers) yield to the servo thread.
  setpriority(PRIO_PROCESS, static_cast<id_t>(gettid()), 10);

#ifdef HC_HAVE_AUDIO
  std::unique_ptr<audio::AudioEngine> sound;
  if (!o_.no_audio) {
    const auto& base = built_->base;
    const HeightField* texture = base.layers.texture.rows() > 0 ? &base.layers.texture : nullptr;
    const GridGeometry grid = base.depth().geometry();
    // The run config's audio: section (regions, materials); a scene folder gets the sliding
    // sound only.
    const audio::AudioConfig ac = config_ ? audio_config_from(config_->audio) : audio::AudioConfig{};
    sound = std::make_unique<audio::AudioEngine>(audio::build_audio_scene(ac, {&grid, texture}));
    const audio::EngineReport ar = sound->start(shared_);
    drain_events_ = false;  // the engine reads shared_.events
    std::cout << "explore: audio " << (ar.device_open ? ar.device : std::string("off")) << ": " << ar.detail << "\n";
  }
#endif

  viewer::ViewerOptions vo;
  vo.width_px = o_.width;
  vo.height_px = o_.height;
  vo.visible = !o_.hidden;
  vo.stereo = o_.stereo;
  vo.mouse_drives_hip = mouse_ != nullptr;
  vo.max_force_n = cfg.proxy.max_force_n;
  vo.max_stiffness_n_per_m = device_->info().max_stable_stiffness_n_per_m;
  vo.stiffness_n_per_m = cfg.proxy.stiffness_n_per_m;
  vo.rho = cfg.proxy.rho;
  vo.surface.mu_s = layer_options_.mu_s;
  vo.surface.friction_model = pipeline::to_string(layer_options_.friction_model);
  viewer::ViewerCallbacks cb;
  cb.on_region = [this](const viewer::RegionCommand& c) { on_region(c); };
  if (config_) cb.on_rescan = [this](const Eigen::Quaterniond& q) { on_rescan(q); };
  cb.on_surface_settings = [this](const viewer::SurfaceSettings& s) { on_surface_settings(s); };
#ifdef HC_HAVE_AUDIO
  if (sound) cb.on_audio_volume = [&sound](double v) { sound->set_volume(v); };
#endif
  cb.on_frame = [this] { on_frame(); };
  cb.status = [this] { return status_; };
  try {
    viewer_ = std::make_unique<viewer::Viewer>(shared_, vo, cb);
  } catch (...) {
    loop_->stop();
    device_->close();
    throw;
  }
  show_window();
  arm_pending_ = !shared_.commands.try_push(haptics::Command::of(haptics::CommandType::kArm));

  const auto t0 = std::chrono::steady_clock::now();
  for (int frame = 1;; ++frame) {
    if (haptics::stop_requested()) {
      // Ctrl-C / SIGTERM: close the viewer and end cleanly (a re-scan under way is waited for
      // below; the servo stops and the device closes with zero force).
      stopped_by_signal_ = true;
      std::cout << "explore: stop requested (signal); ending the session\n";
      break;
    }
    // A session never ends half-way through a re-scan or a swap.
    const bool busy = job_.valid() || swap_ != Swap::kIdle || next_step < script.size();
    const double elapsed_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const bool last = !busy && ((o_.frames > 0 && frame >= o_.frames) || (o_.seconds > 0.0 && elapsed_s >= o_.seconds));
    if (last && !o_.screenshot.empty()) {
      viewer::write_png(viewer_->capture(), o_.screenshot);
      std::cout << "explore: wrote " << o_.screenshot << "\n";
      break;
    }
    if (!viewer_->frame() || last) break;
    // Scripted steps go through the same entry points as keys, the panel and the orientation
    // tool; a step waits while a re-scan or rebuild is under way.
    while (next_step < script.size() && script[next_step].frame <= frame && !job_.valid() && swap_ == Swap::kIdle) {
      run_step(script[next_step++]);
    }
  }
  if (job_.valid()) job_.wait();
  loop_->stop();
#ifdef HC_HAVE_AUDIO
  if (sound) sound->stop();
#endif
  const haptics::ServoStats stats = loop_->stats();
  device_->close();
  write_summary(stats, rt);
  viewer_.reset();
}

#endif  // HC_HAVE_VIEWER

void run_explore(const ExploreOptions& o) {
#ifdef HC_HAVE_VIEWER
  Session session(o);
  session.run();
#else
  (void)o;
  throw ConfigError("explore: this build has no viewer (hc::viewer was not built)");
#endif
}

}  // namespace

void add_explore_command(CLI::App& app) {
  auto o = std::make_shared<ExploreOptions>();
  CLI::App* cmd = app.add_subcommand(
      "explore",
      "Interactive session: see, feel and hear a scene (viewer + servo loop + device). Press H in the window for the controls.");
  cmd->add_option("CONFIG_OR_SCENE", o->input, "Run config (.yaml; its scene is built first, re-scans possible) or a scene folder")
      ->required();
  cmd->add_option("--device", o->device, "falcon | mouse | sim (a scripted path)")->capture_default_str();
  cmd->add_option("--path", o->path, "Scripted path of --device sim: raster | circle | line | press-slide | hold")
      ->capture_default_str();
  cmd->add_option("--speed", o->speed_m_per_s, "Speed of the scripted path [m/s] (device frame)")->capture_default_str();
  cmd->add_option("--screenshot", o->screenshot, "Render --frames N frames (1 if not given), save the last as PNG and exit");
  cmd->add_option("--frames", o->frames, "Exit after this many frames (0 = run until the window closes)")->capture_default_str();
  cmd->add_option("--seconds", o->seconds, "Exit after this many seconds (0 = no limit)")->capture_default_str();
  cmd->add_option("--summary", o->summary, "Write servo and frame statistics of the session as JSON to this file");
  cmd->add_option("--out", o->out, "Folder for the scenes built from a config (scan-0, scan-1 after re-scans, ...)")
      ->capture_default_str();
  cmd->add_option("--width", o->width, "Window width [px]")->capture_default_str();
  cmd->add_option("--height", o->height, "Window height [px]")->capture_default_str();
  cmd->add_option("--window-cells", o->window_cells, "Haptic window side [samples] (default: the config's lod.window_cells, else 200)");
  cmd->add_option("--stiffness", o->stiffness_n_per_m, "Stiffness k [N/m] (device frame)")->capture_default_str();
  cmd->add_option("--rho", o->rho, "Proxy step factor rho of Eq. 4-5, (0, 1]")->capture_default_str();
  cmd->add_option("--realtime", o->realtime, "Servo thread scheduling: off | warn | enforce (SCHED_FIFO + mlockall)")
      ->capture_default_str();
  cmd->add_option("--script", o->script,
                  "Scripted actions for tests and demos, \"FRAME ACTION ARGS; ...\": finer, coarser, level N, pan DX DY "
                  "(window widths), centre X_M Y_M, texture on|off, mu_s V, model paper|curvature, rescan AX AY AZ "
                  "(deg, R = Rx*Ry*Rz), stereo on|off; each goes through the same path as the keys and the panel");
  cmd->add_flag("--stereo", o->stereo, "Start in red/cyan anaglyph stereo");
  cmd->add_flag("--hidden", o->hidden, "Do not show the window (with --screenshot or --seconds)");
  cmd->add_flag("--no-audio", o->no_audio, "No contact sounds");
#ifdef HC_HAVE_VIEWER
  std::string controls = "Controls in the window (H shows them):\n";
  for (const std::string& line : viewer::controls_help()) controls += "  " + line + "\n";
  cmd->footer(controls);
#endif
  cmd->callback([o] { run_explore(*o); });
}

}  // namespace hc::app
