#pragma once
/// @file explore_session.hpp
/// The UI-thread side of `hapticloud explore` (explore_command.cpp parses the options): loads the
/// scene, starts the device and the servo loop, wires the viewer's keys, panel and orientation
/// tool to the level-of-detail controller, runs re-scans and friction rebuilds on workers and
/// swaps their scenes in (hc::session::SceneSwap), runs --script steps and writes the summary.
///
/// Threads (docs/architecture.md): servo (SCHED_FIFO when granted), UI (this, nice +10 once the
/// servo runs, and every thread it starts inherits that: Mesa's, the workers'), re-scan /
/// rebuild workers (std::async), audio (hc::audio's own).

#include "explore_script.hpp"
#include "hc/common/format.hpp"

#include <string>

#ifdef HC_HAVE_VIEWER
#include "hc/haptics/clock.hpp"
#include "hc/haptics/recording.hpp"
#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/udp_device.hpp"
#include "hc/haptics/shared_state.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/session/explore_scene.hpp"
#include "hc/session/lod_controller.hpp"
#include "hc/session/scene_swap.hpp"
#include "hc/viewer/input_devices.hpp"
#include "hc/viewer/viewer.hpp"

#ifdef HC_HAVE_AUDIO
#include "hc/audio/engine.hpp"
#endif

#include <future>
#include <memory>
#include <optional>
#include <sstream>
#include <vector>
#endif

namespace hc::app {

/// The actions a recording's @session lines may hold (docs/recording.md).
inline constexpr const char* kSessionActions = "window LEVEL COL0 ROW0, texture on|off, mu_s V, model NAME, rescan AX AY AZ";

/// The options of `hapticloud explore` (see add_explore_command for each one's meaning).
struct ExploreOptions {
  std::string input;
  std::string device = "mouse";  ///< falcon | mouse | sim | replay:FILE
  std::string record;            ///< --record FILE (docs/recording.md), or empty
  std::string path = "raster";
  double speed_m_per_s = 0.03;
  std::string screenshot;
  int frames = 0;
  double seconds = 0.0;
  std::string summary;
  std::string out = "explore-out";
  int width = 1280, height = 800;
  bool stereo = false;
  bool show_regions = false;  ///< start with the audio-region overlay on (key A)
  double udp_timeout_s = 0.1;  ///< --device udp: silence after which the device faults [s], (0, 10]
  std::string display = "colour";  ///< starting display: colour | grey | texture | mu_d | error
  bool hidden = false;
  bool no_audio = false;
  double stiffness_n_per_m = 800.0;
  double rho = 0.9;
  int window_cells = 0;  ///< 0: the config's lod.window_cells (200 for a scene folder)
  std::string realtime = "warn";
  std::string script;  ///< scripted actions "FRAME ACTION ARGS; ..." (explore_script.hpp)
};

/// Runs one interactive session to its end (window closed, --frames/--seconds reached, or a
/// stop signal). @throws hc::ConfigError for invalid options or a build without the viewer;
/// hc::InputError for unreadable input or unwritable output; whatever the device, the pipeline
/// and the viewer throw.
void run_explore(const ExploreOptions& options);

#ifdef HC_HAVE_VIEWER

inline std::string fmt(double v, int precision = 4) { return format_number(v, precision); }

/// The level whose whole grid fits in `cells` samples (else the coarsest).
int fitting_level(const session::LodController& lod, int cells);

/// The interactive session (UI-thread side). Every member is called on the UI thread.
class Session {
 public:
  explicit Session(const ExploreOptions& o) : o_(o) {}

  void run();

