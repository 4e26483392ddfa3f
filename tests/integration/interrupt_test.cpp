// Issue 15: SIGTERM (or Ctrl-C) while `hapticloud run` writes its output leaves no
// `<out>.partial-<pid>` behind, and stale ones of dead processes are removed by the next run.
// Issue 14: nor does it leave a tiled run's spill folder in scale.scratch, a tile plan's spill
// files, or a tile job's temporary files. Nor does the scan generator hc-gen-relief leave its
// half-written `.part-*` temporary.

#include <gtest/gtest.h>

#include "test_paths.hpp"

#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <thread>
#include <vector>

extern char** environ;

namespace {

namespace fs = std::filesystem;

bool has_partial(const fs::path& dir) {
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().filename().string().find(".partial-") != std::string::npos) return true;
  }
  return false;
}

// Starts `program` (default the app) with `args` (after the program name); its pid, or -1 when
// it cannot start.
pid_t spawn_app(const std::vector<std::string>& args, const char* program = HC_APP) {
  std::vector<std::string> all = {program};
  all.insert(all.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : all) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid = 0;
  return posix_spawn(&pid, program, nullptr, nullptr, argv.data(), environ) == 0 ? pid : -1;
}

// Starts the app with `args` (after the program name), waits until `seen()` (polling), sends
// `signo` and returns the exit status (waitpid's). A failed assertion when the run ends, or
// takes over 300 s, before seen(): `what` names what never appeared.
template <class Seen>
void interrupt_when(const std::vector<std::string>& args, Seen&& seen, int signo, const std::string& what, int& status) {
  const pid_t pid = spawn_app(args);
  ASSERT_GT(pid, 0) << "cannot start " << HC_APP;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(300);
  bool appeared = false;
  while (!appeared && std::chrono::steady_clock::now() < deadline) {
    if (waitpid(pid, &status, WNOHANG) == pid) break;  // finished before we saw it
    appeared = seen();
    if (!appeared) std::this_thread::sleep_for(std::chrono::microseconds(500));
  }
  ASSERT_TRUE(appeared) << what << " never appeared (the run ended or took over 300 s)";
  ASSERT_EQ(kill(pid, signo), 0);
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
}

// Runs the app with `args` to its end; returns its exit status (waitpid's).
int run_app(const std::vector<std::string>& args) {
  const pid_t pid = spawn_app(args);
  if (pid <= 0) return -1;
  int status = 0;
  return waitpid(pid, &status, 0) == pid ? status : -1;
}

// The entries of `dir` whose names start with `prefix` or contain `infix` (empty: not tested).
std::vector<std::string> entries_like(const fs::path& dir, const std::string& prefix, const std::string& infix = "") {
  std::vector<std::string> found;
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string n = it->path().filename().string();
    if ((!prefix.empty() && n.rfind(prefix, 0) == 0) || (!infix.empty() && n.find(infix) != std::string::npos)) found.push_back(n);
  }
  return found;
}

