/// `hapticloud explore`, what happens during frames (explore_session.hpp): level and region
/// commands, re-scans and friction rebuilds on workers, the swap of their scenes (through
/// hc::session::SceneSwap) and the --script steps.

#include "explore_session.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/transform.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <numbers>

namespace hc::app {

#ifdef HC_HAVE_VIEWER

namespace fs = std::filesystem;

int fitting_level(const session::LodController& lod, int cells) {
  for (int l = 0; l < lod.level_count(); ++l) {
    const GridGeometry& g = lod.level_geometry(l);
    if (std::max(g.rows, g.cols) <= cells) return l;
  }
  return lod.level_count() - 1;
}

std::optional<Eigen::Vector3d> Session::anchor() const {
  const haptics::Snapshot& s = viewer_->snapshot();
  if (s.tick == 0) return std::nullopt;
  return s.proxy_m.eigen();
}

void Session::centre_first_window() {
  const GridGeometry& g = lod_->level_geometry(0);
  lod_->centre_window(fitting_level(*lod_, lod_->window_cells()), g.x_of_col(0.5 * (g.cols - 1)),
                      g.y_of_row(0.5 * (g.rows - 1)));
}

void Session::show_window() {
  const session::HapticWindow& w = lod_->window();
  auto layers = lod_->pyramid().window(w.level, w.row0, w.col0, w.rows, w.cols);
  auto d = std::make_shared<viewer::DisplayScene>();
  d->window = (!texture_enabled_ && layers->envelope_m.rows() > 0) ? layers->envelope_m : layers->depth_m;
  d->window_layers.colour_rgb8 = layers->colour_rgb8;
  d->window_layers.texture_m = layers->texture_m;
  d->window_layers.mu_d = layers->mu_d;
  d->window_layers.cell_error_m = layers->cell_error_m;
  // The overview level with its layers (a coarse level: ≤ 256 samples a side, cheap to build).
  const int ov = fitting_level(*lod_, 256);
  const std::shared_ptr<const pipeline::LodLevel> overview = lod_->pyramid().level(ov);
  d->overview = overview->depth_m;
  d->overview_layers.colour_rgb8.assign(overview->colour_rgb8.begin(), overview->colour_rgb8.end());
  d->overview_layers.texture_m = overview->texture_m;
  d->overview_layers.mu_d = overview->mu_d;
  d->overview_layers.cell_error_m = overview->cell_error_m;
  d->workspace = w.map;
  d->level = w.level;
  d->level_count = lod_->level_count();
  d->cloud_xyz_m = cloud_;
  d->region_id = region_layer_;
  d->region_names = region_names_;
  d->orientation = built_->orientation;
  d->description = built_->description + ": level " + std::to_string(w.level) + " (levels 0.." +
                   std::to_string(lod_->level_count() - 1) + "), window " + std::to_string(w.cols) + "x" +
                   std::to_string(w.rows) + " samples, cell " + fmt(1e3 * w.geometry.cell_size_m, 3) + " mm";
  if (viewer_) viewer_->set_scene(std::move(d));
}

void Session::on_region(const viewer::RegionCommand& c) {
  if (!lod_ || swap_.busy()) return;
  const session::HapticWindow& w = lod_->window();
  try {
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
  } catch (const InputError& e) {
    // A window with no data (a scan's gap, the empty part of a large tiled scene) cannot be
    // rendered: the controller published nothing, so the session keeps its window and says why.
    status_ = std::string("kept the window: ") + e.what();
    std::cout << "explore: " << status_ << "\n";
    return;
  }
  note_window();
  show_window();
}

void Session::note(const std::string& action) {
  if (recorder_) recorder_->note(action);
}

void Session::set_window_step(const ScriptStep& st) {
  const int level = script_int(st, 0);
  if (level < 0 || level >= lod_->level_count()) {
    throw ConfigError("explore: step window: level " + st.args[0] + " is out of range (expected 0.." +
                      std::to_string(lod_->level_count() - 1) + ")");
  }
  lod_->set_window(level, script_int(st, 1), script_int(st, 2));
}

void Session::note_window() {
  // The window itself, not the command: finer and coarser depend on the proxy's position.
  const session::HapticWindow& w = lod_->window();
  note("window " + std::to_string(w.level) + " " + std::to_string(w.col0) + " " + std::to_string(w.row0));
}

void Session::on_rescan(const Eigen::Quaterniond& q) {
  if (!config_ || busy()) return;
  {
    // R = Rx·Ry·Rz, as the script's rescan AX AY AZ [deg].
    const Eigen::Vector3d a = q.normalized().toRotationMatrix().eulerAngles(0, 1, 2) * (180.0 / std::numbers::pi);
    char buf[128];
    std::snprintf(buf, sizeof buf, "rescan %.17g %.17g %.17g", a.x(), a.y(), a.z());
    note(buf);
  }
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
    auto b = session::build_explore_scene(std::move(scan.scene), layers, lod, false);
    b->orientation = cfg.view.rotation;
    b->description = name + " (re-scanned)";
    b->disarm = true;
    return b;
  });
}

