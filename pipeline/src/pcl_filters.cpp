// filters.pcl (issue 18): PCL's own filter classes as pipeline stages. Every class is called
// through its public API on a pcl::PointXYZ copy of the cloud, in the PCL module hc_pcl.so
// (pipeline/pcl/pcl_module.cpp, loaded on first use: modules.hpp); subset filters hand back indices
// (FilterIndices::filter(Indices&), UniformSampling's removed indices, the cluster indices), so
// the original double points and their attributes survive; replacing filters hand back PCL's
// points. tests/pcl/pcl_filters_test.cpp compares every stage with the class called directly.

#include "hc/pipeline/pcl_filters.hpp"

#include "hc/common/error.hpp"
#include "hc/common/format.hpp"
#include "modules.hpp"
#include "stage_util.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace hc::pipeline {

namespace {

[[noreturn]] void bad(const PclFilterSpec& s, const std::string& param, const std::string& what) {
  throw ConfigError("filters.pcl " + s.name + "." + param + " " + what);
}

/// PCL's VoxelGrid and UniformSampling index voxels with 32-bit integers: VoxelGrid returns its
/// input unchanged (a warning only) and UniformSampling overflows when the box holds more than
/// 2^31 − 1 voxels. Refuse such a leaf, naming the cloud's extent and the smallest leaf allowed.
void check_voxel_count(const PclFilterSpec& s, const char* param, double leaf_m, const std::vector<float>& in) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (std::size_t i = 0; i + 2 < in.size(); i += 3) {
    const Eigen::Vector3d q(in[i], in[i + 1], in[i + 2]);
    if (!q.allFinite()) continue;
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

/// Float copy of the finite points (x y z each); rows[i] = the cloud column of PCL point i.
std::vector<float> to_xyz(const Cloud& cloud, std::vector<std::uint32_t>& rows) {
  std::vector<float> out;
  out.reserve(3 * cloud.size());
  rows.reserve(cloud.size());
  for (Eigen::Index i = 0; i < cloud.xyz.cols(); ++i) {
    const Eigen::Vector3f p = cloud.xyz.col(i).cast<float>();
    if (!p.allFinite()) continue;
    out.insert(out.end(), {p.x(), p.y(), p.z()});
    rows.push_back(static_cast<std::uint32_t>(i));
  }
  return out;
}

/// The cloud restricted to the PCL points `kept` (indices into the PCL cloud), in input order.
Cloud keep_indices(Cloud cloud, const std::vector<std::uint32_t>& rows, std::vector<std::uint32_t> kept) {
  std::sort(kept.begin(), kept.end());
  std::vector<bool> keep(cloud.size(), false);
  for (const auto k : kept) keep[rows[k]] = true;
  cloud.keep_if(keep);
  return cloud;
}

/// A cloud of PCL's output points; attributes dropped (named in the report's notes).
Cloud from_points(const Cloud& in, const float* out, std::size_t n_out, StageReport& report) {
  Cloud result;
  result.xyz.resize(3, static_cast<Eigen::Index>(n_out));
  for (std::size_t i = 0; i < n_out; ++i) {
    for (int a = 0; a < 3; ++a) result.xyz(a, static_cast<Eigen::Index>(i)) = static_cast<double>(out[3 * i + static_cast<std::size_t>(a)]);
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
  const std::vector<float> in = to_xyz(cloud, rows);
  if (in.empty()) throw InputError("filters.pcl " + spec.name + ": the cloud has no finite points to filter");
  if (rows.size() != cloud.size()) {
    rep.notes.push_back(std::to_string(cloud.size() - rows.size()) + " non-finite points dropped before the filter");
  }
  if (spec.kind == PclFilterKind::kUniformSampling) check_voxel_count(spec, "radius_m", spec.radius_m, in);
  if (spec.kind == PclFilterKind::kVoxelGrid) check_voxel_count(spec, "leaf_m", spec.leaf_m, in);
  const detail::PclModule& pcl = detail::pcl_module("filters.pcl " + spec.name);
  HcPclFilterJob job{};
  job.abi = HC_PCL_ABI;
  job.kind = static_cast<int>(spec.kind);
  job.xyz = in.data();
  job.n = rows.size();
  job.mean_k = spec.mean_k;
  job.stddev_mul = spec.stddev_mul;
  job.radius_m = spec.radius_m;
  job.min_neighbors = spec.min_neighbors;
  job.leaf_m = spec.leaf_m;
  job.search_radius_m = spec.search_radius_m;
  job.polynomial_order = spec.polynomial_order;
  job.field = spec.field.empty() ? 'z' : spec.field[0];
  job.min_m = spec.min_m;
  job.max_m = spec.max_m;
  for (int a = 0; a < 3; ++a) {
    job.box_min_m[a] = spec.box_min_m[a];
    job.box_max_m[a] = spec.box_max_m[a];
  }
  job.negative = spec.negative ? 1 : 0;
  job.tolerance_m = spec.tolerance_m;
  job.min_cluster_size = spec.min_cluster_size;
  job.max_cluster_size = spec.max_cluster_size;
  job.keep_clusters = spec.keep_clusters;
  HcPclFilterResult res{};
  const int rc = pcl.filter(&job, &res);
  const detail::PclFilterResultGuard release{pcl, res};  // the module's buffers, on every way out
  if (rc != 0) throw InputError("filters.pcl " + spec.name + ": " + res.what + ": " + res.detail);
  switch (spec.kind) {
    case PclFilterKind::kStatisticalOutlierRemoval:
      rep.figure("mean_k", spec.mean_k);
      rep.figure("stddev_mul", spec.stddev_mul);
      break;
    case PclFilterKind::kRadiusOutlierRemoval:
      rep.figure("radius_mm", spec.radius_m * 1e3);
      rep.figure("min_neighbors", spec.min_neighbors);
      break;
    case PclFilterKind::kPassThrough:
      rep.figure("min_mm", spec.min_m * 1e3);
      rep.figure("max_mm", spec.max_m * 1e3);
      break;
    case PclFilterKind::kCropBox:
      break;
    case PclFilterKind::kUniformSampling:
      rep.figure("radius_mm", spec.radius_m * 1e3);
      break;
    case PclFilterKind::kEuclideanClusterExtraction: {
      const std::size_t n = std::min<std::size_t>(res.clusters, static_cast<std::size_t>(spec.keep_clusters));
      rep.figure("tolerance_mm", spec.tolerance_m * 1e3);
      rep.figure("clusters", static_cast<double>(res.clusters));
      rep.figure("clusters_kept", static_cast<double>(n));
      if (res.clusters == 0) rep.notes.push_back("no cluster within [min_cluster_size, max_cluster_size]: every point removed");
      break;
    }
    case PclFilterKind::kVoxelGrid:
    case PclFilterKind::kApproximateVoxelGrid:
      rep.figure("leaf_mm", spec.leaf_m * 1e3);
      break;
    case PclFilterKind::kMovingLeastSquares:
      rep.figure("search_radius_mm", spec.search_radius_m * 1e3);
      rep.figure("polynomial_order", spec.polynomial_order);
      break;
  }
  if (res.subset) {
    for (std::size_t i = 0; i < res.n_kept; ++i) {
      if (res.kept[i] >= rows.size()) {
        throw InputError("filters.pcl " + spec.name + ": PCL returned index " + std::to_string(res.kept[i]) + " for " +
                         std::to_string(rows.size()) + " points");
      }
    }
    r.value = keep_indices(std::move(cloud), rows, std::vector<std::uint32_t>(res.kept, res.kept + res.n_kept));
  } else {
    r.value = from_points(cloud, res.xyz, res.n_out, rep);
  }
  rep.count_out = r.value.size();
  rep.seconds = detail::seconds_since(t0);
  return r;
}

}  // namespace hc::pipeline
