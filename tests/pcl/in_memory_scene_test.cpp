// build_scene from an in-memory PCL cloud (issue 18) against the file path on the same points,
// and filters.pcl stages inside a run.
#include "hc/pcl/conversions.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/ingest.hpp"

#include <gtest/gtest.h>

#include <pcl/io/pcd_io.h>

#include "test_paths.hpp"

#include <cmath>
#include <algorithm>
#include <cstring>
#include <string>

namespace {

namespace fs = std::filesystem;
using namespace hc::pipeline;

RunConfig config_for(const fs::path& file, const std::string& extra = "") {
  return parse_run_config("input: {files: [" + file.filename().string() + "]}\n"
                          "grid: {n: 200, splat_radius_cells: 1, see_through_depth_m: 0.003, hole_fill_max_cells: 16}\n"
                          "filters:\n"
                          "  outliers: {enabled: true}\n" +
                              extra,
                          file.parent_path() / "run.yaml");
}

bool same_bits(const hc::CellBuffer<float>& a, const hc::CellBuffer<float>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

const char* kPclStages =
    "  pcl:\n"
    "    - {name: StatisticalOutlierRemoval, mean_k: 16, stddev_mul: 2}\n"
    "    - {name: UniformSampling, radius_m: 0.0006}\n";

TEST(PclInMemory, SamePointsGiveTheSameSceneAsTheFilePath) {
  const fs::path dir = hc::test::temp_dir("bunny");
  // A PCL user's cloud: the bunny scan as pcl::PointXYZ, saved with PCL as binary PCD.
  pcl::PointCloud<pcl::PointXYZ> cloud;
  to_pcl(load_cloud(hc::test::scan_path("bunny/bun000.ply")).value, cloud);
  ASSERT_GT(cloud.size(), 30000u);
  ASSERT_EQ(pcl::io::savePCDFileBinary((dir / "bunny.pcd").string(), cloud), 0);

  const RunConfig config = config_for(dir / "bunny.pcd", kPclStages);
  const BuiltScene from_file = build_scene(config, /*keep_cloud=*/true);
  const BuiltScene from_memory = build_scene(cloud, config, /*keep_cloud=*/true);

  const Scene& a = from_file.scene;
  const Scene& b = from_memory.scene;
  ASSERT_EQ(a.geometry.rows, b.geometry.rows);
  ASSERT_EQ(a.geometry.cols, b.geometry.cols);
  EXPECT_EQ(a.geometry.x0_m, b.geometry.x0_m);
  EXPECT_EQ(a.geometry.y0_m, b.geometry.y0_m);
  EXPECT_EQ(a.geometry.cell_size_m, b.geometry.cell_size_m);
  EXPECT_TRUE(a.model_to_grid.matrix() == b.model_to_grid.matrix());
  EXPECT_GT(from_file.summary.valid_cells, 10000u);
  EXPECT_EQ(from_file.summary.valid_cells, from_memory.summary.valid_cells);
  EXPECT_TRUE(same_bits(a.depth().values(), b.depth().values()));
  EXPECT_TRUE(same_bits(a.layers.texture.values(), b.layers.texture.values()));
  EXPECT_TRUE(same_bits(a.layers.mu_d.values(), b.layers.mu_d.values()));
  EXPECT_EQ(a.layers.flags, b.layers.flags);
  // Every stage after ingest saw the same counts; the cross-check found the same.
  const auto& sa = from_file.summary.stages;
  const auto& sb = from_memory.summary.stages;
  ASSERT_EQ(sa.size(), sb.size());
  for (std::size_t i = 0; i < sa.size(); ++i) {
    EXPECT_EQ(sa[i].stage, sb[i].stage);
    EXPECT_EQ(sa[i].count_in, sb[i].count_in) << sa[i].stage;
    EXPECT_EQ(sa[i].count_out, sb[i].count_out) << sa[i].stage;
  }
  ASSERT_TRUE(from_file.summary.cross_check && from_memory.summary.cross_check);
  EXPECT_EQ(from_file.summary.cross_check->supported_fraction, from_memory.summary.cross_check->supported_fraction);
  ASSERT_TRUE(from_file.summary.verdict && from_memory.summary.verdict);
  EXPECT_EQ(from_file.summary.verdict->status, from_memory.summary.verdict->status);
  // The filtered clouds are the same points.
  ASSERT_TRUE(from_file.cloud && from_memory.cloud);
  EXPECT_TRUE(from_file.cloud->xyz == from_memory.cloud->xyz);
  // Provenance names the in-memory input.
  ASSERT_EQ(b.provenance.inputs.size(), 1u);
  EXPECT_NE(b.provenance.inputs[0].file.find("in-memory"), std::string::npos);
}

TEST(PclInMemory, PclStagesAppearInTheRunReportInConfigOrder) {
  const fs::path dir = hc::test::temp_dir("stages");
  pcl::PointCloud<pcl::PointXYZ> cloud;
  to_pcl(load_cloud(hc::test::scan_path("bunny/bun000.ply")).value, cloud);
  const BuiltScene built = build_scene(cloud, config_for(dir / "none.pcd", kPclStages));
  const auto& st = built.summary.stages;
  std::vector<std::string> names;
  for (const auto& s : st) names.push_back(s.stage);
  const auto sor = std::find(names.begin(), names.end(), "pcl:StatisticalOutlierRemoval");
  const auto us = std::find(names.begin(), names.end(), "pcl:UniformSampling");
  const auto voxel_or_nf = std::find(names.begin(), names.end(), "non_finite");
  const auto outliers = std::find(names.begin(), names.end(), "outliers");
  ASSERT_NE(sor, names.end());
  ASSERT_NE(us, names.end());
  EXPECT_LT(voxel_or_nf, sor);
  EXPECT_EQ(sor + 1, us);
  EXPECT_LT(us, outliers);
  const auto& r_sor = st[static_cast<std::size_t>(sor - names.begin())];
  const auto& r_us = st[static_cast<std::size_t>(us - names.begin())];
  EXPECT_LT(r_sor.count_out, r_sor.count_in);
  EXPECT_EQ(r_us.count_in, r_sor.count_out);
  EXPECT_LT(r_us.count_out, r_us.count_in);
}

TEST(PclInMemory, ColourAndIntensityReachTheSceneLayers) {
  const fs::path dir = hc::test::temp_dir("colour");
  Cloud c = load_cloud(hc::test::scan_path("bunny/bun000.ply")).value;
  c.rgb.assign(3 * c.size(), 0);
  c.intensity.assign(c.size(), 0.25f);
  for (std::size_t i = 0; i < c.size(); ++i) c.rgb[3 * i] = 200;  // red
  pcl::PointCloud<pcl::PointXYZRGB> rgb;
  to_pcl(c, rgb);
  const BuiltScene a = build_scene(rgb, config_for(dir / "none.pcd"));
  ASSERT_FALSE(a.scene.layers.colour_rgb8.empty());
  bool red = false;
  for (std::size_t i = 0; i + 2 < a.scene.layers.colour_rgb8.size(); i += 3) {
    red = red || (a.scene.layers.colour_rgb8[i] == 200 && a.scene.layers.colour_rgb8[i + 1] == 0);
  }
  EXPECT_TRUE(red);
  pcl::PointCloud<pcl::PointXYZI> xyzi;
  to_pcl(c, xyzi);
  const BuiltScene b = build_scene(xyzi, config_for(dir / "none.pcd"));
  ASSERT_FALSE(b.scene.layers.intensity.values().empty());
}

TEST(PclInMemory, NormalsFollowTheKeptPointsAndTurnWithTheView) {
  // Each point's normal is set to its own file position n = p (any vector is carried as given).
  // Through a run with a 90-degree view rotation about x and subset filters (outliers,
  // StatisticalOutlierRemoval, UniformSampling), a kept point ends at p' = R·(p − c) + t and its
  // normal at n' = R·p, so n' − p' = R·c − t is the same vector for every kept point. A normal
  // left unrotated, or one that stayed with another point, breaks that.
  const fs::path dir = hc::test::temp_dir("normals");
  Cloud c = load_cloud(hc::test::scan_path("bunny/bun000.ply")).value;
  pcl::PointCloud<pcl::PointXYZRGBNormal> pn;
  to_pcl(c, pn);
  for (std::size_t i = 0; i < pn.size(); ++i) {
    pn[i].normal_x = pn[i].x;
    pn[i].normal_y = pn[i].y;
    pn[i].normal_z = pn[i].z;
    // A per-point curvature the rotation keeps: |p|, which must stay equal to |n'| = |R·p|.
    pn[i].curvature = std::sqrt(pn[i].x * pn[i].x + pn[i].y * pn[i].y + pn[i].z * pn[i].z);
  }
  const RunConfig config =
      config_for(dir / "none.pcd", std::string(kPclStages) + "view: {rotation: {axis: [1, 0, 0], angle_deg: 90}}\n");
  const BuiltScene built = build_scene(pn, config, /*keep_cloud=*/true);
  ASSERT_TRUE(built.cloud.has_value());
  const Cloud& kept = *built.cloud;
  ASSERT_GT(kept.size(), 10000u);
  ASSERT_LT(kept.size(), pn.size());  // the filters removed points
  ASSERT_EQ(kept.normal.size(), 3 * kept.size());
  ASSERT_EQ(kept.curvature.size(), kept.size());
  const Eigen::Vector3d d0 = Eigen::Vector3d(kept.normal[0], kept.normal[1], kept.normal[2]) - kept.xyz.col(0);
  double worst_m = 0.0;
  for (std::size_t i = 0; i < kept.size(); ++i) {
    const Eigen::Vector3d n(kept.normal[3 * i], kept.normal[3 * i + 1], kept.normal[3 * i + 2]);
    worst_m = std::max(worst_m, (n - kept.xyz.col(static_cast<Eigen::Index>(i)) - d0).norm());
    ASSERT_NEAR(kept.curvature[i], n.norm(), 1e-6) << "point " << i;  // stayed with its point
  }
  // Float normals of a 0.2 m object agree to about 1e-8 m; unrotated ones would differ by up to
  // 0.1 m (n' − p' would then be (I − R)·p + R·c − t, varying with y and z).
  EXPECT_LT(worst_m, 1e-6);
  // to_pcl hands them back to PCL as they are.
  pcl::PointCloud<pcl::PointXYZRGBNormal> out;
  to_pcl(kept, out);
  ASSERT_EQ(out.size(), kept.size());
  EXPECT_EQ(out[out.size() - 1].normal_z, kept.normal[3 * kept.size() - 1]);
  // A filter that makes new points drops them, with a note.
  const BuiltScene voxel =
      build_scene(pn, config_for(dir / "none.pcd", "  pcl:\n    - {name: VoxelGrid, leaf_m: 0.002}\n"), true);
  ASSERT_TRUE(voxel.cloud.has_value());
  EXPECT_FALSE(voxel.cloud->has_normals());
  bool noted = false;
  for (const auto& st : voxel.summary.stages)
    for (const auto& note : st.notes) noted = noted || note.find("normals") != std::string::npos;
  EXPECT_TRUE(noted);
  // An in-memory cloud whose normals do not match its points is refused, naming them.
  Cloud bad = c;
  bad.normal.assign(3 * c.size() - 3, 0.0f);
  try {
    build_scene(bad, config);
    ADD_FAILURE() << "expected an InputError";
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("its normal holds " + std::to_string(3 * c.size() - 3) + " values"), std::string::npos)
        << e.what();
  }
  bad.normal.clear();
  bad.curvature.assign(c.size(), 0.0f);
  EXPECT_THROW(build_scene(bad, config), hc::InputError);  // curvature without normals
}

}  // namespace
