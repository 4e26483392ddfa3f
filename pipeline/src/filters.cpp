// Stage 4: non-finite removal, crop box, voxel grid (PCL VoxelGrid) and statistical outlier
// removal.
//
// Statistical outlier removal computes, like PCL's StatisticalOutlierRemoval, the mean distance
// of every point to its k nearest neighbours, then removes the points whose mean distance exceeds
// mean + σ·stddev over all points. The k-NN distances are exact and, on the same float input,
// PCL's (tests/pipeline/filters_test.cpp checks the removed set against PCL and brute force);
// the search engine, a uniform grid of cubic cells, is in knn_grid.hpp/.cpp.
//
// Scope front (remove_front_statistical_outliers) tests only the points that can reach the Monge
// grid: a stratified sample for the threshold, the extremes of the x-y box, then the front-most
// point of every grid cell, again and again while it is an outlier. The queries use the same
// grid with a dense key table (no binary searches), in grid order, the 3×3×3 block first and
// the radius hint of stage A; larger blocks are trimmed to the cells within the best (k+1)-th
// distance so far. On the merged Buddha at N = 800 it tests 253 k of 1.1 M points.
//
// A voxel-count density pre-test ("only points in sparse neighbourhoods pay a k-NN query") was
// measured and rejected: on the merged Buddha with k = 16, σ = 1 the threshold lies at the 89th
// percentile of the mean distances, only 0.11 mm above the median, and the best count-based
// bound certifies 1.3 % of the points as inliers (27 % at σ = 2, 62 % at σ = 3), while the
// mean and stddev still need every point's distance.

#include "hc/common/format.hpp"
#include "knn_grid.hpp"
#include "modules.hpp"
#include "stage_util.hpp"
#include "hc/pipeline/filters.hpp"

#include "hc/common/error.hpp"


#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace hc::pipeline {

namespace {

using detail::build_grid;
using detail::CellGrid;
using detail::Clock;
using hc::format_number;
using detail::kSearchThreads;
using detail::make_report;
using detail::mean_knn_distances;
using detail::PointQueries;
using detail::run_parallel;
using detail::seconds_since;
using detail::splitmix64;

// Float32 copy of the finite points, recentred on their bounding-box centre (double), so that
// float keeps sub-micrometre resolution whatever the cloud's offset.
std::vector<float> recentred_float(const Cloud& cloud, const std::vector<std::uint32_t>& rows) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  for (const std::uint32_t i : rows) {
    lo = lo.cwiseMin(cloud.xyz.col(static_cast<Eigen::Index>(i)));
    hi = hi.cwiseMax(cloud.xyz.col(static_cast<Eigen::Index>(i)));
  }
  const Eigen::Vector3d centre = 0.5 * (lo + hi);
  std::vector<float> p(3 * rows.size());
  for (std::size_t j = 0; j < rows.size(); ++j) {
    const auto c = cloud.xyz.col(static_cast<Eigen::Index>(rows[j]));
    for (Eigen::Index a = 0; a < 3; ++a) p[3 * j + static_cast<std::size_t>(a)] = static_cast<float>(c(a) - centre(a));
  }
  return p;
}

}  // namespace

StageResult<Cloud> remove_non_finite(Cloud cloud) {
  const auto t0 = Clock::now();
  StageReport report = make_report("non_finite", cloud.size());
  std::vector<bool> keep(cloud.size());
  std::size_t kept = 0;
  for (Eigen::Index i = 0; i < cloud.xyz.cols(); ++i) {
    const bool ok = cloud.xyz.col(i).allFinite();
    keep[static_cast<std::size_t>(i)] = ok;
    kept += ok ? 1u : 0u;
  }
  const std::size_t dropped = cloud.size() - kept;
  if (dropped > 0) cloud.keep_if(keep);
  report.count_out = cloud.size();
  report.figure("dropped", static_cast<double>(dropped));
  report.notes.push_back("dropped " + std::to_string(dropped) + " of " + std::to_string(report.count_in) +
                         " points with a NaN or infinite coordinate");
  report.seconds = seconds_since(t0);
  return {std::move(cloud), std::move(report)};
}

bool inside_box(const Eigen::Ref<const Eigen::Vector3d>& p_m, const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m) {
  return (p_m.array() >= min_m.array()).all() && (p_m.array() <= max_m.array()).all();
}

