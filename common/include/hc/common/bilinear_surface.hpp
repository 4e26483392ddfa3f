#pragma once
/// @file bilinear_surface.hpp
/// The continuous Monge surface z = f(x, y) through the samples of a height field, by bilinear
/// interpolation (Sec. 3 of the paper: "bilinear interpolation is sufficient"). PCL-free and
/// allocation-free: the haptic servo loop evaluates it thousands of times a second.

#include "hc/common/height_field.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstddef>
#include <limits>

namespace hc {

/// Non-owning read-only window (ROI) on a height field's samples.
/// `data` points at the window's sample (0, 0); `row_stride` is the distance in floats between
/// two rows of the underlying field (≥ geometry.cols). geometry describes the window itself
/// (x0_m, y0_m of its first sample). The viewed field must outlive the view.
struct HeightFieldView {
  const float* data = nullptr;
  GridGeometry geometry{};
  std::ptrdiff_t row_stride = 0;

  float at(int row, int col) const { return data[row * row_stride + col]; }

  /// Whole-field view. Real-time: yes.
  static HeightFieldView of(const HeightField& field) {
    return HeightFieldView{field.data(), field.geometry(), field.cols()};
  }
  /// Window of rows × cols samples starting at (row0, col0); the caller keeps it inside the field.
  static HeightFieldView window(const HeightField& field, int row0, int col0, int rows, int cols);
};

/// Value and first derivatives of f at one point.
struct SurfaceSample {
  double z_m = 0.0;    ///< f(x, y) [m]; NaN when `valid` is false
  double dz_dx = 0.0;  ///< ∂f/∂x [-]
  double dz_dy = 0.0;  ///< ∂f/∂y [-]
  bool valid = false;  ///< false when any of the four corner samples is no-data (NaN)
};

/// Bilinear interpolant over a HeightFieldView.
///
/// Inside cell (i, j) with local coordinates u, v ∈ [0, 1]:
///   f = (1−u)(1−v)·z00 + u(1−v)·z10 + (1−u)v·z01 + uv·z11,
/// so ∂f/∂x = ((1−v)(z10−z00) + v(z11−z01)) / cell and ∂f/∂y likewise.
/// Border: x and y are clamped to the window's extent, so f continues as a constant beyond it
/// and the clamped direction has zero slope there. On a shared cell edge the gradient is that
/// of the cell with the larger index, except on the last row/column (the gradient of a
/// bilinear surface jumps across cell edges; callers that need a smooth normal blend it).
/// No data: a cell with a NaN corner gives valid = false and NaN z; callers that must never
/// see NaN (the haptic renderer) evaluate a floor-filled field instead.
/// Requires rows ≥ 2 and cols ≥ 2. Real-time: yes (noexcept, no allocation). Thread-safe: yes.
class BilinearSurface {
 public:
  BilinearSurface() = default;
  explicit BilinearSurface(const HeightFieldView& view) : view_(view) {}

  /// f and its gradient at (x_m, y_m), grid frame, metres. Inline (defined below): the
  /// pipeline's cross-check and honest check evaluate it at every input point (about 2 × 10^8
  /// times at 10^8 points), where an out-of-line call returning 32 bytes cost 4 % of the run.
  SurfaceSample sample(double x_m, double y_m) const noexcept;

  /// f(x, y) [m] only (NaN where a corner is no-data).
  double height(double x_m, double y_m) const noexcept { return sample(x_m, y_m).z_m; }

  /// The top-left corner of the cell sample(x_m, y_m) reads (grid frame, metres), as prefetch()
  /// names it: the cell is bilinear_cell's, found with a multiplication instead of its division,
  /// so it may be the neighbouring cell at a cell edge; clamped to the grid, so that it and the
  /// sample below it (one row_stride on) are always samples of the view. nullptr for a NaN
  /// coordinate, a view without data, a grid under 2 × 2 cells or a cell size not > 0. Real-time: yes.
  const float* cell_address(double x_m, double y_m) const noexcept {
    const GridGeometry& g = view_.geometry;
    if (view_.data == nullptr || g.rows < 2 || g.cols < 2 || !(g.cell_size_m > 0.0)) return nullptr;
    const double inv = 1.0 / g.cell_size_m;
    const double cu = (x_m - g.x0_m) * inv, cv = (y_m - g.y0_m) * inv;
    if (!(cu == cu) || !(cv == cv)) return nullptr;
    const int i = static_cast<int>(std::clamp(cu, 0.0, static_cast<double>(g.cols - 2)));
    const int j = static_cast<int>(std::clamp(cv, 0.0, static_cast<double>(g.rows - 2)));
    return view_.data + static_cast<std::ptrdiff_t>(j) * view_.row_stride + i;
  }

  /// Asks the processor to fetch the two grid rows sample(x_m, y_m) will read (cell_address and
  /// the sample below it), so that a loop over points in no spatial order can name a point some
  /// iterations ahead and find its cell in cache. No effect on any result; nothing for a point
  /// cell_address gives none. Real-time: yes. Added 2026-11-29 (fifty-ninth session): about a
  /// quarter of the tiled run's cross-check first pass was spent waiting on these loads at 10^8
  /// points (N = 4096, a 32 MB grid; `perf annotate`). Always inlined: GCC 12's pure-const
  /// analysis takes a function whose only effect is __builtin_prefetch for a pure one and, its
  /// result unused, deletes its calls; not inlined, this emitted no instruction at all (found
  /// 2026-11-30 in the release binary's disassembly: the fifty-ninth session's fetch ahead never ran).
  [[gnu::always_inline]] void prefetch(double x_m, double y_m) const noexcept {
    const float* top = cell_address(x_m, y_m);
    if (top == nullptr) return;
    __builtin_prefetch(top);
    __builtin_prefetch(top + view_.row_stride);
  }

