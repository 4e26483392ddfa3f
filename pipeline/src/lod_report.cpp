#include "stage_util.hpp"
#include "hc/pipeline/lod_report.hpp"

#include "hc/common/error.hpp"
#include "hc/common/units.hpp"
#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/simulated_device.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/filters.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/lod_controller.hpp"
#include "hc/pipeline/preview.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/pipeline/synthetic.hpp"
#include "hc/pipeline/transform.hpp"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>

namespace hc::pipeline {
namespace {

using detail::Clock;
using detail::seconds_since;

std::string fixed(double v, int precision) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(precision) << v;
  return s.str();
}

/// The scene's stored resolved config as YAML text and the config file it came from.
bool stored_config(const Scene& scene, std::string& yaml_text, std::filesystem::path& origin) {
  YAML::Node meta;
  try {
    meta = YAML::Load(scene.metadata_yaml);
  } catch (const YAML::Exception& e) {
    throw InputError(std::string("levels: the scene's scene.yaml does not parse: ") + e.what());
  }
  const YAML::Node resolved = meta["resolved_config"];
  if (!resolved || !resolved.IsMap()) return false;
  YAML::Emitter out;
  out << resolved;
  yaml_text = out.c_str();
  const YAML::Node prov = meta["provenance"];
  origin = prov && prov["config_file"] && prov["config_file"].IsScalar() ? prov["config_file"].Scalar()
                                                                          : std::string("scene.yaml");
  if (origin.empty()) origin = "scene.yaml";
  return true;
}

}  // namespace

Cloud prepare_points(const RunConfig& config) {
  Cloud cloud;
  if (config.input.synthetic) {
    cloud = generate_surface(*config.input.synthetic);
  } else if (config.input.conf) {
    cloud = load_and_merge_scans(config.input.files, *config.input.conf).value;
  } else {
    cloud = load_cloud(config.input.files.front()).value;
  }
  Eigen::Vector3d offset_m = Eigen::Vector3d::Zero();
  cloud = to_metres_and_recentre(std::move(cloud), metres_per_unit(config.input.units), &offset_m,
                                 config.input.max_extent_m).value;
  cloud = apply_view_transform(std::move(cloud), config.view).value;
  cloud = remove_non_finite(std::move(cloud)).value;
  if (config.filters.crop_m) {
    cloud = crop_box(std::move(cloud), config.filters.crop_m->first, config.filters.crop_m->second).value;
  }
  if (config.filters.voxel_m > 0.0) cloud = voxel_downsample(std::move(cloud), config.filters.voxel_m).value;
  if (config.filters.outliers.enabled) {
    if (config.filters.outliers.scope == OutlierScope::kFront) {
      cloud = remove_front_statistical_outliers(std::move(cloud), config.filters.outliers.k,
                                                config.filters.outliers.std_multiplier, config.grid.reproject)
                  .value;
    } else {
      cloud = remove_statistical_outliers(std::move(cloud), config.filters.outliers.k,
                                          config.filters.outliers.std_multiplier)
                  .value;
    }
  }
  return cloud;
}

Cloud scene_points(const Scene& scene, const std::optional<std::filesystem::path>& config_override) {
  RunConfig config;
  if (config_override) {
    config = load_run_config(*config_override);
  } else {
    std::string text;
    std::filesystem::path origin;
    if (!stored_config(scene, text, origin)) {
      throw InputError("levels: the scene's scene.yaml has no resolved_config to find its points; give the run "
                       "config with --config");
    }
    config = parse_run_config(text, origin);
  }
  for (const auto& f : config.input.files) {
    if (!std::filesystem::exists(f)) {
      throw InputError("levels: the scene's input '" + f.string() + "' (relative to the config '" +
                       config.source.string() + "') does not exist from this folder; run from the folder the scene "
                       "was made in, or give the run config with --config");
    }
  }
  return prepare_points(config);
}

void scene_options(const Scene& scene, SurfaceLayerOptions& layers, LodOptions& lod) {
  std::string text;
  std::filesystem::path origin;
  if (!stored_config(scene, text, origin)) {
    layers = SurfaceLayerOptions{};
    lod = LodOptions{};
    return;
  }
  const RunConfig c = parse_run_config(text, origin);
  layers = c.layers.options;
  lod = c.lod;
}

