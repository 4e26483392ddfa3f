#pragma once
/// @file preview.hpp
/// PNG previews of grid layers for people: colour-mapped values with a legend, and a
/// hillshade. Images are flipped so +y points up; no-data cells are drawn grey.

#include "hc/common/height_field.hpp"

#include <span>
#include <array>
#include <filesystem>
#include <cstdint>
#include <string>
#include <vector>

namespace hc::pipeline {

/// The colour bar of a layer: the robust range (1st and 99th percentiles of the finite values,
/// nearest rank) and its labels, in the display unit (values × scale).
struct ColourBar {
  double lo = 0.0, hi = 1.0;          ///< colour range [layer unit]
  double min = 0.0, max = 1.0;        ///< finite extremes [layer unit]
  bool clipped_low = false, clipped_high = false;  ///< values beyond the range exist
  std::string lo_label, hi_label;     ///< lo·scale and hi·scale (hc::format_number), with as many
                                      ///< significant digits (3..12) as it takes for them to differ
  std::string min_label, max_label;   ///< "min …" / "max …" when clipped, else empty
};

/// The colour bar of `layer` (NaN and infinities ignored; an all-NaN layer gives 0..1).
/// Labels stay readable whatever the range: a +500 m offset with a 0.1 mm range reads
/// "500000.00" and "500000.10", not "5e+05" twice. Thread-safe.
ColourBar colour_bar(const HeightField& layer, double scale);

/// Marks given on level 0 ((row, col) samples) moved to level `level` of the level-of-detail
/// pyramid, whose grid is `level_grid` (lod_level_geometry: level k's sample j lies on level
/// 0's sample j·2^k): the nearest level-k sample, a tie to the larger index, clamped to the
/// level's last row and column. Level 0 returns the marks unchanged. Shapes: one output per
/// input mark. @throws std::invalid_argument for a level outside [0, 30].
std::vector<std::array<int, 2>> marks_on_level(const std::vector<std::array<int, 2>>& marks, int level,
                                               const GridGeometry& level_grid);

/// Writes `layer` colour-mapped (turbo) between its 1st and 99th percentile (colour_bar), with a
/// legend bar labelled in `unit` after multiplying values by `scale` (e.g. 1000 for metres → mm);
/// clipped ends are marked by a triangle on the bar and labelled with the true min / max.
/// `marks` (row, col) are circled in magenta (spikes, pits, islands). Grids smaller than 400 px
/// on their long side are enlarged (nearest neighbour). Memory: besides `layer`, a copy of its
/// finite values (4 bytes a cell, for the percentiles; freed before the image) and then the
/// image only (3 bytes a pixel): the colours are drawn straight into it.
/// @throws hc::InputError naming the file if it cannot be written or `layer` has no sample.
void write_colour_preview(const HeightField& layer, const std::filesystem::path& png,
                          const std::string& title, const std::string& unit, double scale,
                          const std::vector<std::array<int, 2>>& marks = {});

/// Writes a hillshade of a height field (light from the north-west, 45° altitude; Horn's
/// gradient on the real cell size) under a two-line title strip (44 px): `title`, then the
/// light, "grey: no data" and "+y up" (the image widens when a line needs it). Source: standard GIS
/// hillshade (Horn 1981).
/// @throws hc::InputError naming the file if it cannot be written.
void write_hillshade_preview(const HeightField& depth_m, const std::filesystem::path& png,
                             const std::string& title = "hillshade");

/// Writes the hillshades of `fields` side by side at one height (the first's, at most
/// `max_height_px`; nearest-neighbour enlargement, area averaging when reduced), each under a
/// full-size title strip from `titles` (the levels-of-detail image).
/// @throws std::invalid_argument when the counts differ or are 0; hc::InputError naming the
///         file if it cannot be written.
void write_hillshades_side_by_side(const std::vector<const HeightField*>& fields, const std::vector<std::string>& titles,
                                   const std::filesystem::path& png, int max_height_px = 600);

/// Writes the scan's colour per cell (`colour_rgb8`: rows·cols·3 bytes, R G B, row-major like
/// `depth_m`); with `shaded`, each channel is multiplied by the hillshade grey level / 255 of
/// write_hillshade_preview (colour over hillshade). Cells whose depth is no data are grey.
/// @throws hc::InputError naming the file if colour_rgb8 does not match the grid or the file
///         cannot be written.
void write_rgb_preview(const HeightField& depth_m, std::span<const std::uint8_t> colour_rgb8,
                       const std::filesystem::path& png, bool shaded);

}  // namespace hc::pipeline