  /// Upward unit normal (−f_x, −f_y, 1)/‖·‖ at (x_m, y_m); (0, 0, 1) where no data.
  Eigen::Vector3d normal(double x_m, double y_m) const noexcept;

  const HeightFieldView& view() const noexcept { return view_; }

 private:
  HeightFieldView view_{};
};

/// The cell of a grid of geometry `g` (rows, cols ≥ 2) that BilinearSurface::sample evaluates
/// at (x_m, y_m) [m, grid frame]: i, j its first column and row (i ≤ cols − 2, j ≤ rows − 2),
/// u, v ∈ [0, 1] the point's place in it after clamping to the grid's extent (outside_u,
/// outside_v: it was clamped), nan: a coordinate is NaN (no cell). Real-time: yes. Source: as
/// BilinearSurface (the index arithmetic every bilinear evaluation here shares).
struct BilinearCell {
  int i = 0, j = 0;
  double u = 0.0, v = 0.0;
  bool outside_u = false, outside_v = false, nan = false;
};
[[gnu::always_inline]] inline BilinearCell bilinear_cell(const GridGeometry& g, double x_m, double y_m) noexcept {
  const double max_u = static_cast<double>(g.cols - 1);
  const double max_v = static_cast<double>(g.rows - 1);
  double cu = (x_m - g.x0_m) / g.cell_size_m;
  double cv = (y_m - g.y0_m) / g.cell_size_m;
  BilinearCell c;
  // NaN coordinates would make the index arithmetic undefined: no cell.
  if (!(cu == cu) || !(cv == cv)) {
    c.nan = true;
    return c;
  }
  c.outside_u = cu < 0.0 || cu > max_u;  // beyond the border: constant extension
  c.outside_v = cv < 0.0 || cv > max_v;
  cu = std::clamp(cu, 0.0, max_u);
  cv = std::clamp(cv, 0.0, max_v);
  c.i = std::min(static_cast<int>(cu), g.cols - 2);
  c.j = std::min(static_cast<int>(cv), g.rows - 2);
  c.u = cu - c.i;
  c.v = cv - c.j;
  return c;
}

/// BilinearSurface::sample of the whole grid of geometry `g` (rows, cols ≥ 2), read from a
/// part of it held apart: `data` holds grid samples from (row0, col0) on, `row_stride` floats a
/// row, and must cover the cell (x_m, y_m) falls in and its far corners (rows j, j + 1 and
/// columns i, i + 1 of bilinear_cell). The index arithmetic is the
/// whole grid's, so the result is bit for bit what sample() gives on the whole grid (sample()
/// calls this with row0 = col0 = 0): the levels table of a stored pyramid evaluates a level a
/// window at a time with it (lod_report.cpp). Real-time: yes. Source: as BilinearSurface.
[[gnu::always_inline]] inline SurfaceSample bilinear_sample_of_part(const float* data, std::ptrdiff_t row_stride, int row0,
                                                                    int col0, const GridGeometry& g, double x_m,
                                                                    double y_m) noexcept;

// Always inlined: GCC 12 at -O3 left two of the pipeline's per-point calls out of line (the
// honest check's classes and the cross-check's (b) bucketing pass: about 10^8 calls each at 10^8
// points; inlined, the tiled run's honest check took 1.0 s less of CPU, forty-eighth session).
[[gnu::always_inline]] inline SurfaceSample BilinearSurface::sample(double x_m, double y_m) const noexcept {
  return bilinear_sample_of_part(view_.data, view_.row_stride, 0, 0, view_.geometry, x_m, y_m);
}

[[gnu::always_inline]] inline SurfaceSample bilinear_sample_of_part(const float* data, std::ptrdiff_t row_stride, int row0,
                                                                    int col0, const GridGeometry& g, double x_m,
                                                                    double y_m) noexcept {
  assert(g.rows >= 2 && g.cols >= 2 && g.cell_size_m > 0.0);
  const BilinearCell cell = bilinear_cell(g, x_m, y_m);
  if (cell.nan) return SurfaceSample{std::numeric_limits<double>::quiet_NaN(), 0, 0, false};
  const int i = cell.i, j = cell.j;
  const double u = cell.u, v = cell.v;
  const float* top = data + static_cast<std::ptrdiff_t>(j - row0) * row_stride + (i - col0);
  const float* bottom = top + row_stride;
  const double z00 = top[0], z10 = top[1], z01 = bottom[0], z11 = bottom[1];
  SurfaceSample s;
  s.z_m = (1 - u) * (1 - v) * z00 + u * (1 - v) * z10 + (1 - u) * v * z01 + u * v * z11;
  s.valid = !std::isnan(s.z_m);
  if (!s.valid) return s;
  const double inv = 1.0 / g.cell_size_m;
  s.dz_dx = cell.outside_u ? 0.0 : ((1 - v) * (z10 - z00) + v * (z11 - z01)) * inv;
  s.dz_dy = cell.outside_v ? 0.0 : ((1 - u) * (z01 - z00) + u * (z11 - z10)) * inv;
  return s;
}

}  // namespace hc
