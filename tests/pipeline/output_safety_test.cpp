// Issue 15, D1 and D5: absurd but finite coordinates are refused with a clear error (no crash
// inside OpenCV), and an output folder never replaces what hapticloud did not write.

#include "hc/common/error.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/pipeline/surface_layers.hpp"
#include "hc/pipeline/transform.hpp"

#include <gtest/gtest.h>

#include "cloud_fixtures.hpp"
#include "test_paths.hpp"

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cerrno>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>
#include <vector>

namespace {

namespace fs = std::filesystem;
using namespace hc::pipeline;

/// A binary little-endian float PLY: a 40 × 40 plane of 1 mm pitch plus `extra` vertices.
void write_plane_ply(const fs::path& file, const std::vector<Eigen::Vector3f>& extra) {
  std::vector<Eigen::Vector3f> v;
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 40; ++j) v.emplace_back(0.001f * float(i), 0.001f * float(j), 0.0002f * float(i % 3));
  v.insert(v.end(), extra.begin(), extra.end());
  std::ofstream out(file, std::ios::binary);
  out << "ply\nformat binary_little_endian 1.0\nelement vertex " << v.size()
      << "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  for (const auto& p : v) out.write(reinterpret_cast<const char*>(p.data()), 3 * sizeof(float));
}

RunConfig plane_config(const fs::path& ply, bool outliers) {
  return parse_run_config("input: {files: [" + ply.filename().string() + "]}\n"
                          "grid: {n: 40}\n"
                          "filters: {outliers: {enabled: " + std::string(outliers ? "true" : "false") + "}}\n",
                          ply.parent_path() / "run.yaml");
}

std::string slurp(const fs::path& f) {
  std::ifstream in(f, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

bool has_partial_sibling(const fs::path& dir) {
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().filename().string().find(".partial") != std::string::npos) return true;
  }
  return false;
}

// D1: two vertices at z = ±3e38 (finite floats) with the outlier filter off crashed in
// cv::bilateralFilter (vmax − vmin overflowed float). Now: an InputError naming the key, no output.
TEST(OutputSafety, FiniteButAbsurdCoordinatesAreRefusedNotCrashed) {
  const fs::path dir = hc::test::temp_dir("d1");
  write_plane_ply(dir / "spike.ply", {{0.02f, 0.02f, 3e38f}, {0.021f, 0.02f, -3e38f}});
  try {
    run_pipeline(plane_config(dir / "spike.ply", false), dir / "out");
    FAIL() << "the run accepted a 6e38 m extent";
  } catch (const hc::InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("input.max_extent_m"), std::string::npos) << what;
    EXPECT_NE(what.find("along z"), std::string::npos) << what;
  }
  EXPECT_FALSE(fs::exists(dir / "out"));
  EXPECT_FALSE(has_partial_sibling(dir));
}

