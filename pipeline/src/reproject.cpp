// Stage 5: orthographic depth scan onto a node-centred grid, with optional disc, interpolating
// or plane splats and see-through detection. Hole filling lives in hole_fill.cpp.
//
// Design (the why, in one place):
//  * Geometry. The grid covers the x-y bounding box of the finite points. With N given, the
//    longer side holds N samples, so cell = extent_long / (N − 1); the shorter side gets
//    round(extent_short / cell) + 1 samples, centred on the box. With a cell size given, both
//    sides are computed that way. Each point goes to its nearest node (ties to the higher index),
//    so a "cell" is the cell-sized square centred on its node.
//  * Threads. For clouds of 2^18 points or more, the two passes over the points (bounds, then
//    binning) each run on two threads (std::thread), each on half of the points; the second
//    thread bins into its own grid, merged by the front-most rule (one pass over the cells).
//  * Front-most rule. A depth buffer: the largest z (nearest to the viewer, who looks along −z)
//    per cell wins. Heights are kept as float with −inf for "nothing yet" during the scan, so the
//    inner loop is one compare and one store per point; −inf becomes NaN (no data) at the end.
//  * Splats. A point also writes every node within splat_radius_cells of its exact (x, y) into a
//    second, "splat" buffer (front-most rule again). Splat heights only fill cells where no point
//    fell, and act as occluders in the see-through test: they never overwrite a measured cell
//    that agrees with them, so splatting does not bias measured heights on slopes.
//  * See-through. A point cloud is not a closed surface: where the front surface of an object has
//    a gap at this resolution, the front-most point of a cell can be a point on the back of the
//    object. Such a cell is "enclosed" by a front surface that lies far above it on opposite
//    sides. A cell with height z is declared see-through when, for at least kMinBracketingPairs of
//    the 4 line directions through it (row, column, two diagonals), BOTH opposite rays within
//    see_through_window_cells hold a cell higher than z + see_through_depth_m. The two-sided test
//    is what separates a gap from a legitimate drop: at a silhouette or the wall of a step the
//    higher surface is on one side only, so these cells are kept; a single outlier spike above
//    the surface cannot bracket anything on its own. With splats on, a measured cell that lies
//    more than see_through_depth_m below the splat of a neighbour's point is occluded by that
//    disc: the disc's height replaces it (flag kCellSplatted), which closes gaps narrower than
//    the splat radius before the ray test runs.
//    Interpolating splats (SplatMode::kInterpolate) fill EMPTY cells with the Gaussian-weighted
//    mean of the measured cells within the radius (normalised convolution). The same occlusion
//    step runs first: a measured cell more than see_through_depth_m below the front-most
//    measured z within the radius is emptied and then interpolated from the front surface
//    (without it a merged 15-view Buddha lost 18 451 cells as see-through, against 958 with
//    discs: back-surface samples were averaged into the front). The see-through test runs after
//    either kind of splat, on the filled grid: splatted cells bracket back-surface cells seen
//    through a gap just as measured front cells do, and splatted cells that are themselves
//    bracketed (an interpolated value pulled down by a back-surface point) are rejected too.
//    Plane splats (SplatMode::kPlane) replace the front-most rule itself: each node takes the
//    weighted least-squares plane through the front-surface points within the radius (see
//    splat_planes), which averages a merged scan's views instead of letting the front-most
//    sample of each cell decide (the ribbing of overlapping views at the cell scale).
//    Candidate cells are pre-selected with a separable (2w+1)² max filter (a cell can only be
//    bracketed if something in its window is higher than z + depth), so the ray test runs on a
//    small fraction of the grid.
//  * Upsampling. Cells finer than the point spacing hold a point only here and there; splats
//    then fill the rest with flat discs (terraces with one-cell risers, which hold a point proxy)
//    and the see-through test meets gaps wider than its window. With upsample_factor K the scan
//    runs on every K-th node (K× the cell) and bilinear interpolation fills the nodes between:
//    the surface is then exactly the coarse scan's bilinear surface, no detail is invented.
//    Auto picks the smallest K at which 90 % of the hit nodes have 4 hit neighbours (a scan
//    hitting each node with probability p has that fraction ≈ p⁴, so 0.9 means p ≈ 0.97).
//    Known limits: a genuine crease narrower than the window and deeper than the depth threshold
//    on both sides is indistinguishable from a gap and is dropped (it becomes a small hole that
//    hole filling may close); a gap wider than the window is not found.

#include "stage_util.hpp"
#include "hc/pipeline/reproject.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <exception>
#include <functional>
#include <limits>
#include <memory>
#include <sstream>
#include <thread>
#include <vector>

