// Fuzz target: one file of a tiled scene folder (format 3, scene.yaml valid; made by
// `tiled_scene_bench generate DIR --rows 40 --cols 44 --band 30 --tile 16 --colour --min-cells 8
// --window-cells 24`) through load_scene and LodPyramid::open_stored with window reads at every
// level: any tiled TIFF of any level (float layers, the cross-check error and the colour), and
// points_sample.bin (the levels table's stored points, read_level_point_sample; added to the
// base by hand, 5 points standing for 50). The first byte picks the file (modulo their number:
// the images in name order, then the .bin), the rest is its content.
#include "scene_common.hpp"

namespace hc::fuzz {

void scene_tiled(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return;
  const auto& files = tiled_scene_files();
  open_tiled_scene_with(files[data[0] % files.size()], data + 1, size - 1);
}

}  // namespace hc::fuzz
