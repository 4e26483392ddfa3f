#pragma once
/// @file mesh_raster.hpp
/// Stage 5 for meshes: the triangles of a Cloud's Mesh rasterised into the Monge grid with a
/// z-buffer (the depth-buffer scan of the paper, on the mesh itself rather than its vertices).

#include "hc/pipeline/cloud.hpp"
#include "hc/pipeline/reproject.hpp"

namespace hc::pipeline {

/// Rasterises the triangles of `mesh_m.mesh` (grid frame, metres, z towards the viewer) onto
/// the grid reproject() would make from the same points: it covers the x-y box of ALL finite
/// vertices (faces or not), with options.grid's N or cell size (GridSpec rule, node-centred).
/// Per node, the front-most (largest) z over every triangle covering the node's (x, y), by
/// barycentric interpolation of its corners' z in double (stored as float). No back-face
/// culling: a mesh seen from behind shows its back faces, like the points path.
/// Inside test: edge functions evaluated in double with each edge's endpoints taken in a fixed
/// (x, then y) order, so two triangles sharing an edge (same coordinates, whatever the vertex
/// indices) compute bitwise-opposite values; a node exactly on an edge belongs to the triangle
/// on the side of (+ε, +ε²) (a top-left rule), so a node on a shared edge or vertex is covered
/// exactly once and a closed or watertight surface leaves no pinholes. Triangles of zero x-y
/// area (seen edge-on) or with a non-finite corner cover nothing (counted).
/// Attributes, each only when present: colour from the texture (Mesh::has_texture: UV
/// interpolated barycentrically, the image sampled bilinearly at texel centres, x = u·W − ½,
/// y = (1 − v)·H − ½ (OBJ's v points up; row 0 is the image's top), coordinates outside [0, 1]
/// wrap (repeat)), else from per-vertex rgb interpolated barycentrically; intensity likewise
/// from per-vertex intensity. Rounded to 8 bit.
/// Flags: covered nodes kCellMeasured (a height on a face of the mesh), the others kCellEmpty
/// (no data, NaN). splat_radius_cells, see_through_depth_m and upsample_factor do not apply
/// (a z-buffer over faces has no gaps to splat and sees nothing through a surface); when set
/// they are ignored with a note. Hole filling (fill_holes) applies afterwards as for points.
/// @return depth grid + flags (+ colour / intensity); report figures: rows, cols, cell_size_mm,
///         cells, cells_valid, cells_measured, triangles, triangles_rasterised,
///         triangles_edge_on, triangles_non_finite, vertices_unreferenced.
/// @throws hc::InputError if the cloud has no triangles, a triangle indexes a point that does
///         not exist, or attributes / UVs are misaligned; otherwise as reproject() for the
///         grid (hc::ConfigError for bad GridSpec, hc::DegenerateInputError, hc::ResourceError).
/// Real-time: no. Threads: 1. Cost: O(triangles + Σ nodes in each triangle's x-y box) + O(cells);
/// memory 21 bytes per cell while rasterising.
/// Source: depth-buffer scan of Sec. 1 of the paper; edge functions and the top-left fill rule
/// (Pineda, "A parallel algorithm for polygon rasterization", SIGGRAPH 1988); OBJ texture
/// coordinates: Wavefront OBJ format description (vt).
StageResult<DepthGrid> rasterise_mesh(const Cloud& mesh_m, const ReprojectOptions& options);

}  // namespace hc::pipeline
