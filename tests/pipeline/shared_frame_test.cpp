// input.shared_frame (issue 14, whole sites in several files): a scan given as several files in
// one frame gives the scene of the one file that holds all their points in the same order. The
// oracle is that one file, written by this test from the same generated points
// (hc::tools::relief_point): its scene, in core and tiled, must equal the parts' bit for bit.
// Also: colour that one part lacks is dropped in both runs alike, two CRS are refused naming both
// files, and several files without input.conf or input.shared_frame are refused naming both keys.
// input.conf (raw scans placed by their poses, the Buddha's real scans and scanalyze .conf): the
// tiled run streams them; its oracle is the in-core merge (load_and_merge_scans, whose pose
// convention ingest_test.cpp proves by the overlap of neighbouring views): the same scene, and
// the stream's points the merge's bit for bit in any chunk size.

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/point_stream.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/tiling.hpp"
#include "hc/tools/relief.hpp"

#include "error_of.hpp"
#include "height_field_bits.hpp"
#include "stage_figure.hpp"
#include "test_paths.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <iomanip>
#include <limits>
#include <random>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using hc::pipeline::BuiltScene;
using hc::pipeline::RunConfig;
using hc::test::differing_bits;

hc::tools::ReliefSpec wall_spec() {
  hc::tools::ReliefSpec spec;
  spec.width_m = 0.6;
  spec.height_m = 0.4;
  spec.points = 240'000;
  spec.rgb = true;
  spec.outlier_fraction = 0.002;
  return spec;
}

// Points [first, last) of the generated wall as a binary little-endian PLY: x y z float [m],
// red green blue uchar when `rgb`.
void write_ply(const fs::path& file, std::uint64_t first, std::uint64_t last, bool rgb) {
  const hc::tools::ReliefSpec spec = wall_spec();
  std::ofstream out(file, std::ios::binary);
  out << "ply\nformat binary_little_endian 1.0\nelement vertex " << last - first
      << "\nproperty float x\nproperty float y\nproperty float z\n";
  if (rgb) out << "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  out << "end_header\n";
  for (std::uint64_t i = first; i < last; ++i) {
    const hc::tools::ReliefPoint p = hc::tools::relief_point(spec, i);
    const float f[3] = {static_cast<float>(p.x_m), static_cast<float>(p.y_m), static_cast<float>(p.z_m)};
    out.write(reinterpret_cast<const char*>(f), sizeof f);
    if (rgb) {
      const unsigned char c[3] = {p.r, p.g, p.b};
      out.write(reinterpret_cast<const char*>(c), sizeof c);
    }
  }
  ASSERT_TRUE(out.good()) << file;
}

// The same points as text lines "x y z": each float's value printed exactly (17 significant
// digits of the double it widens to), so the text reads back to the same doubles.
void write_xyz(const fs::path& file, std::uint64_t first, std::uint64_t last) {
  const hc::tools::ReliefSpec spec = wall_spec();
  std::ofstream out(file, std::ios::binary);
  out << std::setprecision(std::numeric_limits<double>::max_digits10);
  for (std::uint64_t i = first; i < last; ++i) {
    const hc::tools::ReliefPoint p = hc::tools::relief_point(spec, i);
    out << static_cast<double>(static_cast<float>(p.x_m)) << ' ' << static_cast<double>(static_cast<float>(p.y_m)) << ' '
        << static_cast<double>(static_cast<float>(p.z_m)) << '\n';
  }
  ASSERT_TRUE(out.good()) << file;
}

RunConfig config_of(const fs::path& dir, const std::string& files, bool tiled, bool outliers) {
  const std::string yaml = "input: {files: [" + files + "], units: m" + (files.find(',') != std::string::npos ? ", shared_frame: true" : "") +
                           "}\n"
                           "grid: {n: 500, splat_radius_cells: 1.2, splat_mode: plane, see_through_depth_m: 0.02, "
                           "hole_fill_max_cells: 64}\n"
                           "cross_check: {tolerance_m: 0.002}\n"
                           "filters: {outliers: {enabled: " +
                           std::string(outliers ? "true" : "false") +
                           "}}\n"
                           "scale: {chunk_points: 7000, tile_cells: 96, tiled: " +
                           (tiled ? "'on'" : "'off'") + "}\n";
  RunConfig c = hc::pipeline::parse_run_config(yaml, dir / "run.yaml");
  if (tiled) {
    c.scale.scratch = dir / "scratch";
    fs::create_directories(c.scale.scratch);
  }
  return c;
}

