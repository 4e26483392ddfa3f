/* The interface between hc::pipeline (raster_export.cpp) and the GeoTIFF writer module
 * hc_geotiff_gdal.so (pipeline/gdal/geotiff_gdal.cpp), which links GDAL. The pipeline loads
 * the module with dlopen on the first export, so that no other command loads GDAL and the
 * about 60 shared libraries it brings (bench/README.md, "Start-up"). Plain C data only: the
 * two sides share no C++ types, exceptions or allocations. Private to hc::pipeline. */
#ifndef HC_PIPELINE_GEOTIFF_MODULE_H
#define HC_PIPELINE_GEOTIFF_MODULE_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

#define HC_GEOTIFF_ABI 1

/* One single-band float32 GeoTIFF to write. */
typedef struct HcGeoTiffJob {
  int abi;                       /* HC_GEOTIFF_ABI */
  const char* path;              /* the file to create (an empty temporary the host made) */
  int cols, rows;                /* pixels */
  const float* pixels;           /* rows × cols values, image row 0 first (top), NaN = no data */
  const double* geotransform;    /* 6 values, GDAL's affine geotransform */
  const char* crs;               /* "" = none; else anything OGRSpatialReference reads */
  int crs_in_file_frame;         /* 0: the grid frame, the CRS is not written (a note says so) */
  const char* const* metadata;   /* n_metadata KEY=VALUE items */
  size_t n_metadata;
} HcGeoTiffJob;

/* What the module reports: on failure `what` ("GDAL cannot create", ...) and GDAL's message;
 * on success notes for the user, separated by '\n'. */
typedef struct HcGeoTiffResult {
  char what[128];
  char detail[1024];
  char notes[2048];
} HcGeoTiffResult;

/* Returns 0 on success, else non-zero with `result->what` and `result->detail` set. */
typedef int (*HcGeoTiffWriteFn)(const HcGeoTiffJob* job, HcGeoTiffResult* result);
#define HC_GEOTIFF_WRITE_SYMBOL "hc_geotiff_write"

#ifdef __cplusplus
}
#endif

#endif
