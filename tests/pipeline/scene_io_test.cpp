// The scene contract on disk: format 2 round-trips every typed field; format-1 folders written
// by earlier versions still load.

#include "hc/common/cell_buffer.hpp"
#include "hc/common/error.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <gdal_priv.h>

#include "image_io.hpp"  // pipeline/src: write_png
#include "test_paths.hpp"
#include "resident_bytes.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>

namespace {

namespace fs = std::filesystem;
using namespace hc::pipeline;

bool same_values(const hc::HeightField& a, const hc::HeightField& b) {
  if (!(a.geometry() == b.geometry())) return false;
  for (std::size_t i = 0; i < a.values().size(); ++i) {
    const float x = a.values()[i], y = b.values()[i];
    if (!((std::isnan(x) && std::isnan(y)) || x == y)) return false;
  }
  return true;
}

hc::HeightField ramp(const hc::GridGeometry& g, float scale, const Eigen::Affine3d& frame) {
  hc::HeightField f(g);
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c) f.at(r, c) = scale * float(r * g.cols + c) + 1e-7f;
  f.model_to_grid = frame;
  return f;
}

TEST(SceneIo, FormatTwoRoundTripsEveryTypedField) {
  const fs::path dir = hc::test::temp_dir("v2");
  const hc::GridGeometry g{3, 4, -0.01, 0.02, 0.001};
  const Eigen::Affine3d frame(Eigen::Translation3d(1, 2, 3) * Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitY()));
  Scene s;
  s.geometry = g;
  s.model_to_grid = frame;
  s.layers.depth = ramp(g, 0.001f, frame);
  s.layers.depth.at(1, 2) = hc::kNoData;
  s.layers.envelope = ramp(g, 0.0009f, frame);
  s.layers.texture = ramp(g, 0.0001f, frame);
  s.layers.mu_d = ramp(g, 0.01f, frame);
  s.layers.mu_s = hc::HeightField(g, 0.25f);
  s.layers.region_id = hc::HeightField(g, 2.0f);
  s.layers.flags.assign(12, kCellMeasured);
  s.layers.flags[6] = kCellSeeThrough;
  s.layers.colour_rgb8.assign(36, 0);
  for (std::size_t i = 0; i < 36; ++i) s.layers.colour_rgb8[i] = static_cast<std::uint8_t>(7 * i);
  s.friction_model = hc::FrictionModel::kCurvature;
  s.layer_options.sigma_space_cells = 2.5;
  s.layer_options.sigma_range_m = 0.0007;
  s.layer_options.friction_model = hc::FrictionModel::kCurvature;
  s.layer_options.mu_s = 0.35;
  s.layer_options.mu_s_regions.push_back({-0.01, 0.0, 0.1 / 3.0, 0.5, 0.9});
  s.lod.min_cells = 20;
  s.lod.window_cells = 64;
  s.lod.valid_fraction = 0.3;
  s.lod.report = true;  // not the default: the round trip must carry it
  s.provenance.tool = "hapticloud test";
  s.provenance.config_file = "configs/x.yaml";
  s.provenance.units = "mm";
  s.provenance.recentre_offset_m = {452311.25, 5218733.5, 0.1};
  s.provenance.inputs = {{"data/scans/a.ply", "00ff"}, {"data/scans/a.conf", "abcd"}};
  s.provenance.resolved_config_yaml = "input:\n  files: [a.ply]\nnote: test\n";
  write_scene(s, dir / "scene");
  EXPECT_THROW(write_scene(s, dir / "scene"), hc::InputError);  // never overwrite in place

  const Scene back = load_scene(dir / "scene");
  EXPECT_EQ(back.format_version, kSceneFormatVersion);
  EXPECT_EQ(back.geometry, g);
  EXPECT_TRUE(back.model_to_grid.matrix().isApprox(frame.matrix(), 1e-15));
  EXPECT_TRUE(same_values(back.layers.depth, s.layers.depth));
  EXPECT_TRUE(same_values(back.layers.envelope, s.layers.envelope));
  EXPECT_TRUE(same_values(back.layers.texture, s.layers.texture));
  EXPECT_TRUE(same_values(back.layers.mu_d, s.layers.mu_d));
  EXPECT_TRUE(same_values(back.layers.mu_s, s.layers.mu_s));
  EXPECT_TRUE(same_values(back.layers.region_id, s.layers.region_id));
  EXPECT_EQ(back.layers.cell_error.rows(), 0);  // absent stays absent
  EXPECT_EQ(back.layers.intensity.rows(), 0);
  EXPECT_TRUE(back.layers.depth.model_to_grid.matrix().isApprox(frame.matrix(), 1e-15));
  EXPECT_EQ(back.layers.flags, s.layers.flags);
  EXPECT_EQ(back.layers.colour_rgb8, s.layers.colour_rgb8);
  EXPECT_EQ(back.friction_model, hc::FrictionModel::kCurvature);
  EXPECT_EQ(back.layer_options, s.layer_options);  // doubles exact (17 digits)
  EXPECT_EQ(back.lod, s.lod);
  EXPECT_EQ(back.provenance.tool, s.provenance.tool);
  EXPECT_EQ(back.provenance.config_file, s.provenance.config_file);
  EXPECT_EQ(back.provenance.units, "mm");
  EXPECT_EQ(back.provenance.recentre_offset_m, s.provenance.recentre_offset_m);
  EXPECT_EQ(back.provenance.inputs, s.provenance.inputs);
  EXPECT_NE(back.provenance.resolved_config_yaml.find("note: test"), std::string::npos);
  EXPECT_TRUE(back.notes.empty());
}

