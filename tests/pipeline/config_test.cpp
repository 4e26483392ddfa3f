#include "hc/pipeline/config.hpp"

#include "hc/common/error.hpp"

#include <gtest/gtest.h>

#include "test_paths.hpp"
#include "config_error.hpp"

#include <algorithm>
#include <fstream>

namespace {

using hc::pipeline::parse_run_config;
using hc::test::config_error;

const std::string kMinimal = "input:\n  files: [scan.ply]\n";

TEST(Config, DefaultsAreFilledAndPathsResolvedAgainstTheConfigFolder) {
  const auto c = parse_run_config(kMinimal, "configs/test.yaml");
  ASSERT_EQ(c.input.files.size(), 1u);
  EXPECT_EQ(c.input.files[0], std::filesystem::path("configs/scan.ply"));
  EXPECT_EQ(c.name, "test");
  EXPECT_EQ(c.grid.reproject.grid.n_long_side, 800);
  EXPECT_TRUE(c.filters.outliers.enabled);
  EXPECT_EQ(c.filters.outliers.k, 16);
  EXPECT_NE(c.resolved_yaml.find("n: 800"), std::string::npos) << c.resolved_yaml;
  EXPECT_NE(c.resolved_yaml.find("std_multiplier: 2"), std::string::npos);
  // The naive grid's comparison is a report extra (a third gridding): by request only.
  EXPECT_FALSE(c.cross_check.compare_naive);
  EXPECT_TRUE(parse_run_config(kMinimal + "cross_check: {compare_naive: true}\n", "configs/test.yaml").cross_check.compare_naive);
}

TEST(Config, UnknownKeyIsNamedWithItsLineAndTheAllowedKeys) {
  const std::string msg = config_error(kMinimal + "grid:\n  n: 400\n  nn: 3\n");
  EXPECT_NE(msg.find("configs/test.yaml:5"), std::string::npos) << msg;
  EXPECT_NE(msg.find("grid.nn"), std::string::npos) << msg;
  EXPECT_NE(msg.find("cell_size_m"), std::string::npos) << msg;  // the allowed keys are listed
  EXPECT_NE(config_error(kMinimal + "grdi: {n: 3}\n").find("unknown key 'grdi'"), std::string::npos);
}

TEST(Config, WrongTypeAndOutOfRangeNameKeyLineValueAndRange) {
  std::string msg = config_error(kMinimal + "grid:\n  n: lots\n");
  EXPECT_NE(msg.find("configs/test.yaml:4"), std::string::npos) << msg;
  EXPECT_NE(msg.find("grid.n"), std::string::npos) << msg;
  EXPECT_NE(msg.find("'lots'"), std::string::npos) << msg;
  EXPECT_NE(msg.find("integer"), std::string::npos) << msg;

  msg = config_error(kMinimal + "grid:\n  n: 1\n");  // N ≤ 1
  EXPECT_NE(msg.find("grid.n = 1"), std::string::npos) << msg;
  EXPECT_NE(msg.find("[2, 65536]"), std::string::npos) << msg;

  msg = config_error(kMinimal + "filters:\n  outliers: {std_multiplier: -1}\n");
  EXPECT_NE(msg.find("filters.outliers.std_multiplier = -1"), std::string::npos) << msg;
  EXPECT_NE(msg.find("(0, 100]"), std::string::npos) << msg;

  msg = config_error(kMinimal + "input:\n  files: [a]\n  units: inch\n");
  EXPECT_NE(msg.find("configs/test.yaml:3: duplicate key 'input' (first given on line 1)"), std::string::npos) << msg;
  msg = config_error("input:\n  files: [a]\n  units: inch\n");
  EXPECT_NE(msg.find("input.units = 'inch': expected one of: m, cm, mm"), std::string::npos) << msg;

  msg = config_error(kMinimal + "layers:\n  friction: {model: magic}\n");
  EXPECT_NE(msg.find("paper, curvature"), std::string::npos) << msg;
  msg = config_error(kMinimal + "layers:\n  friction: {mu_min: 0.5, mu_max: 0.1}\n");
  EXPECT_NE(msg.find("layers.friction.mu_max"), std::string::npos) << msg;
}

TEST(Config, ConflictingOrMissingChoicesAreErrors) {
  EXPECT_NE(config_error(kMinimal + "grid: {n: 100, cell_size_m: 0.001}\n").find("both n and cell_size_m"), std::string::npos);
  EXPECT_NE(config_error("grid: {n: 100}\n").find("input.files"), std::string::npos);
  EXPECT_NE(config_error("input:\n  files: [a.ply, b.ply]\n").find("input.conf"), std::string::npos);
  EXPECT_NE(config_error(kMinimal + "view:\n  rotation: {axis: [0,1,0], angle_deg: 10, euler_deg: [1,2,3]}\n")
                .find("mixes forms"), std::string::npos);
  EXPECT_NE(config_error(kMinimal + "view:\n  rotation: {axis: [0,0,0], angle_deg: 10}\n").find("non-zero axis"),
            std::string::npos);
}

TEST(Config, SetOverridesApplyBeforeValidationAndAreNamedInErrors) {
  const auto c = parse_run_config(kMinimal, "configs/test.yaml", {"grid.n=400", "view.rotation.axis=[0,1,0]",
                                                                  "view.rotation.angle_deg=90"});
  EXPECT_EQ(c.grid.reproject.grid.n_long_side, 400);
  const Eigen::Vector3d x = c.view.rotation * Eigen::Vector3d::UnitX();
  EXPECT_NEAR(x.z(), -1.0, 1e-12);  // +90° about y takes +x to −z
  const std::string msg = config_error(kMinimal, {"grid.n=0"});
  EXPECT_NE(msg.find("--set grid.n"), std::string::npos) << msg;
  EXPECT_NE(config_error(kMinimal, {"grid.n"}).find("key=value"), std::string::npos);
  EXPECT_NE(config_error(kMinimal, {"grid.bogus=3"}).find("unknown key 'grid.bogus'"), std::string::npos);
}

TEST(Config, InvalidYamlAndMissingFileAreInputErrorsWithPosition) {
  try {
    parse_run_config("input: [unclosed\n", "configs/bad.yaml");
    FAIL() << "expected an InputError";
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("configs/bad.yaml:"), std::string::npos) << e.what();
  }
  EXPECT_THROW(hc::pipeline::load_run_config("does/not/exist.yaml"), hc::InputError);
}