namespace hc::pipeline {

namespace {

using detail::run_two;

constexpr float kEmpty = -std::numeric_limits<float>::infinity();
// Plane splats (splat_planes): when a slope is fitted along a direction, and the moments per node.
constexpr double kPlaneMinVariance = 1e-6;  // [cells²] below this a direction has no spread (float moments)
constexpr double kPlaneMaxLeverage = 3.0;   // [standard deviations]
// Σw, Σw·dx, Σw·dy, Σw·dx², Σw·dx·dy, Σw·dy², Σw·z, Σw·dx·z, Σw·dy·z.
constexpr int kPlaneMoments = 9;
constexpr int kMinBracketingPairs = 2;
constexpr std::size_t kTwoThreadPoints = 1u << 18;  ///< clouds this large use two threads

struct Bounds {
  double x_min = std::numeric_limits<double>::infinity();
  double x_max = -std::numeric_limits<double>::infinity();
  double y_min = std::numeric_limits<double>::infinity();
  double y_max = -std::numeric_limits<double>::infinity();
  std::size_t finite = 0;
};

bool finite_point(const double* p) {
  return std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
}

// One pass over the points: x-y bounds of the finite points and their count.
// Fast path: plain min/max in two interleaved chains plus a finiteness sum (x·0 + y·0 + z·0 is
// 0 for a finite point and NaN otherwise); only a cloud with a non-finite point takes the
// careful per-point path.
Bounds finite_bounds(const double* p, std::size_t n) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  double x_lo[2] = {kInf, kInf}, x_hi[2] = {-kInf, -kInf}, y_lo[2] = {kInf, kInf}, y_hi[2] = {-kInf, -kInf};
  double zero[2] = {0.0, 0.0};
  std::size_t i = 0;
  for (; i + 1 < n; i += 2) {
    for (int k = 0; k < 2; ++k) {
      const double* q = p + 3 * (i + static_cast<std::size_t>(k));
      x_lo[k] = std::min(x_lo[k], q[0]);
      x_hi[k] = std::max(x_hi[k], q[0]);
      y_lo[k] = std::min(y_lo[k], q[1]);
      y_hi[k] = std::max(y_hi[k], q[1]);
      zero[k] += q[0] * 0.0 + q[1] * 0.0 + q[2] * 0.0;
    }
  }
  for (; i < n; ++i) {
    const double* q = p + 3 * i;
    x_lo[0] = std::min(x_lo[0], q[0]);
    x_hi[0] = std::max(x_hi[0], q[0]);
    y_lo[0] = std::min(y_lo[0], q[1]);
    y_hi[0] = std::max(y_hi[0], q[1]);
    zero[0] += q[0] * 0.0 + q[1] * 0.0 + q[2] * 0.0;
  }
  Bounds b;
  if (zero[0] + zero[1] == 0.0) {  // every point finite
    b.x_min = std::min(x_lo[0], x_lo[1]);
    b.x_max = std::max(x_hi[0], x_hi[1]);
    b.y_min = std::min(y_lo[0], y_lo[1]);
    b.y_max = std::max(y_hi[0], y_hi[1]);
    b.finite = n;
    return b;
  }
  for (i = 0; i < n; ++i, p += 3) {
    if (!finite_point(p)) continue;
    b.x_min = std::min(b.x_min, p[0]);
    b.x_max = std::max(b.x_max, p[0]);
    b.y_min = std::min(b.y_min, p[1]);
    b.y_max = std::max(b.y_max, p[1]);
    ++b.finite;
  }
  return b;
}

Bounds merge(const Bounds& a, const Bounds& b) {
  Bounds m;
  m.x_min = std::min(a.x_min, b.x_min);
  m.x_max = std::max(a.x_max, b.x_max);
  m.y_min = std::min(a.y_min, b.y_min);
  m.y_max = std::max(a.y_max, b.y_max);
  m.finite = a.finite + b.finite;
  return m;
}

void validate_options(const ReprojectOptions& o) {
  const GridSpec& g = o.grid;
  std::ostringstream msg;
  if (o.window) {
    const GridWindow& w = *o.window;
    const int k = o.upsample_factor;
    if (k < 1 || k > kMaxUpsampleFactor || w.rows < 2 || w.cols < 2 || w.row0 < 0 || w.col0 < 0 ||
        w.row0 + w.rows > w.grid.rows || w.col0 + w.cols > w.grid.cols || w.row0 % k != 0 || w.col0 % k != 0 ||
        !(w.grid.cell_size_m > 0.0)) {
      msg << "reproject: window rows " << w.row0 << " + " << w.rows << ", cols " << w.col0 << " + " << w.cols
          << " of a " << w.grid.rows << " x " << w.grid.cols << " grid with upsample_factor " << k
          << " (expected a window of at least 2 x 2 nodes inside the grid, starting on a multiple of a given "
             "upsample factor 1 to "
          << kMaxUpsampleFactor << ")";
      throw ConfigError(msg.str());
    }
  }
  if (g.n_long_side != 0 && g.cell_size_m != 0.0) {
    msg << "reproject: grid is ambiguous: n_long_side = " << g.n_long_side
        << " and cell_size_m = " << g.cell_size_m << " are both set (give exactly one)";
    throw ConfigError(msg.str());
  }
  if (g.n_long_side == 0 && g.cell_size_m == 0.0) {
    throw ConfigError("reproject: grid is unspecified: give n_long_side (>= 2) or cell_size_m (> 0)");
  }
  if (g.cell_size_m == 0.0 && g.n_long_side <= 1) {
    msg << "reproject: n_long_side = " << g.n_long_side << " (expected >= 2 samples along the longer side)";
    throw ConfigError(msg.str());
  }
  if (g.n_long_side == 0 && !(g.cell_size_m > 0.0 && std::isfinite(g.cell_size_m))) {
    msg << "reproject: cell_size_m = " << g.cell_size_m << " (expected a finite value > 0)";
    throw ConfigError(msg.str());
  }
  if (o.splat_mode != SplatMode::kDisc && o.splat_mode != SplatMode::kInterpolate && o.splat_mode != SplatMode::kPlane) {
    msg << "reproject: splat_mode = " << static_cast<int>(o.splat_mode) << " (expected kDisc, kInterpolate or kPlane)";
    throw ConfigError(msg.str());
  }
  if (!(o.splat_radius_cells >= 0.0) || o.splat_radius_cells > 64.0) {
    msg << "reproject: splat_radius_cells = " << o.splat_radius_cells << " (expected 0 to 64)";
    throw ConfigError(msg.str());
  }
  if (std::isnan(o.see_through_depth_m)) {
    throw ConfigError("reproject: see_through_depth_m is NaN (expected a depth in metres, <= 0 disables)");
  }
  if (o.upsample_factor < 0 || o.upsample_factor > kMaxUpsampleFactor) {
    msg << "reproject: upsample_factor = " << o.upsample_factor << " (expected 0 = auto, or 1 to "
        << kMaxUpsampleFactor << ")";
    throw ConfigError(msg.str());
  }
  if (o.see_through_depth_m > 0.0 && (o.see_through_window_cells < 1 || o.see_through_window_cells > 64)) {
    msg << "reproject: see_through_window_cells = " << o.see_through_window_cells << " (expected 1 to 64)";
    throw ConfigError(msg.str());
  }
}

std::size_t bytes_per_cell(const ReprojectOptions& o) {
  std::size_t b = sizeof(float) + sizeof(std::uint8_t);  // height + flag
  if (o.splat_radius_cells > 0.0 && o.splat_mode == SplatMode::kInterpolate) {
    b += 2 * sizeof(float) + sizeof(std::uint32_t);  // z·mask, mask, summed-area table
    if (o.see_through_depth_m > 0.0) b += sizeof(float) * (1 + static_cast<std::size_t>(std::floor(o.splat_radius_cells)));  // occlusion discs
  } else if (o.splat_radius_cells > 0.0 && o.splat_mode == SplatMode::kPlane) {
    b += sizeof(float) * (static_cast<std::size_t>(kPlaneMoments) + 2 +
                          static_cast<std::size_t>(std::floor(o.splat_radius_cells + 0.7072)));  // moments, ref, discs
  } else if (o.splat_radius_cells > 0.0) {  // splat buffer + running maxima of half-width 1..⌊r⌋
    b += sizeof(float) * (1 + static_cast<std::size_t>(std::floor(o.splat_radius_cells)));
  }
  if (o.see_through_depth_m > 0.0) b += 2 * sizeof(float);  // window max (two passes)
  return b;
}

GridGeometry make_geometry(const Bounds& b, const ReprojectOptions& o) {
  const double ext_x = b.x_max - b.x_min;
  const double ext_y = b.y_max - b.y_min;
  const double ext_long = std::max(ext_x, ext_y);
  std::ostringstream msg;
  if (!(ext_long > 0.0)) {
    msg << "reproject: all " << b.finite << " finite points share one x-y position (" << b.x_min
        << ", " << b.y_min << ") m: zero projected area (a single point, or a cloud seen edge-on "
        << "along the view direction -z)";
    throw DegenerateInputError(msg.str());
  }
  const double cell = o.grid.n_long_side > 0 ? ext_long / (o.grid.n_long_side - 1) : o.grid.cell_size_m;
  const double cols_d = std::round(ext_x / cell) + 1.0;
  const double rows_d = std::round(ext_y / cell) + 1.0;
  if (cols_d < 2.0 || rows_d < 2.0) {
    msg << "reproject: the points' x-y extent " << ext_x << " m x " << ext_y << " m gives a grid of "
        << cols_d << " x " << rows_d << " samples (cols x rows) at cell size " << cell << " m: ";
    if (cols_d < 2.0 && rows_d < 2.0) {
      msg << "all points fall in one cell";
    } else {
      msg << "the points lie on a line along " << (cols_d < 2.0 ? "y" : "x")
          << " (zero projected area: a cloud edge-on to the view direction -z?)";
    }
    msg << "; a grid needs at least 2 x 2 samples";
    throw DegenerateInputError(msg.str());
  }
  const double cells = cols_d * rows_d;
  if (cells > static_cast<double>(o.grid.max_cells) || cols_d > 2.0e9 || rows_d > 2.0e9) {
    const double bytes = cells * static_cast<double>(bytes_per_cell(o));
    msg.precision(17);
    msg << "reproject: a grid of " << cols_d << " x " << rows_d << " = " << cells
        << " cells (cell size " << cell << " m) exceeds max_cells = " << o.grid.max_cells
        << "; it would need ";
    if (bytes < 9.0e18) {
      msg << static_cast<std::uint64_t>(bytes);
    } else {
      msg << bytes;
    }
    msg << " bytes (" << bytes_per_cell(o) << " bytes per cell); raise the cap or coarsen the grid";
    throw ResourceError(msg.str());
  }
  GridGeometry g;
  g.cols = static_cast<int>(cols_d);
  g.rows = static_cast<int>(rows_d);
  g.cell_size_m = cell;
  g.x0_m = 0.5 * (b.x_min + b.x_max) - 0.5 * (g.cols - 1) * cell;
  g.y0_m = 0.5 * (b.y_min + b.y_max) - 0.5 * (g.rows - 1) * cell;
  return g;
}

// A window of a larger grid (ReprojectOptions::window): the geometry passed around keeps the
// whole grid's origin, and node indices are computed exactly as on the whole grid, then
// shifted by the window's first row and column (integers: exact), so a window's nodes get the
// values the whole grid's get. Points whose node falls outside the window are skipped.
struct NodeOffset {
  int r = 0, c = 0;
  bool window = false;
};

// Front-most z per cell over every finite point; returns the number of points binned.
// Every finite point lies inside the bounding box the geometry was made from, so its fractional
// index plus one half is in [0.25, n − 0.25): truncation is the nearest node (ties to the higher
// index). One unsigned min per axis guards against rounding (a negative index would wrap to a
// large unsigned value and be clamped too).
std::size_t bin_front_most(const double* p, std::size_t n, const GridGeometry& g, bool all_finite,
                           float* depth, const NodeOffset& off = {}) {
  const double inv = 1.0 / g.cell_size_m;
  const double cx = 0.5 - g.x0_m * inv, cy = 0.5 - g.y0_m * inv;
  const std::size_t cols = static_cast<std::size_t>(g.cols);
  const auto c_max = static_cast<unsigned>(g.cols - 1), r_max = static_cast<unsigned>(g.rows - 1);
  if (off.window) {
    std::size_t binned = 0;
    for (std::size_t i = 0; i < n; ++i, p += 3) {
      if (!all_finite && !finite_point(p)) continue;
      const auto c = static_cast<unsigned>(static_cast<int>(p[0] * inv + cx) - off.c);
      const auto r = static_cast<unsigned>(static_cast<int>(p[1] * inv + cy) - off.r);
      if (c > c_max || r > r_max) continue;
      float& cell = depth[static_cast<std::size_t>(r) * cols + c];
      cell = std::max(cell, static_cast<float>(p[2]));
      ++binned;
    }
    return binned;
  }
  auto bin = [&](const double* q) {
    const unsigned c = std::min(static_cast<unsigned>(static_cast<int>(q[0] * inv + cx)), c_max);
    const unsigned r = std::min(static_cast<unsigned>(static_cast<int>(q[1] * inv + cy)), r_max);
    float& cell = depth[static_cast<std::size_t>(r) * cols + c];
    cell = std::max(cell, static_cast<float>(q[2]));
  };
  if (all_finite) {
    for (std::size_t i = 0; i < n; ++i, p += 3) bin(p);
    return n;
  }
  std::size_t binned = 0;
  for (std::size_t i = 0; i < n; ++i, p += 3) {
    if (!finite_point(p)) continue;
    bin(p);
    ++binned;
  }
  return binned;
}

// Disc splats: every node within radius_cells of a node holding a point takes that node's
// front-most z, front-most rule again (a grey-value dilation of the measured grid with a disc;
// including the node itself, which changes nothing where the result is used). Points are taken
// at their node: a point splats the nodes within radius_cells of the node it fell on.
// The disc is a stack of row segments: the row at offset dr spans |dc| ≤ hw(dr) with
// hw(dr) = ⌊√(r² − dr²)⌋. Horizontal running maxima H_h (half-width h) are built incrementally
// (H_{h+1}(c) = max(H_h(c), m(c − h − 1), m(c + h + 1))), and each output row takes the max of
// H_hw(dr) over the disc's rows: O(rows·cols·r) with branch-free inner loops.
void splat_discs(const float* measured, int rows, int cols, double radius_cells, float* splat) {
  const int reach = static_cast<int>(std::floor(radius_cells));
  const double r2 = radius_cells * radius_cells;
  const auto ucols = static_cast<std::size_t>(cols);
  const std::size_t cells = static_cast<std::size_t>(rows) * ucols;
  std::vector<int> half_width(static_cast<std::size_t>(reach) + 1);
  for (int dr = 0; dr <= reach; ++dr) {
    half_width[static_cast<std::size_t>(dr)] =
        static_cast<int>(std::floor(std::sqrt(std::max(0.0, r2 - static_cast<double>(dr) * dr)) + 1e-9));
  }
  // running[h] = H_h for h = 1..reach; H_0 is the measured grid itself.
  std::vector<std::vector<float>> running(static_cast<std::size_t>(reach) + 1);
  std::vector<const float*> level(static_cast<std::size_t>(reach) + 1, measured);
  for (int h = 1; h <= reach; ++h) {
    std::vector<float>& out = running[static_cast<std::size_t>(h)];
    out.assign(level[static_cast<std::size_t>(h - 1)], level[static_cast<std::size_t>(h - 1)] + cells);
    level[static_cast<std::size_t>(h)] = out.data();
    for (int r = 0; r < rows; ++r) {
      float* dst = out.data() + static_cast<std::size_t>(r) * ucols;
      const float* src = measured + static_cast<std::size_t>(r) * ucols;
      for (int c = 0; c + h < cols; ++c) dst[c] = std::max(dst[c], src[c + h]);
      for (int c = h; c < cols; ++c) dst[c] = std::max(dst[c], src[c - h]);
    }
  }
  for (int r = 0; r < rows; ++r) {
    float* dst = splat + static_cast<std::size_t>(r) * ucols;
    for (int dr = -reach; dr <= reach; ++dr) {
      const int rr = r + dr;
      if (rr < 0 || rr >= rows) continue;
      const float* src = level[static_cast<std::size_t>(half_width[static_cast<std::size_t>(std::abs(dr))])] +
                         static_cast<std::size_t>(rr) * ucols;
      for (int c = 0; c < cols; ++c) dst[c] = std::max(dst[c], src[c]);
    }
  }
}

// Interpolating splats: order-0 normalised convolution restricted to a disc. Every EMPTY cell
// (flag kCellEmpty) with at least one measured cell within radius_cells takes
// Σ w·z / Σ w over those measured cells, w = exp(−d² / 2σ²), σ = radius / 2 (so the rim of the
// disc still weighs exp(−2) ≈ 0.14 of the centre); it is written in place (only measured cells
// are read, so the order of the writes does not matter) and flagged kCellSplatted. Cells with
// no measured cell in their (2⌊r⌋+1)² box are skipped in O(1) with a summed-area table of the
// mask, which is what keeps the background of a large grid cheap. Each cell's heights are summed
// relative to a measured height of its own disc (its first measured tap, in tap order), so that
// the float sums keep their precision and a cell's value depends on its disc alone: a window of
// the grid (ReprojectOptions::window, the tiled run) gives every cell whose disc it holds the
// whole grid's value bit for bit. (Until 2026-11-30 the reference was the grid's first measured
// cell, which a window finds elsewhere: windows agreed to float rounding only.) Rows are split
// between two threads for large grids. Returns the number of cells filled.
std::size_t splat_interpolate(float* depth, std::uint8_t* flags, int rows, int cols, double radius_cells,
                              const float* front, float depth_gap) {
  const int reach = static_cast<int>(std::floor(radius_cells));
  const std::size_t ucols = static_cast<std::size_t>(cols);
  const std::size_t cells = static_cast<std::size_t>(rows) * ucols;
  if (reach < 1) return 0;  // a disc of radius < 1 holds no other node
  // z·mask and mask, padded by `reach` on every side so the inner loop needs no bounds checks.
  const int pc = cols + 2 * reach;
  const std::size_t upc = static_cast<std::size_t>(pc);
  const std::size_t padded = static_cast<std::size_t>(rows + 2 * reach) * upc;
  std::vector<float> zm(padded, 0.0f), mask(padded, 0.0f);
  // Summed-area table of the mask, (rows + 1) × (cols + 1).
  std::vector<std::uint32_t> sat((static_cast<std::size_t>(rows) + 1) * (ucols + 1), 0u);
  for (int r = 0; r < rows; ++r) {
    std::uint32_t run = 0;
    const std::size_t prow = static_cast<std::size_t>(r + reach) * upc + static_cast<std::size_t>(reach);
    for (int c = 0; c < cols; ++c) {
      const std::size_t i = static_cast<std::size_t>(r) * ucols + static_cast<std::size_t>(c);
      const bool m = flags[i] == kCellMeasured;
      if (m) {
        zm[prow + static_cast<std::size_t>(c)] = depth[i];
        mask[prow + static_cast<std::size_t>(c)] = 1.0f;
      }
      run += m ? 1u : 0u;
      sat[(static_cast<std::size_t>(r) + 1) * (ucols + 1) + static_cast<std::size_t>(c) + 1] =
          sat[static_cast<std::size_t>(r) * (ucols + 1) + static_cast<std::size_t>(c) + 1] + run;
    }
  }
  // Disc taps: offsets into the padded arrays and Gaussian weights.
  const double r2 = radius_cells * radius_cells;
  const double sigma = 0.5 * radius_cells;
  std::vector<std::ptrdiff_t> offset;
  std::vector<float> weight;
  for (int dr = -reach; dr <= reach; ++dr) {
    for (int dc = -reach; dc <= reach; ++dc) {
      const double d2 = static_cast<double>(dr * dr + dc * dc);
      if (d2 > r2 || d2 == 0.0) continue;  // the centre is empty by construction
      offset.push_back(static_cast<std::ptrdiff_t>(dr) * pc + dc);
      weight.push_back(static_cast<float>(std::exp(-d2 / (2.0 * sigma * sigma))));
    }
  }
  const std::size_t taps = offset.size();
  auto box_count = [&](int r, int c) {
    const std::size_t r0 = static_cast<std::size_t>(std::max(0, r - reach));
    const std::size_t r1 = static_cast<std::size_t>(std::min(rows, r + reach + 1));
    const std::size_t c0 = static_cast<std::size_t>(std::max(0, c - reach));
    const std::size_t c1 = static_cast<std::size_t>(std::min(cols, c + reach + 1));
    const std::size_t w = ucols + 1;
    return sat[r1 * w + c1] + sat[r0 * w + c0] - sat[r0 * w + c1] - sat[r1 * w + c0];
  };
  auto rows_range = [&](int r_begin, int r_end, std::size_t* filled) {
    std::size_t n = 0;
    for (int r = r_begin; r < r_end; ++r) {
      for (int c = 0; c < cols; ++c) {
        const std::size_t i = static_cast<std::size_t>(r) * ucols + static_cast<std::size_t>(c);
        if (flags[i] != kCellEmpty || box_count(r, c) == 0) continue;
        const std::ptrdiff_t p = static_cast<std::ptrdiff_t>(static_cast<std::size_t>(r + reach) * upc +
                                                             static_cast<std::size_t>(c + reach));
        // The cell's reference height: its disc's first measured tap (none: nothing to fill; a
        // measured cell in the box may still lie outside the disc).
        std::size_t first = 0;
        while (first < taps && mask[static_cast<std::size_t>(p + offset[first])] == 0.0f) ++first;
        if (first == taps) continue;
        const float z_ref = zm[static_cast<std::size_t>(p + offset[first])];
        float num = 0.0f, den = 0.0f;
        if (front == nullptr) {
          for (std::size_t k = first; k < taps; ++k) {
            const std::size_t q = static_cast<std::size_t>(p + offset[k]);
            num += weight[k] * mask[q] * (zm[q] - z_ref);
            den += weight[k] * mask[q];
          }
        } else {
          // Only the front surface: measured cells within depth_gap of the front-most one.
          const float lim = front[i] - depth_gap;
          for (std::size_t k = first; k < taps; ++k) {
            const std::size_t q = static_cast<std::size_t>(p + offset[k]);
            const float m = (mask[q] > 0.0f && zm[q] >= lim) ? 1.0f : 0.0f;
            num += m * weight[k] * (zm[q] - z_ref);
            den += m * weight[k];
          }
        }
        if (den > 0.0f) {
          depth[i] = z_ref + num / den;
          flags[i] = kCellSplatted;
          ++n;
        }
      }
    }
    *filled = n;
  };
  std::size_t filled_a = 0, filled_b = 0;
  if (cells >= (1u << 20)) {
    const int mid = rows / 2;
    run_two([&] { rows_range(mid, rows, &filled_b); }, [&] { rows_range(0, mid, &filled_a); });
  } else {
    rows_range(0, rows, &filled_a);
  }
  return filled_a + filled_b;
}

// Weighted local planes (SplatMode::kPlane). Every node within radius_cells (exact x-y
// distance d, in cells) of a point gathers that point with weight exp(−d² / 2σ²), σ = radius / 2,
// when the point lies on the front surface there: z ≥ ref − depth_gap, ref = the front-most
// measured z within radius + √2/2 cells of the node (the disc dilation of the measured grid; a
// point's own node is at most √2/2 cells from it, so ref ≥ z of every gathered point). With
// depth_gap ≤ 0 every point in the radius is gathered. The node then takes the value at its own
// position of the weighted least-squares plane z = z̄ + b·(dx − x̄) + c·(dy − ȳ) through its points
// (dx, dy the point's offset from the node in cells), i.e. z̄ − b·x̄ − c·ȳ. The 2 × 2 normal
// equations are solved by eigen-decomposition; along an eigen-direction with variance under
// kPlaneMinVariance cells² (collinear or single points), or in which the node lies more than
// kPlaneMaxLeverage standard deviations from the points' centroid, the slope is 0, so the fit
// takes the weighted mean there instead of extrapolating. Moments are float, per node,
// relative to ref; they are solved in double.
// Separable weights: exp of the row and column offsets, (2⌊r⌋+2)·2 exponentials per point, in
// float (the weight is a float in the moments; float exp costs about half of double's, which
// was a fifth of this loop).
// The points are taken in row order (⌊fy⌋, then input order; see the sort below). Rows are
// split between two threads for large clouds (each thread reads the points whose disc can meet
// its rows and writes only its own rows). The plane solve is split too: each thread solves a contiguous half
// of the nodes, writes only their depth and flags and counts its own filled and occluded nodes;
// the counts are summed, so the results equal one thread's. Written: depth[i] and flags[i] of every node with weight > 0
// (measured nodes stay kCellMeasured unless their front-most point lies more than depth_gap
// below the plane: then kCellSplatted, counted in *occluded; empty nodes become kCellSplatted,
// counted in the return value). Nodes with no gathered point keep their value and flag.

std::size_t splat_planes(const double* p, std::size_t n, bool all_finite, const GridGeometry& g, double radius_cells,
                         float depth_gap, bool two_threads, float* depth, std::uint8_t* flags,
                         std::size_t* occluded, const NodeOffset& off = {}) {
  const int rows = g.rows, cols = g.cols;
  const std::size_t ucols = static_cast<std::size_t>(cols);
  const std::size_t cells = static_cast<std::size_t>(rows) * ucols;
  std::vector<float> ref(cells, kEmpty);
  splat_discs(depth, rows, cols, radius_cells + 0.7072, ref.data());
  std::vector<float> mom(static_cast<std::size_t>(kPlaneMoments) * cells, 0.0f);

  const double inv = 1.0 / g.cell_size_m;
  const double r2 = radius_cells * radius_cells;
  const double k_exp = -1.0 / (2.0 * 0.25 * r2);  // −1 / 2σ², σ = radius / 2
  const int span = 2 * static_cast<int>(std::ceil(radius_cells)) + 2;
  // The points in row order: by ⌊fy⌋ (the whole grid's row, less the window's integer offset),
  // in input order within a row (a counting sort of their indices: 8 bytes a point while it
  // runs, `order`'s 4 kept through the gathering), so that the moments a point adds to lie in
  // the rows just written. In input order a
  // scan in no order (the generated walls) adds to nodes anywhere in the grid: a cache miss
  // per row of its disc once the moments (36 bytes a node) outgrow the cache, which made this
  // loop the reprojection's largest cost. A node's sum takes its points in (⌊fy⌋, input)
  // order: a tile's window holds the whole scan's points in their order, and for every point
  // that reaches a node the tiled run compares ⌊fy⌋ differs from the whole grid's by the
  // window's integer offset (the subtraction is exact there), so the tiled run's sums are the
  // in-core run's bit for bit. Points more than the radius and a cell outside the rows are left
  // out (they reach no row). (Until 2026-11-25 the
  // points were taken in input order: sums in another order, equal to within float rounding.)
  const int reach = static_cast<int>(std::ceil(radius_cells));
  const int row_lo = -reach - 1;                                           // the first ⌊fy⌋ kept
  const auto nrow = static_cast<std::size_t>(rows + 2 * reach + 2);        // ⌊fy⌋ in [row_lo, rows + reach]
  if (n > std::numeric_limits<std::uint32_t>::max()) {
    throw ResourceError("reproject: splat_mode plane orders at most 2^32 - 1 points by row, got " + std::to_string(n));
  }
  std::vector<std::uint32_t> row_start(nrow + 1, 0), order;
  {
    std::vector<std::int32_t> key(n);
    const double* q = p;
    for (std::size_t i = 0; i < n; ++i, q += 3) {
      key[i] = -1;
      if (!all_finite && !finite_point(q)) continue;
      const double fy = (q[1] - g.y0_m) * inv - off.r;
      if (!(fy >= -radius_cells - 1.0 && fy <= rows + radius_cells)) continue;  // no row within reach
      key[i] = static_cast<std::int32_t>(std::floor(fy)) - row_lo;                // in [0, nrow) by the test above
      ++row_start[static_cast<std::size_t>(key[i]) + 1];
    }
    for (std::size_t k = 0; k < nrow; ++k) row_start[k + 1] += row_start[k];
    order.resize(row_start[nrow]);
    std::vector<std::uint32_t> at(row_start.begin(), row_start.end() - 1);
    for (std::size_t i = 0; i < n; ++i) {
      if (key[i] >= 0) order[at[static_cast<std::size_t>(key[i])]++] = static_cast<std::uint32_t>(i);
    }
  }
  auto gather = [&](int r_begin, int r_end) {
    std::vector<float> wc(static_cast<std::size_t>(span)), wr(static_cast<std::size_t>(span));
    // The points whose disc can meet rows [r_begin, r_end): ⌊fy⌋ in [r_begin − reach − 1,
    // r_end + reach), within [row_lo, rows + reach] since 0 ≤ r_begin ≤ r_end ≤ rows.
    const std::uint32_t ob = row_start[static_cast<std::size_t>(r_begin - reach - 1 - row_lo)];
    const std::uint32_t oe = row_start[static_cast<std::size_t>(r_end + reach - row_lo)];
    constexpr std::uint32_t kAhead = 32;  // prefetch distance [points]
    for (std::uint32_t o = ob; o < oe; ++o) {
      if (o + kAhead < oe) __builtin_prefetch(p + 3 * static_cast<std::size_t>(order[o + kAhead]));
      const double* q = p + 3 * static_cast<std::size_t>(order[o]);
      // Window: the whole grid's fractional index minus an integer offset (exact).
      const double fx = (q[0] - g.x0_m) * inv - off.c, fy = (q[1] - g.y0_m) * inv - off.r;
      const int r0 = std::max(r_begin, static_cast<int>(std::ceil(fy - radius_cells)));
      const int r1 = std::min(r_end - 1, static_cast<int>(std::floor(fy + radius_cells)));
      if (r0 > r1) continue;
      const int c0 = std::max(0, static_cast<int>(std::ceil(fx - radius_cells)));
      const int c1 = std::min(cols - 1, static_cast<int>(std::floor(fx + radius_cells)));
      for (int c = c0; c <= c1; ++c) {
        const double d = fx - c;
        wc[static_cast<std::size_t>(c - c0)] = std::exp(static_cast<float>(k_exp * d * d));
      }
      for (int r = r0; r <= r1; ++r) {
        const double d = fy - r;
        wr[static_cast<std::size_t>(r - r0)] = std::exp(static_cast<float>(k_exp * d * d));
      }
      for (int r = r0; r <= r1; ++r) {
        const double dy = fy - r;
        for (int c = c0; c <= c1; ++c) {
          const double dx = fx - c;
          if (dx * dx + dy * dy > r2) continue;
          const std::size_t j = static_cast<std::size_t>(r) * ucols + static_cast<std::size_t>(c);
          const float zr = static_cast<float>(q[2]) - ref[j];
          if (depth_gap > 0.0f && zr < -depth_gap) continue;  // behind the front surface here
          const float w = wc[static_cast<std::size_t>(c - c0)] * wr[static_cast<std::size_t>(r - r0)];
          const float x = static_cast<float>(dx), y = static_cast<float>(dy);
          float* m = mom.data() + static_cast<std::size_t>(kPlaneMoments) * j;
          m[0] += w;
          m[1] += w * x;
          m[2] += w * y;
          m[3] += w * x * x;
          m[4] += w * x * y;
          m[5] += w * y * y;
          m[6] += w * zr;
          m[7] += w * x * zr;
          m[8] += w * y * zr;
        }
      }
    }
  };
  if (two_threads) {
    const int mid = rows / 2;
    run_two([&] { gather(mid, rows); }, [&] { gather(0, mid); });
  } else {
    gather(0, rows);
  }
  // Each node's plane is solved from its own moments: on two threads, each a contiguous half of
  // the nodes with its own counts (the same values as one thread).
  auto solve = [&](std::size_t j_begin, std::size_t j_end, std::size_t& filled, std::size_t& hidden) {
    for (std::size_t j = j_begin; j < j_end; ++j) {
      const float* m = mom.data() + static_cast<std::size_t>(kPlaneMoments) * j;
      if (!(m[0] > 0.0f)) continue;
      const double w = m[0];
      const double xm = m[1] / w, ym = m[2] / w, zm = m[6] / w;
      const double sxx = m[3] / w - xm * xm, sxy = m[4] / w - xm * ym, syy = m[5] / w - ym * ym;
      const double sxz = m[7] / w - xm * zm, syz = m[8] / w - ym * zm;
      // Slope (b, c) = S⁺·(sxz, syz) with S the 2 × 2 x-y covariance, through its eigen-
      // decomposition S = Σ l_k·e_k·e_kᵀ. Along e_k the slope is fitted only when the node lies
      // within kPlaneMaxLeverage standard deviations of the centroid, (e_k·x̄)² ≤ kPlaneMaxLeverage²·l_k:
      // otherwise (a node beyond a scan line, a single point, the rim of the data) the value would
      // be an extrapolation amplified by |e_k·x̄| / √l_k, and the slope along e_k is 0 (the
      // weighted mean across).
      const double half_tr = 0.5 * (sxx + syy), half_diff = 0.5 * (sxx - syy);
      const double rad = std::sqrt(half_diff * half_diff + sxy * sxy);
      const double l1 = half_tr + rad, l2 = half_tr - rad;  // l1 ≥ l2
      double e1x = 1.0, e1y = 0.0;                          // unit eigenvector of l1
      if (rad > 0.0) {
        const double vx = half_diff + rad, vy = sxy;  // a column of S − l2·I: along e1
        const double len = std::hypot(vx, vy);
        if (len > 0.0) {
          e1x = vx / len;
          e1y = vy / len;
        } else {  // half_diff = −rad and sxy = 0: syy > sxx, e1 is y
          e1x = 0.0;
          e1y = 1.0;
        }
      }
      const double a1 = e1x * xm + e1y * ym, a2 = -e1y * xm + e1x * ym;     // x̄ along e1, e2
      const double p1 = e1x * sxz + e1y * syz, p2 = -e1y * sxz + e1x * syz;  // cov(·, z) along e1, e2
      constexpr double lev2 = kPlaneMaxLeverage * kPlaneMaxLeverage;
      const double k1 = l1 > kPlaneMinVariance && a1 * a1 <= lev2 * l1 ? p1 / l1 : 0.0;
      const double k2 = l2 > kPlaneMinVariance && a2 * a2 <= lev2 * l2 ? p2 / l2 : 0.0;
      const double b = k1 * e1x - k2 * e1y, c = k1 * e1y + k2 * e1x;
      const float z = ref[j] + static_cast<float>(zm - b * xm - c * ym);
      if (flags[j] == kCellMeasured) {
        if (depth_gap > 0.0f && depth[j] < z - depth_gap) {
          flags[j] = kCellSplatted;
          ++hidden;
        }
      } else {
        flags[j] = kCellSplatted;
        ++filled;
      }
      depth[j] = z;
    }
  };
  std::size_t filled = 0, hidden = 0;
  if (two_threads) {
    std::size_t filled_b = 0, hidden_b = 0;
    run_two([&] { solve(cells / 2, cells, filled_b, hidden_b); }, [&] { solve(0, cells / 2, filled, hidden); });
    filled += filled_b;
    hidden += hidden_b;
  } else {
    solve(0, cells, filled, hidden);
  }
  *occluded = hidden;
  return filled;
}

// Separable (2w+1)² max filter of `in` (−inf = empty) into `out`, using `tmp`.
void window_max(const float* in, int rows, int cols, int w, float* tmp, float* out) {
  const std::size_t ncols = static_cast<std::size_t>(cols);
  for (int r = 0; r < rows; ++r) {
    const float* src = in + static_cast<std::size_t>(r) * ncols;
    float* dst = tmp + static_cast<std::size_t>(r) * ncols;
    for (int c = 0; c < cols; ++c) dst[c] = src[c];
    for (int k = 1; k <= w; ++k) {
      for (int c = 0; c + k < cols; ++c) dst[c] = std::max(dst[c], src[c + k]);
      for (int c = k; c < cols; ++c) dst[c] = std::max(dst[c], src[c - k]);
    }
  }
  for (int r = 0; r < rows; ++r) {
    float* dst = out + static_cast<std::size_t>(r) * ncols;
    const int lo = std::max(0, r - w), hi = std::min(rows - 1, r + w);
    const float* first = tmp + static_cast<std::size_t>(lo) * ncols;
    for (int c = 0; c < cols; ++c) dst[c] = first[c];
    for (int rr = lo + 1; rr <= hi; ++rr) {
      const float* src = tmp + static_cast<std::size_t>(rr) * ncols;
      for (int c = 0; c < cols; ++c) dst[c] = std::max(dst[c], src[c]);
    }
  }
}

// True when a cell strictly higher than `threshold` lies on the ray from (r, c) in direction
// (dr, dc) within w steps.
inline bool ray_has_higher(const float* depth, int rows, int cols, int r, int c, int dr, int dc,
                           int w, float threshold) {
  for (int k = 1; k <= w; ++k) {
    const int rr = r + k * dr, cc = c + k * dc;
    if (rr < 0 || rr >= rows || cc < 0 || cc >= cols) return false;
    if (depth[static_cast<std::size_t>(rr) * static_cast<std::size_t>(cols) + static_cast<std::size_t>(cc)] > threshold) return true;
  }
  return false;
}


// Coverage of the scan on geometry g: of the nodes holding at least one point, the fraction
// whose 4 neighbours hold one too (1 for a scan denser than the grid everywhere; about p⁴ when
// a node is hit with probability p, so it falls fast once cells get finer than the spacing).
// Marks the node of every finite point (the binning of bin_front_most, clamped) in `hit`, a bit
// per node (row-major, (g's nodes + 63) / 64 words): 1 MB for 4 096 × 2 049 nodes, which points
// in random order mostly find in a core's cache (a byte per node, until 2026-11-28, missed it).
void mark_hits(const double* p, std::size_t n, const GridGeometry& g, bool all_finite, std::uint64_t* hit) {
  const double inv = 1.0 / g.cell_size_m;
  const double cx = 0.5 - g.x0_m * inv, cy = 0.5 - g.y0_m * inv;
  const auto c_max = static_cast<unsigned>(g.cols - 1), r_max = static_cast<unsigned>(g.rows - 1);
  const std::size_t cols = static_cast<std::size_t>(g.cols);
  for (std::size_t i = 0; i < n; ++i, p += 3) {
    if (!all_finite && !finite_point(p)) continue;
    const unsigned c = std::min(static_cast<unsigned>(static_cast<int>(p[0] * inv + cx)), c_max);
    const unsigned r = std::min(static_cast<unsigned>(static_cast<int>(p[1] * inv + cy)), r_max);
    const std::size_t at = static_cast<std::size_t>(r) * cols + c;
    hit[at >> 6] |= std::uint64_t{1} << (at & 63);
  }
}

// Words of a bit per node of g (mark_hits' `hit`).
std::size_t hit_words(const GridGeometry& g) { return (g.cell_count() + 63) / 64; }

// Of the hit nodes not on the border, the fraction whose 4 neighbours are hit.
double coverage_of_hits(const std::vector<std::uint64_t>& hit, const GridGeometry& g);
// The counts behind it: the hit nodes not on the border, and those of them whose 4 neighbours are hit.
std::array<std::uint64_t, 2> coverage_counts_of_hits(const std::vector<std::uint64_t>& hit, const GridGeometry& g);

double coverage_on(const double* p, std::size_t n, const GridGeometry& g, bool all_finite) {
  std::vector<std::uint64_t> hit(hit_words(g), 0);
  if (n < kTwoThreadPoints) {
    mark_hits(p, n, g, all_finite, hit.data());
  } else {  // each half of the points marks its own array; the marks are joined (OR) after
    std::vector<std::uint64_t> upper(hit.size(), 0);
    run_two([&] { mark_hits(p + 3 * (n / 2), n - n / 2, g, all_finite, upper.data()); },
            [&] { mark_hits(p, n / 2, g, all_finite, hit.data()); });
    for (std::size_t i = 0; i < hit.size(); ++i) hit[i] |= upper[i];
  }
  return coverage_of_hits(hit, g);
}

double coverage_of_hits(const std::vector<std::uint64_t>& hit, const GridGeometry& g) {
  const auto [occupied, interior] = coverage_counts_of_hits(hit, g);
  return occupied == 0 ? 0.0 : static_cast<double>(interior) / static_cast<double>(occupied);
}

std::array<std::uint64_t, 2> coverage_counts_of_hits(const std::vector<std::uint64_t>& hit, const GridGeometry& g) {
  const std::size_t cols = static_cast<std::size_t>(g.cols);
  const auto at = [&](std::size_t i) { return static_cast<unsigned>((hit[i >> 6] >> (i & 63)) & 1U); };
  std::size_t occupied = 0, interior = 0;
  for (int r = 1; r + 1 < g.rows; ++r) {
    for (int c = 1; c + 1 < g.cols; ++c) {
      const std::size_t i = static_cast<std::size_t>(r) * cols + static_cast<std::size_t>(c);
      if (!at(i)) continue;
      ++occupied;
      interior += (at(i - 1) & at(i + 1) & at(i - cols) & at(i + cols)) != 0U ? 1U : 0U;
    }
  }
  return {occupied, interior};
}

// The grid whose node (R, C) is node (K·R, K·C) of g: same origin, K× the cell, covering g.
GridGeometry coarse_geometry(const GridGeometry& g, int k) {
  GridGeometry c = g;
  c.cell_size_m = g.cell_size_m * k;
  c.cols = (g.cols - 1 + k - 1) / k + 1;
  c.rows = (g.rows - 1 + k - 1) / k + 1;
  return c;
}

int auto_upsample_factor(const double* p, std::size_t n, const GridGeometry& g, bool all_finite,
                         double* coverage) {
  for (int k = 1; k <= kMaxUpsampleFactor; ++k) {
    const GridGeometry c = coarse_geometry(g, k);
    if (c.cols < 3 || c.rows < 3) return std::max(1, k - 1);
    *coverage = coverage_on(p, n, c, all_finite);
    if (*coverage >= kAutoUpsampleCoverage) return k;
  }
  return kMaxUpsampleFactor;
}

// Bilinear interpolation of the coarse scan onto g (g's node (r, c) sits at coarse (r/K, c/K)).
// A node is no data when a coarse node with non-zero weight is; nodes that coincide with a
// coarse node keep its value and flag, the others are flagged kCellUpsampled (or keep the
// no-data flag of the nearest coarse node).
DepthGrid upsample(const DepthGrid& coarse, const GridGeometry& cg, const GridGeometry& g, int k) {
  DepthGrid out;
  out.depth = HeightField(g, kNoData);
  out.flags.assign(g.cell_count(), kCellEmpty);
  const float* z = coarse.depth.data();
  const std::size_t ccols = static_cast<std::size_t>(cg.cols);
  const double inv_k = 1.0 / k;
  for (int r = 0; r < g.rows; ++r) {
    const int r0 = std::min(r / k, cg.rows - 2);
    const double v = (r - r0 * k) * inv_k;
    for (int c = 0; c < g.cols; ++c) {
      const int c0 = std::min(c / k, cg.cols - 2);
      const double u = (c - c0 * k) * inv_k;
      const std::size_t i00 = static_cast<std::size_t>(r0) * ccols + static_cast<std::size_t>(c0);
      const double w[4] = {(1 - u) * (1 - v), u * (1 - v), (1 - u) * v, u * v};
      const std::size_t idx[4] = {i00, i00 + 1, i00 + ccols, i00 + ccols + 1};
      double acc = 0.0;
      bool valid = true;
      for (int q = 0; q < 4; ++q) {
        if (w[q] == 0.0) continue;
        const float zq = z[idx[q]];
        if (std::isnan(zq)) valid = false;
        acc += w[q] * static_cast<double>(zq);
      }
      const std::size_t near = idx[(u >= 0.5 ? 1 : 0) + (v >= 0.5 ? 2 : 0)];
      const std::size_t o = static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(c);
      const bool on_node = (r % k == 0) && (c % k == 0) && r / k < cg.rows && c / k < cg.cols;
      if (valid) {
        out.depth.data()[o] = static_cast<float>(acc);
        out.flags[o] = on_node ? coarse.flags[near] : std::uint8_t{kCellUpsampled};
      } else {
        out.flags[o] = std::isnan(z[near]) ? coarse.flags[near] : std::uint8_t{kCellEmpty};
      }
    }
  }
  return out;
}

// The see-through test (header comment, "See-through") on a depth grid whose empty cells are
// kEmpty: rejected cells become kEmpty and kCellSeeThrough. Returns the number rejected;
// `candidates` gets the number of cells the window pre-selection passed to the ray test.
std::size_t reject_see_through(float* depth, std::uint8_t* flags, const GridGeometry& g, int w, float depth_gap,
                               std::size_t& candidates) {
  const std::size_t cells = g.cell_count();
  candidates = 0;
  const auto tmp = std::make_unique_for_overwrite<float[]>(cells);
  const auto wmax = std::make_unique_for_overwrite<float[]>(cells);
  window_max(depth, g.rows, g.cols, w, tmp.get(), wmax.get());
  std::vector<std::size_t> rejected;
  static constexpr int kDirs[4][2] = {{0, 1}, {1, 0}, {1, 1}, {1, -1}};
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      const std::size_t i = static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(c);
      const float z = depth[i];
      if (z == kEmpty) continue;
      const float threshold = z + depth_gap;
      if (!(wmax[i] > threshold)) continue;
      ++candidates;
      int pairs = 0;
      if (r >= w && c >= w && r + w < g.rows && c + w < g.cols) {
        // Interior: branch-free maxima along the 8 rays.
        for (const auto& d : kDirs) {
          const std::ptrdiff_t step = static_cast<std::ptrdiff_t>(d[0]) * g.cols + d[1];
          float up = kEmpty, down = kEmpty;
          for (int k = 1; k <= w; ++k) {
            up = std::max(up, depth[static_cast<std::ptrdiff_t>(i) + k * step]);
            down = std::max(down, depth[static_cast<std::ptrdiff_t>(i) - k * step]);
          }
          pairs += (up > threshold && down > threshold) ? 1 : 0;
        }
      } else {
        for (const auto& d : kDirs) {
          if (ray_has_higher(depth, g.rows, g.cols, r, c, d[0], d[1], w, threshold) &&
              ray_has_higher(depth, g.rows, g.cols, r, c, -d[0], -d[1], w, threshold)) {
            ++pairs;
          }
        }
      }
      if (pairs >= kMinBracketingPairs) rejected.push_back(i);
    }
  }
  // Applied after the scan so that every test saw the same (unmodified) grid.
  for (std::size_t i : rejected) {
    depth[i] = kEmpty;
    flags[i] = kCellSeeThrough;
  }
  return rejected.size();
}

