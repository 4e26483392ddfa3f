/* The interface between hc::pipeline and the PCL module hc_pcl.so (pipeline/pcl/pcl_module.cpp),
 * which links PCL. The pipeline loads the module with dlopen when a run first needs PCL:
 * filters.voxel_m (pcl::VoxelGrid) or a filters.pcl stage. No
 * other command loads PCL's libraries and VTK, about 50 ms of every start (bench/README.md,
 * "Start-up"). Plain C data only: the two sides share no C++ types, exceptions or allocations
 * (what the module allocates, hc_pcl_free releases). Private to hc::pipeline. */
#ifndef HC_PIPELINE_PCL_MODULE_H
#define HC_PIPELINE_PCL_MODULE_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define HC_PCL_ABI 2

/* The PCL filter classes (hc::pipeline::PclFilterKind, in its order). */
enum HcPclFilterKind {
  HC_PCL_STATISTICAL_OUTLIER_REMOVAL = 0,
  HC_PCL_RADIUS_OUTLIER_REMOVAL = 1,
  HC_PCL_VOXEL_GRID = 2,
  HC_PCL_APPROXIMATE_VOXEL_GRID = 3,
  HC_PCL_UNIFORM_SAMPLING = 4,
  HC_PCL_MOVING_LEAST_SQUARES = 5,
  HC_PCL_PASS_THROUGH = 6,
  HC_PCL_CROP_BOX = 7,
  HC_PCL_EUCLIDEAN_CLUSTER_EXTRACTION = 8
};

/* One PCL filter on float points (pcl::PointXYZ), with the parameters its class takes
 * (hc::pipeline::PclFilterSpec, checked by the host). */
typedef struct HcPclFilterJob {
  int abi;                      /* HC_PCL_ABI */
  int kind;                     /* HcPclFilterKind */
  const float* xyz;             /* n points, x y z, all finite [m] */
  size_t n;
  int mean_k;                   /* StatisticalOutlierRemoval */
  double stddev_mul;
  double radius_m;              /* RadiusOutlierRemoval, UniformSampling */
  int min_neighbors;
  double leaf_m;                /* VoxelGrid, ApproximateVoxelGrid */
  double search_radius_m;       /* MovingLeastSquares */
  int polynomial_order;
  char field;                   /* PassThrough: 'x', 'y' or 'z' */
  double min_m, max_m;
  double box_min_m[3];          /* CropBox */
  double box_max_m[3];
  int negative;                 /* PassThrough, CropBox */
  double tolerance_m;           /* EuclideanClusterExtraction */
  int min_cluster_size, max_cluster_size, keep_clusters;
} HcPclFilterJob;

/* What a filter gave: the kept points' indices into the job's points (a subset filter, in PCL's
 * order) or new points (VoxelGrid, ApproximateVoxelGrid, MovingLeastSquares). On failure `what`
 * names it and `detail` holds PCL's message. */
typedef struct HcPclFilterResult {
  int subset;                   /* 1: kept and n_kept; 0: xyz and n_out */
  uint32_t* kept;
  size_t n_kept;
  float* xyz;
  size_t n_out;
  size_t clusters;              /* EuclideanClusterExtraction: clusters found */
  char what[256];
  char detail[1024];
} HcPclFilterResult;

/* Returns 0 on success, else non-zero with `result->what` and `result->detail` set. */
typedef int (*HcPclFilterFn)(const HcPclFilterJob* job, HcPclFilterResult* result);
#define HC_PCL_FILTER_SYMBOL "hc_pcl_filter"

/* Releases what the module allocated (HcPclFilterResult::kept / xyz). */
typedef void (*HcPclFreeFn)(void* p);
#define HC_PCL_FREE_SYMBOL "hc_pcl_free"

#ifdef __cplusplus
}
#endif

#endif