TEST(Config, StaticFrictionRegionsAreValidated) {
  const auto c = parse_run_config(
      kMinimal + "layers:\n  friction:\n    mu_s_regions:\n      - {x_min_m: 0, y_min_m: 0, x_max_m: 0.01, y_max_m: 0.02, mu_s: 0.4}\n",
      "configs/test.yaml");
  ASSERT_EQ(c.layers.options.mu_s_regions.size(), 1u);
  EXPECT_DOUBLE_EQ(c.layers.options.mu_s_regions[0].mu_s, 0.4);
  EXPECT_NE(config_error(kMinimal + "layers:\n  friction:\n    mu_s_regions:\n      - {x_min_m: 0, y_min_m: 0, x_max_m: 0.01, y_max_m: 0.02, mu: 0.4}\n")
                .find("unknown key"), std::string::npos);
}

TEST(Config, SplatModeIsReadAndValidated) {
  EXPECT_EQ(parse_run_config(kMinimal, "configs/test.yaml").grid.reproject.splat_mode, hc::pipeline::SplatMode::kDisc);
  EXPECT_EQ(parse_run_config(kMinimal + "grid: {splat_mode: interpolate}\n", "configs/test.yaml").grid.reproject.splat_mode,
            hc::pipeline::SplatMode::kInterpolate);
  EXPECT_EQ(parse_run_config(kMinimal + "grid: {splat_mode: plane}\n", "configs/test.yaml").grid.reproject.splat_mode,
            hc::pipeline::SplatMode::kPlane);
  EXPECT_NE(config_error(kMinimal + "grid: {splat_mode: blur}\n").find("grid.splat_mode = 'blur': expected one of: disc, interpolate, plane"),
            std::string::npos);
}

