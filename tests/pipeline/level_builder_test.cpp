// The streaming level builder (issue 14): the coarser levels of a tiled scene made tile by tile
// from the stored level above. Oracle: the in-memory pyramid (LodPyramid) of the same level 0,
// which builds every level whole (downsample_2x over the whole finer grid, compute_surface_layers
// over the whole level; lod_test.cpp and surface_layers_test.cpp check those against brute force
// and analytic surfaces). Every stored level must equal it bit for bit.

#include "height_field_bits.hpp"
#include "file_bytes.hpp"
#include "test_paths.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/level_builder.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <vector>

namespace level_builder_test {

namespace fs = std::filesystem;
using hc::GridGeometry;
using hc::HeightField;
using hc::pipeline::LodLevel;
using hc::pipeline::LodPyramid;
using hc::test::differing_bits;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

/// rows × cols samples of a relief that is hard on the tiles: carved grooves, a 5 cm cliff
/// along a diagonal, noise of 0.3 mm, no data in two blocks that straddle tile corners and
/// in a ragged band (scan shadows), colour from the position and a cross-check error field.
/// `void_corner`: no data in the last 100 rows' first 130 columns too (tiles whose windows hold
/// no sample, which the builder leaves sparse without computing them).
hc::Scene hard_scene(int rows, int cols, bool layers, bool void_corner = false) {
  std::mt19937 rng(11);
  std::normal_distribution<float> noise(0.0f, 3e-4f);
  hc::Scene s;
  s.geometry = GridGeometry{rows, cols, -0.2, 0.1, 0.001};
  HeightField d(s.geometry), err(s.geometry);
  s.layers.colour_rgb8.assign(3 * s.geometry.cell_count(), 0);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      const std::size_t i = static_cast<std::size_t>(r) * static_cast<std::size_t>(cols) + static_cast<std::size_t>(c);
      const bool hole = (r >= 40 && r < 75 && c >= 50 && c < 90) || (r >= 150 && r < 170 && c >= 200 && c < 300) ||
                        (std::abs(c - 2 * r + 100) < 3 + (r * 7 % 5)) ||
                        (void_corner && r >= rows - 100 && c < 130);
      if (hole) continue;
      const double groove = 0.004 * std::sin(0.31 * c) * std::sin(0.17 * r);
      const double cliff = c > r + 60 ? 0.05 : 0.0;
      d.data()[i] = static_cast<float>(1.5 + 0.02 * std::sin(0.01 * r) + groove + cliff) + noise(rng);
      err.data()[i] = static_cast<float>(1e-4 * ((r * 13 + c * 7) % 11));
      s.layers.colour_rgb8[3 * i] = static_cast<std::uint8_t>((r * 3) % 256);
      s.layers.colour_rgb8[3 * i + 1] = static_cast<std::uint8_t>((c * 5) % 256);
      s.layers.colour_rgb8[3 * i + 2] = static_cast<std::uint8_t>((r + c) % 256);
    }
  }
  s.layers.depth = std::move(d);
  s.layers.cell_error = std::move(err);
  s.lod.min_cells = 8;
  s.lod.window_cells = 40;
  if (layers) {
    hc::pipeline::SurfaceLayers l = hc::pipeline::compute_surface_layers(s.layers.depth, s.layer_options, s.lod.window_cells).value;
    s.layers.envelope = std::move(l.envelope_m);
    s.layers.texture = std::move(l.texture_m);
    s.layers.mu_d = std::move(l.mu_d);
    s.layers.mu_s = std::move(l.mu_s);
  }
  return s;
}

/// Level 0 of `s` as a tiled scene folder whose levels are not built yet.
fs::path write_level0(const hc::Scene& s, const fs::path& dir, int tile, int levels) {
  const fs::path scene_dir = dir / "scene";
  hc::pipeline::write_scene(s, scene_dir, hc::SceneStorage{tile, levels});
  return scene_dir;
}

