#include "image_io.hpp"
#include "stage_util.hpp"
#include "tiled_layers.hpp"
#include "hc/pipeline/scene_io.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/surface_layers.hpp"

#include <yaml-cpp/yaml.h>

#include <signal.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstring>
#include <ctime>
#include <fstream>
#include <algorithm>
#include <map>
#include <mutex>
#include <set>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace hc::pipeline {
namespace fs = std::filesystem;

namespace {


/// Why writing `bytes` into `file` may have failed: "no space left" when the file system has
/// less free than that, else the errno text (may be "Success" when OpenCV swallowed it).
std::string write_failure_reason(const fs::path& file, std::size_t bytes) {
  std::error_code ec;
  const fs::space_info sp = fs::space(file.parent_path(), ec);
  if (!ec && sp.available < bytes + (1u << 20)) {
    return "no space left on the device (" + std::to_string(sp.available) + " bytes free, about " +
           std::to_string(bytes) + " needed)";
  }
  return errno != 0 ? std::string(std::strerror(errno)) : std::string("the image encoder refused it");
}

void write_float_tiff(const HeightField& f, const fs::path& file) {
  errno = 0;
  const std::string why = detail::write_float_tiff(file, f.data(), f.cols(), f.rows());
  if (!why.empty()) {
    const std::string space = write_failure_reason(file, f.values().size() * sizeof(float));
    throw InputError(file.string() + ": cannot write the TIFF layer: " +
                     (space.rfind("no space", 0) == 0 ? space : why));
  }
}

}  // namespace

void detail::write_tiled_layer(const fs::path& file, const void* values, const GridGeometry& g, int tile_cells,
                               TileSamples samples, const std::function<void()>& after_tile_row) {
  errno = 0;
  const std::string why = detail::write_tiled_tiff(file, values, g.cols, g.rows, tile_cells, samples, after_tile_row);
  if (!why.empty()) {
    const std::string space =
        write_failure_reason(file, g.cell_count() * static_cast<std::size_t>(detail::tile_sample_bytes(samples)));
    throw InputError(file.string() + ": cannot write the tiled TIFF layer: " +
                     (space.rfind("no space", 0) == 0 ? space : why));
  }
}

std::string detail::read_tiled_layer(const fs::path& file, const GridGeometry& g, TileSamples samples,
                                     const std::function<void*()>& buffer) {
  TiledTiffReader reader;
  std::string why = reader.open(file, samples);
  if (why.empty() && (reader.width() != g.cols || reader.height() != g.rows)) {
    why = std::to_string(reader.width()) + "x" + std::to_string(reader.height());
  }
  if (why.empty()) why = reader.read_region(0, 0, g.rows, g.cols, buffer());
  return why;
}

fs::path detail::stored_layer_file(const fs::path& scene_dir, int level, const std::string& name) {
  if (level == 0) return scene_dir / (name + ".tiff");
  // Built with append: GCC 12's -Wrestrict misfires on a literal + std::string at -O3.
  std::string folder = "L";
  folder.append(std::to_string(level));
  return scene_dir / kSceneLevelsFolder / folder / (name + ".tiff");
}

