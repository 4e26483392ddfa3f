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

#include <cctype>
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

  // One job for every tile (about 1.5 s in all), killed while a tile's temporary kept file
  // exists (from its first write to its move, which may be short): tried again, up to eight
  // times, until the kill leaves something.
  std::set<std::string> left;
  for (int attempt = 0; attempt < 8 && left.empty(); ++attempt) {
    const pid_t pid = spawn({HC_APP, "tile-job", (work / "plan.json").string(), "--tiles", all, "-q"});
    ASSERT_GT(pid, 0);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(300);
    bool seen = false;
    int status = 0;
    bool ended = false;
    while (!seen && std::chrono::steady_clock::now() < deadline) {
      if (waitpid(pid, &status, WNOHANG) == pid) {
        ended = true;  // finished before we saw it
        break;
      }
      for (const std::string& n : entries(work)) seen = seen || n.rfind(".kept-job-", 0) == 0;
      if (!seen) std::this_thread::yield();
    }
    if (!ended) {
      ASSERT_EQ(kill(pid, SIGKILL), 0);
      ASSERT_EQ(waitpid(pid, &status, 0), pid);
    }
    for (const std::string& n : entries(work))
      if (is_scratch(n)) left.insert(n);
  }
  ASSERT_FALSE(left.empty()) << "eight tile jobs, each killed while it wrote kept points, left nothing to remove";
  // What a job killed at other moments leaves (the Buddha's jobs make no block copies, and a
  // result is written in microseconds), named as docs/scale.md says a job names them, with
  // another host in the tag.
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
  // What is the user's stays: other names, even with a leading dot or close to scratch names,
  // a folder named like scratch inside a folder of the user's, and a link.
  const std::vector<std::string> users = {"notes.txt", ".hidden", ".foo.tmp-1", ".part_x.bin.tmp-node7-4242-0123456789abcdef",
                                          ".kept-job-mine.bin", ".blocks-mine"};
  for (const std::string& n : users) std::ofstream(work / n) << "mine";
  fs::create_directories(work / "mine" / ".blocks-node7-4242-0123456789abcdef");
  fs::create_directory_symlink(work / "mine", work / ".blocks-node8-4242-0123456789abcdef");
  // Scratch of a process of this host that is alive (this test) stays: a running attempt's.
  char host[256] = {0};
  ASSERT_EQ(gethostname(host, sizeof host - 1), 0);
  std::string tag;
  for (const char* c = host; *c; ++c) tag.push_back(std::isalnum(static_cast<unsigned char>(*c)) ? *c : '_');
  tag += "-" + std::to_string(getpid()) + "-0123456789abcdef";
  fs::create_directory(work / (".blocks-" + tag));

  ASSERT_EQ(run({HC_APP, "tile-job", (work / "plan.json").string(), "--tiles", all, "-q"}), 0);
  const fs::path out = dir / "run";
  ASSERT_EQ(run({HC_APP, "tile-merge", (work / "plan.json").string(), "--out", out.string(), "-q"}), 0);

  for (const std::string& n : left) EXPECT_FALSE(fs::exists(fs::symlink_status(work / n))) << n << " is left in the plan's folder";
  for (const std::string& n : users) EXPECT_TRUE(fs::is_regular_file(work / n)) << n;
  EXPECT_TRUE(fs::is_directory(work / "mine" / ".blocks-node7-4242-0123456789abcdef"));
  EXPECT_TRUE(fs::is_symlink(work / ".blocks-node8-4242-0123456789abcdef"));
  EXPECT_TRUE(fs::is_directory(work / (".blocks-" + tag)));
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