/// Every level of the stored pyramid against the in-memory one, layer by layer, bit for bit.
void expect_levels_equal(const fs::path& scene_dir, const hc::Scene& s) {
  hc::LodOptions big = s.lod;
  big.memory_budget_mb = 4096;
  auto stored = LodPyramid::open_stored(scene_dir, big);
  auto mem = LodPyramid::from_scene(hc::Scene(s), s.layer_options, big);
  ASSERT_EQ(stored->level_count(), mem->level_count());
  for (int level = 0; level < mem->level_count(); ++level) {
    const auto a = stored->level(level);
    const auto b = mem->level(level);
    ASSERT_TRUE(a->has_layers);
    EXPECT_EQ(differing_bits(a->depth_m, b->depth_m), 0u) << "depth, level " << level;
    EXPECT_EQ(differing_bits(a->envelope_m, b->envelope_m), 0u) << "envelope, level " << level;
    EXPECT_EQ(differing_bits(a->texture_m, b->texture_m), 0u) << "texture, level " << level;
    EXPECT_EQ(differing_bits(a->mu_d, b->mu_d), 0u) << "mu_d, level " << level;
    EXPECT_EQ(differing_bits(a->mu_s, b->mu_s), 0u) << "mu_s, level " << level;
    EXPECT_EQ(differing_bits(a->cell_error_m, b->cell_error_m), 0u) << "cell_error, level " << level;
    EXPECT_EQ(a->colour_rgb8, b->colour_rgb8) << "colour, level " << level;
    EXPECT_GT(b->depth_m.valid_count(), 0u) << "level " << level;  // the comparison saw data
  }
}

TEST(LevelBuilder, LevelsBuiltTileByTileEqualTheInMemoryPyramidBitForBit) {
  // Sizes that are not multiples of the tile, tiles of 32 samples: every level has partial
  // tiles, and holes and the cliff cross tile edges at every level.
  const hc::Scene s = hard_scene(301, 517, true);
  const fs::path dir = hc::test::temp_dir("hard");
  const int levels = hc::pipeline::lod_level_count(s.geometry, s.lod.min_cells);
  ASSERT_GE(levels, 5);
  const fs::path scene_dir = write_level0(s, dir, 32, levels);
  std::vector<std::string> told;
  const hc::pipeline::StoredLevelsReport rep =
      hc::pipeline::build_stored_levels(scene_dir, dir / "scratch", [&](const std::string& what, double) {
        if (told.empty() || told.back() != what) told.push_back(what);
      });
  EXPECT_EQ(rep.levels_built, levels - 1);
  EXPECT_FALSE(rep.level0_layers);
  EXPECT_GT(rep.bytes, 0u);
  EXPECT_FALSE(told.empty());
  // Nothing is left in the scratch folder.
  EXPECT_TRUE(fs::is_empty(dir / "scratch"));
  expect_levels_equal(scene_dir, s);
  // The largest buffer is a row of tiles or a block with its halo, not a level.
  EXPECT_LT(rep.peak_buffer_bytes, s.geometry.cell_count() * 4 * 3);
}

TEST(LevelBuilder, ASceneWithoutLayersGetsLevelZerosLayersAndOtherFrictionOptionsHold) {
  // Layers off in the run: level 0's layers are computed into levels/L0; the curvature
  // friction model in scene units and static-friction regions across tile edges.
  hc::Scene s = hard_scene(190, 260, false, true);
  s.layer_options.friction_model = hc::FrictionModel::kCurvature;
  s.layer_options.friction_scale = hc::FrictionScale::kScene;
  s.layer_options.mu_s_regions = {{-0.19, 0.12, -0.1, 0.2, 0.9}, {-0.15, 0.15, 0.0, 0.25, 0.1}};
  s.layer_options.sigma_space_cells = 3.5;
  s.lod.antialias_sigma_cells = 1.5;
  s.lod.valid_fraction = 0.6;
  const fs::path dir = hc::test::temp_dir("nolayers");
  const int levels = hc::pipeline::lod_level_count(s.geometry, s.lod.min_cells);
  const fs::path scene_dir = write_level0(s, dir, 16, levels);
  const hc::pipeline::StoredLevelsReport rep = hc::pipeline::build_stored_levels(scene_dir, dir / "scratch");
  EXPECT_TRUE(rep.level0_layers);
  EXPECT_TRUE(fs::exists(scene_dir / "levels" / "L0" / "mu_d.tiff"));
  EXPECT_FALSE(fs::exists(scene_dir / "mu_d.tiff"));  // level 0's own files are left as written
  expect_levels_equal(scene_dir, s);
}