std::vector<LevelRow> level_table(const std::shared_ptr<LodPyramid>& pyramid, const Cloud* points,
                                  const LevelTableOptions& options) {
  std::vector<LevelRow> rows;
  const haptics::DeviceInfo info = haptics::SimulatedDevice::default_info();
  for (int level = 0; level < pyramid->level_count(); ++level) {
    LevelRow row;
    row.level = level;
    const auto lvl = pyramid->level(level);
    const GridGeometry& g = lvl->depth_m.geometry();
    row.rows = g.rows;
    row.cols = g.cols;
    row.cell_size_m = g.cell_size_m;
    row.valid_cells = lvl->depth_m.valid_count();
    row.build_seconds = lvl->depth_seconds + lvl->layers_seconds;
    if (options.cross_check && level == 0 && options.level0_cross_check) {
      row.point_vertical = options.level0_cross_check->point_vertical;
      row.supported_fraction = options.level0_cross_check->supported_fraction;
    } else if (options.cross_check && points != nullptr && row.valid_cells > 0 && g.rows >= 2 && g.cols >= 2) {
      const CrossCheck c = cross_check(*points, lvl->depth_m, options.tolerance_m, options.hidden_band_m).value;
      row.point_vertical = c.point_vertical;
      row.supported_fraction = c.supported_fraction;
    }

    // Per-tick cost: a pressing circle on the centred window of this level.
    haptics::SharedState shared;
    LodControllerOptions lo;
    lo.device_half_extent_m = info.workspace_half_extent_m;
    lo.prefetch_neighbours = false;  // time this level alone, in the order of the table
    LodController lod(pyramid, shared, lo);
    const HapticWindow& w =
        lod.centre_window(level, g.x_of_col(0.5 * (g.cols - 1)), g.y_of_row(0.5 * (g.rows - 1)));
    haptics::ManualClock clock;
    haptics::ScriptedPath path;
    path.kind = haptics::PathKind::kCircle;
    path.half_x_m = 0.5 * info.workspace_half_extent_m.x();
    path.z_above_m = (w.max_height_m - w.map.origin_m.z()) / w.map.scale + 0.01;
    path.z_contact_m = -0.005;
    path.speed_m_per_s = 0.05;
    path.approach_s = 0.2;
    haptics::SimulatedDevice dev(clock, path, haptics::VirtualHand{}, info);
    dev.open();
    haptics::ServoConfig cfg;
    cfg.workspace = w.map;
    haptics::ServoLoop loop(dev, shared, clock, cfg);
    shared.commands.try_push(haptics::Command::of(haptics::CommandType::kArm));
    loop.run_ticks(static_cast<std::uint64_t>(std::max(options.ticks, 10)), clock);
    row.tick_p50_ns = loop.stats().compute.percentile_ns(0.5);
    row.tick_p99_ns = loop.stats().compute.percentile_ns(0.99);

    // Switch: from a neighbouring level to this one (levels cached), to the first tick on it.
    const int other = level + 1 < pyramid->level_count() ? level + 1 : std::max(0, level - 1);
    std::vector<double> ms;
    for (int k = 0; k < 5; ++k) {
      lod.set_level(other);
      loop.run_ticks(5, clock);
      haptics::Snapshot snap;
      shared.snapshots.read(snap);
      const auto t0 = Clock::now();
      lod.set_level(level, snap.proxy_m.eigen());
      loop.run_ticks(1, clock);
      ms.push_back(seconds_since(t0) * 1000.0);
      shared.collect_retired();
    }
    std::nth_element(ms.begin(), ms.begin() + 2, ms.end());
    row.switch_ms = ms[2];
    rows.push_back(row);
  }
  return rows;
}

