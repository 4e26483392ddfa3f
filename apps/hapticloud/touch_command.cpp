/// `hapticloud touch`: a headless scripted haptic session. A SimulatedDevice follows a scripted
/// path through a virtual hand, the servo loop renders the scene (as fast as possible on a
/// manual clock, or in real time on its own thread with --realtime), and the session is written
/// as trace.csv, events.csv, summary.json and PNG plots in --out, with a summary on stdout.
/// --validate reproduces the paper's validation (Sec. 5.1): the same press-and-slide with and
/// without texture and friction, proxy z and force against time, in one report.
/// The session itself is hc::session (touch_session.hpp); this file parses options and wires
/// the scene, the output folder (staged: written whole or not at all) and the audio.

#include "commands.hpp"
#include "hc/session/lod_session.hpp"
#include "hc/session/scene_source.hpp"
#include "hc/session/touch_session.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/scene_io.hpp"

#ifdef HC_HAVE_AUDIO
#include "touch_audio.hpp"
#endif

#include <CLI/CLI.hpp>

#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <string>

namespace hc::app {
namespace {

namespace fs = std::filesystem;

struct TouchOptions {
  session::TouchSessionOptions s;  ///< the session's numbers (range-checked by s.validate())
  std::string input;
  std::string synthetic;
  std::string out = "touch-out";
  bool force = false;        ///< replace a foreign --out (kept aside as <out>.replaced-<time>)
  bool no_friction = false;
  bool no_hand = false;
  int cells = 400;
  bool validate = false;
  std::string audio_out;     ///< offline render of the session's contact sounds (WAV)
  std::string audio_live;    ///< play live: "default", "loopback" or an OpenAL device name
  std::string audio_config;  ///< run config whose audio: section to use
  std::string window;        ///< "X,Y": first column and row of the haptic window at --level
  std::string zoom_path;     ///< scripted level switches and pans (file or spec)
  int window_cells = 0;      ///< side of the haptic window [samples] (0: the scene's lod.window_cells)
  bool level_given = false;         ///< --level was on the command line (even -1)
  bool window_cells_given = false;  ///< --window-cells was on the command line
  std::string device = "sim";       ///< sim | replay:FILE
  std::string record;               ///< --record FILE (docs/recording.md), or empty
};

/// The session's options from the command line. @throws hc::ConfigError naming the option.
session::TouchSessionOptions session_options(const TouchOptions& o) {
  session::TouchSessionOptions s = o.s;
  s.friction = !o.no_friction;
  s.hand = !o.no_hand;
  // Levels of detail are on when --level, --window or --zoom-path is given, and always for a
  // tiled scene folder (its stored levels are rendered window by window; scene.yaml only is read).
  s.levels = o.level_given || !o.window.empty() || !o.zoom_path.empty();
  if (!s.levels && !o.validate && o.synthetic.empty() && !o.input.empty() && !session::is_run_config(o.input)) {
    std::error_code ec;
    const fs::path dir(o.input);
    if (fs::exists(dir / "scene.yaml", ec)) {
      s.levels = pipeline::load_scene(dir, false).storage.stores_levels();
    }
  }
  if (o.window_cells_given && o.window_cells == 0) {
    throw ConfigError("touch: --window-cells 0: expected an integer in [2, 4096]");
  }
  s.window_cells = o.window_cells_given ? o.window_cells : 0;
  s.validate();
  if (!o.window.empty()) s.window_origin = session::parse_window_origin(o.window);
  if (!o.zoom_path.empty()) s.zoom_path = session::parse_zoom_path(o.zoom_path);
  if (!o.synthetic.empty() && o.synthetic != "sinusoid") {
    throw ConfigError("touch: --synthetic '" + o.synthetic + "' is unknown (expected: sinusoid)");
  }
  if (!o.synthetic.empty() && (o.cells < 2 || o.cells > 8192)) {
    throw ConfigError("touch: --cells " + std::to_string(o.cells) + " is out of range (expected 2..8192)");
  }
  if (o.synthetic.empty() && o.input.empty()) {
    throw ConfigError("touch: give a scene folder (written by `hapticloud run`) or --synthetic sinusoid");
  }
  if (o.device.rfind("replay:", 0) == 0 && o.device.size() > 7) {
    s.replay_file = o.device.substr(7);
  } else if (o.device != "sim") {
    throw ConfigError("touch: --device '" + o.device + "' is unknown (expected sim or replay:FILE)");
  }
  s.record_file = o.record;
  if (o.validate && (!s.replay_file.empty() || !s.record_file.empty())) {
    throw ConfigError("touch: --record and --device replay:FILE are for one session, not with --validate");
  }
  if (!s.record_file.empty() && fs::exists(fs::symlink_status(s.record_file))) {
    throw ConfigError("touch: --record " + o.record + " exists already (not overwritten; choose another file)");
  }
  if (o.validate && (!o.audio_out.empty() || !o.audio_live.empty())) {
    throw ConfigError("touch: --audio-out and --audio-live are for one session, not with --validate");
  }
#ifndef HC_HAVE_AUDIO
  if (!o.audio_out.empty() || !o.audio_live.empty()) {
    throw ConfigError("touch: this build has no audio module (hc::audio); --audio-out/--audio-live are unavailable");
  }
#endif
  return s;
}

/// The scene: the synthetic sinusoid, a scene folder, or a run config built in memory (its run
/// folder written to `run_dir`, inside the staged output).
session::OpenedScene load_input(const TouchOptions& o, const fs::path& run_dir, const fs::path& shown_run_dir) {
  if (!o.synthetic.empty()) {
    session::OpenedScene opened;
    opened.scene = session::synthetic_sinusoid_scene(o.cells);
    opened.description = "synthetic sinusoid " + std::to_string(o.cells) + "x" + std::to_string(o.cells);
    return opened;
  }
  const fs::path p(o.input);
  session::SceneSourceOptions so;
  // A tiled scene's levels are read from disk, window by window (issue 14).
  so.open_stored_levels = !o.validate;
  so.stored_window_cells = o.window_cells_given ? o.window_cells : 0;
  if (session::is_run_config(p)) {
    so.run_dir = run_dir;
    std::cout << "touch: building the scene of " << p.string() << " into " << shown_run_dir.string() << "\n";
  }
  session::OpenedScene opened = session::open_scene_or_config(p, so);
  for (const std::string& note : opened.notes) std::cout << "touch: " << note << "\n";
  if (!opened.config) opened.description = "scene " + p.string();
  return opened;
}

void print_realtime(const session::TouchSessionOptions& s, const session::TouchSessionResult& r) {
  if (!s.realtime) return;
  std::cout << "realtime: SCHED_FIFO " << (r.realtime.fifo_granted ? "granted" : "not granted") << ", memory "
            << (r.realtime.memory_locked ? "locked" : "not locked") << ", CPU wake-up latency "
            << (r.realtime.cpu_latency_pinned ? "pinned to 0" : "not pinned") << "\n";
  if (!r.realtime.detail.empty()) std::cout << "realtime: " << r.realtime.detail << "\n";
}

void run_touch(const TouchOptions& o) {
  // Every option is checked before anything is written to --out.
  const session::TouchSessionOptions s = session_options(o);
  const fs::path out(o.out);
  // The output is staged beside --out and replaces it only when complete: a failure leaves
  // nothing, an earlier output is replaced whole, anything else is refused (or kept, --force).
  pipeline::StagingDir staging(out, o.force ? pipeline::ExistingOutput::kMoveAside : pipeline::ExistingOutput::kRefuse);
  const fs::path dir = staging.path();
  session::OpenedScene opened = load_input(o, dir / "pipeline", out / "pipeline");
  const Scene& scene = opened.scene;
  if (!o.validate) {
    session::TouchSessionHooks hooks;
    std::string extra_json;
#ifdef HC_HAVE_AUDIO
    std::optional<TouchAudio> audio;
    if (!o.audio_out.empty() || !o.audio_live.empty()) {
      const std::optional<audio::AudioConfig> spec = !o.audio_config.empty() ? pipeline::load_run_config(o.audio_config).audio
                                                     : opened.config         ? opened.config->audio
                                                                             : std::nullopt;
      audio.emplace(spec, scene, o.audio_out, o.audio_live);
      hooks = audio->start();
    }
#endif
    const session::TouchSessionResult r = session::run_touch_session(scene, s, hooks, opened.stored_levels);
    print_realtime(s, r);
#ifdef HC_HAVE_AUDIO
    if (audio) extra_json = audio->finish(r, s.rate_hz);
#endif
    session::write_touch_session(r, s, opened.description, dir, extra_json);
    staging.commit();
    session::print_touch_session(std::cout, r, s, opened.description, out);
  } else {
    // The paper's validation (Sec. 5.1, Figs. of proxy z and force against time): one scripted
    // press-and-slide, rendered with texture and friction, and again without either.
    const auto [with, without] = session::validation_options(s);
    const session::TouchSessionResult a = session::run_touch_session(scene, with);
    session::write_touch_session(a, with, opened.description, dir / "with_texture_friction");
    const session::TouchSessionResult b = session::run_touch_session(scene, without);
    session::write_touch_session(b, without, opened.description, dir / "without_texture_friction");
    session::write_validation_report(a, b, with.path, opened.description, dir);
    staging.commit();
    session::print_touch_session(std::cout, a, with, opened.description, out / "with_texture_friction");
    session::print_touch_session(std::cout, b, without, opened.description, out / "without_texture_friction");
    std::cout << "touch: validation report " << (out / "report.md").string() << "\n";
  }
  if (!staging.moved_aside().empty()) {
    std::cout << "kept the earlier content of " << out.string() << " as " << staging.moved_aside().string() << "\n";
  }
}

}  // namespace

void add_touch_command(CLI::App& app) {
  auto opts = std::make_shared<TouchOptions>();
  CLI::App* cmd = app.add_subcommand(
      "touch", "Headless scripted haptic session: a simulated hand explores a scene; writes trace.csv and a summary.");
  cmd->add_option("SCENE_OR_CONFIG", opts->input,
                  "Scene folder written by `hapticloud run`, or a run config (its scene is built first)");
  cmd->add_option("--synthetic", opts->synthetic, "Built-in scene instead of a folder: sinusoid (the paper's validation surface)");
  cmd->add_option("--path", opts->s.path, "Scripted path: raster | circle | line | press-slide | hold")->capture_default_str();
  cmd->add_option("--seconds", opts->s.seconds, "Session length [s], (0, 3600]")->capture_default_str();
  cmd->add_option("--rate", opts->s.rate_hz, "Servo rate [Hz], (0, 10000]")->capture_default_str();
  cmd->add_flag("--realtime", opts->s.realtime, "Run the servo thread in real time (tries SCHED_FIFO; realtime: warn)");
  cmd->add_option("--out", opts->out,
                  "Output folder; an earlier output there is replaced whole, anything else is refused")
      ->capture_default_str();
  cmd->add_flag("--force", opts->force,
                "Write --out even if it holds something else: that is kept as <out>.replaced-<time>, never deleted");
  cmd->add_option("--texture-gain", opts->s.texture_gain, "Texture gain, [0, 100] (0 renders the envelope only)")->capture_default_str();
  cmd->add_flag("--no-friction", opts->no_friction, "Render without friction (mu_d = mu_s = 0)");
  cmd->add_option("--mu-d", opts->s.mu_d, "mu_d where the scene has no mu_d layer, [0, 10]")->capture_default_str();
  cmd->add_option("--mu-s", opts->s.mu_s, "mu_s where the scene has no mu_s layer, [0, 10]")->capture_default_str();
  cmd->add_option("--stiffness", opts->s.stiffness_n_per_m, "Stiffness k [N/m] (device frame), (0, the device's max stable stiffness]")->capture_default_str();
  cmd->add_option("--max-force", opts->s.max_force_n, "Force cap [N], (0, the device's max force]")->capture_default_str();
  cmd->add_option("--rho", opts->s.rho, "Proxy step factor rho of Eq. 4-5, (0, 1]")->capture_default_str();
  cmd->add_option("--cells", opts->cells, "Grid size of the synthetic scene (N x N), 2..8192")->capture_default_str();
  cmd->add_option("--press", opts->s.press_m, "How far below mid height the hand aims [m] (device frame), [0, 0.1]")->capture_default_str();
  cmd->add_option("--speed", opts->s.speed_m_per_s, "Path speed [m/s] (device frame), (0, 10]")->capture_default_str();
  cmd->add_flag("--validate", opts->validate,
                "Paper's validation: the session with and without texture and friction, plots and report.md");
  cmd->add_flag("--no-hand", opts->no_hand, "Drive the device exactly along the path (no virtual hand)");
  cmd->add_option("--device", opts->device,
                  "sim (the scripted path through a virtual hand) or replay:FILE (a --record file played back one "
                  "sample per servo tick; docs/recording.md)")
      ->capture_default_str();
  cmd->add_option("--record", opts->record,
                  "Record the device's positions, buttons and the forces sent, per servo tick, to FILE (refused if "
                  "it exists; docs/recording.md)");
  cmd->add_option("--audio-out", opts->audio_out,
                  "Write the session's contact sounds to this WAV file (offline, sample-accurate to the events)");
  cmd->add_option("--audio-live", opts->audio_live,
                  "Play the contact sounds while the session runs: default | loopback | an OpenAL device name");
  cmd->add_option("--audio-config", opts->audio_config,
                  "Run config whose audio: section to use (default: the input config's own)");
  CLI::Option* level_opt = cmd->add_option(
      "--level", opts->s.level,
      "Levels of detail: render a window of this level (0 = finest; each level halves the resolution; -1 = coarsest)");
  cmd->add_option("--window", opts->window,
                  "X,Y: first column and row of the haptic window at --level (default: centred)");
  CLI::Option* cells_opt = cmd->add_option("--window-cells", opts->window_cells,
                                           "Side of the haptic window [samples], 2..4096 (default: the scene's "
                                           "lod.window_cells, else 200); needs --level, --window or --zoom-path");
  cmd->add_option("--zoom-path", opts->zoom_path,
                  "Scripted level switches and pans: a file (one 'T ACTION ARGS' per line) or a spec like "
                  "'1:in,2.5:pan:20:-10,4:out,5:level:2,6:window:1:0:40' (T in seconds; zooms keep the proxy)");
  cmd->callback([opts, level_opt, cells_opt] {
    opts->level_given = level_opt->count() > 0;
    opts->window_cells_given = cells_opt->count() > 0;
    run_touch(*opts);
  });
}

}  // namespace hc::app