// The final grid's cells by flag: measured, splatted and upsampled (valid is their sum).
struct FlagCounts {
  std::size_t measured = 0, splatted = 0, upsampled = 0;
  std::size_t valid() const { return measured + splatted + upsampled; }
};
FlagCounts count_flags(const CellBuffer<std::uint8_t>& flags) {
  FlagCounts n;
  for (const std::uint8_t f : flags) {
    n.measured += f == kCellMeasured ? 1U : 0U;
    n.splatted += f == kCellSplatted ? 1U : 0U;
    n.upsampled += f == kCellUpsampled ? 1U : 0U;
  }
  return n;
}

// Counts of one scan_grid call, for the stage report.
struct ScanCounts {
  std::size_t binned = 0, splatted = 0, occluded = 0, see_through = 0, candidates = 0;
};

// Binning, splats and see-through detection on geometry g (the whole scan at one resolution).
DepthGrid scan_grid(const double* pts, std::size_t n_points, std::size_t half, bool two_threads,
                    bool all_finite, const GridGeometry& g, const ReprojectOptions& options,
                    ScanCounts& counts, const NodeOffset& off = {}) {
  const std::size_t cells = g.cell_count();
  DepthGrid out;
  out.depth = HeightField(g, kEmpty);
  out.flags.assign(cells, kCellEmpty);
  float* depth = out.depth.data();
  std::size_t& binned = counts.binned;
  if (two_threads) {
    const auto upper = std::make_unique_for_overwrite<float[]>(cells);
    std::size_t binned_upper = 0;
    run_two(
        [&] {
          std::fill_n(upper.get(), cells, kEmpty);
          binned_upper = bin_front_most(pts + 3 * half, n_points - half, g, all_finite, upper.get(), off);
        },
        [&] { binned = bin_front_most(pts, half, g, all_finite, depth, off); });
    for (std::size_t i = 0; i < cells; ++i) depth[i] = std::max(depth[i], upper[i]);
    binned += binned_upper;
  } else {
    binned = bin_front_most(pts, n_points, g, all_finite, depth, off);
  }
  for (std::size_t i = 0; i < cells; ++i) out.flags[i] = depth[i] != kEmpty ? kCellMeasured : kCellEmpty;

  const bool see_through = options.see_through_depth_m > 0.0;
  const float depth_gap = static_cast<float>(options.see_through_depth_m);
  std::size_t& splatted = counts.splatted;
  std::size_t& occluded = counts.occluded;
  if (options.splat_radius_cells > 0.0 && options.splat_mode == SplatMode::kPlane) {
    splatted = splat_planes(pts, n_points, all_finite, g, options.splat_radius_cells, see_through ? depth_gap : 0.0f,
                            two_threads, depth, out.flags.data(), &occluded, off);
  } else if (options.splat_radius_cells > 0.0 && options.splat_mode == SplatMode::kInterpolate) {
    std::vector<float> front;
    if (see_through) {
      // The disc rule's occlusion first: a measured cell lying more than see_through_depth_m
      // below the front-most measured z within the radius is a back surface seen through the
      // front one's sampling gaps (merged multi-view scans). It is emptied, and every cell is
      // interpolated from the front surface only (measured cells within see_through_depth_m of
      // the front-most one in its disc), so back-surface samples never enter a mean.
      front.assign(cells, kEmpty);
      splat_discs(depth, g.rows, g.cols, options.splat_radius_cells, front.data());
      for (std::size_t i = 0; i < cells; ++i) {
        if (out.flags[i] != kCellMeasured || !(front[i] > depth[i] + depth_gap)) continue;
        depth[i] = kEmpty;
        out.flags[i] = kCellEmpty;
        ++occluded;
      }
    }
    splatted = splat_interpolate(depth, out.flags.data(), g.rows, g.cols, options.splat_radius_cells,
                                 see_through ? front.data() : nullptr, depth_gap);
    // Every emptied cell has its front neighbour within the radius, so it is filled again:
    // counted as occluded, not as a filled empty cell.
    splatted -= std::min(splatted, occluded);
  } else if (options.splat_radius_cells > 0.0) {
    std::vector<float> splat(cells, kEmpty);
    splat_discs(depth, g.rows, g.cols, options.splat_radius_cells, splat.data());
    for (std::size_t i = 0; i < cells; ++i) {
      const float s = splat[i];
      if (s == kEmpty) continue;
      if (depth[i] == kEmpty) {
        depth[i] = s;
        out.flags[i] = kCellSplatted;
        ++splatted;
      } else if (see_through && s > depth[i] + depth_gap) {
        depth[i] = s;  // the measured point is hidden behind a neighbour's disc
        out.flags[i] = kCellSplatted;
        ++occluded;
      }
    }
  }

  if (see_through) {
    counts.see_through = reject_see_through(depth, out.flags.data(), g, options.see_through_window_cells, depth_gap,
                                            counts.candidates);
  }

  // −inf (nothing) becomes NaN (no data) (empty and see-through cells are the only −inf ones).
  for (std::size_t i = 0; i < cells; ++i) depth[i] = depth[i] == kEmpty ? kNoData : depth[i];
  return out;
}