TEST(OutputSafety, ExtentLimitIsAppliedAfterUnitConversion) {
  // 9 000 000 mm = 9 km passes the 10 km default; 11 000 000 mm = 11 km does not.
  const auto ok = hc::test::cloud_of({{0, 0, 0}, {9e6, 1, 1}});
  EXPECT_NO_THROW(to_metres_and_recentre(ok, 0.001, nullptr));
  const auto far = hc::test::cloud_of({{0, 0, 0}, {1.1e7, 1, 1}});
  EXPECT_THROW(to_metres_and_recentre(far, 0.001, nullptr), hc::InputError);
  EXPECT_NO_THROW(to_metres_and_recentre(far, 0.001, nullptr, 20'000.0));
  EXPECT_THROW(to_metres_and_recentre(ok, 0.001, nullptr, -1.0), hc::ConfigError);
  EXPECT_EQ(parse_run_config("input: {files: [a.ply], max_extent_m: 250}\n", "x.yaml").input.max_extent_m, 250.0);
  EXPECT_THROW(parse_run_config("input: {files: [a.ply], max_extent_m: 0}\n", "x.yaml"), hc::ConfigError);
}

TEST(OutputSafety, EnvelopeRefusesADepthRangeFloatCannotFilter) {
  // The layer stage called on its own (no ingest check in front of it) must not crash either.
  hc::HeightField depth(hc::GridGeometry{16, 16, 0.0, 0.0, 0.001}, 0.0f);
  depth.at(3, 3) = 3e38f;
  depth.at(9, 9) = -3e38f;
  EXPECT_THROW(compute_surface_layers(depth, SurfaceLayerOptions{}), hc::InputError);
}

// D5: --out deleted whatever was there.
TEST(OutputSafety, AnExistingFileIsNeverReplaced) {
  const fs::path dir = hc::test::temp_dir("d5file");
  write_plane_ply(dir / "plane.ply", {});
  { std::ofstream(dir / "notes.txt") << "the user's notes\n"; }
  EXPECT_THROW(run_pipeline(plane_config(dir / "plane.ply", true), dir / "notes.txt"), hc::InputError);
  EXPECT_EQ(slurp(dir / "notes.txt"), "the user's notes\n");
  EXPECT_FALSE(has_partial_sibling(dir));
}

TEST(OutputSafety, AForeignFolderIsRefusedAndWithForceKeptAside) {
  const fs::path dir = hc::test::temp_dir("d5dir");
  write_plane_ply(dir / "plane.ply", {});
  fs::create_directories(dir / "thesis" / "chapter1");
  { std::ofstream(dir / "thesis" / "chapter1" / "draft.tex") << "\\section{Temples}\n"; }
  EXPECT_THROW(run_pipeline(plane_config(dir / "plane.ply", true), dir / "thesis"), hc::InputError);
  EXPECT_EQ(slurp(dir / "thesis" / "chapter1" / "draft.tex"), "\\section{Temples}\n");

  const RunSummary s =
      run_pipeline(plane_config(dir / "plane.ply", true), dir / "thesis", {}, ExistingOutput::kMoveAside);
  EXPECT_TRUE(fs::exists(dir / "thesis" / "scene" / "scene.yaml"));
  ASSERT_FALSE(s.moved_aside.empty());
  EXPECT_EQ(s.moved_aside.parent_path(), dir);
  EXPECT_EQ(slurp(s.moved_aside / "chapter1" / "draft.tex"), "\\section{Temples}\n");
}

TEST(OutputSafety, EmptyFoldersAndEarlierOutputsAreReplaced) {
  const fs::path dir = hc::test::temp_dir("d5ok");
  write_plane_ply(dir / "plane.ply", {});
  fs::create_directories(dir / "empty");
  run_pipeline(plane_config(dir / "plane.ply", true), dir / "empty");
  EXPECT_TRUE(fs::exists(dir / "empty" / kOutputMarkerFile));
  EXPECT_TRUE(is_hapticloud_output(dir / "empty"));
  // The same folder again: an earlier output, replaced without --force, nothing kept aside.
  const RunSummary again = run_pipeline(plane_config(dir / "plane.ply", true), dir / "empty");
  EXPECT_TRUE(again.moved_aside.empty());
  int siblings = 0;
  for (const auto& e : fs::directory_iterator(dir)) siblings += e.path().filename().string().rfind("empty", 0) == 0;
  EXPECT_EQ(siblings, 1);
  // A run folder written before the marker existed is still recognised as an earlier output.
  fs::remove(dir / "empty" / kOutputMarkerFile);
  EXPECT_TRUE(is_hapticloud_output(dir / "empty"));
  { std::ofstream(dir / "empty" / "mine.txt") << "x"; }
  EXPECT_FALSE(is_hapticloud_output(dir / "empty"));
}

TEST(OutputSafety, AStagingNameThatExistsIsLeftAlone) {
  const fs::path dir = hc::test::temp_dir("d5staging");
  fs::path squatter = dir / "out";
  squatter += ".partial-" + std::to_string(::getpid());
  fs::create_directories(squatter);
  { std::ofstream(squatter / "keep.txt") << "keep"; }
  {
    StagingDir staging(dir / "out");
    EXPECT_NE(staging.path(), squatter);
    staging.commit();
  }
  EXPECT_EQ(slurp(squatter / "keep.txt"), "keep");
  EXPECT_TRUE(fs::exists(dir / "out" / kOutputMarkerFile));
}

}  // namespace

namespace {

TEST(OutputSafety, StaleStagingFoldersOfDeadProcessesAreRemovedOnlyWhenOurs) {
  const fs::path dir = hc::test::temp_dir("stale");
  // A pid that is not running: the first free one above a high start.
  long pid = 4'000'000;
  while (::kill(static_cast<pid_t>(pid), 0) == 0 || errno != ESRCH) ++pid;
  const fs::path ours = dir / ("out.partial-" + std::to_string(pid));
  const fs::path old = dir / ("out.old-" + std::to_string(pid));
  const fs::path foreign = dir / ("out.partial-" + std::to_string(pid) + "-1");
  for (const fs::path& p : {ours, old, foreign}) fs::create_directories(p);
  { std::ofstream(ours / kOutputMarkerFile) << "x"; }
  { std::ofstream(old / kOutputMarkerFile) << "x"; }
  { std::ofstream(foreign / "thesis.tex") << "mine"; }  // no marker: not ours
  // This process's own name is never touched either.
  const fs::path mine = dir / ("out.partial-" + std::to_string(::getpid()) + "-7");
  fs::create_directories(mine);
  { std::ofstream(mine / kOutputMarkerFile) << "x"; }
  {
    StagingDir staging(dir / "out");
    staging.commit();
  }
  EXPECT_FALSE(fs::exists(ours));
  EXPECT_FALSE(fs::exists(old));
  EXPECT_TRUE(fs::exists(foreign / "thesis.tex"));
  EXPECT_TRUE(fs::exists(mine));
}

TEST(OutputSafety, LiveStagingFoldersCanBeRemovedByASignalWatcher) {
  const fs::path dir = hc::test::temp_dir("live");
  StagingDir a(dir / "a");
  StagingDir b(dir / "b");
  ASSERT_TRUE(fs::exists(a.path()));
  EXPECT_EQ(remove_live_staging_dirs(), 2);
  EXPECT_FALSE(fs::exists(a.path()));
  EXPECT_FALSE(fs::exists(b.path()));
}

// Scratch a signal watcher removes besides staging folders: a registered file, and the entries of
// a folder that stays (a tile plan's files in the user's work folder) whose names start with a
// registered prefix; what is unregistered, or matches no prefix, stays.
TEST(OutputSafety, RegisteredScratchFilesAndEntriesAreRemovedByASignalWatcher) {
  const fs::path dir = hc::test::temp_dir("live-scratch");
  const fs::path work = dir / "work";
  fs::create_directories(work / "tile_sub");
  for (const char* n : {"tile_0.bin", "tile_12.bin", "plan.json", ".plan.json.tmp-x", "notes.txt", "my_tile_0.bin"}) {
    std::ofstream(work / n) << "x";
  }
  std::ofstream(work / "tile_sub" / "a") << "x";
  const fs::path file = dir / ".part_3.bin.tmp-y", kept_file = dir / "kept.bin";
  std::ofstream(file) << "x";
  std::ofstream(kept_file) << "x";
  const fs::path other = dir / "other";
  fs::create_directories(other);
  std::ofstream(other / "tile_1.bin") << "x";
  register_live_scratch_entries(work, {"tile_", "plan.json", ".plan.json"});
  register_live_scratch_entries(other, {"tile_"});
  unregister_live_scratch_entries(other);
  register_live_scratch_dir(file);
  register_live_scratch_dir(kept_file);
  unregister_live_scratch_dir(kept_file);
  EXPECT_EQ(remove_live_staging_dirs(), 2);
  EXPECT_FALSE(fs::exists(file));
  EXPECT_TRUE(fs::exists(kept_file));
  EXPECT_TRUE(fs::exists(other / "tile_1.bin"));
  ASSERT_TRUE(fs::is_directory(work));
  std::vector<std::string> left;
  for (const auto& e : fs::directory_iterator(work)) left.push_back(e.path().filename().string());
  std::sort(left.begin(), left.end());
  EXPECT_EQ(left, (std::vector<std::string>{"my_tile_0.bin", "notes.txt"}));
  // Acted on once: the registrations are gone.
  std::ofstream(work / "tile_5.bin") << "x";
  EXPECT_EQ(remove_live_staging_dirs(), 0);
  EXPECT_TRUE(fs::exists(work / "tile_5.bin"));
}

// The signal watcher's clean-up is final: after it, a scratch file is neither created nor renamed
// into place (the calls wait for the process to end), so nothing appears behind it. Run in a
// child process, whose lock stays held until it exits.
TEST(OutputSafety, AfterAFinalCleanUpNoScratchFileIsCreatedOrMoved) {
  const fs::path dir = hc::test::temp_dir("final-cleanup");
  const fs::path late = dir / "tile_7.bin", src = dir / ".plan.json.tmp-x", moved = dir / "plan.json";
  std::ofstream(src) << "x";
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    register_live_scratch_dir(dir / "gone");
    (void)remove_live_staging_dirs(true);
    std::atomic<int> returned{0};
    std::thread opener([&] {
      if (std::FILE* f = open_live_scratch_file(late, "wb")) std::fclose(f);
      ++returned;
    });
    std::thread mover([&] {
      std::error_code ec;
      rename_live_scratch(src, moved, ec);
      ++returned;
    });
    opener.detach();
    mover.detach();
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    ::_exit(returned.load() == 0 ? 0 : 1);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0) << "a call returned after the final clean-up";
  EXPECT_FALSE(fs::exists(late));
  EXPECT_TRUE(fs::exists(src));
  EXPECT_FALSE(fs::exists(moved));
}

}  // namespace
