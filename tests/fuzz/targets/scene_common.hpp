#pragma once
// A scene folder for the two scene targets: the small valid scene in tests/fuzz/scene_base
// (scene.yaml + float TIFF layers) copied to a scratch folder, with one file replaced by the
// fuzz input; then hc::pipeline::load_scene (hc/pipeline/scene_io.hpp) on that folder.

#include "../fuzz_support.hpp"

#include <filesystem>
#include <string>
#include <vector>

namespace hc::fuzz {

/// The image files of scene_base (TIFF layers and the flags PNG), sorted by name (fixed, so an
/// input maps to one file).
const std::vector<std::string>& scene_base_layers();

/// Copies scene_base into scratch_dir()/scene (once), writes `data` over `file` (restoring the
/// file replaced by the previous call) and loads the folder. hc::Error is swallowed.
void load_scene_with(const std::string& file, const std::uint8_t* data, std::size_t size);

/// The image files of scene_tiled_base (a tiled scene, format 3: level 0 and levels/L<k>/), as
/// paths relative to it, sorted by name.
const std::vector<std::string>& tiled_scene_files();

/// Copies scene_tiled_base into scratch_dir()/scene_tiled (once), writes `data` over `file`
/// (restoring the file replaced by the previous call), loads the folder whole, then opens its
/// stored levels (LodPyramid::open_stored) and reads windows of every level and the coarsest
/// level whole. hc::Error is swallowed.
void open_tiled_scene_with(const std::string& file, const std::uint8_t* data, std::size_t size);

}  // namespace hc::fuzz