// ---- Colour and intensity -------------------------------------------------------------------
// Carried in passes of their own after the depth scan, so the depth path (and its result) is
// the same with or without attributes. The winner of a cell is found again here by the same
// binning as bin_front_most (same float z, same node); it is single-threaded.

constexpr std::uint32_t kNoPoint = std::numeric_limits<std::uint32_t>::max();

// Index of the front-most point per node of g (largest float z, ties to the earliest point),
// kNoPoint where no finite point fell; `front_z` gets that point's z (the measured grid).
std::vector<std::uint32_t> front_most_index(const double* p, std::size_t n, const GridGeometry& g,
                                            bool all_finite, std::vector<float>& front_z, const NodeOffset& off = {}) {
  const std::size_t cells = g.cell_count();
  std::vector<std::uint32_t> winner(cells, kNoPoint);
  front_z.assign(cells, kEmpty);
  const double inv = 1.0 / g.cell_size_m;
  const double cx = 0.5 - g.x0_m * inv, cy = 0.5 - g.y0_m * inv;
  const std::size_t cols = static_cast<std::size_t>(g.cols);
  const auto c_max = static_cast<unsigned>(g.cols - 1), r_max = static_cast<unsigned>(g.rows - 1);
  for (std::size_t i = 0; i < n; ++i, p += 3) {
    if (!all_finite && !finite_point(p)) continue;
    unsigned c, r;
    if (off.window) {
      c = static_cast<unsigned>(static_cast<int>(p[0] * inv + cx) - off.c);
      r = static_cast<unsigned>(static_cast<int>(p[1] * inv + cy) - off.r);
      if (c > c_max || r > r_max) continue;
    } else {
      c = std::min(static_cast<unsigned>(static_cast<int>(p[0] * inv + cx)), c_max);
      r = std::min(static_cast<unsigned>(static_cast<int>(p[1] * inv + cy)), r_max);
    }
    const std::size_t k = static_cast<std::size_t>(r) * cols + c;
    const float z = static_cast<float>(p[2]);
    if (winner[k] == kNoPoint || z > front_z[k]) {
      winner[k] = static_cast<std::uint32_t>(i);
      front_z[k] = z;
    }
  }
  return winner;
}