void throw_nothing_inside_box(std::size_t points, const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m, const std::string& where) {
  throw DegenerateInputError("crop_box: no point of " + std::to_string(points) + " lies inside the box min (" + format_number(min_m.x()) +
                             ", " + format_number(min_m.y()) + ", " + format_number(min_m.z()) + ") m, max (" + format_number(max_m.x()) +
                             ", " + format_number(max_m.y()) + ", " + format_number(max_m.z()) + ") m (grid frame" + where + ")");
}

Cloud keep_inside_box(Cloud cloud, const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m) {
  std::vector<bool> keep(cloud.size());
  for (Eigen::Index i = 0; i < cloud.xyz.cols(); ++i) keep[static_cast<std::size_t>(i)] = inside_box(cloud.xyz.col(i), min_m, max_m);
  cloud.keep_if(keep);
  return cloud;
}

StageResult<Cloud> crop_box(Cloud cloud, const Eigen::Vector3d& min_m, const Eigen::Vector3d& max_m) {
  const auto t0 = Clock::now();
  if (!min_m.allFinite() || !max_m.allFinite() || (min_m.array() > max_m.array()).any()) {
    throw ConfigError("crop_box: min (" + format_number(min_m.x()) + ", " + format_number(min_m.y()) + ", " + format_number(min_m.z()) +
                      ") m and max (" + format_number(max_m.x()) + ", " + format_number(max_m.y()) + ", " + format_number(max_m.z()) +
                      ") m must be finite with min <= max on every axis");
  }
  if (cloud.size() == 0) throw InputError("crop_box: the cloud is empty");
  StageReport report = make_report("crop", cloud.size());
  cloud = keep_inside_box(std::move(cloud), min_m, max_m);
  if (cloud.size() == 0) throw_nothing_inside_box(report.count_in, min_m, max_m);
  report.count_out = cloud.size();
  report.figure("removed", static_cast<double>(report.count_in - report.count_out));
  report.seconds = seconds_since(t0);
  return {std::move(cloud), std::move(report)};
}