 private:
  // explore_session.cpp: set-up and the frame loop.
  std::vector<ScriptStep> check_options();  ///< also parses --script (its errors in the old order)
  void load_input();
  void start_device();
  void start_servo();
  void make_viewer();
  session::LodControllerOptions controller_options() const;
  // explore_session_events.cpp: what happens during frames.
  void show_window();
  void on_region(const viewer::RegionCommand& c);
  void on_rescan(const Eigen::Quaterniond& q);
  void on_surface_settings(const viewer::SurfaceSettings& s);
  void on_frame();
  void adopt(const std::shared_ptr<session::ExploreScene>& b);
  /// A session action into the recording (--record), as a script step without the frame.
  void note(const std::string& action);
  /// The current window as "window LEVEL COL0 ROW0" into the recording.
  void note_window();
  /// Sets the window of a `window LEVEL COL0 ROW0` step (no note, no display update).
  /// @throws hc::ConfigError for a level outside the pyramid (script_int's errors too).
  void set_window_step(const ScriptStep& st);
  /// Takes a recording's @session actions and panel servo settings for the replay (sorted by
  /// tick). @throws hc::InputError naming the file, the tick and the text of a bad action.
  void take_replay_events(const haptics::Recording& rec);
  void centre_first_window();
  void run_step(const ScriptStep& st);
  std::optional<Eigen::Vector3d> anchor() const;
  bool busy() const { return job_.valid() || swap_.busy(); }
  // explore_summary.cpp
  void write_summary(const haptics::ServoStats& stats) const;

  ExploreOptions o_;
  std::optional<pipeline::RunConfig> config_;
  std::vector<float> cloud_;
  std::shared_ptr<const HeightField> region_layer_;  ///< audio region per level-0 sample (overlay), or null
  std::vector<std::string> region_names_; ///< by region index
  pipeline::SurfaceLayerOptions layer_options_;
  pipeline::LodOptions lod_options_;
  std::shared_ptr<session::ExploreScene> built_;
  bool texture_enabled_ = true;

  haptics::SteadyClock clock_;
  haptics::SharedState shared_;
  std::unique_ptr<session::LodController> lod_;
  std::unique_ptr<haptics::HapticDevice> device_;
  std::unique_ptr<haptics::RecordingDevice> recorder_;  ///< wraps device_ with --record (declared after it)
  /// The device the servo loop drives: the recorder when recording, else device_.
  haptics::HapticDevice& active_device() { return recorder_ ? *recorder_ : *device_; }
  viewer::MouseDevice* mouse_ = nullptr;
  haptics::TickReplayDevice* replay_ = nullptr;  ///< device_ with --device replay:FILE
  haptics::UdpDevice* udp_ = nullptr;             ///< device_ with --device udp:HOST:PORT
  /// The replay's recorded session actions with their servo ticks, and the next one to run.
  std::vector<std::pair<std::uint64_t, ScriptStep>> replay_steps_;
  std::size_t next_replay_step_ = 0;
  /// The replay's recorded servo settings (stiffness, damping, force cap, ρ, friction on/off).
  std::vector<std::pair<std::uint64_t, haptics::Command>> replay_commands_;
  std::size_t next_replay_command_ = 0;
  double replay_rate_hz_ = 0.0;  ///< the recording's servo rate (0: not recorded)
  haptics::ServoConfig servo_config_;
  haptics::RealtimeReport realtime_;
  std::unique_ptr<haptics::ServoLoop> loop_;
  std::unique_ptr<viewer::Viewer> viewer_;

  // Re-scan / rebuild on a worker thread, then the swap (UI thread).
  std::future<std::shared_ptr<session::ExploreScene>> job_;
  session::SceneSwap swap_{shared_};
  bool drain_events_ = true;  ///< nothing else (no sound engine) reads shared_.events
  bool stopped_by_signal_ = false;
  int rescans_ = 0;
  std::size_t script_steps_ = 0, script_steps_run_ = 0;  ///< --script steps given and run
  std::string status_;
#ifdef HC_HAVE_AUDIO
  std::unique_ptr<audio::AudioEngine> sound_;  ///< reads shared_.events; stopped before the servo's stats
#endif
};

#endif  // HC_HAVE_VIEWER

}  // namespace hc::app
