#pragma once
/// @file raster_export.hpp
/// Export of one scene layer as a GeoTIFF (issue "Ecosystem"), through GDAL, for GIS tools,
/// image viewers and Python (rasterio, tifffile). No GDAL header here: GDAL stays PRIVATE.

#include "hc/common/height_field.hpp"

#include <Eigen/Geometry>

#include <array>
#include <filesystem>
#include <string>
#include <vector>

namespace hc::pipeline {

/// Where a GeoTIFF's pixels sit and what their values mean.
struct GeoTiffLayout {
  /// GDAL geotransform (GDAL data model, "Affine GeoTransform"): pixel (col i, row j) has its
  /// top-left corner at (gt[0] + i·gt[1] + j·gt[2], gt[3] + i·gt[4] + j·gt[5]). Pixel centres
  /// are the grid's nodes; image row 0 is the grid's last row (largest y), so viewers and GIS
  /// tools show the scene upright (north up in a georeferenced top view).
  std::array<double, 6> geotransform{};
  /// True when the scene looks straight down on its scan (model_to_grid = uniform scale, a
  /// translation and no rotation): x, y (and the heights of depth and envelope) are then in the
  /// scan's own file frame and units, so a georeferenced scan lands on its map. False: the grid
  /// frame in metres (a chosen view orientation has no place on a map) and no CRS.
  bool file_frame = false;
  double z_scale = 1.0;   ///< file value = z_scale · grid value + z_offset (heights only)
  double z_offset = 0.0;
};

/// The layout for a layer of `geometry` seen through `model_to_grid` (file units → grid frame
/// [m], hc::Scene::model_to_grid). `is_height`: the layer holds z in the grid frame (depth,
/// envelope), mapped to the file frame with x and y; other layers (texture, μ, cell error,
/// intensity, region) keep their stored values. Pure: no I/O.
GeoTiffLayout geotiff_layout(const GridGeometry& geometry, const Eigen::Affine3d& model_to_grid, bool is_height);

/// Writes `layer` as a single-band float32 GeoTIFF: rows flipped to image order (row 0 = largest
/// y), values mapped by `layout` (z_scale, z_offset), no-data NaN (GDAL_NODATA = nan), DEFLATE
/// with the floating-point predictor, the geotransform of `layout`, and `crs` (WKT, "EPSG:n",
/// PROJ string: anything OGRSpatialReference::SetFromUserInput reads) when `layout.file_frame`
/// and crs is not empty. `metadata`: KEY=VALUE items stored in the dataset's metadata (layer
/// name, units, provenance). Returns notes for the user (e.g. a CRS GDAL could not read, kept
/// as the metadata item HAPTICLOUD_CRS_TEXT instead).
/// Written to an exclusively created temporary file beside `file` and hard-linked into place,
/// so nothing existing is overwritten and no half-written file is left.
/// Sources: GeoTIFF, OGC 19-008r4 (GeoTIFF 1.1) via GDAL's GTiff driver; GDAL raster data model.
/// Precision: float32, so heights mapped back to a georeferenced frame keep about 7 significant
/// digits (0.12 mm at 2 km elevation), below the noise of airborne and terrestrial scans.
/// GDAL is loaded on the first call, from the module geotiff_module_path() names.
/// @throws hc::InputError naming the file when it exists, its folder is missing, the GeoTIFF
///         module cannot be found or loaded (naming where it looked), GDAL has no GTiff driver
///         or cannot write it (with GDAL's message); std::invalid_argument for an
///         empty layer or a metadata item that is not KEY=VALUE. Nothing is left on any throw.
std::vector<std::string> write_geotiff(const HeightField& layer, const GeoTiffLayout& layout, const std::string& crs,
                                       const std::filesystem::path& file,
                                       const std::vector<std::string>& metadata = {});

/// The GeoTIFF writer module write_geotiff loads on first use (hc_geotiff_gdal.so, which links
/// GDAL, so that no other command loads GDAL at start-up): its path, loading it if needed, or
/// "" when it was not found. Looked for, in order: the file $HC_GDAL_MODULE; beside the binary
/// holding the pipeline (by its absolute path, else /proc/self/exe) and in <that binary's
/// folder>/<bindir → libdir/hapticloud> (an installed tree); the install prefix's
/// libdir/hapticloud; the build tree's lib/hapticloud. Looked for once per process. Never throws.
std::string geotiff_module_path();

}  // namespace hc::pipeline