// The layers on disk are files other readers read: OpenCV reads the float TIFFs (several
// strips, NaN kept) and the PNGs back bit for bit; a layer rewritten as a tiled TIFF by GDAL
// loads too; a flags PNG in colour is refused.
TEST(SceneIo, LayerFilesAreReadBackByOtherReaders) {
  const fs::path dir = hc::test::temp_dir("readers");
  const hc::GridGeometry g{257, 300, 0.0, 0.0, 0.001};  // 300 floats a row: 54 rows a strip, 5 strips
  Scene s;
  s.geometry = g;
  s.layers.depth = ramp(g, 1e-6f, Eigen::Affine3d::Identity());
  s.layers.depth.at(200, 7) = hc::kNoData;
  s.layers.flags.assign(g.cell_count(), kCellMeasured);
  s.layers.flags[12345] = kCellFilled;
  s.layers.colour_rgb8.assign(3 * g.cell_count(), 0);
  for (std::size_t i = 0; i < 3 * g.cell_count(); ++i) s.layers.colour_rgb8[i] = static_cast<std::uint8_t>(i * 31 % 251);
  write_scene(s, dir / "scene");
  const cv::Mat depth = cv::imread((dir / "scene" / "depth.tiff").string(), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(depth.type(), CV_32FC1);
  ASSERT_EQ(depth.rows, g.rows);
  ASSERT_EQ(depth.cols, g.cols);
  hc::HeightField back(g);
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c) back.at(r, c) = depth.at<float>(r, c);
  EXPECT_TRUE(same_values(back, s.layers.depth));
  const cv::Mat flags = cv::imread((dir / "scene" / "flags.png").string(), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(flags.type(), CV_8UC1);
  EXPECT_TRUE(std::equal(s.layers.flags.begin(), s.layers.flags.end(), flags.ptr<std::uint8_t>(0)));
  const cv::Mat bgr = cv::imread((dir / "scene" / "colour.png").string(), cv::IMREAD_COLOR);
  ASSERT_EQ(bgr.type(), CV_8UC3);
  for (std::size_t i = 0; i < g.cell_count(); i += 997)
    for (int k = 0; k < 3; ++k)
      EXPECT_EQ(bgr.ptr<std::uint8_t>(0)[3 * i + static_cast<std::size_t>(2 - k)], s.layers.colour_rgb8[3 * i + static_cast<std::size_t>(k)]);
  // A tiled TIFF (OpenCV writes none; GDAL does) in place of the depth layer.
  {
    GDALAllRegister();
    GDALDriver* gtiff = GetGDALDriverManager()->GetDriverByName("GTiff");
    ASSERT_NE(gtiff, nullptr);
    const char* options[] = {"TILED=YES", "BLOCKXSIZE=64", "BLOCKYSIZE=32", "COMPRESS=LZW", nullptr};
    fs::remove(dir / "scene" / "depth.tiff");
    GDALDataset* ds = gtiff->Create((dir / "scene" / "depth.tiff").c_str(), g.cols, g.rows, 1, GDT_Float32,
                                    const_cast<char**>(options));
    ASSERT_NE(ds, nullptr);
    std::vector<float> values(s.layers.depth.values().begin(), s.layers.depth.values().end());
    ASSERT_EQ(ds->GetRasterBand(1)->RasterIO(GF_Write, 0, 0, g.cols, g.rows, values.data(), g.cols, g.rows, GDT_Float32,
                                             0, 0),
              CE_None);
    GDALClose(ds);
  }
  const Scene loaded = load_scene(dir / "scene");
  EXPECT_TRUE(same_values(loaded.layers.depth, s.layers.depth));
  EXPECT_EQ(loaded.layers.flags, s.layers.flags);
  EXPECT_EQ(loaded.layers.colour_rgb8, s.layers.colour_rgb8);
  // A colour PNG where the grey flags belong.
  ASSERT_TRUE(cv::imwrite((dir / "scene" / "flags.png").string(), bgr));
  try {
    load_scene(dir / "scene");
    ADD_FAILURE() << "a colour flags layer was accepted";
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("flags.png"), std::string::npos) << e.what();
  }
}

