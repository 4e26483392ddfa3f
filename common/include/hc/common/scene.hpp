#pragma once
/// @file scene.hpp
/// The scene: the one typed data contract between the offline pipeline (which builds it), the
/// scene folder on disk (hc::pipeline::write_scene / read_scene) and the online side (levels of
/// detail, the haptic surface, the viewer). Eigen only. See docs/architecture.md, "Data contract".
///
/// A Scene holds one GridGeometry shared by every layer, the model → grid transform, a fixed set
/// of layers (depth always; the others empty when absent), and typed metadata: the friction model
/// and the layer and level-of-detail options the layers were made with (so levels ≥ 1 are
/// computed the same way), and the provenance (tool, inputs with SHA-256, recentring offset, the
/// resolved config as text for the record only — nothing parses it back).

#include "hc/common/height_field.hpp"

#include <Eigen/Geometry>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace hc {

/// `paper`: μ_d = 1/(R·√(H² + K²)) (the paper's Eq. for μ_d; shrinks with curvature);
/// `curvature`: μ_d = μ_min + c·√(H² + K²) (grows with curvature, as the paper's text says).
/// Both are clamped to [μ_min, μ_max]; see docs/friction.md.
enum class FrictionModel { kPaper, kCurvature };

/// In which units the resultant curvature s = √(H² + K²) enters the friction model
/// (`layers.friction.scale`, docs/friction.md "Per level, in the units the hand feels"):
/// - `scene`: H [1/m], K [1/m²] of the grid in scene metres (the paper's formula read in SI; the
///   behaviour before per-level scaling);
/// - `device`: H and K in device metres: the haptic window of `lod.window_cells` samples of the
///   level (side (n − 1)·Δ_L) spans the workspace's inscribed sphere diameter 2R, so lengths scale
///   by σ_L = 2R / ((n − 1)·Δ_L) and H_dev = H/σ_L, K_dev = K/σ_L²;
/// - `level_median` (default): s in device units divided by its median over the level's cells
///   with s > 0, ŝ = s/s̃_L (dimensionless; s̃_L is floored at 1/(R·μ_max), so a texture flat to
///   the hand is not stretched over the range); the paper model becomes μ_d = √(μ_min·μ_max)/ŝ and
///   the curvature model μ_d = μ_min + ½(μ_max − μ_min)·ŝ, so the level's median cell sits
///   mid-range and fewer than half the cells can reach either clamp.
enum class FrictionScale { kScene, kDevice, kLevelMedian };

/// An axis-aligned box region (grid frame, metres) with its own μ_s.
struct StaticFrictionRegion {
  double x_min_m = 0, y_min_m = 0, x_max_m = 0, y_max_m = 0;
  double mu_s = 0.0;  ///< [-], ≥ 0
  bool operator==(const StaticFrictionRegion&) const = default;
};

/// Options of the surface-layer stage (config keys `layers.*`, docs/config.md).
/// Source: paper Sec. 3.1 (bilateral envelope, texture) and 3.2 (curvature, μ_d).
struct SurfaceLayerOptions {
  double sigma_space_cells = 3.0;   ///< bilateral σ_s [cells], > 0
  double sigma_range_m = 0.001;     ///< bilateral σ_r [m], > 0
  FrictionModel friction_model = FrictionModel::kPaper;
  double mu_min = 0.05;             ///< lower clamp of μ_d [-], ≥ 0
  double mu_max = 0.6;              ///< upper clamp of μ_d [-], ≥ μ_min
  double workspace_radius_m = 0.05; ///< R: radius of the largest sphere inscribed in the
                                    ///< haptic workspace [m] (paper model), > 0
  double curvature_gain_m = 0.01;   ///< c in the curvature model [m] (μ per 1/m), ≥ 0
  FrictionScale friction_scale = FrictionScale::kLevelMedian;  ///< units of √(H²+K²), see above
  double mu_s = 0.2;                ///< default static friction μ_s [-], ≥ 0
  std::vector<StaticFrictionRegion> mu_s_regions;  ///< later regions override earlier ones
  bool operator==(const SurfaceLayerOptions&) const = default;
};

/// Options of the level-of-detail pyramid, its cache and the haptic window (config keys
/// `lod.*`, docs/config.md and docs/lod.md). Source: paper Sec. 4.1 ("adaptive scaling").
struct LodOptions {
  int min_cells = 64;                ///< lod.min_cells: a level is made only while its longer
                                     ///< side stays ≥ this [samples], [2, 65536]
  double valid_fraction = 0.5;       ///< lod.valid_fraction: a coarse sample is valid only if the
                                     ///< smoothing weight of its valid fine samples is at least this
                                     ///< fraction of the weight of its fine samples inside the grid, (0, 1]
  double antialias_sigma_cells = 1.0;///< lod.antialias_sigma_cells: Gaussian σ of the smoothing
                                     ///< before each 2× decimation [fine samples], [0.5, 4]
  double memory_budget_mb = 384.0;   ///< lod.memory_budget_mb: bound on the cache of built levels
                                     ///< and windows [MiB] (the finest level is held outside it), (0, 1e6]
  int window_cells = 200;            ///< lod.window_cells: haptic window side [samples], [2, 4096]
  bool report = false;               ///< lod.report: levels table in the run report, by request
                                     ///< (`hapticloud levels SCENE` makes it for a written scene)
  bool report_cross_check = true;    ///< lod.report_cross_check: cross-check every level against the points
  std::size_t report_sample_points = 200000;  ///< lod.report_sample_points: that cross-check's (a) on
                                     ///< every ⌈N / this⌉-th point (0 = every point); support over all
  bool operator==(const LodOptions&) const = default;
};