namespace {

/// The float layers of a scene in file order, with their file stems.
template <class Layers, class F>
void for_each_layer(Layers& l, F&& f) {
  f("depth", l.depth);
  f("envelope", l.envelope);
  f("texture", l.texture);
  f("mu_d", l.mu_d);
  f("mu_s", l.mu_s);
  f("cell_error", l.cell_error);
  f("region_id", l.region_id);
  f("intensity", l.intensity);
}

void emit_layer_options(YAML::Emitter& y, const SurfaceLayerOptions& o) {
  y << YAML::Key << "layer_options" << YAML::Value << YAML::BeginMap;
  y << YAML::Key << "sigma_space_cells" << YAML::Value << o.sigma_space_cells;
  y << YAML::Key << "sigma_range_m" << YAML::Value << o.sigma_range_m;
  y << YAML::Key << "friction_model" << YAML::Value << to_string(o.friction_model);
  y << YAML::Key << "mu_min" << YAML::Value << o.mu_min;
  y << YAML::Key << "mu_max" << YAML::Value << o.mu_max;
  y << YAML::Key << "workspace_radius_m" << YAML::Value << o.workspace_radius_m;
  y << YAML::Key << "curvature_gain_m" << YAML::Value << o.curvature_gain_m;
  y << YAML::Key << "friction_scale" << YAML::Value << to_string(o.friction_scale);
  y << YAML::Key << "mu_s" << YAML::Value << o.mu_s;
  y << YAML::Key << "mu_s_regions" << YAML::Value << YAML::BeginSeq;
  for (const auto& r : o.mu_s_regions) {
    y << YAML::Flow << YAML::BeginSeq << r.x_min_m << r.y_min_m << r.x_max_m << r.y_max_m << r.mu_s << YAML::EndSeq;
  }
  y << YAML::EndSeq << YAML::EndMap;
}

void emit_lod_options(YAML::Emitter& y, const LodOptions& o) {
  y << YAML::Key << "lod" << YAML::Value << YAML::BeginMap;
  y << YAML::Key << "min_cells" << YAML::Value << o.min_cells;
  y << YAML::Key << "valid_fraction" << YAML::Value << o.valid_fraction;
  y << YAML::Key << "antialias_sigma_cells" << YAML::Value << o.antialias_sigma_cells;
  y << YAML::Key << "memory_budget_mb" << YAML::Value << o.memory_budget_mb;
  y << YAML::Key << "window_cells" << YAML::Value << o.window_cells;
  y << YAML::Key << "report" << YAML::Value << o.report;
  y << YAML::Key << "report_cross_check" << YAML::Value << o.report_cross_check;
  y << YAML::Key << "report_sample_points" << YAML::Value << static_cast<unsigned long long>(o.report_sample_points);
  y << YAML::EndMap;
}

void emit_provenance(YAML::Emitter& y, const SceneProvenance& p) {
  y << YAML::Key << "provenance" << YAML::Value << YAML::BeginMap;
  y << YAML::Key << "tool" << YAML::Value << p.tool;
  y << YAML::Key << "config_file" << YAML::Value << p.config_file;
  y << YAML::Key << "units" << YAML::Value << p.units;
  y << YAML::Key << "recentre_offset_m" << YAML::Value << YAML::Flow << YAML::BeginSeq << p.recentre_offset_m.x()
    << p.recentre_offset_m.y() << p.recentre_offset_m.z() << YAML::EndSeq;
  y << YAML::Key << "inputs" << YAML::Value << YAML::BeginSeq;
  for (const auto& in : p.inputs) {
    y << YAML::BeginMap << YAML::Key << "file" << YAML::Value << in.file << YAML::Key << "sha256" << YAML::Value
      << in.sha256 << YAML::EndMap;
  }
  y << YAML::EndSeq;
  if (!p.synthetic.empty()) y << YAML::Key << "synthetic" << YAML::Value << p.synthetic;
  if (!p.crs.empty()) y << YAML::Key << "crs" << YAML::Value << p.crs;
  y << YAML::EndMap;
}

/// Reads `node[key]` as T, or keeps `out` when the key is absent.
template <class T>
void read_opt(const YAML::Node& node, const char* key, T& out) {
  if (const YAML::Node v = node[key]) out = v.as<T>();
}

SurfaceLayerOptions parse_layer_options(const YAML::Node& n) {
  SurfaceLayerOptions o;
  read_opt(n, "sigma_space_cells", o.sigma_space_cells);
  read_opt(n, "sigma_range_m", o.sigma_range_m);
  if (const YAML::Node fm = n["friction_model"]) o.friction_model = friction_model_from_string(fm.as<std::string>());
  read_opt(n, "mu_min", o.mu_min);
  read_opt(n, "mu_max", o.mu_max);
  read_opt(n, "workspace_radius_m", o.workspace_radius_m);
  read_opt(n, "curvature_gain_m", o.curvature_gain_m);
  // Scenes written before per-level friction scaling had their μ_d in scene units.
  o.friction_scale = FrictionScale::kScene;
  if (const YAML::Node fs = n["friction_scale"]) o.friction_scale = friction_scale_from_string(fs.as<std::string>());
  read_opt(n, "mu_s", o.mu_s);
  for (const auto& r : n["mu_s_regions"]) {
    o.mu_s_regions.push_back({r[0].as<double>(), r[1].as<double>(), r[2].as<double>(), r[3].as<double>(),
                              r[4].as<double>()});
  }
  return o;
}

LodOptions parse_lod_options(const YAML::Node& n) {
  LodOptions o;
  read_opt(n, "min_cells", o.min_cells);
  read_opt(n, "valid_fraction", o.valid_fraction);
  read_opt(n, "antialias_sigma_cells", o.antialias_sigma_cells);
  read_opt(n, "memory_budget_mb", o.memory_budget_mb);
  read_opt(n, "window_cells", o.window_cells);
  read_opt(n, "report", o.report);
  read_opt(n, "report_cross_check", o.report_cross_check);
  read_opt(n, "report_sample_points", o.report_sample_points);
  return o;
}

SceneProvenance parse_provenance(const YAML::Node& n) {
  SceneProvenance p;
  if (!n || !n.IsMap()) return p;
  read_opt(n, "tool", p.tool);
  read_opt(n, "config_file", p.config_file);
  read_opt(n, "units", p.units);
  read_opt(n, "synthetic", p.synthetic);
  read_opt(n, "crs", p.crs);
  if (const YAML::Node o = n["recentre_offset_m"]) {
    p.recentre_offset_m = {o[0].as<double>(), o[1].as<double>(), o[2].as<double>()};
  }
  for (const auto& in : n["inputs"]) {
    if (in["file"]) p.inputs.push_back({in["file"].as<std::string>(), in["sha256"] ? in["sha256"].as<std::string>() : ""});
  }
  return p;
}

void write_text_file(const fs::path& file, const std::string& text) {
  errno = 0;
  std::ofstream out(file);
  out << text;
  out.flush();
  if (!out) {
    throw InputError(file.string() + ": cannot write: " + write_failure_reason(file, text.size()));
  }
}

/// scene.yaml of a scene folder: format, storage, grid, frame, the layer files (`<name>.tiff`
/// for each of `layers`), flags and colour files (when not empty), friction model, options,
/// provenance and the resolved config.
std::string scene_yaml_text(const Scene& scene, const SceneStorage& storage, const std::vector<std::string>& layers,
                            const std::string& flags_file, const std::string& colour_file) {
  const GridGeometry& g = scene.geometry;
  const bool tiled = storage.tile_cells != 0;
  YAML::Emitter y;
  y.SetDoublePrecision(17);
  y << YAML::BeginMap;
  y << YAML::Key << "format" << YAML::Value << "hapticloud-scene";
  y << YAML::Key << "format_version" << YAML::Value << (tiled ? kTiledSceneFormatVersion : kSceneFormatVersion);
  if (tiled) {
    y << YAML::Key << "storage" << YAML::Value << YAML::BeginMap;
    y << YAML::Key << "tile_cells" << YAML::Value << storage.tile_cells;
    y << YAML::Key << "stored_levels" << YAML::Value << storage.stored_levels;
    y << YAML::Key << "levels_folder" << YAML::Value << kSceneLevelsFolder;
    y << YAML::Key << "layout" << YAML::Value
      << "square tiles of tile_cells samples in every layer TIFF; tiles without bytes are no data; level k >= 1 in "
         "levels_folder/L<k>/<layer>.tiff";
    y << YAML::EndMap;
  }
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
    for (int c = 0; c < 4; ++c) y << scene.model_to_grid.matrix()(r, c);
    y << YAML::EndSeq;
  }
  y << YAML::EndSeq;
  y << YAML::Key << "layers" << YAML::Value << YAML::BeginMap;
  for (const std::string& name : layers) y << YAML::Key << name << YAML::Value << (name + ".tiff");
  y << YAML::EndMap;
  if (!flags_file.empty()) {
    y << YAML::Key << "flags" << YAML::Value << flags_file;
    y << YAML::Key << "flag_codes" << YAML::Value
      << "0 empty, 1 measured, 2 splatted, 3 see-through (no data), 4 filled, 5 upsampled";
  }
  if (!colour_file.empty()) y << YAML::Key << "colour" << YAML::Value << colour_file;
  if (scene.friction_model) y << YAML::Key << "friction_model" << YAML::Value << to_string(*scene.friction_model);
  emit_layer_options(y, scene.layer_options);
  emit_lod_options(y, scene.lod);
  emit_provenance(y, scene.provenance);
  y << YAML::EndMap;