std::string level_table_markdown(const std::vector<LevelRow>& rows) {
  std::ostringstream md;
  md << "| level | cell (mm) | size (samples) | valid | build (ms) | RMS (mm) | p95 (mm) | supported | tick p50 / p99 (ns) "
        "| switch (ms) |\n|---|---|---|---|---|---|---|---|---|---|\n";
  for (const LevelRow& r : rows) {
    md << "| " << r.level << " | " << fixed(r.cell_size_m * 1000.0, 4) << " | " << r.cols << " × " << r.rows << " | "
       << r.valid_cells << " | " << fixed(r.build_seconds * 1000.0, 1) << " | ";
    if (r.point_vertical) {
      md << fixed(r.point_vertical->rms_mm, 3) << " | " << fixed(r.point_vertical->p95_mm, 3) << " | "
         << fixed(100.0 * r.supported_fraction, 1) << " % | ";
    } else {
      md << "– | – | – | ";
    }
    md << fixed(r.tick_p50_ns, 0) << " / " << fixed(r.tick_p99_ns, 0) << " | " << fixed(r.switch_ms, 3) << " |\n";
  }
  return md.str();
}

std::string level_table_text(const std::vector<LevelRow>& rows) {
  std::ostringstream t;
  t << std::left << std::setw(6) << "level" << std::setw(11) << "cell_mm" << std::setw(14) << "cols x rows"
    << std::setw(10) << "build_ms" << std::setw(10) << "rms_mm" << std::setw(10) << "p95_mm" << std::setw(11)
    << "supported" << std::setw(13) << "tick_p50_ns" << std::setw(12) << "tick_p99_ns" << "switch_ms\n";
  for (const LevelRow& r : rows) {
    t << std::setw(6) << r.level << std::setw(11) << fixed(r.cell_size_m * 1000.0, 4) << std::setw(14)
      << (std::to_string(r.cols) + " x " + std::to_string(r.rows)) << std::setw(10) << fixed(r.build_seconds * 1000.0, 1);
    if (r.point_vertical) {
      t << std::setw(10) << fixed(r.point_vertical->rms_mm, 3) << std::setw(10) << fixed(r.point_vertical->p95_mm, 3)
        << std::setw(11) << (fixed(100.0 * r.supported_fraction, 1) + "%");
    } else {
      t << std::setw(10) << "-" << std::setw(10) << "-" << std::setw(11) << "-";
    }
    t << std::setw(13) << fixed(r.tick_p50_ns, 0) << std::setw(12) << fixed(r.tick_p99_ns, 0) << fixed(r.switch_ms, 3)
      << "\n";
  }
  return t.str();
}

std::vector<std::string> write_level_previews(LodPyramid& pyramid, const std::filesystem::path& dir) {
  std::vector<std::string> names;
  std::vector<cv::Mat> images;
  for (int level = 0; level < pyramid.level_count(); ++level) {
    const std::string name = "lod_level_" + std::to_string(level) + ".png";
    const std::filesystem::path png = dir / name;
    write_hillshade_preview(pyramid.depth_level(level)->depth_m, png);
    names.push_back(name);
    images.push_back(cv::imread(png.string(), cv::IMREAD_COLOR));
    if (images.back().empty()) throw InputError("levels: cannot read back '" + png.string() + "'");
  }
  // Side by side at one height (level 0's, at most 600 px); coarse levels keep their cells.
  const int height = std::min(600, images.front().rows);
  std::vector<cv::Mat> row;
  for (const cv::Mat& img : images) {
    cv::Mat scaled;
    const double f = static_cast<double>(height) / img.rows;
    cv::resize(img, scaled, cv::Size(std::max(1, static_cast<int>(std::lround(img.cols * f))), height), 0, 0,
               f >= 1.0 ? cv::INTER_NEAREST : cv::INTER_AREA);
    if (!row.empty()) row.push_back(cv::Mat(height, 8, CV_8UC3, cv::Scalar(255, 255, 255)));
    row.push_back(scaled);
  }
  cv::Mat composite;
  cv::hconcat(row, composite);
  const std::filesystem::path out = dir / "lod_levels.png";
  bool ok = false;
  try {
    ok = cv::imwrite(out.string(), composite, {cv::IMWRITE_PNG_COMPRESSION, 1});
  } catch (const cv::Exception&) {
    ok = false;
  }
  if (!ok) throw InputError("levels: cannot write '" + out.string() + "'");
  names.push_back("lod_levels.png");
  return names;
}

}  // namespace hc::pipeline
