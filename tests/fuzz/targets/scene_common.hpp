#pragma once
// A scene folder for the two scene targets: the small valid scene in tests/fuzz/scene_base
// (scene.yaml + float TIFF layers) copied to a scratch folder, with one file replaced by the
// fuzz input; then hc::pipeline::load_scene (hc/pipeline/scene_io.hpp) on that folder.

#include "../fuzz_support.hpp"

#include <filesystem>
#include <string>

namespace hc::fuzz {

/// The image files of scene_base (TIFF layers and the flags PNG), sorted by name (fixed, so an
/// input maps to one file).
const std::vector<std::string>& scene_base_layers();

/// Copies scene_base into scratch_dir()/scene (once), writes `data` over `file` (restoring the
/// file replaced by the previous call) and loads the folder. hc::Error is swallowed.
void load_scene_with(const std::string& file, const std::uint8_t* data, std::size_t size);

}  // namespace hc::fuzz
