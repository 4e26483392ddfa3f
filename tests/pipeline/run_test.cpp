#include "hc/pipeline/run.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <gtest/gtest.h>

#include "test_paths.hpp"

#include <sys/resource.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <fstream>

namespace {

namespace fs = std::filesystem;
using namespace hc::pipeline;

/// Writes a cloud as XYZ text with 17 significant digits (exact round trip of doubles).
void write_xyz(const Cloud& c, const fs::path& file, const Eigen::Vector3d& shift) {
  std::FILE* f = std::fopen(file.c_str(), "w");
  ASSERT_NE(f, nullptr);
  for (Eigen::Index i = 0; i < c.xyz.cols(); ++i) {
    const Eigen::Vector3d p = c.xyz.col(i) + shift;
    std::fprintf(f, "%.17g %.17g %.17g\n", p.x(), p.y(), p.z());
  }
  std::fclose(f);
}

RunConfig xyz_config(const fs::path& file) {
  return parse_run_config("input: {files: [" + file.filename().string() + "]}\n"
                          "grid: {n: 200, see_through_depth_m: 0.003, hole_fill_max_cells: 16}\n"
                          "filters: {outliers: {enabled: true}}\n",
                          file.parent_path() / "run.yaml");
}

TEST(RunPipeline, GeoreferencedOffsetsGiveTheSameGridWithinOneMicrometre) {
  const fs::path dir = hc::test::temp_dir("geo");
  const Cloud bunny = load_cloud(hc::test::scan_path("bunny/bun000.ply")).value;
  write_xyz(bunny, dir / "near.xyz", Eigen::Vector3d::Zero());
  write_xyz(bunny, dir / "far.xyz", Eigen::Vector3d(452311.25, 5218733.5, 312.75));  // UTM-like offsets
  run_pipeline(xyz_config(dir / "near.xyz"), dir / "near");
  run_pipeline(xyz_config(dir / "far.xyz"), dir / "far");
  const Scene near = load_scene(dir / "near" / "scene");
  const Scene far = load_scene(dir / "far" / "scene");
  ASSERT_EQ(near.depth().geometry().rows, far.depth().geometry().rows);
  ASSERT_EQ(near.depth().geometry().cols, far.depth().geometry().cols);
  EXPECT_NEAR(near.depth().geometry().x0_m, far.depth().geometry().x0_m, 1e-6);
  EXPECT_NEAR(near.depth().geometry().y0_m, far.depth().geometry().y0_m, 1e-6);
  double max_diff = 0.0;
  std::size_t valid = 0;
  for (std::size_t i = 0; i < near.depth().values().size(); ++i) {
    const float a = near.depth().values()[i], b = far.depth().values()[i];
    ASSERT_EQ(std::isnan(a), std::isnan(b)) << "cell " << i;
    if (std::isnan(a)) continue;
    ++valid;
    max_diff = std::max(max_diff, std::abs(double(a) - double(b)));
  }
  EXPECT_GT(valid, 10000u);
  EXPECT_LE(max_diff, 1e-6);
  // The frame records the offset, so grid points map back to georeferenced coordinates.
  const Eigen::Vector3d back = far.depth().model_to_grid.inverse() * Eigen::Vector3d(0, 0, 0);
  EXPECT_NEAR(back.x(), 452311.25 + (near.depth().model_to_grid.inverse() * Eigen::Vector3d::Zero()).x(), 1e-6);
}

/// User plus system CPU time of this process so far [s] (getrusage(2)), measured here and not
/// by the code under test.
double own_cpu_seconds() {
  rusage u{};
  EXPECT_EQ(getrusage(RUSAGE_SELF, &u), 0);
  auto s = [](const timeval& t) { return static_cast<double>(t.tv_sec) + 1e-6 * static_cast<double>(t.tv_usec); };
  return s(u.ru_utime) + s(u.ru_stime);
}

TEST(RunPipeline, StagesCpuSecondsAddUpToAtMostTheRunsOwnAndAreInTheReport) {
  const fs::path dir = hc::test::temp_dir("cpu");
  const Cloud bunny = load_cloud(hc::test::scan_path("bunny/bun000.ply")).value;
  write_xyz(bunny, dir / "in.xyz", Eigen::Vector3d::Zero());
  const double before = own_cpu_seconds();
  const RunSummary summary = run_pipeline(xyz_config(dir / "in.xyz"), dir / "out");
  const double spent = own_cpu_seconds() - before;
  // Each stage's figure is the process's CPU over that stage alone: the stages run one after
  // another inside the call, so together they cannot exceed what the call cost (a figure taken
  // as the process's running total instead of a difference would exceed it at once), and they
  // cover most of it (only the config's checks and the summary lie between them).
  double sum = 0.0;
  for (const StageReport& s : summary.stages) {
    EXPECT_GE(s.cpu_seconds, 0.0) << s.stage;
    sum += s.cpu_seconds;
  }
  EXPECT_GT(sum, 0.0);
  EXPECT_LE(sum, spent + 1e-3);
  EXPECT_GE(sum, 0.5 * spent);
  std::ifstream f(dir / "out" / "report.json");
  const auto j = nlohmann::json::parse(f);
  ASSERT_EQ(j["stages"].size(), summary.stages.size());
  for (std::size_t i = 0; i < summary.stages.size(); ++i) {
    const double v = summary.stages[i].cpu_seconds;
    if (v > 0.0) {
      EXPECT_DOUBLE_EQ(j["stages"][i]["cpu_seconds"].get<double>(), v) << summary.stages[i].stage;
    } else {
      EXPECT_FALSE(j["stages"][i].contains("cpu_seconds")) << summary.stages[i].stage;
    }
  }
}

TEST(RunPipeline, AFailedRunLeavesNothingAndKeepsTheEarlierOutput) {
  const fs::path dir = hc::test::temp_dir("atomic");
  const Cloud bunny = load_cloud(hc::test::scan_path("bunny/bun000.ply")).value;
  write_xyz(bunny, dir / "ok.xyz", Eigen::Vector3d::Zero());
  run_pipeline(xyz_config(dir / "ok.xyz"), dir / "out");
  ASSERT_TRUE(fs::exists(dir / "out" / "report.json"));
  const auto before = fs::last_write_time(dir / "out" / "report.json");

  // A run whose input is broken must fail without touching dir/out or leaving a partial folder.
  { std::ofstream(dir / "broken.xyz") << "0 0 0\n1 2 x\n"; }
  EXPECT_THROW(run_pipeline(xyz_config(dir / "broken.xyz"), dir / "out"), hc::InputError);
  EXPECT_EQ(fs::last_write_time(dir / "out" / "report.json"), before);
  for (const auto& e : fs::directory_iterator(dir)) {
    EXPECT_EQ(e.path().filename().string().find(".partial"), std::string::npos) << e.path();
  }
  EXPECT_THROW(run_pipeline(xyz_config(dir / "broken.xyz"), dir / "fresh"), hc::InputError);
  EXPECT_FALSE(fs::exists(dir / "fresh"));
}

TEST(SceneIo, MissingOrCorruptScenesAreNamedErrors) {
  const fs::path dir = hc::test::temp_dir("bad");
  try {
    load_scene(dir / "nothing");
    FAIL();
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("nothing"), std::string::npos);
  }
  fs::create_directories(dir / "s");
  std::ofstream(dir / "s" / "scene.yaml") << "format_version: 1\ngrid: {rows: 2, cols: 2, x0_m: 0, y0_m: 0, cell_size_m: 1}\nlayers: {depth: depth.tiff}\n";
  try {
    load_scene(dir / "s");
    FAIL();
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("depth.tiff"), std::string::npos) << e.what();
  }
  std::ofstream(dir / "s" / "scene.yaml") << "format_version: 99\n";
  EXPECT_THROW(load_scene(dir / "s"), hc::InputError);
}