bool has_note(const BuiltScene& b, const std::string& text) {
  for (const auto& s : b.summary.stages)
    for (const auto& note : s.notes)
      if (note.find(text) != std::string::npos) return true;
  return false;
}

using hc::test::stage_figure;

// Every layer bit for bit, the frame, and the cross-check's figures: equal, except the cells'
// nearest-point distances between an in-core and a tiled run (`exact_cells` false), which each
// tile takes in its own float frame (to 1e-6 of the scene's extent, as tiled_run_test.cpp).
void expect_same_scene(const BuiltScene& a, const BuiltScene& b, const char* what, bool exact_cells = true) {
  SCOPED_TRACE(what);
  EXPECT_EQ(a.scene.geometry, b.scene.geometry);
  EXPECT_EQ(a.scene.model_to_grid.matrix(), b.scene.model_to_grid.matrix());
  hc::test::expect_same_layers(a.scene.layers, b.scene.layers);
  ASSERT_TRUE(a.summary.cross_check && b.summary.cross_check);
  const auto& p = *a.summary.cross_check;
  const auto& q = *b.summary.cross_check;
  EXPECT_EQ(p.point_vertical.count, q.point_vertical.count);
  EXPECT_EQ(p.point_vertical.max_mm, q.point_vertical.max_mm);
  EXPECT_EQ(p.point_vertical.p95_mm, q.point_vertical.p95_mm);
  EXPECT_EQ(p.points_off_surface, q.points_off_surface);
  EXPECT_EQ(p.cell_to_point.count, q.cell_to_point.count);
  if (exact_cells) {
    EXPECT_EQ(p.cell_to_point.max_mm, q.cell_to_point.max_mm);
  } else {
    const double extent_mm = 1e3 * a.scene.geometry.cell_size_m * std::max(a.scene.geometry.rows, a.scene.geometry.cols);
    EXPECT_NEAR(p.cell_to_point.max_mm, q.cell_to_point.max_mm, 1e-6 * extent_mm);
  }
}

