#pragma once
/// @file filters.hpp
/// Stage 4: non-finite removal, statistical outlier removal, crop box, voxel grid.

#include "hc/pipeline/cloud.hpp"

#include <Eigen/Core>

namespace hc::pipeline {

/// Drops points with a NaN or infinite coordinate (scan_id follows). An all-NaN cloud gives an
/// empty cloud, not an error: the next stage rejects it. The report's figure "dropped" and its
/// first note say how many points were dropped. Cost O(N).
StageResult<Cloud> remove_non_finite(Cloud cloud);

/// Statistical outlier removal (Rusu et al. 2008, as PCL's StatisticalOutlierRemoval): a point
/// is an outlier when its mean distance to its k nearest neighbours exceeds
/// mean + std_multiplier·stddev of that distance over all tested points.
/// Exact: the k-NN distances are computed in float32 on recentred coordinates, with PCL's
/// arithmetic, so the removed set equals PCL's on the same input; a uniform grid replaces the
/// kd-tree for speed (2 threads). Non-finite points are dropped (counted in a note).
/// @param k               neighbours, 1..1000
/// @param std_multiplier  σ multiplier [-], > 0
/// @throws hc::ConfigError on out-of-range parameters; hc::DegenerateInputError (an InputError)
///         when fewer than k + 2 finite points remain.
StageResult<Cloud> remove_statistical_outliers(Cloud cloud, int k, double std_multiplier);

/// Keeps the points inside the axis-aligned box [min_m, max_m] (grid frame, metres; faces
/// included). @throws hc::ConfigError if min > max on an axis; hc::InputError on an empty cloud;
/// hc::DegenerateInputError if no point lies inside.
StageResult<Cloud> crop_box(Cloud cloud, const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m);

/// Replaces the points of each cubic voxel of edge leaf_m [m] by their centroid (PCL VoxelGrid;
/// float32; scan_id is dropped). @throws hc::ConfigError if leaf_m <= 0 or so small that PCL's
/// 32-bit voxel indices would overflow (the message gives the smallest usable leaf);
/// hc::InputError if no point is finite.
StageResult<Cloud> voxel_downsample(Cloud cloud, double leaf_m);

}  // namespace hc::pipeline
