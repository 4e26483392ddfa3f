// Fuzz target: one image of a scene folder (scene.yaml valid) through load_scene: a float TIFF
// layer or the flags PNG. The first byte picks the file (modulo their number, in name order),
// the rest is its content.
#include "scene_common.hpp"

namespace hc::fuzz {

void scene_tiff(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return;
  const auto& layers = scene_base_layers();
  load_scene_with(layers[data[0] % layers.size()], data + 1, size - 1);
}

}  // namespace hc::fuzz
