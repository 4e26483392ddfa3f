#pragma once
/// @file touch_session.hpp
/// The scripted, headless haptic session of `hapticloud touch` (issue 3): a SimulatedDevice
/// follows a scripted path through a virtual hand, the servo loop renders a scene (as fast as
/// possible on a manual clock, or in real time on its own thread), optionally a window of a
/// level of detail with scripted switches (LodSession, issue 4); the result is the per-tick
/// trace, the contact events and the summary figures, written as trace.csv, events.csv,
/// summary.json and PNG plots. Also the paper's validation (Sec. 5.1): the same press-and-slide
/// with and without texture and friction, plotted together in one report.
///
/// Audio is not part of this target: a caller that plays or renders contact sounds passes a
/// hook that sees every contact event and the region-id layer the events should carry.

#include "hc/common/height_field.hpp"
#include "hc/common/scene.hpp"
#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/shared_state.hpp"
#include "hc/haptics/workspace_map.hpp"
#include "hc/session/lod_session.hpp"

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

namespace hc::session {

/// Settings of one scripted session. Device-frame quantities are in the simulated device's frame
/// (SimulatedDevice::default_info(): a ±50 mm cube); the scene's extent is fitted into it.
struct TouchSessionOptions {
  std::string path = "raster";      ///< hold | line | circle | raster | press-slide
  double seconds = 10.0;            ///< session length [s], (0, 3600]
  double rate_hz = 1000.0;          ///< servo rate [Hz], (0, 10000]
  bool realtime = false;            ///< servo on its own thread in real time (else a manual clock)
  double texture_gain = 1.0;        ///< rendered height = envelope + gain·texture [-], [0, 100]
  bool friction = true;             ///< false: μ_d = μ_s = 0 whatever the scene holds
  double mu_d = 0.3;                ///< μ_d where the scene has no μ_d layer [-], [0, 10]
  double mu_s = 0.4;                ///< μ_s where the scene has no μ_s layer [-], [0, 10]
  double stiffness_n_per_m = 800.0; ///< proxy spring k [N/m] (device frame), (0, 1e5]
  double max_force_n = 8.0;         ///< force cap [N], (0, 100]
  double rho = 0.9;                 ///< proxy step factor ρ of Eq. 4–5 [-], (0, 1]
  bool hand = true;                 ///< false: the device sits exactly on the scripted target
  double press_m = 0.01;            ///< how far below mid height the hand aims [m] (device frame), [0, 0.5]
  double speed_m_per_s = 0.05;      ///< path speed [m/s] (device frame), (0, 10]
  /// Device: empty = the scripted SimulatedDevice; otherwise a recording (docs/recording.md)
  /// played back one sample per servo read (TickReplayDevice; path, hand, press and speed unused).
  std::filesystem::path replay_file;
  /// Record the session's device samples and forces here (RecordingDevice), or empty. Must not
  /// exist yet.
  std::filesystem::path record_file;

  /// Levels of detail: on when `levels` is true; then the servo renders a window of `level`
  /// (−1: the coarsest) whose first sample is `window_origin` (column, row; empty: centred),
  /// `window_cells` samples on a side (0: the scene's lod.window_cells), switched by `zoom_path`.
  bool levels = false;
  int level = -1;
  std::optional<std::pair<int, int>> window_origin;
  std::vector<ZoomAction> zoom_path;
  int window_cells = 0;

