#pragma once
/// @file preview.hpp
/// PNG previews of grid layers for people: colour-mapped values with a legend, and a
/// hillshade. Images are flipped so +y points up; no-data cells are drawn grey.

#include "hc/common/height_field.hpp"

#include <filesystem>
#include <string>

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

}  // namespace hc::pipeline
