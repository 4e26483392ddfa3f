#pragma once
/// @file scene_io.hpp
/// The scene on disk: the one data contract between the offline pipeline and the online
/// renderer. A folder holding one 32-bit float TIFF per layer (metres or [-], NaN = no data,
/// row 0 = smallest y) and `scene.yaml` (format version, grid geometry, frame, provenance).

#include "hc/common/height_field.hpp"

#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

namespace hc::pipeline {

inline constexpr int kSceneFormatVersion = 1;

/// A scene as loaded: named float layers sharing one GridGeometry, plus metadata.
/// Layer names: "depth" (always), and when present "envelope", "texture", "mu_d", "mu_s",
/// "cell_error" (cross-check, metres).
struct Scene {
  std::map<std::string, HeightField> layers;
  std::vector<std::uint8_t> flags;  ///< CellFlag per cell (reproject.hpp); may be empty
  std::string friction_model;       ///< "paper" | "curvature" | "" (no friction layers)
  std::string metadata_yaml;        ///< the full scene.yaml text (provenance, config)

  const HeightField& depth() const { return layers.at("depth"); }
  bool has(const std::string& layer) const { return layers.count(layer) != 0; }
};

/// Loads a scene folder written by `hapticloud run`.
/// @throws hc::InputError naming the folder or file when scene.yaml or a layer is missing,
///         the format version is not kSceneFormatVersion, or a layer's size disagrees with
///         the geometry.
Scene load_scene(const std::filesystem::path& scene_dir);

}  // namespace hc::pipeline