// Fills out.colour_rgb8 / out.intensity (whichever the cloud has) on geometry g after scan_grid.
void scan_attributes(const Cloud& cloud, bool all_finite, const GridGeometry& g, const ReprojectOptions& options,
                     DepthGrid& out, const NodeOffset& off = {}) {
  const bool rgb = cloud.has_rgb(), inten = cloud.has_intensity();
  const std::size_t cells = g.cell_count();
  std::vector<float> front_z;
  const std::vector<std::uint32_t> winner = front_most_index(cloud.xyz.data(), cloud.size(), g, all_finite, front_z, off);
  if (rgb) out.colour_rgb8.assign(3 * cells, 0);
  if (inten) out.intensity = HeightField(g, kNoData);
  auto copy_from = [&](std::size_t cell, std::uint32_t point) {
    if (rgb) std::copy_n(cloud.rgb.data() + 3 * static_cast<std::size_t>(point), 3, out.colour_rgb8.data() + 3 * cell);
    if (inten) out.intensity.data()[cell] = cloud.intensity[point];
  };
  const int reach = static_cast<int>(std::floor(options.splat_radius_cells));
  const double r2 = options.splat_radius_cells * options.splat_radius_cells;
  std::vector<int> half_width(static_cast<std::size_t>(reach) + 1);
  for (int dr = 0; dr <= reach; ++dr) {  // the disc of splat_discs
    half_width[static_cast<std::size_t>(dr)] =
        static_cast<int>(std::floor(std::sqrt(std::max(0.0, r2 - static_cast<double>(dr) * dr)) + 1e-9));
  }
  const double sigma = 0.5 * options.splat_radius_cells;
  // Interpolating and plane splats: the measured nodes whose points can have reached the cell
  // (a plane fill needs a point within the radius; its node lies up to √2/2 cells farther).
  const double attr_radius = options.splat_radius_cells + (options.splat_mode == SplatMode::kPlane ? 0.7072 : 0.0);
  const int attr_reach = static_cast<int>(std::floor(attr_radius));
  const double attr_r2 = attr_radius * attr_radius;
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      const std::size_t i = static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(c);
      const std::uint8_t f = out.flags[i];
      if (f == kCellMeasured) {
        copy_from(i, winner[i]);
      } else if (f == kCellSplatted && options.splat_mode == SplatMode::kDisc) {
        // The measured node whose z the disc dilation took: the front-most one in the disc.
        std::size_t best = cells;
        for (int dr = -reach; dr <= reach; ++dr) {
          const int rr = r + dr;
          if (rr < 0 || rr >= g.rows) continue;
          const int hw = half_width[static_cast<std::size_t>(std::abs(dr))];
          for (int cc = std::max(0, c - hw); cc <= std::min(g.cols - 1, c + hw); ++cc) {
            const std::size_t j = static_cast<std::size_t>(rr) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(cc);
            if (winner[j] == kNoPoint) continue;
            if (best == cells || front_z[j] > front_z[best]) best = j;
          }
        }
        if (best != cells) copy_from(i, winner[best]);
      } else if (f == kCellSplatted) {
        // Interpolating splat: the Gaussian-weighted mean over the measured cells in the disc.
        double w_sum = 0.0, c_sum[3] = {0.0, 0.0, 0.0}, i_sum = 0.0;
        for (int dr = -attr_reach; dr <= attr_reach; ++dr) {
          const int rr = r + dr;
          if (rr < 0 || rr >= g.rows) continue;
          for (int dc = -attr_reach; dc <= attr_reach; ++dc) {
            const int cc = c + dc;
            const double d2 = static_cast<double>(dr * dr + dc * dc);
            if (cc < 0 || cc >= g.cols || d2 > attr_r2 || d2 == 0.0) continue;
            const std::size_t j = static_cast<std::size_t>(rr) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(cc);
            if (winner[j] == kNoPoint) continue;
            const double w = static_cast<float>(std::exp(-d2 / (2.0 * sigma * sigma)));
            w_sum += w;
            const std::size_t pt = winner[j];
            if (rgb) {
              for (int k = 0; k < 3; ++k) c_sum[k] += w * cloud.rgb[3 * pt + static_cast<std::size_t>(k)];
            }
            if (inten) i_sum += w * static_cast<double>(cloud.intensity[pt]);
          }
        }
        if (w_sum > 0.0) {
          if (rgb) {
            for (int k = 0; k < 3; ++k) {
              out.colour_rgb8[3 * i + static_cast<std::size_t>(k)] =
                  static_cast<std::uint8_t>(std::clamp(std::lround(c_sum[k] / w_sum), 0L, 255L));
            }
          }
          if (inten) out.intensity.data()[i] = static_cast<float>(i_sum / w_sum);
        }
      }
    }
  }
}

