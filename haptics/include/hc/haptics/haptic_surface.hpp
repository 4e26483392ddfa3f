#pragma once
/// @file haptic_surface.hpp
/// What the servo loop renders: a NaN-free, padded copy of the Monge surface z = f(x, y) with
/// optional friction (μ_d, μ_s) and region-id layers, built once OFF the servo thread and then
/// queried thousands of times a second at a cost independent of the grid size.

#include "hc/common/bilinear_surface.hpp"
#include "hc/common/height_field.hpp"

#include <cstddef>
#include <cstdint>
#include <memory>

namespace hc::haptics {

/// Input layers of a HapticSurface. All fields share `depth`'s GridGeometry; only `depth` is
/// required. Pointers are read during HapticSurface's construction only (not retained).
struct SurfaceLayers {
  const HeightField* depth = nullptr;     ///< measured f(x, y) [m], NaN = no data (required)
  const HeightField* envelope = nullptr;  ///< f_b, bilateral-filtered depth [m] (optional)
  const HeightField* texture = nullptr;   ///< h = f − f_b [m] (optional; paper Sec. 3.1)
  const HeightField* mu_d = nullptr;      ///< dynamic friction coefficient [-] (optional)
  const HeightField* mu_s = nullptr;      ///< static friction coefficient [-] (optional)
  const HeightField* region_id = nullptr; ///< audio/region id per cell as float, NaN = none
};

/// Options of HapticSurface's construction.
struct SurfaceOptions {
  double texture_gain = 1.0;   ///< g ≥ 0 [-]: rendered height = envelope + g·texture (see below)
  double default_mu_d = 0.0;   ///< μ_d [-] ≥ 0 where no μ_d layer is given or it holds NaN
  double default_mu_s = 0.0;   ///< μ_s [-] ≥ 0 where no μ_s layer is given or it holds NaN
  double floor_margin_m = 0.0; ///< floor = lowest valid rendered height − this margin, ≥ 0 [m]
};

/// Friction coefficients at one point.
struct FrictionSample {
  double mu_d = 0.0;  ///< dynamic friction coefficient [-]
  double mu_s = 0.0;  ///< static friction coefficient [-]
};

/// Rendered surface owned by the haptic side.
///
/// Rendered height per sample (grid frame, metres):
///   envelope E = envelope if given, else depth − texture if texture is given, else depth;
///   texture  T = texture if given, else depth − envelope if envelope is given, else 0;
///   z = E + texture_gain·T   (texture_gain = 1 reproduces depth; 0 renders the envelope only).
/// With depth alone the gain has no effect (there is no texture to scale).
///
/// No data: a sample where any layer it needs is NaN (or ±inf) is a no-data sample. It is set to
/// the FLOOR, floor_m() = (lowest finite rendered height) − floor_margin_m. So holes are pits
/// whose walls are the bilinear slopes of the cells around them.
/// Grid border: the stored grid is padded by one ring of floor samples on every side, so the
/// surface falls from the border sample to the floor over one cell outside the input grid, and
/// is exactly the constant floor beyond that (hc::BilinearSurface extends the padded border as
/// a constant). The rendered surface is therefore defined, finite and continuous everywhere.
///
/// Friction: μ_d, μ_s are interpolated bilinearly from the node values (missing layer or NaN →
/// the default; the padding ring → the default). Region id: nearest sample, −1 = none.
/// Thread-safe for concurrent reads. Queries are real-time (noexcept, no allocation, O(1)).
class HapticSurface {
 public:
  /// Builds the padded, NaN-free copy.
  /// @param layers  depth required; every given layer must have depth's GridGeometry, rows and
  ///                cols ≥ 1, cell_size_m > 0.
  /// @param options texture_gain, defaults and margin finite and ≥ 0.
  /// @throws hc::InputError if depth is missing or a layer's geometry differs (names the layer
  ///         and both sizes); hc::DegenerateInputError if no sample has a finite rendered height;
  ///         hc::ConfigError for a negative or non-finite option (names it and its value).
  /// Real-time: no (allocates O(rows·cols)). Cost: O(rows·cols).
  HapticSurface(const SurfaceLayers& layers, const SurfaceOptions& options);

  /// f(x, y) [m] and its gradient [-] at (x_m, y_m), grid frame; always valid and finite
  /// (non-finite coordinates are clamped to the grid's corner).
  /// The same bilinear interpolant and border rule as hc::BilinearSurface over the padded grid
  /// (equal to it up to rounding; tested), written inline without divisions or NaN checks
  /// because the servo loop calls it several times per tick (always inlined: as a call it was a
  /// tenth of a tick). On a shared cell edge the gradient is that of the cell with the larger
  /// index. Real-time: yes. Cost: O(1).
  [[gnu::always_inline]] SurfaceSample sample(double x_m, double y_m) const noexcept {
    const CellAt c = locate(x_m, y_m);
    const double u = c.u, v = c.v;
    const float* r0 = data_ + c.offset;
    const double z00 = r0[0], z10 = r0[1], z01 = r0[stride_], z11 = r0[stride_ + 1];
    SurfaceSample s;
    s.z_m = (1 - u) * (1 - v) * z00 + u * (1 - v) * z10 + (1 - u) * v * z01 + u * v * z11;
    s.dz_dx = c.inside_u ? ((1 - v) * (z10 - z00) + v * (z11 - z01)) * inv_cell_ : 0.0;
    s.dz_dy = c.inside_v ? ((1 - u) * (z01 - z00) + u * (z11 - z10)) * inv_cell_ : 0.0;
    s.valid = true;
    return s;
  }