// An in-core read of a scan that cannot fit is refused before it starts (check_in_core_fits):
// a binary PLY of 1 000 points (counted from its header) needs at least
// 1 000 × kInCoreBytesPerPointAtLeast = 100 000 bytes. The oracle is that product: a limit one
// byte below it refuses, naming the file, the count and the way out; the product itself, an
// unknown limit (0), an input counted only by a pass over it (an XYZ text file of the same
// points) and an uncounted input (a synthetic one) pass. check_in_core_run_fits names what
// keeps the run in core: scale.tiled off, an option the tiled run lacks (by its key), the count
// at or below scale.tiled_above_points.
TEST(InCoreMemory, AScanThatCannotFitIsRefusedBeforeItIsReadNamingTheFileAndTheWayOut) {
  const fs::path dir = hc::test::temp_dir("in_core_memory");
  {
    std::ofstream xyz(dir / "text.xyz");
    std::ofstream ply(dir / "scan.ply", std::ios::binary);
    ply << "ply\nformat binary_little_endian 1.0\nelement vertex 1000\nproperty float x\nproperty float y\n"
           "property float z\nend_header\n";
    for (int i = 0; i < 1000; ++i) {
      const float p[3] = {0.001f * static_cast<float>(i), 0.002f * static_cast<float>(i % 37), 0.0005f * static_cast<float>(i % 11)};
      ply.write(reinterpret_cast<const char*>(p), sizeof p);
      xyz << p[0] << " " << p[1] << " " << p[2] << "\n";
    }
  }
  const auto config_with = [&](const std::string& extra) {
    return parse_run_config("input: {files: [scan.ply], units: m}\ngrid: {n: 40}\n" + extra, dir / "run.yaml");
  };
  const RunConfig off = config_with("scale: {tiled: \"off\"}\n");
  const std::uint64_t need = 1000 * kInCoreBytesPerPointAtLeast;
  try {
    check_in_core_fits(off, need - 1, "THE WAY OUT");
    ADD_FAILURE() << "a limit below the need was not refused";
  } catch (const hc::ResourceError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("scan.ply"), std::string::npos) << m;
    EXPECT_NE(m.find("1000 points"), std::string::npos) << m;
    EXPECT_NE(m.find("THE WAY OUT"), std::string::npos) << m;
  }
  EXPECT_NO_THROW(check_in_core_fits(off, need, "x"));
  EXPECT_NO_THROW(check_in_core_fits(off, 0, "x")) << "an unknown limit refuses nothing";
  EXPECT_NO_THROW(check_in_core_fits(parse_run_config("input: {files: [text.xyz], units: m}\ngrid: {n: 40}\n", dir / "t.yaml"), 1, "x"))
      << "a text file is counted only by a pass over it: left out";
  EXPECT_NO_THROW(check_in_core_fits(parse_run_config("input: {synthetic: {surface: sinusoid}}\ngrid: {n: 40}\n", dir / "s.yaml"), 1, "x"))
      << "an input not counted without reading it";
  const auto why = [&](const RunConfig& c) {
    try {
      check_in_core_run_fits(c, false, 1);
    } catch (const hc::ResourceError& e) {
      return std::string(e.what());
    }
    return std::string("(not refused)");
  };
  EXPECT_NE(why(off).find("scale.tiled is off"), std::string::npos) << why(off);
  const RunConfig voxel = config_with("filters: {voxel_m: 0.01}\n");
  EXPECT_NE(why(voxel).find("filters.voxel_m"), std::string::npos) << why(voxel);
  const RunConfig small = config_with("");
  EXPECT_NE(why(small).find("scale.tiled_above_points"), std::string::npos) << why(small);
  // The limit this process reports: some memory, no more than the machine's RAM and swap.
  std::ifstream meminfo("/proc/meminfo");
  std::uint64_t total_kb = 0;
  for (std::string key; meminfo >> key;) {
    std::uint64_t kb = 0;
    meminfo >> kb;
    if (key == "MemTotal:" || key == "SwapTotal:") total_kb += kb;
    meminfo.ignore(64, '\n');
  }
  ASSERT_GT(total_kb, 0U);
  EXPECT_GT(memory_limit_bytes(), 0U);
  EXPECT_LE(memory_limit_bytes(), total_kb * 1024 + 4096);
}