TEST(Config, UpsampleIsOffAutoOrAFactor) {
  const auto factor = [](const std::string& extra) {
    return parse_run_config(kMinimal + extra, "configs/test.yaml").grid.reproject.upsample_factor;
  };
  EXPECT_EQ(factor(""), 1);
  EXPECT_EQ(factor("grid: {upsample: off}\n"), 1);
  EXPECT_EQ(factor("grid: {upsample: auto}\n"), 0);
  EXPECT_EQ(factor("grid: {upsample: 4}\n"), 4);
  for (const std::string bad : {"0", "17", "2.5", "yes", "4x"}) {
    EXPECT_NE(config_error(kMinimal + "grid: {upsample: " + bad + "}\n")
                  .find("grid.upsample = '" + bad + "': expected auto, off, or an integer factor in [1, 16]"),
              std::string::npos)
        << bad;
  }
}

TEST(Config, FilterHaloIsAutoOrACellCount) {
  const auto cells = [](const std::string& extra) {
    return parse_run_config(kMinimal + extra, "configs/test.yaml").scale.filter_halo_cells;
  };
  EXPECT_EQ(cells(""), hc::pipeline::ScaleConfig::kAutoFilterHalo) << "auto is the default";
  EXPECT_EQ(cells("scale: {filter_halo_cells: auto}\n"), hc::pipeline::ScaleConfig::kAutoFilterHalo);
  EXPECT_EQ(cells("scale: {filter_halo_cells: 0}\n"), 0);
  EXPECT_EQ(cells("scale: {filter_halo_cells: 4096}\n"), 4096);
  for (const std::string bad : {"-1", "4097", "2.5", "yes", "8c"}) {
    EXPECT_NE(config_error(kMinimal + "scale: {filter_halo_cells: " + bad + "}\n")
                  .find("scale.filter_halo_cells = '" + bad + "': expected auto or an integer in [0, 4096]"),
              std::string::npos)
        << bad;
  }
}

// scale.island_halo: auto (the default), or a YAML bool; the resolved config says which.
TEST(Config, IslandHaloIsAutoOrABool) {
  using hc::pipeline::ScaleConfig;
  const auto parsed = [](const std::string& extra) { return parse_run_config(kMinimal + extra, "configs/test.yaml"); };
  EXPECT_EQ(parsed("").scale.island_halo, ScaleConfig::Tiled::kAuto) << "auto is the default";
  EXPECT_EQ(parsed("scale: {island_halo: auto}\n").scale.island_halo, ScaleConfig::Tiled::kAuto);
  EXPECT_EQ(parsed("scale: {island_halo: true}\n").scale.island_halo, ScaleConfig::Tiled::kOn);
  EXPECT_EQ(parsed("scale: {island_halo: yes}\n").scale.island_halo, ScaleConfig::Tiled::kOn);
  EXPECT_EQ(parsed("scale: {island_halo: false}\n").scale.island_halo, ScaleConfig::Tiled::kOff);
  EXPECT_NE(parsed("").resolved_yaml.find("island_halo: auto"), std::string::npos) << parsed("").resolved_yaml;
  EXPECT_NE(parsed("scale: {island_halo: off}\n").resolved_yaml.find("island_halo: false"), std::string::npos);
  for (const std::string bad : {"2", "maybe", "Auto"}) {
    const std::string what = config_error(kMinimal + "scale: {island_halo: " + bad + "}\n");
    EXPECT_NE(what.find("scale.island_halo = '" + bad + "': expected auto, true or false"), std::string::npos) << what;
  }
  EXPECT_NE(config_error(kMinimal + "scale: {island_halo: [true]}\n").find("scale.island_halo = "), std::string::npos);
}

// scale.band_mb bounds the robust test's band of first looks; scale.block_copies, which the
// bands replaced, is refused by name with what to do (not taken as an unknown key's typo).
TEST(Config, BandMegabytesAreReadAndBlockCopiesIsRefusedByName) {
  const auto band = [](const std::string& extra) { return parse_run_config(kMinimal + extra, "configs/test.yaml").scale.band_mb; };
  EXPECT_EQ(band(""), 128.0);
  EXPECT_EQ(band("scale: {band_mb: 0}\n"), 0.0);
  EXPECT_EQ(band("scale: {band_mb: 0.01}\n"), 0.01);
  EXPECT_EQ(band("scale: {band_mb: 65536}\n"), 65536.0);
  EXPECT_NE(config_error(kMinimal + "scale: {band_mb: -1}\n").find("scale.band_mb"), std::string::npos);
  EXPECT_NE(config_error(kMinimal + "scale: {band_mb: 65537}\n").find("scale.band_mb"), std::string::npos);
  const std::string what = config_error(kMinimal + "scale: {block_copies: false}\n");
  EXPECT_NE(what.find("scale.block_copies"), std::string::npos) << what;
  EXPECT_NE(what.find("was removed"), std::string::npos) << what;
  EXPECT_NE(what.find("delete the key"), std::string::npos) << what;
}

