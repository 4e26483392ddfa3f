/// `hapticloud explore`: the interactive session of the paper. The scene (built from a run
/// config, or loaded from a scene folder) goes into a level-of-detail pyramid; a LodController
/// publishes the haptic window to the servo loop (its own thread, 1 kHz); the viewer (the UI
/// thread) draws snapshots, sends level/region and parameter commands, and asks for re-scans,
/// which run the pipeline on a worker thread and replace the scene without a restart while the
/// device is disarmed (zero force; hc::session::SceneSwap). Devices: the Falcon (hc::falcon), the
/// mouse, or a scripted path (sim). Audio through hc::audio when it is built.
/// This file is the command line; the session is explore_session.hpp, the script
/// explore_script.hpp.

#include "commands.hpp"
#include "explore_session.hpp"

#include "hc/common/error.hpp"

#ifdef HC_HAVE_VIEWER
#include "hc/viewer/viewer.hpp"
#endif

#include <CLI/CLI.hpp>

#include <memory>
#include <string>

namespace hc::app {

void add_explore_command(CLI::App& app) {
  auto o = std::make_shared<ExploreOptions>();
  CLI::App* cmd = app.add_subcommand(
      "explore",
      "Interactive session: see, feel and hear a scene (viewer + servo loop + device). Press H in the window for the controls.");
  cmd->add_option("CONFIG_OR_SCENE", o->input, "Run config (.yaml; its scene is built first, re-scans possible) or a scene folder")
      ->required();
  cmd->add_option("--device", o->device, "falcon | mouse | sim (a scripted path) | replay:FILE (a --record file, "
                                          "one sample per servo tick; docs/recording.md) | udp:HOST:PORT (poses in, "
                                          "forces out over UDP; docs/udp_bridge.md)")->capture_default_str();
  cmd->add_option("--record", o->record,
                  "Record the device's positions, buttons and the forces sent, per servo tick, to FILE (refused if "
                  "it exists; docs/recording.md)");
  cmd->add_option("--path", o->path, "Scripted path of --device sim: raster | circle | line | press-slide | hold")
      ->capture_default_str();
  cmd->add_option("--speed", o->speed_m_per_s, "Speed of the scripted path [m/s] (device frame)")->capture_default_str()->check(finite_in(0.0, 10.0, true));
  cmd->add_option("--screenshot", o->screenshot, "Render --frames N frames (1 if not given), save the last as PNG and exit");
  cmd->add_option("--frames", o->frames, "Exit after this many frames (0 = run until the window closes)")->capture_default_str()->check(CLI::Range(0, 100000000));
  cmd->add_option("--seconds", o->seconds, "Exit after this many seconds (0 = no limit)")->capture_default_str()->check(finite_in(0.0, 86400.0));
  cmd->add_option("--summary", o->summary, "Write servo and frame statistics of the session as JSON to this file");
  cmd->add_option("--out", o->out, "Folder for the scenes built from a config (scan-0, scan-1 after re-scans, ...)")
      ->capture_default_str();
  cmd->add_option("--width", o->width, "Window width [px]")->capture_default_str()->check(CLI::Range(64, 16384));
  cmd->add_option("--height", o->height, "Window height [px]")->capture_default_str()->check(CLI::Range(64, 16384));
  cmd->add_option("--window-cells", o->window_cells, "Haptic window side [samples] (default: the config's lod.window_cells, else 200)");
  cmd->add_option("--stiffness", o->stiffness_n_per_m, "Stiffness k [N/m] (device frame)")->capture_default_str()->check(finite_in(0.0, 100000.0, true));
  cmd->add_option("--rho", o->rho, "Proxy step factor rho of Eq. 4-5, (0, 1]")->capture_default_str()->check(finite_in(0.0, 1.0, true));
  cmd->add_option("--realtime", o->realtime, "Servo thread scheduling: off | warn | enforce (SCHED_FIFO + mlockall)")
      ->capture_default_str();
  cmd->add_option("--script", o->script,
                  "Scripted actions for tests and demos, \"FRAME ACTION ARGS; ...\": finer, coarser, level N, pan DX DY "
                  "(window widths), centre X_M Y_M, window LEVEL COL0 ROW0, stiffness N_PER_M, texture on|off, mu_s V, "
                  "model paper|curvature, rescan AX AY AZ "
                  "(deg, R = Rx*Ry*Rz), stereo on|off, display colour|grey|texture|mu_d|error; each goes through the same path as the keys and the panel. "
                  "FRAME may be a time, '12.5s'. @FILE reads the steps from FILE (one per line or ';'-separated)");
  cmd->add_flag("--stereo", o->stereo, "Start in red/cyan anaglyph stereo");
  CLI::Option* udp_timeout = cmd->add_option("--udp-timeout", o->udp_timeout_s,
                  "--device udp: silence [s] after which the device faults (zero force until reset), (0, 10]")
      ->capture_default_str()
      ->check(finite_in(0.0, 10.0, true));
  cmd->add_flag("--show-regions", o->show_regions, "Start with the audio regions' outlines drawn (key A toggles them)");
  cmd->add_option("--display", o->display,
                  "Starting colours of the window and the navigation view: colour | grey | texture | mu_d | error. "
                  "colour: the scan's own (grey when the scene has none); grey: shaded grey; texture, mu_d, error: "
                  "a layer map of texture h, mu_d or the cross-check error through the colour map (range in the "
                  "panel). Keys C and L switch it")
      ->capture_default_str();
  cmd->add_flag("--hidden", o->hidden, "Do not show the window (with --screenshot or --seconds)");
  cmd->add_flag("--no-audio", o->no_audio, "No contact sounds");
#ifdef HC_HAVE_VIEWER
  std::string controls = "Controls in the window (H shows them):\n";
  for (const std::string& line : viewer::controls_help()) controls += "  " + line + "\n";
  cmd->footer(controls);
#endif
  cmd->callback([o, udp_timeout] {
    if (udp_timeout->count() > 0 && o->device.rfind("udp:", 0) != 0) {
      throw ConfigError("explore: --udp-timeout applies to --device udp:HOST:PORT only (the device is '" + o->device + "')");
    }
    run_explore(*o);
  });
}

}  // namespace hc::app
