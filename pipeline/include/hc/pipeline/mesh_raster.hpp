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
/// Points on no triangle (stray vertices; an organised scan's isolated samples and the ends of
/// edges cut at depth jumps) are binned like points: their own z at their nearest node, by the
/// same front-most rule, so no input point lies in front of the grid unrendered.
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
///         cells, cells_valid, cells_measured, triangles, triangles_covering_a_node,
///         triangles_edge_on, triangles_non_finite, vertices_unreferenced,
///         vertices_binned_as_points.
/// @throws hc::ResourceError for 2^31 triangles or points or more;
///         hc::InputError if the cloud has no triangles, a triangle indexes a point that does
///         not exist, or attributes / UVs are misaligned; otherwise as reproject() for the
///         grid (hc::ConfigError for bad GridSpec, hc::DegenerateInputError, hc::ResourceError).
/// Real-time: no. Threads: 1. Cost: O(triangles + Σ nodes in each triangle's x-y box) + O(cells);
/// memory 21 bytes per cell while rasterising.
/// Source: depth-buffer scan of Sec. 1 of the paper; edge functions and the top-left fill rule
/// (Pineda, "A parallel algorithm for polygon rasterization", SIGGRAPH 1988); OBJ texture
/// coordinates: Wavefront OBJ format description (vt).
/// layer_blend_m (≥ 0, metres; 0 = off): each node's z becomes the mean over every face
/// covering it whose z lies within layer_blend_m of the front-most face (figure cells_blended):
/// for organised scans of several views, meshed per scan (mesh_organised_scans), whose
/// surfaces overlap; not for a single closed mesh (its thin parts would be averaged with their
/// back faces). Colour and intensity stay the front-most face's. hc::ConfigError if negative,
/// NaN or infinite. Cost: a second pass over the triangles.
StageResult<DepthGrid> rasterise_mesh(const Cloud& mesh_m, const ReprojectOptions& options, double layer_blend_m = 0.0);

}  // namespace hc::pipeline

namespace hc::pipeline {

/// Scan-aware reconstruction: meshes each organised scan on its own grid. Points carry their
/// scanner row/col (Cloud::row, col: Stanford range_grid PLYs, PTX, E57 with row/column
/// indices) and, for several scans, scan_id (points of one scan share it; none = one scan).
/// Per scan, each 2 × 2 block of neighbouring samples (r, c), (r, c+1), (r+1, c), (r+1, c+1)
/// becomes two triangles split along the shorter 3-D diagonal (one triangle when only three
/// samples exist); a triangle is kept only when none of its edges is longer than
/// max_edge_factor × the scan's median neighbour spacing (the 3-D distance between row- and
/// column-neighbours), so depth jumps (occlusion edges, silhouettes) stay open.
/// Frame and units: any (the grid frame in build_scene, after the filters; metres).
/// @return the same points with `mesh` set (replacing any); report figures: scans, triangles,
///         triangles_cut (over the limit), median_spacing_mm (median over the scans).
/// @throws hc::InputError if the cloud has no row/col, or they or scan_id are misaligned;
///         hc::ConfigError if max_edge_factor is not in [1, 100].
/// Real-time: no. Threads: 1. Cost: O(points + Σ scans' row × column extents).
/// Source: range-image triangulation with an edge-length test, as in "Zippered polygon meshes
/// from range images" (Turk & Levoy, SIGGRAPH 1994), Sec. 3 (their limit: a multiple of the
/// sample spacing).
StageResult<Cloud> mesh_organised_scans(Cloud points_m, double max_edge_factor);

/// Corrugation of a depth grid (rows of splats between scan lines show as a ribbed texture).
/// E_x, E_y: mean of the squared second difference of z along x (z[r][c−1] − 2 z[r][c] +
/// z[r][c+1]) and along y, over the node triples whose three nodes hold data that was not
/// hole-filled and whose two first differences are at most 2 cells in height (slopes ≤ 2: steps and
/// silhouettes excluded). The corrugation is max(E_x, E_y) [µm²]: the fine relief energy
/// across the ribbing, whichever grid axis the scan lines run along (on a smooth surface at
/// cells of a few tenths of a millimetre, the curvature's share is small: 1/R·h² ≈ 0.01 mm for
/// R = 20 mm, h = 0.5 mm, i.e. ~100 µm², against 10^4–10^5 µm² of splat terraces).
/// anisotropy = max / min − 1 [-], 0 when the fine relief is the same along x and y.
/// Figures: d2_energy_x_um2, d2_energy_y_um2, corrugation_um2 [µm²], triples_x, triples_y,
/// corrugation_anisotropy [-] (NaN when fewer than 100 triples in either direction).
/// @throws nothing for any grid (flags may be empty: every valid node counts).
/// Source: own definition (second differences as a discrete curvature; issue "A surface you
/// can trust").
StageResult<int> corrugation(const DepthGrid& grid);

}  // namespace hc::pipeline
