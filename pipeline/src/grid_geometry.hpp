#pragma once
// The grid geometry rule of reproject (reproject.cpp), shared with the mesh rasteriser
// (mesh_raster.cpp) so that a mesh and its vertices as points give the same grid.
// Internal to hc::pipeline (not installed).

#include "hc/common/height_field.hpp"
#include "hc/pipeline/cloud.hpp"
#include "hc/pipeline/reproject.hpp"

namespace hc::pipeline::detail {

/// The grid reproject(points_m, options) would scan into: it covers the x-y box of the finite
/// points (GridSpec rule, see reproject). @throws as reproject does for its options, a cloud
/// without a finite point, a degenerate box or a grid over max_cells.
GridGeometry grid_geometry_of(const Cloud& points_m, const ReprojectOptions& options);

}  // namespace hc::pipeline::detail
