// `hapticloud export SCENE --format ply|stl|obj --out FILE`: the scene's height field as a triangle
// mesh for mesh tools and 3-D printing (issue "Ecosystem"). See hc/pipeline/mesh_export.hpp.

#include "commands.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/mesh_export.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <CLI/CLI.hpp>

#include <filesystem>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>

namespace hc::app {

namespace {

struct ExportOptions {
  std::string scene;
  std::string format = "ply";
  std::string out;
  int level = 0;
};

void run_export(const ExportOptions& o) {
  const pipeline::MeshFormat format = pipeline::parse_mesh_format(o.format);
  Scene scene = pipeline::load_scene(o.scene);
  const Eigen::Vector3d d = scene.provenance.recentre_offset_m;
  pipeline::HeightMesh mesh;
  if (o.level == 0) {
    mesh = pipeline::triangulate_height_field(scene.layers.depth, scene.layers.colour_rgb8);
  } else {
    // Level L of the scene's pyramid (its own lod options): depth and colour only.
    const SurfaceLayerOptions layer_options = scene.layer_options;
    const LodOptions lod = scene.lod;
    const auto pyramid = pipeline::LodPyramid::from_scene(std::move(scene), layer_options, lod);
    if (o.level >= pyramid->level_count()) {
      throw ConfigError("export --level = " + std::to_string(o.level) + ": the scene has levels 0 to " +
                        std::to_string(pyramid->level_count() - 1));
    }
    const auto level = pyramid->depth_level(o.level);
    mesh = pipeline::triangulate_height_field(level->depth_m, level->colour_rgb8);
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
                "no data stays open; grid frame, metres)");
  cmd->add_option("SCENE", opts->scene, "Scene folder written by `hapticloud run`")->required();
  cmd->add_option("--format", opts->format,
                  "ply (binary, vertex colours when the scene has a colour layer), stl (binary), or obj (with FILE.mtl "
                  "and FILE.png: the colour layer as a texture)")
      ->capture_default_str();
  cmd->add_option("--out", opts->out, "Mesh file to write (refused if it exists)")->required();
  cmd->add_option("--level", opts->level, "Level of detail (0 = finest; each level halves the resolution, as in touch)")
      ->capture_default_str()
      ->check(CLI::Range(0, 30));
  cmd->callback([opts] { run_export(*opts); });
}

}  // namespace hc::app
