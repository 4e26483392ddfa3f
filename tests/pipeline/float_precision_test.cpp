// Float-stored georeferenced coordinates (issue "Scanner data in", precision): a cloud stored in
// float32 whose coordinates cannot resolve a tenth of the grid cell (|x|·2⁻²⁴ > cell/10) gets a
// warning in the report; when the grid collapses, an error naming the cause.
// Oracle: the bunny scan written here as float32 / float64 PLY with a known offset; the precision
// limit by hand: 500 000 m · 2⁻²⁴ ≈ 29.8 mm, 2 000 m · 2⁻²⁴ ≈ 0.119 mm, against 0.5 mm cells.

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/run.hpp"

#include "test_paths.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

namespace {

using namespace hc::pipeline;

/// Writes the points + (dx, dy, 0) as a binary little-endian PLY with float or double x y z.
void write_ply(const std::filesystem::path& file, const Cloud& c, double dx, double dy, bool as_double) {
  std::ofstream out(file, std::ios::binary);
  const char* type = as_double ? "double" : "float";
  out << "ply\nformat binary_little_endian 1.0\nelement vertex " << c.size() << "\nproperty " << type
      << " x\nproperty " << type << " y\nproperty " << type << " z\nend_header\n";
  for (std::size_t i = 0; i < c.size(); ++i) {
    const double v[3] = {c.xyz(0, static_cast<Eigen::Index>(i)) + dx, c.xyz(1, static_cast<Eigen::Index>(i)) + dy,
                         c.xyz(2, static_cast<Eigen::Index>(i))};
    for (double d : v) {
      if (as_double) {
        out.write(reinterpret_cast<const char*>(&d), 8);
      } else {
        const float f = static_cast<float>(d);
        out.write(reinterpret_cast<const char*>(&f), 4);
      }
    }
  }
}

RunConfig config_for(const std::filesystem::path& dir, const std::string& ply) {
  const std::string yaml = "name: georef\ninput: {files: [" + ply + "], units: m}\ngrid: {n: 300}\n"
                           "lod: {report: false}\nlayers: {enabled: false}\n";
  return parse_run_config(yaml, dir / "georef.yaml");
}

class FloatPrecision : public ::testing::Test {
 protected:
  void SetUp() override {
    bunny_ = load_cloud(hc::test::scan_path("bunny/bun000.ply")).value;
    ASSERT_GT(bunny_.size(), 10000U);
  }
  Cloud bunny_;
};

TEST_F(FloatPrecision, ReadersTellTheStoredPrecision) {
  const auto dir = hc::test::temp_dir("p");
  write_ply(dir / "f.ply", bunny_, 0, 0, false);
  write_ply(dir / "d.ply", bunny_, 0, 0, true);
  EXPECT_TRUE(load_cloud(dir / "f.ply").value.float32_xyz);
  EXPECT_FALSE(load_cloud(dir / "d.ply").value.float32_xyz);
}

TEST_F(FloatPrecision, GeoreferencedFloatPlyThatCollapsesTheGridIsAnErrorNamingTheCause) {
  const auto dir = hc::test::temp_dir("collapse");
  write_ply(dir / "georef_float.ply", bunny_, 500000.0, 500000.0, false);
  try {
    (void)build_scene(config_for(dir, "georef_float.ply"));
    FAIL() << "no exception";
  } catch (const hc::DegenerateInputError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("georef_float.ply"), std::string::npos) << m;
    EXPECT_NE(m.find("32-bit float"), std::string::npos) << m;
    EXPECT_NE(m.find("collapses"), std::string::npos) << m;
  }
}

TEST_F(FloatPrecision, CoarseButUsableFloatCoordinatesGiveAReportWarning) {
  const auto dir = hc::test::temp_dir("warn");
  write_ply(dir / "georef_2km.ply", bunny_, 2000.0, -2000.0, false);
  const BuiltScene b = build_scene(config_for(dir, "georef_2km.ply"));
  // 2 000 m · 2⁻²⁴ = 0.119 mm > cell/10 (the bunny at n = 300: ≈ 0.05 mm) on x and y, not on z.
  const double cell = b.scene.geometry.cell_size_m;
  ASSERT_LT(cell / 10.0, 2000.0 * std::ldexp(1.0, -24));
  ASSERT_EQ(b.summary.warnings.size(), 2U);
  EXPECT_NE(b.summary.warnings[0].find("|x|"), std::string::npos) << b.summary.warnings[0];
  EXPECT_NE(b.summary.warnings[1].find("|y|"), std::string::npos) << b.summary.warnings[1];
  EXPECT_GT(b.summary.valid_cells, 10000U);
}

TEST_F(FloatPrecision, TheSameOffsetStoredAsDoubleNeedsNoWarning) {
  const auto dir = hc::test::temp_dir("double");
  write_ply(dir / "georef_double.ply", bunny_, 500000.0, 500000.0, true);
  const BuiltScene b = build_scene(config_for(dir, "georef_double.ply"));
  EXPECT_TRUE(b.summary.warnings.empty());
  EXPECT_GT(b.summary.valid_cells, 10000U);
}

}  // namespace