// The memory limit from /proc/self/cgroup's text and a cgroup tree built in a temporary folder
// (detail::memory_limit_from): the least of RAM + swap and every limit on the process's
// cgroup's path, v2 (memory.max, under the root or unified/ on a hybrid host) and v1
// (memory.limit_in_bytes, under memory/ or the controllers' folder); "max", v1's "no limit"
// number, text and missing files are no limit; a line without the memory controller is not read.
TEST(InCoreMemory, TheMemoryLimitIsTheLeastOfRamAndTheCgroupLimitsOnTheProcesssPath) {
  const fs::path root = hc::test::temp_dir("cgroup_tree");
  const auto put = [&](const fs::path& rel, const std::string& text) {
    fs::create_directories((root / rel).parent_path());
    std::ofstream(root / rel) << text << "\n";
  };
  put("memory.max", "max");
  put("a/memory.max", "3000");
  put("a/b/memory.max", "max");
  EXPECT_EQ(hc::pipeline::detail::memory_limit_from("0::/a/b\n", root, 10000), 3000U) << "an ancestor's limit";
  EXPECT_EQ(hc::pipeline::detail::memory_limit_from("0::/a/b\n", root, 2000), 2000U) << "RAM and swap below it";
  EXPECT_EQ(hc::pipeline::detail::memory_limit_from("0::/a/b\n", root, 0), 3000U) << "RAM unknown";
  EXPECT_EQ(hc::pipeline::detail::memory_limit_from("0::/\n", root, 10000), 10000U) << "the root: max";
  put("unified/a/b/memory.max", "2500");
  EXPECT_EQ(hc::pipeline::detail::memory_limit_from("0::/a/b\n", root, 10000), 2500U) << "a hybrid host's unified tree";
  put("memory/x/memory.limit_in_bytes", "9223372036854771712");
  put("memory/memory.limit_in_bytes", "1800");
  put("cpuset,memory/y/memory.limit_in_bytes", "1500");
  put("cpu/z/memory.limit_in_bytes", "100");
  put("memory/w/memory.limit_in_bytes", "lots");
  EXPECT_EQ(hc::pipeline::detail::memory_limit_from("4:memory:/x\n", root, 10000), 1800U) << "v1: no limit on x, 1800 on its root";
  EXPECT_EQ(hc::pipeline::detail::memory_limit_from("4:cpuset,memory:/y\n", root, 10000), 1500U) << "v1 with two controllers";
  EXPECT_EQ(hc::pipeline::detail::memory_limit_from("3:cpu:/z\n1:name=systemd:/\n", root, 10000), 10000U) << "no memory controller";
  EXPECT_EQ(hc::pipeline::detail::memory_limit_from("4:memory:/w\n", root, 10000), 1800U) << "text is no limit";
  EXPECT_EQ(hc::pipeline::detail::memory_limit_from("garbage\n\n", root, 0), 0U) << "unknown";
  EXPECT_EQ(hc::pipeline::detail::memory_limit_from("4:memory:/x\n0::/a/b\n", root, 10000), 1800U) << "both trees: the least";
}

}  // namespace
