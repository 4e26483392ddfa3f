// `hapticloud explore` end to end under Xvfb: a simulated device on its scripted path, the servo
// loop on its own thread, the viewer drawing, a re-scan swapping the scene mid-session.

#include "app_runner.hpp"
#include "test_paths.hpp"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sys/wait.h>
#include <string>
#include <vector>

namespace hc {
namespace {

namespace fs = std::filesystem;

struct Result {
  int status = -1;
  std::string output;
};

Result run_app(const std::string& args) {
  Result r;
  r.status = test::run_app(args, &r.output);
  return r;
}

using test::read_json;

/// Servo statistics of a session with the viewer drawing: the loop's own counters. Functional
/// checks only: the loop ran, the viewer drew, nothing was lost or rejected. How many ticks and
/// frames fit in the session's wall-clock seconds, and how many deadlines the loop missed
/// (overruns), measure the machine's load and scheduling, not the code: they are reported,
/// never asserted (issue 15: "overruns 5 vs 3" failed on a loaded machine, and "frames > 2" in
/// 3 s fails when Mesa's software renderer shares 2 cores with compilers). Timing is
/// benchmarked in bench/, not tested.
void expect_servo_unharmed(const nlohmann::json& s) {
  EXPECT_GT(s["ticks"].get<long>(), 0);
  EXPECT_GT(s["frames"].get<long>(), 0);
  EXPECT_EQ(s["device_errors"].get<long>(), 0);
  EXPECT_EQ(s["commands_rejected"].get<long>(), 0);
  EXPECT_EQ(s["events_dropped"].get<long>(), 0);
  ASSERT_TRUE(s.contains("overruns")) << s.dump();  // the counter is reported ...
  ASSERT_TRUE(s.contains("fifo_granted")) << s.dump();
  const long overruns = s["overruns"].get<long>();  // a count: never asserted (a loaded machine overruns)
  // ... in the test's XML/console output, for whoever studies timing, not as a pass criterion.
  ::testing::Test::RecordProperty("servo_ticks", std::to_string(s["ticks"].get<long>()));
  ::testing::Test::RecordProperty("viewer_frames", std::to_string(s["frames"].get<long>()));
  ::testing::Test::RecordProperty("servo_overruns", std::to_string(overruns));
  ::testing::Test::RecordProperty("sched_fifo", s["fifo_granted"].get<bool>() ? "granted" : "not granted");
}

TEST(ExploreSession, SimulatedDeviceWithTheViewerRunsTheServoLoop) {
  const fs::path dir = test::temp_dir("sim");
  const fs::path config = fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml";
  const Result r = run_app("explore " + config.string() + " --device sim --seconds 3 --hidden --out " +
                           (dir / "out").string() + " --summary " + (dir / "summary.json").string() +
                           " --screenshot " + (dir / "last.png").string());
  ASSERT_EQ(r.status, 0) << r.output;
  const nlohmann::json s = read_json(dir / "summary.json");
  expect_servo_unharmed(s);
  EXPECT_GE(s["surfaces_adopted"].get<long>(), 1);
  EXPECT_GT(s["mesh_quads"].get<long>(), 10000);
  EXPECT_GT(fs::file_size(dir / "last.png"), 10000U);
}

TEST(ExploreSession, RescanReplacesTheSceneWithoutRestartAndWithZeroForce) {
  const fs::path dir = test::temp_dir("rescan");
  const fs::path config = fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml";
  const Result r = run_app("explore " + config.string() + " --device sim --seconds 2 --hidden --out " +
                           (dir / "out").string() + " --summary " + (dir / "summary.json").string() +
                           " --script '2 rescan 0 25 0'");
  ASSERT_EQ(r.status, 0) << r.output;
  const nlohmann::json s = read_json(dir / "summary.json");
  expect_servo_unharmed(s);
  EXPECT_EQ(s["rescans"].get<int>(), 1);
  EXPECT_EQ(s["swaps"].get<int>(), 1) << s["status"];
  // First scene, then the re-scanned one: two surfaces adopted by the one servo loop.
  EXPECT_GE(s["surfaces_adopted"].get<long>(), 2);
  // Disarm, publish, wait for adoption, re-arm: never armed in between, no force sent.
  EXPECT_FALSE(s["swap_seen_armed"].get<bool>());
  EXPECT_EQ(s["swap_max_device_force_n"].get<double>(), 0.0);
  EXPECT_TRUE(fs::exists(dir / "out" / "scan-1" / "scene" / "scene.yaml"));
  // The session's pyramid builds levels on demand: the pipeline runs (first scan and re-scan)
  // build no levels table for their reports.
  for (const char* scan : {"scan-0", "scan-1"}) {
    std::ifstream in(dir / "out" / scan / "report.md");
    ASSERT_TRUE(in) << scan;
    const std::string report((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_EQ(report.find("## Levels of detail"), std::string::npos) << scan;
  }
}

TEST(ExploreSession, InterruptEndsTheSessionCleanly) {
  const fs::path dir = test::temp_dir("sigint");
  const fs::path config = fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml";
  const fs::path out = dir / "out";
  const fs::path summary = dir / "summary.json";
  // No frame or time limit (--seconds 600 only bounds a broken build): the session runs until
  // SIGINT, sent once its first scene exists (the handler is installed before it is built).
  // Without audio nothing but the session drains the contact events.
  // Under ASan the leak check runs at its exit too (the tracer crash seen here on 2026-11-21 was
  // the __tls_get_addr interceptor's: scripts/test turns it off, docs/ci.md).
  const std::string script = std::string(HC_APP) + " explore '" + config.string() +
                             "' --device sim --seconds 600 --hidden --no-audio --out '" + out.string() +
                             "' --summary '" + summary.string() + "' & pid=$!; " +
                             "while kill -0 $pid 2>/dev/null && [ ! -f '" + (out / "scan-0" / "scene" / "scene.yaml").string() +
                             "' ]; do sleep 0.2; done; sleep 2; kill -INT $pid; wait $pid";
  std::string output;
  std::FILE* p = popen(("{ " + script + "; } 2>&1").c_str(), "r");
  ASSERT_NE(p, nullptr);
  char buf[4096];
  while (std::fgets(buf, sizeof buf, p)) output += buf;
  const int raw = pclose(p);
  ASSERT_TRUE(WIFEXITED(raw)) << output;
  ASSERT_EQ(WEXITSTATUS(raw), 0) << output;
  EXPECT_NE(output.find("stop requested"), std::string::npos) << output;
  const nlohmann::json s = read_json(summary);
  EXPECT_TRUE(s["stopped_by_signal"].get<bool>());
  EXPECT_EQ(s["device_errors"].get<long>(), 0);
  EXPECT_EQ(s["events_dropped"].get<long>(), 0);
  EXPECT_GE(s["surfaces_adopted"].get<long>(), 1);
}

TEST(ExploreSession, LevelRegionAndSurfaceCommandsReachTheServoLoop) {
  const fs::path dir = test::temp_dir("script");
  const fs::path config = fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml";
  // The sinusoid's 200-sample grid with 64-sample windows: levels 0 and 1, starting at 1. The
  // steps come from a file (--script @FILE, one step per line), as the soak benchmark passes them.
  const fs::path script = dir / "steps.script";
  {
    std::ofstream f(script);
    f << "3 finer\n6 pan 0.25 0\n9 texture off\n12 mu_s 0.5\n16 model curvature\n20 coarser\n";
  }
  const Result r = run_app("explore " + config.string() + " --device sim --frames 30 --hidden --no-audio --out " +
                           (dir / "out").string() + " --window-cells 64 --summary " + (dir / "summary.json").string() +
                           " --script @" + script.string());
  ASSERT_EQ(r.status, 0) << r.output;
  const nlohmann::json s = read_json(dir / "summary.json");
  expect_servo_unharmed(s);
  EXPECT_EQ(s["script_steps"].get<int>(), 6);
  EXPECT_EQ(s["script_steps_run"].get<int>(), 6);
  // Surface accounting at the end of the session: everything published but the current, the
  // pending and the retire ring (2 + 8) has been freed.
  EXPECT_GE(s["surfaces_published"].get<long>(), 7);
  EXPECT_LE(s["surfaces_published"].get<long>() - s["surfaces_freed"].get<long>(), 10);
  EXPECT_EQ(s["level_count"].get<int>(), 2);
  EXPECT_EQ(s["level"].get<int>(), 1);
  EXPECT_FALSE(s["texture"].get<bool>());
  EXPECT_DOUBLE_EQ(s["mu_s"].get<double>(), 0.5);
  EXPECT_EQ(s["friction_model"].get<std::string>(), "curvature");
  // Every step published a new surface: the first window, finer, pan, texture off, μ_s,
  // friction model, coarser. The servo adopts the newest one at a tick boundary, and may also
  // adopt a republished one (a rebuild finishing), so at least these seven.
  EXPECT_GE(s["surfaces_adopted"].get<long>(), 7);
  // The window the session ended on: level 1 (100 x 100 samples), a 64-sample window inside it.
  ASSERT_TRUE(s.contains("window")) << s.dump();
  EXPECT_EQ(s["window"]["cols"].get<int>(), 64);
  EXPECT_EQ(s["window"]["rows"].get<int>(), 64);
  EXPECT_GE(s["window"]["col0"].get<int>(), 0);
  EXPECT_LE(s["window"]["col0"].get<int>(), 100 - 64);
  EXPECT_GE(s["window"]["row0"].get<int>(), 0);
  EXPECT_LE(s["window"]["row0"].get<int>(), 100 - 64);
  EXPECT_EQ(s["swaps"].get<int>(), 0);  // none of these disarms the device
}

/// The lines of `file` that start with `prefix`.
std::vector<std::string> lines_starting(const fs::path& file, const std::string& prefix) {
  std::ifstream in(file);
  std::vector<std::string> out;
  for (std::string l; std::getline(in, l);)
    if (l.rfind(prefix, 0) == 0) out.push_back(l);
  return out;
}

/// "@session,TICK,ACTION" → ACTION.
std::string action_of(const std::string& line) { return line.substr(line.find(',', 9) + 1); }

// explore --record writes the session's actions (the windows they led to, surface settings)
// with their servo ticks, besides the servo's commands and surface switches; --device
// replay:FILE plays the positions back and re-issues the actions when the servo reaches their
// ticks, so the replayed session ends in the same window with the same settings.
TEST(ExploreSession, ARecordingHoldsTheSessionsActionsAndAReplayRepeatsThem) {
  const fs::path dir = test::temp_dir("explore_record");
  const fs::path config = fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml";
  const std::string common = "explore " + config.string() + " --hidden --no-audio --window-cells 64 --frames 40 ";
  Result r = run_app(common + "--device sim --out " + (dir / "a").string() + " --record " + (dir / "a.csv").string() +
                     " --summary " + (dir / "a.json").string() + " --script '3 finer; 6 pan 0.25 0; 9 texture off; 12 mu_s 0.5; 14 stiffness 512.5'");
  ASSERT_EQ(r.status, 0) << r.output;
  const std::vector<std::string> sa = lines_starting(dir / "a.csv", "@session,");
  ASSERT_EQ(sa.size(), 5u) << r.output;
  EXPECT_EQ(sa[0].rfind("@session,0,window 1 ", 0), 0u) << sa[0];  // the first window, level 1 of 0..1
  EXPECT_EQ(action_of(sa[1]).rfind("window 0 ", 0), 0u) << sa[1];  // finer: level 1 → 0
  EXPECT_EQ(action_of(sa[2]).rfind("window 0 ", 0), 0u) << sa[2];
  EXPECT_NE(action_of(sa[1]), action_of(sa[2])) << "the pan moved the window";
  EXPECT_EQ(action_of(sa[3]), "texture off");
  EXPECT_EQ(action_of(sa[4]), "mu_s 0.5");
  EXPECT_FALSE(lines_starting(dir / "a.csv", "@surface,").empty());
  EXPECT_FALSE(lines_starting(dir / "a.csv", "@command,").empty());
  EXPECT_NE(lines_starting(dir / "a.csv", "# device:").at(0).find("servo_rate_hz: 1000"), std::string::npos);

  r = run_app(common + "--device replay:" + (dir / "a.csv").string() + " --out " + (dir / "b").string() + " --record " +
              (dir / "b.csv").string() + " --summary " + (dir / "b.json").string());
  ASSERT_EQ(r.status, 0) << r.output;
  const std::vector<std::string> sb = lines_starting(dir / "b.csv", "@session,");
  ASSERT_EQ(sb.size(), sa.size()) << r.output;
  const auto tick_of = [](const std::string& l) { return std::stoull(l.substr(9, l.find(',', 9) - 9)); };
  for (std::size_t i = 0; i < sa.size(); ++i) {
    EXPECT_EQ(action_of(sb[i]), action_of(sa[i]));
    // Re-issued once the servo reached the recorded tick, never before it.
    EXPECT_GE(tick_of(sb[i]), tick_of(sa[i])) << sa[i] << " replayed as " << sb[i];
  }
  EXPECT_EQ(sb[0], sa[0]) << "the replay starts in the recorded first window, at tick 0";
  // A recording whose action is not one: an error naming the file, the tick and the action.
  {
    std::ifstream in(dir / "a.csv");
    std::ofstream bad(dir / "bad.csv");
    for (std::string l; std::getline(in, l);) bad << l << "\n";
    bad << "@session,5,teleport 1 2\n";
  }
  r = run_app(common + "--device replay:" + (dir / "bad.csv").string() + " --out " + (dir / "c").string());
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.output.find("bad.csv: @session at tick 5 'teleport 1 2'"), std::string::npos) << r.output;
  // The panel's servo setting is re-sent: the replay's servo applied it too.
  const auto stiffness = [](const fs::path& f) {
    std::vector<std::string> out;
    for (const std::string& l : lines_starting(f, "@command,"))
      if (l.find(",set_stiffness,") != std::string::npos) out.push_back(l.substr(l.find(",set_stiffness,")));
    return out;
  };
  ASSERT_EQ(stiffness(dir / "a.csv").size(), 1u);
  EXPECT_EQ(stiffness(dir / "a.csv").at(0), ",set_stiffness,512.5,0,0,0,0");
  EXPECT_EQ(stiffness(dir / "b.csv"), stiffness(dir / "a.csv"));
  const nlohmann::json ja = read_json(dir / "a.json"), jb = read_json(dir / "b.json");
  EXPECT_EQ(jb["window"], ja["window"]);
  EXPECT_EQ(jb["level"], ja["level"]);
  EXPECT_EQ(jb["texture"], ja["texture"]);
  EXPECT_EQ(jb["mu_s"], ja["mu_s"]);
  // The same positions, tick by tick, as long as the recording lasts (the replay device reads
  // them from the file: this checks the recorder and the replay's tick count, not the servo).
  std::vector<std::string> pa = lines_starting(dir / "a.csv", ""), pb = lines_starting(dir / "b.csv", "");
  const auto positions = [](const std::vector<std::string>& lines) {
    std::vector<std::string> out;
    for (const std::string& l : lines) {
      if (l.empty() || !std::isdigit(static_cast<unsigned char>(l[0]))) continue;
      const std::size_t c1 = l.find(','), c2 = l.find(',', c1 + 1);
      std::size_t c5 = c2;
      for (int k = 0; k < 3; ++k) c5 = l.find(',', c5 + 1);
      out.push_back(l.substr(c2 + 1, c5 - c2 - 1));  // x,y,z as written
    }
    return out;
  };
  const std::vector<std::string> xa = positions(pa), xb = positions(pb);
  ASSERT_GT(xa.size(), 100u);
  ASSERT_GE(xb.size(), xa.size());
  for (std::size_t k = 0; k < xa.size(); ++k) ASSERT_EQ(xb[k], xa[k]) << "tick " << k;
}

// --device udp: the session says which port it listens on (0 = any free one) and, at the
// end, the bridge's counters; the watchdog's time is an option, checked.
TEST(ExploreSession, TheUdpBridgeNamesItsPortAndCounters) {
  const fs::path dir = test::temp_dir("udp");
  const fs::path config = fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml";
  Result r = run_app("explore " + config.string() + " --hidden --no-audio --frames 3 --device udp:127.0.0.1:0 "
                     "--udp-timeout 0.25 --out " + (dir / "out").string());
  ASSERT_EQ(r.status, 0) << r.output;
  const std::size_t at = r.output.find("waiting for poses on udp 127.0.0.1:");
  ASSERT_NE(at, std::string::npos) << r.output;
  const int port = std::atoi(r.output.c_str() + at + std::string("waiting for poses on udp 127.0.0.1:").size());
  EXPECT_GT(port, 0) << "the port the system chose, not 0";
  EXPECT_NE(r.output.find("(watchdog 0.25 s"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("udp: 0 poses dropped"), std::string::npos) << r.output;
  r = run_app("explore " + config.string() + " --hidden --no-audio --frames 3 --device udp:127.0.0.1:0 "
              "--udp-timeout 0 --out " + (dir / "out2").string());
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.output.find("--udp-timeout"), std::string::npos) << r.output;
  r = run_app("explore " + config.string() + " --hidden --no-audio --frames 3 --device sim --udp-timeout 0.5 --out " +
              (dir / "out3").string());
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.output.find("--udp-timeout applies to --device udp"), std::string::npos) << r.output;
}

TEST(ExploreSession, ScriptErrorsNameTheStep) {
  const fs::path config = fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml";
  const Result r = run_app("explore " + config.string() + " --device sim --hidden --out " +
                           test::temp_dir("badscript").string() + " --script '3 jump'");
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.output.find("'3 jump': unknown action"), std::string::npos) << r.output;
  // Timed steps ("0.5s") and frame steps do not mix; a time must be a number of seconds ≥ 0.
  const Result mixed = run_app("explore " + config.string() + " --device sim --hidden --out " +
                               test::temp_dir("badscript2").string() + " --script '3 finer; 1.5s coarser'");
  EXPECT_NE(mixed.status, 0);
  EXPECT_NE(mixed.output.find("not both"), std::string::npos) << mixed.output;
  const Result negative = run_app("explore " + config.string() + " --device sim --hidden --out " +
                                  test::temp_dir("badscript3").string() + " --script '-1s finer'");
  EXPECT_NE(negative.status, 0);
  EXPECT_NE(negative.output.find("seconds ≥ 0"), std::string::npos) << negative.output;
}

TEST(ExploreSession, BadWindowCellsNamesTheOption) {
  const fs::path config = fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml";
  const fs::path out = test::temp_dir("badcells") / "out";
  const Result r = run_app("explore " + config.string() + " --device sim --hidden --window-cells 1 --out " + out.string());
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.output.find("--window-cells 1:"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(out));  // nothing built
}

TEST(ExploreSession, SceneFolderWithTheMouseDeviceInStereo) {
  const fs::path dir = test::temp_dir("folder");
  const fs::path config = fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml";
  // The scene's own lod.* come with the folder: levels down to 30 samples (120, 60, 30).
  const Result built = run_app("run " + config.string() + " --out " + (dir / "run").string() +
                               " --set grid.n=120 --set lod.min_cells=30 --set lod.report=false");
  ASSERT_EQ(built.status, 0) << built.output;
  const Result r = run_app("explore " + (dir / "run" / "scene").string() +
                           " --device mouse --stereo --frames 20 --hidden --no-audio --summary " +
                           (dir / "summary.json").string() + " --screenshot " + (dir / "stereo.png").string());
  ASSERT_EQ(r.status, 0) << r.output;
  const nlohmann::json s = read_json(dir / "summary.json");
  EXPECT_EQ(s["frames"].get<long>(), 20);
  EXPECT_EQ(s["device"].get<std::string>(), "mouse");
  EXPECT_EQ(s["device_errors"].get<long>(), 0);
  EXPECT_GT(s["mesh_quads"].get<long>(), 119L * 119L * 9 / 10);  // the grid, less its few holes
  EXPECT_EQ(s["level_count"].get<int>(), 3);
  EXPECT_GT(fs::file_size(dir / "stereo.png"), 10000U);
}

TEST(ExploreSession, UnknownDeviceIsAnErrorNamingTheChoices) {
  const fs::path config = fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml";
  const Result r = run_app("explore " + config.string() + " --device joystick --hidden --out " +
                           test::temp_dir("bad").string());
  EXPECT_EQ(r.status != 0, true);
  EXPECT_NE(r.output.find("falcon, mouse, sim, replay:FILE or udp:HOST:PORT"), std::string::npos) << r.output;
  const Result u = run_app("explore " + config.string() + " --device udp:localhost --hidden --out " +
                           test::temp_dir("bad_udp").string());
  EXPECT_NE(u.status, 0);
  EXPECT_NE(u.output.find("expected HOST:PORT"), std::string::npos) << u.output;
}

TEST(ExploreSession, BadDisplayIsAnErrorNamingTheOptionAndTheChoices) {
  const fs::path config = fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml";
  const fs::path out = test::temp_dir("baddisplay") / "out";
  const Result r = run_app("explore " + config.string() + " --device sim --display purple --hidden --out " + out.string());
  EXPECT_EQ(r.status != 0, true);
  EXPECT_NE(r.output.find("--display 'purple' is unknown (expected colour, grey, texture, mu_d or error)"),
            std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(out / "scan-0")) << "checked before any scene is built";
  // --help lists the option and the keys.
  const Result help = run_app("explore --help");
  EXPECT_NE(help.output.find("--display"), std::string::npos) << help.output;
  EXPECT_NE(help.output.find("colour | grey | texture | mu_d | error"), std::string::npos) << help.output;
  EXPECT_NE(help.output.find("C            colours"), std::string::npos) << help.output;
}

TEST(ExploreSession, DisplayModesFromTheOptionAndTheScriptReachTheViewer) {
  // A scene folder with its cross-check error map and no colour: --display starts a mode, a
  // script step switches it (the summary records the viewer's mode and its note at the end).
  const fs::path config = fs::path(HC_SOURCE_DIR) / "configs" / "sinusoid.yaml";
  const fs::path dir = test::temp_dir("display");
  const Result built = run_app("run " + config.string() + " --out " + (dir / "run").string() +
                               " --set grid.n=120 --set lod.min_cells=30 --set lod.report=false");
  ASSERT_EQ(built.status, 0) << built.output;
  const std::string common = "explore " + (dir / "run" / "scene").string() +
                             " --device sim --hidden --no-audio --frames 3 --window-cells 64 --out " +
                             (dir / "out").string() + " --summary " + (dir / "summary.json").string() + " ";
  const Result a = run_app(common + "--display texture --script '2 display error' --screenshot " +
                           (dir / "error.png").string());
  ASSERT_EQ(a.status, 0) << a.output;
  nlohmann::json s = read_json(dir / "summary.json");
  EXPECT_EQ(s["display"].get<std::string>(), "error");
  EXPECT_EQ(s["display_note"].get<std::string>(), "") << "the scene's cell_error reached the viewer";
  EXPECT_GT(fs::file_size(dir / "error.png"), 10000U);
  // The default, colour, on a scene without colour: grey, and the note says so.
  const Result b = run_app(common);
  ASSERT_EQ(b.status, 0) << b.output;
  s = read_json(dir / "summary.json");
  EXPECT_EQ(s["display"].get<std::string>(), "colour");
  EXPECT_NE(s["display_note"].get<std::string>().find("no colour"), std::string::npos) << s.dump();
  const Result bad = run_app(common + "--script '1 display purple'");
  EXPECT_NE(bad.status, 0);
  EXPECT_NE(bad.output.find("display 'purple' is unknown"), std::string::npos) << bad.output;
}

}  // namespace
}  // namespace hc