// Bilinear interpolation of the coarse attributes onto g with the weights upsample() gives the
// depth; only nodes whose depth is valid get values.
void upsample_attributes(const DepthGrid& coarse, const GridGeometry& cg, const GridGeometry& g, int k,
                         DepthGrid& out) {
  const bool rgb = coarse.has_colour(), inten = coarse.has_intensity();
  if (rgb) out.colour_rgb8.assign(3 * g.cell_count(), 0);
  if (inten) out.intensity = HeightField(g, kNoData);
  const std::size_t ccols = static_cast<std::size_t>(cg.cols);
  const double inv_k = 1.0 / k;
  for (int r = 0; r < g.rows; ++r) {
    const int r0 = std::min(r / k, cg.rows - 2);
    const double v = (r - r0 * k) * inv_k;
    for (int c = 0; c < g.cols; ++c) {
      const std::size_t o = static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(c);
      if (std::isnan(out.depth.data()[o])) continue;
      const int c0 = std::min(c / k, cg.cols - 2);
      const double u = (c - c0 * k) * inv_k;
      const std::size_t i00 = static_cast<std::size_t>(r0) * ccols + static_cast<std::size_t>(c0);
      const double w[4] = {(1 - u) * (1 - v), u * (1 - v), (1 - u) * v, u * v};
      const std::size_t idx[4] = {i00, i00 + 1, i00 + ccols, i00 + ccols + 1};
      double c_acc[3] = {0.0, 0.0, 0.0}, i_acc = 0.0;
      for (int q = 0; q < 4; ++q) {
        if (w[q] == 0.0) continue;
        if (rgb) {
          for (int ch = 0; ch < 3; ++ch) c_acc[ch] += w[q] * coarse.colour_rgb8[3 * idx[q] + static_cast<std::size_t>(ch)];
        }
        if (inten) i_acc += w[q] * static_cast<double>(coarse.intensity.data()[idx[q]]);
      }
      if (rgb) {
        for (int ch = 0; ch < 3; ++ch) {
          out.colour_rgb8[3 * o + static_cast<std::size_t>(ch)] =
              static_cast<std::uint8_t>(std::clamp(std::lround(c_acc[ch]), 0L, 255L));
        }
      }
      if (inten) out.intensity.data()[o] = static_cast<float>(i_acc);
    }
  }
}

}  // namespace

namespace {

// The x-y bounds of the finite points, on two threads for large clouds (each half of them).
Bounds bounds_of(const double* pts, std::size_t n) {
  if (n < kTwoThreadPoints) return finite_bounds(pts, n);
  Bounds lower, upper;
  run_two([&] { upper = finite_bounds(pts + 3 * (n / 2), n - n / 2); }, [&] { lower = finite_bounds(pts, n / 2); });
  return merge(lower, upper);
}

// reproject, returning the scan's event counts (ScanCounts) in *counts_out when given.
StageResult<DepthGrid> reproject_counted(const Cloud& points_m, const ReprojectOptions& options, ScanCounts* counts_out) {
  const auto t0 = std::chrono::steady_clock::now();
  validate_options(options);
  // The two passes over the points (bounds, binning) run on two threads for large clouds; each
  // thread takes half of the points (binning into its own grid, merged by the front-most rule).
  const double* pts = points_m.xyz.data();
  const std::size_t n_points = points_m.size();
  const bool two_threads = n_points >= kTwoThreadPoints;
  const std::size_t half = two_threads ? n_points / 2 : n_points;
  const Bounds bounds = bounds_of(pts, n_points);
  if (bounds.finite == 0) {
    std::ostringstream msg;
    msg << "reproject: none of the " << points_m.size()
        << " input points is finite (every point has a NaN or infinite coordinate)";
    throw InputError(msg.str());
  }
  // A window of a given grid (the tiled pipeline), or the grid of the points' own box.
  NodeOffset off;
  GridGeometry g;
  if (options.window) {
    const GridWindow& w = *options.window;
    g = w.grid;  // the whole grid's origin and cell: node indices as on the whole grid
    g.rows = w.rows;
    g.cols = w.cols;
    off = {w.row0, w.col0, true};
  } else {
    g = make_geometry(bounds, options);
  }
  const bool all_finite = bounds.finite == n_points;
  StageResult<DepthGrid> result;
  ScanCounts counts;
  double coverage = 0.0;
  const int factor = options.upsample_factor == 0
                         ? auto_upsample_factor(pts, n_points, g, all_finite, &coverage)
                         : options.upsample_factor;
  const bool attributes = points_m.has_rgb() || points_m.has_intensity();
  if (attributes) {
    std::ostringstream msg;
    if ((points_m.has_rgb() && points_m.rgb.size() != 3 * n_points) ||
        (points_m.has_intensity() && points_m.intensity.size() != n_points)) {
      msg << "reproject: the cloud's attributes are misaligned (" << n_points << " points, " << points_m.rgb.size()
          << " rgb bytes, " << points_m.intensity.size() << " intensities; expected 3 bytes and 1 intensity per point)";
      throw InputError(msg.str());
    }
    if (n_points >= kNoPoint) {
      msg << "reproject: " << n_points << " points with colour or intensity; at most " << kNoPoint - 1 << " supported";
      throw ResourceError(msg.str());
    }
  }
  if (factor == 1) {
    result.value = scan_grid(pts, n_points, half, two_threads, all_finite, g, options, counts, off);
    if (attributes) scan_attributes(points_m, all_finite, g, options, result.value, off);
  } else {
    const GridGeometry coarse = coarse_geometry(g, factor);
    const NodeOffset coarse_off{off.r / factor, off.c / factor, off.window};  // validated: multiples of K
    DepthGrid scanned = scan_grid(pts, n_points, half, two_threads, all_finite, coarse, options, counts, coarse_off);
    if (attributes) scan_attributes(points_m, all_finite, coarse, options, scanned, coarse_off);
    result.value = upsample(scanned, coarse, g, factor);
    if (attributes) upsample_attributes(scanned, coarse, g, factor, result.value);
  }
  if (off.window) {  // the window's own origin, for the layers and the scene
    g.x0_m = options.window->grid.x_of_col(off.c);
    g.y0_m = options.window->grid.y_of_row(off.r);
    HeightField depth(g);
    depth.values() = std::move(result.value.depth.values());
    result.value.depth = std::move(depth);
    if (result.value.has_intensity()) {
      HeightField intensity(g);
      intensity.values() = std::move(result.value.intensity.values());
      result.value.intensity = std::move(intensity);
    }
  }
  DepthGrid& out = result.value;
  const std::size_t cells = g.cell_count();
  const FlagCounts by_flag = count_flags(out.flags);
  const std::size_t measured = by_flag.measured, splat_final = by_flag.splatted, upsampled = by_flag.upsampled;
  const std::size_t valid = by_flag.valid();
  const std::size_t binned = counts.binned, splatted = counts.splatted, occluded = counts.occluded;
  const std::size_t see_through_cells = counts.see_through, candidates = counts.candidates;

  StageReport& rep = result.report;
  rep.stage = "reproject";
  rep.count_in = points_m.size();
  rep.count_out = valid;
  rep.figure("rows", g.rows);
  rep.figure("cols", g.cols);
  rep.figure("cell_size_mm", g.cell_size_m * 1e3);
  rep.figure("points_binned", static_cast<double>(binned));
  rep.figure(off.window ? "points_outside_window_or_non_finite" : "points_non_finite",
             static_cast<double>(points_m.size() - binned));
  rep.figure("cells", static_cast<double>(cells));
  rep.figure("cells_valid", static_cast<double>(valid));
  rep.figure("cells_measured", static_cast<double>(measured));
  rep.figure("cells_splatted", static_cast<double>(splat_final));
  rep.figure("cells_splat_filled_empty", static_cast<double>(splatted));
  rep.figure("cells_occluded_by_splat", static_cast<double>(occluded));
  rep.figure("cells_see_through", static_cast<double>(see_through_cells));
  rep.figure("upsample_factor", factor);
  rep.figure("cells_upsampled", static_cast<double>(upsampled));
  if (options.upsample_factor == 0) rep.figure("upsample_coverage", coverage);
  rep.figure("see_through_candidates", static_cast<double>(candidates));
  if (attributes) {
    rep.notes.emplace_back(std::string("carried per cell from the front-most point:") +
                           (points_m.has_rgb() ? " colour (rgb8)" : "") + (points_m.has_intensity() ? " intensity" : ""));
  }
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (counts_out != nullptr) *counts_out = counts;
  return result;
}

}  // namespace

