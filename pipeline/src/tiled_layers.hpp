#pragma once
// Tiled layer files of a scene (issue 14): shared by scene_io.cpp (level 0) and lod.cpp (the
// stored levels). Private to hc::pipeline.

#include "image_io.hpp"

#include "hc/common/height_field.hpp"

#include <filesystem>
#include <functional>
#include <string>

namespace hc::pipeline::detail {

/// Writes one layer of grid `g` (rows·cols samples, row-major, × 3 bytes for RGB) as a tiled
/// TIFF (write_tiled_tiff: square tiles of `tile_cells`, all-NaN tiles sparse), calling
/// `after_tile_row` (when set) after each row of tiles.
/// @throws hc::InputError naming the file and why (no space left, a libtiff error).
void write_tiled_layer(const std::filesystem::path& file, const void* values, const GridGeometry& g, int tile_cells,
                       TileSamples samples, const std::function<void()>& after_tile_row = {});

/// Reads the whole tiled TIFF `file` of grid `g` (as write_tiled_layer writes it) into the
/// memory `buffer()` returns, which it calls only once the file is known to hold g.cols × g.rows
/// samples of `samples` (so nothing is allocated from a size the file does not have): g.rows·g.cols
/// samples, row-major, × 3 bytes for RGB; tiles without bytes read as NaN or 0.
/// @return "" or why not (not a tiled TIFF of `samples`, another size, a libtiff read error);
/// callers name the file and the layer in their error.
std::string read_tiled_layer(const std::filesystem::path& file, const GridGeometry& g, TileSamples samples,
                             const std::function<void*()>& buffer);

/// The file of layer `name` ("depth", ..., "colour") of stored level `level` in a tiled scene:
/// `<scene>/<name>.tiff` for level 0, `<scene>/levels/L<level>/<name>.tiff` above.
std::filesystem::path stored_layer_file(const std::filesystem::path& scene_dir, int level, const std::string& name);

}  // namespace hc::pipeline::detail