// scale.max_gatherings: 1 to 64 gatherings of a band's strays, 32 by default (8 until the forty-second session); a value outside,
// or not a whole number, is refused naming the key.
TEST(Config, MaxGatheringsIsReadWithinItsRange) {
  const auto most = [](const std::string& extra) { return parse_run_config(kMinimal + extra, "configs/test.yaml").scale.max_gatherings; };
  EXPECT_EQ(most(""), 32);
  EXPECT_EQ(most("scale: {max_gatherings: 1}\n"), 1);
  EXPECT_EQ(most("scale: {max_gatherings: 64}\n"), 64);
  for (const char* bad : {"0", "65", "2.5", "many"}) {
    const std::string what = config_error(kMinimal + "scale: {max_gatherings: " + bad + "}\n");
    EXPECT_NE(what.find("scale.max_gatherings"), std::string::npos) << bad << ": " << what;
  }
}

TEST(Config, FalconSectionIsReadAndValidated) {
  const auto c = parse_run_config(kMinimal + "falcon: {firmware: fw/falcon.bin, index: 1, max_force_n: 5}\n",
                                  "configs/test.yaml");
  EXPECT_EQ(c.falcon.firmware_path, (std::filesystem::path("configs") / "fw" / "falcon.bin").string());
  EXPECT_EQ(c.falcon.device_index, 1);
  EXPECT_EQ(c.falcon.max_force_n, 5.0);
  EXPECT_EQ(c.falcon.max_missed_ticks, 10);
  EXPECT_TRUE(parse_run_config(kMinimal, "configs/test.yaml").falcon.firmware_path.empty());
  EXPECT_NE(config_error(kMinimal + "falcon: {max_force_n: 20}\n").find("falcon.max_force_n = 20: expected a number in (0, 10]"),
            std::string::npos);
  EXPECT_NE(config_error(kMinimal + "falcon: {max_missed_ticks: 0}\n").find("falcon.max_missed_ticks = 0"), std::string::npos);
}

TEST(Config, ShippedConfigsAllValidate) {
  for (const char* name : {"happy_buddha.yaml", "buddha_raw_scans.yaml", "bunny.yaml", "sinusoid.yaml"}) {
    const auto path = std::filesystem::path(HC_SOURCE_DIR) / "configs" / name;
    EXPECT_NO_THROW(hc::pipeline::load_run_config(path)) << name;
  }
}


// Issue 15 D3: a known section that is not a map (a scalar, a list, empty) used to be ignored,
// the run going on with the defaults. Each must stop the run naming file, line, key, "expected a map".
void expect_not_a_map(const std::string& yaml, const std::vector<std::string>& sets, const std::string& where,
                      const std::string& key) {
  std::string msg;
  try {
    parse_run_config(yaml, "configs/test.yaml", sets);
  } catch (const hc::ConfigError& e) {
    msg = e.what();
  }
  ASSERT_FALSE(msg.empty()) << "no ConfigError for:\n" << yaml;
  EXPECT_EQ(msg.rfind(where + ": ", 0), 0u) << msg;  // file and line (or the --set) first
  EXPECT_NE(msg.find(key), std::string::npos) << msg;
  EXPECT_NE(msg.find("expected a map"), std::string::npos) << msg;
}

TEST(Config, SectionGivenAsAScalarIsAnErrorNamingFileLineAndKey) {
  expect_not_a_map(kMinimal + "grid: 5\n", {}, "configs/test.yaml:3", "grid = '5'");
  expect_not_a_map(kMinimal + "filters: yes\n", {}, "configs/test.yaml:3", "filters = 'yes'");
  expect_not_a_map(kMinimal + "lod: off\n", {}, "configs/test.yaml:3", "lod = 'off'");
  expect_not_a_map("input: scan.ply\n", {}, "configs/test.yaml:1", "input = 'scan.ply'");
}