  std::string text = "# hapticloud scene: heights in metres (grid frame), NaN = no data\n";
  text += y.c_str();
  text += "\n";
  if (!scene.provenance.resolved_config_yaml.empty()) {
    text += "# the run config as resolved, for the record (nothing reads it back)\nresolved_config:\n";
    std::istringstream is(scene.provenance.resolved_config_yaml);
    for (std::string line; std::getline(is, line);) text += "  " + line + "\n";
  }
  return text;
}

}  // namespace

void write_scene(const Scene& scene, const fs::path& scene_dir, const SceneStorage& storage) {
  const GridGeometry& g = scene.geometry;
  const bool tiled = storage.tile_cells != 0;
  if (tiled && (storage.tile_cells < 16 || storage.tile_cells > 4096 || storage.tile_cells % 16 != 0)) {
    throw std::invalid_argument("write_scene: tile side " + std::to_string(storage.tile_cells) +
                                ": expected a multiple of 16 in [16, 4096]");
  }
  if (storage.stored_levels < 0) throw std::invalid_argument("write_scene: stored_levels < 0");
  if (scene.layers.depth.rows() == 0) throw std::invalid_argument("write_scene: the scene has no depth layer");
  for_each_layer(scene.layers, [&](const char* name, const HeightField& layer) {
    if (layer.rows() != 0 && !(layer.geometry() == g)) {
      throw std::invalid_argument(std::string("write_scene: layer '") + name +
                                  "' has a different grid geometry than the scene");
    }
  });
  if (!scene.layers.flags.empty() && scene.layers.flags.size() != g.cell_count()) {
    throw std::invalid_argument("write_scene: flags hold " + std::to_string(scene.layers.flags.size()) +
                                " cells, the grid " + std::to_string(g.cell_count()));
  }
  if (!scene.layers.colour_rgb8.empty() && scene.layers.colour_rgb8.size() != 3 * g.cell_count()) {
    throw std::invalid_argument("write_scene: colour holds " + std::to_string(scene.layers.colour_rgb8.size()) +
                                " bytes, expected 3 per cell (" + std::to_string(3 * g.cell_count()) + ")");
  }
  std::error_code ec;
  if (fs::exists(scene_dir)) throw InputError(scene_dir.string() + ": the scene folder already exists");
  // Not create_directories: a run's staging folder removed by the interrupt watcher must not be
  // recreated by a write still under way (remove_live_staging_dirs).
  fs::create_directory(scene_dir, ec);
  if (ec) throw InputError(scene_dir.string() + ": cannot create the scene folder: " + ec.message());

  std::vector<std::string> layer_files;
  for_each_layer(scene.layers, [&](const char* name, const HeightField& layer) {
    if (layer.rows() == 0) return;
    layer_files.emplace_back(name);
    const fs::path file = scene_dir / (std::string(name) + ".tiff");
    if (tiled) {
      // A file-backed layer's pages given back after each row of tiles (cell_buffer.hpp).
      detail::write_tiled_layer(file, layer.data(), g, storage.tile_cells, detail::TileSamples::kFloat32,
                                [&layer] { layer.values().release_resident(); });
    } else {
      write_float_tiff(layer, file);
    }
    layer.values().release_resident();  // a file-backed layer's pages given back (cell_buffer.hpp)
  });
  std::string flags_file, colour_file;
  if (!scene.layers.flags.empty()) {
    errno = 0;
    const std::string why =
        detail::write_png(scene_dir / "flags.png", scene.layers.flags.data(), g.cols, g.rows, detail::PixelFormat::kGray,
                          0, false, [&scene] { scene.layers.flags.release_resident(); });  // by blocks of rows
    if (!why.empty()) {
      const std::string space = write_failure_reason(scene_dir / "flags.png", g.cell_count());
      throw InputError((scene_dir / "flags.png").string() + ": cannot write the flags layer: " +
                       (space.rfind("no space", 0) == 0 ? space : why));
    }
    flags_file = "flags.png";
  }
  if (!scene.layers.colour_rgb8.empty() && tiled) {
    detail::write_tiled_layer(scene_dir / "colour.tiff", scene.layers.colour_rgb8.data(), g, storage.tile_cells,
                              detail::TileSamples::kRgb8, [&scene] { scene.layers.colour_rgb8.release_resident(); });
    colour_file = "colour.tiff";
  } else if (!scene.layers.colour_rgb8.empty()) {
    errno = 0;
    const std::string why =
        detail::write_png(scene_dir / "colour.png", scene.layers.colour_rgb8.data(), g.cols, g.rows,
                          detail::PixelFormat::kRgb, 0, false, [&scene] { scene.layers.colour_rgb8.release_resident(); });
    if (!why.empty()) {
      const std::string space = write_failure_reason(scene_dir / "colour.png", 3 * g.cell_count());
      throw InputError((scene_dir / "colour.png").string() + ": cannot write the colour layer: " +
                       (space.rfind("no space", 0) == 0 ? space : why));
    }
    colour_file = "colour.png";
  }
  write_text_file(scene_dir / "scene.yaml", scene_yaml_text(scene, storage, layer_files, flags_file, colour_file));
}

