#pragma once
/// @file filters.hpp
/// Stage 4: non-finite removal, statistical outlier removal, crop box, voxel grid.

#include "hc/pipeline/cloud.hpp"

#include <Eigen/Core>

namespace hc::pipeline {

/// Drops points with a NaN or infinite coordinate.
StageResult<Cloud> remove_non_finite(Cloud cloud);

/// Statistical outlier removal (Rusu et al. 2008, as PCL's StatisticalOutlierRemoval): a point
/// is an outlier when its mean distance to its k nearest neighbours exceeds
/// mean + std_multiplier·stddev of that distance over all tested points.
/// @param k               neighbours, ≥ 1
/// @param std_multiplier  σ multiplier [-], > 0
/// @throws hc::ConfigError on out-of-range parameters.
StageResult<Cloud> remove_statistical_outliers(Cloud cloud, int k, double std_multiplier);

/// Keeps the points inside the axis-aligned box [min_m, max_m] (grid frame, metres).
StageResult<Cloud> crop_box(Cloud cloud, const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m);

/// Replaces the points of each cubic voxel of edge leaf_m [m] by their centroid (PCL VoxelGrid).
StageResult<Cloud> voxel_downsample(Cloud cloud, double leaf_m);

}  // namespace hc::pipeline
