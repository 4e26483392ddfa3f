// `hapticloud export SCENE --format ply|stl|obj|geotiff --out FILE [--level L] [--window X0 Y0 X1 Y1]
// [--layer NAME]`: the scene's height field as a triangle mesh for mesh tools and 3-D printing,
// or one layer as a GeoTIFF for GIS tools (issue "Ecosystem"). See hc/pipeline/mesh_export.hpp and raster_export.hpp.

#include "commands.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/mesh_export.hpp"
#include "hc/pipeline/raster_export.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <span>
#include <CLI/CLI.hpp>

#include <filesystem>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

namespace hc::app {

namespace {

struct ExportOptions {
  std::string scene;
  std::string format = "ply";
  std::string out;
  int level = 0;
  std::string layer = "depth";
  std::vector<double> window;  ///< X0 Y0 X1 Y1 [m], grid frame, or empty (the whole grid)
};

// The nodes of `g` inside o.window (all of them without --window).
pipeline::SampleWindow window_of(const ExportOptions& o, const GridGeometry& g) {
  if (o.window.empty()) return {0, 0, g.rows, g.cols};
  return pipeline::window_of_extent(g, o.window[0], o.window[1], o.window[2], o.window[3]);
}

// The layers a GeoTIFF can hold, with their units; `height`: z in the grid frame.
struct RasterLayer {
  const char* name;
  const char* units;
  bool height;
};
constexpr RasterLayer kRasterLayers[] = {
    {"depth", "m", true},   {"envelope", "m", true},    {"texture", "m", false},   {"mu_d", "1", false},
    {"mu_s", "1", false},   {"cell_error", "m", false}, {"intensity", "as stored by the scanner", false},
    {"region_id", "1", false}};

// The scene's level-of-detail pyramid (its own layer and lod options), with `level` in range.
// @throws hc::ConfigError naming --level and the scene's level range.
std::shared_ptr<pipeline::LodPyramid> pyramid_for_level(Scene&& scene, int level) {
  const SurfaceLayerOptions layer_options = scene.layer_options;
  const LodOptions lod = scene.lod;
  auto pyramid = pipeline::LodPyramid::from_scene(std::move(scene), layer_options, lod);
  if (level >= pyramid->level_count()) {
    throw ConfigError("export --level = " + std::to_string(level) + ": the scene has levels 0 to " +
                      std::to_string(pyramid->level_count() - 1));
  }
  return pyramid;
}

// The layer `name` of `scene` at `level` (0: the scene's own; above: the pyramid's level, which
// holds depth, envelope, texture, μ_d and μ_s). @throws hc::ConfigError naming the layer.
HeightField raster_of(Scene scene, const std::string& name, int level) {
  if (level == 0) {
    SceneLayers& l = scene.layers;
    HeightField* f = name == "depth"        ? &l.depth
                     : name == "envelope"   ? &l.envelope
                     : name == "texture"    ? &l.texture
                     : name == "mu_d"       ? &l.mu_d
                     : name == "mu_s"       ? &l.mu_s
                     : name == "cell_error" ? &l.cell_error
                     : name == "intensity"  ? &l.intensity
                                            : &l.region_id;
    if (f->rows() == 0) throw ConfigError("export --layer = " + name + ": the scene has no such layer");
    return std::move(*f);
  }
  if (name != "depth" && name != "envelope" && name != "texture" && name != "mu_d" && name != "mu_s") {
    throw ConfigError("export --layer = " + name + " with --level " + std::to_string(level) +
                      ": levels above 0 hold depth, envelope, texture, mu_d and mu_s");
  }
  const bool has_layers = scene.layers.has_surface_layers();
  const auto pyramid = pyramid_for_level(std::move(scene), level);
  if (name == "depth") return pyramid->depth_level(level)->depth_m;
  if (!has_layers) throw ConfigError("export --layer = " + name + ": the scene has no surface layers");
  const auto l = pyramid->level(level);
  return name == "envelope" ? l->envelope_m : name == "texture" ? l->texture_m : name == "mu_d" ? l->mu_d : l->mu_s;
}

void run_raster_export(const ExportOptions& o) {
  const RasterLayer* layer = nullptr;
  for (const RasterLayer& l : kRasterLayers)
    if (o.layer == l.name) layer = &l;
  if (!layer) {
    std::string names;
    for (const RasterLayer& l : kRasterLayers) names += std::string(names.empty() ? "" : ", ") + l.name;
    throw ConfigError("export --layer = '" + o.layer + "': expected one of: " + names);
  }
  Scene scene = pipeline::load_scene(o.scene);
  const Eigen::Affine3d model_to_grid = scene.model_to_grid;
  const std::string crs = scene.provenance.crs;
  const std::string file_units = scene.provenance.units.empty() ? std::string("file units") : scene.provenance.units;
  HeightField field = raster_of(std::move(scene), o.layer, o.level);
  if (!o.window.empty()) {
    const pipeline::SampleWindow w = window_of(o, field.geometry());
    field = pipeline::crop_height_field(field, w.row0, w.col0, w.rows, w.cols);
  }
  const pipeline::GeoTiffLayout layout = pipeline::geotiff_layout(field.geometry(), model_to_grid, layer->height);
  const std::string frame = layout.file_frame ? "the scan's file frame and units" : "the grid frame, metres";
  const std::vector<std::string> notes = pipeline::write_geotiff(
      field, layout, crs, o.out,
      {"HAPTICLOUD_LAYER=" + o.layer, "HAPTICLOUD_LEVEL=" + std::to_string(o.level),
       "HAPTICLOUD_UNITS=" + (layer->height && layout.file_frame ? file_units : std::string(layer->units)),
       "HAPTICLOUD_FRAME=" + frame, "HAPTICLOUD_SCENE=" + o.scene});
  std::cout << "export: layer " << o.layer << " (level " << o.level << "), " << field.rows() << " x " << field.cols()
            << " pixels, " << frame << (crs.empty() || !layout.file_frame ? "" : ", with the scan's CRS") << " -> "
            << o.out << "\n";
  for (const std::string& n : notes) std::cout << "export: note: " << n << "\n";
  std::cout << "export: GeoTIFF written through " << pipeline::geotiff_module_path() << "\n";
}

void run_export(const ExportOptions& o) {
  if (o.format != "ply" && o.format != "stl" && o.format != "obj" && o.format != "geotiff") {
    throw ConfigError("export --format = '" + o.format + "': expected one of: ply, stl, obj, geotiff");
  }
  if (o.format == "geotiff") {
    run_raster_export(o);
    return;
  }
  if (o.layer != "depth") throw ConfigError("export --layer is for --format geotiff; a mesh is made of the depth layer");
  const pipeline::MeshFormat format = pipeline::parse_mesh_format(o.format);
  Scene scene = pipeline::load_scene(o.scene);
  const Eigen::Vector3d d = scene.provenance.recentre_offset_m;
  // The depth and colour of the level, cropped to --window.
  auto triangulate = [&o](const HeightField& depth, std::span<const std::uint8_t> colour) {
    if (o.window.empty()) return pipeline::triangulate_height_field(depth, colour);
    const pipeline::SampleWindow w = window_of(o, depth.geometry());
    const std::vector<std::uint8_t> cropped =
        colour.empty() ? std::vector<std::uint8_t>() : pipeline::crop_colour(colour, depth.geometry(), w.row0, w.col0, w.rows, w.cols);
    return pipeline::triangulate_height_field(pipeline::crop_height_field(depth, w.row0, w.col0, w.rows, w.cols), cropped);
  };
  pipeline::HeightMesh mesh;
  if (o.level == 0) {
    mesh = triangulate(scene.layers.depth, scene.layers.colour_rgb8);
  } else {
    // Level L of the scene's pyramid: depth and colour only.
    const auto level = pyramid_for_level(std::move(scene), o.level)->depth_level(o.level);
    mesh = triangulate(level->depth_m, level->colour_rgb8);
  }
  std::ostringstream offset;
  offset.precision(17);
  offset << "recentre_offset_m " << d.x() << " " << d.y() << " " << d.z()
         << " (file frame; the vertices are in the grid frame, see the scene's scene.yaml)";
  pipeline::write_mesh(mesh, o.out, format, {offset.str()});
  std::cout << "export: " << mesh.vertex_count() << " vertices, " << mesh.triangle_count() << " triangles"
            << (mesh.rgb8.empty() || format == pipeline::MeshFormat::kStl ? ""
                : format == pipeline::MeshFormat::kPly                   ? ", vertex colours"
                                                                         : ", texture")
            << " -> " << o.out << "\n";
}

}  // namespace

void add_export_command(CLI::App& app) {
  auto opts = std::make_shared<ExportOptions>();
  CLI::App* cmd = app.add_subcommand(
      "export", "Write a scene's height field as a triangle mesh (two triangles per cell with four valid corners; "
                "no data stays open; grid frame, metres), or one layer as a GeoTIFF (upright; in the scan's frame "
                "and CRS when the view looks straight down on it)");
  cmd->add_option("SCENE", opts->scene, "Scene folder written by `hapticloud run`")->required();
  cmd->add_option("--format", opts->format,
                  "ply (binary, vertex colours when the scene has a colour layer), stl (binary), obj (with FILE.mtl "
                  "and FILE.png: the colour layer as a texture), or geotiff (float32, one layer, NaN no-data)")
      ->capture_default_str();
  cmd->add_option("--out", opts->out, "File to write (refused if it exists)")->required();
  cmd->add_option("--window", opts->window,
                  "X0 Y0 X1 Y1: only the nodes with X0 <= x <= X1 and Y0 <= y <= Y1 [m, grid frame: the frame of "
                  "filters.crop and of explore's centre command]")
      ->expected(4);
  cmd->add_option("--layer", opts->layer,
                  "geotiff only: depth, envelope, texture, mu_d, mu_s, cell_error, intensity or region_id")
      ->capture_default_str();
  cmd->add_option("--level", opts->level, "Level of detail (0 = finest; each level halves the resolution, as in touch)")
      ->capture_default_str()
      ->check(CLI::Range(0, 30));
  cmd->callback([opts] { run_export(*opts); });
}

}  // namespace hc::app