void add_level0_surface_layers(const fs::path& scene_dir) {
  const fs::path meta = scene_dir / "scene.yaml";
  Scene s = load_scene(scene_dir, false);  // checks the format and that every listed file is there
  if (s.storage.tile_cells == 0) {
    throw InputError(meta.string() + ": not a tiled scene (format 3): level 0's surface layers are added to tiled scenes only");
  }
  static const std::array<const char*, 4> kSurface = {"envelope", "texture", "mu_d", "mu_s"};
  for (const char* name : kSurface) {
    const fs::path file = scene_dir / (std::string(name) + ".tiff");
    if (!fs::exists(file)) throw InputError(file.string() + ": missing: level 0's surface layer '" + name + "' was not written");
  }
  std::string text;
  {
    std::ifstream in(meta, std::ios::binary);
    std::ostringstream ss;
    ss << in.rdbuf();
    if (!in || !ss) throw InputError(meta.string() + ": cannot read it back: " + std::strerror(errno));
    text = ss.str();
  }
  // The layers listed, in write_scene's order, and the four surface layers; the flags and
  // colour files as named.
  std::vector<std::string> layer_files;
  std::string flags_file, colour_file;
  try {
    const YAML::Node root = YAML::Load(text);
    const YAML::Node listed = root["layers"];
    if (!listed || !listed.IsMap() || !listed["depth"]) throw InputError(meta.string() + ": no 'layers' map with 'depth'");
    for_each_layer(s.layers, [&](const char* name, const HeightField&) {
      const bool surface = std::find_if(kSurface.begin(), kSurface.end(),
                                        [&](const char* n) { return std::strcmp(n, name) == 0; }) != kSurface.end();
      if (surface || listed[name]) layer_files.emplace_back(name);
    });
    if (root["flags"]) flags_file = root["flags"].as<std::string>();
    if (root["colour"]) colour_file = root["colour"].as<std::string>();
  } catch (const YAML::Exception& e) {
    throw InputError(meta.string() + ": malformed scene metadata: " + e.what());
  }
  // The model the layers were made with (compute_surface_layers records the options' model).
  if (!s.friction_model) s.friction_model = s.layer_options.friction_model;
  // The resolved config as written (scene_yaml_text indents each line by two spaces), not as
  // re-emitted by the parser.
  const std::string marker = "\nresolved_config:\n";
  s.provenance.resolved_config_yaml.clear();
  if (const std::size_t at = text.find(marker); at != std::string::npos) {
    std::istringstream is(text.substr(at + marker.size()));
    for (std::string line; std::getline(is, line);) {
      s.provenance.resolved_config_yaml += (line.rfind("  ", 0) == 0 ? line.substr(2) : line) + "\n";
    }
  }
  // Replaced in one rename: a reader sees the old list or the new one, never half a file.
  detail::write_atomically(meta, scene_yaml_text(s, s.storage, layer_files, flags_file, colour_file));
}

