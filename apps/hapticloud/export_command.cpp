// `hapticloud export SCENE --format ply|stl|obj --out FILE`: the scene's height field as a triangle
// mesh for mesh tools and 3-D printing (issue "Ecosystem"). See hc/pipeline/mesh_export.hpp.

#include "commands.hpp"

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
};

void run_export(const ExportOptions& o) {
  const pipeline::MeshFormat format = pipeline::parse_mesh_format(o.format);
  const Scene scene = pipeline::load_scene(o.scene);
  const pipeline::HeightMesh mesh = pipeline::triangulate_height_field(scene.layers.depth, scene.layers.colour_rgb8);
  std::ostringstream offset;
  offset.precision(17);
  const Eigen::Vector3d& d = scene.provenance.recentre_offset_m;
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
  cmd->callback([opts] { run_export(*opts); });
}

}  // namespace hc::app
