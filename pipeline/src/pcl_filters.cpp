// filters.pcl (issue 18): PCL's own filter classes as pipeline stages. Every class is called
// through its public API on a pcl::PointXYZ copy of the cloud; subset filters hand back indices
// (FilterIndices::filter(Indices&), UniformSampling's removed indices, the cluster indices), so
// the original double points and their attributes survive; replacing filters hand back PCL's
// points. tests/pcl/pcl_filters_test.cpp compares every stage with the class called directly.

#include "hc/pipeline/pcl_filters.hpp"

#include "hc/common/error.hpp"
#include "hc/common/format.hpp"
#include "stage_util.hpp"

#include <pcl/filters/approximate_voxel_grid.h>
#include <pcl/filters/crop_box.h>
#include <pcl/filters/passthrough.h>
#include <pcl/filters/radius_outlier_removal.h>
#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/filters/uniform_sampling.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>
#include <pcl/segmentation/extract_clusters.h>
// pcl::extractEuclideanClusters is instantiated here, not taken from libpcl_segmentation (not
// linked: pipeline/CMakeLists.txt). Only that function template: the class's extract() would
// also instantiate OrganizedNeighbor, whose vtable copy here would then stand in for the one
// of Debian's C++14 libpcl_search in every program linking hc::pipeline.
#include <pcl/segmentation/impl/extract_clusters.hpp>
#include <pcl/surface/mls.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace hc::pipeline {

namespace {

using PointCloudXYZ = pcl::PointCloud<pcl::PointXYZ>;

[[noreturn]] void bad(const PclFilterSpec& s, const std::string& param, const std::string& what) {
  throw ConfigError("filters.pcl " + s.name + "." + param + " " + what);
}

/// PCL's VoxelGrid and UniformSampling index voxels with 32-bit integers: VoxelGrid returns its
/// input unchanged (a warning only) and UniformSampling overflows when the box holds more than
/// 2^31 − 1 voxels. Refuse such a leaf, naming the cloud's extent and the smallest leaf allowed.
void check_voxel_count(const PclFilterSpec& s, const char* param, double leaf_m, const PointCloudXYZ& in) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (const auto& p : in.points) {
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) continue;
    const Eigen::Vector3d q(p.x, p.y, p.z);
    lo = lo.cwiseMin(q);
    hi = hi.cwiseMax(q);
  }
  if (!(hi.x() >= lo.x())) return;  // no finite point: PCL returns nothing
  const Eigen::Vector3d ext = hi - lo;
  double voxels = 1.0;
  for (int a = 0; a < 3; ++a) voxels *= std::floor(ext[a] / leaf_m) + 1.0;
  constexpr double kMaxVoxels = 2147483647.0;
  if (voxels > kMaxVoxels) {
    const double smallest = std::cbrt((ext.x() + leaf_m) * (ext.y() + leaf_m) * (ext.z() + leaf_m) / kMaxVoxels);
    bad(s, param,
        "= " + format_number(leaf_m) + " m: the cloud spans " + format_number(ext.x()) + " x " + format_number(ext.y()) +
            " x " + format_number(ext.z()) + " m, " + format_number(voxels, 3) +
            " voxels, more than PCL's 32-bit voxel index holds (2^31 - 1); expected at least about " +
            format_number(smallest, 3) + " m, or crop first");
  }
}

void check_positive(const PclFilterSpec& s, const char* param, double v, double hi) {
  if (!std::isfinite(v) || !(v > 0.0) || v > hi) {
    bad(s, param, "= " + format_number(v) + ": expected a number in (0, " + format_number(hi) + "]");
  }
}

void check_int(const PclFilterSpec& s, const char* param, long long v, long long lo, long long hi) {
  if (v < lo || v > hi) {
    bad(s, param, "= " + std::to_string(v) + ": expected an integer in [" + std::to_string(lo) + ", " +
                      std::to_string(hi) + "]");
  }
}

