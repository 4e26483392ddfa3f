// The PCL module hc_pcl.so (interface pipeline/src/pcl_module.h): PCL's filter classes behind a C interface, loaded by hc::pipeline on first use so that no other command
// pays PCL's start-up. Each entry point catches every exception; nothing C++ crosses the
// boundary. The host (pcl_filters.cpp, filters.cpp) checks the parameters,
// copies the points in and maps the result back onto its cloud.

#include "pcl_module.h"

#include <pcl/exceptions.h>
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
// linked). Only that function template: the class's extract() would also instantiate
// OrganizedNeighbor, whose vtable copy here would then stand in for the one of Debian's C++14
// libpcl_search.
#include <pcl/segmentation/impl/extract_clusters.hpp>
#include <pcl/surface/mls.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <limits>
#include <string>
#include <vector>

namespace {

using PointCloudXYZ = pcl::PointCloud<pcl::PointXYZ>;

// For the catch blocks: no allocation, so nothing can throw out of an entry point.
void put_c(char* out, std::size_t size, const char* a, const char* b = "") noexcept {
  std::snprintf(out, size, "%s%s", a, b);
}

template <class T>
T* copy_out(const std::vector<T>& v) {
  if (v.empty()) return nullptr;
  auto* p = static_cast<T*>(std::malloc(v.size() * sizeof(T)));
  if (p == nullptr) throw std::bad_alloc();
  std::memcpy(p, v.data(), v.size() * sizeof(T));
  return p;
}

// The filter of the job; the kept indices (subset filters) or the new points in `out`.
void run_filter(const HcPclFilterJob& job, const PointCloudXYZ::Ptr& in, HcPclFilterResult& result,
                std::vector<std::uint32_t>& kept_out, PointCloudXYZ& out) {
  pcl::Indices kept;
  result.subset = 1;
  switch (job.kind) {
    case HC_PCL_STATISTICAL_OUTLIER_REMOVAL: {
      pcl::StatisticalOutlierRemoval<pcl::PointXYZ> f;
      f.setInputCloud(in);
      f.setMeanK(job.mean_k);
      f.setStddevMulThresh(job.stddev_mul);
      f.filter(kept);
      break;
    }
    case HC_PCL_RADIUS_OUTLIER_REMOVAL: {
      pcl::RadiusOutlierRemoval<pcl::PointXYZ> f;
      f.setInputCloud(in);
      f.setRadiusSearch(job.radius_m);
      f.setMinNeighborsInRadius(job.min_neighbors);
      f.filter(kept);
      break;
    }
    case HC_PCL_PASS_THROUGH: {
      pcl::PassThrough<pcl::PointXYZ> f;
      f.setInputCloud(in);
      f.setFilterFieldName(std::string(1, job.field));
      f.setFilterLimits(static_cast<float>(job.min_m), static_cast<float>(job.max_m));
      f.setNegative(job.negative != 0);
      f.filter(kept);
      break;
    }
    case HC_PCL_CROP_BOX: {
      pcl::CropBox<pcl::PointXYZ> f;
      f.setInputCloud(in);
      f.setMin(Eigen::Vector4f(static_cast<float>(job.box_min_m[0]), static_cast<float>(job.box_min_m[1]),
                               static_cast<float>(job.box_min_m[2]), 1.0f));
      f.setMax(Eigen::Vector4f(static_cast<float>(job.box_max_m[0]), static_cast<float>(job.box_max_m[1]),
                               static_cast<float>(job.box_max_m[2]), 1.0f));
      f.setNegative(job.negative != 0);
      f.filter(kept);
      break;
    }
    case HC_PCL_UNIFORM_SAMPLING: {
      pcl::UniformSampling<pcl::PointXYZ> f(/*extract_removed_indices=*/true);
      f.setInputCloud(in);
      f.setRadiusSearch(job.radius_m);
      f.filter(out);
      std::vector<bool> removed(in->size(), false);
      for (const auto i : *f.getRemovedIndices()) removed[static_cast<std::size_t>(i)] = true;
      for (std::size_t i = 0; i < in->size(); ++i) {
        if (!removed[i]) kept.push_back(static_cast<pcl::index_t>(i));
      }
      if (kept.size() != out.size()) {
        // Never misalign attributes: PCL's removed list must be the complement of its output.
        throw std::runtime_error(std::to_string(kept.size()) + " kept indices but " + std::to_string(out.size()) +
                                 " output points");
      }
      break;
    }
    case HC_PCL_EUCLIDEAN_CLUSTER_EXTRACTION: {
      // What pcl::EuclideanClusterExtraction::extract does with a k-d tree given and no
      // indices: the single-linkage clusters of the whole cloud, then sorted by size with
      // PCL's own comparison, largest first (tests/pcl compare it with the class).
      pcl::search::Search<pcl::PointXYZ>::Ptr tree(new pcl::search::KdTree<pcl::PointXYZ>);
      tree->setInputCloud(in);
      std::vector<pcl::PointIndices> clusters;
      if (!in->empty()) {
        pcl::extractEuclideanClusters(*in, tree, static_cast<float>(job.tolerance_m), clusters,
                                      static_cast<unsigned int>(job.min_cluster_size),
                                      static_cast<unsigned int>(job.max_cluster_size));
      }
      std::sort(clusters.rbegin(), clusters.rend(), pcl::comparePointClusters);
      const std::size_t n = std::min<std::size_t>(clusters.size(), static_cast<std::size_t>(job.keep_clusters));
      for (std::size_t c = 0; c < n; ++c) kept.insert(kept.end(), clusters[c].indices.begin(), clusters[c].indices.end());
      result.clusters = clusters.size();
      break;
    }
    case HC_PCL_VOXEL_GRID: {
      result.subset = 0;
      pcl::VoxelGrid<pcl::PointXYZ> f;
      f.setInputCloud(in);
      const auto leaf = static_cast<float>(job.leaf_m);
      f.setLeafSize(leaf, leaf, leaf);
      f.filter(out);
      break;
    }
    case HC_PCL_APPROXIMATE_VOXEL_GRID: {
      result.subset = 0;
      pcl::ApproximateVoxelGrid<pcl::PointXYZ> f;
      f.setInputCloud(in);
      const auto leaf = static_cast<float>(job.leaf_m);
      f.setLeafSize(leaf, leaf, leaf);
      f.filter(out);
      break;
    }
    case HC_PCL_MOVING_LEAST_SQUARES: {
      result.subset = 0;
      pcl::search::KdTree<pcl::PointXYZ>::Ptr tree(new pcl::search::KdTree<pcl::PointXYZ>);
      pcl::MovingLeastSquares<pcl::PointXYZ, pcl::PointXYZ> f;
      f.setInputCloud(in);
      f.setSearchMethod(tree);
      f.setSearchRadius(job.search_radius_m);
      f.setPolynomialOrder(job.polynomial_order);
      f.setComputeNormals(false);
      f.process(out);
      break;
    }
    default:
      throw std::invalid_argument("unknown filter kind " + std::to_string(job.kind));
  }
  kept_out.assign(kept.begin(), kept.end());
}

}  // namespace

