// `hapticloud touch`'s output is staged like run's (issue 15): a failed session leaves nothing,
// a foreign --out is refused and left untouched (kept aside with --force), a rerun replaces the
// earlier output whole; bad numbers stop before anything is written, naming the option.

#include <gtest/gtest.h>

#include "app_runner.hpp"
#include "test_paths.hpp"

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>

namespace {

namespace fs = std::filesystem;
using hc::test::run_app;

/// Names in `dir` (not recursive).
std::set<std::string> entries(const fs::path& dir) {
  std::set<std::string> out;
  for (const auto& e : fs::directory_iterator(dir)) out.insert(e.path().filename().string());
  return out;
}

std::string read_text(const fs::path& file) {
  std::ifstream in(file);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

TEST(TouchOutput, AFailedSessionLeavesNothingNotEvenThePipelineFolder) {
  // The config's scene is built and its run folder written (into the staging folder) before
  // the session finds that level 9 does not exist.
  const fs::path dir = hc::test::temp_dir("failed");
  {
    std::ofstream cfg(dir / "sin.yaml");
    cfg << "input: {synthetic: {surface: sinusoid, half_extent_m: 0.02, density_per_m2: 2.0e7, wavelength_m: 0.008}}\n"
           "filters: {outliers: {enabled: false}}\n"
           "grid: {n: 80, splat_radius_cells: 1.0}\n"
           "lod: {report: false}\n";
  }
  std::string log;
  EXPECT_EQ(run_app("touch " + (dir / "sin.yaml").string() + " --seconds 1 --level 9 --out " + (dir / "out").string(),
                    &log),
            1)
      << log;
  EXPECT_NE(log.find("--level 9"), std::string::npos) << log;
  EXPECT_EQ(entries(dir), std::set<std::string>{"sin.yaml"}) << log;  // no out, no out.partial-*
}

TEST(TouchOutput, AForeignFolderIsRefusedAndUntouchedAndKeptAsideWithForce) {
  const fs::path dir = hc::test::temp_dir("foreign");
  const fs::path out = dir / "mine";
  fs::create_directories(out);
  std::ofstream(out / "notes.txt") << "my notes\n";
  std::string log;
  EXPECT_EQ(run_app("touch --synthetic sinusoid --cells 101 --seconds 1 --out " + out.string(), &log), 1) << log;
  EXPECT_NE(log.find("--force"), std::string::npos) << log;
  EXPECT_EQ(entries(out), std::set<std::string>{"notes.txt"});
  EXPECT_EQ(read_text(out / "notes.txt"), "my notes\n");
  EXPECT_EQ(entries(dir), std::set<std::string>{"mine"});

  // A regular file as --out: refused, untouched.
  std::ofstream(dir / "a_file") << "keep\n";
  log.clear();
  EXPECT_EQ(run_app("touch --synthetic sinusoid --cells 101 --seconds 1 --out " + (dir / "a_file").string(), &log), 1)
      << log;
  EXPECT_EQ(read_text(dir / "a_file"), "keep\n");

  // --force: the session is written and the folder is kept beside it, whole.
  log.clear();
  ASSERT_EQ(run_app("touch --synthetic sinusoid --cells 101 --seconds 1 --force --out " + out.string(), &log), 0)
      << log;
  EXPECT_TRUE(fs::exists(out / "summary.json"));
  EXPECT_FALSE(fs::exists(out / "notes.txt"));
  int kept = 0;
  for (const std::string& name : entries(dir)) {
    if (name.rfind("mine.replaced-", 0) != 0) continue;
    ++kept;
    EXPECT_EQ(read_text(dir / name / "notes.txt"), "my notes\n");
  }
  EXPECT_EQ(kept, 1) << log;
}

TEST(TouchOutput, ARerunReplacesTheEarlierOutputWhole) {
  const fs::path dir = hc::test::temp_dir("rerun");
  const fs::path out = dir / "touch";
  std::string log;
  ASSERT_EQ(run_app("touch --synthetic sinusoid --cells 101 --seconds 1 --validate --out " + out.string(), &log), 0)
      << log;
  EXPECT_TRUE(fs::exists(out / "with_texture_friction" / "summary.json"));
  EXPECT_TRUE(fs::exists(out / "report.md"));
  log.clear();
  ASSERT_EQ(run_app("touch --synthetic sinusoid --cells 101 --seconds 1 --path line --out " + out.string(), &log), 0)
      << log;
  // Only the second session's files: nothing of the validation is mixed in.
  std::set<std::string> names = entries(out);
  names.erase(".hapticloud-output");
  EXPECT_EQ(names, (std::set<std::string>{"trace.csv", "events.csv", "summary.json", "proxy_z.png", "force.png"}));
  EXPECT_NE(read_text(out / "summary.json").find("\"line\""), std::string::npos);
  EXPECT_EQ(entries(dir), std::set<std::string>{"touch"});  // no .old-* or .partial-* left
}

TEST(TouchOutput, BadNumbersStopBeforeAnythingIsWrittenNamingTheOption) {
  const fs::path dir = hc::test::temp_dir("numbers");
  const fs::path out = dir / "out";
  for (const std::string bad : {"--rate -5", "--rate 0", "--seconds nan", "--seconds 4000", "--stiffness -1",
                                 "--max-force nan", "--rho 0", "--press -0.01", "--speed 0", "--mu-d -1",
                                 "--mu-s -0.5", "--texture-gain -2", "--cells 1"}) {
    std::string log;
    const std::string seconds = bad.rfind("--seconds", 0) == 0 ? "" : "--seconds 1 ";
    EXPECT_EQ(run_app("touch --synthetic sinusoid " + seconds + bad + " --out " + out.string(), &log), 1)
        << bad << "\n" << log;
    EXPECT_NE(log.find(bad), std::string::npos) << bad << "\n" << log;
    EXPECT_EQ(log.find("internal error"), std::string::npos) << log;
    EXPECT_TRUE(entries(dir).empty()) << bad;
  }
}

TEST(FalconCheckOptions, BadSecondsAreRejectedNamingTheOption) {
  std::string help;
  run_app("--help", &help);
  if (help.find("falcon-check") == std::string::npos) GTEST_SKIP() << "this build has no Falcon support";
  for (const std::string bad : {"--home-timeout -1", "--floor-seconds nan", "--home-timeout 0"}) {
    std::string log;
    // --emulate: no hardware is needed, and the check fails before the emulator is opened.
    EXPECT_EQ(run_app("falcon-check --emulate " + bad, &log), 1) << bad << "\n" << log;
    EXPECT_NE(log.find(bad), std::string::npos) << bad << "\n" << log;
  }
}

}  // namespace
