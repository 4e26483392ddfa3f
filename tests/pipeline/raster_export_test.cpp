// GeoTIFF export (raster_export.hpp), read back with GDAL for the georeferencing (geotransform,
// CRS, no-data, metadata) and with OpenCV's TIFF reader for the pixels, independently of how
// they were written. The oracle: the grid's construction and the transform, by hand.

#include "hc/pipeline/raster_export.hpp"

#include "hc/common/error.hpp"

#include "test_paths.hpp"
#include <gdal_priv.h>
#include <gtest/gtest.h>
#include <ogr_spatialref.h>
#include <opencv2/imgcodecs.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <string>

namespace hc::pipeline {
namespace {

namespace fs = std::filesystem;

constexpr double kFoot = 0.3048;

// 4 rows × 5 columns of 1 ft cells, z = 0.1·r + 0.01·c m, no data at (1, 2).
HeightField fixture() {
  HeightField f(GridGeometry{4, 5, -1.0, 2.0, kFoot});
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 5; ++c) f.at(r, c) = static_cast<float>(0.1 * r + 0.01 * c);
  f.at(1, 2) = std::numeric_limits<float>::quiet_NaN();
  return f;
}

struct Dataset {
  std::unique_ptr<GDALDataset, void (*)(GDALDataset*)> ds{nullptr, [](GDALDataset* d) { GDALClose(d); }};
  explicit Dataset(const fs::path& p) {
    GDALAllRegister();
    ds.reset(static_cast<GDALDataset*>(GDALOpen(p.c_str(), GA_ReadOnly)));
  }
};

TEST(GeoTiffExport, TopViewIsInTheFileFrameUprightWithItsCrsAndNanNoData) {
  const HeightField f = fixture();
  // A scan in feet recentred by `offset` metres: grid = 0.3048·file − offset, no rotation.
  const Eigen::Vector3d offset(152400.0, 30480.0, 30.48);
  const Eigen::Affine3d model_to_grid = Eigen::Translation3d(-offset) * Eigen::Scaling(kFoot);
  const GeoTiffLayout layout = geotiff_layout(f.geometry(), model_to_grid, true);
  ASSERT_TRUE(layout.file_frame);
  const fs::path file = hc::test::temp_dir("geotiff") / "depth.tif";
  const auto notes = write_geotiff(f, layout, "EPSG:32610", file, {"HAPTICLOUD_LAYER=depth"});
  EXPECT_TRUE(notes.empty());
  EXPECT_FALSE(hc::test::has_entry_named_with(file.parent_path(), ".part-"));

  Dataset d(file);
  ASSERT_TRUE(d.ds);
  ASSERT_EQ(d.ds->GetRasterXSize(), 5);
  ASSERT_EQ(d.ds->GetRasterYSize(), 4);
  double gt[6];
  ASSERT_EQ(d.ds->GetGeoTransform(gt), CE_None);
  // By hand: node (r, c) at file x = (−1 + 0.3048·c + 152400) / 0.3048 ft, y likewise; pixel
  // (0, 0)'s corner half a cell (0.5 ft) left of and above node (3, 0), the top row.
  EXPECT_NEAR(gt[0], (-1.0 + 152400.0) / kFoot - 0.5, 1e-6);
  EXPECT_NEAR(gt[1], 1.0, 1e-12);
  EXPECT_EQ(gt[2], 0.0);
  EXPECT_NEAR(gt[3], (2.0 + 3 * kFoot + 30480.0) / kFoot + 0.5, 1e-6);
  EXPECT_EQ(gt[4], 0.0);
  EXPECT_NEAR(gt[5], -1.0, 1e-12);
  const OGRSpatialReference* srs = d.ds->GetSpatialRef();
  ASSERT_NE(srs, nullptr);
  EXPECT_STREQ(srs->GetAuthorityCode(nullptr), "32610");
  int has_nodata = 0;
  EXPECT_TRUE(std::isnan(d.ds->GetRasterBand(1)->GetNoDataValue(&has_nodata)));
  EXPECT_TRUE(has_nodata);
  ASSERT_NE(d.ds->GetMetadataItem("HAPTICLOUD_LAYER"), nullptr);
  EXPECT_STREQ(d.ds->GetMetadataItem("HAPTICLOUD_LAYER"), "depth");

  // Pixels through OpenCV: image row j is grid row 3 − j; heights in feet, file frame.
  const cv::Mat img = cv::imread(file.string(), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(img.type(), CV_32FC1);
  ASSERT_EQ(img.rows, 4);
  ASSERT_EQ(img.cols, 5);
  for (int j = 0; j < 4; ++j)
    for (int i = 0; i < 5; ++i) {
      const int r = 3 - j;
      const float v = img.at<float>(j, i);
      if (r == 1 && i == 2) {
        EXPECT_TRUE(std::isnan(v));
        continue;
      }
      EXPECT_NEAR(v, (0.1 * r + 0.01 * i + 30.48) / kFoot, 1e-4) << j << " " << i;
    }
}

TEST(GeoTiffExport, ARotatedViewStaysInTheGridFrameWithoutTheCrs) {
  const HeightField f = fixture();
  const Eigen::Affine3d model_to_grid(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitX()));
  const GeoTiffLayout layout = geotiff_layout(f.geometry(), model_to_grid, true);
  EXPECT_FALSE(layout.file_frame);
  EXPECT_EQ(layout.z_scale, 1.0);
  EXPECT_EQ(layout.z_offset, 0.0);
  const fs::path file = hc::test::temp_dir("geotiff_rot") / "depth.tif";
  const auto notes = write_geotiff(f, layout, "EPSG:32610", file);
  ASSERT_EQ(notes.size(), 1u);
  EXPECT_NE(notes[0].find("grid frame"), std::string::npos);
  Dataset d(file);
  ASSERT_TRUE(d.ds);
  double gt[6];
  ASSERT_EQ(d.ds->GetGeoTransform(gt), CE_None);
  EXPECT_NEAR(gt[0], -1.0 - 0.5 * kFoot, 1e-12);
  EXPECT_NEAR(gt[3], 2.0 + 3.5 * kFoot, 1e-12);
  EXPECT_NEAR(gt[5], -kFoot, 1e-12);
  EXPECT_EQ(d.ds->GetSpatialRef(), nullptr);
  const cv::Mat img = cv::imread(file.string(), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(img.type(), CV_32FC1);
  EXPECT_NEAR(img.at<float>(0, 4), 0.1 * 3 + 0.01 * 4, 1e-6);  // grid row 3, stored z
}

TEST(GeoTiffExport, NonHeightLayersKeepTheirValuesAndUnreadableCrsTextIsKept) {
  const HeightField f = fixture();
  const Eigen::Affine3d model_to_grid = Eigen::Translation3d(-5.0, 0.0, -7.0) * Eigen::Scaling(2.0);
  const GeoTiffLayout layout = geotiff_layout(f.geometry(), model_to_grid, false);
  EXPECT_TRUE(layout.file_frame);
  EXPECT_EQ(layout.z_scale, 1.0);
  const fs::path file = hc::test::temp_dir("geotiff_mu") / "mu.tif";
  const auto notes = write_geotiff(f, layout, "a local survey grid, not a CRS", file);
  ASSERT_EQ(notes.size(), 1u);
  EXPECT_NE(notes[0].find("HAPTICLOUD_CRS_TEXT"), std::string::npos);
  Dataset d(file);
  ASSERT_TRUE(d.ds);
  ASSERT_NE(d.ds->GetMetadataItem("HAPTICLOUD_CRS_TEXT"), nullptr);
  EXPECT_STREQ(d.ds->GetMetadataItem("HAPTICLOUD_CRS_TEXT"), "a local survey grid, not a CRS");
  double gt[6];
  ASSERT_EQ(d.ds->GetGeoTransform(gt), CE_None);
  // grid = 2·file − (5, 0, 7): file = (grid + (5, 0, 7)) / 2, cells of 0.3048 / 2 file units.
  EXPECT_NEAR(gt[1], kFoot / 2.0, 1e-12);
  EXPECT_NEAR(gt[0], (-1.0 + 5.0) / 2.0 - kFoot / 4.0, 1e-12);
  EXPECT_NEAR(gt[3], (2.0 + 3 * kFoot) / 2.0 + kFoot / 4.0, 1e-12);
  EXPECT_NEAR(gt[5], -kFoot / 2.0, 1e-12);
  const cv::Mat img = cv::imread(file.string(), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(img.type(), CV_32FC1);
  EXPECT_NEAR(img.at<float>(0, 4), 0.1 * 3 + 0.01 * 4, 1e-7);  // grid row 3, col 4: the stored value, not mapped
}

TEST(GeoTiffExport, AnExistingFileOrAMissingFolderIsRefusedAndNothingIsLeft) {
  const HeightField f = fixture();
  const fs::path dir = hc::test::temp_dir("geotiff_refuse");
  const fs::path file = dir / "depth.tif";
  { std::ofstream(file) << "the user's file"; }
  const GeoTiffLayout layout = geotiff_layout(f.geometry(), Eigen::Affine3d::Identity(), true);
  try {
    write_geotiff(f, layout, "", file);
    FAIL() << "expected hc::InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("exists already"), std::string::npos) << e.what();
  }
  std::ifstream in(file);
  std::string text;
  std::getline(in, text);
  EXPECT_EQ(text, "the user's file");
  EXPECT_THROW(write_geotiff(f, layout, "", dir / "missing" / "d.tif"), InputError);
  EXPECT_FALSE(hc::test::has_entry_named_with(dir, ".part-"));
  EXPECT_THROW(write_geotiff(HeightField{}, layout, "", dir / "empty.tif"), std::invalid_argument);
}

}  // namespace
}  // namespace hc::pipeline
