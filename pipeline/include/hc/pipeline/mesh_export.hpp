#pragma once
/// Export of a scene's height field as a triangle mesh (issue "Ecosystem": PLY and OBJ for
/// viewers and mesh tools, STL in millimetres for slicers; the sheet is open, so a printable
/// tactile replica still needs a base added in a mesh tool).

#include "hc/common/height_field.hpp"

#include <span>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace hc::pipeline {

/// A triangle mesh of a height field, in the grid frame [m] (x, y of the nodes, z the height;
/// larger z nearer the viewer). Vertices are the valid nodes that are a corner of a valid cell,
/// in row-major order.
struct HeightMesh {
  std::vector<double> xyz_m;          ///< 3 per vertex
  std::vector<std::uint8_t> rgb8;     ///< 3 per vertex, or empty (no colour layer)
  std::vector<std::uint32_t> triangles;  ///< 3 vertex indices per triangle, counter-clockwise seen from +z
  /// With a colour layer: the texture image (texture_rows × texture_cols × 3 bytes, R G B, image
  /// row 0 at the top = the grid's last row, so it shows upright) and per vertex its (u, v)
  /// (2 per vertex; OBJ convention, v = 0 at the image's bottom) at the centre of its node's texel.
  std::vector<std::uint8_t> texture_rgb8;
  int texture_rows = 0, texture_cols = 0;
  std::vector<float> uv;
  std::size_t vertex_count() const { return xyz_m.size() / 3; }
  std::size_t triangle_count() const { return triangles.size() / 3; }
};

/// Two triangles per cell whose four corner nodes are valid (the cell (r, c) spans nodes
/// (r, c), (r, c + 1), (r + 1, c + 1), (r + 1, c); split along the diagonal (r, c)–(r + 1, c + 1)),
/// none elsewhere: no data stays open. Only nodes that are a corner of some triangle become
/// vertices (an isolated valid node would be a vertex without a face). `colour_rgb8` is the
/// scene's colour layer (rows·cols·3 bytes, row-major) or empty.
/// @throws std::invalid_argument when colour_rgb8 is neither empty nor rows·cols·3 bytes;
///         hc::ResourceError at 2^32 − 1 vertices or more.
HeightMesh triangulate_height_field(const HeightField& depth, std::span<const std::uint8_t> colour_rgb8);

/// Mesh file formats.
enum class MeshFormat {
  kPly,  ///< PLY 1.0 binary little-endian [m]: vertex float x y z [uchar red green blue], face list uchar uint
  /// binary STL in millimetres (slicers read STL as mm): 80-byte header, uint32 count, per
  /// triangle a float unit normal, 3 float vertices, uint16 0. An open sheet, not a closed solid.
  kStl,
  /// Wavefront OBJ (text, 1-based `v`, `vt`, `f a/a b/b c/c`); with a colour layer also FILE.mtl
  /// (material `colour`, map_Kd) and FILE.png (the texture), beside FILE with its stem.
  kObj,
};

/// Parses "ply", "stl" or "obj". @throws hc::ConfigError naming the value and the choices.
MeshFormat parse_mesh_format(const std::string& name);

/// Writes `mesh` to `file` (float32 coordinates in the grid frame: metres, STL millimetres; PLY
/// and OBJ also store `comments`, e.g. the recentring offset to add for the scan's frame).
/// Written to an exclusively created temporary file in the same folder and hard-linked into
/// place (link(2) never replaces a file, also one that appears meanwhile), so no half-written
/// file is left and nothing existing is overwritten.
/// Sources: PLY, Greg Turk, "The PLY Polygon File Format" (1994); STL, 3D Systems' StereoLithography
/// Interface Specification (1989), binary form; OBJ and MTL, Wavefront's Advanced Visualizer
/// manual, appendices B1 and B2. The OBJ's companions (.mtl, .png) are checked and written the
/// same way; the OBJ is renamed into place last.
/// @throws hc::InputError naming the file when it (or a companion) exists already (never
///         overwritten), --out is itself a companion's name, its folder is missing or the write
///         fails (the folder must allow hard links: a local file system); hc::ResourceError
///         beyond the formats' 32-bit counts; cv::Exception if the texture cannot be encoded.
///         Nothing is left behind on any failure.
void write_mesh(const HeightMesh& mesh, const std::filesystem::path& file, MeshFormat format,
                const std::vector<std::string>& comments = {});

}  // namespace hc::pipeline
