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

/// Writes `scene` into the folder `scene_dir` (created; must not exist yet): one 32-bit float
/// TIFF per layer (`<name>.tiff`, TIFF row 0 = grid row 0 = smallest y), `flags.png` (8-bit
/// CellFlag codes) when flags are present, and `scene.yaml` with format_version, grid geometry,
/// the model→grid frame of the depth layer, the layer list, friction model and the contents of
/// `extra_yaml` (a YAML map, e.g. provenance and the resolved config) appended.
/// Callers make the write atomic by writing into a temporary folder (see StagingDir).
/// @throws hc::InputError if the folder exists or a file cannot be written (names it);
///         std::invalid_argument if layers disagree in geometry.
void write_scene(const Scene& scene, const std::filesystem::path& scene_dir,
                 const std::string& extra_yaml);

/// Name of the marker file every output folder written through StagingDir holds: it tells a
/// later run that the folder is hapticloud's own output and may be replaced.
inline constexpr const char* kOutputMarkerFile = ".hapticloud-output";

/// What StagingDir may do with an existing target that is not an earlier hapticloud output.
enum class ExistingOutput {
  kRefuse,    ///< refuse (default): a file, or a non-empty folder without the marker
  kMoveAside  ///< `--force`: keep it as `<target>.replaced-<time>` (never deleted)
};

/// A temporary sibling folder `<target>.partial-<pid>[-k]` that replaces `target` only on
/// commit(): a failed run (an exception, a crash) never leaves a half-written `target`, and an
/// existing `target` from an earlier run is only removed once the new one is complete.
/// Never deletes what hapticloud did not write: an existing `target` is replaced only if it is
/// an empty folder or an earlier output (it holds kOutputMarkerFile, or it is a pre-marker run
/// folder: only scene/, previews/, report.md, report.json with scene/scene.yaml present);
/// anything else is refused, or with ExistingOutput::kMoveAside renamed aside and kept.
class StagingDir {
 public:
  /// @throws hc::InputError if `target` is a file or a foreign non-empty folder (kRefuse; the
  ///         message names it and suggests --force) or the staging folder cannot be created.
  explicit StagingDir(std::filesystem::path target, ExistingOutput existing = ExistingOutput::kRefuse);
  ~StagingDir();  ///< removes the staging folder unless committed
  StagingDir(const StagingDir&) = delete;
  StagingDir& operator=(const StagingDir&) = delete;

  const std::filesystem::path& path() const { return staging_; }
  const std::filesystem::path& target() const { return target_; }
  /// Where a foreign target was moved by commit() (kMoveAside), else empty.
  const std::filesystem::path& moved_aside() const { return moved_aside_; }
  /// Renames staging → target (an earlier output is moved aside first, then removed; a foreign
  /// target, allowed by kMoveAside, is moved aside and kept).
  /// @throws hc::InputError naming both paths if a rename fails.
  void commit();

 private:
  std::filesystem::path target_;
  std::filesystem::path staging_;
  std::filesystem::path moved_aside_;
  bool target_is_foreign_ = false;
  bool committed_ = false;
};

/// True if `dir` is an output folder hapticloud wrote (see StagingDir). Never throws.
bool is_hapticloud_output(const std::filesystem::path& dir);

/// Loads a scene folder written by `hapticloud run`.
/// @throws hc::InputError naming the folder or file when scene.yaml or a layer is missing,
///         the format version is not kSceneFormatVersion, or a layer's size disagrees with
///         the geometry.
Scene load_scene(const std::filesystem::path& scene_dir);

}  // namespace hc::pipeline