  /// Checks every number: finite and in the range given above (window_cells 0 or [2, 4096],
  /// level ≥ −1), and the path name.
  /// @throws hc::ConfigError naming the command-line option (e.g. "--rate -5"), the value and
  ///         the expected range.
  void validate() const;
};

/// What a caller may add to a session (audio lives outside hc::session).
struct TouchSessionHooks {
  /// Called for every contact event, in order, on the calling thread, while the session runs
  /// (between servo batches as fast as possible; every few ms in real time). Not real-time.
  std::function<void(const haptics::ContactEvent&)> on_event;
  /// Region id per cell (scene geometry, float, NaN = none) carried into the contact events;
  /// must outlive the call. Not supported with levels of detail.
  const HeightField* region_id = nullptr;
};

/// Summary figures of a session, from its trace and events.
struct TouchFigures {
  double max_force_n = 0.0;             ///< largest |F| of any tick [N]
  double deepest_m = 0.0;               ///< largest (surface − proxy z) [m], grid frame (≥ 0)
  double mean_force_contact_n = 0.0;    ///< mean |F| over the ticks in contact [N] (0 without contact)
  std::size_t contact_ticks = 0;        ///< ticks in contact
  double contact_fraction = 0.0;        ///< contact_ticks / trace rows
  std::size_t events_by_type[4] = {0, 0, 0, 0};  ///< onset, slide, release, press
  std::uint64_t events_dropped = 0;     ///< events the servo could not queue
  double p50_ns = 0, p99_ns = 0, p999_ns = 0, max_ns = 0;  ///< tick compute time [ns]
};

/// One finished session.
struct TouchSessionResult {
  std::vector<haptics::TickRecord> trace;   ///< one row per tick, grid frame, SI units
  std::vector<double> surface_z_m;          ///< per trace row: rendered height under the proxy
                                            ///< (on the surface that tick rendered) [m], grid frame
  std::vector<haptics::ContactEvent> events;
  haptics::ServoStats stats;
  haptics::RealtimeReport realtime;         ///< what the real-time mode got (default when off)
  haptics::WorkspaceMap map;                ///< device ↔ grid map of the first surface
  TouchFigures figures;
  std::string lod_json;                     ///< LodSession::json() with levels of detail, else empty
  std::string lod_text;                     ///< LodSession::print() with levels of detail, else empty
};

/// Runs one scripted session on `scene` (depth required; envelope, texture, μ_d and μ_s used
/// when present). Without levels of detail the scene's extent fills the device box with device
/// z = 0 at mid height of the rendered surface; the hand descends from 10 mm above the top to
/// `press_m` below mid height over min(0.5 s, seconds/10), then follows the path at 0.6 of the
/// device box. ceil(seconds·rate) ticks are run and traced (at most 5e7).
/// Source: the proxy algorithm of the paper (Sec. 4, Eqs. 4–5) as implemented by hc::haptics.
/// @throws hc::ConfigError from options.validate(), for a level or window out of the scene's
///         pyramid, or for a region layer with levels of detail; hc::ResourceError for more than
///         5e7 ticks; hc::InputError for a scene without depth. Real-time: no (it runs the loop).
/// With `stored_levels` (a tiled scene's levels on disk, LodPyramid::open_stored; issue 14) the
/// session renders windows of that pyramid and `scene` needs no layers: levels of detail are
/// then always on (without --level the coarsest level is rendered).
TouchSessionResult run_touch_session(const Scene& scene, const TouchSessionOptions& options,
                                     const TouchSessionHooks& hooks = {},
                                     std::shared_ptr<pipeline::LodPyramid> stored_levels = nullptr);

/// Writes a session into the folder `dir` (made if missing): trace.csv (one row per tick:
/// t_s from the first tick, HIP, proxy and force, contact, sticking, μ_d, μ_s, β, iterations,
/// compute_ns, surface_z_m, proxy_below_surface_m), events.csv (t_s, type, region_id, proxy,
/// |F|, speed), summary.json (`description`, the options, tick statistics, figures, events,
/// levels of detail; `extra_json`, a JSON object text or empty, adds its members before "lod")
/// and proxy_z.png / force.png.
/// @throws hc::InputError naming the file that cannot be written; hc::ConfigError if
///         `extra_json` is not a JSON object.
void write_touch_session(const TouchSessionResult& result, const TouchSessionOptions& options,
                         const std::string& description, const std::filesystem::path& dir,
                         const std::string& extra_json = {});

/// Prints the summary lines of a session (ticks, overruns, compute percentiles, force, contact,
/// events, levels of detail) to `out`.
void print_touch_session(std::ostream& out, const TouchSessionResult& result, const TouchSessionOptions& options,
                         const std::string& description, const std::filesystem::path& dir);

/// The paper's validation (Sec. 5.1): the options of its two sessions, with texture and friction
/// (`options` as given) and without either (texture gain 0, friction off); both on the path
/// press-slide when `options.path` is the default raster.
std::pair<TouchSessionOptions, TouchSessionOptions> validation_options(const TouchSessionOptions& options);

/// Writes the validation report into `dir`: validation_proxy_z.png and validation_force.png
/// (both sessions against time from their first tick) and report.md (a table of their figures).
/// @throws hc::InputError naming report.md when it cannot be written.
void write_validation_report(const TouchSessionResult& with, const TouchSessionResult& without,
                             const std::string& path, const std::string& description,
                             const std::filesystem::path& dir);

/// The paper's validation surface (Sec. 5.1) with a fine texture, over a 100 mm square centred
/// on the origin, n × n samples: envelope A·sin(2πx/λ)·sin(2πy/λ), A = 4 mm, λ = 40 mm; texture
/// a·sin(2πx/λt)·sin(2πy/λt), a = 0.2 mm, λt = 2 mm; depth = envelope + texture (grid frame,
/// metres; heights from pipeline::synthetic_height). No μ layers.
/// @throws hc::ConfigError naming --cells when n is outside [2, 8192].
Scene synthetic_sinusoid_scene(int n);

}  // namespace hc::session