extern "C" __attribute__((visibility("default"))) int hc_pcl_filter(const HcPclFilterJob* job, HcPclFilterResult* result) {
  if (job == nullptr || result == nullptr) return 1;
  *result = HcPclFilterResult{};
  if (job->abi != HC_PCL_ABI) {
    put_c(result->what, sizeof result->what, "ABI mismatch");
    std::snprintf(result->detail, sizeof result->detail, "the module speaks ABI %d, the host %d", HC_PCL_ABI, job->abi);
    return 1;
  }
  try {
    PointCloudXYZ::Ptr in(new PointCloudXYZ);
    in->resize(job->n);
    for (std::size_t i = 0; i < job->n; ++i) (*in)[i] = pcl::PointXYZ(job->xyz[3 * i], job->xyz[3 * i + 1], job->xyz[3 * i + 2]);
    in->is_dense = true;
    std::vector<std::uint32_t> kept;
    PointCloudXYZ out;
    run_filter(*job, in, *result, kept, out);
    if (result->subset) {
      result->kept = copy_out(kept);
      result->n_kept = kept.size();
    } else {
      std::vector<float> xyz(3 * out.size());
      for (std::size_t i = 0; i < out.size(); ++i) {
        xyz[3 * i] = out[i].x;
        xyz[3 * i + 1] = out[i].y;
        xyz[3 * i + 2] = out[i].z;
      }
      result->xyz = copy_out(xyz);
      result->n_out = out.size();
    }
    return 0;
  } catch (const std::exception& e) {
    std::free(result->kept);
    std::free(result->xyz);
    result->kept = nullptr;
    result->xyz = nullptr;
    put_c(result->what, sizeof result->what, "PCL failed");
    put_c(result->detail, sizeof result->detail, e.what());
  } catch (...) {
    std::free(result->kept);
    std::free(result->xyz);
    result->kept = nullptr;
    result->xyz = nullptr;
    put_c(result->what, sizeof result->what, "PCL failed");
    put_c(result->detail, sizeof result->detail, "an unknown exception");
  }
  return 1;
}

extern "C" __attribute__((visibility("default"))) void hc_pcl_free(void* p) { std::free(p); }