using hc::test::resident_bytes_of_mapping;

// The scene's flags (and an untiled colour layer) are written row by row, a file-backed layer's
// pages given back after each 4 MiB of rows (scene_io.cpp): a level 0 in a file is never
// resident whole while its PNG is written. Oracles: the kernel's resident count, OpenCV's decoder.
TEST(SceneIo, APngWrittenByBlocksOfRowsGivesAFileBackedLayersPagesBackAndDecodesToItsCells) {
  const fs::path dir = hc::test::temp_dir("png-rows");
  constexpr int cols = 4096, rows = 9000;  // 35.2 MiB: above ScratchMapping::kReleaseAboveBytes
  const std::size_t n = std::size_t{cols} * rows;
  hc::CellBuffer<std::uint8_t> flags(dir, n, 0, "a test flags layer");
  ASSERT_TRUE(flags.file_backed());
  for (std::size_t i = 0; i < n; ++i) flags[i] = static_cast<std::uint8_t>((i / 7 + i / cols) % 5);
  ASSERT_GE(resident_bytes_of_mapping(flags.data()), static_cast<long long>(n) - (1 << 20));
  flags.release_resident();  // as the run's stages leave it (cell_buffer.hpp)
  int calls = 0;
  long long most_resident = 0;
  const std::string why = detail::write_png(dir / "flags.png", flags.data(), cols, rows, detail::PixelFormat::kGray, 0,
                                            false, [&] {
                                              ++calls;
                                              // What the block just written made resident.
                                              most_resident = std::max(most_resident, resident_bytes_of_mapping(flags.data()));
                                              flags.release_resident();
                                            });
  ASSERT_EQ(why, "");
  // 4 MiB of 4096-byte rows is 1024 rows: 8 full blocks in 9000 rows, then the last 808 rows.
  EXPECT_EQ(calls, 9);
  EXPECT_LE(most_resident, 5 << 20) << "each block's pages were given back before the next block";
  EXPECT_LE(resident_bytes_of_mapping(flags.data()), 1 << 20);
  const cv::Mat back = cv::imread((dir / "flags.png").string(), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(back.type(), CV_8UC1);
  ASSERT_EQ(back.rows, rows);
  ASSERT_EQ(back.cols, cols);
  ASSERT_TRUE(back.isContinuous());
  for (std::size_t i = 0; i < n; ++i)
    ASSERT_EQ(back.ptr<std::uint8_t>(0)[i], static_cast<std::uint8_t>((i / 7 + i / cols) % 5)) << i;
}

TEST(SceneIo, AFormatOneFolderStillLoads) {
  // Written the way format 1 was (before the typed scene): layers by name, friction model and
  // the resolved config as free text, no layer_options or lod keys.
  const fs::path dir = hc::test::temp_dir("v1") / "scene";
  fs::create_directories(dir);
  const hc::GridGeometry g{2, 3, 0.5, -0.25, 0.002};
  cv::Mat depth(2, 3, CV_32FC1), mu(2, 3, CV_32FC1, cv::Scalar(0.3));
  for (int i = 0; i < 6; ++i) depth.at<float>(i / 3, i % 3) = 0.01f * float(i);
  depth.at<float>(1, 1) = std::numeric_limits<float>::quiet_NaN();
  ASSERT_TRUE(cv::imwrite((dir / "depth.tiff").string(), depth));
  ASSERT_TRUE(cv::imwrite((dir / "mu_d.tiff").string(), mu));
  std::ofstream(dir / "scene.yaml")
      << "# hapticloud scene: heights in metres (grid frame), NaN = no data\n"
         "format: hapticloud-scene\nformat_version: 1\n"
         "grid:\n  rows: 2\n  cols: 3\n  x0_m: 0.5\n  y0_m: -0.25\n  cell_size_m: 0.002\n"
         "model_to_grid: [[1, 0, 0, 0.5], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n"
         "layers:\n  depth: depth.tiff\n  mu_d: mu_d.tiff\n"
         "friction_model: curvature\n"
         "provenance:\n  tool: hapticloud 0.1.0\n  config_file: \"configs/bunny.yaml\"\n  units: m\n"
         "  recentre_offset_m: [1, 2, 3]\n  inputs:\n    - file: \"bun000.ply\"\n      sha256: abc\n"
         "resolved_config:\n  name: bunny\n  layers: {sigma_space_cells: 5}\n";
  const Scene s = load_scene(dir);
  EXPECT_EQ(s.format_version, 1);
  EXPECT_EQ(s.geometry, g);
  EXPECT_EQ(s.layers.depth.at(0, 2), 0.02f);
  EXPECT_TRUE(std::isnan(s.layers.depth.at(1, 1)));
  EXPECT_EQ(s.layers.mu_d.at(1, 2), 0.3f);
  EXPECT_NEAR(s.model_to_grid.translation().x(), 0.5, 0.0);
  EXPECT_EQ(s.friction_model, hc::FrictionModel::kCurvature);
  // No typed options in format 1: defaults, the recorded friction model, and a note saying so.
  EXPECT_EQ(s.layer_options.sigma_space_cells, hc::SurfaceLayerOptions{}.sigma_space_cells);
  EXPECT_EQ(s.layer_options.friction_model, hc::FrictionModel::kCurvature);
  EXPECT_EQ(s.lod, hc::LodOptions{});
  ASSERT_EQ(s.notes.size(), 1U);
  EXPECT_NE(s.notes[0].find("format_version 1"), std::string::npos);
  EXPECT_EQ(s.provenance.config_file, "configs/bunny.yaml");
  ASSERT_EQ(s.provenance.inputs.size(), 1U);
  EXPECT_EQ(s.provenance.inputs[0].sha256, "abc");
  EXPECT_EQ(s.provenance.recentre_offset_m, Eigen::Vector3d(1, 2, 3));
  EXPECT_NE(s.provenance.resolved_config_yaml.find("bunny"), std::string::npos);
}

TEST(SceneIo, UnknownLayersAndVersionsAreNamedErrors) {
  const fs::path dir = hc::test::temp_dir("badv") / "scene";
  fs::create_directories(dir);
  std::ofstream(dir / "scene.yaml") << "format_version: 2\ngrid: {rows: 1, cols: 1, x0_m: 0, y0_m: 0, cell_size_m: 1}\n"
                                       "layers: {depth: depth.tiff, albedo: albedo.tiff}\n";
  try {
    load_scene(dir);
    FAIL();
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("albedo"), std::string::npos) << e.what();
  }
  std::ofstream(dir / "scene.yaml") << "format_version: 3\n";
  try {
    load_scene(dir);
    FAIL();
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("format_version 3"), std::string::npos) << e.what();
  }
}

}  // namespace
