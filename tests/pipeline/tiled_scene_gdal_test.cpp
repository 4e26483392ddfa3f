// A tiled scene's layer file as GDAL reads it (an independent reader, as QGIS and rasterio use
// it). In hc_pipeline_oracle_tests, which links GDAL (tests/CMakeLists.txt); the other tiled-scene
// tests are tiled_scene_test.cpp's.

#include "test_paths.hpp"
#include "tiled_scene_fixture.hpp"

#include <gdal.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <vector>

namespace tiled_scene_gdal {

namespace fs = std::filesystem;

// 150 × 97 samples in tiles of 32 (partial edge tiles both ways); the hole covers the whole tile
// (row 2, col 1), samples [64, 96) × [32, 64), which the writer stores without bytes
// (TiledScene.LayersAreTiledTiffsWithNoDataTilesStoredWithoutBytesAndLoadAsTheWholeScene reads
// the same file with libtiff).
TEST(TiledScene, GdalReadsATileWithoutBytesAsNoDataAndTheTileBesideItAsTheLayer) {
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  const hc::Scene s = hc::test::wavy_scene(150, 97, 64, 32, 32);
  const fs::path tiled = hc::test::write_tiled(s, hc::test::temp_dir("scene_gdal"), 32);
  // GDAL (an independent reader, as QGIS and rasterio use it) reads the no-data tile (2, 1) as
  // NaN through the file's no-data tag, and the tile beside it as the layer.
  GDALAllRegister();
  GDALDatasetH ds = GDALOpen((tiled / "depth.tiff").c_str(), GA_ReadOnly);
  ASSERT_NE(ds, nullptr);
  GDALRasterBandH band = GDALGetRasterBand(ds, 1);
  int has_nodata = 0;
  EXPECT_TRUE(std::isnan(GDALGetRasterNoDataValue(band, &has_nodata)));
  EXPECT_TRUE(has_nodata);
  std::vector<float> block(32 * 64);
  ASSERT_EQ(GDALRasterIO(band, GF_Read, 32, 64, 64, 32, block.data(), 64, 32, GDT_Float32, 0, 0), CE_None);
  for (int r = 0; r < 32; ++r) {
    for (int c = 0; c < 64; ++c) {
      const float want = c < 32 ? kNaN : s.layers.depth.at(64 + r, 32 + c);
      EXPECT_EQ(std::isnan(block[static_cast<std::size_t>(r * 64 + c)]), std::isnan(want)) << r << "," << c;
      if (!std::isnan(want)) {
        EXPECT_EQ(block[static_cast<std::size_t>(r * 64 + c)], want) << r << "," << c;
      }
    }
  }
  GDALClose(ds);
}

}  // namespace tiled_scene_gdal
