// Every shipped example config that reads a scanner sample or a mesh (configs/*.yaml; the
// Buddha configs have their own tests in honest_cross_check_test.cpp and elsewhere) runs end
// to end and never ends in verdict fail: a new user's first run of an example must not exit 4.
// Where an example ends in warn, the reasons are the ones its config file explains (a limit of
// the data, not of the grid): the expected codes are those comments, so a new warn or a fail is
// a regression. The airborne examples also claim that every spike cell (tree tops, roofs) is
// confirmed by a scan point; that is checked from the spike figures.
// The LAZ example is also run on its LAS 1.4 twin (the same Autzen points, read by the other
// reader): the grids must agree cell for cell. This checks the two readers against each other
// end to end, not the pipeline against an outside oracle.

#include "hc/pipeline/config.hpp"
#include "hc/pipeline/honest_check.hpp"
#include "hc/pipeline/run.hpp"

#include "test_paths.hpp"
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <set>
#include <string>
#include <vector>

namespace hc::pipeline {
namespace {

namespace fs = std::filesystem;

struct Shipped {
  const char* config;                 ///< configs/<config>.yaml
  const char* scan;                   ///< a file it reads (data/get-data), checked first
  const char* status;                 ///< the expected verdict
  std::set<std::string> warn_codes;   ///< the warn reasons its comments explain
  bool all_spikes_confirmed = false;  ///< its comments say every spike cell is confirmed
};

std::ostream& operator<<(std::ostream& os, const Shipped& s) { return os << s.config; }

std::string reasons_of(const Verdict& v) {
  std::string s = v.status + ":";
  for (const auto& r : v.reasons) s += "\n  " + r.level + " " + r.code + ": " + r.message;
  return s;
}

class ShippedConfig : public ::testing::TestWithParam<Shipped> {};

TEST_P(ShippedConfig, EndsInItsDocumentedVerdictNeverFail) {
  const Shipped& s = GetParam();
  if (*s.scan) hc::test::scan_path(s.scan);  // a clear failure when data/get-data was not run
  const RunConfig config = load_run_config(fs::path(HC_SOURCE_DIR) / "configs" / (std::string(s.config) + ".yaml"));
  const BuiltScene b = build_scene(config);
  ASSERT_TRUE(b.summary.verdict.has_value());
  const Verdict& v = *b.summary.verdict;
  EXPECT_NE(v.status, "fail") << reasons_of(v);
  EXPECT_EQ(v.status, s.status) << reasons_of(v);
  std::set<std::string> codes;
  for (const auto& r : v.reasons) {
    EXPECT_EQ(r.level, "warn") << reasons_of(v);
    codes.insert(r.code);
  }
  EXPECT_EQ(codes, s.warn_codes) << reasons_of(v);
  EXPECT_GT(b.summary.valid_cells, 0u);
  if (s.all_spikes_confirmed) {
    ASSERT_TRUE(b.summary.grid_spikes.has_value());
    const GridSpikes& sp = *b.summary.grid_spikes;
    EXPECT_GT(sp.spikes, 0u);  // trees and roofs stand above their windows
    EXPECT_EQ(sp.confirmed, sp.spikes + sp.pits);
  }
}

INSTANTIATE_TEST_SUITE_P(
    Examples, ShippedConfig,
    ::testing::Values(Shipped{"las_sample", "scanner_samples/las/pdal-simple.las", "warn", {"visible_off_surface", "unsupported"}, true},
                      Shipped{"laz_autzen", "scanner_samples/laz/pdal-autzen_trim.laz", "warn", {"islands", "unsupported"}, true},
                      Shipped{"e57_pump", "scanner_samples/e57/pye57-pumpAVisualReferenceImage.e57", "warn", {"unsupported"}},
                      Shipped{"ptx_transform", "scanner_samples/ptx/pdal-complex-transform.ptx", "pass", {}},
                      Shipped{"mask_obj", "scanner_samples/mesh/balinese_mask", "pass", {}},
                      Shipped{"bunny", "bunny/bun000.ply", "pass", {}},
                      Shipped{"temple_relief", "", "pass", {}}),
    [](const ::testing::TestParamInfo<Shipped>& p) { return std::string(p.param.config); });

TEST(ShippedConfig, LazExampleGivesTheSameGridAsItsLas14Twin) {
  const fs::path las = hc::test::scan_path("scanner_samples/las/pdal-autzen_trim_7.las");
  const fs::path config_path = fs::path(HC_SOURCE_DIR) / "configs" / "laz_autzen.yaml";
  const BuiltScene from_laz = build_scene(load_run_config(config_path));
  const BuiltScene from_las = build_scene(load_run_config(config_path, {"input.files=[" + las.string() + "]"}));
  const HeightField& a = from_laz.scene.depth();
  const HeightField& b = from_las.scene.depth();
  ASSERT_EQ(a.rows(), b.rows());
  ASSERT_EQ(a.cols(), b.cols());
  EXPECT_EQ(a.geometry().cell_size_m, b.geometry().cell_size_m);
  std::size_t differ = 0;
  for (std::size_t i = 0; i < a.values().size(); ++i) {
    const float x = a.values()[i], y = b.values()[i];
    if (!((std::isnan(x) && std::isnan(y)) || x == y)) ++differ;
  }
  EXPECT_EQ(differ, 0u);
  EXPECT_EQ(from_laz.summary.verdict->status, from_las.summary.verdict->status);
}

}  // namespace
}  // namespace hc::pipeline
