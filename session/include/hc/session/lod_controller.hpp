#pragma once
/// @file lod_controller.hpp
/// Run-time level-of-detail and region-of-interest control (paper Sec. 4.1: "users can select the
/// level as well as the region of interest at run time"). A LodController owns (shares) the
/// pyramid, knows the current level and haptic window, and on every request builds the new
/// window's HapticSurface and its workspace map OFF the servo thread and publishes both together
/// through SharedState's surface mailbox, so the servo loop switches surface and map at one tick
/// and carries the proxy over (servo_loop.hpp). Used by `hapticloud touch` and the viewer.
/// No OpenCV, PCL or yaml-cpp in this header.

#include "hc/common/height_field.hpp"
#include "hc/haptics/haptic_surface.hpp"
#include "hc/haptics/shared_state.hpp"
#include "hc/haptics/workspace_map.hpp"
#include "hc/pipeline/lod.hpp"

#include <Eigen/Core>

#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

namespace hc::session {

using pipeline::LodLevel;
using pipeline::LodOptions;
using pipeline::LodPyramid;
using pipeline::LodWindowLayers;


/// How windows are turned into haptic surfaces and mapped into the device.
struct LodControllerOptions {
  haptics::SurfaceOptions surface;  ///< texture gain, default μ_d/μ_s, floor margin of each window
  /// Half extents of the device workspace box [m] (DeviceInfo::workspace_half_extent_m); x and y
  /// are used for the map's scale.
  Eigen::Vector3d device_half_extent_m = Eigen::Vector3d(0.05, 0.05, 0.05);
  double rotation_rad = 0.0;        ///< rotation of every map about the view axis [rad]
  /// After each switch, build the levels just finer and coarser than the new one on a background
  /// thread, so the next zoom step costs only its window (the ≤ 1 ms switch of issue 4) instead
  /// of a level build; the pyramid's LRU budget still bounds the memory.
  bool prefetch_neighbours = true;
};

/// The haptic window: what the servo renders (or is about to).
struct HapticWindow {
  int level = 0;             ///< pyramid level (0 = finest)
  int row0 = 0, col0 = 0;    ///< the window's first sample in the level's samples
  int rows = 0, cols = 0;    ///< size [samples]: window_cells, or the level's size when smaller
  GridGeometry geometry;     ///< the window's samples, grid frame
  /// Device ↔ grid map published with the surface. Its scale is the same for every window of a
  /// level: (window_cells − 1)·cell_L fills the device box (the smaller of its x, y extents), so
  /// each finer level doubles the detail under the hand; x, y and z share the scale.
  haptics::WorkspaceMap map;
  std::uint64_t tag = 0;     ///< surface tag: Snapshot::surface_tag once the servo renders it
  double level_seconds = 0.0;   ///< time spent building the level for this request [s] (0 if cached)
  double window_seconds = 0.0;  ///< time to crop the window and build its HapticSurface [s]
  double min_height_m = 0.0, max_height_m = 0.0;  ///< rendered height range of the window [m]
};

/// The haptic surface of one window: its depth, and its envelope, texture, μ_d and μ_s when the
/// pyramid computed layers (`win.envelope_m` non-empty). Frames and units as in `win` (grid
/// frame of the level, metres). Real-time: no (allocates). Throws what HapticSurface throws.
std::unique_ptr<haptics::HapticSurface> make_window_surface(const LodWindowLayers& win,
                                                            const haptics::SurfaceOptions& options);

/// Level and window control for one SharedState. Not thread-safe: call from one thread (the UI
/// or main thread); never from the servo thread (every call allocates and may take long: a level
/// not yet cached is built, up to seconds for the coarse levels of a 4096² scene).
/// Every request clamps the window into the level and publishes (SharedState::publish_surface
/// with the map); it returns the window published. The proxy keeps its DEVICE position across a
/// switch (the servo maps it through the old and the new map), so:
///  - set_level / zoom_in / zoom_out anchor the new map at a grid point (normally the proxy):
///    the anchor keeps both its grid and its device position, so the hand stays on the same
///    feature, now shown 2× larger or smaller; the window is centred on where the device box
///    lands, clamped into the level;
///  - pan moves the window by whole samples and the map by the same distance, so the proxy
///    slides over the object by that distance;
///  - set_window / centre_window fit the window to the device box (centred, device z = 0 at the
///    window's mid height).
class LodController {
 public:
  /// @param pyramid shared with whoever else reads levels (the viewer draws them).
  /// @param shared  the SharedState the servo loop of this session reads; must outlive this.
  /// @throws hc::ConfigError for non-positive device extents or invalid surface options.
  LodController(std::shared_ptr<LodPyramid> pyramid, haptics::SharedState& shared,
                const LodControllerOptions& options);
  /// Stops the prefetch thread (waits for a level build in progress to end).
  ~LodController();
  LodController(const LodController&) = delete;
  LodController& operator=(const LodController&) = delete;