TEST(LevelBuilder, LevelZerosLayersIntoTheSceneFolderAreListedAndEqualTheWholeGridsAndAFailureLeavesNone) {
  // Level0Layers::kSceneFolder: level 0's layers beside depth.tiff, listed in scene.yaml. Oracle:
  // compute_surface_layers on the whole level 0 in memory (hard_scene with layers), and the same
  // scene written whole by write_scene (its scene.yaml, byte for byte).
  const hc::Scene with = hard_scene(190, 260, true);
  hc::Scene without = hard_scene(190, 260, false);
  without.friction_model = with.layer_options.friction_model;  // as a run that left the layers to the builder
  without.provenance.resolved_config_yaml = "name: relief\ngrid:\n  n: 260  # cells\n";
  hc::Scene with_prov = with;
  with_prov.friction_model = with.layer_options.friction_model;
  with_prov.provenance = without.provenance;
  const fs::path dir = hc::test::temp_dir("level0_root");
  const int levels = hc::pipeline::lod_level_count(with.geometry, with.lod.min_cells);
  for (const char* sub : {"failing", "built", "whole"}) fs::create_directories(dir / sub);

  // A scratch "folder" that is a file: the build stops at level 0's median, after its layer files
  // were opened, and neither levels/ nor any of them stays; scene.yaml is as written.
  const fs::path failing = write_level0(without, dir / "failing", 32, levels);
  const std::string yaml_before = hc::test::read_bytes(failing / "scene.yaml");
  std::ofstream(dir / "a_file") << "not a folder";
  EXPECT_THROW(hc::pipeline::build_stored_levels(failing, dir / "a_file", {},
                                                 hc::pipeline::Level0Layers::kSceneFolder),
               hc::InputError);
  EXPECT_FALSE(fs::exists(failing / "levels"));
  for (const char* name : {"envelope.tiff", "texture.tiff", "mu_d.tiff", "mu_s.tiff"}) EXPECT_FALSE(fs::exists(failing / name)) << name;
  EXPECT_EQ(hc::test::read_bytes(failing / "scene.yaml"), yaml_before);

  const fs::path scene_dir = write_level0(without, dir / "built", 32, levels);
  fs::create_directories(dir / "scratch");
  const hc::pipeline::StoredLevelsReport rep =
      hc::pipeline::build_stored_levels(scene_dir, dir / "scratch", {}, hc::pipeline::Level0Layers::kSceneFolder);
  EXPECT_TRUE(rep.level0_layers);
  EXPECT_FALSE(fs::exists(scene_dir / "levels" / "L0"));
  const hc::Scene loaded = hc::pipeline::load_scene(scene_dir);
  ASSERT_TRUE(loaded.layers.has_surface_layers());
  EXPECT_EQ(differing_bits(loaded.layers.envelope, with.layers.envelope), 0u);
  EXPECT_EQ(differing_bits(loaded.layers.texture, with.layers.texture), 0u);
  EXPECT_EQ(differing_bits(loaded.layers.mu_d, with.layers.mu_d), 0u);
  EXPECT_EQ(differing_bits(loaded.layers.mu_s, with.layers.mu_s), 0u);
  EXPECT_GT(loaded.layers.texture.valid_count(), 30'000u);
  // scene.yaml is the one write_scene writes for the scene with its layers.
  const fs::path whole = write_level0(with_prov, dir / "whole", 32, levels);
  EXPECT_EQ(hc::test::read_bytes(scene_dir / "scene.yaml"), hc::test::read_bytes(whole / "scene.yaml"));
  EXPECT_NE(hc::test::read_bytes(scene_dir / "scene.yaml").find("  n: 260  # cells"), std::string::npos);  // the config's text kept
  expect_levels_equal(scene_dir, with);
}

TEST(LevelBuilder, TheBuddhaScenesLevelsEqualTheInMemoryPyramid) {
  hc::test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz");
  const std::string cfg = std::string(HC_SOURCE_DIR) + "/configs/happy_buddha.yaml";
  const hc::pipeline::RunConfig config = hc::pipeline::load_run_config(cfg, {"grid.n=400", "lod.report=false"});
  const hc::pipeline::BuiltScene built = hc::pipeline::build_scene(config);
  const fs::path dir = hc::test::temp_dir("buddha");
  hc::pipeline::write_run(built, config, dir / "run");
  const hc::Scene s = hc::pipeline::load_scene(dir / "run" / "scene");
  ASSERT_TRUE(s.layers.has_surface_layers());
  const int levels = hc::pipeline::lod_level_count(s.geometry, s.lod.min_cells);
  const fs::path scene_dir = write_level0(s, dir, 64, levels);
  hc::pipeline::build_stored_levels(scene_dir, dir / "scratch");
  expect_levels_equal(scene_dir, s);
}

TEST(LevelBuilder, BuiltLevelsAndAFailedBuildAreNamedAndLeaveNoLevelsFolder) {
  const hc::Scene s = hard_scene(120, 140, true);
  const fs::path dir = hc::test::temp_dir("errors");
  const int levels = hc::pipeline::lod_level_count(s.geometry, s.lod.min_cells);
  const fs::path scene_dir = write_level0(s, dir, 32, levels);
  hc::pipeline::build_stored_levels(scene_dir, dir / "scratch");
  try {
    hc::pipeline::build_stored_levels(scene_dir, dir / "scratch");
    ADD_FAILURE() << "a second build over built levels was accepted";
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("levels folder already exists"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(fs::exists(scene_dir / "levels" / "L1" / "depth.tiff"));  // the first build is kept

  // A level-0 layer file cut short: the error names it and no levels folder is left behind.
  fs::create_directory(dir / "cut");
  const fs::path other = write_level0(s, dir / "cut", 32, levels);
  const fs::path colour = other / "colour.tiff";
  fs::resize_file(colour, fs::file_size(colour) / 2);
  try {
    hc::pipeline::build_stored_levels(other, dir / "scratch");
    ADD_FAILURE() << "a cut colour file was accepted";
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("colour.tiff"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(other / "levels"));

  // An infinite height in level 0 (a scene no run writes, edited by hand): named by sample.
  hc::Scene inf = s;
  inf.layers.depth.at(37, 101) = std::numeric_limits<float>::infinity();
  fs::create_directory(dir / "inf");
  const fs::path inf_dir = write_level0(inf, dir / "inf", 32, levels);
  try {
    hc::pipeline::build_stored_levels(inf_dir, dir / "scratch");
    ADD_FAILURE() << "an infinite depth was accepted";
  } catch (const hc::InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("depth.tiff"), std::string::npos) << what;
    EXPECT_NE(what.find("(37, 101) is infinite"), std::string::npos) << what;
  }
  EXPECT_FALSE(fs::exists(inf_dir / "levels"));

  // A scene written whole (format 2) has no tiles to build from.
  const fs::path whole = dir / "whole";
  hc::pipeline::write_scene(s, whole);
  try {
    hc::pipeline::build_stored_levels(whole, dir / "scratch");
    ADD_FAILURE() << "an untiled scene was accepted";
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("not a tiled scene"), std::string::npos) << e.what();
  }
}

}  // namespace level_builder_test
