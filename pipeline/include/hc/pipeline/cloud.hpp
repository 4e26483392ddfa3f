#pragma once
/// @file cloud.hpp
/// The point cloud and stage-report types that flow through the offline pipeline.

#include <Eigen/Core>

#include <cstddef>
#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace hc::pipeline {

/// An 8-bit RGB texture image as decoded from its file (OBJ + MTL `map_Kd`): row 0 is the top
/// row of the image, pixel (x, y) at rgb[3·(y·width + x) + {0, 1, 2}].
struct TextureImage {
  int width = 0, height = 0;
  std::vector<std::uint8_t> rgb;  ///< width·height·3 bytes
  std::string source;             ///< the image file, for reports
};

/// Triangles on the points of a Cloud (a mesh read from PLY `face` or OBJ `f`, polygons
/// fan-split (v0, v_k, v_k+1)). Indices refer to the Cloud's points, so every point transform
/// (units, recentring, the rigid + uniform-scale view transform) keeps the faces valid.
struct Mesh {
  std::vector<std::array<std::uint32_t, 3>> triangles;  ///< point indices per triangle
  /// Empty, or 6 floats per triangle: (u, v) of its three corners, OBJ convention (u to the
  /// right, v up: v = 0 is the BOTTOM row of the image) [-].
  std::vector<float> corner_uv;
  /// The image the corner_uv address (shared between copies: read-only), or null.
  std::shared_ptr<const TextureImage> texture;

  bool empty() const { return triangles.empty(); }
  bool has_texture() const { return texture != nullptr && corner_uv.size() == 6 * triangles.size(); }
};

/// A point cloud in double precision: 3 × N coordinates. The frame and unit depend on the stage
/// (file units right after ingest; metres from `to_metres_and_recentre` on). Double precision
/// keeps georeferenced offsets (10^5 to 10^6 m) exact until recentring.
struct Cloud {
  Eigen::Matrix3Xd xyz;                ///< 3 × N coordinates
  std::vector<std::uint16_t> scan_id;  ///< empty, or N source-scan indices (multi-view merges)
  /// Per-point attributes, each empty or of size N (scanner formats fill what they carry):
  std::vector<float> intensity;        ///< return intensity as stored by the scanner [-]
                                       ///< (E57 and PTX normalised to [0, 1], LAS raw 0..65535)
  std::vector<std::uint8_t> rgb;       ///< empty or 3·N bytes: R G B per point, 8 bit
  std::vector<std::int32_t> row, col;  ///< organised scans (E57 rowIndex/columnIndex, PTX):
                                       ///< the point's row and column in its scan's grid
  /// Empty or 3·N: the point's surface normal (nx ny nz, in the same frame as xyz; the view
  /// transform rotates it, units and recentring leave it) as given by its source (today a PCL
  /// cloud with normals, hc/pcl/conversions.hpp), not normalised or re-estimated here.
  std::vector<float> normal;
  std::vector<float> curvature;        ///< empty or N: PCL's surface curvature λ0/(λ0+λ1+λ2) [-], with normal
  Mesh mesh;                           ///< faces on the points (meshes), or empty
  /// True when the file stored x, y and z as 32-bit floats (PLY float/float32, PCD F 4, E57
  /// Float precision="single" without a pose), so coordinates carry 24 significant bits:
  /// a georeferenced magnitude |x| resolves only about |x|·2⁻²⁴ (build_scene warns, docs/config.md).
  bool float32_xyz = false;
  /// The file's coordinate reference system as text, or empty: LAS OGC WKT (VLR LASF_Projection
  /// 2112) verbatim, or "GeoTIFF keys: ..." (VLRs 34735–34737) summarised; E57 the root's
  /// coordinateMetadata string (ASTM E2807 §8.4). Carried into SceneProvenance::crs.
  std::string crs;

  std::size_t size() const { return static_cast<std::size_t>(xyz.cols()); }
  bool has_scan_id() const { return !scan_id.empty(); }
  bool has_intensity() const { return !intensity.empty(); }
  bool has_rgb() const { return !rgb.empty(); }
  bool has_grid_index() const { return !row.empty(); }
  bool has_normals() const { return !normal.empty(); }
  bool has_mesh() const { return !mesh.empty(); }
  /// Keeps the points whose keep[i] is true, in order (every attribute follows; a triangle
  /// survives only if all three of its points do, its indices renumbered).
  /// keep.size() == size().
  void keep_if(const std::vector<bool>& keep);
  /// Appends `other`'s points; an attribute that only one side has is dropped (the result must
  /// hold it for every point or for none). Triangles of both are kept (other's renumbered); the
  /// texture only when both share the same image (else "texture" is dropped, with the UVs).
  /// Returns the names of the attributes dropped.
  std::vector<std::string> append(const Cloud& other);
};

/// Points a stage took out of a cloud, kept for a later stage that updates what it made from
/// the cloud before (reproject_after_removal): their coordinates and their places in that cloud.
struct RemovedPoints {
  std::vector<double> xyz;      ///< 3 per point: x y z [m] in the cloud's frame
  std::vector<std::size_t> at;  ///< each point's column in the cloud before the removal, increasing
  /// Far-cluster removal only (remove_far_clusters): each point's cluster, numbered 0, 1, ... in
  /// the order of the clusters' first points in the cloud; empty for every other stage.
  std::vector<std::uint32_t> cluster;
  std::size_t size() const { return at.size(); }
};

/// What one stage did: counts in and out, wall time, named figures and free-text notes.
/// Figures carry their unit in the name (for example "rms_mm").
struct StageReport {
  std::string stage;
  std::size_t count_in = 0;
  std::size_t count_out = 0;
  double seconds = 0.0;
  /// Peak resident memory of the process while the stage ran [bytes] (Linux: VmHWM after the
  /// high-water mark was reset at the stage's start, proc(5) /proc/PID/clear_refs "5"); 0 when
  /// not measured (another OS, a stage run outside run.cpp's stage helper, or no permission).
  std::size_t peak_rss_bytes = 0;
  /// CPU time of the whole process while the stage ran, user plus system, over all its threads
  /// [s] (getrusage(2) RUSAGE_SELF at the stage's start and end); 0 when not measured (a stage
  /// run outside run.cpp's stage helper). Against `seconds`, it tells how many cores the stage
  /// kept busy; summed, what a run costs a shared machine.
  double cpu_seconds = 0.0;
  std::vector<std::pair<std::string, double>> figures;
  std::vector<std::string> notes;

  void figure(std::string name, double value) { figures.emplace_back(std::move(name), value); }
};

/// A stage's result together with its report.
template <class T>
struct StageResult {
  T value;
  StageReport report;
};

}  // namespace hc::pipeline