void Session::on_surface_settings(const viewer::SurfaceSettings& s) {
  if (swap_.busy()) return;
  const pipeline::FrictionModel model = pipeline::friction_model_from_string(s.friction_model);
  if (s.texture_enabled != texture_enabled_) {
    // Same pyramid, new surface options: republish the window in place.
    texture_enabled_ = s.texture_enabled;
    note(std::string("texture ") + (s.texture_enabled ? "on" : "off"));
    const session::HapticWindow w = lod_->window();
    lod_ = std::make_unique<session::LodController>(built_->pyramid, shared_, controller_options());
    lod_->set_window(w.level, w.col0, w.row0);
    show_window();
  }
  const bool friction_changed = model != layer_options_.friction_model || s.mu_s != layer_options_.mu_s;
  if (friction_changed && built_->pyramid->stored()) {
    // A stored scene's levels hold their μ layers; recomputing them needs every level in memory.
    status_ = "the friction model and mu_s of a tiled scene are fixed (set them in the run config and run it again)";
  } else if (friction_changed && !job_.valid()) {
    // Friction layers of every level change: rebuild the pyramid on a worker.
    if (model != layer_options_.friction_model) note("model " + s.friction_model);
    if (s.mu_s != layer_options_.mu_s) {
      char buf[64];
      std::snprintf(buf, sizeof buf, "mu_s %.17g", s.mu_s);
      note(buf);
    }
    layer_options_.friction_model = model;
    layer_options_.mu_s = s.mu_s;
    Scene base = session::explore_base_layers(built_->base);
    const pipeline::SurfaceLayerOptions layers = layer_options_;
    const pipeline::LodOptions lod = lod_options_;
    const Eigen::Quaterniond q = built_->orientation;
    const std::string name = built_->description;
    status_ = "rebuilding the friction layers ...";
    job_ = std::async(std::launch::async, [base = std::move(base), layers, lod, q, name]() mutable {
      auto b = session::build_explore_scene(std::move(base), layers, lod, true);
      b->orientation = q;
      b->description = name;
      b->disarm = false;
      b->keep_window = true;
      return b;
    });
  }
}

void Session::adopt(const std::shared_ptr<session::ExploreScene>& b) {
  std::optional<session::HapticWindow> old;
  if (lod_ && lod_->has_window()) old = lod_->window();
  built_ = b;
  lod_ = std::make_unique<session::LodController>(built_->pyramid, shared_, controller_options());
  if (b->keep_window && old) {
    lod_->set_window(old->level, old->col0, old->row0);
  } else {
    centre_first_window();
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
  if (job_.valid() && job_.wait_for(std::chrono::seconds(0)) == std::future_status::ready) {
    std::shared_ptr<session::ExploreScene> incoming;
    try {
      incoming = job_.get();
    } catch (const std::exception& e) {
      status_ = std::string("failed: ") + e.what();
    }
    if (incoming && incoming->disarm) {
      // A new object: zero force while it swaps (docs/architecture.md, "Re-scan"). The swap
      // publishes its first window once the device is disarmed.
      swap_.begin([this, incoming] {
        adopt(incoming);
        return lod_->window().tag;
      });
      status_ = "swapping the scene (forces off) ...";
    } else if (incoming) {
      adopt(incoming);  // same object, new friction layers: in place
      status_.clear();
    }
  }
  // Retries a pending arm or disarm, advances a swap under way (re-arms when the new scene is in).
  const bool swapping = swap_.busy();
  if (swap_.step() == session::SwapPhase::kIdle && swapping) status_ = "new scene in place";
}

void Session::run_step(const ScriptStep& st) {
  using viewer::RegionCommandType;
  const std::string& a = st.action;
  if (a == "finer") viewer_->issue({RegionCommandType::kFiner});
  if (a == "coarser") viewer_->issue({RegionCommandType::kCoarser});
  if (a == "level") viewer_->issue({RegionCommandType::kSetLevel, script_int(st, 0)});
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
  if (a == "window") {
    if (!lod_ || swap_.busy()) return;
    set_window_step(st);
    note_window();
    show_window();
  }
  if (a == "rescan") {
    on_rescan(pipeline::rotation_from_euler(
        Eigen::Vector3d(script_number(st, 0), script_number(st, 1), script_number(st, 2)), "xyz"));
  }
  if (a == "stiffness") {
    // What the panel's slider sends (the servo clamps it to the device's stable range).
    (void)shared_.commands.try_push(haptics::Command::of(haptics::CommandType::kSetStiffness, script_number(st, 0)));
  }
  if (a == "stereo") viewer_->set_stereo(st.args[0] == "on");
  if (a == "display") viewer_->set_display(viewer::display_choice_from_string(st.args[0], "explore: --script display"));
}

#endif  // HC_HAVE_VIEWER

}  // namespace hc::app