TEST(Config, SectionGivenAsAListIsAnError) {
  expect_not_a_map(kMinimal + "cross_check: [1, 2]\n", {}, "configs/test.yaml:3", "cross_check = [1, 2]");
  expect_not_a_map(kMinimal + "layers:\n  friction: [paper]\n", {}, "configs/test.yaml:4", "layers.friction");
}

TEST(Config, EmptySectionIsAnErrorNotTheDefaults) {
  expect_not_a_map(kMinimal + "grid:\n", {}, "configs/test.yaml:3", "grid is empty");
  expect_not_a_map(kMinimal + "grid:\nlod: {min_cells: 4}\n", {}, "configs/test.yaml:3", "grid is empty");
  // Sections read only when present are checked too: an empty one is not "absent".
  expect_not_a_map(kMinimal + "audio:\n", {}, "configs/test.yaml:3", "audio is empty");
  expect_not_a_map(kMinimal + "filters:\n  crop:\n", {}, "configs/test.yaml:4", "filters.crop is empty");
  expect_not_a_map("input:\n  synthetic: sinusoid\n", {}, "configs/test.yaml:2", "input.synthetic = 'sinusoid'");
}

TEST(Config, NestedSectionGivenAsAScalarIsAnError) {
  expect_not_a_map(kMinimal + "filters:\n  outliers: false\n", {}, "configs/test.yaml:4", "filters.outliers = 'false'");
  expect_not_a_map(kMinimal + "view:\n  rotation: 90\n", {}, "configs/test.yaml:4", "view.rotation = '90'");
  expect_not_a_map(kMinimal + "audio:\n  slide: on\n", {}, "configs/test.yaml:4", "audio.slide = 'on'");
}

TEST(Config, SetOfASectionToAScalarIsAnError) {
  expect_not_a_map(kMinimal, {"grid=5"}, "configs/test.yaml (--set grid)", "grid = '5'");
  expect_not_a_map(kMinimal, {"filters=[1]"}, "configs/test.yaml (--set filters)", "filters = [1]");
  // A --set below a section the file gives as a scalar does not silently replace the file's value.
  expect_not_a_map(kMinimal + "grid: 5\n", {"grid.n=400"}, "configs/test.yaml:3", "grid = '5'");
}

TEST(Config, WellFormedSectionsAndScalarMaterialStillLoad) {
  // The checks above must not reject what is valid: maps, a null file, a material given by name.
  EXPECT_NO_THROW(parse_run_config(kMinimal + "grid: {n: 300}\nfilters:\n  outliers: {k: 8}\n", "configs/test.yaml"));
  EXPECT_NO_THROW(parse_run_config(kMinimal + "audio:\n  slide: {material: marble}\n", "configs/test.yaml"));
  const auto c = parse_run_config(kMinimal, "configs/test.yaml", {"grid.n=300"});
  EXPECT_EQ(c.grid.reproject.grid.n_long_side, 300);
}

TEST(Config, TabIndentationIsNamedWithItsLine) {
  for (const std::string& yaml : {kMinimal + "grid:\n\tn: 5\n", std::string("input:\n\tfiles: [a]\n"),
                                  kMinimal + "grid:\n  n: 5\n\tsplat_mode: disc\n"}) {
    std::string msg;
    try {
      parse_run_config(yaml, "configs/tabs.yaml");
    } catch (const hc::InputError& e) {
      msg = e.what();
    }
    const auto lines = std::count(yaml.begin(), yaml.end(), '\n');
    int tab_line = 0;  // the line of the tab, counted here independently of the reader
    for (int n = 1, pos = 0; n <= lines; ++n) {
      if (yaml[static_cast<std::size_t>(pos)] == '\t') tab_line = n;
      pos = static_cast<int>(yaml.find('\n', static_cast<std::size_t>(pos))) + 1;
    }
    ASSERT_GT(tab_line, 0);
    EXPECT_EQ(msg.rfind("configs/tabs.yaml:" + std::to_string(tab_line) + ": ", 0), 0u) << msg;
    EXPECT_NE(msg.find("tab"), std::string::npos) << msg;
  }
  // A tab that is not indentation (inside a line) is not reported as one.
  EXPECT_NO_THROW(parse_run_config(kMinimal + "grid:\t{n: 300}\n", "configs/test.yaml"));
}

}  // namespace