StageResult<Cloud> voxel_downsample(Cloud cloud, double leaf_m) {
  const auto t0 = Clock::now();
  if (!(leaf_m > 0.0) || !std::isfinite(leaf_m)) {
    throw ConfigError("voxel_downsample: leaf = " + format_number(leaf_m) + " m, expected a finite value > 0");
  }
  StageReport report = make_report("voxel", cloud.size());
  std::vector<float> in;  // the finite points as float, x y z each (pcl::PointXYZ)
  in.reserve(3 * cloud.size());
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::infinity());
  Eigen::Vector3f hi = -lo;
  for (Eigen::Index i = 0; i < cloud.xyz.cols(); ++i) {
    if (!cloud.xyz.col(i).allFinite()) continue;
    const Eigen::Vector3f p = cloud.xyz.col(i).cast<float>();
    in.insert(in.end(), {p.x(), p.y(), p.z()});
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  if (in.empty()) throw InputError("voxel_downsample: the cloud has no finite points");
  // PCL's VoxelGrid indexes voxels with 32-bit ints; beyond that it only warns and returns the
  // input unchanged. Check with its own arithmetic and say so instead.
  const float inv = static_cast<float>(1.0 / leaf_m);
  std::int64_t voxels = 1;
  bool overflow = false;
  for (int a = 0; a < 3; ++a) {
    const double lo_i = std::floor(static_cast<double>(lo[a] * inv));
    const double hi_i = std::floor(static_cast<double>(hi[a] * inv));
    if (std::abs(lo_i) > 1e9 || std::abs(hi_i) > 1e9) {
      overflow = true;
      break;
    }
    voxels *= static_cast<std::int64_t>(hi_i - lo_i) + 1;
    if (voxels > std::numeric_limits<std::int32_t>::max()) {
      overflow = true;
      break;
    }
  }
  if (overflow) {
    const Eigen::Vector3d ext = (hi - lo).cast<double>();
    const double min_leaf = std::cbrt(std::max(ext.prod(), 0.0) / std::numeric_limits<std::int32_t>::max()) * 1.05;
    throw ConfigError("voxel_downsample: leaf " + format_number(leaf_m) + " m is too small for a cloud of " + format_number(ext.x()) +
                      " x " + format_number(ext.y()) + " x " + format_number(ext.z()) +
                      " m: PCL's VoxelGrid allows at most 2147483647 voxels (use a leaf of at least about " +
                      format_number(std::max(min_leaf, std::max({ext.x(), ext.y(), ext.z()}) / 1.0e9)) +
                      " m, or recentre the cloud first)");
  }
  // pcl::VoxelGrid<pcl::PointXYZ> in the PCL module (modules.hpp).
  const detail::PclModule& pcl = detail::pcl_module("filters.voxel_m");
  HcPclFilterJob job{};
  job.abi = HC_PCL_ABI;
  job.kind = HC_PCL_VOXEL_GRID;
  job.xyz = in.data();
  job.n = in.size() / 3;
  job.leaf_m = leaf_m;
  HcPclFilterResult res{};
  const int rc = pcl.filter(&job, &res);
  const detail::PclFilterResultGuard release{pcl, res};  // an allocation below may throw
  if (rc != 0) throw InputError(std::string("voxel_downsample: ") + res.what + ": " + res.detail);
  const std::size_t n_out = res.n_out;
  Cloud result;
  result.xyz.resize(3, static_cast<Eigen::Index>(n_out));
  for (std::size_t i = 0; i < n_out; ++i) {
    for (int a = 0; a < 3; ++a) result.xyz(a, static_cast<Eigen::Index>(i)) = static_cast<double>(res.xyz[3 * i + static_cast<std::size_t>(a)]);
  }
  report.count_out = result.size();
  report.figure("leaf_mm", leaf_m * 1e3);
  if (cloud.has_scan_id()) report.notes.push_back("scan_id dropped: a voxel centroid mixes scans");
  if (cloud.has_grid_index()) report.notes.push_back("row/col dropped: a voxel centroid has no scan grid position");
  if (cloud.has_normals()) report.notes.push_back("normals and curvature dropped: a voxel centroid has none of its own");
  if (cloud.has_rgb() || cloud.has_intensity()) {
    // Colour and intensity: the mean over the voxel's points. Each input point's voxel is found
    // with VoxelGrid's own arithmetic (float floor(p · (1/leaf)) − min index, linear index
    // i + j·nx + k·nx·ny); PCL emits one centroid per occupied voxel in increasing linear index
    // (min_points_per_voxel 0), so the i-th distinct index is output point i. Checked: the
    // voxel count and each voxel's centroid must match PCL's output, else the attributes are
    // dropped with a note (never misaligned).
    const float inv_leaf = 1.0f / static_cast<float>(leaf_m);
    Eigen::Vector3i min_b, div_b;
    for (int a = 0; a < 3; ++a) {
      min_b[a] = static_cast<int>(std::floor(lo[a] * inv_leaf));
      div_b[a] = static_cast<int>(std::floor(hi[a] * inv_leaf)) - min_b[a] + 1;
    }
    std::vector<std::pair<std::int64_t, std::size_t>> keyed;  // (voxel index, input point)
    keyed.reserve(in.size() / 3);
    for (Eigen::Index i = 0; i < cloud.xyz.cols(); ++i) {
      if (!cloud.xyz.col(i).allFinite()) continue;
      const Eigen::Vector3f p = cloud.xyz.col(i).cast<float>();
      std::int64_t ijk[3];
      for (int a = 0; a < 3; ++a) {
        ijk[a] = static_cast<std::int64_t>(std::floor(p[a] * inv_leaf) - static_cast<float>(min_b[a]));
      }
      keyed.emplace_back(ijk[0] + ijk[1] * div_b[0] + ijk[2] * static_cast<std::int64_t>(div_b[0]) * div_b[1],
                         static_cast<std::size_t>(i));
    }
    std::stable_sort(keyed.begin(), keyed.end(),
                     [](const auto& a, const auto& b) { return a.first < b.first; });
    const bool rgb = cloud.has_rgb(), inten = cloud.has_intensity();
    std::vector<std::uint8_t> rgb_out(rgb ? 3 * n_out : 0);
    std::vector<float> int_out(inten ? n_out : 0);
    bool ok = true;
    std::size_t voxel = 0;
    for (std::size_t b = 0; b < keyed.size() && ok; ++voxel) {
      std::size_t e = b;
      while (e < keyed.size() && keyed[e].first == keyed[b].first) ++e;
      if (voxel >= n_out) {
        ok = false;
        break;
      }
      Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
      double c_sum[3] = {0.0, 0.0, 0.0}, i_sum = 0.0;
      for (std::size_t q = b; q < e; ++q) {
        const std::size_t pt = keyed[q].second;
        centroid += cloud.xyz.col(static_cast<Eigen::Index>(pt));
        if (rgb) {
          for (std::size_t ch = 0; ch < 3; ++ch) c_sum[ch] += cloud.rgb[3 * pt + ch];
        }
        if (inten) i_sum += static_cast<double>(cloud.intensity[pt]);
      }
      const double n = static_cast<double>(e - b);
      centroid /= n;
      const double tol = 1e-3 * leaf_m + 1e-6 * centroid.cwiseAbs().maxCoeff();
      if ((centroid - result.xyz.col(static_cast<Eigen::Index>(voxel))).cwiseAbs().maxCoeff() > tol) ok = false;
      if (rgb) {
        for (std::size_t ch = 0; ch < 3; ++ch) {
          rgb_out[3 * voxel + ch] = static_cast<std::uint8_t>(std::clamp(std::lround(c_sum[ch] / n), 0L, 255L));
        }
      }
      if (inten) int_out[voxel] = static_cast<float>(i_sum / n);
      b = e;
    }
    if (ok && voxel == n_out) {
      result.rgb = std::move(rgb_out);
      result.intensity = std::move(int_out);
      report.notes.push_back(std::string("per voxel mean of") + (rgb ? " colour (rgb)" : "") + (inten ? " intensity" : ""));
    } else {
      report.notes.push_back("colour and intensity dropped: the voxels could not be matched to PCL's centroids");
    }
  }
  report.seconds = seconds_since(t0);
  return {std::move(result), std::move(report)};
}