StageResult<DepthGrid> reproject(const Cloud& points_m, const ReprojectOptions& options) {
  return reproject_counted(points_m, options, nullptr);
}

namespace {

// A box of absolute coarse nodes of the whole grid, rows [r0, r1] × columns [c0, c1].
struct NodeBox {
  int r0 = 0, r1 = -1, c0 = 0, c1 = -1;
  bool overlaps(const NodeBox& o) const { return r0 <= o.r1 && o.r0 <= r1 && c0 <= o.c1 && o.c0 <= c1; }
  NodeBox grown(int d, const NodeBox& limit) const {
    return {std::max(r0 - d, limit.r0), std::min(r1 + d, limit.r1), std::max(c0 - d, limit.c0), std::min(c1 + d, limit.c1)};
  }
  std::size_t cells() const {
    return static_cast<std::size_t>(std::max(0, r1 - r0 + 1)) * static_cast<std::size_t>(std::max(0, c1 - c0 + 1));
  }
};

}  // namespace

StageResult<DepthGrid> reproject_after_removal(const Cloud& points_m, const RemovedPoints& removed,
                                               StageResult<DepthGrid> before, const ReprojectOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  validate_options(options);
  const std::size_t n = points_m.size(), m = removed.size();
  if (removed.xyz.size() != 3 * m) {
    throw std::invalid_argument("reproject_after_removal: " + std::to_string(removed.xyz.size()) +
                                " coordinates for " + std::to_string(m) + " removed points (expected 3 per point)");
  }
  for (std::size_t i = 0; i < m; ++i) {
    if (removed.at[i] >= n + m || (i > 0 && removed.at[i] <= removed.at[i - 1])) {
      throw std::invalid_argument("reproject_after_removal: removed point " + std::to_string(i) + " at column " +
                                  std::to_string(removed.at[i]) + " (expected increasing columns below " +
                                  std::to_string(n + m) + ", the cloud's size before the removal)");
    }
  }
  if (m == 0) return before;
  const auto whole = [&](const std::string& why) {
    StageResult<DepthGrid> r = reproject(points_m, options);
    r.report.notes.push_back("made again over the whole grid after " + std::to_string(m) + " points were removed: " + why);
    return r;
  };
  if (options.splat_radius_cells > 0.0 && options.splat_mode == SplatMode::kInterpolate) {
    // The nodes are the grid's bit for bit in a window (splat_interpolate), but the fills its
    // margin counts before and after the removal need not differ as the whole grid's do (a
    // margin node reads taps past the window), so the report's cells_splat_filled_empty would.
    return whole("a window's margin counts interpolating splats' fills that the whole grid does not");
  }
  if (m > 4096) return whole("more than 4096 points removed");
  if (n >= std::numeric_limits<std::uint32_t>::max()) return whole("2^32 - 1 points or more (the windows list points by 32-bit column)");

  // The whole grid and the factor, as reproject would make them from these points.
  const double* pts = points_m.xyz.data();
  const Bounds bounds = bounds_of(pts, n);
  if (bounds.finite == 0) return whole("no finite point is left");
  const bool all_finite = bounds.finite == n;
  const GridGeometry& had = before.value.depth.geometry();
  GridGeometry g;        // the whole grid
  int k = 0;             // the upsample factor
  int base_r0 = 0, base_c0 = 0;  // the first fine node of the grid `before` holds
  double coverage = 0.0;
  if (options.window) {
    const GridWindow& w = *options.window;
    g = w.grid;
    k = options.upsample_factor;
    base_r0 = w.row0;
    base_c0 = w.col0;
    if (had.rows != w.rows || had.cols != w.cols) {
      throw std::invalid_argument("reproject_after_removal: the grid before holds " + std::to_string(had.rows) + " x " +
                                  std::to_string(had.cols) + " nodes, the window " + std::to_string(w.rows) + " x " +
                                  std::to_string(w.cols));
    }
  } else {
    g = make_geometry(bounds, options);
    if (!(g == had)) return whole("the points' box, hence the grid, changed");
    k = options.upsample_factor == 0 ? auto_upsample_factor(pts, n, g, all_finite, &coverage) : options.upsample_factor;
    if (k != static_cast<int>(detail::figure_of(before.report, "upsample_factor", 0.0))) return whole("the upsample factor changed");
  }
  const int fine_rows = had.rows, fine_cols = had.cols;
  // Work in the whole grid's coarse nodes (the nodes the scan runs on; the fine ones when K = 1).
  const GridGeometry cg = coarse_geometry(g, k);
  const double inv = 1.0 / cg.cell_size_m;
  const double cx = 0.5 - cg.x0_m * inv, cy = 0.5 - cg.y0_m * inv;
  const NodeBox base{base_r0 / k, base_r0 / k + (fine_rows - 1 + k - 1) / k, base_c0 / k,
                     base_c0 / k + (fine_cols - 1 + k - 1) / k};
  // A finite point's coarse node as reproject bins it (clamped on the whole grid; in a window,
  // unclamped: reproject bins only the points whose node lies inside, but every point given
  // splats into the cells its disc reaches). False for a non-finite point.
  const bool window_mode = options.window.has_value();
  const auto node_of = [&](const double* p, int& r, int& c) {
    if (!finite_point(p)) return false;
    r = static_cast<int>(p[1] * inv + cy);
    c = static_cast<int>(p[0] * inv + cx);
    if (!window_mode) {
      r = static_cast<int>(std::min(static_cast<unsigned>(r), static_cast<unsigned>(cg.rows - 1)));
      c = static_cast<int>(std::min(static_cast<unsigned>(c), static_cast<unsigned>(cg.cols - 1)));
    }
    return true;
  };
  const auto in_base = [&](int r, int c) { return r >= base.r0 && r <= base.r1 && c >= base.c0 && c <= base.c1; };
  // Reach: a coarse node's value and events depend on the points within rc coarse nodes
  // (reproject_reach_cells, which counts upsampling's next node too). U, the nodes made again,
  // lies one node beyond the reach of each removed point's node; the points within rc + 1 of U
  // are gathered and the window U + rc + 1 (within the grid held) scanned, so every node of U
  // gets the whole grid's value and events.
  const int rc = reproject_reach_cells(options, k) / k;
  std::vector<NodeBox> boxes;
  std::size_t removed_binned = 0;
  for (std::size_t i = 0; i < m; ++i) {
    int r = 0, c = 0;
    if (!node_of(&removed.xyz[3 * i], r, c)) continue;
    removed_binned += in_base(r, c) ? 1U : 0U;
    const NodeBox u = NodeBox{r, r, c, c}.grown(rc + 1, base);
    if (u.r0 <= u.r1 && u.c0 <= u.c1) boxes.push_back(u);  // else beyond the reach of the grid held
  }
  // Overlapping boxes merged, until none overlap: each node is made again (and its events
  // counted) once, and a removed point within another box's gather belongs to that box, so a
  // window's events outside its box are the same with and without its removed points.
  for (bool merged = true; merged;) {
    merged = false;
    for (std::size_t a = 0; a < boxes.size(); ++a) {
      for (std::size_t b = a + 1; b < boxes.size();) {
        if (!boxes[a].overlaps(boxes[b])) {
          ++b;
          continue;
        }
        boxes[a] = {std::min(boxes[a].r0, boxes[b].r0), std::max(boxes[a].r1, boxes[b].r1),
                    std::min(boxes[a].c0, boxes[b].c0), std::max(boxes[a].c1, boxes[b].c1)};
        boxes[b] = boxes.back();
        boxes.pop_back();
        b = a + 1;  // box a grew: check the rest again
        merged = true;
      }
    }
  }
  std::vector<NodeBox> windows, gather;  // scanned (within the grid held); points taken
  std::size_t scanned = 0;
  constexpr int kFar = std::numeric_limits<int>::max() / 4;
  for (const NodeBox& u : boxes) {
    windows.push_back(u.grown(rc + 1, base));
    gather.push_back(u.grown(rc + 1, NodeBox{-kFar, kFar, -kFar, kFar}));
    scanned += windows.back().cells();
  }
  if (3 * scanned > base.cells()) return whole("the windows about the removed points cover over a third of the grid");

  // The points of each window, in the cloud's order: after the removal (with their attributes),
  // and before it (coordinates only, the removed points back in their places).
  const bool rgb = points_m.has_rgb(), inten = points_m.has_intensity();
  int row_lo = 0, row_hi = -1;
  for (std::size_t b = 0; b < gather.size(); ++b) {
    row_lo = b == 0 ? gather[b].r0 : std::min(row_lo, gather[b].r0);
    row_hi = b == 0 ? gather[b].r1 : std::max(row_hi, gather[b].r1);
  }
  std::vector<std::vector<std::uint32_t>> in_row(static_cast<std::size_t>(std::max(0, row_hi - row_lo + 1)));
  for (std::size_t b = 0; b < gather.size(); ++b) {
    for (int r = gather[b].r0; r <= gather[b].r1; ++r) in_row[static_cast<std::size_t>(r - row_lo)].push_back(static_cast<std::uint32_t>(b));
  }
  std::vector<std::vector<std::uint32_t>> after_of(windows.size());   // point columns
  std::vector<std::vector<double>> before_of(windows.size());         // x y z
  const auto place = [&](const double* p, auto&& add) {
    int r = 0, c = 0;
    if (!node_of(p, r, c) || r < row_lo || r > row_hi) return;
    for (const std::uint32_t b : in_row[static_cast<std::size_t>(r - row_lo)]) {
      if (c >= gather[b].c0 && c <= gather[b].c1) add(b);
    }
  };
  // The points [i0, i1) and the removed points [r0, r1) that stood among them (removed point r
  // stood before point at[r] − r; those past the last point come at the end), into lists of
  // their own; two halves on two threads, joined in order after.
  using Lists = std::pair<std::vector<std::vector<std::uint32_t>>, std::vector<std::vector<double>>>;
  const auto collect = [&](std::size_t i0, std::size_t i1, std::size_t r0, std::size_t r1, Lists& out) {
    auto& after = out.first;  // named references, not a structured binding: lambdas capture them
    auto& before_xyz = out.second;
    after.resize(windows.size());
    before_xyz.resize(windows.size());
    const auto removed_point = [&](std::size_t ri) {
      const double* p = &removed.xyz[3 * ri];
      place(p, [&](std::uint32_t b) { before_xyz[b].insert(before_xyz[b].end(), p, p + 3); });
    };
    std::size_t next = r0;  // the next removed point
    for (std::size_t i = i0; i < i1; ++i) {
      while (next < r1 && removed.at[next] == i + next) removed_point(next++);
      const double* p = pts + 3 * i;
      place(p, [&](std::uint32_t b) {
        after[b].push_back(static_cast<std::uint32_t>(i));
        before_xyz[b].insert(before_xyz[b].end(), p, p + 3);
      });
    }
    while (next < r1) removed_point(next++);
  };
  const std::size_t mid = n >= kTwoThreadPoints ? n / 2 : n;
  std::size_t r_mid = 0;  // the first removed point that stood at or after point mid
  while (r_mid < m && removed.at[r_mid] - r_mid < mid) ++r_mid;
  Lists lower, upper;
  if (mid < n) {
    run_two([&] { collect(mid, n, r_mid, m, upper); }, [&] { collect(0, mid, 0, r_mid, lower); });
  } else {
    collect(0, n, 0, r_mid, lower);
    collect(n, n, r_mid, m, upper);
  }
  for (std::size_t b = 0; b < windows.size(); ++b) {
    after_of[b] = std::move(lower.first[b]);
    after_of[b].insert(after_of[b].end(), upper.first[b].begin(), upper.first[b].end());
    before_of[b] = std::move(lower.second[b]);
    before_of[b].insert(before_of[b].end(), upper.second[b].begin(), upper.second[b].end());
  }

  DepthGrid& grid = before.value;
  // Each window is made again on its own: its box U is disjoint from every other window's, and
  // only U's nodes are written, so two threads take the windows in turn; the event differences
  // and node counts are integer sums per window, added after in window order.
  struct WindowSums {
    long long filled = 0, occluded = 0, see_through = 0, candidates = 0;  ///< event differences [nodes]
    std::size_t remade = 0;                                                ///< U's fine nodes written
  };
  std::vector<WindowSums> sums(windows.size());
  const auto remake_window = [&](std::size_t b) {
    WindowSums& sum = sums[b];
    const NodeBox& wb = windows[b];
    const NodeBox& ub = boxes[b];
    ReprojectOptions wo = options;
    wo.upsample_factor = k;
    GridWindow win;
    win.grid = g;
    win.row0 = wb.r0 * k;
    win.col0 = wb.c0 * k;
    win.rows = std::min(wb.r1 * k, base_r0 + fine_rows - 1) - win.row0 + 1;
    win.cols = std::min(wb.c1 * k, base_c0 + fine_cols - 1) - win.col0 + 1;
    wo.window = win;
    // The window's events with and without its removed points differ only within its box.
    ScanCounts was, now;
    {
      Cloud old;
      old.xyz = Eigen::Map<const Eigen::Matrix3Xd>(before_of[b].data(), 3, static_cast<Eigen::Index>(before_of[b].size() / 3));
      (void)reproject_counted(old, wo, &was);
    }
    DepthGrid part;
    const std::vector<std::uint32_t>& cols = after_of[b];
    if (!cols.empty()) {
      Cloud cur;
      cur.xyz.resize(3, static_cast<Eigen::Index>(cols.size()));
      if (rgb) cur.rgb.resize(3 * cols.size());
      if (inten) cur.intensity.resize(cols.size());
      for (std::size_t q = 0; q < cols.size(); ++q) {
        cur.xyz.col(static_cast<Eigen::Index>(q)) = points_m.xyz.col(static_cast<Eigen::Index>(cols[q]));
        if (rgb) std::copy_n(points_m.rgb.data() + 3 * static_cast<std::size_t>(cols[q]), 3, cur.rgb.data() + 3 * q);
        if (inten) cur.intensity[q] = points_m.intensity[cols[q]];
      }
      part = reproject_counted(cur, wo, &now).value;
    }
    sum.filled = static_cast<long long>(now.splatted) - static_cast<long long>(was.splatted);
    sum.occluded = static_cast<long long>(now.occluded) - static_cast<long long>(was.occluded);
    sum.see_through = static_cast<long long>(now.see_through) - static_cast<long long>(was.see_through);
    sum.candidates = static_cast<long long>(now.candidates) - static_cast<long long>(was.candidates);
    // U's fine nodes (its coarse nodes and the fine ones up to the next), within the grid held.
    const int fr0 = ub.r0 * k, fc0 = ub.c0 * k;
    const int fr1 = std::min(ub.r1 * k + k - 1, base_r0 + fine_rows - 1), fc1 = std::min(ub.c1 * k + k - 1, base_c0 + fine_cols - 1);
    for (int r = fr0; r <= fr1; ++r) {
      for (int c = fc0; c <= fc1; ++c) {
        const std::size_t o = static_cast<std::size_t>(r - base_r0) * static_cast<std::size_t>(fine_cols) +
                              static_cast<std::size_t>(c - base_c0);
        const std::size_t i = static_cast<std::size_t>(r - win.row0) * static_cast<std::size_t>(win.cols) +
                              static_cast<std::size_t>(c - win.col0);
        const bool any = !cols.empty();
        grid.depth.data()[o] = any ? part.depth.data()[i] : kNoData;
        grid.flags[o] = any ? part.flags[i] : std::uint8_t{kCellEmpty};
        if (grid.has_colour()) {
          for (int ch = 0; ch < 3; ++ch) grid.colour_rgb8[3 * o + static_cast<std::size_t>(ch)] = any ? part.colour_rgb8[3 * i + static_cast<std::size_t>(ch)] : std::uint8_t{0};
        }
        if (grid.has_intensity()) grid.intensity.data()[o] = any ? part.intensity.data()[i] : kNoData;
        ++sum.remade;
      }
    }
  };
  std::vector<std::function<void()>> tasks;
  tasks.reserve(windows.size());
  for (std::size_t b = 0; b < windows.size(); ++b) tasks.emplace_back([&remake_window, b] { remake_window(b); });
  detail::run_tasks_on_two(tasks);
  long long d_filled = 0, d_occluded = 0, d_see_through = 0, d_candidates = 0;
  std::size_t remade = 0;
  for (const WindowSums& sum : sums) {
    d_filled += sum.filled;
    d_occluded += sum.occluded;
    d_see_through += sum.see_through;
    d_candidates += sum.candidates;
    remade += sum.remade;
  }

  // The report reproject would give: the counts of the cells again, the events corrected by
  // the windows' differences.
  StageReport& rep = before.report;
  const std::size_t cells = grid.flags.size();
  const FlagCounts by_flag = count_flags(grid.flags);
  const std::size_t measured = by_flag.measured, splat_final = by_flag.splatted, upsampled = by_flag.upsampled;
  const std::size_t valid = by_flag.valid();
  const double binned = window_mode ? detail::figure_of(rep, "points_binned", 0.0) - static_cast<double>(removed_binned)
                                    : static_cast<double>(bounds.finite);
  const auto shifted = [&](const char* name, long long delta) {
    detail::set_figure(rep, name, detail::figure_of(rep, name, 0.0) + static_cast<double>(delta));
  };
  rep.count_in = n;
  rep.count_out = valid;
  detail::set_figure(rep, "points_binned", binned);
  detail::set_figure(rep, window_mode ? "points_outside_window_or_non_finite" : "points_non_finite", static_cast<double>(n) - binned);
  detail::set_figure(rep, "cells_valid", static_cast<double>(valid));
  detail::set_figure(rep, "cells_measured", static_cast<double>(measured));
  detail::set_figure(rep, "cells_splatted", static_cast<double>(splat_final));
  shifted("cells_splat_filled_empty", d_filled);
  shifted("cells_occluded_by_splat", d_occluded);
  shifted("cells_see_through", d_see_through);
  detail::set_figure(rep, "cells_upsampled", static_cast<double>(upsampled));
  if (options.upsample_factor == 0) detail::set_figure(rep, "upsample_coverage", coverage);
  shifted("see_through_candidates", d_candidates);
  rep.notes.push_back("made again only about the " + std::to_string(m) + " removed points: " + std::to_string(windows.size()) +
                      " windows, " + std::to_string(remade) + " of " + std::to_string(cells) + " nodes");
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return before;
}

}  // namespace hc::pipeline