// The wall as one file and as parts, in a folder of the calling test's own (ctest runs tests in
// parallel processes).
fs::path write_wall_and_parts() {
  const fs::path dir = hc::test::temp_dir("shared_frame");
  const std::uint64_t n = wall_spec().points;
  write_ply(dir / "whole.ply", 0, n, true);
  write_ply(dir / "a.ply", 0, 70'001, true);
  write_ply(dir / "b.ply", 70'001, 160'000, true);
  write_ply(dir / "c.ply", 160'000, n, true);
  write_xyz(dir / "b.xyz", 70'001, 160'000);
  return dir;
}

// Three parts equal the one file, in core and tiled, with the robust outlier filter on (the
// points in the same order give the same sample, scale and verdicts); and the tiled run of the
// parts equals their in-core run (filter off: the tiled grid box is taken before the filter).
TEST(SharedFrame, ThreePartsGiveTheSceneOfTheOneFileHoldingThemAll) {
  const fs::path d = write_wall_and_parts();
  for (const bool tiled : {false, true}) {
    const BuiltScene whole = hc::pipeline::build_scene(config_of(d, "whole.ply", tiled, true));
    const BuiltScene parts = hc::pipeline::build_scene(config_of(d, "a.ply, b.ply, c.ply", tiled, true));
    EXPECT_EQ(whole.from_tiled_run, tiled);
    EXPECT_EQ(parts.from_tiled_run, tiled);
    expect_same_scene(whole, parts, tiled ? "tiled, outliers on" : "in core, outliers on");
    EXPECT_FALSE(parts.scene.layers.colour_rgb8.empty());
    if (tiled) {
      EXPECT_GT(stage_figure(parts, "tile_plan", "tiles"), 4.0);
      EXPECT_TRUE(has_note(parts, "c.ply: 80000 points"));
      EXPECT_FALSE(has_note(parts, "read whole"));
      EXPECT_TRUE(fs::is_empty(d / "scratch"));
    } else {
      EXPECT_EQ(stage_figure(parts, "ingest", "files"), 3.0);
    }
    // The provenance lists every part with its checksum, in order.
    ASSERT_EQ(parts.scene.provenance.inputs.size(), 3U);
    EXPECT_EQ(fs::path(parts.scene.provenance.inputs[1].file).filename(), "b.ply");
    EXPECT_EQ(parts.scene.provenance.inputs[1].sha256.size(), 64U);
  }
  // scale.tiled: auto counts the parts' points together (each part alone is below the bound).
  RunConfig aut = config_of(d, "a.ply, b.ply, c.ply", false, false);
  aut.scale.tiled = hc::pipeline::ScaleConfig::Tiled::kAuto;
  aut.scale.tiled_above_points = 200'000;
  EXPECT_TRUE(hc::pipeline::runs_tiled(aut));
  aut.scale.tiled_above_points = 240'000;
  EXPECT_FALSE(hc::pipeline::runs_tiled(aut));
  const BuiltScene in = hc::pipeline::build_scene(config_of(d, "a.ply, b.ply, c.ply", false, false));
  const BuiltScene tiled = hc::pipeline::build_scene(config_of(d, "a.ply, b.ply, c.ply", true, false));
  expect_same_scene(in, tiled, "parts, in core against tiled, outliers off", false);
}

// Tile jobs (hapticloud tile-plan, tile-job, tile-merge: another process could run each) on the
// three parts: the plan file lists the three inputs, and the merged scene is the one file's
// tiled scene.
TEST(SharedFrame, TileJobsOnThePartsMergeIntoTheOneFilesScene) {
  const fs::path d = write_wall_and_parts();
  const BuiltScene whole = hc::pipeline::build_scene(config_of(d, "whole.ply", true, true));
  // The config as a file for the plan (tile jobs reload it).
  const RunConfig parts = config_of(d, "a.ply, b.ply, c.ply", true, true);
  std::ofstream(d / "parts.yaml") << parts.resolved_yaml;
  const auto info = hc::pipeline::write_tile_plan(d / "parts.yaml", {}, d / "work");
  ASSERT_GT(info.tiles, 4U);
  std::ifstream plan(info.plan_file);
  const std::string text((std::istreambuf_iterator<char>(plan)), std::istreambuf_iterator<char>());
  for (const char* f : {"a.ply", "b.ply", "c.ply"}) EXPECT_NE(text.find(f), std::string::npos) << f;
  std::vector<std::size_t> all(info.tiles);
  for (std::size_t t = 0; t < info.tiles; ++t) all[t] = t;
  hc::pipeline::run_tile_jobs(info.plan_file, all);
  const auto merged = hc::pipeline::merge_tile_jobs(info.plan_file);
  expect_same_scene(whole, merged.built, "tile jobs on the parts against the one file, tiled");
  ASSERT_EQ(merged.built.scene.provenance.inputs.size(), 3U);
  EXPECT_EQ(fs::path(merged.built.scene.provenance.inputs[2].file).filename(), "c.ply");
}

// A part without colour (b.xyz: the same points as text): colour is dropped in both runs, with a
// note naming the part, and the geometry is the one file's.
TEST(SharedFrame, APartWithoutColourDropsTheColourInBothRunsAlike) {
  const fs::path d = write_wall_and_parts();
  const BuiltScene whole = hc::pipeline::build_scene(config_of(d, "whole.ply", false, false));
  for (const bool tiled : {false, true}) {
    const BuiltScene mixed = hc::pipeline::build_scene(config_of(d, "a.ply, b.xyz, c.ply", tiled, false));
    SCOPED_TRACE(tiled ? "tiled" : "in core");
    EXPECT_TRUE(mixed.scene.layers.colour_rgb8.empty());
    EXPECT_TRUE(has_note(mixed, "rgb dropped: b.xyz has none"));
    EXPECT_EQ(mixed.scene.geometry, whole.scene.geometry);
    EXPECT_EQ(differing_bits(mixed.scene.layers.depth, whole.scene.layers.depth), 0U);
    EXPECT_EQ(differing_bits(mixed.scene.layers.texture, whole.scene.layers.texture), 0U);
  }
}

// The stream hands out the parts' points in order, as load_files_in_one_frame does, never a
// chunk across two files; total_points is the sum.
TEST(SharedFrame, TheStreamGivesTheConcatenationInChunksThatNeverSpanTwoFiles) {
  const fs::path d = write_wall_and_parts();
  const std::vector<fs::path> files = {d / "a.ply", d / "b.xyz", d / "c.ply"};
  const hc::pipeline::Cloud all = hc::pipeline::load_files_in_one_frame(files).value;
  const hc::pipeline::Cloud whole = hc::pipeline::load_cloud(d / "whole.ply").value;
  ASSERT_EQ(all.size(), whole.size());
  EXPECT_TRUE(all.xyz == whole.xyz);
  EXPECT_TRUE(all.rgb.empty());
  EXPECT_TRUE(all.float32_xyz);
  // Each file's points carry its own scan id (scanner rows and columns are per scan).
  ASSERT_EQ(all.scan_id.size(), all.size());
  EXPECT_EQ(std::count(all.scan_id.begin(), all.scan_id.end(), 0), 70'001);
  EXPECT_EQ(std::count(all.scan_id.begin(), all.scan_id.end(), 1), 89'999);
  EXPECT_EQ(std::count(all.scan_id.begin(), all.scan_id.end(), 2), 80'000);
  EXPECT_EQ(all.scan_id[70'000], 0);
  EXPECT_EQ(all.scan_id[70'001], 1);
  auto s = hc::pipeline::open_point_streams(files);
  EXPECT_EQ(s->total_points(), whole.size());
  hc::pipeline::Cloud chunk;
  Eigen::Index at = 0;
  std::vector<Eigen::Index> ends;
  while (s->next(chunk, 50'000)) {
    ASSERT_LE(at + chunk.xyz.cols(), all.xyz.cols());
    EXPECT_TRUE(chunk.xyz == all.xyz.middleCols(at, chunk.xyz.cols())) << "chunk at " << at;
    EXPECT_TRUE(chunk.rgb.empty());
    EXPECT_TRUE(chunk.float32_xyz);
    at += chunk.xyz.cols();
    ends.push_back(at);
  }
  EXPECT_EQ(at, all.xyz.cols());
  // 70 001 points: 50 000 and 20 001; 89 999: 50 000 and 39 999; 80 000: 50 000 and 30 000.
  EXPECT_EQ(ends, (std::vector<Eigen::Index>{50'000, 70'001, 120'001, 160'000, 210'000, 240'000}));
  EXPECT_TRUE(std::find(s->notes().begin(), s->notes().end(), "b.xyz: 89999 points") != s->notes().end());
}

// Two files declaring different CRS are refused by both readers, naming both files; one CRS twice
// is kept.
TEST(SharedFrameCrs, TwoDifferentCrsAreRefusedNamingBothFiles) {
  const fs::path nm = hc::test::scan_path("scanner_samples/las/pdal-test1_4.las");
  const fs::path other = hc::test::scan_path("scanner_samples/las/pdal-autzen_trim_7.las");
  const std::string crs_nm = hc::pipeline::load_cloud(nm).value.crs, crs_other = hc::pipeline::load_cloud(other).value.crs;
  ASSERT_FALSE(crs_nm.empty());
  ASSERT_FALSE(crs_other.empty());
  ASSERT_NE(crs_nm, crs_other);
  for (const std::string& m : {hc::test::error_of([&] { (void)hc::pipeline::load_files_in_one_frame({nm, other}); }),
                                hc::test::error_of([&] { (void)hc::pipeline::open_point_streams({nm, other}); })}) {
    EXPECT_NE(m.find("pdal-test1_4.las"), std::string::npos) << m;
    EXPECT_NE(m.find("pdal-autzen_trim_7.las"), std::string::npos) << m;
    EXPECT_NE(m.find("coordinate reference system"), std::string::npos) << m;
  }
  EXPECT_EQ(hc::pipeline::load_files_in_one_frame({nm, nm}).value.crs, crs_nm);
  EXPECT_EQ(hc::pipeline::open_point_streams({nm, nm})->crs(), crs_nm);
}

// Several files need input.conf (poses) or input.shared_frame (one frame), not both.
TEST(SharedFrameConfig, SeveralFilesNeedConfOrSharedFrameAndNotBoth) {
  const fs::path dir = hc::test::temp_dir("shared_frame_config");
  const auto error_of = [&](const std::string& input) {
    try {
      (void)hc::pipeline::parse_run_config("input: " + input + "\ngrid: {n: 64}\n", dir / "run.yaml");
    } catch (const hc::ConfigError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  const std::string neither = error_of("{files: [a.ply, b.ply]}");
  EXPECT_NE(neither.find("input.conf"), std::string::npos) << neither;
  EXPECT_NE(neither.find("input.shared_frame: true"), std::string::npos) << neither;
  const std::string both = error_of("{files: [a.ply, b.ply], conf: a.conf, shared_frame: true}");
  EXPECT_NE(both.find("input.shared_frame"), std::string::npos) << both;
  EXPECT_NE(both.find("input.conf"), std::string::npos) << both;
  EXPECT_EQ(error_of("{files: [a.ply, b.ply], shared_frame: true}"), "");
  const std::string wrong = error_of("{files: [a.ply, b.ply], shared_frame: maybe}");
  EXPECT_NE(wrong.find("input.shared_frame = 'maybe': expected true or false"), std::string::npos) << wrong;
}

// --- input.conf ----------------------------------------------------------------------------------

// The Buddha's raw scans at 0°, 24°, 48° and 72° (285 k points) and their real .conf.
std::vector<fs::path> raw_scans() {
  const fs::path raw = hc::test::scan_path("happy_buddha/raw_scans");
  return {raw / "happyStandRight_0.ply.gz", raw / "happyStandRight_24.ply.gz", raw / "happyStandRight_48.ply.gz",
          raw / "happyStandRight_72.ply.gz"};
}
fs::path raw_conf() { return hc::test::scan_path("happy_buddha/raw_scans/happyStandRight.conf"); }

RunConfig posed_config(const fs::path& dir, const std::vector<fs::path>& scans, bool tiled) {
  std::string files;
  for (const fs::path& f : scans) files += (files.empty() ? "" : ", ") + f.string();
  const std::string yaml = "input: {files: [" + files + "], conf: " + raw_conf().string() +
                           ", units: m}\n"
                           "grid: {n: 400, splat_radius_cells: 1.2, see_through_depth_m: 0.002, hole_fill_max_cells: 64}\n"
                           "cross_check: {tolerance_m: 0.0005}\n"
                           "filters: {outliers: {enabled: true}}\n"
                           "scale: {chunk_points: 20000, tile_cells: 64, tiled: " +
                           std::string(tiled ? "'on'" : "'off'") + "}\n";
  RunConfig c = hc::pipeline::parse_run_config(yaml, dir / "run.yaml");
  c.scale.scratch = dir / "scratch";
  fs::create_directories(c.scale.scratch);
  return c;
}

// The tiled run of raw scans placed by their poses equals the in-core merge's run (robust
// filter and cross-check on), streams every scan, leaves nothing in the scratch folder, and lists
// the scans and the .conf in the provenance as the in-core run does; scale.tiled: auto counts
// the scans' points together.
TEST(PosedScans, TheTiledRunOfRawScansEqualsTheInCoreMerge) {
  const fs::path d = hc::test::temp_dir("posed_scans");
  const BuiltScene in = hc::pipeline::build_scene(posed_config(d, raw_scans(), false));
  const BuiltScene tiled = hc::pipeline::build_scene(posed_config(d, raw_scans(), true));
  EXPECT_FALSE(in.from_tiled_run);
  ASSERT_TRUE(tiled.from_tiled_run);
  EXPECT_GT(stage_figure(tiled, "tile_plan", "tiles"), 4.0);
  expect_same_scene(in, tiled, "raw scans by their poses, in core against tiled", false);
  EXPECT_GT(in.scene.geometry.rows * in.scene.geometry.cols, 50'000);
  EXPECT_FALSE(has_note(tiled, "read whole"));
  std::size_t total = 0, last = 0;  // the scans' points as load_cloud reads each
  for (const fs::path& f : raw_scans()) total += (last = hc::pipeline::load_cloud(f).value.size());
  EXPECT_TRUE(has_note(tiled, "happyStandRight_72.ply.gz: " + std::to_string(last) + " points"));
  EXPECT_TRUE(fs::is_empty(d / "scratch"));
  for (const BuiltScene* b : {&in, &tiled}) {
    const auto& inputs = b->scene.provenance.inputs;
    ASSERT_EQ(inputs.size(), 5U);
    EXPECT_EQ(fs::path(inputs[1].file).filename(), "happyStandRight_24.ply.gz");
    EXPECT_EQ(fs::path(inputs[4].file).filename(), "happyStandRight.conf");
    EXPECT_EQ(inputs[4].sha256.size(), 64U);
  }
  RunConfig aut = posed_config(d, raw_scans(), false);
  aut.scale.tiled = hc::pipeline::ScaleConfig::Tiled::kAuto;
  ASSERT_GT(total, 250'000U);
  aut.scale.tiled_above_points = total - 1;
  EXPECT_TRUE(hc::pipeline::runs_tiled(aut));
  aut.scale.tiled_above_points = total;
  EXPECT_FALSE(hc::pipeline::runs_tiled(aut));
}

// The posed stream hands out the in-core merge's points bit for bit, in its order, in chunks of
// 1, 13 (sizes at which an Eigen product takes another kernel) and 50 000 points, never across two
// scans, with no float32 flag (posed coordinates are no file's floats).
TEST(PosedScans, TheStreamGivesTheMergesPointsBitForBitInAnyChunkSize) {
  const std::vector<fs::path> scans = {raw_scans()[0], raw_scans()[1]};
  const hc::pipeline::Cloud merged = hc::pipeline::load_and_merge_scans(scans, raw_conf()).value;
  ASSERT_EQ(merged.size(), 78'056U + 75'582U);
  for (const std::size_t chunk_points : {std::size_t{1}, std::size_t{13}, std::size_t{50'000}}) {
    SCOPED_TRACE(chunk_points);
    auto s = hc::pipeline::open_posed_point_streams(scans, raw_conf());
    EXPECT_EQ(s->total_points(), merged.size());
    EXPECT_EQ(s->crs(), "");
    hc::pipeline::Cloud chunk;
    Eigen::Index at = 0;
    bool same = true, float32 = false, spans = false;
    while (s->next(chunk, chunk_points)) {
      ASSERT_LE(at + chunk.xyz.cols(), merged.xyz.cols());
      same = same && std::memcmp(chunk.xyz.data(), merged.xyz.col(at).data(), sizeof(double) * 3 * chunk.size()) == 0;
      float32 = float32 || chunk.float32_xyz;
      spans = spans || (at < 78'056 && at + chunk.xyz.cols() > 78'056);
      at += chunk.xyz.cols();
    }
    EXPECT_EQ(at, merged.xyz.cols());
    EXPECT_TRUE(same);
    EXPECT_FALSE(float32);
    EXPECT_FALSE(spans);
  }
}

// move_to_world is the pose's affine map (Eigen's product as the oracle, to rounding), also for
// a pose with a translation far from the origin.
TEST(PosedScans, MoveToWorldIsThePosesAffineMap) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  const auto poses = hc::pipeline::scan_poses(raw_scans(), raw_conf());
  ASSERT_EQ(poses.size(), 4U);
  std::vector<Eigen::Affine3d> all(poses.begin(), poses.end());
  Eigen::Affine3d far = poses[2];
  far.translation() += Eigen::Vector3d(1e5, -3e4, 12.0);
  all.push_back(far);
  for (const Eigen::Affine3d& m : all) {
    Eigen::Matrix3Xd p(3, 257);
    for (Eigen::Index i = 0; i < p.size(); ++i) p.data()[i] = u(rng);
    Eigen::Matrix3Xd q = p;
    hc::pipeline::move_to_world(m, q);
    for (Eigen::Index i = 0; i < p.cols(); ++i) {
      const Eigen::Vector3d want = m * Eigen::Vector3d(p.col(i));
      EXPECT_LE((q.col(i) - want).cwiseAbs().maxCoeff(), 4.0 * std::numeric_limits<double>::epsilon() * (want.cwiseAbs().maxCoeff() + 2.0))
          << i;
    }
  }
}

// A scan the .conf has no pose for stops both runs before any scan is read, naming the scan and
// the .conf; the tiled run leaves nothing in its scratch folder.
TEST(PosedScans, AScanWithoutAPoseIsRefusedNamingItAndTheConf) {
  const fs::path d = hc::test::temp_dir("posed_scans_stray");
  fs::copy_file(raw_scans()[0], d / "stray.ply.gz", fs::copy_options::overwrite_existing);
  for (const bool tiled : {false, true}) {
    SCOPED_TRACE(tiled ? "tiled" : "in core");
    const std::string m = hc::test::error_of([&] { (void)hc::pipeline::build_scene(posed_config(d, {raw_scans()[0], d / "stray.ply.gz"}, tiled)); });
    EXPECT_NE(m.find("stray.ply.gz"), std::string::npos) << m;
    EXPECT_NE(m.find("happyStandRight.conf"), std::string::npos) << m;
    EXPECT_NE(m.find("no bmesh line"), std::string::npos) << m;
  }
  EXPECT_TRUE(fs::is_empty(d / "scratch"));
}

}  // namespace