/// The spec's own range checks (the config reader checks the same ranges at the key's line;
/// these guard callers that build specs in code).
void check_spec(const PclFilterSpec& s) {
  switch (s.kind) {
    case PclFilterKind::kStatisticalOutlierRemoval:
      check_int(s, "mean_k", s.mean_k, 1, 1000);
      check_positive(s, "stddev_mul", s.stddev_mul, 100.0);
      break;
    case PclFilterKind::kRadiusOutlierRemoval:
      check_positive(s, "radius_m", s.radius_m, 10.0);
      check_int(s, "min_neighbors", s.min_neighbors, 0, 1000000);
      break;
    case PclFilterKind::kVoxelGrid:
    case PclFilterKind::kApproximateVoxelGrid:
      check_positive(s, "leaf_m", s.leaf_m, 10.0);
      break;
    case PclFilterKind::kUniformSampling:
      check_positive(s, "radius_m", s.radius_m, 10.0);
      break;
    case PclFilterKind::kMovingLeastSquares:
      check_positive(s, "search_radius_m", s.search_radius_m, 10.0);
      check_int(s, "polynomial_order", s.polynomial_order, 0, 5);
      break;
    case PclFilterKind::kPassThrough:
      if (s.field != "x" && s.field != "y" && s.field != "z") bad(s, "field", "= '" + s.field + "': expected one of: x, y, z");
      if (!std::isfinite(s.min_m) || !std::isfinite(s.max_m) || s.min_m > s.max_m) {
        bad(s, "min_m", "= " + format_number(s.min_m) + ", max_m = " + format_number(s.max_m) +
                            ": expected finite limits with min_m <= max_m");
      }
      break;
    case PclFilterKind::kCropBox:
      if (!s.box_min_m.allFinite() || !s.box_max_m.allFinite() || (s.box_max_m.array() < s.box_min_m.array()).any()) {
        bad(s, "min_m", "and max_m: expected finite corners with min_m <= max_m on every axis");
      }
      break;
    case PclFilterKind::kEuclideanClusterExtraction:
      check_positive(s, "tolerance_m", s.tolerance_m, 10.0);
      check_int(s, "min_cluster_size", s.min_cluster_size, 1, 2147483647);
      check_int(s, "max_cluster_size", s.max_cluster_size, s.min_cluster_size, 2147483647);
      check_int(s, "keep_clusters", s.keep_clusters, 1, 1000000);
      break;
  }
}

/// Float copy of the finite points; rows[i] = the cloud column of PCL point i.
PointCloudXYZ::Ptr to_xyz(const Cloud& cloud, std::vector<std::uint32_t>& rows) {
  PointCloudXYZ::Ptr out(new PointCloudXYZ);
  out->reserve(cloud.size());
  rows.reserve(cloud.size());
  for (Eigen::Index i = 0; i < cloud.xyz.cols(); ++i) {
    const Eigen::Vector3f p = cloud.xyz.col(i).cast<float>();
    if (!p.allFinite()) continue;
    out->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
    rows.push_back(static_cast<std::uint32_t>(i));
  }
  out->is_dense = true;
  return out;
}

/// The cloud restricted to the PCL points `kept` (indices into the PCL cloud), in input order.
Cloud keep_indices(Cloud cloud, const std::vector<std::uint32_t>& rows, pcl::Indices kept) {
  std::sort(kept.begin(), kept.end());
  std::vector<bool> keep(cloud.size(), false);
  for (const auto k : kept) keep[rows[static_cast<std::size_t>(k)]] = true;
  cloud.keep_if(keep);
  return cloud;
}

/// A cloud of PCL's output points; attributes dropped (named in the report's notes).
Cloud from_points(const Cloud& in, const PointCloudXYZ& out, StageReport& report) {
  Cloud result;
  result.xyz.resize(3, static_cast<Eigen::Index>(out.size()));
  for (std::size_t i = 0; i < out.size(); ++i) {
    result.xyz.col(static_cast<Eigen::Index>(i)) = out[i].getVector3fMap().cast<double>();
  }
  std::string dropped;
  auto item = [&](bool has, const char* what) {
    if (has) dropped += (dropped.empty() ? "" : ", ") + std::string(what);
  };
  item(in.has_rgb(), "colour");
  item(in.has_intensity(), "intensity");
  item(in.has_scan_id(), "scan_id");
  item(in.has_grid_index(), "row/col");
  item(in.has_normals(), "normals and curvature");
  item(in.has_mesh(), "faces");
  if (!dropped.empty()) report.notes.push_back(dropped + " dropped: this filter outputs new points");
  result.crs = in.crs;
  return result;
}

}  // namespace

