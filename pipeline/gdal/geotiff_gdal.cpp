// The GeoTIFF writer on GDAL (module hc_geotiff_gdal.so; the interface is
// pipeline/src/geotiff_module.h, the contract raster_export.hpp's write_geotiff). The host
// validates the request, creates the temporary file and puts it in place; this side only turns
// the pixels, the geotransform, the CRS and the metadata into a GeoTIFF through GDAL's GTiff
// driver (GeoTIFF 1.1, OGC 19-008r4; GDAL raster data model).

#include "geotiff_module.h"

#include <cpl_conv.h>
#include <cpl_error.h>
#include <gdal_priv.h>
#include <ogr_spatialref.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <string>

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

void copy_text(char* out, std::size_t size, const std::string& text) {
  std::snprintf(out, size, "%s", text.c_str());
}

// Fills `result` with a failure and returns 1.
int fail(HcGeoTiffResult* result, const char* what) {
  copy_text(result->what, sizeof result->what, what);
  copy_text(result->detail, sizeof result->detail, QuietGdal::last());
  return 1;
}

}  // namespace

extern "C" __attribute__((visibility("default"))) int hc_geotiff_write(const HcGeoTiffJob* job, HcGeoTiffResult* result) {
  std::memset(result, 0, sizeof *result);
  if (job->abi != HC_GEOTIFF_ABI) {
    copy_text(result->what, sizeof result->what, "the GeoTIFF module does not match this program for");
    copy_text(result->detail, sizeof result->detail,
              "module interface " + std::to_string(HC_GEOTIFF_ABI) + ", program " + std::to_string(job->abi));
    return 1;
  }
  try {
    static std::once_flag once;
    std::call_once(once, [] { GDALAllRegister(); });
    const QuietGdal quiet;
    // No .aux.xml side file (it would be named after the temporary): what GeoTIFF keys cannot
    // hold is not written.
    CPLSetThreadLocalConfigOption("GDAL_PAM_ENABLED", "NO");
    struct RestorePam {
      ~RestorePam() { CPLSetThreadLocalConfigOption("GDAL_PAM_ENABLED", nullptr); }
    } restore_pam;
    std::string notes;
    GDALDriver* driver = GetGDALDriverManager()->GetDriverByName("GTiff");
    if (!driver) return fail(result, "GDAL has no GTiff driver for");
    {
      const char* options[] = {"COMPRESS=DEFLATE", "PREDICTOR=3", nullptr};
      std::unique_ptr<GDALDataset, void (*)(GDALDataset*)> ds(
          driver->Create(job->path, job->cols, job->rows, 1, GDT_Float32, const_cast<char**>(options)),
          [](GDALDataset* d) { GDALClose(d); });
      if (!ds) return fail(result, "GDAL cannot create");
      double gt[6];
      std::copy(job->geotransform, job->geotransform + 6, gt);
      if (ds->SetGeoTransform(gt) != CE_None) return fail(result, "GDAL cannot set the geotransform of");
      const std::string crs = job->crs ? job->crs : "";
      if (!crs.empty() && job->crs_in_file_frame) {
        OGRSpatialReference srs;
        const char* srs_options[] = {"ALLOW_NETWORK_ACCESS=NO", "ALLOW_FILE_ACCESS=NO", nullptr};
        if (srs.SetFromUserInput(crs.c_str(), srs_options) == OGRERR_NONE) {
          if (ds->SetSpatialRef(&srs) != CE_None) return fail(result, "GDAL cannot set the CRS of");
        } else {
          ds->SetMetadataItem("HAPTICLOUD_CRS_TEXT", crs.c_str());
          notes += "the scan's CRS text is not one GDAL reads; kept as the metadata item HAPTICLOUD_CRS_TEXT\n";
          CPLErrorReset();
        }
      } else if (!crs.empty()) {
        notes += "the scene's view is not a top view of its scan: written in the grid frame, without the scan's CRS\n";
      }
      for (std::size_t i = 0; i < job->n_metadata; ++i) {
        const std::string item = job->metadata[i];
        const std::size_t eq = item.find('=');
        ds->SetMetadataItem(item.substr(0, eq).c_str(), item.substr(eq + 1).c_str());
      }
      GDALRasterBand* band = ds->GetRasterBand(1);
      if (band->SetNoDataValue(std::numeric_limits<double>::quiet_NaN()) != CE_None) {
        return fail(result, "GDAL cannot set no-data in");
      }
      for (int j = 0; j < job->rows; ++j) {
        float* row = const_cast<float*>(job->pixels) + static_cast<std::size_t>(j) * static_cast<std::size_t>(job->cols);
        if (band->RasterIO(GF_Write, 0, j, job->cols, 1, row, job->cols, 1, GDT_Float32, 0, 0) != CE_None) {
          return fail(result, "GDAL cannot write");
        }
      }
      ds->FlushCache(false);
      if (CPLGetLastErrorType() == CE_Failure) return fail(result, "GDAL cannot write");
    }  // closed here
    if (CPLGetLastErrorType() == CE_Failure) return fail(result, "GDAL failed writing");
    copy_text(result->notes, sizeof result->notes, notes);
    return 0;
  } catch (const std::exception& e) {
    copy_text(result->what, sizeof result->what, "the GeoTIFF module failed on");
    copy_text(result->detail, sizeof result->detail, e.what());
    return 1;
  } catch (...) {  // nothing crosses the C boundary
    copy_text(result->what, sizeof result->what, "the GeoTIFF module failed on");
    copy_text(result->detail, sizeof result->detail, "an unknown exception");
    return 1;
  }
}