struct TiledSceneWriter::Impl {
  fs::path dir;
  Scene header;
  SceneStorage storage;
  Contents contents;
  std::vector<std::string> names;                 // layer files every level holds
  std::vector<GridGeometry> geometries;           // per level
  std::vector<std::vector<std::unique_ptr<detail::TiledTiffWriter>>> files;  // [level][name]
  std::uint64_t bytes = 0;
  bool finished = false;
};

TiledSceneWriter::TiledSceneWriter(const fs::path& scene_dir, const Scene& header, const SceneStorage& storage,
                                   const Contents& contents)
    : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  const GridGeometry& g = header.geometry;
  if (storage.tile_cells < 16 || storage.tile_cells > 4096 || storage.tile_cells % 16 != 0) {
    throw std::invalid_argument("TiledSceneWriter: tile side " + std::to_string(storage.tile_cells) +
                                ": expected a multiple of 16 in [16, 4096]");
  }
  if (g.rows < 2 || g.cols < 2 || !(g.cell_size_m > 0.0)) {
    throw std::invalid_argument("TiledSceneWriter: level 0 must have at least 2 x 2 samples and a cell size > 0");
  }
  const int max_levels = lod_level_count(g, 2);
  if (storage.stored_levels < 1 || storage.stored_levels > max_levels) {
    throw std::invalid_argument("TiledSceneWriter: stored_levels " + std::to_string(storage.stored_levels) +
                                ": expected 1.." + std::to_string(max_levels));
  }
  m.dir = scene_dir;
  m.header = header;
  m.header.layers = SceneLayers{};
  m.storage = storage;
  m.contents = contents;
  m.names = {"depth"};
  if (contents.surface_layers) m.names.insert(m.names.end(), {"envelope", "texture", "mu_d", "mu_s"});
  if (contents.cell_error) m.names.emplace_back("cell_error");
  if (contents.colour) m.names.emplace_back("colour");
  if (fs::exists(scene_dir)) throw InputError(scene_dir.string() + ": the scene folder already exists");
  std::error_code ec;
  fs::create_directory(scene_dir, ec);
  if (ec) throw InputError(scene_dir.string() + ": cannot create the scene folder: " + ec.message());
  for (int l = 0; l < storage.stored_levels; ++l) {
    m.geometries.push_back(lod_level_geometry(g, l));
    const GridGeometry& lg = m.geometries.back();
    if (l == 1) fs::create_directory(scene_dir / kSceneLevelsFolder, ec);
    if (l >= 1 && !ec) fs::create_directory(detail::stored_layer_file(scene_dir, l, "depth").parent_path(), ec);
    if (ec) throw InputError(scene_dir.string() + ": cannot create the folder of level " + std::to_string(l) + ": " + ec.message());
    auto& level_files = m.files.emplace_back();
    for (const std::string& name : m.names) {
      const fs::path file = detail::stored_layer_file(scene_dir, l, name);
      auto w = std::make_unique<detail::TiledTiffWriter>();
      const std::string why = w->open(file, lg.cols, lg.rows, storage.tile_cells,
                                      name == "colour" ? detail::TileSamples::kRgb8 : detail::TileSamples::kFloat32);
      if (!why.empty()) throw InputError(file.string() + ": cannot create the tiled layer: " + why);
      level_files.push_back(std::move(w));
    }
  }
}

TiledSceneWriter::~TiledSceneWriter() = default;

const GridGeometry& TiledSceneWriter::level_geometry(int level) const {
  if (level < 0 || level >= static_cast<int>(impl_->geometries.size())) {
    throw std::out_of_range("TiledSceneWriter: level " + std::to_string(level) + " is not stored");
  }
  return impl_->geometries[static_cast<std::size_t>(level)];
}

int TiledSceneWriter::tile_cells() const noexcept { return impl_->storage.tile_cells; }

void TiledSceneWriter::write_tile(int level, const std::string& layer, int tile_row, int tile_col, const void* data) {
  Impl& m = *impl_;
  const GridGeometry& g = level_geometry(level);
  const auto it = std::find(m.names.begin(), m.names.end(), layer);
  if (m.finished) throw std::invalid_argument("TiledSceneWriter: write_tile after finish()");
  if (it == m.names.end()) {
    throw std::invalid_argument("TiledSceneWriter: layer '" + layer + "' is not written by this writer");
  }
  const int t = m.storage.tile_cells;
  if (tile_row < 0 || tile_col < 0 || tile_row * t >= g.rows || tile_col * t >= g.cols) {
    throw std::invalid_argument("TiledSceneWriter: tile (" + std::to_string(tile_row) + ", " + std::to_string(tile_col) +
                                ") is outside level " + std::to_string(level));
  }
  auto& w = *m.files[static_cast<std::size_t>(level)][static_cast<std::size_t>(it - m.names.begin())];
  const std::uint64_t before = w.bytes_written();
  const std::string why = w.write_tile(tile_row, tile_col, data);
  if (!why.empty()) throw InputError(detail::stored_layer_file(m.dir, level, layer).string() + ": " + why);
  m.bytes += w.bytes_written() - before;
}

