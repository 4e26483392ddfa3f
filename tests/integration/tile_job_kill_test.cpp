// Issue 14: a tile job killed outright (SIGKILL: a lost node, the OOM killer) cannot clean up,
// and leaves its scratch (a temporary kept file, block copies, a temporary result) in the plan's
// folder, hidden by their leading dot and up to gigabytes at 10^8 points. The merge that finds
// every tile's result removes that scratch and nothing else. The oracle is a real job, killed
// while it runs, and the folder listed before and after (with, beside what the kill left, a
// block-copy folder and a temporary result as a job killed at those moments leaves them).

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "test_paths.hpp"

#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <string>
#include <thread>
#include <vector>

extern char** environ;

namespace tile_job_kill_test {

namespace fs = std::filesystem;

pid_t spawn(std::vector<std::string> args) {
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid = 0;
  if (posix_spawn(&pid, HC_APP, nullptr, nullptr, argv.data(), environ) != 0) return -1;
  return pid;
}

// Exit status of the finished program, or -1 when it did not exit normally.
int run(const std::vector<std::string>& args) {
  const pid_t pid = spawn(args);
  int status = 0;
  if (pid <= 0 || waitpid(pid, &status, 0) != pid || !WIFEXITED(status)) return -1;
  return WEXITSTATUS(status);
}

std::set<std::string> entries(const fs::path& dir) {
  std::set<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.insert(e.path().filename().string());
  return names;
}

bool is_scratch(const std::string& name) {
  return name.rfind(".blocks-", 0) == 0 || name.rfind(".kept-job-", 0) == 0 || name.find(".tmp-") != std::string::npos;
}

TEST(TileJobKill, TheMergeRemovesWhatAKilledJobLeftAndNothingElse) {
  hc::test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz");
  const fs::path dir = hc::test::temp_dir("killed_job");
  const fs::path work = dir / "work";
  const std::string config = (fs::path(HC_SOURCE_DIR) / "configs" / "happy_buddha.yaml").string();
  ASSERT_EQ(run({HC_APP, "tile-plan", config, "--work", work.string(), "-q", "--set", "grid.n=400", "--set",
                 "scale.tile_cells=64", "--set", "lod.report=false"}),
            0);
  std::ifstream plan_in(work / "plan.json");
  const auto plan = nlohmann::json::parse(plan_in);
  const int tiles = plan["tiles"]["count"].get<int>();
  ASSERT_GT(tiles, 8);
  std::string all;
  for (int t = 0; t < tiles; ++t) all += (t ? "," : "") + std::to_string(t);

  // One job for every tile, killed once it is writing a tile's kept points (about 1.5 s in all).
  const pid_t pid = spawn({HC_APP, "tile-job", (work / "plan.json").string(), "--tiles", all, "-q"});
  ASSERT_GT(pid, 0);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(300);
  bool seen = false;
  int status = 0;
  while (!seen && std::chrono::steady_clock::now() < deadline) {
    if (waitpid(pid, &status, WNOHANG) == pid) break;  // finished before we saw it
    for (const std::string& n : entries(work)) seen = seen || n.rfind(".kept-job-", 0) == 0;
    if (!seen) std::this_thread::sleep_for(std::chrono::microseconds(200));
  }
  ASSERT_TRUE(seen) << "the job's temporary kept file never appeared (the job ended or took over 300 s)";
  ASSERT_EQ(kill(pid, SIGKILL), 0);
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFSIGNALED(status));

  std::set<std::string> left;
  for (const std::string& n : entries(work))
    if (is_scratch(n)) left.insert(n);
  ASSERT_FALSE(left.empty()) << "the killed job left nothing to remove";
  // The Buddha's jobs make no block copies, and a result is written in microseconds: what a job
  // killed at those moments leaves, named as docs/scale.md says a job names them.
  fs::create_directory(work / ".blocks-node7-4242-0123456789abcdef");
  std::ofstream(work / ".blocks-node7-4242-0123456789abcdef" / "blocks_3.bin") << std::string(1000, 'b');
  std::ofstream(work / ".part_3.bin.tmp-node7-4242-0123456789abcdef") << std::string(100, 'p');
  left.insert(".blocks-node7-4242-0123456789abcdef");
  left.insert(".part_3.bin.tmp-node7-4242-0123456789abcdef");
  std::uintmax_t left_bytes = 0;
  for (const std::string& n : left) {
    if (fs::is_directory(work / n)) {
      for (const auto& e : fs::recursive_directory_iterator(work / n))
        if (e.is_regular_file()) left_bytes += e.file_size();
    } else {
      left_bytes += fs::file_size(work / n);
    }
  }
  // What is the user's, even with a leading dot, stays; so does a folder named like scratch
  // inside a folder of the user's.
  std::ofstream(work / "notes.txt") << "mine";
  std::ofstream(work / ".hidden") << "mine";
  fs::create_directories(work / "mine" / ".blocks-x");

  ASSERT_EQ(run({HC_APP, "tile-job", (work / "plan.json").string(), "--tiles", all, "-q"}), 0);
  const fs::path out = dir / "run";
  ASSERT_EQ(run({HC_APP, "tile-merge", (work / "plan.json").string(), "--out", out.string(), "-q"}), 0);

  for (const std::string& n : entries(work)) EXPECT_FALSE(is_scratch(n)) << n << " is left in the plan's folder";
  EXPECT_TRUE(fs::exists(work / "notes.txt"));
  EXPECT_TRUE(fs::exists(work / ".hidden"));
  EXPECT_TRUE(fs::is_directory(work / "mine" / ".blocks-x"));
  // The report says what went: every entry the kill left (the rerun's own scratch was gone).
  std::ifstream report_in(out / "report.json");
  const auto report = nlohmann::json::parse(report_in);
  bool reported = false;
  for (const auto& s : report["stages"]) {
    if (s["stage"] != "tiles" || !s.contains("figures") || !s["figures"].contains("stale_scratch_removed")) continue;
    reported = true;
    EXPECT_EQ(s["figures"]["stale_scratch_removed"].get<double>(), static_cast<double>(left.size()));
    EXPECT_DOUBLE_EQ(s["figures"]["stale_scratch_mb"].get<double>(), static_cast<double>(left_bytes) / 1e6);
  }
  EXPECT_TRUE(reported) << "the tiles stage reports no stale_scratch_removed";
}

}  // namespace tile_job_kill_test
