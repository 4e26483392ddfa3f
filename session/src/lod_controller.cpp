#include "hc/session/lod_controller.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>

namespace hc::session {
namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

}  // namespace

std::unique_ptr<haptics::HapticSurface> make_window_surface(const LodWindowLayers& win,
                                                            const haptics::SurfaceOptions& options) {
  haptics::SurfaceLayers layers;
  layers.depth = &win.depth_m;
  if (!win.envelope_m.values().empty()) {
    layers.envelope = &win.envelope_m;
    layers.texture = &win.texture_m;
    layers.mu_d = &win.mu_d;
    layers.mu_s = &win.mu_s;
  }
  return std::make_unique<haptics::HapticSurface>(layers, options);
}

LodController::LodController(std::shared_ptr<LodPyramid> pyramid, haptics::SharedState& shared,
                             const LodControllerOptions& options)
    : pyramid_(std::move(pyramid)), shared_(shared), options_(options) {
  if (!pyramid_) throw InputError("lod controller: no pyramid given");
  const Eigen::Vector3d& h = options_.device_half_extent_m;
  if (!h.allFinite() || !(h.x() > 0.0) || !(h.y() > 0.0) || !(h.z() > 0.0) || !std::isfinite(options_.rotation_rad)) {
    std::ostringstream s;
    s << "lod controller: device half extents (" << h.transpose() << ") m and rotation " << options_.rotation_rad
      << " rad: expected positive finite extents and a finite rotation";
    throw ConfigError(s.str());
  }
  if (options_.prefetch_neighbours) prefetch_thread_ = std::thread([this] { prefetch_loop(); });
}

LodController::~LodController() {
  {
    std::lock_guard<std::mutex> lock(prefetch_mutex_);
    prefetch_stop_ = true;
  }
  prefetch_cv_.notify_all();
  if (prefetch_thread_.joinable()) prefetch_thread_.join();
}

void LodController::queue_prefetch(int level) {
  // A stored pyramid builds nothing: its levels are on disk and a window reads only its tiles.
  if (!options_.prefetch_neighbours || pyramid_->stored() || level < 0 || level >= pyramid_->level_count()) return;
  if (pyramid_->is_cached(level, true)) return;
  {
    std::lock_guard<std::mutex> lock(prefetch_mutex_);
    if (std::find(prefetch_queue_.begin(), prefetch_queue_.end(), level) != prefetch_queue_.end()) return;
    prefetch_queue_.push_back(level);
  }
  prefetch_cv_.notify_all();
}

void LodController::prefetch_loop() {
  std::unique_lock<std::mutex> lock(prefetch_mutex_);
  for (;;) {
    prefetch_cv_.wait(lock, [this] { return prefetch_stop_ || !prefetch_queue_.empty(); });
    if (prefetch_stop_) return;
    const int level = prefetch_queue_.front();
    prefetch_queue_.erase(prefetch_queue_.begin());
    prefetch_busy_ = true;
    lock.unlock();
    try {
      (void)pyramid_->level(level);
    } catch (const std::exception&) {
      // A level that cannot be built fails again, with its message, when it is asked for.
    }
    lock.lock();
    prefetch_busy_ = false;
    prefetch_cv_.notify_all();
  }
}

void LodController::wait_prefetch_idle() {
  std::unique_lock<std::mutex> lock(prefetch_mutex_);
  prefetch_cv_.wait(lock, [this] { return prefetch_stop_ || (prefetch_queue_.empty() && !prefetch_busy_); });
}

const HapticWindow& LodController::window() const {
  if (!window_) throw InputError("lod controller: no window has been published yet");
  return *window_;
}

bool LodController::adopted() const noexcept {
  return window_.has_value() && shared_.counters.surface_tag.load(std::memory_order_acquire) == window_->tag;
}

double LodController::level_scale(int level) const {
  const GridGeometry& g = level_geometry(level);
  const double extent = static_cast<double>(window_cells() - 1) * g.cell_size_m;
  return haptics::WorkspaceMap::fit(options_.device_half_extent_m, 0.0, extent, 0.0, extent, 0.0, options_.rotation_rad)
      .scale;
}

haptics::WorkspaceMap LodController::fitted_map(const HapticWindow& w, double z_centre_m) const {
  // The nominal window (window_cells samples) centred on the actual one: the same scale at every
  // position of a level, also when the level is smaller than the window.
  const double half = 0.5 * static_cast<double>(window_cells() - 1) * w.geometry.cell_size_m;
  const double cx = w.geometry.x_of_col(0.5 * (w.cols - 1));
  const double cy = w.geometry.y_of_row(0.5 * (w.rows - 1));
  return haptics::WorkspaceMap::fit(options_.device_half_extent_m, cx - half, cx + half, cy - half, cy + half,
                                    z_centre_m, options_.rotation_rad);
}

