/// `hapticloud explore`, the session's set-up and frame loop (explore_session.hpp).

#include "explore_session.hpp"

#include "hc/common/error.hpp"
#include "hc/haptics/recording.hpp"
#include "hc/haptics/simulated_device.hpp"
#include "hc/haptics/stop_signal.hpp"
#include "hc/haptics/udp_device.hpp"
#include "hc/session/scene_source.hpp"

#ifdef HC_HAVE_FALCON
#include "hc/falcon/falcon_device.hpp"
#include "hc/falcon/usb_transport.hpp"
#endif
#ifdef HC_HAVE_AUDIO
#include "hc/audio/mixer.hpp"
#endif

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <iostream>

namespace hc::app {

#ifdef HC_HAVE_VIEWER

namespace fs = std::filesystem;

session::LodControllerOptions Session::controller_options() const {
  session::LodControllerOptions c;
  c.device_half_extent_m = device_ ? device_->info().workspace_half_extent_m : Eigen::Vector3d(0.05, 0.05, 0.05);
  c.surface.texture_gain = texture_enabled_ ? 1.0 : 0.0;
  c.surface.default_mu_s = layer_options_.mu_s;
  return c;
}

std::vector<ScriptStep> Session::check_options() {
  if (o_.frames < 0) throw ConfigError("explore: --frames " + std::to_string(o_.frames) + " must be ≥ 0");
  if (!(o_.seconds >= 0.0) || o_.seconds > 86400.0) {
    throw ConfigError("explore: --seconds " + fmt(o_.seconds) + " is out of range (expected [0, 86400])");
  }
  if (!o_.screenshot.empty() && o_.frames == 0 && o_.seconds == 0.0) o_.frames = 1;
  std::vector<ScriptStep> script = parse_script(script_text(o_.script));
  for (const ScriptStep& st : script) check_script_numbers(st);
  const bool replay = o_.device.rfind("replay:", 0) == 0 && o_.device.size() > 7;
  const bool udp = o_.device.rfind("udp:", 0) == 0;
  if (udp) (void)haptics::parse_udp_address(o_.device.substr(4));
  if (o_.device != "falcon" && o_.device != "mouse" && o_.device != "sim" && !replay && !udp) {
    throw ConfigError("explore: --device '" + o_.device + "' is unknown (expected falcon, mouse, sim, replay:FILE or udp:HOST:PORT)");
  }
  if (!o_.record.empty() && std::filesystem::exists(std::filesystem::symlink_status(o_.record))) {
    throw ConfigError("explore: --record " + o_.record + " exists already (not overwritten; choose another file)");
  }
  (void)viewer::display_choice_from_string(o_.display, "explore: --display");
  for (const ScriptStep& st : script) {
    if (st.action == "display") (void)viewer::display_choice_from_string(st.args[0], "explore: --script display");
  }
  if (o_.window_cells != 0 && (o_.window_cells < 2 || o_.window_cells > 4096)) {
    throw ConfigError("explore: --window-cells " + std::to_string(o_.window_cells) +
                      ": expected an integer in [2, 4096] (or 0: the scene's lod.window_cells)");
  }
  if (o_.window_cells > 0) lod_options_.window_cells = o_.window_cells;
  return script;
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
  // A tiled scene's stored levels are read from disk, window by window (issue 14).
  so.open_stored_levels = true;
  so.stored_window_cells = o_.window_cells;
  session::OpenedScene opened = session::open_scene_or_config(p, so);
  for (const std::string& note : opened.notes) std::cout << "explore: " << note << "\n";
  // The scene's own layers.* and lod.* (as `hapticloud run` built it); --window-cells still wins.
  const int cells = lod_options_.window_cells;
  layer_options_ = opened.scene.layer_options;
  lod_options_ = opened.scene.lod;
  if (o_.window_cells > 0) lod_options_.window_cells = cells;
  if (opened.config) {
    config_ = std::move(opened.config);
    config_->lod.report = false;
    if (opened.cloud) cloud_ = session::cloud_preview(*opened.cloud, config_->view, 150000);  // none from a tiled run
  }
  if (opened.stored_levels) {
    // Nothing is loaded whole: the base keeps the geometry and metadata, the pyramid reads tiles.
    built_ = std::make_shared<session::ExploreScene>();
    built_->base = std::move(opened.scene);
    built_->pyramid = std::move(opened.stored_levels);
    std::cout << "explore: tiled scene, " << built_->pyramid->level_count() << " stored levels read window by window\n";
  } else {
    built_ = session::build_explore_scene(std::move(opened.scene), layer_options_, lod_options_, false);
  }
  if (config_) built_->orientation = config_->view.rotation;
  built_->description = config_ ? config_->name : p.filename().string();
}

void Session::start_device() {
  if (o_.device == "mouse") {
    auto m = std::make_unique<viewer::MouseDevice>(clock_);
    mouse_ = m.get();
    device_ = std::move(m);
  } else if (o_.device == "sim") {
    // Made in start_servo() once the first window's heights are known (the path's heights need them).
  } else if (o_.device.rfind("replay:", 0) == 0) {
    haptics::Recording rec = haptics::read_recording_file(o_.device.substr(7));
    take_replay_events(rec);
    replay_rate_hz_ = rec.servo_rate_hz;
    auto r = std::make_unique<haptics::TickReplayDevice>(clock_, std::move(rec), haptics::SimulatedDevice::default_info());
    replay_ = r.get();
    device_ = std::move(r);
  } else if (o_.device.rfind("udp:", 0) == 0) {
    // A rig outside the process (docs/udp_bridge.md): Falcon-like capabilities unless its
    // client scales to them.
    haptics::UdpDeviceOptions uo = haptics::parse_udp_address(o_.device.substr(4));
    uo.info = haptics::SimulatedDevice::default_info();
    uo.info.name = "udp " + o_.device.substr(4);
    uo.timeout_s = o_.udp_timeout_s;
    auto u = std::make_unique<haptics::UdpDevice>(clock_, uo);
    udp_ = u.get();
    device_ = std::move(u);
  } else if (o_.device == "falcon") {
#ifdef HC_HAVE_FALCON
    // The run config's falcon: section when there is one (firmware, which device, force cap).
    const falcon::FalconConfig fc = config_ ? config_->falcon : falcon::FalconConfig{};
    device_ = std::make_unique<falcon::FalconDevice>(clock_, std::make_unique<falcon::UsbFalconProvider>(fc.device_index), fc);
#else
    throw ConfigError("explore: --device falcon: this build has no Falcon driver (hc::falcon was not built)");
#endif
  } else {
    throw ConfigError("explore: --device '" + o_.device + "' is unknown (expected falcon, mouse, sim, replay:FILE or udp:HOST:PORT)");
  }
}

void Session::take_replay_events(const haptics::Recording& rec) {
  // The recorded session actions, played when the servo reaches their tick (run()).
  for (const haptics::RecordedEvent& e : rec.events) {
    // The panel's servo settings made during the recording (arm, disarm and resets are the
    // replaying session's own).
    using haptics::CommandType;
    const CommandType t = e.command.type;
    if (e.kind == haptics::RecordedEvent::Kind::kCommand &&
        (t == CommandType::kSetStiffness || t == CommandType::kSetDamping || t == CommandType::kSetMaxForce ||
         t == CommandType::kSetRho || t == CommandType::kSetFrictionEnabled)) {
      replay_commands_.emplace_back(e.tick, e.command);
    }
    if (e.kind != haptics::RecordedEvent::Kind::kSession) continue;
    const std::string where = "explore: " + o_.device.substr(7) + ": @session at tick " + std::to_string(e.tick) + " '" +
                              e.action + "'";
    std::vector<ScriptStep> one;
    try {
      one = parse_script("1 " + e.action);
      if (one.size() == 1) check_script_numbers(one.front());
    } catch (const ConfigError& err) {
      throw InputError(where + " is not a session action (" + err.what() + ")");
    }
    if (one.size() != 1) throw InputError(where + ": expected one action (" + kSessionActions + ")");
    replay_steps_.emplace_back(e.tick, std::move(one.front()));
  }
  // In tick order (the file lists them in the order they were drained, nearly sorted).
  const auto by_tick = [](const auto& a, const auto& b) { return a.first < b.first; };
  std::stable_sort(replay_steps_.begin(), replay_steps_.end(), by_tick);
  std::stable_sort(replay_commands_.begin(), replay_commands_.end(), by_tick);
}

void Session::start_servo() {
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
  haptics::ServoConfig& cfg = servo_config_;
  if (!o_.record.empty()) {
    recorder_ = std::make_unique<haptics::RecordingDevice>(*device_, o_.record);
    recorder_->watch(shared_, cfg.rate_hz);  // commands, surface switches and session actions too
  }
  active_device().open();
  if (udp_ != nullptr) {
    const haptics::UdpDeviceOptions uo = haptics::parse_udp_address(o_.device.substr(4));
    std::cout << "explore: waiting for poses on udp " << uo.host << ":" << udp_->bound_port() << " (watchdog "
              << o_.udp_timeout_s << " s; docs/udp_bridge.md)\n";
  }
  if (replay_ != nullptr && replay_rate_hz_ > 0.0 && replay_rate_hz_ != cfg.rate_hz) {
    std::cout << "explore: the recording's servo ran at " << replay_rate_hz_ << " Hz, this one at " << cfg.rate_hz
              << " Hz (forces follow the rate during ramps and blends)\n";
  }
  cfg.realtime = haptics::realtime_mode_from_string(o_.realtime);
  cfg.workspace = w0.map;
  cfg.proxy.stiffness_n_per_m = o_.stiffness_n_per_m;
  cfg.proxy.rho = o_.rho;
  cfg.proxy.max_force_n = std::min(cfg.proxy.max_force_n, device_->info().max_force_n);
  loop_ = std::make_unique<haptics::ServoLoop>(active_device(), shared_, clock_, cfg);
  // The first window, at tick 0 (before the servo runs), so a replay starts there and a replay
  // on another scene or --window-cells shows.
  note_window();
  realtime_ = loop_->start();
  std::cout << "explore: device " << device_->info().name << "; servo " << cfg.rate_hz << " Hz, SCHED_FIFO "
            << (realtime_.fifo_granted ? "granted" : "not granted") << ", CPU wake-up latency "
            << (realtime_.cpu_latency_pinned ? "pinned to 0" : "not pinned") << "\n";
  if (!realtime_.detail.empty()) std::cout << "explore: " << realtime_.detail << "\n";
  // The UI thread and everything it starts (Mesa's threads, workers) yield to the servo thread.
  setpriority(PRIO_PROCESS, static_cast<id_t>(gettid()), 10);
}

void Session::make_viewer() {
#ifdef HC_HAVE_AUDIO
  const bool has_regions = config_ && config_->audio && !config_->audio->regions.empty();
  if (!o_.no_audio || has_regions) {
    const auto& base = built_->base;
    const HeightField* texture = base.layers.texture.rows() > 0 ? &base.layers.texture : nullptr;
    const GridGeometry grid = base.geometry;
    // The run config's audio: section (regions, materials); a scene folder gets the sliding
    // sound only.
    const audio::AudioConfig ac = config_ && config_->audio ? *config_->audio : audio::AudioConfig{};
    std::shared_ptr<const audio::AudioScene> scene;
    if (o_.no_audio) {
      // Only the regions of the overlay are wanted: a clip that cannot be read is no error here.
      try {
        scene = audio::build_audio_scene(ac, {&grid, texture});
      } catch (const std::exception& e) {
        std::cout << "explore: no audio-region overlay (" << e.what() << ")\n";
      }
    } else {
      scene = audio::build_audio_scene(ac, {&grid, texture});
    }
    // The regions for the viewer's overlay (key A), on the grid they were rasterised on.
    if (has_regions && scene) {
      region_layer_ = std::make_shared<const HeightField>(scene->regions.to_layer(grid));
      for (const audio::RegionConfig& r : ac.regions) region_names_.push_back(r.name);
    }
    if (!o_.no_audio) {
      sound_ = std::make_unique<audio::AudioEngine>(std::move(scene));
      const audio::EngineReport ar = sound_->start(shared_);
      drain_events_ = false;  // the engine reads shared_.events
      std::cout << "explore: audio " << (ar.device_open ? ar.device : std::string("off")) << ": " << ar.detail << "\n";
    }
  }
#endif
  viewer::ViewerOptions vo;
  vo.width_px = o_.width;
  vo.height_px = o_.height;
  vo.visible = !o_.hidden;
  vo.stereo = o_.stereo;
  vo.show_regions = o_.show_regions;
  vo.display = viewer::display_choice_from_string(o_.display, "explore: --display");
  vo.mouse_drives_hip = mouse_ != nullptr;
  vo.max_force_n = servo_config_.proxy.max_force_n;
  vo.max_stiffness_n_per_m = device_->info().max_stable_stiffness_n_per_m;
  vo.stiffness_n_per_m = servo_config_.proxy.stiffness_n_per_m;
  vo.rho = servo_config_.proxy.rho;
  vo.surface.mu_s = layer_options_.mu_s;
  vo.surface.friction_model = pipeline::to_string(layer_options_.friction_model);
  viewer::ViewerCallbacks cb;
  cb.on_region = [this](const viewer::RegionCommand& c) { on_region(c); };
  if (config_) cb.on_rescan = [this](const Eigen::Quaterniond& q) { on_rescan(q); };
  cb.on_surface_settings = [this](const viewer::SurfaceSettings& s) { on_surface_settings(s); };
#ifdef HC_HAVE_AUDIO
  if (sound_) cb.on_audio_volume = [this](double v) { sound_->set_volume(v); };
#endif
  cb.on_frame = [this] { on_frame(); };
  cb.status = [this] { return status_; };
  try {
    viewer_ = std::make_unique<viewer::Viewer>(shared_, vo, cb);
  } catch (...) {
    loop_->stop();
    active_device().close();
    throw;
  }
}

void Session::run() {
  const std::vector<ScriptStep> script = check_options();
  script_steps_ = script.size();
  std::size_t next_step = 0;
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
  centre_first_window();
  if (!replay_steps_.empty() && replay_steps_.front().first == 0 && replay_steps_.front().second.action == "window") {
    // A replay starts in the recording's first window (its tick-0 note), not a centred one.
    try {
      set_window_step(replay_steps_.front().second);
    } catch (const ConfigError& e) {
      throw InputError("explore: " + o_.device.substr(7) + ": the recording's first window does not fit this scene (" +
                       e.what() + "; another scene?)");
    }
    ++next_replay_step_;
  }
  start_servo();
  make_viewer();
  show_window();
  swap_.arm();  // retried by swap_.step() each frame while the command ring is full

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
    const bool pending = busy() || next_step < script.size() ||
                         next_replay_step_ < replay_steps_.size() || next_replay_command_ < replay_commands_.size() ||
                         // a replay lasts at least as long as its recording
                         (replay_ != nullptr && shared_.counters.ticks.load(std::memory_order_relaxed) < replay_->sample_count());
    const double elapsed_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const bool last =
        !pending && ((o_.frames > 0 && frame >= o_.frames) || (o_.seconds > 0.0 && elapsed_s >= o_.seconds));
    if (last && !o_.screenshot.empty()) {
      viewer::write_png(viewer_->capture(), o_.screenshot);
      std::cout << "explore: wrote " << o_.screenshot << "\n";
      break;
    }
    if (!viewer_->frame() || last) break;
    // Scripted steps go through the same entry points as keys, the panel and the orientation
    // tool; a step waits while a re-scan or rebuild is under way.
    const auto due = [&](const ScriptStep& st) { return st.at_s >= 0.0 ? st.at_s <= elapsed_s : st.frame <= frame; };
    while (next_step < script.size() && due(script[next_step]) && !busy()) {
      run_step(script[next_step++]);
      ++script_steps_run_;
    }
    // A replay's recorded actions and servo settings, once the servo has reached their tick
    // (a command waits while the command ring is full).
    const std::uint64_t servo_tick = shared_.counters.ticks.load(std::memory_order_relaxed);
    while (next_replay_command_ < replay_commands_.size() && replay_commands_[next_replay_command_].first <= servo_tick &&
           shared_.commands.try_push(replay_commands_[next_replay_command_].second)) {
      ++next_replay_command_;
    }
    while (next_replay_step_ < replay_steps_.size() && !busy() &&
           replay_steps_[next_replay_step_].first <= shared_.counters.ticks.load(std::memory_order_relaxed)) {
      run_step(replay_steps_[next_replay_step_++].second);
    }
  }
  if (job_.valid()) job_.wait();
  loop_->stop();
#ifdef HC_HAVE_AUDIO
  if (sound_) sound_->stop();
#endif
  const haptics::ServoStats stats = loop_->stats();
  if (recorder_) recorder_->keep_on_close();  // a normal end: the recording is kept
  active_device().close();
  write_summary(stats);
  viewer_.reset();
  if (udp_ != nullptr) {
    std::cout << "explore: udp: " << udp_->poses_dropped() << " poses dropped (stale or malformed), " << udp_->sends_failed()
              << " force datagrams not sent\n";
  }
  if (recorder_) {
    if (!recorder_->error().empty()) throw InputError("explore: " + recorder_->error());
    std::cout << "explore: recorded " << recorder_->written() << " servo ticks to " << o_.record << "\n";
  }
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

}  // namespace hc::app
