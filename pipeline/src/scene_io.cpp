#include "hc/pipeline/scene_io.hpp"

#include "hc/common/error.hpp"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/core.hpp>
#include <yaml-cpp/yaml.h>

#include <unistd.h>

#include <ctime>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>

namespace hc::pipeline {
namespace fs = std::filesystem;

namespace {

cv::Mat as_mat(const HeightField& f) {
  // cv::Mat over the field's memory (no copy); imwrite only reads it.
  return cv::Mat(f.rows(), f.cols(), CV_32FC1, const_cast<float*>(f.data()));
}

void write_float_tiff(const HeightField& f, const fs::path& file) {
  bool ok = false;
  try {
    ok = cv::imwrite(file.string(), as_mat(f));
  } catch (const cv::Exception& e) {
    throw InputError(file.string() + ": cannot write the TIFF layer: " + e.what());
  }
  if (!ok) throw InputError(file.string() + ": cannot write the TIFF layer");
}

}  // namespace

void write_scene(const Scene& scene, const fs::path& scene_dir, const std::string& extra_yaml) {
  if (!scene.has("depth")) throw std::invalid_argument("write_scene: the scene has no 'depth' layer");
  const HeightField& depth = scene.depth();
  const GridGeometry& g = depth.geometry();
  for (const auto& [name, layer] : scene.layers) {
    if (!(layer.geometry() == g)) {
      throw std::invalid_argument("write_scene: layer '" + name + "' has a different grid geometry than 'depth'");
    }
  }
  if (!scene.flags.empty() && scene.flags.size() != g.cell_count()) {
    throw std::invalid_argument("write_scene: flags hold " + std::to_string(scene.flags.size()) +
                                " cells, the grid " + std::to_string(g.cell_count()));
  }
  std::error_code ec;
  if (fs::exists(scene_dir)) throw InputError(scene_dir.string() + ": the scene folder already exists");
  fs::create_directories(scene_dir, ec);
  if (ec) throw InputError(scene_dir.string() + ": cannot create the scene folder: " + ec.message());

  YAML::Emitter y;
  y << YAML::BeginMap;
  y << YAML::Key << "format" << YAML::Value << "hapticloud-scene";
  y << YAML::Key << "format_version" << YAML::Value << kSceneFormatVersion;
  y << YAML::Key << "grid" << YAML::Value << YAML::BeginMap;
  y << YAML::Key << "rows" << YAML::Value << g.rows << YAML::Key << "cols" << YAML::Value << g.cols;
  y << YAML::Key << "x0_m" << YAML::Value << g.x0_m << YAML::Key << "y0_m" << YAML::Value << g.y0_m;
  y << YAML::Key << "cell_size_m" << YAML::Value << g.cell_size_m;
  y << YAML::Key << "sample_layout" << YAML::Value
    << "node-centred: sample (r, c) at x = x0_m + c*cell_size_m, y = y0_m + r*cell_size_m; TIFF row 0 = grid row 0 (smallest y)";
  y << YAML::Key << "view_direction" << YAML::Value << "-z (larger z is nearer the viewer)";
  y << YAML::Key << "no_data" << YAML::Value << "NaN";
  y << YAML::EndMap;
  y << YAML::Key << "model_to_grid" << YAML::Value << YAML::Flow << YAML::BeginSeq;
  for (int r = 0; r < 4; ++r) {
    y << YAML::Flow << YAML::BeginSeq;
    for (int c = 0; c < 4; ++c) y << depth.model_to_grid.matrix()(r, c);
    y << YAML::EndSeq;
  }
  y << YAML::EndSeq;
  y << YAML::Key << "layers" << YAML::Value << YAML::BeginMap;
  for (const auto& [name, layer] : scene.layers) {
    (void)layer;
    y << YAML::Key << name << YAML::Value << (name + ".tiff");
    write_float_tiff(layer, scene_dir / (name + ".tiff"));
  }
  y << YAML::EndMap;
  if (!scene.flags.empty()) {
    const cv::Mat flags(g.rows, g.cols, CV_8UC1, const_cast<std::uint8_t*>(scene.flags.data()));
    if (!cv::imwrite((scene_dir / "flags.png").string(), flags)) {
      throw InputError((scene_dir / "flags.png").string() + ": cannot write the flags layer");
    }
    y << YAML::Key << "flags" << YAML::Value << "flags.png";
    y << YAML::Key << "flag_codes" << YAML::Value
      << "0 empty, 1 measured, 2 splatted, 3 see-through (no data), 4 filled";
  }
  if (!scene.friction_model.empty()) y << YAML::Key << "friction_model" << YAML::Value << scene.friction_model;
  y << YAML::EndMap;

  std::ofstream out(scene_dir / "scene.yaml");
  out << "# hapticloud scene: heights in metres (grid frame), NaN = no data\n" << y.c_str() << "\n";
  if (!extra_yaml.empty()) out << extra_yaml << (extra_yaml.back() == '\n' ? "" : "\n");
  if (!out) throw InputError((scene_dir / "scene.yaml").string() + ": cannot write");
}

Scene load_scene(const fs::path& scene_dir) {
  const fs::path meta = scene_dir / "scene.yaml";
  if (!fs::exists(meta)) {
    throw InputError(scene_dir.string() + ": not a scene folder (no scene.yaml; make one with 'hapticloud run')");
  }
  YAML::Node root;
  try {
    root = YAML::LoadFile(meta.string());
  } catch (const YAML::Exception& e) {
    throw InputError(meta.string() + ": not valid YAML: " + e.what());
  }
  Scene s;
  {
    std::ifstream in(meta);
    std::stringstream ss;
    ss << in.rdbuf();
    s.metadata_yaml = ss.str();
  }
  try {
    const int version = root["format_version"].as<int>();
    if (version != kSceneFormatVersion) {
      throw InputError(meta.string() + ": format_version " + std::to_string(version) + " is not supported (expected " +
                       std::to_string(kSceneFormatVersion) + ")");
    }
    const YAML::Node grid = root["grid"];
    GridGeometry g;
    g.rows = grid["rows"].as<int>();
    g.cols = grid["cols"].as<int>();
    g.x0_m = grid["x0_m"].as<double>();
    g.y0_m = grid["y0_m"].as<double>();
    g.cell_size_m = grid["cell_size_m"].as<double>();
    if (g.rows < 1 || g.cols < 1 || !(g.cell_size_m > 0)) {
      throw InputError(meta.string() + ": grid has rows, cols ≥ 1 and cell_size_m > 0 violated");
    }
    Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
    if (const YAML::Node frame = root["model_to_grid"]) {
      for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) m(r, c) = frame[static_cast<std::size_t>(r)][static_cast<std::size_t>(c)].as<double>();
    }
    for (const auto& kv : root["layers"]) {
      const std::string name = kv.first.as<std::string>();
      const fs::path file = scene_dir / kv.second.as<std::string>();
      if (!fs::exists(file)) throw InputError(file.string() + ": missing scene layer '" + name + "'");
      const cv::Mat img = cv::imread(file.string(), cv::IMREAD_UNCHANGED);
      if (img.empty()) throw InputError(file.string() + ": missing or unreadable scene layer '" + name + "'");
      if (img.type() != CV_32FC1 || img.rows != g.rows || img.cols != g.cols) {
        throw InputError(file.string() + ": layer '" + name + "' is " + std::to_string(img.cols) + "x" +
                         std::to_string(img.rows) + " (type " + std::to_string(img.type()) + "), expected " +
                         std::to_string(g.cols) + "x" + std::to_string(g.rows) + " 32-bit float");
      }
      HeightField f(g);
      for (int r = 0; r < g.rows; ++r) {
        const float* src = img.ptr<float>(r);
        std::copy(src, src + g.cols, f.data() + static_cast<std::ptrdiff_t>(r) * g.cols);
      }
      f.model_to_grid = Eigen::Affine3d(m);
      s.layers.emplace(name, std::move(f));
    }
    if (!s.has("depth")) throw InputError(meta.string() + ": the scene lists no 'depth' layer");
    if (const YAML::Node flags = root["flags"]) {
      const fs::path file = scene_dir / flags.as<std::string>();
      const cv::Mat img = cv::imread(file.string(), cv::IMREAD_UNCHANGED);
      if (img.empty() || img.type() != CV_8UC1 || img.rows != g.rows || img.cols != g.cols) {
        throw InputError(file.string() + ": missing or malformed flags layer");
      }
      s.flags.assign(img.begin<std::uint8_t>(), img.end<std::uint8_t>());
    }
    if (const YAML::Node fm = root["friction_model"]) s.friction_model = fm.as<std::string>();
  } catch (const YAML::Exception& e) {
    throw InputError(meta.string() + ": malformed scene metadata: " + e.what());
  }
  return s;
}

