#include "hc/pipeline/cloud.hpp"

#include <algorithm>
#include <cassert>

namespace hc::pipeline {

namespace {

/// Moves the points [from, from + count) to slot `to` (≤ from) in a per-point attribute with
/// `stride` values per point (one memmove: the ranges may overlap); an empty attribute (the
/// cloud has none) is left as it is.
template <class T>
void move_run(std::vector<T>& v, std::size_t to, std::size_t from, std::size_t count, std::size_t stride) {
  if (v.empty() || to == from || count == 0) return;
  std::copy(v.begin() + static_cast<std::ptrdiff_t>(from * stride), v.begin() + static_cast<std::ptrdiff_t>((from + count) * stride),
            v.begin() + static_cast<std::ptrdiff_t>(to * stride));
}

}  // namespace

void Cloud::keep_if(const std::vector<bool>& keep) {
  assert(keep.size() == size());
  if (has_mesh()) {  // renumber the triangles whose three points stay; drop the others
    constexpr std::uint32_t kGone = 0xFFFFFFFFu;
    std::vector<std::uint32_t> new_index(size(), kGone);
    std::uint32_t next = 0;
    for (std::size_t i = 0; i < size(); ++i) {
      if (keep[i]) new_index[i] = next++;
    }
    const bool uv = !mesh.corner_uv.empty();
    std::size_t t_out = 0;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
      std::array<std::uint32_t, 3> tri = mesh.triangles[t];
      bool all = true;
      for (auto& v : tri) {
        v = v < new_index.size() ? new_index[v] : kGone;
        all = all && v != kGone;
      }
      if (!all) continue;
      mesh.triangles[t_out] = tri;
      if (uv) std::copy_n(mesh.corner_uv.begin() + static_cast<std::ptrdiff_t>(6 * t), 6,
                          mesh.corner_uv.begin() + static_cast<std::ptrdiff_t>(6 * t_out));
      ++t_out;
    }
    mesh.triangles.resize(t_out);
    if (uv) mesh.corner_uv.resize(6 * t_out);
  }
  // Runs of kept points moved as blocks: fast when the removed points are few (the outlier,
  // isolated and despike stages remove a few hundred of a million: a handful of runs); runs of
  // one point cost about what a point-by-point copy does.
  const std::size_t n = size();
  double* p = xyz.data();
  std::size_t out = 0;
  for (std::size_t i = 0; i < n;) {
    if (!keep[i]) {
      ++i;
      continue;
    }
    std::size_t j = i + 1;
    while (j < n && keep[j]) ++j;
    const std::size_t count = j - i;
    if (out != i) {
      std::copy(p + 3 * i, p + 3 * j, p + 3 * out);  // to ≤ from: a forward copy
      move_run(scan_id, out, i, count, 1);
      move_run(intensity, out, i, count, 1);
      move_run(rgb, out, i, count, 3);
      move_run(normal, out, i, count, 3);
      move_run(curvature, out, i, count, 1);
      if (has_grid_index()) {
        move_run(row, out, i, count, 1);
        move_run(col, out, i, count, 1);
      }
    }
    out += count;
    i = j;
  }
  xyz.conservativeResize(Eigen::NoChange, static_cast<Eigen::Index>(out));
  if (has_scan_id()) scan_id.resize(out);
  if (has_intensity()) intensity.resize(out);
  if (has_rgb()) rgb.resize(3 * out);
  if (has_normals()) normal.resize(3 * out);
  if (!curvature.empty()) curvature.resize(out);
  if (has_grid_index()) {
    row.resize(out);
    col.resize(out);
  }
}

std::vector<std::string> Cloud::append(const Cloud& other) {
  std::vector<std::string> dropped;
  const bool first = size() == 0;
  auto join = [&](auto& mine, const auto& theirs, const char* name) {
    if (first) {
      mine = theirs;
    } else if (mine.empty() != theirs.empty()) {
      if (!mine.empty() || !theirs.empty()) dropped.push_back(name);
      mine.clear();
    } else {
      mine.insert(mine.end(), theirs.begin(), theirs.end());
    }
  };
  join(scan_id, other.scan_id, "scan_id");
  join(intensity, other.intensity, "intensity");
  join(rgb, other.rgb, "rgb");
  join(normal, other.normal, "normal");
  join(curvature, other.curvature, "curvature");
  if (normal.empty() && !curvature.empty()) {  // curvature only travels with its normals
    curvature.clear();
    dropped.push_back("curvature");
  }
  join(row, other.row, "row");
  join(col, other.col, "col");
  if (row.empty() != col.empty()) {
    row.clear();
    col.clear();
  }
  if (first || crs.empty()) crs = other.crs;  // the first CRS found is kept
  // Any float-stored part limits the precision of the whole.
  float32_xyz = first ? other.float32_xyz : (float32_xyz || other.float32_xyz);
  const Eigen::Index n = xyz.cols();
  if (first) {
    mesh = other.mesh;
  } else if (!other.mesh.empty()) {
    const bool uv = mesh.has_texture() && other.mesh.has_texture() && mesh.texture == other.mesh.texture;
    if (!uv && (mesh.has_texture() || other.mesh.has_texture())) dropped.push_back("texture");
    if (!uv) {
      mesh.corner_uv.clear();
      mesh.texture.reset();
    }
    const auto offset = static_cast<std::uint32_t>(n);
    for (auto tri : other.mesh.triangles) {
      for (auto& v : tri) v += offset;
      mesh.triangles.push_back(tri);
    }
    if (uv) mesh.corner_uv.insert(mesh.corner_uv.end(), other.mesh.corner_uv.begin(), other.mesh.corner_uv.end());
  }
  xyz.conservativeResize(Eigen::NoChange, n + other.xyz.cols());
  xyz.rightCols(other.xyz.cols()) = other.xyz;
  return dropped;
}

}  // namespace hc::pipeline