StageResult<Cloud> remove_statistical_outliers(Cloud cloud, int k, double std_multiplier) {
  const auto t0 = Clock::now();
  if (k < 1 || k > 1000) throw ConfigError("remove_statistical_outliers: k = " + std::to_string(k) + ", expected 1..1000");
  if (!(std_multiplier > 0.0) || !std::isfinite(std_multiplier)) {
    throw ConfigError("remove_statistical_outliers: std_multiplier = " + format_number(std_multiplier) +
                      ", expected a finite value > 0");
  }
  StageReport report = make_report("outliers", cloud.size());
  std::vector<std::uint32_t> rows;
  rows.reserve(cloud.size());
  if (cloud.size() > std::numeric_limits<std::uint32_t>::max() - 1) {
    throw ResourceError("remove_statistical_outliers: " + std::to_string(cloud.size()) +
                        " points, at most 4294967294 supported");
  }
  for (Eigen::Index i = 0; i < cloud.xyz.cols(); ++i) {
    if (cloud.xyz.col(i).allFinite()) rows.push_back(static_cast<std::uint32_t>(i));
  }
  const std::size_t n = rows.size();
  if (n < static_cast<std::size_t>(k) + 2) {
    throw DegenerateInputError("remove_statistical_outliers: the cloud has " + std::to_string(n) +
                               " finite points; k = " + std::to_string(k) + " needs at least " +
                               std::to_string(k + 2));
  }
  const std::vector<float> p = recentred_float(cloud, rows);
  const std::vector<float> d = mean_knn_distances(p, n, k, &report);

  // Statistics exactly as PCL: sums in input order, squares in float, variance over n - 1.
  double sum = 0.0, sq_sum = 0.0;
  for (const float v : d) {
    sum += v;
    sq_sum += v * v;
  }
  const double nd = static_cast<double>(n);
  const double mean = sum / nd;
  const double variance = (sq_sum - sum * sum / nd) / (nd - 1.0);
  const double stddev = std::sqrt(std::max(variance, 0.0));
  const double threshold = mean + std_multiplier * stddev;

  std::vector<bool> keep(cloud.size(), false);
  for (std::size_t j = 0; j < n; ++j) keep[rows[j]] = static_cast<double>(d[j]) <= threshold;
  cloud.keep_if(keep);
  report.count_out = cloud.size();
  report.figure("k", k);
  report.figure("std_multiplier", std_multiplier);
  report.figure("mean_knn_distance_mm", mean * 1e3);
  report.figure("stddev_knn_distance_mm", stddev * 1e3);
  report.figure("threshold_mm", threshold * 1e3);
  report.figure("removed", static_cast<double>(n - report.count_out));
  if (n != report.count_in) {
    report.notes.push_back("dropped " + std::to_string(report.count_in - n) + " non-finite points");
  }
  report.seconds = seconds_since(t0);
  return {std::move(cloud), std::move(report)};
}