TEST(Interrupt, SigtermDuringTheWriteRemovesTheStagingFolder) {
  const fs::path dir = hc::test::temp_dir("sigterm");
  const std::string config = (fs::path(HC_SOURCE_DIR) / "configs" / "happy_buddha.yaml").string();
  const std::string out = (dir / "out").string();
  // N = 1600 with the levels table: the write stage (scene, previews, levels) lasts long enough
  // to be caught by polling; the folder only exists during it.
  int status = 0;
  interrupt_when({"run", config, "--out", out, "-q", "--set", "grid.n=1600", "--set", "lod.report=true"},
                 [&] { return has_partial(dir); }, SIGTERM, "the run's staging folder", status);
  if (HasFatalFailure()) return;
  ASSERT_TRUE(WIFEXITED(status)) << "killed by signal " << (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
  EXPECT_EQ(WEXITSTATUS(status), 128 + SIGTERM);
  EXPECT_FALSE(has_partial(dir));
  EXPECT_FALSE(fs::exists(dir / "out"));
}

// The spill folder (`hapticloud-tiles-*` in scale.scratch) holds the tiled run's spill files
// while it runs; SIGINT in the tile loop removes it with everything in it.
TEST(Interrupt, SigintDuringATiledRunRemovesTheSpillFolder) {
  const fs::path dir = hc::test::temp_dir("sigint-tiled");
  const fs::path scratch = dir / "scratch";
  fs::create_directories(scratch);
  const std::string config = (fs::path(HC_SOURCE_DIR) / "configs" / "happy_buddha.yaml").string();
  const std::string out = (dir / "out").string();
  // A spill file of a tile past the first in the spill folder: the tile loop is under way.
  const auto spilling = [&] {
    std::error_code ec;
    for (const auto& d : fs::directory_iterator(scratch, ec)) {
      if (fs::exists(d.path() / "kept_1.bin", ec)) return true;
    }
    return false;
  };
  int status = 0;
  interrupt_when({"run", config, "--out", out, "-q", "--set", "scale.tiled=on", "--set", "scale.tile_cells=64", "--set",
                  "scale.scratch=" + scratch.string()},
                 spilling, SIGINT, "the tile loop's files in " + scratch.string(), status);
  if (HasFatalFailure()) return;
  ASSERT_TRUE(WIFEXITED(status)) << "killed by signal " << (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
  EXPECT_EQ(WEXITSTATUS(status), 128 + SIGINT);
  EXPECT_TRUE(fs::is_empty(scratch)) << "left in the scratch folder: " << fs::directory_iterator(scratch)->path();
  EXPECT_FALSE(fs::exists(dir / "out"));
}

// `hapticloud tile-plan` into a folder that existed (empty, the user's): SIGINT while it spills
// removes the spill files it wrote, and keeps the folder.
TEST(Interrupt, SigintDuringATilePlanRemovesItsSpillFilesAndKeepsTheFolder) {
  const fs::path dir = hc::test::temp_dir("sigint-plan");
  const fs::path work = dir / "work";
  fs::create_directories(work);
  const std::string config = (fs::path(HC_SOURCE_DIR) / "configs" / "happy_buddha.yaml").string();
  int status = 0;
  interrupt_when({"tile-plan", config, "--work", work.string(), "-q", "--set", "scale.tile_cells=64"},
                 [&] { return !entries_like(work, "tile_").empty() && !fs::exists(work / "plan.json"); }, SIGINT,
                 "a spill file in " + work.string() + " before plan.json", status);
  if (HasFatalFailure()) return;
  ASSERT_TRUE(WIFEXITED(status)) << "killed by signal " << (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
  EXPECT_EQ(WEXITSTATUS(status), 128 + SIGINT);
  ASSERT_TRUE(fs::is_directory(work)) << "the user's folder went";
  EXPECT_TRUE(fs::is_empty(work)) << "left in the work folder: " << fs::directory_iterator(work)->path();
}

// `hapticloud tile-job` over every tile of a plan: SIGINT once its band's second sweep has
// finished a tile (the first `part_*` file; a temporary kept file lives only between a tile's
// mask and its rename, too briefly to wait for) removes every temporary it registered, and
// leaves the plan's files as they were, so the job can run again.
TEST(Interrupt, SigintDuringATileJobRemovesItsScratchAndKeepsThePlan) {
  const fs::path dir = hc::test::temp_dir("sigint-job");
  const fs::path work = dir / "work";
  const std::string config = (fs::path(HC_SOURCE_DIR) / "configs" / "happy_buddha.yaml").string();
  const int planned = run_app({"tile-plan", config, "--work", work.string(), "-q", "--set", "scale.tile_cells=64"});
  ASSERT_TRUE(WIFEXITED(planned) && WEXITSTATUS(planned) == 0) << "tile-plan failed: status " << planned;
  std::map<std::string, std::uintmax_t> plan_files;  // name -> size
  for (const auto& e : fs::directory_iterator(work)) plan_files[e.path().filename().string()] = fs::file_size(e.path());
  const std::size_t tiles = entries_like(work, "tile_").size();
  ASSERT_GT(tiles, 4U);
  std::string all;
  for (std::size_t t = 0; t < tiles; ++t) all += (t ? "," : "") + std::to_string(t);
  int status = 0;
  interrupt_when({"tile-job", (work / "plan.json").string(), "--tiles", all, "-q"},
                 [&] { return !entries_like(work, "part_").empty(); }, SIGINT, "a part_* file in " + work.string(),
                 status);
  if (HasFatalFailure()) return;
  ASSERT_TRUE(WIFEXITED(status)) << "killed by signal " << (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
  EXPECT_EQ(WEXITSTATUS(status), 128 + SIGINT);
  EXPECT_TRUE(entries_like(work, ".blocks-").empty()) << "a block copies' folder (builds before 2026-11-27)";
  EXPECT_TRUE(entries_like(work, ".kept-job-").empty()) << "a temporary kept file was left";
  EXPECT_TRUE(entries_like(work, "", ".tmp-").empty()) << "a part file's temporary was left";
  for (const auto& [name, size] : plan_files) {
    std::error_code ec;
    EXPECT_EQ(fs::file_size(work / name, ec), size) << name << (ec ? " is gone" : " changed");
  }
  // What is left besides the plan is finished tiles' results only: a part file and its mask.
  for (const auto& e : fs::directory_iterator(work)) {
    const std::string n = e.path().filename().string();
    if (plan_files.count(n)) continue;
    EXPECT_TRUE(n.rfind("part_", 0) == 0 || n.rfind("kept_", 0) == 0) << "left: " << n;
  }
}

// hc-gen-relief stopped by SIGTERM, SIGINT or SIGHUP while it writes: its exclusive temporary
// (`<out>.part-*`, already holding points) is removed, no output appears, and the exit status is
// 128 + the signal. 2 × 10^7 points on one thread in small chunks take seconds, so the signal
// comes mid-write.
TEST(Interrupt, TheGeneratorStoppedMidWriteLeavesNoTemporary) {
  for (const int signo : {SIGTERM, SIGINT, SIGHUP}) {
    SCOPED_TRACE(signo);
    const fs::path dir = hc::test::temp_dir("interrupt_gen_relief_" + std::to_string(signo));
    const fs::path out = dir / "wall.ply";
    const auto part_with_points = [&] {
      for (const auto& e : fs::directory_iterator(dir)) {
        std::error_code ec;
        if (e.path().filename().string().rfind("wall.ply.part-", 0) == 0 && fs::file_size(e.path(), ec) > 4096) return true;
      }
      return false;
    };
    const pid_t pid = spawn_app({out.string(), "--points", "2e7", "--threads", "1", "--chunk", "2000", "--quiet"}, HC_GEN_RELIEF);
    ASSERT_GT(pid, 0) << "cannot start " << HC_GEN_RELIEF;
    int status = 0;
    bool seen = false, ended = false;
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
    while (!seen && std::chrono::steady_clock::now() < deadline) {
      if (waitpid(pid, &status, WNOHANG) == pid) {
        ended = true;
        break;
      }
      seen = part_with_points();
      if (!seen) std::this_thread::sleep_for(std::chrono::microseconds(500));
    }
    if (!ended) {
      ASSERT_TRUE(seen) << "no temporary with points appeared in 120 s";
      ASSERT_EQ(kill(pid, signo), 0);
      ASSERT_EQ(waitpid(pid, &status, 0), pid);
    }
    ASSERT_FALSE(ended) << "the generator ended before its temporary held points";
    ASSERT_TRUE(WIFEXITED(status)) << "ended by the signal's default action (status " << status << ")";
    EXPECT_EQ(WEXITSTATUS(status), 128 + signo);
    EXPECT_TRUE(fs::is_empty(dir)) << "left behind: " << fs::directory_iterator(dir)->path();
  }
}

}  // namespace
