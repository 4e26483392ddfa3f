// Fuzz target: one file of a tiled scene folder (format 3; scene.yaml valid) through load_scene
// and LodPyramid::open_stored with window reads at every level: a tiled float TIFF layer of any
// level, or the flags PNG. The first byte picks the file (modulo their number, in name order),
// the rest is its content.
#include "scene_common.hpp"

namespace hc::fuzz {

void scene_tiled(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return;
  const auto& files = tiled_scene_files();
  open_tiled_scene_with(files[data[0] % files.size()], data + 1, size - 1);
}

}  // namespace hc::fuzz
