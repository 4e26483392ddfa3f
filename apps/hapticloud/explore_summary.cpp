/// `hapticloud explore`, the end-of-session statistics on stdout and the --summary JSON
/// (explore_session.hpp).

#include "explore_session.hpp"

#include "hc/common/error.hpp"

#include <nlohmann/json.hpp>

#include <fstream>
#include <iostream>

namespace hc::app {

#ifdef HC_HAVE_VIEWER

void Session::write_summary(const haptics::ServoStats& stats) const {
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
  j["fifo_granted"] = realtime_.fifo_granted;
  j["memory_locked"] = realtime_.memory_locked;
  j["cpu_latency_pinned"] = realtime_.cpu_latency_pinned;
  j["mesh_quads"] = viewer_->mesh_quads();
  j["display"] = viewer::to_string(viewer_->display());  // at the end of the session
  j["display_note"] = viewer_->display_note();           // why it is drawn grey, or empty
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
  j["script_steps"] = script_steps_;
  j["script_steps_run"] = script_steps_run_;
  // Surface accounting (SharedState): published − freed is what is still held (current, pending,
  // retire ring) when the summary is written, before the shared state is destroyed.
  j["surfaces_published"] = shared_.surfaces_published();
  j["surfaces_freed"] = shared_.surfaces_freed();
  // What the swaps looked like from the UI thread: swaps completed, the largest device force and
  // whether the device was ever seen Armed between the disarm and the re-arm (SceneSwap).
  const session::SceneSwapFigures& sw = swap_.figures();
  j["swaps"] = sw.swaps_done;
  j["swap_max_device_force_n"] = sw.max_device_force_n;
  j["swap_seen_armed"] = sw.seen_armed;
  j["stopped_by_signal"] = stopped_by_signal_;
  j["status"] = status_;
  js << j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) << "\n";
}

#endif  // HC_HAVE_VIEWER

}  // namespace hc::app
