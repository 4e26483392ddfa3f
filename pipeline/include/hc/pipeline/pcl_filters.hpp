#pragma once
/// @file pcl_filters.hpp
/// PCL filters as pipeline stages (config key `filters.pcl`, issue 18): an ordered list of named
/// PCL classes with their parameters, each run on the cloud as its own stage with its report.
/// This header includes no PCL header (PCL stays in pipeline/src/pcl_filters.cpp).

#include "hc/pipeline/cloud.hpp"

#include <Eigen/Core>

#include <cstddef>
#include <string>
#include <vector>

namespace hc::pipeline {

/// The PCL classes `filters.pcl` can run (PCL 1.13 names).
enum class PclFilterKind {
  kStatisticalOutlierRemoval,   ///< pcl::StatisticalOutlierRemoval<PointXYZ>
  kRadiusOutlierRemoval,        ///< pcl::RadiusOutlierRemoval<PointXYZ>
  kVoxelGrid,                   ///< pcl::VoxelGrid<PointXYZ>
  kApproximateVoxelGrid,        ///< pcl::ApproximateVoxelGrid<PointXYZ>
  kUniformSampling,             ///< pcl::UniformSampling<PointXYZ>
  kMovingLeastSquares,          ///< pcl::MovingLeastSquares<PointXYZ, PointXYZ> (smoothing only)
  kPassThrough,                 ///< pcl::PassThrough<PointXYZ>
  kCropBox,                     ///< pcl::CropBox<PointXYZ>
  kEuclideanClusterExtraction,  ///< pcl::EuclideanClusterExtraction<PointXYZ>, largest clusters kept
};

/// One `filters.pcl` entry: which class and its parameters (SI; only those of `kind` are used).
/// Defaults are PCL's own unless noted; the config reader fills and range-checks them
/// (docs/config.md lists every key).
struct PclFilterSpec {
  PclFilterKind kind = PclFilterKind::kVoxelGrid;
  std::string name;              ///< the PCL class name as written in the config ("VoxelGrid")
  // StatisticalOutlierRemoval
  int mean_k = 16;               ///< neighbours [-], 1..1000 (setMeanK)
  double stddev_mul = 1.0;       ///< σ multiplier [-], > 0 (setStddevMulThresh)
  // RadiusOutlierRemoval
  double radius_m = 0.0;         ///< search radius [m] (setRadiusSearch); UniformSampling: its radius
  int min_neighbors = 1;         ///< RadiusOutlierRemoval: fewer neighbours within radius_m → removed
  // VoxelGrid, ApproximateVoxelGrid
  double leaf_m = 0.0;           ///< cubic leaf edge [m] (setLeafSize)
  // MovingLeastSquares
  double search_radius_m = 0.0;  ///< setSearchRadius [m]
  int polynomial_order = 2;      ///< setPolynomialOrder, 0..5
  // PassThrough
  std::string field = "z";       ///< "x" | "y" | "z" (setFilterFieldName)
  double min_m = 0.0, max_m = 0.0;  ///< setFilterLimits [m]
  // CropBox
  Eigen::Vector3d box_min_m = Eigen::Vector3d::Zero(), box_max_m = Eigen::Vector3d::Zero();
  // PassThrough, CropBox
  bool negative = false;         ///< keep the points outside instead (setNegative / setFilterLimitsNegative)
  // EuclideanClusterExtraction
  double tolerance_m = 0.0;      ///< setClusterTolerance [m]
  int min_cluster_size = 1;      ///< setMinClusterSize [points]
  int max_cluster_size = 2147483647;  ///< setMaxClusterSize [points]
  int keep_clusters = 1;         ///< the this-many largest clusters are kept (hapticloud's rule)
};

/// Whether the filter outputs new points (centroids, smoothed positions) rather than a subset of
/// its input: VoxelGrid, ApproximateVoxelGrid, MovingLeastSquares.
bool pcl_filter_replaces_points(PclFilterKind kind);

/// The farthest a point of the input can be from the output point that stands for it, for the
/// honest cross-check's removal test [m]: the leaf for the voxel grids, the search radius for
/// MovingLeastSquares, 0 for the subset filters.
double pcl_filter_displacement_m(const PclFilterSpec& spec);

/// Runs one PCL filter on `cloud` (grid frame, metres).
/// The coordinates go to PCL as pcl::PointXYZ (float32, cast from double; non-finite points are
/// dropped first and counted in a note). Subset filters (StatisticalOutlierRemoval,
/// RadiusOutlierRemoval, UniformSampling, PassThrough, CropBox, EuclideanClusterExtraction) keep
/// the original double points and every attribute, in input order: the kept set is exactly the
/// points PCL's class outputs (UniformSampling and EuclideanClusterExtraction emit them in their
/// own order; hapticloud keeps input order). Replacing filters (VoxelGrid, ApproximateVoxelGrid,
/// MovingLeastSquares) return PCL's output points in PCL's order (float32 values in double);
/// attributes and faces are dropped with a note. EuclideanClusterExtraction keeps the
/// `keep_clusters` largest clusters (PCL sorts them by size, descending; ties keep PCL's order).
/// Report: stage "pcl:<name>" (build_scene names it), count_in, count_out, seconds, figures with
/// the parameters (lengths in mm) and, for the cluster extraction, "clusters".
/// @throws hc::ConfigError on a parameter out of range (naming the parameter and the range);
///         hc::InputError when no finite point is left to filter.
/// Real-time: no. Threads: 1 (PCL's single-threaded paths). Source: PCL 1.13's classes, called
/// through their public API; nothing reimplemented.
StageResult<Cloud> apply_pcl_filter(Cloud cloud, const PclFilterSpec& spec);

}  // namespace hc::pipeline
