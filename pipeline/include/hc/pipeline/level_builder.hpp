#pragma once
/// @file level_builder.hpp
/// The streaming level builder (issue 14, "a tiled scene"): the coarser levels of detail of a
/// tiled scene folder made tile by tile from the stored level above, in memory bounded by two
/// tiles and their halos (two threads), not by the grid. Equal bit for bit to the in-memory
/// pyramid (LodPyramid, lod.hpp). docs/scale.md, "The tiled scene".

#include "hc/common/height_field.hpp"

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace hc::pipeline {

/// What build_stored_levels did.
struct StoredLevelsReport {
  int levels_built = 0;         ///< levels k ≥ 1 written (stored_levels − 1)
  bool level0_layers = false;   ///< level 0 had no surface layers: they were computed (where Level0Layers says)
  std::uint64_t bytes = 0;      ///< bytes of tile data written (tiles without bytes count 0)
  /// Largest scratch file on disk [bytes]: a level's s, 8 bytes a sample, for its tiles with data only.
  std::uint64_t scratch_bytes = 0;
  /// Largest buffers held at once [bytes]: two blocks with their halos (one per thread) and the
  /// working images of the layers, or the median's candidates (at most 4 M doubles).
  std::size_t peak_buffer_bytes = 0;
  double seconds = 0.0;
  /// Per level built (index k − 1, or k for a level 0 given layers): seconds of the depth pass
  /// (mean heights, decimation) and of the layers (mean, fill range, envelope, median, friction).
  std::vector<double> depth_seconds, layers_seconds;
};

/// Progress: (what, fraction done in [0, 1]) after every row of tiles.
using LevelProgress = std::function<void(const std::string& what, double fraction)>;

/// Where build_stored_levels puts the surface layers it computes for a level 0 that has none.
enum class Level0Layers {
  /// `levels/L0/<name>.tiff`, beside the coarser levels; level 0's own files and scene.yaml are
  /// left as written (a scene made with layers off: LodPyramid::open_stored reads them there).
  kLevelsFolder,
  /// `<name>.tiff` beside depth.tiff, listed in scene.yaml (add_level0_surface_layers,
  /// scene_io.hpp): the scene is then the one write_scene writes from a scene with its layers
  /// (a tiled run that left level 0's layers to the builder: SurfaceLayersAt, run.hpp).
  kSceneFolder,
};

/// Writes levels 1 .. stored_levels − 1 of the tiled scene folder `scene_dir` (format 3, as
/// write_scene with SceneStorage{tile_cells, stored_levels}), whose level 0 is on disk and whose
/// `levels/` folder does not exist yet, into `levels/L<k>/` (depth, envelope, texture, mu_d,
/// mu_s and, when level 0 has them, cell_error and colour; square tiles of the scene's
/// tile_cells, all-NaN tiles sparse). Level 0 without surface layers gets them in `levels/L0/`.
/// The levels are those LodPyramid builds from the scene's layers with the scene's
/// layer_options and lod options (scene.yaml), bit for bit: level k's depth, colour and error by
/// downsample_2x_block from level k − 1's stored tiles plus the kernel's halo; its layers by
/// surface_layers_block from level k's stored depth plus surface_layers_halo_cells, with the
/// level-wide values: the mean heights and the band of valid depths (exact sums, ExactFloatSum:
/// level 0's in one pass over its tiles, every coarser level's while its tiles are written), the
/// fill range (a pass over the blocks), and the exact median of s for `level_median` (radix
/// selection over a scratch file of s in `scratch_dir`, removed at the end). Two threads make
/// pairs of tiles of a row; the tiles are written in order. Each level is read and written once
/// or a few times; nothing holds a whole level or a row of it.
/// With `level0` kSceneFolder a level 0 without surface layers gets them in the scene folder
/// itself and listed in scene.yaml (see Level0Layers); the files equal those of kLevelsFolder.
/// On an error the `levels/` folder it made is removed, and so are level 0's layer files it
/// wrote in the scene folder (scene.yaml is then unchanged; the folder is otherwise untouched).
/// @throws hc::InputError naming the folder or file: not a tiled scene, `levels/` already there,
///         a layer file that cannot be read or written, an infinite level-0 depth (naming the sample),
///         a scratch file that cannot be made;
///         hc::ConfigError for the scene's options out of range.
StoredLevelsReport build_stored_levels(const std::filesystem::path& scene_dir, const std::filesystem::path& scratch_dir,
                                       const LevelProgress& progress = {},
                                       Level0Layers level0 = Level0Layers::kLevelsFolder);

}  // namespace hc::pipeline
