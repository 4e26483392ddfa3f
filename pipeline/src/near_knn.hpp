#pragma once
// The exact mean k-NN distances of a few listed points of a large cloud, searched only among the
// points near them (robust_outliers.cpp; the tiled run's stage tile_scale lists about 600
// sampled points of a window of 3.4 M on the 10^8 wall).

#include "hc/pipeline/cloud.hpp"

#include <cstddef>
#include <cstdint>
#include <vector>

namespace hc::pipeline::detail {

/// How mean_knn_distances_of searched.
struct NearSearch {
  bool near = false;              ///< the listed points were searched among a subset of the cloud
  std::size_t blocks = 0;         ///< listed points (distinct) whose subset share is their block
  std::size_t wide_blocks = 0;    ///< listed points (distinct) whose subset share is their wider
                                  ///< block (9 × 9 × 9 cells), their 3 × 3 × 3 one not enough
  std::size_t balls = 0;          ///< listed points (distinct) whose subset share is a ball
  std::size_t subset_points = 0;  ///< the subset's points (0 without one)
  bool columns = false;           ///< a pass over the cloud met most points by their x-y column
                                  ///< alone (ColumnTable, voxel_keys.hpp: not when the blocks'
                                  ///< columns span more than 2^24, reach near 2^20 from the
                                  ///< centre or cover more than half their range)
};

/// hc::pipeline::mean_knn_distances (robust_outliers.hpp: shapes, units, errors, result), with
/// the search among the points near the listed ones when `near_only` and the listed points are
/// few (at most 1/1024 of the finite points). Cubic cells are sized for about k + 1 points on
/// the largest face of the cloud's 1 %–99 % box (of a sample of 4096 points). A listed point
/// whose block of 3 × 3 × 3 cells about its own holds k + 1 points within a distance that stays
/// inside the block takes the block; any other, its block of 9 × 9 × 9 cells on the same terms
/// (a second pass, for those only: a sparse sheet beside a dense one); any other the ball of the
/// smallest such distance its blocks or the sample give (k + 1 points always bound the k-th
/// neighbour's distance). The passes meet a point outside the blocks' x-y columns on its x and
/// y alone. The
/// union then holds every point within each listed point's k-th distance, and the grid search
/// over it (the same centre and float coordinates, copies at distance 0 alike) gives the same
/// result as over the whole cloud: the same k distances, summed in double. That sum is exact in
/// any order, hence the same bits, unless the k distances span more than 2^19 in magnitude
/// (knn_grid.cpp, SmallestK::mean_distance), where the whole cloud's own result already
/// depends on the search's order. The whole cloud is searched when the union holds more than
/// half of it or fewer than k + 2 points, when the cells cannot be sized (the sampled points on
/// one line or at one point) or a bound is not finite. `how`, when given, says which.
/// Cost: one pass over the cloud, two with a wider block, three with a ball (each on two
/// threads), then the grid search over the subset (two threads).
std::vector<double> mean_knn_distances_of(const Cloud& cloud, const std::vector<std::uint32_t>& columns, int k,
                                          std::vector<double>* nearest_m, bool near_only, NearSearch* how);

/// The same over points given as float coordinates: xyz holds x y z [m] of point j at
/// xyz[3j .. 3j + 2] (any frame: the search takes them as they are, without recentring, so the
/// caller recentres them near the points that matter: float's resolution is about 6e-8 of the
/// distance from the origin); `list`: points j (0 .. xyz.size() / 3 − 1), repeats allowed. The
/// result's order and units, the near search, `nearest_m` and `how` as above; each listed
/// point's distances are those over every point given (the tiled run's stage tile_scale: a
/// tile's window as read from its spill). `top_d2`, when given, receives each listed point's
/// k + 1 smallest squared distances [m²] over the points given (its own 0 among them,
/// unordered; PointQueries::mean_distance) at (*top_d2)[i·(k + 1) .. i·(k + 1) + k] for list
/// entry i, all 0 for a point with k copies. Errors: hc::ConfigError for k outside 1..1000;
/// hc::InputError for xyz.size() not a multiple of 3, a non-finite coordinate or a listed
/// point out of range; hc::DegenerateInputError for fewer than k + 2 points; hc::ResourceError
/// beyond 2^32 − 2 points.
std::vector<double> mean_knn_distances_of(const std::vector<float>& xyz, const std::vector<std::uint32_t>& list, int k,
                                          std::vector<double>* nearest_m, bool near_only, NearSearch* how,
                                          std::vector<float>* top_d2 = nullptr);

}  // namespace hc::pipeline::detail