/// One input file of a scene, as read.
struct SceneInput {
  std::string file;    ///< path as given in the config (resolved against the config's folder)
  std::string sha256;  ///< lowercase hex SHA-256 of the file's bytes
  bool operator==(const SceneInput&) const = default;
};

/// Where a scene came from.
struct SceneProvenance {
  std::string tool;                     ///< "hapticloud <version>"
  std::string config_file;              ///< the run config's path as given
  std::string units;                    ///< input.units of the scan ("m", "cm", "mm")
  Eigen::Vector3d recentre_offset_m = Eigen::Vector3d::Zero();  ///< subtracted centre [m], file frame
  std::vector<SceneInput> inputs;       ///< scans (and the .conf), with checksums
  std::string synthetic;                ///< generated surface kind, or empty
  std::string crs;                      ///< the scan's coordinate reference system as text (LAS WKT or
                                        ///< GeoTIFF key summary, E57 coordinateMetadata), or empty
  std::string resolved_config_yaml;     ///< the resolved run config, for the record only
};

/// The layers of a scene. Every non-empty HeightField has the scene's geometry and model_to_grid;
/// NaN = no data. `depth` is always present; the others are empty (rows = cols = 0) when absent.
struct SceneLayers {
  HeightField depth;        ///< f(x, y) [m], grid frame (larger z nearer the viewer)
  HeightField envelope;     ///< f_b, bilateral envelope of f [m] (paper Sec. 3.1)
  HeightField texture;      ///< h = f − f_b [m]
  HeightField mu_d;         ///< dynamic friction coefficient [-] (paper Sec. 3.2)
  HeightField mu_s;         ///< static friction coefficient [-]
  HeightField cell_error;   ///< cross-check: grid sample to nearest point [m]
  HeightField region_id;    ///< sounding/semantic region per cell as float, NaN = none
  HeightField intensity;    ///< scanner return intensity [-] (as stored by the scanner)
  /// CellFlag per cell (hc/pipeline/reproject.hpp), or empty; on the heap, or in a scratch
  /// file's mapping (cell_buffer.hpp; a tiled run's level 0)
  CellBuffer<std::uint8_t> flags;
  CellBuffer<std::uint8_t> colour_rgb8;  ///< rows·cols·3 bytes, R G B per cell, or empty (as `flags`)

  /// True when envelope, texture, μ_d and μ_s are all present (the haptic surface layers).
  bool has_surface_layers() const noexcept {
    return envelope.rows() > 0 && texture.rows() > 0 && mu_d.rows() > 0 && mu_s.rows() > 0;
  }
  /// Every file-backed layer's pages given back to the kernel (CellBuffer::release_resident;
  /// nothing for layers on the heap). Thread-safe with concurrent reads and writes.
  void release_resident() const {
    for (const HeightField* f : {&depth, &envelope, &texture, &mu_d, &mu_s, &cell_error, &region_id, &intensity}) {
      f->values().release_resident();
    }
    flags.release_resident();
    colour_rgb8.release_resident();
  }
};

/// How a scene folder stores its layers (issue 14; docs/scale.md "The tiled scene").
struct SceneStorage {
  /// 0: every layer one whole-grid TIFF in strips (format 2). Else the side of the square tiles
  /// [samples] of every layer TIFF (format 3), with the coarser levels of detail stored beside.
  int tile_cells = 0;
  /// Levels of detail stored (level 0 in the scene folder, level k ≥ 1 in levels/L<k>/); 0 when
  /// the folder stores level 0 only.
  int stored_levels = 0;
  /// True when the folder is tiled and stores its levels (LodPyramid::open_stored can open it).
  bool stores_levels() const noexcept { return tile_cells > 0 && stored_levels > 0; }
  bool operator==(const SceneStorage&) const = default;
};

/// A whole scene: geometry, frame, layers and metadata.
struct Scene {
  GridGeometry geometry;                                     ///< shared by every layer
  Eigen::Affine3d model_to_grid = Eigen::Affine3d::Identity();  ///< file units → grid frame [m]
  SceneLayers layers;
  std::optional<FrictionModel> friction_model;  ///< set when μ_d was computed
  SurfaceLayerOptions layer_options;            ///< the options that made the layers
  LodOptions lod;                               ///< the level-of-detail options of the run
  SceneProvenance provenance;
  int format_version = 0;               ///< on a loaded scene: the folder's format_version
  SceneStorage storage;                 ///< on a loaded scene: how its folder stores the layers
  std::vector<std::string> notes;       ///< what loading assumed (e.g. defaults for an old folder)
  /// On a loaded scene: the folder load_scene read (as given to it), so that what the folder
  /// stores beside the layers (points_sample.bin, the levels table's points) can be found from
  /// the Scene; empty on a scene built in memory. Not written (fifty-seventh session, 2026-11-29).
  std::filesystem::path loaded_from;

  const HeightField& depth() const noexcept { return layers.depth; }
};

}  // namespace hc