const HapticWindow& LodController::publish(int level, int row0, int col0,
                                           const std::optional<haptics::WorkspaceMap>& map) {
  const auto t0 = Clock::now();
  // A level is built before its window is cropped (timed apart); a stored level is never read
  // whole: the window reads its own tiles.
  const bool was_cached = pyramid_->stored() || pyramid_->is_cached(level, true);
  if (!was_cached) (void)pyramid_->level(level);
  const double level_seconds = was_cached ? 0.0 : seconds_since(t0);
  const auto t1 = Clock::now();
  const int w = window_cells();
  const std::shared_ptr<const LodWindowLayers> win = pyramid_->window(level, row0, col0, w, w);
  auto surface = make_window_surface(*win, options_.surface);

  HapticWindow hw;
  hw.level = level;
  hw.row0 = win->row0;
  hw.col0 = win->col0;
  hw.rows = win->depth_m.rows();
  hw.cols = win->depth_m.cols();
  hw.geometry = win->depth_m.geometry();
  hw.min_height_m = surface->min_height_m();
  hw.max_height_m = surface->max_height_m();
  hw.map = map ? *map : fitted_map(hw, 0.5 * (hw.min_height_m + hw.max_height_m));
  hw.tag = next_tag_++;
  hw.level_seconds = level_seconds;
  shared_.publish_surface(std::move(surface), hw.map, hw.tag);
  hw.window_seconds = seconds_since(t1);
  shared_.collect_retired();
  window_ = hw;
  recent_.push_back(hw);
  if (recent_.size() > 8) recent_.erase(recent_.begin());
  queue_prefetch(level - 1);
  queue_prefetch(level + 1);
  return *window_;
}

const haptics::WorkspaceMap& LodController::adopted_map() const {
  const std::uint64_t tag = shared_.counters.surface_tag.load(std::memory_order_acquire);
  for (auto it = recent_.rbegin(); it != recent_.rend(); ++it) {
    if (it->tag == tag) return it->map;
  }
  return window_->map;
}

const HapticWindow& LodController::set_window(int level, int col0, int row0) {
  (void)level_geometry(level);
  return publish(level, row0, col0, std::nullopt);
}

const HapticWindow& LodController::centre_window(int level, double x_m, double y_m) {
  const GridGeometry& g = level_geometry(level);
  if (!std::isfinite(x_m) || !std::isfinite(y_m)) {
    throw InputError("lod controller: window centre (" + std::to_string(x_m) + ", " + std::to_string(y_m) +
                     ") m is not finite");
  }
  const int rows = std::min(window_cells(), g.rows), cols = std::min(window_cells(), g.cols);
  const auto col0 = static_cast<int>(std::lround(std::clamp(g.col_of_x(x_m) - 0.5 * (cols - 1), -1e9, 1e9)));
  const auto row0 = static_cast<int>(std::lround(std::clamp(g.row_of_y(y_m) - 0.5 * (rows - 1), -1e9, 1e9)));
  return publish(level, row0, col0, std::nullopt);
}

const HapticWindow& LodController::set_level(int level, std::optional<Eigen::Vector3d> anchor_grid_m) {
  const GridGeometry& g = level_geometry(level);
  if (!window_) {
    const GridGeometry& g0 = level_geometry(0);
    return centre_window(level, g0.x_of_col(0.5 * (g0.cols - 1)), g0.y_of_row(0.5 * (g0.rows - 1)));
  }
  const haptics::WorkspaceMap& old = adopted_map();
  const Eigen::Vector3d anchor = anchor_grid_m && anchor_grid_m->allFinite() ? *anchor_grid_m : old.origin_m;
  const Eigen::Vector3d anchor_dev = old.to_device(anchor);
  haptics::WorkspaceMap next;
  next.rotation_rad = options_.rotation_rad;
  next.scale = level_scale(level);
  next.origin_m = Eigen::Vector3d::Zero();
  // origin' = anchor − scale'·R·anchor_dev, so that next.to_grid(anchor_dev) = anchor.
  next.origin_m = anchor - next.to_grid(anchor_dev);
  // The window is centred on where the device box lands (its centre is the map's origin).
  const int rows = std::min(window_cells(), g.rows), cols = std::min(window_cells(), g.cols);
  const auto col0 =
      static_cast<int>(std::lround(std::clamp(g.col_of_x(next.origin_m.x()) - 0.5 * (cols - 1), -1e9, 1e9)));
  const auto row0 =
      static_cast<int>(std::lround(std::clamp(g.row_of_y(next.origin_m.y()) - 0.5 * (rows - 1), -1e9, 1e9)));
  return publish(level, row0, col0, next);
}

const HapticWindow& LodController::zoom_in(std::optional<Eigen::Vector3d> anchor_grid_m) {
  if (!window_) return set_level(0, anchor_grid_m);
  if (window_->level == 0) return *window_;
  return set_level(window_->level - 1, anchor_grid_m);
}

const HapticWindow& LodController::zoom_out(std::optional<Eigen::Vector3d> anchor_grid_m) {
  if (!window_) return set_level(level_count() - 1, anchor_grid_m);
  if (window_->level + 1 >= level_count()) return *window_;
  return set_level(window_->level + 1, anchor_grid_m);
}

const HapticWindow& LodController::pan(int dcols, int drows) {
  if (!window_) throw InputError("lod controller: pan before any window was published");
  const HapticWindow& w = *window_;
  const GridGeometry& g = level_geometry(w.level);
  const int col0 = std::clamp(w.col0 + dcols, 0, g.cols - w.cols);
  const int row0 = std::clamp(w.row0 + drows, 0, g.rows - w.rows);
  if (col0 == w.col0 && row0 == w.row0) return w;  // at the border already
  haptics::WorkspaceMap next = w.map;
  next.origin_m.x() += (col0 - w.col0) * g.cell_size_m;
  next.origin_m.y() += (row0 - w.row0) * g.cell_size_m;
  return publish(w.level, row0, col0, next);
}

void LodController::prefetch(int level) { (void)pyramid_->level(level); }

}  // namespace hc::session
