// The scan's CRS carried into the scene's provenance (issue "Scanner data in"): LAS OGC WKT from
// VLR LASF_Projection 2112. Oracle: the WKT read here straight from the file's bytes following
// ASPRS LAS 1.4 R15 §2.4–2.5 (header size at byte 94, VLR count at 100, 54-byte VLR headers).

#include "hc/pipeline/config.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"

#include "test_paths.hpp"
#include "file_bytes.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <string>

namespace {

using hc::test::le;

using namespace hc::pipeline;

/// The payload of the first VLR with user id "LASF_Projection" and record id 2112, trailing NULs removed.
std::string wkt_from_vlr_bytes(const std::filesystem::path& las) {
  std::ifstream in(las, std::ios::binary);
  const std::string b((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::size_t at = le<std::uint16_t>(b, 94);
  const std::uint32_t n_vlr = le<std::uint32_t>(b, 100);
  for (std::uint32_t i = 0; i < n_vlr && at + 54 <= b.size(); ++i) {
    const std::string user(b.c_str() + at + 2, strnlen(b.c_str() + at + 2, 16));
    const auto record = le<std::uint16_t>(b, at + 18);
    const auto length = le<std::uint16_t>(b, at + 20);
    if (user == "LASF_Projection" && record == 2112) {
      std::string wkt = b.substr(at + 54, length);
      while (!wkt.empty() && wkt.back() == '\0') wkt.pop_back();
      return wkt;
    }
    at += 54 + length;
  }
  return {};
}

TEST(CrsProvenance, LasWktReachesTheCloudTheSceneAndScaneYaml) {
  const auto las = hc::test::scan_path("scanner_samples/las/pdal-test1_4.las");
  const std::string wkt = wkt_from_vlr_bytes(las);
  ASSERT_EQ(wkt.rfind("PROJCS[\"NAD83(HARN) / New Mexico Central (ftUS)\"", 0), 0U) << wkt.substr(0, 80);

  EXPECT_EQ(load_cloud(las).value.crs, wkt);

  const auto dir = hc::test::temp_dir("crs");
  const std::string yaml = "name: crs\ninput: {files: [" + las.string() +
                           "], units: us-ft}\ngrid: {n: 64}\nfilters: {outliers: {enabled: false}}\n"
                           "lod: {report: false}\nlayers: {enabled: false}\ncross_check: {enabled: false}\n";
  const BuiltScene built = build_scene(parse_run_config(yaml, dir / "crs.yaml"));
  EXPECT_EQ(built.scene.provenance.crs, wkt);
  write_scene(built.scene, dir / "scene");
  EXPECT_EQ(load_scene(dir / "scene").provenance.crs, wkt);
}

TEST(CrsProvenance, AScanWithoutCrsLeavesItEmpty) {
  EXPECT_TRUE(load_cloud(hc::test::scan_path("scanner_samples/las/pdal-simple.las")).value.crs.empty());
  EXPECT_TRUE(load_cloud(hc::test::scan_path("bunny/bun000.ply")).value.crs.empty());
}

}  // namespace