  /// f(x, y) [m]; always finite. Real-time: yes.
  double height(double x_m, double y_m) const noexcept { return sample(x_m, y_m).z_m; }

  /// True when μ_d or μ_s vary over the surface (a layer was given). Real-time: yes.
  bool has_friction_maps() const noexcept { return mu_d_ != nullptr || mu_s_ != nullptr; }

  /// μ_d and μ_s [-] at (x_m, y_m), bilinear between nodes. Real-time: yes. Cost: O(1).
  FrictionSample friction(double x_m, double y_m) const noexcept {
    if (!has_friction_maps()) return FrictionSample{options_.default_mu_d, options_.default_mu_s};
    return friction_from_maps(x_m, y_m);
  }

  /// Region id of the nearest sample (−1 = none or no region layer). Real-time: yes.
  std::int32_t region_id(double x_m, double y_m) const noexcept;

  /// Geometry of the stored (padded) grid: rows + 2, cols + 2, origin one cell before the input.
  const GridGeometry& geometry() const noexcept { return padded_geometry_; }
  /// Geometry of the input grid.
  const GridGeometry& source_geometry() const noexcept { return source_geometry_; }
  /// Padded sample (row, col) [m], 0 ≤ row < geometry().rows; never NaN. Real-time: yes.
  float node(int row, int col) const noexcept { return data_[row * stride_ + col]; }
  /// The floor height [m] used for no-data samples and the world beyond the border.
  double floor_m() const noexcept { return floor_m_; }
  /// Lowest and highest finite rendered height [m] of the input samples.
  double min_height_m() const noexcept { return min_height_m_; }
  double max_height_m() const noexcept { return max_height_m_; }
  /// Number of input samples that had no data and were set to the floor.
  std::size_t no_data_count() const noexcept { return no_data_count_; }
  const SurfaceOptions& options() const noexcept { return options_; }
  /// The underlying bilinear interpolant over the padded grid.
  const BilinearSurface& bilinear() const noexcept { return surface_; }

  HapticSurface(const HapticSurface&) = delete;
  HapticSurface& operator=(const HapticSurface&) = delete;

 private:
  /// Node storage: 2 MiB-aligned and advised for transparent huge pages on Linux, so that the
  /// servo loop's walks over large grids (4096²) do not miss the TLB on every row.
  struct FreeDeleter {
    void operator()(float* p) const noexcept;
  };
  using NodeBuffer = std::unique_ptr<float[], FreeDeleter>;
  static NodeBuffer allocate_nodes(std::size_t count, float fill);

  FrictionSample friction_from_maps(double x_m, double y_m) const noexcept;

  /// The padded grid's cell holding (x_m, y_m) and the point's place in it, for every layer
  /// (they share the padded geometry): each coordinate clamped to the grid (a NaN one to 0, the
  /// padding), the cell's lower-left node at `offset` (row-major, stride_), u, v ∈ [0, 1].
  struct CellAt {
    std::ptrdiff_t offset;
    double u, v;
    bool inside_u, inside_v;  ///< the coordinate lay within the grid (else it was clamped)
  };
  [[gnu::always_inline]] CellAt locate(double x_m, double y_m) const noexcept {
    double cu = (x_m - x0_m_) * inv_cell_;
    double cv = (y_m - y0_m_) * inv_cell_;
    const bool inside_u = cu >= 0.0 && cu <= max_u_;  // false for NaN too
    const bool inside_v = cv >= 0.0 && cv <= max_v_;
    if (!inside_u) cu = cu > max_u_ ? max_u_ : 0.0;
    if (!inside_v) cv = cv > max_v_ ? max_v_ : 0.0;
    int i = static_cast<int>(cu);
    int j = static_cast<int>(cv);
    if (i > last_i_) i = last_i_;
    if (j > last_j_) j = last_j_;
    return {static_cast<std::ptrdiff_t>(j) * stride_ + i, cu - i, cv - j, inside_u, inside_v};
  }

  // Hot-path copies of the padded grid's geometry.
  const float* data_ = nullptr;
  std::ptrdiff_t stride_ = 0;
  double x0_m_ = 0.0, y0_m_ = 0.0, inv_cell_ = 0.0, max_u_ = 0.0, max_v_ = 0.0;
  int last_i_ = 0, last_j_ = 0;

  SurfaceOptions options_{};
  GridGeometry source_geometry_{};
  GridGeometry padded_geometry_{};
  NodeBuffer nodes_;                  // padded heights, never NaN
  BilinearSurface surface_{};
  NodeBuffer mu_d_;                   // padded; null when constant (default_mu_d everywhere)
  NodeBuffer mu_s_;                   // padded; null when constant
  std::unique_ptr<std::int32_t[]> region_;  // padded; null when no region layer
  double floor_m_ = 0.0;
  double min_height_m_ = 0.0;
  double max_height_m_ = 0.0;
  std::size_t no_data_count_ = 0;
};

}  // namespace hc::haptics
