#pragma once
/// @file reproject.hpp
/// Stage 5: orthographic reprojection onto a regular grid (the depth-buffer scan of the paper),
/// see-through detection, and hole filling.

#include "hc/common/height_field.hpp"
#include "hc/pipeline/cloud.hpp"

#include <cstdint>
#include <vector>

namespace hc::pipeline {

/// How the grid is sized. Exactly one of n_long_side or cell_size_m is > 0.
struct GridSpec {
  int n_long_side = 0;       ///< cells along the longer side of the points' x-y extent, ≥ 2
  double cell_size_m = 0.0;  ///< or the spacing [m]
  std::size_t max_cells = 64u * 1024u * 1024u;  ///< memory cap on rows·cols
};

/// Orthographic depth scan options.
struct ReprojectOptions {
  GridSpec grid;
  /// Each point also writes, front-most rule again, the nodes within this radius [cells] of the
  /// node it falls on (a disc splat), so sparse scans leave no pinholes. Splats fill empty
  /// cells and, with see-through handling on, hide measured cells lying more than
  /// see_through_depth_m behind them; they never move a measured cell otherwise.
  /// 0 = only the cell containing the point.
  double splat_radius_cells = 0.0;
  /// See-through handling: a valid cell whose height lies more than this [m] below the
  /// robust front envelope of its neighbourhood is treated as a hole (a point seen through a
  /// gap in the front surface). ≤ 0 disables.
  double see_through_depth_m = 0.0;
  int see_through_window_cells = 3;  ///< half-width of that neighbourhood [cells]
};

/// Per-cell classification masks, rows·cols each, row-major like the HeightField.
enum CellFlag : std::uint8_t {
  kCellEmpty = 0,        ///< no point fell (no data)
  kCellMeasured = 1,     ///< front-most point of the cell
  kCellSplatted = 2,     ///< written by a neighbouring point's splat
  kCellSeeThrough = 3,   ///< rejected as see-through (now no data)
  kCellFilled = 4,       ///< filled by hole filling
};

struct DepthGrid {
  HeightField depth;                ///< heights [m], NaN = no data
  std::vector<std::uint8_t> flags;  ///< CellFlag per cell
};

/// Reprojects grid-frame points (metres; z towards the viewer) onto a grid covering their x-y
/// bounding box; the front-most (largest) z per cell wins.
/// @return depth grid plus flags; report figures: cells, valid cells, see-through cells.
/// @throws hc::InputError if there is no finite point; hc::DegenerateInputError if the x-y
///         extent is zero (a cloud edge-on to the view, all points in one cell);
///         hc::ConfigError if n_long_side ≤ 1 or the spec is ambiguous; hc::ResourceError if
///         rows·cols exceeds max_cells (the message gives both numbers and the bytes needed).
/// Real-time: no. Cost: two passes over the points + O(rows·cols) (·r² with a splat radius r).
/// Source: depth-buffer scan of Sec. 1 of the paper; front-most rule as in an OpenGL z-buffer.
StageResult<DepthGrid> reproject(const Cloud& points_m, const ReprojectOptions& options);

/// Fills holes (connected no-data regions, 4-connectivity) of at most max_hole_cells cells
/// that do not touch the grid border, by normalised convolution; larger holes and the
/// background stay no data. Filled cells get kCellFilled in `grid.flags`.
/// @param max_hole_cells  0 disables filling.
StageResult<DepthGrid> fill_holes(DepthGrid grid, int max_hole_cells);

}  // namespace hc::pipeline
