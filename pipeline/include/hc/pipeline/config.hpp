#pragma once
/// @file config.hpp
/// The YAML run configuration of `hapticloud run`, validated into plain structs.
/// Every key, its type, default and allowed range is listed in docs/config.md.

#include "hc/pipeline/filters.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/surface_layers.hpp"
#include "hc/pipeline/synthetic.hpp"
#include "hc/pipeline/transform.hpp"

#include <Eigen/Core>

#include <array>
#include <limits>

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace hc::pipeline {

struct InputConfig {
  std::vector<std::filesystem::path> files;     ///< scans, resolved against the config's folder
  std::optional<std::filesystem::path> conf;    ///< scanalyze .conf to merge several views
  std::string units = "m";                      ///< "m" | "cm" | "mm" | "ft" | "us-ft" | "in"
  std::vector<int> las_drop_classes{7, 18};     ///< LAS classes dropped on reading (0..255)
  double max_extent_m = kDefaultMaxExtentM;     ///< largest accepted bounding-box side [m]
  std::optional<SyntheticSpec> synthetic;       ///< generate instead of reading files
};

struct OutlierConfig {
  bool enabled = true;
  int k = 16;                    ///< neighbours [-], 1..256
  double std_multiplier = 2.0;   ///< σ multiplier [-], (0, 100]
  OutlierScope scope = OutlierScope::kAll;  ///< "all" | "front" (which points are tested)
};

struct FilterConfig {
  OutlierConfig outliers;
  std::optional<std::pair<Eigen::Vector3d, Eigen::Vector3d>> crop_m;  ///< min, max (grid frame)
  double voxel_m = 0.0;          ///< voxel-grid leaf [m]; 0 = off
};

struct GridConfig {
  ReprojectOptions reproject;    ///< N or cell size, splat radius, see-through
  int hole_fill_max_cells = 0;   ///< largest hole filled [cells]; 0 = off
};

struct CrossCheckConfig {
  bool enabled = true;
  double tolerance_m = 0.0005;   ///< a cell is supported if a point lies within this [m]
  double hidden_band_m = 0.002;  ///< (a) uses points at most this far below the surface [m]
  bool compare_naive = true;     ///< also grid naively (front-most only) and cross-check that,
                                 ///< so the report shows what see-through handling, splats and
                                 ///< hole filling change
};

struct LayersConfig {
  bool enabled = true;           ///< texture, curvature and friction layers (issue 3)
  SurfaceLayerOptions options;
};

/// Sliding-sound material of the `audio:` section: a preset and optional overrides (NaN = the
/// preset's value). The app turns it into hc::audio::Material (docs/audio.md).
struct AudioMaterialSpec {
  std::string preset = "granite";  ///< granite | sandstone | marble | bronze | wood
  double slide_gain = std::numeric_limits<double>::quiet_NaN();
  double resonance_hz = std::numeric_limits<double>::quiet_NaN();
  double q = std::numeric_limits<double>::quiet_NaN();
  double grain_m = std::numeric_limits<double>::quiet_NaN();
  double roughness = std::numeric_limits<double>::quiet_NaN();
  double speed_ref_m_per_s = std::numeric_limits<double>::quiet_NaN();
  double texture_ref_m = std::numeric_limits<double>::quiet_NaN();
};

/// One `audio.regions[i]` entry (grid frame, metres).
struct AudioRegionSpec {
  std::string name;
  std::string shape = "box";                    ///< box | polygon | label
  std::array<double, 4> box_m{};                ///< x_min, y_min, x_max, y_max [m]
  std::vector<std::array<double, 2>> polygon_m; ///< vertices (x, y) [m]
  int label = 0;                                ///< value in audio.label_image
  std::filesystem::path clip;                   ///< resolved; empty = a synthesised tone
  std::string note = "Sa";                      ///< Sa Re Ga Ma Pa Dha Ni (synthesised tone)
  double gain = 1.0;
  double pitch = 1.0;
  bool retrigger = true;
  bool trigger_on_enter = true;
  std::string mode = "one_shot";                ///< one_shot | continuous
  AudioMaterialSpec material;
};

/// The `audio:` section (contact sounds, issue 7): read here so that one file configures a run;
/// the app turns it into hc::audio::AudioConfig (hc::pipeline does not depend on hc::audio).
struct AudioSpec {
  bool present = false;            ///< the config has an audio section
  bool enabled = true;
  int sample_rate_hz = 48000;
  double master_gain = 0.5;
  double limiter_threshold_dbfs = -1.0;
  double limiter_release_s = 0.05;
  double sa_hz = 196.0;
  double tone_seconds = 2.5;
  double region_cell_m = 0.0005;
  std::filesystem::path label_image;  ///< resolved; empty = none
  double force_threshold_n = 0.0;
  double force_full_n = 3.0;
  double force_min_gain = 0.1;
  double strike_window_s = 0.05;
  bool slide_enabled = true;
  AudioMaterialSpec slide_material;   ///< outside every region
  std::vector<AudioRegionSpec> regions;
};

/// A fully validated run configuration.
/// Settings of the Novint Falcon used by `hapticloud explore --device falcon` (falcon.*).
/// Plain data: hc::pipeline does not depend on hc::falcon; the app copies these into
/// falcon::FalconConfig.
struct FalconSpec {
  std::filesystem::path firmware;  ///< firmware image, resolved against the config's folder; "" →
                                   ///< $HAPTICLOUD_FALCON_FIRMWARE (the image is never shipped)
  int index = 0;                   ///< which attached Falcon (0 = the first found), ≥ 0
  double max_force_n = 8.0;        ///< force cap (0, 10] [N]
  int max_missed_ticks = 10;       ///< servo ticks without a read before forces go to zero, [1, 1000]
};

struct RunConfig {
  std::filesystem::path source;        ///< the config file it came from ("" when built in code)
  std::string name;                    ///< run name (default: the config file's stem)
  InputConfig input;
  ViewTransform view;
  FilterConfig filters;
  GridConfig grid;
  CrossCheckConfig cross_check;
  LayersConfig layers;
  AudioSpec audio;                     ///< contact sounds (optional section)
  FalconSpec falcon;                   ///< the Novint Falcon (falcon.*, issue 5)
  LodOptions lod;                      ///< levels of detail and the haptic window (lod.*, issue 4)
  std::string resolved_yaml;           ///< every key with the value used (defaults included)
};

/// Reads and validates a run config. `overrides` are "dotted.key=value" strings (the value is
/// parsed as YAML, so `view.rotation.axis=[0,1,0]` works) applied before validation.
/// Relative input paths are resolved against the config file's folder.
/// @throws hc::ConfigError naming the file, the dotted key, its line (or the --set override),
///         the offending value and the allowed type or range; also for unknown keys.
/// @throws hc::InputError if the file is missing or not valid YAML (with line and column).
RunConfig load_run_config(const std::filesystem::path& path,
                          const std::vector<std::string>& overrides = {});

/// The same from YAML text (used by tests); `origin` names it in messages and is the base for
/// relative paths (its parent folder).
RunConfig parse_run_config(const std::string& yaml_text, const std::filesystem::path& origin,
                           const std::vector<std::string>& overrides = {});

}  // namespace hc::pipeline
