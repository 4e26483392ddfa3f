#pragma once
/// @file conversions.hpp
/// hc::pcl (issue 18): hapticloud for PCL users. Conversions between the pipeline's cloud
/// (hc::pipeline::Cloud: xyz in double, optional colour and intensity) and PCL clouds, and
/// build_scene from an in-memory PCL cloud. This is the one public header that includes PCL:
/// link hc::pcl only where PCL is wanted (PCL headers compile slowly).
///
/// Field mapping (both ways):
///   x, y, z         ↔ Cloud::xyz (double ↔ float: to PCL rounds to the nearest float, so
///                     recentre georeferenced coordinates first; from PCL is exact)
///   intensity       ↔ Cloud::intensity (PointXYZI; float, exact)
///   r, g, b         ↔ Cloud::rgb (PointXYZRGB, PointXYZRGBNormal; 8 bit, exact)
///   a (alpha)       → 255 towards PCL; not kept from PCL (Cloud has no alpha)
///   normal_x/y/z    ↔ Cloud::normal (PointXYZRGBNormal; float, exact; 0 towards PCL when the
///                     Cloud has none). The pipeline keeps them through every subset filter and
///                     turns them with the view rotation; filters that make new points drop them
///   curvature       ↔ Cloud::curvature (PointXYZRGBNormal; float, exact; 0 when absent)
/// An attribute the Cloud lacks is written as 0 (intensity) or black (colour); from PCL every
/// field the point type has is filled. scan_id, row/col and faces have no place in these point
/// types and are not written. Organised PCL clouds (height > 1) are read row-major, point by
/// point; to_pcl writes an unorganised cloud (width = N, height = 1, is_dense = all finite).
/// Units and frame: whatever the cloud is in (a file's units after ingest, metres in the grid
/// frame for BuiltScene::cloud); nothing is scaled or moved.

#include "hc/pipeline/cloud.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/run.hpp"

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

namespace hc::pipeline {

/// Cloud → PCL. Point i of `out` is column i of cloud.xyz (non-finite points kept as NaN/inf,
/// then is_dense = false). `out` is resized to cloud.size(); header and sensor pose untouched.
/// Cost O(N). Thread-safe for distinct outputs. Never throws except std::bad_alloc.
void to_pcl(const Cloud& cloud, pcl::PointCloud<pcl::PointXYZ>& out);
void to_pcl(const Cloud& cloud, pcl::PointCloud<pcl::PointXYZI>& out);
void to_pcl(const Cloud& cloud, pcl::PointCloud<pcl::PointXYZRGB>& out);
void to_pcl(const Cloud& cloud, pcl::PointCloud<pcl::PointXYZRGBNormal>& out);

/// Cloud → a new PCL cloud of point type PointT (one of the four above).
template <class PointT>
typename pcl::PointCloud<PointT>::Ptr to_pcl(const Cloud& cloud) {
  typename pcl::PointCloud<PointT>::Ptr out(new pcl::PointCloud<PointT>);
  to_pcl(cloud, *out);
  return out;
}

/// PCL → Cloud: xyz (float widened to double, exact) and the attributes the point type carries
/// (intensity for PointXYZI, rgb for PointXYZRGB and PointXYZRGBNormal, and normal and curvature
/// for PointXYZRGBNormal). Cloud::float32_xyz is
/// set (the values carry 24 significant bits, which build_scene's precision check needs to know).
/// Non-finite points are kept (the pipeline's non_finite stage drops them and counts them).
/// Cost O(N). Never throws except std::bad_alloc.
Cloud from_pcl(const pcl::PointCloud<pcl::PointXYZ>& in);
Cloud from_pcl(const pcl::PointCloud<pcl::PointXYZI>& in);
Cloud from_pcl(const pcl::PointCloud<pcl::PointXYZRGB>& in);
Cloud from_pcl(const pcl::PointCloud<pcl::PointXYZRGBNormal>& in);

/// build_scene (run.hpp) on an in-memory PCL cloud: from_pcl(cloud), then every stage of the
/// run after ingest (units config.input.units, recentring, view transform, filters including
/// filters.pcl, grid, layers, cross-checks). config.input.files, conf and synthetic are not read
/// (load_run_config still requires one of them in a YAML file; a RunConfig built in code need
/// not). Colour and intensity reach the scene's layers as from a file.
/// @return the scene, its summary (stage reports, cross-check, verdict) and, with keep_cloud,
///         the filtered cloud in the grid frame [m] (to_pcl turns it back into a PCL cloud).
/// @throws as pipeline::build_scene (hc::InputError, hc::DegenerateInputError, hc::ConfigError).
BuiltScene build_scene(const pcl::PointCloud<pcl::PointXYZ>& cloud, const RunConfig& config, bool keep_cloud = false,
                       const ProgressFn& progress = {});
BuiltScene build_scene(const pcl::PointCloud<pcl::PointXYZI>& cloud, const RunConfig& config, bool keep_cloud = false,
                       const ProgressFn& progress = {});
BuiltScene build_scene(const pcl::PointCloud<pcl::PointXYZRGB>& cloud, const RunConfig& config, bool keep_cloud = false,
                       const ProgressFn& progress = {});
BuiltScene build_scene(const pcl::PointCloud<pcl::PointXYZRGBNormal>& cloud, const RunConfig& config,
                       bool keep_cloud = false, const ProgressFn& progress = {});

}  // namespace hc::pipeline
