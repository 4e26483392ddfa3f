#pragma once
/// @file preview.hpp
/// PNG previews of grid layers for people: colour-mapped values with a legend, and a
/// hillshade. Images are flipped so +y points up; no-data cells are drawn grey.

#include "hc/common/height_field.hpp"

#include <filesystem>
#include <cstdint>
#include <string>
#include <vector>

namespace hc::pipeline {

/// Writes `layer` colour-mapped (turbo) between its 1st and 99th percentile, with a legend bar
/// labelled in `unit` after multiplying values by `scale` (e.g. 1000 for metres → mm).
/// Grids smaller than 400 px on their long side are enlarged (nearest neighbour).
/// @throws hc::InputError naming the file if it cannot be written.
void write_colour_preview(const HeightField& layer, const std::filesystem::path& png,
                          const std::string& title, const std::string& unit, double scale);

/// Writes a hillshade of a height field (light from the north-west, 45° altitude; Horn's
/// gradient on the real cell size). Source: standard GIS hillshade (Horn 1981).
/// @throws hc::InputError naming the file if it cannot be written.
void write_hillshade_preview(const HeightField& depth_m, const std::filesystem::path& png);

/// Writes the scan's colour per cell (`colour_rgb8`: rows·cols·3 bytes, R G B, row-major like
/// `depth_m`); with `shaded`, each channel is multiplied by the hillshade grey level / 255 of
/// write_hillshade_preview (colour over hillshade). Cells whose depth is no data are grey.
/// @throws hc::InputError naming the file if colour_rgb8 does not match the grid or the file
///         cannot be written.
void write_rgb_preview(const HeightField& depth_m, const std::vector<std::uint8_t>& colour_rgb8,
                       const std::filesystem::path& png, bool shaded);

}  // namespace hc::pipeline
