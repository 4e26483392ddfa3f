#pragma once
/// @file robust_outliers.hpp
/// Stage 4 (filters.outliers.method = robust, the default): a robust, density-aware outlier
/// test and the removal of small clusters far from the main body, for real scans with far
/// points, stray clusters, uniform clutter and uneven density. The exact PCL-compatible test
/// stays in filters.hpp (method = statistical).

#include "hc/pipeline/cloud.hpp"

#include <Eigen/Core>

#include <array>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <vector>

namespace hc::pipeline {

/// Which outlier test the outliers stage runs (config key filters.outliers.method).
enum class OutlierMethod {
  kRobust,       ///< remove_robust_outliers, then remove_far_clusters (the default)
  kStatistical,  ///< remove_statistical_outliers / remove_front_statistical_outliers (PCL's SOR)
};

/// The robust test's scale: the median and the MAD of ln d_i over its sample, each rounded to a
/// step of 1/128 (see remove_robust_outliers).
struct RobustScale {
  double median_log = 0.0;   ///< median of ln d [ln m]
  double mad_log = 0.0;      ///< median of |ln d − median_log| [-]
  std::size_t sample = 0;    ///< sampled points the figures came from
  /// The scan's spacing: the median distance of the sampled points to their nearest other
  /// point (exact copies give no value), rounded as median_log to a step of 1/128 in ln [m];
  /// 0 when no sampled point has a nearest point at a distance > 0. The isolated-point filter
  /// takes it (remove_isolated_points), so that a tiled run's tiles and the in-core run use one
  /// number.
  double spacing_m = 0.0;
  /// The float frame's centre [m, the cloud's frame]: the per-axis median (the (m/2)-th smallest
  /// of the m values) of the sampled points' coordinates. The test's searches run in float32 on
  /// coordinates less this centre (the subtraction in double), so a tiled run's windows, given
  /// the scale, compute the very floats the in-core run does and find the same k nearest (a
  /// window's own centre rounds differently: on the 10^8-point wall at N = 800 one point's
  /// neighbour set, hence its verdict, differed; fifty-first session). Empty: each call takes
  /// its own cloud's (a scale written before 2026-11-28, or made by hand).
  std::optional<std::array<double, 3>> centre_m = std::nullopt;
};

/// The float frame's centre of RobustScale::centre_m over the sampled points `xyz` (x y z
/// each, metres): per axis the (m/2)-th smallest of the m values. Empty for no point. Source:
/// this project.
std::optional<std::array<double, 3>> robust_sample_centre(const std::vector<std::array<double, 3>>& xyz);

/// Options of the robust test (filters.outliers.*; docs/config.md).
struct RobustOutlierOptions {
  int k = 16;                  ///< neighbours [-], 1..256
  double local_ratio = 3.0;    ///< a point is a local outlier when its mean k-NN distance exceeds
                               ///< local_ratio × its reference distance [-], > 1
  double mad_multiplier = 8.0; ///< global test: ln d > median(ln d) + mad_multiplier·σ, where
                               ///< σ = 1.4826·MAD(ln d) [-], > 0
  double max_surface_variation = 0.05;  ///< above D_glob, a point whose k-neighbourhood's surface
                               ///< variation λ0/(λ0+λ1+λ2) is at most this lies on a sparse
                               ///< surface and gets the local test instead [-], 0..1/3
  std::size_t sample = 20000;  ///< points whose exact k-NN distance gives the median and MAD
                               ///< (standard error of the median of ln d about 1.25·σ/√sample,
                               ///< 0.009·σ: below the 1/128 rounding step for σ < 0.8)
  double off_surface_ratio = 2.0;  ///< the off-surface test judges points with d_i above this ×
                               ///< d_med [-]; 0 = no off-surface test, else > 1 (lower: more
                               ///< clutter caught near the surface, more exact queries)
  /// The scale, given instead of drawn from this cloud's own sample: the tiled run reduces it
  /// across tiles (robust_scale_of over the sample points of every tile), so that every tile
  /// judges its points by the whole scan's statistics, as the in-core run does.
  std::optional<RobustScale> scale;
  /// A tiled run's tile (tiled_run.cpp), in the cloud's frame [m], each box {x_min, x_max,
  /// y_min, y_max}: `window_m` holds every point of the scan whose xy falls inside it (the
  /// tile's window with its halo; a side at ±infinity where the window meets the grid's edge,
  /// beyond which no point was left out), `decides_m` the points whose verdict the tile keeps
  /// (those within the grid stages' reach of its interior). Given, the test measures how far
  /// the searches that decide those points could reach past the window (the report figures
  /// halo_shortfall_mm and points_judged_past_halo; see remove_robust_outliers). What it does
  /// not cover: the tiled run leaves far-cluster points (removed over the whole scan first) out
  /// of every tile, where in core they are neighbours in this test; and the verdicts of points
  /// between decides_m and the window's edge, which the isolated-point and despike counts of
  /// decided points see, are not checked (docs/scale.md); with scale.filter_halo_cells auto the
  /// tiled run widens decides_m by the isolated filter's radius, and its despike verdicts are
  /// needed only that radius and the despike's inside it (tiled_run.cpp, tile_halo).
  struct TileBounds {
    std::array<double, 4> window_m{};
    std::array<double, 4> decides_m{};
    /// When not empty, the cloud is complete in these balls instead of the window: it holds
    /// every point of the scan within one of them ({x, y, z, radius} [m], 3-D distance), and a
    /// search is checked against them (window_m is not used). The tiled run's second look
    /// (judge_only) gathers the points of such balls from the neighbouring tiles.
    std::vector<std::array<double, 4>> complete_m;
  };
  std::optional<TileBounds> tile;
  /// Judge only these input columns (finite points), with `scale` given: no counting pass, each
  /// listed point gets its exact d_i and its verdict (the one the whole test gives it: the
  /// counting only spares queries); every other point's verdict is 0, and the cloud comes back
  /// unchanged (the verdicts carry the result). With `tile`,
  /// the listed points are those checked against the window (decides_m is not used). The tiled
  /// run's second look at the points whose searches could leave its window.
  std::vector<std::uint32_t> judge_only;
  /// Judge only the columns marked 1 (one byte per input column; empty: every column), with
  /// `scale` given and judge_only empty: as judge_only, each marked point gets the verdict the
  /// whole test gives it and every other point's verdict (and near count) is 0, but the
  /// counting pass still settles the marked points it can (over the cells that hold one), and
  /// with `tile` only the marked points within decides_m are checked against the window. The
  /// tiled run's first look at a tile whose window holds points that another tile of its band
  /// owns and judges (docs/scale.md, "Each point judged by its owner", fiftieth session).
  std::vector<std::uint8_t> judge_mask;
  /// The cloud comes back unchanged, its verdicts (RobustVerdicts::verdict, which must then be
  /// asked for) carrying the result; count_out is the number kept. The tiled run keeps a
  /// window's points for its second look instead of reading them again.
  bool verdicts_only = false;
  /// When > 0 (and the verdicts asked for), RobustVerdicts::near tells how many other points
  /// the test shows within near_radius_m [m] of each point. The tiled run asks with (just
  /// inside) the isolated-point filter's radius, so that neither that filter nor the honest
  /// check searches again about a point whose neighbours were already seen
  /// (remove_isolated_points' known_near, InputCheckScope::near).
  double near_radius_m = 0.0;
};

/// What remove_robust_outliers can tell its caller besides the kept points.
struct RobustVerdicts {
  /// One per input column, in input order: 0 kept, 1 removed by the global test, 2 by the local
  /// test, 3 by the off-surface test, 4 not finite (dropped).
  std::vector<std::uint8_t> verdict;
  /// Tiles (RobustOutlierOptions::tile): the candidates in decides_m (with judge_only: the
  /// listed points) whose searches could end past the window or the complete balls (input
  /// columns, ascending).
  std::vector<std::uint32_t> past_halo;
  /// For the past_halo points together, one flat set (not aligned with past_halo; 1 or k + 1
  /// balls per point, in no promised order): the balls ({x, y, z, radius} [m]) in which a set
  /// must hold every point of the scan for their verdicts to be the whole scan's, each point's
  /// k-NN ball and, where its verdict used them, its neighbours' (radii upper bounds, with the
  /// slack: the k-th distance of the point's own search in this cloud, never shorter than the
  /// whole scan's, except for a point left out of the searches as a duplicate, whose ball keeps
  /// the bound; a ball too small would only make the second look list the point again).
  std::vector<std::array<double, 4>> reach_m;
  /// With RobustOutlierOptions::near_radius_m > 0: one per input column, how many other points
  /// of this cloud are shown to lie within near_radius_m (a lower bound, at most min(k, 255)):
  /// k for a point settled by the counting pass when D_cert ≤ near_radius_m; the largest j
  /// with k·d / (k + 1 − j) ≤ near_radius_m for a point whose exact mean k-NN distance d is
  /// known (its j-th nearest lies within that); for a candidate, at least the number of its k
  /// nearest within the radius. Distances between the float32 recentred coordinates the
  /// searches use. 0 for non-finite points, with judge_only for the points not listed, and for every
  /// point when the recentred coordinates reach past 10^4 × near_radius_m (a distance's float
  /// rounding then stays under about 2e-3 of the radius, inside the users' 10 % margins; 10^3
  /// until 2026-11-28). Empty when not asked.
  std::vector<std::uint8_t> near;
};

/// The points remove_robust_outliers samples for its scale: min(n, sample) indices into the n
/// finite points in their order, one drawn (SplitMix64, deterministic) from each of min(n,
/// sample) equal runs; increasing. Pure.
std::vector<std::uint32_t> robust_sample_indices(std::size_t n, std::size_t sample);

/// d_i of the listed points (columns of `cloud`, which must be finite): the mean distance to
/// their k nearest other points of `cloud`, computed exactly as remove_robust_outliers does
/// (float32 on coordinates recentred on the cloud's median, duplicates at distance 0).
/// @param cloud    any frame, metres; columns index it
/// @param nearest_m when given, filled with each listed point's distance to its nearest other
///                 point [m] (0 for a point with an exact copy), as remove_robust_outliers
///                 measures it for RobustScale::spacing_m
/// @return one distance per listed column, in their order [m]
/// @throws hc::ConfigError for k outside 1..1000; hc::DegenerateInputError when the cloud has
///         fewer than k + 2 finite points; hc::InputError for a column that is not a finite
///         point. Threads: 2. Source: the statistic of Rusu et al. 2008 (PCL's
///         StatisticalOutlierRemoval), exact k-NN on the cell grid of knn_grid.hpp.
std::vector<double> mean_knn_distances(const Cloud& cloud, const std::vector<std::uint32_t>& columns, int k,
                                       std::vector<double>* nearest_m = nullptr);

/// The scale of the values ln d (d > 0) of a sample of `sampled` points (those with d = 0,
/// exact duplicates, give no value): median, then the median of the absolute deviations from
/// it, each rounded to a step of 1/128; RobustScale::sample = sampled. `logs` empty: std::nullopt.
/// `nearest_logs`: ln of the sampled points' nearest-point distances (those > 0); their median,
/// rounded alike, gives RobustScale::spacing_m (0 when empty).
/// Source: the MAD as a robust scale (Rousseeuw & Croux 1993; Leys et al. 2013). Never throws
/// (but std::bad_alloc).
std::optional<RobustScale> robust_scale_of(std::vector<double> logs, std::size_t sampled,
                                           std::vector<double> nearest_logs = {});

/// Whether robust_scale_of gives one and the same median_log, mad_log and spacing_m for every
/// choice of sampled values within bounds: `log_d[i]` = {lo, hi} holds ln d of sampled point i
/// (lo = hi where d is known; lo = −∞ and hi = +∞ where nothing is known of it, not even whether
/// d > 0), `log_nearest[i]` likewise ln of its nearest-point distance. Used by the tiled run's
/// stage tile_scale, whose k-NN searches over a tile's window give d only as an upper bound
/// where a search reaches past the window. Every order statistic is non-decreasing in each
/// value, so the median lies between the medians of the lower and of the upper bounds; given
/// the median rounded, each absolute deviation is bounded alike; a value left out (d = 0) lies
/// between one at −∞ and one at +∞ for a median. True when both bounds round to the same
/// step, for the median, the MAD about it and the nearest distances' median (an empty list
/// fixes its figure: no value either way); false otherwise, a NaN bound included. Cost:
/// O(n) (selection). Never throws (but std::bad_alloc). Source: order statistics are monotone
/// in each argument (David & Nagaraja, Order Statistics, 3rd ed., 2003, §1.1); the derivation
/// and the tiled run's bounds: docs/scale.md, "Searches past the window".
bool robust_scale_fixed(const std::vector<std::array<double, 2>>& log_d,
                        const std::vector<std::array<double, 2>>& log_nearest);

/// Options of far-cluster removal (filters.outliers.far_clusters.*; docs/config.md).
struct FarClusterOptions {
  bool enabled = true;
  double link_m = 0.0;          ///< linking distance [m]; 0 = auto (the robust test's global
                                ///< threshold distance, see remove_far_clusters)
  double far_distance_m = 0.0;  ///< a cluster is far when its box is more than this from the main
                                ///< body's box [m]; 0 = auto (10 × the linking distance)
  std::size_t max_points = 1000;  ///< a cluster is small when it has at most
  double max_fraction = 0.01;     ///< max(max_points, max_fraction·N) points
};

/// Robust, density-aware statistical outlier removal.
///
/// Statistic: d_i, the mean Euclidean distance of point i to its k nearest neighbours (as in
/// Rusu et al. 2008 and PCL's StatisticalOutlierRemoval), in float32 on recentred coordinates.
/// Scale (robust, Rousseeuw & Croux 1993; Leys et al. 2013): the median m and σ = 1.4826·MAD
/// of ln d_i over a deterministic stratified sample of min(N, sample) points (exact k-NN each;
/// m and the MAD rounded to steps of 1/128, so that a few added points cannot move them);
/// the median distance is d_med = exp(m). In log space a far point or a cluster 1 km away moves
/// the median and the MAD by at most its share of the sample, never the threshold by metres.
/// Point i is removed when any of the three tests fails:
///  - global: d_i > D_glob = max(exp(m + mad_multiplier·σ), local_ratio·d_med) and the point's
///    neighbourhood (itself and its k nearest) is not a surface: its surface variation
///    λ0/(λ0+λ1+λ2) (Pauly et al. 2002) exceeds max_surface_variation, or more than half of its
///    k nearest are such points themselves (above D_glob, no surface): k + 1 points of isotropic
///    clutter now and then lie near a plane by chance, the clutter around them does not.
///    Isolated clutter away from the surface goes; a sparse but coherent surface (near 0, its
///    neighbours too) gets only the local test;
///  - local (the local-density idea of LOF, Breunig et al. 2000, with the neighbours' median as
///    the reference, as in LoOP, Kriegel et al. 2009): d_i > local_ratio·max(d_ref, d_med), where
///    d_ref is the median of d_j over the k nearest neighbours j of i. A sparse but coherent
///    region (a scan's far side at 3 % density) has neighbours as sparse as itself and stays;
///    a spike in front of the surface, whose neighbours lie on the surface, goes. The floor
///    d_med keeps points of regions denser than typical (overlaps of merged views, duplicates);
///  - off surface (when off_surface_ratio > 0): off_surface_ratio·d_med < d_i <= D_glob, the
///    k nearest neighbours alone form a surface (surface variation <= max_surface_variation) and
///    the point stands off their least-squares plane by more than d_i / 2: clutter in the shell
///    near the surface, where its neighbours are surface points and its density looks normal.
///    A point of that surface lies on the plane (within noise and curvature sag), also at the
///    edge of a scan or of a sparse region.
/// Speed: the tests need d_i only for points with d_i > D_cert = min(local_ratio,
/// off_surface_ratio)·d_med (below it no test can fail; off_surface_ratio 0 counts as
/// infinite). The points are sorted into a uniform grid of cubic cells (knn_grid.hpp); a point
/// with at least k other points within D_cert among its own cell (then among the cells of its
/// 3×3×3 block within D_cert: faces, edges, then corners) has d_i ≤ D_cert and is kept without a k-NN query
/// (counting, no selection; cells of about 0.85·(3k+2) points, where counting and the exact
/// queries cost least together on the Buddha). The others get the exact k-NN distance; those
/// above D_cert also get their k nearest neighbours (the neighbour set breaks distance ties by
/// input index), and those that reach the local test (above local_ratio·d_med, not removed by
/// the other tests) their neighbours' exact distances. The removed set is exactly that of the
/// rule above applied to every point, given the sample's m and σ.
/// Tiles (options.tile given): a point's verdict depends on its k nearest neighbours and, when
/// its d_i exceeds local_ratio·d_med, on theirs. The tile's searches equal the whole scan's when
/// each ends inside the window: for each candidate i in `decides_m` (certified points and
/// candidates of the whole scan are candidates of the tile too, since the tile's d_i is never
/// smaller), r_i (its k-th neighbour's distance) is at most its xy distance to the window's open
/// sides, m_i, and where the verdict used the neighbours (the chance-plane and local tests: above
/// local_ratio·d_med, not removed by its own surface variation or off-surface distance) so is
/// r_j for each neighbour j against m_j, where r_j is bounded by min(|x_j − x_i| + r_i, k·d_j)
/// (the k points i and N(i) \ {j} lie within the first of j; the k-th of k distances is at most
/// their sum) and, where that bound reaches m_j, by j's own k-th distance in this cloud (one
/// more k-NN search). With TileBounds::complete_m, m is the largest of R − |x − c| over its balls (a
/// ball about x of that radius lies inside one of them; 0 when none does). Distance ties at the
/// k-th neighbour are broken by input index, which a tile's order need not share with the
/// whole scan's: such a tie is not listed. The largest excess over the candidates is halo_shortfall_mm (0: every
/// verdict equals the whole scan's, given the same scale and float rounding);
/// points_judged_past_halo counts the candidates with an excess (RobustVerdicts::past_halo
/// lists them).
/// Report figures: k, local_ratio, mad_multiplier, sample, median_knn_distance_mm,
/// mad_log_knn_distance, sigma_log_knn_distance, global_threshold_mm, certify_distance_mm,
/// certified, exact_queries, max_surface_variation, local_tests, coherent_above_global (points
/// above D_glob on a surface, judged locally), planar_among_scattered (points above D_glob on a
/// chance plane among clutter: removed by the global test), removed_robust, removed_global,
/// removed_local, removed_off_surface, local_threshold_mm, off_surface_ratio,
/// duplicates_left_out, knn_grid_cell_mm and the seconds of each step (grid_s, sample_s,
/// certify_s, exact_s, local_s). Notes: what was dropped and why.
/// @param cloud    any frame, metres (the grid frame in build_scene); non-finite points dropped
/// @param options  k 1..1000, local_ratio > 1, mad_multiplier > 0, max_surface_variation
///                0..1/3, sample >= 2, off_surface_ratio 0 or > 1
/// @throws hc::ConfigError on out-of-range options (and a complete ball with a non-finite
///         centre or radius, or a negative radius); hc::DegenerateInputError when fewer than
///         k + 2 finite points remain; hc::ResourceError beyond 2^32 − 2 points; with
///         judge_only, hc::ConfigError when `scale` is not given and hc::InputError for a listed
///         column that is not a finite point of the cloud; hc::ConfigError for verdicts_only
///         without `verdicts`.
/// Real-time: no. Threads: 2. Cost: one grid build and counting pass over all points, plus
/// (sample + uncertified + their neighbours) exact k-NN queries (judge_only: no counting pass;
/// the listed points, their neighbours and those neighbours' neighbours); with `tile`, one more
/// query per neighbour of a checked candidate whose first bounds reach past the margin or that
/// is listed (its neighbours' balls then narrowed from the bounds to their k-th distances), and
/// the complete balls indexed in an xy grid.
/// @param verdicts when given, filled (RobustVerdicts; its previous content is discarded)
/// @param scale_used when given, set to the scale the test used (computed, or options.scale)
///        when there was one; left as it was when every sampled point has k copies
StageResult<Cloud> remove_robust_outliers(Cloud cloud, const RobustOutlierOptions& options,
                                          RobustVerdicts* verdicts = nullptr, RobustScale* scale_used = nullptr);

/// A connected component of the cloud at a linking distance (remove_far_clusters).
struct PointCluster {
  std::size_t count = 0;              ///< points [-]
  Eigen::Vector3d centroid_m{0, 0, 0};  ///< mean position, the cloud's frame [m]
  Eigen::Vector3d min_m{0, 0, 0}, max_m{0, 0, 0};  ///< bounding box [m]
  double gap_m = 0.0;                 ///< distance from its box to the main body's box [m]
  bool removed = false;               ///< small and far: removed by remove_far_clusters
  /// With a FarClusterScope: small and far, but within two cell edges of the scope's
  /// complete_xy_m sides (it may continue past them, where the cloud is not the whole scan's):
  /// not removed.
  bool undecided = false;
};

/// What a caller that holds part of a scan (the tiled run's tile window) tells far-cluster
/// removal, so that every cluster it removes is one the whole scan's run removes too, and none
/// is removed on the strength of the part's edge. Without it, the cloud is the whole scan.
struct FarClusterScope {
  /// The whole scan's main body's bounding box, in the cloud's frame [m]: gaps are measured to
  /// it instead of to the part's largest component (a fragment of a statue cut off by a tile's
  /// edge is then never far), and every component of the linked points (find_far_clusters) is
  /// judged, the part's largest too. The
  /// tiled run passes the box of the largest component of its whole-scan pass on coarse cells
  /// (stage tile_far_clusters), which holds the in-core main body's box.
  Eigen::Vector3d main_body_min_m{0, 0, 0}, main_body_max_m{0, 0, 0};
  /// N in max(max_points, max_fraction·N): the whole scan's points before the robust test
  /// (after non-finite and crop), as remove_far_clusters_after takes it in core [-].
  std::size_t points = 0;
  /// The x-y box {x_min, x_max, y_min, y_max} [m] (an infinite side: none) in which the cloud
  /// holds every point of the scan with its final verdicts (the tile's decided region, where
  /// the robust test's verdicts are the whole scan's). A small, far cluster is removed only
  /// when its box grown by two cell edges (the farthest a linked point can lie per axis) stays
  /// inside it; otherwise it is kept and marked undecided. Columns in z: no z bound.
  std::array<double, 4> complete_xy_m{-std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
                                      -std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
};

/// The clusters of a cloud other than its main body.
struct FarClusters {
  double link_m = 0.0;          ///< linking distance used [m]
  double far_distance_m = 0.0;  ///< "far" beyond this gap [m]
  /// The largest component; with a FarClusterScope, the scope's main body box (count 0,
  /// centroid its centre), the whole scan's.
  PointCluster main_body;
  /// Every other component, largest first; with a scope, every component of the points that
  /// could belong to a far cluster (farther than far_distance_m − 2√3 cell edges from the main
  /// body box; the others cannot, and are not linked: see find_far_clusters).
  std::vector<PointCluster> others;
  /// With a scope: the finite points left out of the linking as too near the main body box to
  /// belong to a far cluster [-]; 0 without one.
  std::size_t points_near_main_body = 0;
};

/// Connected components of the finite points at linking distance link_m, and which of them are
/// small and far (see remove_far_clusters). Two points closer than link_m always share a
/// component; the components are unions of grid cells of edge ≥ link_m linked with their 26
/// neighbours, so points up to 2√3 cell edges apart may share one too (a coarser linking, never
/// a finer one). The cells lie on multiples of the edge in the cloud's frame (not on the
/// cloud's box), and the edge is link_m unless the box spans more than 2 097 150 links on an
/// axis: a part of a scan in the same frame and coordinates links its points as the whole scan
/// does (sixty-fourth session, 2026-11-30). Cost O(N): cells found in a dense table, or by sorted keys (radix sort, binary
/// searches) when the box has more than 4 cells per point. Non-finite points are ignored.
/// @param link_m  > 0 [m]; far_distance_m in `options` (0 = 10·link_m) and max_points /
///                max_fraction decide `removed`.
/// @param scope   when given, the cloud is part of a scan (FarClusterScope): gaps to its main
///                body box, N its points, removal only of clusters complete in its box. Only
///                the points farther than far − δ from the main body box are linked (δ: the
///                longest link, 2√3 cell edges, plus a millionth of an edge), on the whole
///                cloud's cells: the far clusters, their points, boxes and counts are those
///                of linking every point (a chain of links from a point beyond `far` to one left
///                out passes a linked point within far − ε, so its component is not far either
///                way); `others` lists the linked points' components only (fifty-seventh
///                session; before, every point was linked).
/// @throws hc::ConfigError if link_m <= 0 or not finite; hc::InputError if no point is finite.
FarClusters find_far_clusters(const Cloud& cloud, double link_m, const FarClusterOptions& options,
                              const FarClusterScope* scope = nullptr);

/// Removes the clusters that are both small (at most max(max_points, max_fraction·N) points) and
/// far (the gap between their bounding box and the main body's exceeds far_distance_m) — a
/// passer-by, a distant wall, stray returns far behind the object in a terrestrial scan. The
/// main body is the component with the most points. Each removed cluster is reported (count,
/// centroid, gap) in a note; figures: link_mm, far_distance_mm, clusters, far_clusters,
/// removed_far_clusters (points), kept_far_clusters (far but too large: still in the cloud);
/// with a scope also undecided_far_clusters (small and far, kept at the scope's edge: see
/// FarClusterScope) and points_near_main_body (left out of the linking: find_far_clusters), and
/// `clusters` is the number of the linked points' components (without a scope: the main body
/// and the others).
/// @param link_m  linking distance [m], > 0 (build_scene: options.link_m, or when 0 the robust
///                test's global threshold distance, the largest mean k-NN distance it keeps)
/// @param scope   see find_far_clusters (the tiled run's tiles); nullptr: the whole scan
/// @param size_points N of the size limit when > 0 and no scope is given (remove_far_clusters_after:
///                the points the robust test was given); 0: the cloud's finite points
/// @param removed when given, the removed points (RemovedPoints: their columns in `cloud`,
///                increasing, x y z, and each one's cluster, numbered in the order of the
///                clusters' first points: the tiled run counts each cluster once by it)
/// @throws hc::ConfigError on a bad link_m or options; hc::InputError on a cloud without finite
///         points. Source: single-linkage connected components (Euclidean cluster extraction,
///         Rusu 2009, Sec. 6.2) on a cell grid.
StageResult<Cloud> remove_far_clusters(Cloud cloud, double link_m, const FarClusterOptions& options,
                                       const FarClusterScope* scope = nullptr, std::size_t size_points = 0,
                                       RemovedPoints* removed = nullptr);

/// The outliers stage of method robust: remove_robust_outliers, then (when far.enabled)
/// remove_far_clusters at far.link_m, or when that is 0 at the robust test's global threshold
/// distance D_glob (every kept point has its nearest neighbour within D_glob, since the nearest
/// distance is at most the mean k-NN distance). One report with both steps' figures and notes;
/// "removed" = removed_robust + removed_far_clusters; far_s = the far-cluster step's seconds.
/// `scale_used` as in remove_robust_outliers (build_scene takes its spacing_m for the isolated
/// filter and the honest check). Throws what the two steps throw.
StageResult<Cloud> remove_outliers_robust(Cloud cloud, const RobustOutlierOptions& options,
                                          const FarClusterOptions& far, RobustScale* scale_used = nullptr);

/// The robust test's global threshold D_glob = max(exp(m + mad_multiplier·1.4826·MAD),
/// local_ratio·exp(m)) [m] for a scale (m = median_log, MAD = mad_log) and options, the very
/// value remove_robust_outliers computes (it calls this). Never throws.
double robust_global_threshold_m(const RobustScale& scale, const RobustOutlierOptions& options);

/// The linking distance of far-cluster removal after a robust test [m]: far.link_m when > 0,
/// else the robust report's figure global_threshold_mm × 10⁻³ (the value remove_far_clusters_after
/// takes, rounding included), else 1 mm (every point a copy of another). The tiled run's tiles
/// take the same value for the in-core cells of their kept points. Never throws.
double far_link_m(const FarClusterOptions& far, const StageReport& robust_report);
/// The same for a robust test that did not run where its global threshold is known (the tiled
/// run's windows too sparse to judge): far.link_m when > 0, else global_threshold_m as the
/// report carries it (× 10³, then × 10⁻³), else 1 mm.
double far_link_m(const FarClusterOptions& far, double global_threshold_m);

/// The second step of remove_outliers_robust on the result of remove_robust_outliers (as
/// remove_outliers_robust runs it): far-cluster removal at far.link_m or the robust report's
/// global_threshold_mm, the report extended. N of the size limit is the robust report's
/// count_in (the points the test was given), which a tiled run knows before its tiles run. For a caller that runs the robust test itself
/// (the tiled run, which may judge points again over gathered points, and passes its tile's
/// `scope`). `removed` as remove_far_clusters' (columns in robust.value; empty when far is off).
/// Throws what remove_far_clusters throws.
StageResult<Cloud> remove_far_clusters_after(StageResult<Cloud> robust, const FarClusterOptions& far,
                                             const FarClusterScope* scope = nullptr, RemovedPoints* removed = nullptr);

/// One line for an error message when a cloud's grid is degenerate: the clusters far from the
/// main body (count, centroid, gap; at most five) and a filters.crop box around the main body,
/// or "" when the cloud has no far cluster. The linking distance is derived from the cloud's own
/// median k-NN distance (k = 16, on a sample). Never throws on a finite cloud; "" otherwise.
std::string describe_far_points(const Cloud& cloud);

}  // namespace hc::pipeline