namespace hc::pipeline {

GridGeometry grid_geometry_for_box(double x_min, double x_max, double y_min, double y_max, std::size_t finite,
                                   const ReprojectOptions& options) {
  validate_options(options);
  if (finite == 0) throw InputError("reproject: no finite input point");
  Bounds b;
  b.x_min = x_min;
  b.x_max = x_max;
  b.y_min = y_min;
  b.y_max = y_max;
  b.finite = finite;
  return make_geometry(b, options);
}

UpsampleCoverage::UpsampleCoverage(const GridGeometry& g, int k_first, int k_last) : g_(g), k_first_(k_first), k_last_(k_last) {
  if (k_first < 1 || k_last < k_first || k_last > kMaxUpsampleFactor) {
    throw std::invalid_argument("UpsampleCoverage: factors " + std::to_string(k_first) + " to " + std::to_string(k_last) +
                                " (expected 1 <= first <= last <= " + std::to_string(kMaxUpsampleFactor) + ")");
  }
  for (int k = k_first; k <= k_last; ++k) {
    const GridGeometry c = coarse_geometry(g, k);
    if (c.cols < 3 || c.rows < 3) break;  // and every larger factor's grid
    coarse_.push_back(c);
    hit_.emplace_back(hit_words(c), 0);
  }
  if (k_last < kMaxUpsampleFactor) {
    const GridGeometry next = coarse_geometry(g, k_last + 1);
    next_too_small_ = next.cols < 3 || next.rows < 3;
  }
}

void UpsampleCoverage::add(const double* xyz, std::size_t n) {
  for (std::size_t k = 0; k < coarse_.size(); ++k) mark_hits(xyz, n, coarse_[k], false, hit_[k].data());
  points_ += n;
}

std::optional<std::array<std::uint64_t, 2>> UpsampleCoverage::counts(int k) const {
  if (k < k_first_ || k > k_last_ || static_cast<std::size_t>(k - k_first_) >= coarse_.size()) return std::nullopt;
  const std::size_t at = static_cast<std::size_t>(k - k_first_);
  return coverage_counts_of_hits(hit_[at], coarse_[at]);
}

int UpsampleCoverage::factor(double* coverage) const {
  // auto_upsample_factor's loop from k_first on (the factors below it rejected already), on the
  // hits gathered so far.
  for (int k = k_first_; k <= k_last_; ++k) {
    const std::size_t at = static_cast<std::size_t>(k - k_first_);
    if (at >= coarse_.size()) return std::max(1, k - 1);  // this factor's grid is too small
    *coverage = coverage_of_hits(hit_[at], coarse_[at]);
    if (*coverage >= kAutoUpsampleCoverage) return k;
  }
  if (k_last_ == kMaxUpsampleFactor) return kMaxUpsampleFactor;
  return next_too_small_ ? k_last_ : 0;  // the next factor's grid too small: k_last, as one pass gives
}

int reproject_reach_cells(const ReprojectOptions& o, int k) {
  if (k < 1) throw ConfigError("reproject_reach_cells: upsample factor " + std::to_string(k) + " (expected >= 1)");
  const double radius = std::max(0.0, o.splat_radius_cells);
  // The splat's reach S [scan nodes] (the header's derivation): how far, Chebyshev, the nodes
  // whose binned points a node's splatted value reads can lie.
  int s = 0;
  if (radius > 0.0) {
    const int disc = static_cast<int>(std::floor(radius));
    switch (o.splat_mode) {
      case SplatMode::kDisc:
        s = disc;
        break;
      case SplatMode::kInterpolate:  // with see-through handling a tap's emptying reads its own front disc
        s = o.see_through_depth_m > 0.0 ? 2 * disc : disc;
        break;
      case SplatMode::kPlane:  // the reference disc; the gathered points' nodes lie within ⌊r + ½⌋, never farther
        s = static_cast<int>(std::floor(radius + 0.7072));
        break;
    }
  }
  const int w = o.see_through_depth_m > 0.0 ? o.see_through_window_cells : 0;
  // Until 2026-11-28 (fifty-first session) K·(2⌈r⌉ + 3 + w) + K: 11 nodes for the shipped
  // plane splats where 4 suffice.
  return k == 1 ? s + w : k * (s + w + 2);
}

}  // namespace hc::pipeline

namespace hc::pipeline::detail {

GridGeometry grid_geometry_of(const Cloud& points_m, const ReprojectOptions& options) {
  validate_options(options);
  const Bounds bounds = finite_bounds(points_m.xyz.data(), points_m.size());
  if (bounds.finite == 0) {
    throw InputError("reproject: none of the " + std::to_string(points_m.size()) +
                     " input points is finite (every point has a NaN or infinite coordinate)");
  }
  return make_geometry(bounds, options);
}

}  // namespace hc::pipeline::detail
