// GeoTIFF export through GDAL (raster_export.hpp).

#include "hc/pipeline/raster_export.hpp"

#include "hc/common/file_output.hpp"

#include "hc/common/error.hpp"

#include <cpl_conv.h>
#include <cpl_error.h>
#include <gdal_priv.h>
#include <ogr_spatialref.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <system_error>

namespace hc::pipeline {

namespace {

// GDAL's error handler for one call: collects the last failure's message instead of printing.
struct QuietGdal {
  QuietGdal() {
    CPLPushErrorHandler(CPLQuietErrorHandler);
    CPLErrorReset();
  }
  ~QuietGdal() { CPLPopErrorHandler(); }
  QuietGdal(const QuietGdal&) = delete;
  QuietGdal& operator=(const QuietGdal&) = delete;
  static std::string last() {
    const char* m = CPLGetLastErrorMsg();
    return m && *m ? std::string(m) : std::string("no message from GDAL");
  }
};

void register_gdal() {
  static std::once_flag once;
  std::call_once(once, [] { GDALAllRegister(); });
}

}  // namespace

GeoTiffLayout geotiff_layout(const GridGeometry& g, const Eigen::Affine3d& model_to_grid, bool is_height) {
  GeoTiffLayout out;
  const Eigen::Matrix3d l = model_to_grid.linear();
  const double s = l.col(0).norm();
  out.file_frame = s > 0.0 && std::isfinite(s) && (l - s * Eigen::Matrix3d::Identity()).norm() <= 1e-9 * s;
  const double top_y = g.y_of_row(g.rows - 1);
  if (out.file_frame) {
    // grid = s·file + t, so file = (grid − t) / s.
    const Eigen::Vector3d t = model_to_grid.translation();
    const double cell = g.cell_size_m / s;
    out.geotransform = {(g.x0_m - t.x()) / s - 0.5 * cell, cell, 0.0, (top_y - t.y()) / s + 0.5 * cell, 0.0, -cell};
    if (is_height) {
      out.z_scale = 1.0 / s;
      out.z_offset = -t.z() / s;
    }
  } else {
    const double cell = g.cell_size_m;
    out.geotransform = {g.x0_m - 0.5 * cell, cell, 0.0, top_y + 0.5 * cell, 0.0, -cell};
  }
  return out;
}

std::vector<std::string> write_geotiff(const HeightField& layer, const GeoTiffLayout& layout, const std::string& crs,
                                       const std::filesystem::path& file, const std::vector<std::string>& metadata) {
  namespace fs = std::filesystem;
  if (layer.rows() < 1 || layer.cols() < 1) throw std::invalid_argument("write_geotiff: the layer is empty");
  std::error_code ec;
  const fs::path target = file.has_parent_path() ? file : fs::path(".") / file;
  if (!fs::is_directory(target.parent_path(), ec)) {
    throw InputError("export: folder " + target.parent_path().string() + " of " + file.string() + " does not exist");
  }
  if (fs::exists(fs::symlink_status(target, ec))) {
    throw InputError("export: " + target.string() + " exists already (not overwritten; choose another --out)");
  }
  for (const std::string& item : metadata) {
    const std::size_t eq = item.find('=');
    if (eq == std::string::npos || eq == 0) throw std::invalid_argument("write_geotiff: metadata item '" + item + "' is not KEY=VALUE");
  }
  register_gdal();
  const QuietGdal quiet;
  // No .aux.xml side file (it would be named after the temporary): what GeoTIFF keys cannot
  // hold is not written.
  CPLSetThreadLocalConfigOption("GDAL_PAM_ENABLED", "NO");
  struct RestorePam {
    ~RestorePam() { CPLSetThreadLocalConfigOption("GDAL_PAM_ENABLED", nullptr); }
  } restore_pam;
  std::vector<std::string> notes;
  GDALDriver* driver = GetGDALDriverManager()->GetDriverByName("GTiff");
  if (!driver) throw InputError("export: GDAL has no GTiff driver");
  const fs::path tmp = create_temporary_beside(target);
  // Removes the temporary on every way out but the successful link (exceptions included).
  struct RemoveTemporary {
    const fs::path& path;
    bool keep = false;
    ~RemoveTemporary() {
      std::error_code e;
      if (!keep) fs::remove(path, e);
    }
  } cleanup{tmp};
  auto fail = [&](const std::string& what) {
    throw InputError("export: " + what + " " + target.string() + ": " + QuietGdal::last());
  };
  {
    const char* options[] = {"COMPRESS=DEFLATE", "PREDICTOR=3", nullptr};
    std::unique_ptr<GDALDataset, void (*)(GDALDataset*)> ds(
        driver->Create(tmp.c_str(), layer.cols(), layer.rows(), 1, GDT_Float32, const_cast<char**>(options)),
        [](GDALDataset* d) { GDALClose(d); });
    if (!ds) fail("GDAL cannot create");
    double gt[6];
    std::copy(layout.geotransform.begin(), layout.geotransform.end(), gt);
    if (ds->SetGeoTransform(gt) != CE_None) fail("GDAL cannot set the geotransform of");
    if (!crs.empty() && layout.file_frame) {
      OGRSpatialReference srs;
      const char* srs_options[] = {"ALLOW_NETWORK_ACCESS=NO", "ALLOW_FILE_ACCESS=NO", nullptr};
      if (srs.SetFromUserInput(crs.c_str(), srs_options) == OGRERR_NONE) {
        if (ds->SetSpatialRef(&srs) != CE_None) fail("GDAL cannot set the CRS of");
      } else {
        ds->SetMetadataItem("HAPTICLOUD_CRS_TEXT", crs.c_str());
        notes.push_back("the scan's CRS text is not one GDAL reads; kept as the metadata item HAPTICLOUD_CRS_TEXT");
        CPLErrorReset();
      }
    } else if (!crs.empty()) {
      notes.push_back("the scene's view is not a top view of its scan: written in the grid frame, without the scan's CRS");
    }
    for (const std::string& item : metadata) {
      const std::size_t eq = item.find('=');
      ds->SetMetadataItem(item.substr(0, eq).c_str(), item.substr(eq + 1).c_str());
    }
    GDALRasterBand* band = ds->GetRasterBand(1);
    if (band->SetNoDataValue(std::numeric_limits<double>::quiet_NaN()) != CE_None) fail("GDAL cannot set no-data in");
    // Image row j = grid row rows − 1 − j (upright), values mapped to the file frame.
    std::vector<float> row(static_cast<std::size_t>(layer.cols()));
    for (int j = 0; j < layer.rows(); ++j) {
      const int r = layer.rows() - 1 - j;
      for (int c = 0; c < layer.cols(); ++c) {
        const float v = layer.at(r, c);
        row[static_cast<std::size_t>(c)] =
            std::isnan(v) ? v : static_cast<float>(layout.z_scale * static_cast<double>(v) + layout.z_offset);
      }
      if (band->RasterIO(GF_Write, 0, j, layer.cols(), 1, row.data(), layer.cols(), 1, GDT_Float32, 0, 0) != CE_None) {
        fail("GDAL cannot write");
      }
    }
    ds->FlushCache(false);
    if (CPLGetLastErrorType() == CE_Failure) fail("GDAL cannot write");
  }  // closed here
  if (CPLGetLastErrorType() == CE_Failure) fail("GDAL failed writing");
  if (!link_into_place(tmp, target)) {
    const std::string why = errno == EEXIST ? "it exists already (not overwritten)" : std::strerror(errno);
    throw InputError("export: cannot put " + target.string() + " in place: " + why);
  }
  cleanup.keep = true;
  return notes;
}

}  // namespace hc::pipeline