bool pcl_filter_replaces_points(PclFilterKind kind) {
  return kind == PclFilterKind::kVoxelGrid || kind == PclFilterKind::kApproximateVoxelGrid ||
         kind == PclFilterKind::kMovingLeastSquares;
}

double pcl_filter_displacement_m(const PclFilterSpec& spec) {
  switch (spec.kind) {
    case PclFilterKind::kVoxelGrid:
    case PclFilterKind::kApproximateVoxelGrid:
      return spec.leaf_m;
    case PclFilterKind::kMovingLeastSquares:
      return spec.search_radius_m;
    default:
      return 0.0;
  }
}

StageResult<Cloud> apply_pcl_filter(Cloud cloud, const PclFilterSpec& spec) {
  const auto t0 = detail::Clock::now();
  check_spec(spec);
  StageResult<Cloud> r;
  StageReport& rep = r.report;
  rep.stage = "pcl:" + spec.name;
  rep.count_in = cloud.size();
  std::vector<std::uint32_t> rows;
  const PointCloudXYZ::Ptr in = to_xyz(cloud, rows);
  if (in->empty()) throw InputError("filters.pcl " + spec.name + ": the cloud has no finite points to filter");
  if (in->size() != cloud.size()) {
    rep.notes.push_back(std::to_string(cloud.size() - in->size()) + " non-finite points dropped before the filter");
  }
  pcl::Indices kept;
  bool subset = true;
  PointCloudXYZ out;
  switch (spec.kind) {
    case PclFilterKind::kStatisticalOutlierRemoval: {
      pcl::StatisticalOutlierRemoval<pcl::PointXYZ> f;
      f.setInputCloud(in);
      f.setMeanK(spec.mean_k);
      f.setStddevMulThresh(spec.stddev_mul);
      f.filter(kept);
      rep.figure("mean_k", spec.mean_k);
      rep.figure("stddev_mul", spec.stddev_mul);
      break;
    }
    case PclFilterKind::kRadiusOutlierRemoval: {
      pcl::RadiusOutlierRemoval<pcl::PointXYZ> f;
      f.setInputCloud(in);
      f.setRadiusSearch(spec.radius_m);
      f.setMinNeighborsInRadius(spec.min_neighbors);
      f.filter(kept);
      rep.figure("radius_mm", spec.radius_m * 1e3);
      rep.figure("min_neighbors", spec.min_neighbors);
      break;
    }
    case PclFilterKind::kPassThrough: {
      pcl::PassThrough<pcl::PointXYZ> f;
      f.setInputCloud(in);
      f.setFilterFieldName(spec.field);
      f.setFilterLimits(static_cast<float>(spec.min_m), static_cast<float>(spec.max_m));
      f.setNegative(spec.negative);
      f.filter(kept);
      rep.figure("min_mm", spec.min_m * 1e3);
      rep.figure("max_mm", spec.max_m * 1e3);
      break;
    }
    case PclFilterKind::kCropBox: {
      pcl::CropBox<pcl::PointXYZ> f;
      f.setInputCloud(in);
      const Eigen::Vector3f lo = spec.box_min_m.cast<float>(), hi = spec.box_max_m.cast<float>();
      f.setMin(Eigen::Vector4f(lo.x(), lo.y(), lo.z(), 1.0f));
      f.setMax(Eigen::Vector4f(hi.x(), hi.y(), hi.z(), 1.0f));
      f.setNegative(spec.negative);
      f.filter(kept);
      break;
    }
    case PclFilterKind::kUniformSampling: {
      check_voxel_count(spec, "radius_m", spec.radius_m, *in);
      pcl::UniformSampling<pcl::PointXYZ> f(/*extract_removed_indices=*/true);
      f.setInputCloud(in);
      f.setRadiusSearch(spec.radius_m);
      f.filter(out);
      std::vector<bool> removed(in->size(), false);
      for (const auto i : *f.getRemovedIndices()) removed[static_cast<std::size_t>(i)] = true;
      for (std::size_t i = 0; i < in->size(); ++i) {
        if (!removed[i]) kept.push_back(static_cast<pcl::index_t>(i));
      }
      if (kept.size() != out.size()) {
        // Never misalign attributes: PCL's removed list must be the complement of its output.
        throw InputError("filters.pcl UniformSampling: " + std::to_string(kept.size()) + " kept indices but " +
                            std::to_string(out.size()) + " output points");
      }
      rep.figure("radius_mm", spec.radius_m * 1e3);
      break;
    }
    case PclFilterKind::kEuclideanClusterExtraction: {
      // What pcl::EuclideanClusterExtraction::extract does with a k-d tree given and no
      // indices: the single-linkage clusters of the whole cloud, then sorted by size with
      // PCL's own comparison, largest first (tests/pcl compare it with the class).
      pcl::search::Search<pcl::PointXYZ>::Ptr tree(new pcl::search::KdTree<pcl::PointXYZ>);
      tree->setInputCloud(in);
      std::vector<pcl::PointIndices> clusters;
      if (!in->empty()) {
        pcl::extractEuclideanClusters(*in, tree, static_cast<float>(spec.tolerance_m), clusters,
                                      static_cast<unsigned int>(spec.min_cluster_size),
                                      static_cast<unsigned int>(spec.max_cluster_size));
      }
      std::sort(clusters.rbegin(), clusters.rend(), pcl::comparePointClusters);
      const std::size_t n = std::min<std::size_t>(clusters.size(), static_cast<std::size_t>(spec.keep_clusters));
      for (std::size_t c = 0; c < n; ++c) kept.insert(kept.end(), clusters[c].indices.begin(), clusters[c].indices.end());
      rep.figure("tolerance_mm", spec.tolerance_m * 1e3);
      rep.figure("clusters", static_cast<double>(clusters.size()));
      rep.figure("clusters_kept", static_cast<double>(n));
      if (clusters.empty()) rep.notes.push_back("no cluster within [min_cluster_size, max_cluster_size]: every point removed");
      break;
    }
    case PclFilterKind::kVoxelGrid: {
      subset = false;
      check_voxel_count(spec, "leaf_m", spec.leaf_m, *in);
      pcl::VoxelGrid<pcl::PointXYZ> f;
      f.setInputCloud(in);
      const auto leaf = static_cast<float>(spec.leaf_m);
      f.setLeafSize(leaf, leaf, leaf);
      f.filter(out);
      rep.figure("leaf_mm", spec.leaf_m * 1e3);
      break;
    }
    case PclFilterKind::kApproximateVoxelGrid: {
      subset = false;
      pcl::ApproximateVoxelGrid<pcl::PointXYZ> f;
      f.setInputCloud(in);
      const auto leaf = static_cast<float>(spec.leaf_m);
      f.setLeafSize(leaf, leaf, leaf);
      f.filter(out);
      rep.figure("leaf_mm", spec.leaf_m * 1e3);
      break;
    }
    case PclFilterKind::kMovingLeastSquares: {
      subset = false;
      pcl::search::KdTree<pcl::PointXYZ>::Ptr tree(new pcl::search::KdTree<pcl::PointXYZ>);
      pcl::MovingLeastSquares<pcl::PointXYZ, pcl::PointXYZ> f;
      f.setInputCloud(in);
      f.setSearchMethod(tree);
      f.setSearchRadius(spec.search_radius_m);
      f.setPolynomialOrder(spec.polynomial_order);
      f.setComputeNormals(false);
      f.process(out);
      rep.figure("search_radius_mm", spec.search_radius_m * 1e3);
      rep.figure("polynomial_order", spec.polynomial_order);
      break;
    }
  }
  if (subset) {
    r.value = keep_indices(std::move(cloud), rows, std::move(kept));
  } else {
    r.value = from_points(cloud, out, rep);
  }
  rep.count_out = r.value.size();
  rep.seconds = detail::seconds_since(t0);
  return r;
}

}  // namespace hc::pipeline
