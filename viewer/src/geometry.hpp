#pragma once
/// @file geometry.hpp (private to hc::viewer)
/// CPU-side meshes: the height-field quad mesh, a sphere, an arrow. Vertices are interleaved
/// position (x, y, z) + normal (nx, ny, nz) floats.

#include "hc/common/height_field.hpp"

#include <cstdint>
#include <vector>

namespace hc::viewer {

struct MeshData {
  std::vector<float> vertices;        ///< 6 floats per vertex
  std::vector<float> colours;         ///< 3 floats per vertex (linear RGB [0, 1]), or empty
  std::vector<std::uint32_t> indices; ///< triangles
  std::size_t quads = 0;              ///< quads emitted (height-field meshes)
};

/// One vertex per sample taken every `stride` samples (stride ≥ 1 chosen so that neither side
/// exceeds max_side vertices; the last row and column are always included), two triangles per
/// quad whose four corners hold data, so neighbouring quads share edges and the mesh has no
/// gaps. Normals from central differences of the heights (one-sided at borders and next to
/// no-data). Positions in the grid frame [m]. `sample_rgb`, when given, holds rows·cols·3
/// floats (R G B in [0, 1] per sample, row-major); each vertex then takes its sample's colour
/// (MeshData::colours). A size other than rows·cols·3 is ignored (no colours).
MeshData height_field_mesh(const HeightField& field, int max_side, const std::vector<float>* sample_rgb = nullptr);

/// Unit sphere (radius 1) about the origin.
MeshData sphere_mesh(int slices, int stacks);

/// Arrow of length 1 along +z from the origin: a shaft of radius 0.03 up to 0.75, a cone of
/// base radius 0.08 from 0.75 to 1.
MeshData arrow_mesh(int slices);

}  // namespace hc::viewer
