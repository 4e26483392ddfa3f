#pragma once
/// @file cloud.hpp
/// The point cloud and stage-report types that flow through the offline pipeline.

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace hc::pipeline {

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
  /// Keeps the points whose keep[i] is true, in order (every attribute follows).
  /// keep.size() == size().
  void keep_if(const std::vector<bool>& keep);
  /// Appends `other`'s points; an attribute that only one side has is dropped (the result must
  /// hold it for every point or for none). Returns the names of the attributes dropped.
  std::vector<std::string> append(const Cloud& other);
};

/// What one stage did: counts in and out, wall time, named figures and free-text notes.
/// Figures carry their unit in the name (for example "rms_mm").
struct StageReport {
  std::string stage;
  std::size_t count_in = 0;
  std::size_t count_out = 0;
  double seconds = 0.0;
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