  int level_count() const noexcept { return pyramid_->level_count(); }
  /// Geometry of level L. @throws hc::InputError for L out of range.
  const GridGeometry& level_geometry(int level) const { return pyramid_->geometry(level); }
  int window_cells() const noexcept { return pyramid_->options().window_cells; }
  LodPyramid& pyramid() noexcept { return *pyramid_; }
  std::shared_ptr<LodPyramid> shared_pyramid() const noexcept { return pyramid_; }
  const LodControllerOptions& options() const noexcept { return options_; }

  /// True once a window has been published.
  bool has_window() const noexcept { return window_.has_value(); }
  /// The last published window. @throws hc::InputError if none has been published.
  const HapticWindow& window() const;
  /// True when the servo renders the last published window (its tag was adopted).
  bool adopted() const noexcept;

  /// Window at level L whose first sample is (row0, col0) of the level (clamped), fitted to the
  /// device box. @throws hc::InputError for L out of range.
  const HapticWindow& set_window(int level, int col0, int row0);
  /// The same with the window centred (to the nearest sample) on grid point (x_m, y_m).
  const HapticWindow& centre_window(int level, double x_m, double y_m);

  /// Switch to level L keeping `anchor_grid_m` (normally the proxy, from the latest Snapshot)
  /// fixed in both frames. Without an anchor: the grid point at the device origin. The anchor's
  /// device position is taken with the map the servo renders with (the adopted window's, found
  /// by counters.surface_tag), so requests faster than the servo adopts them still anchor right.
  /// Before any window was published this is centre_window(L, centre of the grid).
  /// @throws hc::InputError for L out of range.
  const HapticWindow& set_level(int level, std::optional<Eigen::Vector3d> anchor_grid_m = std::nullopt);
  /// set_level(level − 1) (finer) / set_level(level + 1) (coarser), clamped to the pyramid.
  const HapticWindow& zoom_in(std::optional<Eigen::Vector3d> anchor_grid_m = std::nullopt);
  const HapticWindow& zoom_out(std::optional<Eigen::Vector3d> anchor_grid_m = std::nullopt);
  /// Moves the window by (dcols, drows) samples of the current level (clamped at the border)
  /// and the map with it. @throws hc::InputError if no window has been published.
  const HapticWindow& pan(int dcols, int drows);

  /// Builds (if needed) level L with its layers now, so a later switch to it costs only the
  /// window (call from a worker thread while the user explores; thread-safe w.r.t. the pyramid).
  void prefetch(int level);
  /// Blocks until the background prefetch (prefetch_neighbours) has nothing left to build.
  /// For tests and benchmarks. Real-time: no.
  void wait_prefetch_idle();

 private:
  void queue_prefetch(int level);
  void prefetch_loop();

  const HapticWindow& publish(int level, int row0, int col0, const std::optional<haptics::WorkspaceMap>& map);
  haptics::WorkspaceMap fitted_map(const HapticWindow& w, double z_centre_m) const;
  double level_scale(int level) const;

  std::shared_ptr<LodPyramid> pyramid_;
  haptics::SharedState& shared_;
  LodControllerOptions options_;
  /// The map the servo renders with now (the adopted window's; the last published one if the
  /// adopted tag is no longer among the recent windows).
  const haptics::WorkspaceMap& adopted_map() const;

  std::optional<HapticWindow> window_;
  std::vector<HapticWindow> recent_;  // the last few published windows, for adopted_map()
  std::uint64_t next_tag_ = 1;
  // Background prefetch of neighbouring levels (prefetch_neighbours): a queue served by one thread.
  std::mutex prefetch_mutex_;
  std::condition_variable prefetch_cv_;
  std::vector<int> prefetch_queue_;
  bool prefetch_busy_ = false;
  bool prefetch_stop_ = false;
  std::thread prefetch_thread_;
};

}  // namespace hc::session
