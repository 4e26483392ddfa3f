#include "hc/pcl/conversions.hpp"

#include <cmath>
#include <cstddef>

namespace hc::pipeline {

namespace {

template <class PointT>
void write_xyz(const Cloud& cloud, pcl::PointCloud<PointT>& out) {
  const std::size_t n = cloud.size();
  out.resize(n);
  out.width = static_cast<std::uint32_t>(n);
  out.height = 1;
  bool dense = true;
  for (std::size_t i = 0; i < n; ++i) {
    const auto c = static_cast<Eigen::Index>(i);
    PointT& p = out[i];
    p.x = static_cast<float>(cloud.xyz(0, c));
    p.y = static_cast<float>(cloud.xyz(1, c));
    p.z = static_cast<float>(cloud.xyz(2, c));
    dense = dense && std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z);
  }
  out.is_dense = dense;
}

template <class PointT>
void write_rgb(const Cloud& cloud, pcl::PointCloud<PointT>& out) {
  const bool has = cloud.has_rgb();
  for (std::size_t i = 0; i < out.size(); ++i) {
    PointT& p = out[i];
    p.r = has ? cloud.rgb[3 * i] : 0;
    p.g = has ? cloud.rgb[3 * i + 1] : 0;
    p.b = has ? cloud.rgb[3 * i + 2] : 0;
    p.a = 255;
  }
}

template <class PointT>
Cloud read_xyz(const pcl::PointCloud<PointT>& in) {
  Cloud cloud;
  cloud.xyz.resize(3, static_cast<Eigen::Index>(in.size()));
  for (std::size_t i = 0; i < in.size(); ++i) {
    const auto c = static_cast<Eigen::Index>(i);
    cloud.xyz(0, c) = static_cast<double>(in[i].x);
    cloud.xyz(1, c) = static_cast<double>(in[i].y);
    cloud.xyz(2, c) = static_cast<double>(in[i].z);
  }
  cloud.float32_xyz = true;
  return cloud;
}

template <class PointT>
void read_rgb(const pcl::PointCloud<PointT>& in, Cloud& cloud) {
  cloud.rgb.resize(3 * in.size());
  for (std::size_t i = 0; i < in.size(); ++i) {
    cloud.rgb[3 * i] = in[i].r;
    cloud.rgb[3 * i + 1] = in[i].g;
    cloud.rgb[3 * i + 2] = in[i].b;
  }
}

}  // namespace

void to_pcl(const Cloud& cloud, pcl::PointCloud<pcl::PointXYZ>& out) { write_xyz(cloud, out); }

void to_pcl(const Cloud& cloud, pcl::PointCloud<pcl::PointXYZI>& out) {
  write_xyz(cloud, out);
  const bool has = cloud.has_intensity();
  for (std::size_t i = 0; i < out.size(); ++i) out[i].intensity = has ? cloud.intensity[i] : 0.0f;
}

void to_pcl(const Cloud& cloud, pcl::PointCloud<pcl::PointXYZRGB>& out) {
  write_xyz(cloud, out);
  write_rgb(cloud, out);
}

void to_pcl(const Cloud& cloud, pcl::PointCloud<pcl::PointXYZRGBNormal>& out) {
  write_xyz(cloud, out);
  write_rgb(cloud, out);
  const bool normals = cloud.normal.size() == 3 * out.size();
  const bool curvature = normals && cloud.curvature.size() == out.size();
  for (std::size_t i = 0; i < out.size(); ++i) {
    out[i].normal_x = normals ? cloud.normal[3 * i] : 0.0f;
    out[i].normal_y = normals ? cloud.normal[3 * i + 1] : 0.0f;
    out[i].normal_z = normals ? cloud.normal[3 * i + 2] : 0.0f;
    out[i].curvature = curvature ? cloud.curvature[i] : 0.0f;
  }
}

Cloud from_pcl(const pcl::PointCloud<pcl::PointXYZ>& in) { return read_xyz(in); }

Cloud from_pcl(const pcl::PointCloud<pcl::PointXYZI>& in) {
  Cloud cloud = read_xyz(in);
  cloud.intensity.resize(in.size());
  for (std::size_t i = 0; i < in.size(); ++i) cloud.intensity[i] = in[i].intensity;
  return cloud;
}

Cloud from_pcl(const pcl::PointCloud<pcl::PointXYZRGB>& in) {
  Cloud cloud = read_xyz(in);
  read_rgb(in, cloud);
  return cloud;
}

Cloud from_pcl(const pcl::PointCloud<pcl::PointXYZRGBNormal>& in) {
  Cloud cloud = read_xyz(in);
  read_rgb(in, cloud);
  cloud.normal.resize(3 * in.size());
  cloud.curvature.resize(in.size());
  for (std::size_t i = 0; i < in.size(); ++i) {
    cloud.normal[3 * i] = in[i].normal_x;
    cloud.normal[3 * i + 1] = in[i].normal_y;
    cloud.normal[3 * i + 2] = in[i].normal_z;
    cloud.curvature[i] = in[i].curvature;
  }
  return cloud;
}

BuiltScene build_scene(const pcl::PointCloud<pcl::PointXYZ>& cloud, const RunConfig& config, bool keep_cloud,
                       const ProgressFn& progress) {
  return build_scene(from_pcl(cloud), config, keep_cloud, progress);
}
BuiltScene build_scene(const pcl::PointCloud<pcl::PointXYZI>& cloud, const RunConfig& config, bool keep_cloud,
                       const ProgressFn& progress) {
  return build_scene(from_pcl(cloud), config, keep_cloud, progress);
}
BuiltScene build_scene(const pcl::PointCloud<pcl::PointXYZRGB>& cloud, const RunConfig& config, bool keep_cloud,
                       const ProgressFn& progress) {
  return build_scene(from_pcl(cloud), config, keep_cloud, progress);
}
BuiltScene build_scene(const pcl::PointCloud<pcl::PointXYZRGBNormal>& cloud, const RunConfig& config, bool keep_cloud,
                       const ProgressFn& progress) {
  return build_scene(from_pcl(cloud), config, keep_cloud, progress);
}

}  // namespace hc::pipeline
