// Tile jobs in separate steps (tiling.hpp: write_tile_plan, run_tile_jobs, merge_tile_jobs;
// issue 14's `hapticloud tile-job`): the oracle is build_scene_tiled, the in-process run of the
// same config. Jobs run out of order, in groups and twice give the same scene bit for bit; a
// merge with a tile missing, a result of another plan or a changed config is refused by name;
// a plan never writes into a folder that holds something.
#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/robust_outliers.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/pipeline/tiling.hpp"
#include "height_field_bits.hpp"
#include "patch_scan.hpp"
#include "stage_figure.hpp"
#include "test_paths.hpp"

#include <algorithm>
#include <array>
#include <cstdio>
#include <cstdlib>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <bit>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <optional>
#include <string>
#include <vector>

namespace tile_jobs_test {

namespace fs = std::filesystem;
using hc::pipeline::BuiltScene;
using hc::pipeline::RunConfig;

using hc::test::differing_bits;

// The InputError message of merging `plan_file`, which must refuse it; "" (a failure added)
// when the merge goes through.
std::string merge_refusal(const fs::path& plan_file, const char* what_went_through) {
  try {
    (void)hc::pipeline::merge_tile_jobs(plan_file);
  } catch (const hc::InputError& e) {
    return e.what();
  }
  ADD_FAILURE() << what_went_through << " was merged";
  return "";
}

std::string bytes_of(const fs::path& f) {
  std::ifstream in(f, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

const fs::path& buddha_config() {
  static const fs::path p = fs::path(HC_SOURCE_DIR) / "configs" / "happy_buddha.yaml";
  return p;
}

// The Buddha at N = 400 in tiles of 64 cells, the robust outlier filter on (the tiles share the
// plan's scale), levels table with its sample.
std::vector<std::string> buddha_overrides(const fs::path& scratch) {
  return {"grid.n=400", "scale.tiled=on", "scale.tile_cells=64", "scale.scratch=" + scratch.string(), "lod.report=true"};
}

void expect_same_scene(const BuiltScene& a, const BuiltScene& b) {
  const auto& x = a.scene.layers;
  const auto& y = b.scene.layers;
  EXPECT_GT(x.depth.values().size(), 0U);
  hc::test::expect_same_layers(x, y);
  EXPECT_EQ(differing_bits(x.cell_error, y.cell_error), 0U);
  EXPECT_EQ(a.scene.model_to_grid.matrix(), b.scene.model_to_grid.matrix());
  EXPECT_EQ(a.scene.provenance.recentre_offset_m, b.scene.provenance.recentre_offset_m);
  EXPECT_EQ(a.scene.provenance.inputs, b.scene.provenance.inputs);
  ASSERT_TRUE(a.summary.cross_check && b.summary.cross_check);
  const auto& p = *a.summary.cross_check;
  const auto& q = *b.summary.cross_check;
  EXPECT_EQ(p.points_on_surface, q.points_on_surface);
  EXPECT_EQ(p.points_off_surface, q.points_off_surface);
  EXPECT_EQ(p.points_hidden, q.points_hidden);
  EXPECT_EQ(p.points_outside, q.points_outside);
  EXPECT_EQ(p.point_vertical.rms_mm, q.point_vertical.rms_mm);  // the same sums in the same order
  EXPECT_EQ(p.point_vertical.p95_mm, q.point_vertical.p95_mm);
  EXPECT_EQ(p.point_normal.max_mm, q.point_normal.max_mm);
  EXPECT_EQ(p.cell_to_point.rms_mm, q.cell_to_point.rms_mm);
  EXPECT_EQ(p.supported_fraction, q.supported_fraction);
  // The honest check and the verdict (spikes confirmed, every class of the input).
  ASSERT_TRUE(a.summary.input_check && b.summary.input_check && a.summary.verdict && b.summary.verdict);
  EXPECT_EQ(a.summary.verdict->status, b.summary.verdict->status);
  const auto& u = *a.summary.input_check;
  const auto& w = *b.summary.input_check;
  for (const auto& [x1, x2] : {std::pair{u.points, w.points}, std::pair{u.removed, w.removed}, std::pair{u.on_surface, w.on_surface},
                               std::pair{u.off_surface, w.off_surface}, std::pair{u.hidden, w.hidden}, std::pair{u.no_data, w.no_data},
                               std::pair{u.outside, w.outside}, std::pair{u.isolated, w.isolated}, std::pair{u.spikes_kept, w.spikes_kept},
                               std::pair{u.surface_lost, w.surface_lost}}) {
    EXPECT_EQ(x1, x2);
  }
  EXPECT_EQ(u.spacing_m, w.spacing_m);
  EXPECT_EQ(a.summary.grid_spikes->confirmed, b.summary.grid_spikes->confirmed);
  ASSERT_EQ(a.point_sample.has_value(), b.point_sample.has_value());
  if (a.point_sample) {
    EXPECT_EQ(a.point_sample->xyz, b.point_sample->xyz);
  }
  EXPECT_EQ(a.point_sample_of, b.point_sample_of);
  // The tile loop's summed figures (removed points, cells, ...) are the same.
  auto tiles_stage = [](const BuiltScene& s) {
    for (const auto& st : s.summary.stages) {
      if (st.stage == "tiles") return st;
    }
    return hc::pipeline::StageReport{};
  };
  const auto ta = tiles_stage(a), tb = tiles_stage(b);
  EXPECT_EQ(ta.count_in, tb.count_in);
  EXPECT_EQ(ta.count_out, tb.count_out);
  // Not the work of the second look's gatherings: a process gathers once for the strays of a
  // band of its own tiles, so what it reads and gathers depends on the tiles it ran together.
  // Nor the first look's: in a band, a tile leaves the points another tile of the band owns in
  // its decided region to their owner (since the fiftieth session), so which points it counts,
  // searches, tests and lists as strays depends on the tiles it ran together too.
  // Nor the freed heap the process gave back or whether its tile loop mapped large blocks on
  // their own (its own memory, not the scene's).
  const auto copies_work = [](const std::string& name) {
    return name == "sum_robust_spill_points_scanned" || name == "sum_robust_gatherings" || name == "sum_robust_balls_grown" ||
           name == "sum_robust_points_gathered" || name == "heap_releases" || name == "large_blocks_mapped" ||
           name == "sum_certified" || name == "sum_exact_queries" || name == "sum_local_tests" || name == "sum_coherent_above_global" ||
           name == "sum_planar_among_scattered" || name == "sum_points_judged_past_halo" || name == "sum_robust_windows_widened" ||
           name == "sum_robust_widened_cells" || name == "sum_halo_shortfall_mm";
  };
  for (const auto& [name, v] : ta.figures) {
    if ((name.size() > 2 && name.compare(name.size() - 2, 2, "_s") == 0) || name.find("seconds") != std::string::npos) continue;
    if (copies_work(name)) continue;
    bool found = false;
    for (const auto& [n2, v2] : tb.figures) {
      if (n2 == name) {
        found = true;
        EXPECT_EQ(v, v2) << name;
      }
    }
    EXPECT_TRUE(found) << name;
  }
}

// The robust test's float frame (RobustScale::centre_m) that plan.json hands every job is the
// in-core run's: the per-axis median of the points the in-core test samples. Oracle: the robust
// test's input as the in-core run makes it (prepare_points with the outlier filters off), the
// sampled indices (robust_sample_indices) and a full sort per axis; the in-core test reports
// that centre in its scale too. Found on the 10^8 wall at N = 800 (fifty-first session): each
// window's own frame rounded one point's distances otherwise, a neighbour of equal distance
// was swapped, and its off-surface verdict differed from the in-core run's.
TEST(TileJobs, ThePlanCarriesTheInCoreRobustTestsFloatFrame) {
  hc::test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz");
  const fs::path scratch = hc::test::temp_dir("scratch");
  const fs::path work = hc::test::temp_dir("work") / "plan";
  const auto info = hc::pipeline::write_tile_plan(buddha_config(), buddha_overrides(scratch), work);
  std::array<double, 3> planned{};
  {
    std::ifstream in(info.plan_file);
    const std::string text{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    const auto at = text.find("\"centre_m\"");
    ASSERT_NE(at, std::string::npos) << "plan.json names robust_scale.centre_m";
    std::size_t from = text.find('[', at);
    for (std::size_t a = 0; a < 3; ++a) {
      const std::size_t q0 = text.find('"', from) + 1, q1 = text.find('"', q0);
      planned[a] = std::strtod(text.substr(q0, q1 - q0).c_str(), nullptr);  // hexadecimal floats, exact
      from = q1 + 1;
    }
  }
  std::vector<std::string> off = buddha_overrides(scratch);
  off.push_back("filters.outliers.enabled=false");
  off.push_back("scale.tiled=off");
  const hc::pipeline::Cloud input = hc::pipeline::prepare_points(hc::pipeline::load_run_config(buddha_config(), off));
  const std::vector<std::uint32_t> sample = hc::pipeline::robust_sample_indices(input.size(), hc::pipeline::RobustOutlierOptions{}.sample);
  ASSERT_EQ(sample.size(), 20000U);
  for (Eigen::Index a = 0; a < 3; ++a) {
    std::vector<double> v;
    for (const std::uint32_t j : sample) v.push_back(input.xyz(a, static_cast<Eigen::Index>(j)));
    std::sort(v.begin(), v.end());
    EXPECT_EQ(planned[static_cast<std::size_t>(a)], v[v.size() / 2]) << "axis " << a;
  }
  // The in-core test's scale carries the same centre, and a scale given with it hands it on.
  hc::pipeline::RobustScale used;
  const hc::pipeline::RobustOutlierOptions o;
  (void)hc::pipeline::remove_robust_outliers(input, o, nullptr, &used);
  ASSERT_TRUE(used.centre_m.has_value());
  EXPECT_EQ(*used.centre_m, planned);
  hc::pipeline::RobustOutlierOptions given = o;
  given.scale = used;
  hc::pipeline::RobustScale again;
  (void)hc::pipeline::remove_robust_outliers(input, given, nullptr, &again);
  EXPECT_EQ(again.centre_m, used.centre_m);
}

TEST(TileJobs, PlanJobsInAnyOrderAndMergeGiveTheInProcessScene) {
  hc::test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz");
  const fs::path scratch = hc::test::temp_dir("scratch");
  const fs::path work = hc::test::temp_dir("work") / "plan";  // created by the plan
  const RunConfig config = hc::pipeline::load_run_config(buddha_config(), buddha_overrides(scratch));
  const BuiltScene in_process = hc::pipeline::build_scene_tiled(config);

  const auto info = hc::pipeline::write_tile_plan(buddha_config(), buddha_overrides(scratch), work);
  ASSERT_GT(info.tiles, 8U) << "the grid is cut into many tiles";
  EXPECT_EQ(hc::pipeline::tile_plan_tiles(info.plan_file), info.tiles);
  EXPECT_GT(info.spill_bytes, 0U);
  // Backwards, in groups of up to three: order and grouping must not matter.
  for (std::size_t end = info.tiles; end > 0;) {
    const std::size_t begin = end >= 3 ? end - 3 : 0;
    std::vector<std::size_t> group;
    for (std::size_t t = end; t-- > begin;) group.push_back(t);
    hc::pipeline::run_tile_jobs(info.plan_file, group);
    end = begin;
  }
  // A job run again (a retry after a lost worker) writes the same kept-point mask (its result
  // differs only in its timings; the merge below uses the rerun's), but for the kNear hint (4)
  // on removed records: run alone, tile 1 counts the neighbours of the points tile 0 or 2 owns
  // in its decided region itself, where run with them it took their owners' counts (lower
  // bounds both, from different windows).
  const std::string kept = bytes_of(work / "kept_1.bin");
  ASSERT_GT(kept.size(), 1000U) << "tile 1 has spilled records";
  hc::pipeline::run_tile_jobs(info.plan_file, {1, 1});  // asked twice: done once
  {
    const std::string again = bytes_of(work / "kept_1.bin");
    ASSERT_EQ(again.size(), kept.size());
    const auto verdict = [](char m) { return (m & 3) == 0 ? char{0} : m; };  // a removed record's kNear bit cleared
    std::size_t differ = 0;
    for (std::size_t r = 0; r < kept.size(); ++r) differ += verdict(kept[r]) != verdict(again[r]) ? 1U : 0U;
    EXPECT_EQ(differ, 0U) << "records kept or removed differently, or kept with another kNear";
  }
  EXPECT_FALSE(hc::test::has_entry_named_with(work, ".tmp-"));
  EXPECT_FALSE(hc::test::has_entry_named_with(work, ".kept-job"));
  EXPECT_TRUE(in_process.point_sample.has_value()) << "the levels table's sample";

  const auto merged = hc::pipeline::merge_tile_jobs(info.plan_file);
  expect_same_scene(in_process, merged.built);
  // kept_1.bin marks tile 1's spilled records (a byte each: 0 removed, 1 interior, 2 halo copy,
  // plus 4 where the filters saw the isolated-point test's neighbours: every kept point here, the
  // robust test's run with the whole scan's spacing); one changed into something else is
  // refused, naming the file, not read as a verdict.
  EXPECT_EQ(fs::file_size(work / "tile_1.bin"), 13 * kept.size())
      << "a byte per spilled record (a flag byte, then x y z as the Buddha PLY's own floats)";
  EXPECT_TRUE(std::all_of(kept.begin(), kept.end(), [](char m) { return m == 0 || m == 4 || m == 5 || m == 6; }));
  EXPECT_GT(std::count(kept.begin(), kept.end(), char{5}), 0);
  {
    std::string changed = kept;
    changed[kept.size() / 2] = 7;
    std::ofstream(work / "kept_1.bin", std::ios::binary | std::ios::trunc) << changed;
    const std::string what = merge_refusal(info.plan_file, "a changed kept-point mask");
    EXPECT_NE(what.find("kept_1.bin"), std::string::npos) << what;
    EXPECT_NE(what.find("holds the byte 7"), std::string::npos) << what;
    std::ofstream(work / "kept_1.bin", std::ios::binary | std::ios::trunc) << kept;
  }
  EXPECT_EQ(merged.config.resolved_yaml, hc::pipeline::load_run_config(fs::absolute(buddha_config()), buddha_overrides(scratch)).resolved_yaml);

  // A tile without a result: the merge names it and makes no scene.
  fs::remove(work / "part_5.bin");
  {
    const std::string what = merge_refusal(info.plan_file, "a set with a tile missing");
    EXPECT_NE(what.find("1 of " + std::to_string(info.tiles) + " tiles have no result (5)"), std::string::npos) << what;
    EXPECT_NE(what.find("--tiles 5"), std::string::npos) << what;
  }
  // A result of the version before (without the far clusters hit) is refused as such.
  hc::pipeline::run_tile_jobs(info.plan_file, {5});
  {
    std::string older = bytes_of(work / "part_5.bin");
    ASSERT_EQ(older.substr(0, 11), "HCTILEPART6");
    older[10] = '5';
    std::ofstream(work / "part_5.bin", std::ios::binary | std::ios::trunc) << older;
    const std::string what = merge_refusal(info.plan_file, "a result of another version");
    EXPECT_NE(what.find("part_5.bin: a tile result of another hapticloud version (HCTILEPART5, expected HCTILEPART6)"),
              std::string::npos) << what;
  }
  // A truncated result is refused too.
  hc::pipeline::run_tile_jobs(info.plan_file, {5});
  {
    const std::string whole = bytes_of(work / "part_5.bin");
    std::ofstream(work / "part_5.bin", std::ios::binary | std::ios::trunc) << whole.substr(0, whole.size() - 10);
  }
  EXPECT_THROW((void)hc::pipeline::merge_tile_jobs(info.plan_file), hc::InputError);
  EXPECT_THROW(hc::pipeline::run_tile_jobs(info.plan_file, {info.tiles}), hc::InputError);
}

TEST(TileJobs, AMergeIntoATiledSceneLeavesLevelZerosLayersToTheLevelBuilderAndWritesTheSameScene) {
  // `hapticloud tile-merge` asks for SurfaceLayersAt::kSceneLevels: with a tiled scene and no
  // levels table, level 0's layers are made in stage scene_levels. Oracle: the same merge with
  // its layers in memory (the whole grid's compute_surface_layers), written the same way.
  hc::test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz");
  const fs::path scratch = hc::test::temp_dir("scratch");
  const fs::path dir = hc::test::temp_dir("merge_tiled");
  std::vector<std::string> overrides = {"grid.n=300", "scale.tiled=on", "scale.tile_cells=64",
                                        "scale.scratch=" + scratch.string(), "scale.scene_tiles=on",
                                        "scale.scene_tile_cells=32", "lod.min_cells=30"};
  const auto info = hc::pipeline::write_tile_plan(buddha_config(), overrides, dir / "plan");
  std::vector<std::size_t> all(info.tiles);
  for (std::size_t t = 0; t < info.tiles; ++t) all[t] = t;
  hc::pipeline::run_tile_jobs(info.plan_file, all);
  auto deferred = hc::pipeline::merge_tile_jobs(info.plan_file, {}, hc::pipeline::SurfaceLayersAt::kSceneLevels);
  ASSERT_EQ(deferred.built.surface_layers_at, hc::pipeline::SurfaceLayersAt::kSceneLevels);
  EXPECT_FALSE(deferred.built.scene.layers.has_surface_layers());
  hc::pipeline::write_run(std::move(deferred.built), deferred.config, dir / "builder");
  const auto in_memory = hc::pipeline::merge_tile_jobs(info.plan_file);
  ASSERT_TRUE(in_memory.built.scene.layers.has_surface_layers());
  hc::pipeline::write_run(in_memory.built, in_memory.config, dir / "memory");
  const hc::Scene a = hc::pipeline::load_scene(dir / "builder" / "scene");
  const hc::Scene b = hc::pipeline::load_scene(dir / "memory" / "scene");
  ASSERT_TRUE(a.layers.has_surface_layers());
  EXPECT_EQ(differing_bits(a.layers.texture, in_memory.built.scene.layers.texture), 0U);
  EXPECT_EQ(differing_bits(a.layers.envelope, b.layers.envelope), 0U);
  EXPECT_EQ(differing_bits(a.layers.mu_d, b.layers.mu_d), 0U);
  EXPECT_EQ(differing_bits(a.layers.mu_s, b.layers.mu_s), 0U);
  EXPECT_GT(a.layers.texture.valid_count(), 5000U);
  for (const char* f : {"scene/scene.yaml", "previews/texture.png", "previews/mu_d.png", "previews/mu_s.png"}) {
    ASSERT_TRUE(fs::exists(dir / "builder" / f)) << f;  // bytes_of reads a missing file as ""
    ASSERT_TRUE(fs::exists(dir / "memory" / f)) << f;
    EXPECT_EQ(bytes_of(dir / "builder" / f), bytes_of(dir / "memory" / f)) << f;
  }
}

TEST(TileJobs, RefusesAResultOfAnotherPlanAChangedConfigAndAFolderInUse) {
  hc::test::scan_path("bunny/bun000.ply");
  const fs::path dir = hc::test::temp_dir("w");
  // A config of its own, so that it can change after the plan.
  const fs::path cfg = dir / "bunny.yaml";
  const std::string yaml = "name: bunny_tiles\ninput: {files: [" + hc::test::scan_path("bunny/bun000.ply").string() +
                           "], units: m}\ngrid: {n: 200}\nscale: {tiled: on, tile_cells: 48}\n";
  std::ofstream(cfg) << yaml;
  const auto a = hc::pipeline::write_tile_plan(cfg, {}, dir / "a");
  const auto b = hc::pipeline::write_tile_plan(cfg, {}, dir / "b");
  ASSERT_GT(a.tiles, 2U);
  std::vector<std::size_t> all;
  for (std::size_t t = 0; t < a.tiles; ++t) all.push_back(t);
  hc::pipeline::run_tile_jobs(a.plan_file, all);
  hc::pipeline::run_tile_jobs(b.plan_file, all);
  // The same config: both merge to the same scene.
  expect_same_scene(hc::pipeline::merge_tile_jobs(a.plan_file).built, hc::pipeline::merge_tile_jobs(b.plan_file).built);
  // A result copied from the other plan's folder.
  fs::copy_file(dir / "a" / "part_0.bin", dir / "b" / "part_0.bin", fs::copy_options::overwrite_existing);
  {
    const std::string what = merge_refusal(b.plan_file, "a result of another plan");
    EXPECT_NE(what.find("written for another plan"), std::string::npos) << what;
  }
  // The config changed since the plan: jobs and merge refuse it.
  std::ofstream(cfg) << yaml << "cross_check: {tolerance_m: 0.002}\n";
  EXPECT_THROW(hc::pipeline::run_tile_jobs(a.plan_file, {0}), hc::ConfigError);
  EXPECT_THROW((void)hc::pipeline::merge_tile_jobs(a.plan_file), hc::ConfigError);
  // A folder that holds something is not a work folder; the plan leaves it as it was.
  fs::create_directory(dir / "mine");
  std::ofstream(dir / "mine" / "notes.txt") << "mine";
  EXPECT_THROW((void)hc::pipeline::write_tile_plan(cfg, {}, dir / "mine"), hc::InputError);
  EXPECT_EQ(bytes_of(dir / "mine" / "notes.txt"), "mine");
  EXPECT_EQ(std::distance(fs::directory_iterator(dir / "mine"), fs::directory_iterator()), 1);
  // A plan that fails in an empty folder of the user's leaves the folder, empty.
  fs::create_directory(dir / "empty");
  EXPECT_THROW((void)hc::pipeline::write_tile_plan(cfg, {"input.files=[" + (dir / "none.ply").string() + "]"}, dir / "empty"),
               hc::Error);
  EXPECT_TRUE(fs::is_directory(dir / "empty"));
  EXPECT_TRUE(fs::is_empty(dir / "empty"));
  // A plan that fails (here: an option the tiled run lacks) leaves no folder behind.
  EXPECT_THROW((void)hc::pipeline::write_tile_plan(cfg, {"filters.voxel_m=0.001"}, dir / "c"), hc::ConfigError);
  EXPECT_FALSE(fs::exists(dir / "c"));
  EXPECT_THROW((void)hc::pipeline::write_tile_plan(cfg, {"input.files=[" + (dir / "none.ply").string() + "]"}, dir / "d"),
               hc::Error);
  EXPECT_FALSE(fs::exists(dir / "d"));
}

// `v` as a hexadecimal float ("%a"), as plan.json and grid_box.json hold numbers.
std::string hex_of(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%a", v);
  return buf;
}

// Every tile of `plan_file` in one job each.
void run_every_tile(const hc::pipeline::TilePlanInfo& info) {
  for (std::size_t t = 0; t < info.tiles; ++t) hc::pipeline::run_tile_jobs(info.plan_file, {t});
}

// The InputError or ConfigError message of a plan with `box`, which must refuse it.
std::string plan_refusal(const fs::path& cfg, const std::vector<std::string>& sets, const fs::path& work, const fs::path& box) {
  try {
    (void)hc::pipeline::write_tile_plan(cfg, sets, work, {}, box);
  } catch (const hc::Error& e) {
    EXPECT_FALSE(fs::exists(work)) << "a refused plan leaves no folder";
    return e.what();
  }
  ADD_FAILURE() << "a plan with " << box << " was made";
  return "";
}

// A stray that sets the plan's x-y box and that the filters remove (the cases of
// TiledRun.AStrayThatSetsTheBoxIsRemovedAndTheGridLaidAgainOnTheKeptPoints: a generated patch
// with a stray 7 cm past its edge, and PDAL's test1_4.las, whose box a point the despike removes
// sets). The in-core run lays its grid on the kept points; build_scene_tiled starts again in
// process for them. Through tile jobs, tile-merge refuses the plan's grid and writes the kept
// points' box (GridBoxError, exit 6 in the app); plans made on it (--grid-box) until a merge goes
// through give the in-process run's scene bit for bit and the in-core run's grid (the oracles).
// A box file that is not tile-merge's, or was found with another config or scan, is refused by
// name; a scale key that differs is taken. A plan on a box that is not the kept points' makes
// its merge write their box marked last, as the in-process run's third attempt.
TEST(TileJobs, AMergeOnAGridTheFiltersChangedWritesTheKeptBoxAndAPlanOnItGivesTheInProcessScene) {
  const fs::path dir = hc::test::temp_dir("grid_box_jobs");
  hc::test::write_patch_with(dir / "patch.ply", {{1.06, 0.5, 0.002}});
  fs::copy_file(hc::test::scan_path("scanner_samples/las/pdal-test1_4.las"), dir / "test1_4.las", fs::copy_options::overwrite_existing);
  struct Case {
    const char* name;
    const char* yaml;
    int tile;
    int plans;  // the plans through tile jobs: the in-process run's attempts
  };
  const Case cases[] = {
      {"patch",
       "input: {files: [patch.ply], units: m}\n"
       "grid: {n: 200, splat_radius_cells: 1.2, see_through_depth_m: 0.01, hole_fill_max_cells: 16}\n"
       "cross_check: {tolerance_m: 0.002}\n",
       32, 2},
      {"las",
       "input: {files: [test1_4.las], units: m}\n"
       "grid: {n: 300, splat_radius_cells: 1.2, see_through_depth_m: 2, hole_fill_max_cells: 32}\n"
       "cross_check: {tolerance_m: 0.5}\n",
       48, 2},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const fs::path cfg = dir / (std::string(c.name) + ".yaml");
    std::ofstream(cfg) << c.yaml;
    const fs::path scratch = dir / "scratch";
    fs::create_directories(scratch);
    const std::vector<std::string> sets = {"scale.tiled=on", "scale.tile_cells=" + std::to_string(c.tile), "scale.scratch=" + scratch.string()};
    RunConfig in_core_config = hc::pipeline::load_run_config(cfg, sets);
    in_core_config.scale.tiled = hc::pipeline::ScaleConfig::Tiled::kOff;
    const BuiltScene in_core = hc::pipeline::build_scene(in_core_config);
    const BuiltScene in_process = hc::pipeline::build_scene_tiled(hc::pipeline::load_run_config(cfg, sets));
    const double relaid = hc::test::stage_figure(in_process, "tile_plan", "grid_relaid");
    ASSERT_GE(relaid, 1.0) << "the in-process run started again";
    fs::path box;
    std::optional<hc::pipeline::MergedTileRun> merged;
    int plans = 0;
    while (!merged && plans < 4) {
      ++plans;
      const fs::path work = dir / (std::string(c.name) + "_plan" + std::to_string(plans));
      std::vector<std::string> now = sets;
      if (plans > 1) now.push_back("scale.progress_interval_s=2");  // a scale key: not the scene's
      const auto info = hc::pipeline::write_tile_plan(cfg, now, work, {}, box);
      run_every_tile(info);
      try {
        merged = hc::pipeline::merge_tile_jobs(info.plan_file);
      } catch (const hc::pipeline::GridBoxError& e) {
        EXPECT_EQ(e.box_file, work / "grid_box.json");
        EXPECT_TRUE(fs::is_regular_file(e.box_file));
        const std::string what = e.what();
        EXPECT_NE(what.find("--grid-box " + e.box_file.string()), std::string::npos) << what;
        EXPECT_NE(what.find("No scene was written"), std::string::npos) << what;
        box = e.box_file;
      }
    }
    ASSERT_TRUE(merged.has_value()) << "no plan's merge went through";
    EXPECT_EQ(plans, static_cast<int>(relaid) + 1) << "as many plans as the in-process run's attempts";
    EXPECT_EQ(plans, c.plans);
    EXPECT_EQ(hc::test::stage_figure(merged->built, "tile_plan", "grid_relaid"), relaid);
    EXPECT_TRUE(merged->built.scene.geometry == in_core.scene.geometry) << "the in-core run's grid";
    expect_same_scene(in_process, merged->built);
    EXPECT_TRUE(merged->built.summary.warnings.empty() ||
                std::none_of(merged->built.summary.warnings.begin(), merged->built.summary.warnings.end(),
                             [](const std::string& w) { return w.find("the kept points span") != std::string::npos; }));
    if (std::string(c.name) != "patch") continue;

    // A plan on a box that is not the kept points' (the first box widened by 5 cm in x) gives
    // another grid again: its merge writes the kept points' box once more, marked last (the
    // in-process run's third attempt, which checks no more); a plan on that one goes through
    // with the in-core grid and two grids relaid.
    ASSERT_FALSE(box.empty());
    const std::string good = bytes_of(box);
    {
      nlohmann::json j = nlohmann::json::parse(good);
      EXPECT_FALSE(j["box"]["last"].get<bool>());
      j["box"]["x_max_m"] = hex_of(std::strtod(j["box"]["x_max_m"].get<std::string>().c_str(), nullptr) + 0.05);
      std::ofstream(dir / "wider_box.json") << j.dump();
      const auto wider = hc::pipeline::write_tile_plan(cfg, sets, dir / "wider_plan", {}, dir / "wider_box.json");
      run_every_tile(wider);
      fs::path third;
      try {
        (void)hc::pipeline::merge_tile_jobs(wider.plan_file);
        ADD_FAILURE() << "a plan on a box wider than the kept points' merged";
      } catch (const hc::pipeline::GridBoxError& e) {
        third = e.box_file;
      }
      ASSERT_FALSE(third.empty());
      const nlohmann::json k = nlohmann::json::parse(bytes_of(third));
      EXPECT_TRUE(k["box"]["last"].get<bool>());
      EXPECT_EQ(k["box"]["x_max_m"], nlohmann::json::parse(good)["box"]["x_max_m"]) << "the kept points' box again";
      EXPECT_EQ(k["why"].size(), 2U);
      const auto last = hc::pipeline::write_tile_plan(cfg, sets, dir / "last_plan", {}, third);
      run_every_tile(last);
      const auto m = hc::pipeline::merge_tile_jobs(last.plan_file);
      EXPECT_TRUE(m.built.scene.geometry == in_core.scene.geometry);
      EXPECT_EQ(hc::test::stage_figure(m.built, "tile_plan", "grid_relaid"), 2.0);
    }

    // The refusals, on the patch's box file.
    const fs::path bad = dir / "bad_box.json";
    const auto refused_with = [&](const std::function<void(nlohmann::json&)>& change, const std::vector<std::string>& now) {
      nlohmann::json j = nlohmann::json::parse(good);
      change(j);
      std::ofstream(bad, std::ios::trunc) << j.dump();
      return plan_refusal(cfg, now, dir / "refused_plan", bad);
    };
    {
      const std::string what = refused_with([](nlohmann::json& j) { j["format"] = "hapticloud grid box 0"; }, sets);
      EXPECT_NE(what.find(bad.string() + ": not a grid box of this version"), std::string::npos) << what;
    }
    {
      const std::string what = refused_with([](nlohmann::json& j) { std::swap(j["box"]["x_min_m"], j["box"]["x_max_m"]); }, sets);
      EXPECT_NE(what.find("box has a minimum above its maximum"), std::string::npos) << what;
    }
    {
      const std::string what = refused_with([](nlohmann::json& j) { j["box"].erase("points"); }, sets);
      EXPECT_NE(what.find(bad.string() + ": box: not as hapticloud tile-merge writes a grid box"), std::string::npos) << what;
    }
    {
      const std::string what = refused_with([](nlohmann::json& j) { j["box"]["points"] = -1; }, sets);
      EXPECT_NE(what.find("box.points is -1, expected the count of the points the box holds"), std::string::npos) << what;
    }
    {
      const std::string what = refused_with([](nlohmann::json& j) { j["resolved_yaml"] = "grid: {n: [200"; }, sets);
      EXPECT_NE(what.find(bad.string() + ": resolved_yaml is not YAML text"), std::string::npos) << what;
    }
    {
      std::vector<std::string> other = sets;
      other.push_back("grid.n=210");
      const std::string what = refused_with([](nlohmann::json&) {}, other);
      EXPECT_NE(what.find("resolves to other values outside scale"), std::string::npos) << what;
    }
    {
      const std::string what = refused_with([](nlohmann::json& j) { j["offset_m"][0] = "0x1p-3"; }, sets);
      EXPECT_NE(what.find("the same input files recentred otherwise"), std::string::npos) << what;
    }
    {
      const std::string what = refused_with([](nlohmann::json& j) { j["inputs"][0]["sha256"] = std::string(64, '0'); }, sets);
      EXPECT_NE(what.find("other input files"), std::string::npos) << what;
    }
  }
}

}  // namespace tile_jobs_test
