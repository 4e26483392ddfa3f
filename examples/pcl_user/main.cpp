// hapticloud from a PCL user's side (issue 18): load a cloud with PCL, filter it with PCL, hand
// it to hapticloud, get the scene and the cross-check back, save the filtered cloud with PCL.
//
//   pcl_user_example CLOUD.pcd|.ply RUN_CONFIG.yaml FILTERED_OUT.pcd [--out RUN_DIR] [--set key=value ...]
//                    [--no-sor]   (hand the cloud over unfiltered, to time the run's own filters)
//
// The run config gives everything after ingest (units, view, filters including filters.pcl,
// grid, layers, cross-check); its input.files are not read. Every stage's counts and seconds
// are printed, so the same program compares PCL's filters with hapticloud's own on one cloud
// (docs/architecture.md, "hapticloud and PCL").

#include <hc/pcl/conversions.hpp>

#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/io/auto_io.h>
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

#include <chrono>
#include <cstdio>
#include <exception>
#include <string>
#include <vector>

int main(int argc, char** argv) {
  if (argc < 4) {
    std::fprintf(stderr, "usage: %s CLOUD.pcd|.ply RUN_CONFIG.yaml FILTERED_OUT.pcd [--out RUN_DIR] [--set key=value ...] "
                 "[--no-sor]\n",
                 argv[0]);
    return 2;
  }
  std::vector<std::string> sets;
  std::string out_dir;
  bool sor_first = true;
  for (int i = 4; i < argc; i += 2) {
    const std::string opt = argv[i];
    if (opt == "--no-sor") {
      sor_first = false;
      --i;
    } else if (i + 1 >= argc) {
      std::fprintf(stderr, "%s needs a value\n", opt.c_str());
      return 2;
    } else if (opt == "--set") {
      sets.emplace_back(argv[i + 1]);
    } else if (opt == "--out") {
      out_dir = argv[i + 1];
    } else {
      std::fprintf(stderr, "unknown option %s\n", opt.c_str());
      return 2;
    }
  }
  using Clock = std::chrono::steady_clock;
  auto seconds = [](Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); };
  try {
    // 1. Load with PCL.
    auto t0 = Clock::now();
    pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
    if (pcl::io::load(argv[1], *cloud) != 0) {
      std::fprintf(stderr, "PCL could not read %s\n", argv[1]);
      return 1;
    }
    std::printf("loaded with PCL: %zu points in %.3f s\n", cloud->size(), seconds(t0));

    // 2. Filter with PCL.
    t0 = Clock::now();
    pcl::PointCloud<pcl::PointXYZ>::Ptr filtered(new pcl::PointCloud<pcl::PointXYZ>);
    if (sor_first) {
      pcl::StatisticalOutlierRemoval<pcl::PointXYZ> sor;
      sor.setInputCloud(cloud);
      sor.setMeanK(16);
      sor.setStddevMulThresh(2.0);
      sor.filter(*filtered);
    } else {
      filtered = cloud;
    }
    if (sor_first) std::printf("PCL StatisticalOutlierRemoval (k 16, 2 sigma): %zu -> %zu points in %.3f s\n", cloud->size(),
                filtered->size(), seconds(t0));

    // 3. Hand it to hapticloud: the run config says how to grid it.
    const hc::pipeline::RunConfig config = hc::pipeline::load_run_config(argv[2], sets);
    t0 = Clock::now();
    const hc::pipeline::BuiltScene built = hc::pipeline::build_scene(*filtered, config, /*keep_cloud=*/true);
    std::printf("hapticloud build_scene: %.3f s\n", seconds(t0));
    for (const auto& st : built.summary.stages) {
      std::printf("  %-32s %9zu -> %9zu points  %8.3f s\n", st.stage.c_str(), st.count_in, st.count_out, st.seconds);
    }

    // 4. The scene and the cross-check.
    const auto& g = built.scene.geometry;
    std::printf("scene: %d x %d cells of %.3f mm, %zu with data\n", g.rows, g.cols, g.cell_size_m * 1e3,
                built.summary.valid_cells);
    if (built.summary.cross_check) {
      const auto& cc = *built.summary.cross_check;
      std::printf("cross-check: %.2f %% of the cells supported by a point within the tolerance\n",
                  100.0 * cc.supported_fraction);
    }
    if (built.summary.verdict) std::printf("verdict: %s\n", built.summary.verdict->status.c_str());
    if (!out_dir.empty()) {
      hc::pipeline::write_run(built, config, out_dir);
      std::printf("run folder: %s\n", out_dir.c_str());
    }

    // 5. The points hapticloud gridded (its filters applied; grid frame, metres) back to PCL.
    pcl::PointCloud<pcl::PointXYZ> out;
    hc::pipeline::to_pcl(*built.cloud, out);
    if (pcl::io::savePCDFileBinary(argv[3], out) != 0) {
      std::fprintf(stderr, "PCL could not write %s\n", argv[3]);
      return 1;
    }
    std::printf("saved with PCL: %s (%zu points)\n", argv[3], out.size());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
