#pragma once
/// @file lod_session.hpp
/// Levels of detail in a scripted `hapticloud touch` session (issue 4): the pyramid of the
/// session's scene, the initial window (--level L --window X,Y) and a scripted sequence of level
/// switches and pans (--zoom-path) applied at given session times through a LodController.

#include "hc/common/height_field.hpp"
#include "hc/common/scene.hpp"
#include "hc/haptics/haptic_surface.hpp"
#include "hc/haptics/shared_state.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/session/lod_controller.hpp"
#include "hc/pipeline/surface_layers.hpp"

#include <Eigen/Core>

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

namespace hc::session {

/// One scripted request: at session time t_s, `in` / `out` (zoom around the proxy), `level L`
/// (switch around the proxy), `pan DX DY` (samples of the current level), `window L X Y`
/// (window at level L whose first sample is column X, row Y).
struct ZoomAction {
  enum class Kind { kIn, kOut, kLevel, kPan, kWindow };
  double t_s = 0.0;
  Kind kind = Kind::kIn;
  int a = 0, b = 0, c = 0;
  std::string text;  ///< as written (for the report)
};

/// Parses a zoom path: a file with one action per line ("T ACTION ARGS...", '#' starts a
/// comment), or a spec with actions separated by ',' or ';' and fields by ' ' or ':'
/// (e.g. "1:in,2.5:pan:20:-10,4:out,5:level:2,6:window:1:0:40"). Times must not decrease.
/// @throws hc::ConfigError naming the action and what was expected.
std::vector<ZoomAction> parse_zoom_path(const std::string& file_or_spec);

/// Parses "X,Y" into a column and a row. @throws hc::ConfigError.
std::pair<int, int> parse_window_origin(const std::string& text);

/// One switch made during the session.
struct SwitchRecord {
  double t_s = 0.0;             ///< session time of the request [s]
  std::string request;          ///< the action
  HapticWindow window;
};

class LodSession {
 public:
  /// Builds the pyramid from the scene's layers (hc/common/scene.hpp; depth required; envelope,
  /// texture, mu_d and mu_s are used for level 0 when all four are present, else computed) and publishes the
  /// initial window: level `level` (−1: the coarsest) with its first sample at `origin`
  /// (column, row) or centred on the grid. Levels ≥ 1 get their layers from `layer_options`
  /// (the scene's own, as in `hapticloud run`). Every level and window origin of `actions` is
  /// checked against the pyramid before the first window is published.
  /// @throws hc::ConfigError naming --level, --window or the --zoom-path action for a level or
  ///         origin out of range; hc::InputError for missing layers.
  LodSession(const SceneLayers& layers, const haptics::SurfaceOptions& surface,
             const Eigen::Vector3d& device_half_extent_m, int level, std::optional<std::pair<int, int>> origin,
             std::vector<ZoomAction> actions, haptics::SharedState& shared,
             const pipeline::SurfaceLayerOptions& layer_options, const pipeline::LodOptions& lod);

  /// The same on a given pyramid (a tiled scene's stored levels, LodPyramid::open_stored, or
  /// one shared with others). @throws as above; hc::InputError for a null pyramid.
  LodSession(std::shared_ptr<pipeline::LodPyramid> pyramid, const haptics::SurfaceOptions& surface,
             const Eigen::Vector3d& device_half_extent_m, int level, std::optional<std::pair<int, int>> origin,
             std::vector<ZoomAction> actions, haptics::SharedState& shared);
  const HapticWindow& initial() const { return switches_.front().window; }
  /// Session time [s] of the next scripted action (infinity when none is left).
  double next_time() const;
  /// Applies every action due at session time t_s; `proxy_m` anchors zooms (grid frame).
  /// @return the number applied. Real-time: no (builds windows; call between servo ticks).
  int apply_due(double t_s, const Eigen::Vector3d& proxy_m);

  /// The rendered surface of a published window (by tag), for evaluating trace rows. Rebuilt
  /// from the pyramid on demand; only the last one asked for is kept, so a long session's rows,
  /// asked for in time order (each tag's rows are contiguous), cost one window build per switch
  /// and one window of memory (a 30-minute soak switches 18 000 times).
  /// A tag no switch published (rows traced before the first adoption) gives the first window.
  const haptics::HapticSurface& surface_for(std::uint64_t tag);
  const std::vector<SwitchRecord>& switches() const { return switches_; }
  int level_count() const { return controller_->level_count(); }
  /// JSON object text with the levels and every switch (strings escaped).
  std::string json() const;
  void print(std::ostream& out) const;

 private:
  /// @throws hc::ConfigError naming `what` when (col0, row0) is not a sample of `level`.
  void check_origin(const std::string& what, int level, int col0, int row0) const;

  std::shared_ptr<pipeline::LodPyramid> pyramid_;
  std::unique_ptr<LodController> controller_;
  haptics::SurfaceOptions surface_options_;
  std::vector<ZoomAction> actions_;
  std::size_t next_ = 0;
  std::vector<SwitchRecord> switches_;
  std::uint64_t eval_tag_ = 0;                             ///< tag of eval_ (0: none)
  std::unique_ptr<haptics::HapticSurface> eval_;           ///< the last surface_for result
  std::map<std::uint64_t, std::size_t> switch_of_tag_;     ///< tag → index in switches_
};

}  // namespace hc::session
