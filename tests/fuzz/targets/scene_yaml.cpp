// Fuzz target: scene.yaml of a scene folder (its TIFF layers valid) through load_scene.
#include "scene_common.hpp"

namespace hc::fuzz {

void scene_yaml(const std::uint8_t* data, std::size_t size) { load_scene_with("scene.yaml", data, size); }

}  // namespace hc::fuzz