std::uint64_t TiledSceneWriter::finish() {
  Impl& m = *impl_;
  for (std::size_t l = 0; l < m.files.size(); ++l) {
    for (std::size_t k = 0; k < m.names.size(); ++k) {
      const std::string why = m.files[l][k]->finish();
      if (!why.empty()) {
        throw InputError(detail::stored_layer_file(m.dir, static_cast<int>(l), m.names[k]).string() + ": " + why);
      }
    }
  }
  std::vector<std::string> layers;
  for (const std::string& n : m.names) {
    if (n != "colour") layers.push_back(n);
  }
  write_text_file(m.dir / "scene.yaml",
                  scene_yaml_text(m.header, m.storage, layers, "", m.contents.colour ? "colour.tiff" : ""));
  m.finished = true;
  return m.bytes;
}

Scene load_scene(const fs::path& scene_dir, bool load_layers) {
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
  try {
    if (!root.IsMap() || !root["format_version"]) {
      throw InputError(meta.string() + ": no format_version: not a hapticloud scene");
    }
    const int version = root["format_version"].as<int>();
    if (version != 1 && version != kSceneFormatVersion && version != kTiledSceneFormatVersion) {
      throw InputError(meta.string() + ": format_version " + std::to_string(version) + " is not supported (expected 1, " +
                       std::to_string(kSceneFormatVersion) + " or " + std::to_string(kTiledSceneFormatVersion) + ")");
    }
    s.format_version = version;
    if (version == kTiledSceneFormatVersion) {
      const YAML::Node st = root["storage"];
      if (!st || !st["tile_cells"] || !st["stored_levels"]) {
        throw InputError(meta.string() + ": format_version 3 without storage.tile_cells and storage.stored_levels");
      }
      s.storage.tile_cells = st["tile_cells"].as<int>();
      s.storage.stored_levels = st["stored_levels"].as<int>();
      if (s.storage.tile_cells < 16 || s.storage.tile_cells > 4096 || s.storage.tile_cells % 16 != 0 ||
          s.storage.stored_levels < 0 || s.storage.stored_levels > 64) {
        throw InputError(meta.string() + ": storage.tile_cells " + std::to_string(s.storage.tile_cells) +
                         " or storage.stored_levels " + std::to_string(s.storage.stored_levels) +
                         " out of range (expected a multiple of 16 in [16, 4096] and 0..64)");
      }
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
    s.geometry = g;
    Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
    if (const YAML::Node frame = root["model_to_grid"]) {
      for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) m(r, c) = frame[static_cast<std::size_t>(r)][static_cast<std::size_t>(c)].as<double>();
    }
    s.model_to_grid = Eigen::Affine3d(m);
    const YAML::Node listed = root["layers"];
    for (const auto& kv : listed) {
      const std::string name = kv.first.as<std::string>();
      bool known = false;
      for_each_layer(s.layers, [&](const char* n, HeightField&) { known = known || name == n; });
      if (!known) {
        throw InputError(meta.string() + ": unknown layer '" + name +
                         "' (expected depth, envelope, texture, mu_d, mu_s, cell_error, region_id, intensity)");
      }
    }
    for_each_layer(s.layers, [&](const char* name, HeightField& out) {
      const YAML::Node entry = listed[name];
      if (!entry) return;
      const fs::path file = scene_dir / entry.as<std::string>();
      if (!fs::exists(file)) throw InputError(file.string() + ": missing scene layer '" + name + "'");
      if (!load_layers) return;
      detail::FloatImage img;
      const std::string why = detail::read_float_tiff(file, img, g.cols, g.rows);
      if (!why.empty() || img.height != g.rows || img.width != g.cols) {
        throw InputError(file.string() + ": layer '" + name + "' is " +
                         (why.empty() ? std::to_string(img.width) + "x" + std::to_string(img.height) : why) +
                         ", expected " + std::to_string(g.cols) + "x" + std::to_string(g.rows) + " 32-bit float");
      }
      HeightField f(g);
      std::copy(img.values.begin(), img.values.end(), f.data());
      f.model_to_grid = s.model_to_grid;
      out = std::move(f);
    });
    if (!load_layers) {
      if (!listed["depth"]) throw InputError(meta.string() + ": the scene lists no 'depth' layer");
    } else if (s.layers.depth.rows() == 0) {
      throw InputError(meta.string() + ": the scene lists no 'depth' layer");
    }
    if (const YAML::Node flags = root["flags"]; flags && load_layers) {
      const fs::path file = scene_dir / flags.as<std::string>();
      detail::Image8 img;
      const std::string why = detail::read_png(file, detail::PixelFormat::kGray, img);
      if (!why.empty() || img.converted || img.height != g.rows || img.width != g.cols) {
        throw InputError(file.string() + ": missing or malformed flags layer (expected an 8-bit grey " +
                         std::to_string(g.cols) + "x" + std::to_string(g.rows) + " PNG" + (why.empty() ? "" : "; " + why) + ")");
      }
      s.layers.flags = std::move(img.pixels);
    }
    if (const YAML::Node colour = root["colour"]; colour && load_layers && version == kTiledSceneFormatVersion) {
      const fs::path file = scene_dir / colour.as<std::string>();
      const std::string why = detail::read_tiled_layer(file, g, detail::TileSamples::kRgb8, [&] {
        s.layers.colour_rgb8.assign(3 * g.cell_count(), 0);  // only once the file is known to be g's size
        return static_cast<void*>(s.layers.colour_rgb8.data());
      });
      if (!why.empty()) {
        throw InputError(file.string() + ": missing or malformed colour layer (expected a tiled " + std::to_string(g.cols) +
                         "x" + std::to_string(g.rows) + " RGB TIFF; " + why + ")");
      }
    } else if (const YAML::Node colour_png = root["colour"]; colour_png && load_layers) {
      const fs::path file = scene_dir / colour_png.as<std::string>();
      detail::Image8 img;
      const std::string why = detail::read_png(file, detail::PixelFormat::kRgb, img);
      if (!why.empty() || img.height != g.rows || img.width != g.cols) {
        throw InputError(file.string() + ": missing or malformed colour layer (expected " + std::to_string(g.cols) +
                         "x" + std::to_string(g.rows) + " RGB" + (why.empty() ? "" : "; " + why) + ")");
      }
      s.layers.colour_rgb8 = std::move(img.pixels);
    }
    if (const YAML::Node fm = root["friction_model"]) s.friction_model = friction_model_from_string(fm.as<std::string>());
    s.provenance = parse_provenance(root["provenance"]);
    if (const YAML::Node rc = root["resolved_config"]) {
      YAML::Emitter e;
      e << rc;
      s.provenance.resolved_config_yaml = e.c_str();
    }
    if (version >= 2) {
      if (const YAML::Node lo = root["layer_options"]) s.layer_options = parse_layer_options(lo);
      if (const YAML::Node lod = root["lod"]) s.lod = parse_lod_options(lod);
    } else {
      s.notes.push_back(meta.string() +
                        ": format_version 1 records no typed layer_options or lod; defaults assumed for levels >= 1");
      if (s.friction_model) s.layer_options.friction_model = *s.friction_model;
      s.layer_options.friction_scale = FrictionScale::kScene;  // how format 1 made its μ_d
    }
  } catch (const YAML::Exception& e) {
    throw InputError(meta.string() + ": malformed scene metadata: " + e.what());
  } catch (const ConfigError& e) {
    throw InputError(meta.string() + ": malformed scene metadata: " + e.what());
  }
  s.loaded_from = scene_dir;
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

/// Staging folders of the StagingDirs alive in this process.
std::mutex g_live_mutex;
std::set<std::string> g_live_staging;
/// Scratch folders and files registered by their owners (register_live_scratch_dir).
std::set<std::string> g_live_scratch;
/// Folders whose entries with these name prefixes are scratch (register_live_scratch_entries).
std::map<std::string, std::vector<std::string>> g_live_entries;

/// Removes `<target>.partial-<pid>[-k]` and `<target>.old-<pid>[-k]` siblings whose process is
/// gone and that hold the output marker (so they are ours). Best effort; never throws.
void remove_stale_siblings(const fs::path& target) {
  std::error_code ec;
  const fs::path parent = target.has_parent_path() ? target.parent_path() : fs::path(".");
  const std::string stem = target.filename().string();
  for (fs::directory_iterator it(parent, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    for (const char* tag : {".partial-", ".old-"}) {
      const std::string prefix = stem + tag;
      if (name.rfind(prefix, 0) != 0) continue;
      const std::string rest = name.substr(prefix.size());
      const std::size_t digits = rest.find_first_not_of("0123456789");
      if (digits == 0 || rest.empty()) continue;
      const long pid = std::stol(rest.substr(0, digits));
      if (pid <= 0 || pid == static_cast<long>(::getpid())) continue;
      const bool gone = detail::process_gone(pid);
      std::error_code ec2;
      if (gone && fs::is_regular_file(it->path() / kOutputMarkerFile, ec2)) fs::remove_all(it->path(), ec2);
    }
  }
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

bool check_output_target(const fs::path& target_in, ExistingOutput existing) {
  fs::path target = target_in;
  if (target.filename().empty()) target = target.parent_path();
  std::error_code ec;
  const fs::file_status st = fs::symlink_status(target, ec);
  if (!fs::exists(st)) return false;
  const bool empty_dir = fs::is_directory(st) && fs::is_empty(target, ec) && !ec;
  const bool foreign = !empty_dir && !is_hapticloud_output(target);
  if (foreign && existing == ExistingOutput::kRefuse) {
    const std::string what =
        fs::is_directory(st) ? "a folder that is not an earlier hapticloud output" : "an existing file";
    throw InputError("output " + target.string() + " is " + what +
                     ": refusing to replace it; expected a new or empty folder, or an earlier output "
                     "(choose another --out, or pass --force to keep it as " + target.string() +
                     ".replaced-<time> and write the output there)");
  }
  return foreign;
}

StagingDir::StagingDir(fs::path target, ExistingOutput existing) : target_(std::move(target)) {
  if (target_.filename().empty()) target_ = target_.parent_path();
  std::error_code ec;
  target_is_foreign_ = check_output_target(target_, existing);
  remove_stale_siblings(target_);
  // A fresh staging name: nothing that happens to exist is ever removed.
  staging_ = free_sibling(target_, ".partial-" + std::to_string(::getpid()));
  {
    // Registered before it exists, so a signal watcher never misses a folder it could see.
    std::lock_guard<std::mutex> lock(g_live_mutex);
    g_live_staging.insert(staging_.string());
  }
  fs::create_directories(staging_, ec);
  if (ec) {
    std::lock_guard<std::mutex> lock(g_live_mutex);
    g_live_staging.erase(staging_.string());
    throw InputError(staging_.string() + ": cannot create the output folder: " + ec.message());
  }
  std::ofstream marker(staging_ / kOutputMarkerFile);
  marker << "This folder was written by hapticloud; a later run may replace it.\n";
  if (!marker) {
    fs::remove_all(staging_, ec);
    std::lock_guard<std::mutex> lock(g_live_mutex);
    g_live_staging.erase(staging_.string());
    throw InputError((staging_ / kOutputMarkerFile).string() + ": cannot write the output marker");
  }
}

namespace {
// A registered path as the registry keeps it: without a trailing separator ("work/" and "work"
// are one folder, and "work/" + ".removing" would name a folder inside it).
std::string live_key(const fs::path& path) {
  const fs::path p = path.filename().empty() && path.has_parent_path() ? path.parent_path() : path;
  return p.string();
}
}  // namespace

void register_live_scratch_dir(const fs::path& path) {
  std::lock_guard<std::mutex> lock(g_live_mutex);
  g_live_scratch.insert(live_key(path));
}

void unregister_live_scratch_dir(const fs::path& path) noexcept {
  try {
    std::lock_guard<std::mutex> lock(g_live_mutex);
    g_live_scratch.erase(live_key(path));
  } catch (...) {
  }
}

void register_live_scratch_entries(const fs::path& dir, const std::vector<std::string>& prefixes) {
  std::lock_guard<std::mutex> lock(g_live_mutex);
  g_live_entries[live_key(dir)] = prefixes;
}

void unregister_live_scratch_entries(const fs::path& dir) noexcept {
  try {
    std::lock_guard<std::mutex> lock(g_live_mutex);
    g_live_entries.erase(live_key(dir));
  } catch (...) {
  }
}

LiveScratchFile::LiveScratchFile(fs::path file) : file_(std::move(file)) { register_live_scratch_dir(file_); }

LiveScratchFile::~LiveScratchFile() {
  unregister_live_scratch_dir(file_);
  std::error_code ec;
  fs::remove(file_, ec);
}

std::FILE* open_live_scratch_file(const fs::path& file, const char* mode) {
  std::lock_guard<std::mutex> lock(g_live_mutex);
  return std::fopen(file.c_str(), mode);
}

void rename_live_scratch(const fs::path& from, const fs::path& to, std::error_code& ec) {
  std::lock_guard<std::mutex> lock(g_live_mutex);
  g_live_scratch.erase(live_key(from));
  fs::rename(from, to, ec);
}

int remove_live_staging_dirs(bool final) noexcept {
  int n = 0;
  std::unique_lock<std::mutex> lock(g_live_mutex);
  try {
    std::set<std::string> all = g_live_staging;
    all.insert(g_live_scratch.begin(), g_live_scratch.end());
    for (const std::string& dir : all) {
      // Another thread may still be writing into it: move it out of the way first (its next
      // file then fails to open), then remove it, retrying while files still appear in it.
      std::error_code ec;
      const fs::path trash = free_sibling(dir, ".removing-" + std::to_string(::getpid()));
      fs::rename(dir, trash, ec);
      const fs::path victim = ec ? fs::path(dir) : trash;
      for (int attempt = 0; attempt < 50; ++attempt) {
        fs::remove_all(victim, ec);
        if (!fs::exists(victim, ec)) break;
      }
      fs::remove_all(dir, ec);  // created anew in the meantime (the writers make only subfolders,
                                // never the staging folder itself, so this is a belt and braces)
      ++n;
    }
    // Registered entries of a folder that stays (the user's): those whose names start with a
    // registered prefix. Files are created and renamed under this lock (open_live_scratch_file,
    // rename_live_scratch), so none appears while it is held: one scan finds them all.
    for (const auto& [dir, prefixes] : g_live_entries) {
      std::vector<fs::path> ours;
      std::error_code ec;
      for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
        const std::string name = it->path().filename().string();
        if (std::any_of(prefixes.begin(), prefixes.end(), [&](const std::string& p) { return name.rfind(p, 0) == 0; })) {
          ours.push_back(it->path());
        }
      }
      for (const fs::path& e : ours) fs::remove_all(e, ec);
      ++n;
    }
    g_live_staging.clear();
    g_live_scratch.clear();
    g_live_entries.clear();
  } catch (...) {
  }
  if (final) (void)lock.release();  // held until _exit: nothing is created or moved after this
  return n;
}

StagingDir::~StagingDir() {
  {
    std::lock_guard<std::mutex> lock(g_live_mutex);
    g_live_staging.erase(staging_.string());
  }
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
  {
    std::lock_guard<std::mutex> lock(g_live_mutex);
    g_live_staging.erase(staging_.string());
  }
  if (old.empty()) return;
  if (target_is_foreign_) {
    moved_aside_ = old;  // the user's: kept
  } else {
    fs::remove_all(old, ec);  // an earlier output or an empty folder: ours to remove
  }
}

}  // namespace hc::pipeline