bool is_hapticloud_output(const fs::path& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return false;
  if (fs::is_regular_file(dir / kOutputMarkerFile, ec)) return true;
  // Run folders written before the marker existed: only the names a run writes.
  static const std::set<std::string> kRunEntries = {"scene", "previews", "report.md", "report.json"};
  if (!fs::is_regular_file(dir / "scene" / "scene.yaml", ec)) return false;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    if (!kRunEntries.count(it->path().filename().string())) return false;
  }
  return !ec;
}

namespace {

/// `base` + suffix, with "-1", "-2", ... appended until the name is free.
fs::path free_sibling(const fs::path& base, const std::string& suffix) {
  fs::path p = base;
  p += suffix;
  std::error_code ec;
  for (int k = 1; fs::exists(fs::symlink_status(p, ec)); ++k) {
    p = base;
    p += suffix + "-" + std::to_string(k);
  }
  return p;
}

std::string local_time_stamp() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  localtime_r(&now, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y%m%d-%H%M%S", &tm);
  return buf;
}

}  // namespace

StagingDir::StagingDir(fs::path target, ExistingOutput existing) : target_(std::move(target)) {
  if (target_.filename().empty()) target_ = target_.parent_path();
  std::error_code ec;
  const fs::file_status st = fs::symlink_status(target_, ec);
  if (fs::exists(st)) {
    const bool empty_dir = fs::is_directory(st) && fs::is_empty(target_, ec) && !ec;
    target_is_foreign_ = !empty_dir && !is_hapticloud_output(target_);
    if (target_is_foreign_ && existing == ExistingOutput::kRefuse) {
      const std::string what = fs::is_directory(st) ? "a folder that is not an earlier hapticloud output"
                                                    : "an existing file";
      throw InputError("output " + target_.string() + " is " + what +
                       ": refusing to replace it; expected a new or empty folder, or an earlier output "
                       "(choose another --out, or pass --force to keep it as " + target_.string() +
                       ".replaced-<time> and write the output there)");
    }
  }
  // A fresh staging name: nothing that happens to exist is ever removed.
  staging_ = free_sibling(target_, ".partial-" + std::to_string(::getpid()));
  fs::create_directories(staging_, ec);
  if (ec) throw InputError(staging_.string() + ": cannot create the output folder: " + ec.message());
  std::ofstream marker(staging_ / kOutputMarkerFile);
  marker << "This folder was written by hapticloud; a later run may replace it.\n";
  if (!marker) {
    fs::remove_all(staging_, ec);
    throw InputError((staging_ / kOutputMarkerFile).string() + ": cannot write the output marker");
  }
}

StagingDir::~StagingDir() {
  if (!committed_) {
    std::error_code ec;
    fs::remove_all(staging_, ec);
  }
}

void StagingDir::commit() {
  std::error_code ec;
  fs::path old;
  if (fs::exists(fs::symlink_status(target_, ec))) {
    old = target_is_foreign_ ? free_sibling(target_, ".replaced-" + local_time_stamp())
                             : free_sibling(target_, ".old-" + std::to_string(::getpid()));
    fs::rename(target_, old, ec);
    if (ec) throw InputError("cannot move the earlier output " + target_.string() + " aside: " + ec.message());
  }
  fs::rename(staging_, target_, ec);
  if (ec) {
    const std::string why = ec.message();
    if (!old.empty()) fs::rename(old, target_, ec);
    throw InputError("cannot rename " + staging_.string() + " to " + target_.string() + ": " + why);
  }
  committed_ = true;
  if (old.empty()) return;
  if (target_is_foreign_) {
    moved_aside_ = old;  // the user's: kept
  } else {
    fs::remove_all(old, ec);  // an earlier output or an empty folder: ours to remove
  }
}

}  // namespace hc::pipeline