StageResult<Cloud> remove_front_statistical_outliers(Cloud cloud, int k, double std_multiplier,
                                                     const ReprojectOptions& grid_options,
                                                     std::size_t threshold_sample) {
  const auto t0 = Clock::now();
  if (k < 1 || k > 1000) {
    throw ConfigError("remove_front_statistical_outliers: k = " + std::to_string(k) + ", expected 1..1000");
  }
  if (!(std_multiplier > 0.0) || !std::isfinite(std_multiplier)) {
    throw ConfigError("remove_front_statistical_outliers: std_multiplier = " + format_number(std_multiplier) +
                      ", expected a finite value > 0");
  }
  if (threshold_sample < 2) {
    throw ConfigError("remove_front_statistical_outliers: threshold_sample = " + std::to_string(threshold_sample) +
                      ", expected at least 2");
  }
  StageReport report = make_report("outliers", cloud.size());
  if (cloud.size() > std::numeric_limits<std::uint32_t>::max() - 1) {
    throw ResourceError("remove_front_statistical_outliers: " + std::to_string(cloud.size()) +
                        " points, at most 4294967294 supported");
  }
  std::vector<std::uint32_t> rows;
  rows.reserve(cloud.size());
  for (Eigen::Index i = 0; i < cloud.xyz.cols(); ++i) {
    if (cloud.xyz.col(i).allFinite()) rows.push_back(static_cast<std::uint32_t>(i));
  }
  const std::size_t n = rows.size();
  if (n < static_cast<std::size_t>(k) + 2) {
    throw DegenerateInputError("remove_front_statistical_outliers: the cloud has " + std::to_string(n) +
                               " finite points; k = " + std::to_string(k) + " needs at least " +
                               std::to_string(k + 2));
  }
  const std::vector<float> p = recentred_float(cloud, rows);
  const CellGrid g = build_grid(p, n, k);
  const double t_grid = seconds_since(t0);
  // Sorted grid position of each finite point; left-out copies (mean distance 0) have none.
  constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
  std::vector<std::uint32_t> pos(n, kNone);
  for (std::size_t s = 0; s < g.original.size(); ++s) pos[g.original[s]] = static_cast<std::uint32_t>(s);
  const PointQueries queries(g, k);
  // Mean k-NN distance per finite point; < 0 = not tested yet.
  std::vector<float> mean_d(n, -1.0f);
  auto test = [&](std::size_t j, PointQueries::Scratch& s) {
    if (mean_d[j] < 0.0f) mean_d[j] = pos[j] == kNone ? 0.0f : queries.mean_distance(pos[j], s);
    return mean_d[j];
  };
  // Tests a list of distinct points in grid order (memory locality, and each query's radius
  // hint comes from a nearby point), on two threads for long lists.
  std::vector<std::pair<std::uint32_t, std::uint32_t>> order;
  auto test_all = [&](const std::vector<std::uint32_t>& list) {
    order.clear();
    for (const std::uint32_t j : list) {
      if (mean_d[j] < 0.0f) order.emplace_back(pos[j], j);
    }
    std::sort(order.begin(), order.end());
    const std::size_t len = order.size();
    const int th = len >= 4096 ? kSearchThreads : 1;
    run_parallel(th, [&](int t) {
      PointQueries::Scratch s(k);
      const std::size_t b = len * static_cast<std::size_t>(t) / static_cast<std::size_t>(th);
      const std::size_t e = len * static_cast<std::size_t>(t + 1) / static_cast<std::size_t>(th);
      for (std::size_t i = b; i < e; ++i) test(order[i].second, s);
    });
  };

  // 1. Threshold from a stratified deterministic sample, statistics as PCL's (double sums,
  // float squares, variance over m − 1).
  const std::size_t m = std::min(n, threshold_sample);
  std::vector<std::uint32_t> sample(m);
  for (std::size_t j = 0; j < m; ++j) {
    const std::size_t lo = j * n / m, hi = (j + 1) * n / m;
    sample[j] = static_cast<std::uint32_t>(lo + splitmix64(j) % (hi - lo));
  }
  test_all(sample);
  double sum = 0.0, sq_sum = 0.0;
  for (const std::uint32_t j : sample) {
    const float v = mean_d[j];
    sum += v;
    sq_sum += v * v;
  }
  const double md = static_cast<double>(m);
  const double mean = sum / md;
  const double stddev = std::sqrt(std::max((sq_sum - sum * sum / md) / (md - 1.0), 0.0));
  const double threshold = mean + std_multiplier * stddev;
  const auto removed = [&](std::size_t j) { return mean_d[j] >= 0.0f && static_cast<double>(mean_d[j]) > threshold; };
  const double t_sample = seconds_since(t0);

  // 2. The x-y box: per side, the most extreme point that passes. Candidates come in batches
  // (a bounded heap over one pass), doubled when a batch holds only outliers.
  PointQueries::Scratch scratch(k);
  std::size_t removed_at_bbox = 0;
  std::array<std::size_t, 4> extreme{};
  for (int side = 0; side < 4; ++side) {
    const Eigen::Index axis = side / 2;
    const double sign = side % 2 == 0 ? 1.0 : -1.0;  // smallest of sign·coordinate
    auto key = [&](std::size_t j) { return sign * cloud.xyz(axis, static_cast<Eigen::Index>(rows[j])); };
    bool found = false;
    for (std::size_t want = 16; !found; want *= 4) {
      std::vector<std::pair<double, std::size_t>> heap;  // max-heap of the `want` smallest keys
      heap.reserve(want + 1);
      for (std::size_t j = 0; j < n; ++j) {
        if (removed(j)) continue;
        const std::pair<double, std::size_t> e{key(j), j};
        if (heap.size() < want) {
          heap.push_back(e);
          std::push_heap(heap.begin(), heap.end());
        } else if (e < heap.front()) {
          std::pop_heap(heap.begin(), heap.end());
          heap.back() = e;
          std::push_heap(heap.begin(), heap.end());
        }
      }
      std::sort_heap(heap.begin(), heap.end());
      for (const auto& e : heap) {
        test(e.second, scratch);
        if (!removed(e.second)) {
          extreme[static_cast<std::size_t>(side)] = e.second;
          found = true;
          break;
        }
        ++removed_at_bbox;
      }
      if (!found && heap.size() < want) {
        throw DegenerateInputError("remove_front_statistical_outliers: every one of " + std::to_string(n) +
                                   " finite points on the x-y box is an outlier (threshold " +
                                   format_number(threshold * 1e3) + " mm)");
      }
    }
  }
  Cloud box;
  box.xyz.resize(3, 4);
  for (Eigen::Index i = 0; i < 4; ++i) {
    box.xyz.col(i) = cloud.xyz.col(static_cast<Eigen::Index>(rows[extreme[static_cast<std::size_t>(i)]]));
  }
  ReprojectOptions geometry_only = grid_options;
  geometry_only.splat_radius_cells = 0.0;
  geometry_only.see_through_depth_m = 0.0;
  const GridGeometry geo = reproject(box, geometry_only).value.depth.geometry();
  const double t_box = seconds_since(t0);

  // 3. Bin the remaining points to the grid's nodes, with reproject's arithmetic
  // (bin_front_most in reproject.cpp), in a counting sort by cell.
  const std::size_t cells = geo.cell_count();
  const double inv = 1.0 / geo.cell_size_m;
  const double cx = 0.5 - geo.x0_m * inv, cy = 0.5 - geo.y0_m * inv;
  const auto c_max = static_cast<unsigned>(geo.cols - 1), r_max = static_cast<unsigned>(geo.rows - 1);
  std::vector<std::uint32_t> cell_of(n);
  std::vector<std::uint32_t> start(cells + 1, 0);
  for (std::size_t j = 0; j < n; ++j) {
    const auto q = cloud.xyz.col(static_cast<Eigen::Index>(rows[j]));
    const unsigned c = std::min(static_cast<unsigned>(static_cast<int>(q(0) * inv + cx)), c_max);
    const unsigned r = std::min(static_cast<unsigned>(static_cast<int>(q(1) * inv + cy)), r_max);
    const std::size_t cell = static_cast<std::size_t>(r) * static_cast<std::size_t>(geo.cols) + c;
    cell_of[j] = static_cast<std::uint32_t>(cell);
    ++start[cell + 1];
  }
  for (std::size_t c = 0; c < cells; ++c) start[c + 1] += start[c];
  std::vector<std::uint32_t> members(n);
  {
    std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
    for (std::size_t j = 0; j < n; ++j) members[fill[cell_of[j]]++] = static_cast<std::uint32_t>(j);
  }
  std::vector<float> zf(n);
  for (std::size_t j = 0; j < n; ++j) zf[j] = static_cast<float>(cloud.xyz(2, static_cast<Eigen::Index>(rows[j])));

  const double t_bin = seconds_since(t0);
  // 4. Per cell: test the front-most point until one passes or the cell is empty, in rounds:
  // each round tests the current front-most candidate of every unsettled cell together.
  std::vector<std::uint32_t> pending;
  for (std::size_t c = 0; c < cells; ++c) {
    if (start[c + 1] > start[c]) pending.push_back(static_cast<std::uint32_t>(c));
  }
  std::vector<std::uint32_t> candidates, next;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> asked;  // (cell, point)
  while (!pending.empty()) {
    candidates.clear();
    asked.clear();
    for (const std::uint32_t c : pending) {
      std::size_t best = n;
      for (std::uint32_t q = start[c]; q < start[c + 1]; ++q) {
        const std::uint32_t j = members[q];
        if (removed(j)) continue;
        if (best == n || zf[j] > zf[best]) best = j;
      }
      if (best == n || mean_d[best] >= 0.0f) continue;  // empty, or its front-most already passed
      candidates.push_back(static_cast<std::uint32_t>(best));
      asked.emplace_back(c, static_cast<std::uint32_t>(best));
    }
    test_all(candidates);
    next.clear();
    for (const auto& [c, j] : asked) {
      if (removed(j)) next.push_back(c);
    }
    pending.swap(next);
  }

  std::vector<bool> keep(cloud.size(), false);
  std::size_t tested = 0, n_removed = 0;
  for (std::size_t j = 0; j < n; ++j) {
    tested += mean_d[j] >= 0.0f ? 1u : 0u;
    const bool out = removed(j);
    n_removed += out ? 1u : 0u;
    keep[rows[j]] = !out;
  }
  cloud.keep_if(keep);
  report.count_out = cloud.size();
  report.figure("k", k);
  report.figure("std_multiplier", std_multiplier);
  report.figure("threshold_sample", static_cast<double>(m));
  report.figure("mean_knn_distance_mm", mean * 1e3);
  report.figure("stddev_knn_distance_mm", stddev * 1e3);
  report.figure("threshold_mm", threshold * 1e3);
  report.figure("tested", static_cast<double>(tested));
  report.figure("removed", static_cast<double>(n_removed));
  report.figure("removed_at_bbox", static_cast<double>(removed_at_bbox));
  report.figure("grid_rows", geo.rows);
  report.figure("grid_cols", geo.cols);
  report.figure("knn_grid_cell_mm", g.cell * 1e3);
  report.figure("knn_grid_build_s", t_grid);
  report.figure("threshold_sample_s", t_sample - t_grid);
  report.figure("bbox_s", t_box - t_sample);
  report.figure("bin_s", t_bin - t_box);
  report.figure("cells_s", seconds_since(t0) - t_bin);
  report.notes.push_back("scope front: tested " + std::to_string(tested) + " of " + std::to_string(n) +
                         " points (threshold sample and front-most candidates); the others are kept");
  if (n != report.count_in) {
    report.notes.push_back("dropped " + std::to_string(report.count_in - n) + " non-finite points");
  }
  report.seconds = seconds_since(t0);
  return {std::move(cloud), std::move(report)};
}

}  // namespace hc::pipeline
