#pragma once
/// @file region_map.hpp
/// Which audio region lies under a point: the region shapes rasterised once at start into a
/// label grid, so a lookup is one multiply-add and a load (O(1), real-time safe).

#include "hc/audio/audio_config.hpp"
#include "hc/common/height_field.hpp"

#include <cstdint>
#include <filesystem>
#include <vector>

namespace hc::audio {

/// A label image aligned with a grid: rows × cols labels, row 0 = grid row 0; 0 = no label.
struct LabelImage {
  int rows = 0, cols = 0;
  std::vector<std::int32_t> labels;  ///< row-major
};

/// Reads a binary PGM (P5, 8 or 16 bit) as labels. @throws hc::InputError naming the file for
/// a missing file or a malformed header/body. Real-time: no.
LabelImage read_label_pgm(const std::filesystem::path& path);

class RegionMap {
 public:
  /// An empty map: every lookup is −1.
  RegionMap() = default;

  /// Rasterises `regions` (index i → id i) at the node positions of `grid` (a sample belongs to
  /// a region when its (x, y) lies inside the shape; later regions win where they overlap).
  /// `labels` (optional) must have grid's rows × cols. If `grid` is null, the raster covers the
  /// union of the boxes and polygons with cells of `cell_m` (label regions then need a grid).
  /// @throws hc::ConfigError for a label region without labels or grid, a label image whose
  ///         size differs from the grid's (both sizes named), a degenerate box or polygon
  ///         (naming the region), or a raster above 64 M cells. Real-time: no.
  RegionMap(const std::vector<RegionConfig>& regions, const GridGeometry* grid, double cell_m,
            const LabelImage* labels = nullptr);

  /// Region index under (x_m, y_m), grid frame: the nearest raster sample; −1 outside every
  /// region or outside the raster, or for non-finite input. Real-time: yes. Cost: O(1).
  std::int32_t lookup(double x_m, double y_m) const noexcept {
    if (ids_.empty()) return -1;
    const double cu = (x_m - geometry_.x0_m) * inv_cell_ + 0.5;
    const double cv = (y_m - geometry_.y0_m) * inv_cell_ + 0.5;
    if (!(cu >= 0.0 && cv >= 0.0 && cu < geometry_.cols && cv < geometry_.rows)) return -1;
    return ids_[static_cast<std::size_t>(static_cast<int>(cv)) * static_cast<std::size_t>(geometry_.cols) +
                static_cast<std::size_t>(static_cast<int>(cu))];
  }

  /// The raster as a HeightField (region id as float, NaN = none) on `grid`, for
  /// haptics::SurfaceLayers::region_id (so snapshots and events carry the same ids).
  /// Real-time: no.
  HeightField to_layer(const GridGeometry& grid) const;

  const GridGeometry& geometry() const noexcept { return geometry_; }
  /// Samples per region id (for reports and tests).
  std::vector<std::size_t> counts(std::size_t region_count) const;

 private:
  GridGeometry geometry_{};
  double inv_cell_ = 0.0;
  std::vector<std::int32_t> ids_;
};

}  // namespace hc::audio
