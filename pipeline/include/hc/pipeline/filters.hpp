#pragma once
/// @file filters.hpp
/// Stage 4: non-finite removal, statistical outlier removal, crop box, voxel grid.

#include "hc/pipeline/cloud.hpp"
#include "hc/pipeline/reproject.hpp"

#include <Eigen/Core>

#include <cstddef>
#include <string>

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

/// Which points the statistical outlier test is applied to (config key filters.outliers.scope).
enum class OutlierScope {
  kAll,    ///< every point (remove_statistical_outliers)
  kFront,  ///< only the points that can become a grid cell's front-most sample
           ///< (remove_front_statistical_outliers)
};

/// Default size of the deterministic sample that estimates the threshold in
/// remove_front_statistical_outliers [points].
inline constexpr std::size_t kFrontThresholdSample = 50000;

/// Statistical outlier removal restricted to what the Monge grid of `grid_options` can show.
/// Only the front-most (largest z) point of a grid cell reaches the grid (reproject's
/// front-most rule; splats are cast from a cell's node with its front-most z), so only such
/// points are tested, each with the same test as remove_statistical_outliers: its mean distance
/// to its k nearest neighbours among ALL finite points (exact, same float32 arithmetic), against
/// a threshold mean + std_multiplier·stddev. Steps:
///  1. Threshold: mean and stddev (over m − 1) of the mean k-NN distance of a deterministic
///     stratified sample of m = min(n, threshold_sample) finite points: point j of the sample is
///     drawn uniformly (splitmix64 of j) from the j-th of m equal runs of the input order. With
///     n ≤ threshold_sample every point is used and the threshold is exactly that of
///     remove_statistical_outliers.
///  2. Bounding box: the grid covers the x-y box of the kept points, so for each of min x,
///     max x, min y, max y the most extreme point is tested; an outlier is removed and the next
///     most extreme is tested, until one passes. The grid geometry is then reproject's for the
///     box of these four points (hence for the output cloud).
///  3. Cells: points are binned to the grid's nodes (reproject's nearest-node rule); in each
///     cell the front-most point is tested; an outlier is removed and the next front-most
///     point is tested, until one passes or the cell is empty.
/// Points never tested are kept (they still feed the cross-check). With the exact threshold
/// (n ≤ threshold_sample) the removed set is a subset of remove_statistical_outliers' and
/// reproject gives the same grid, cell for cell. With a sampled threshold, points whose mean
/// distance lies between the two thresholds are judged differently; if one of them is an
/// extreme of the x-y box the grid geometry shifts by a fraction of a cell (merged Buddha,
/// N = 800: threshold 0.37 % low, y0 moves by 0.012 mm).
/// Report figures: k, std_multiplier, threshold_sample, mean_knn_distance_mm,
/// stddev_knn_distance_mm, threshold_mm (from the sample), tested, removed, removed_at_bbox,
/// grid_rows, grid_cols, knn_grid_cell_mm and the seconds of each step (knn_grid_build_s,
/// threshold_sample_s, bbox_s, bin_s, cells_s).
/// @param grid_options    the reproject options of the run (only the grid size matters)
/// @param threshold_sample sample size for the threshold, >= 2
/// @throws hc::ConfigError on out-of-range k (1..1000), std_multiplier (> 0) or
///         threshold_sample; hc::DegenerateInputError when fewer than k + 2 finite points
///         remain; whatever reproject throws for this grid (InputError, DegenerateInputError,
///         ConfigError, ResourceError). Non-finite points are dropped (counted in a note).
/// Real-time: no. Threads: 2. Cost: one grid build over all points plus about
/// (sample + grid cells) k-NN queries, instead of one per point.
/// Source: Rusu et al. 2008 (the test), restricted to the depth-buffer scan of the paper.
StageResult<Cloud> remove_front_statistical_outliers(Cloud cloud, int k, double std_multiplier,
                                                     const ReprojectOptions& grid_options,
                                                     std::size_t threshold_sample = kFrontThresholdSample);

/// Keeps the points inside the axis-aligned box [min_m, max_m] (grid frame, metres; faces
/// included). @throws hc::ConfigError if min > max on an axis; hc::InputError on an empty cloud;
/// hc::DegenerateInputError if no point lies inside.
StageResult<Cloud> crop_box(Cloud cloud, const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m);

/// crop_box's selection alone: the points inside [min_m, max_m] (faces included), attributes
/// kept alongside; no check, no report, and no point inside is not an error (a chunk of a
/// streamed scan may lie wholly outside the crop: the tiled run crops chunk by chunk and judges
/// the whole scan; until 2026-11-30 it called crop_box and stopped at such a chunk).
Cloud keep_inside_box(Cloud cloud, const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m);

/// crop_box's test for one point: p_m (3-vector, grid frame [m]) inside [min_m, max_m], faces
/// included. False for a non-finite coordinate.
bool inside_box(const Eigen::Ref<const Eigen::Vector3d>& p_m, const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m);

/// crop_box's error when none of `points` finite points lies inside [min_m, max_m] (grid frame
/// [m]); `where` is appended inside the message's last parentheses (e.g. "; tiled run").
/// @throws hc::DegenerateInputError always, naming the count and the box.
[[noreturn]] void throw_nothing_inside_box(std::size_t points, const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m,
                                           const std::string& where = "");

/// Replaces the points of each cubic voxel of edge leaf_m [m] by their centroid (PCL VoxelGrid;
/// float32; scan_id is dropped). @throws hc::ConfigError if leaf_m <= 0 or so small that PCL's
/// 32-bit voxel indices would overflow (the message gives the smallest usable leaf);
/// hc::InputError if no point is finite.
StageResult<Cloud> voxel_downsample(Cloud cloud, double leaf_m);

}  // namespace hc::pipeline
