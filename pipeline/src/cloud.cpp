#include "hc/pipeline/cloud.hpp"

#include <cassert>

namespace hc::pipeline {

namespace {

/// Moves element i to slot out in a per-point attribute with `stride` values per point.
template <class T>
void move_point(std::vector<T>& v, std::size_t out, std::size_t i, std::size_t stride) {
  for (std::size_t k = 0; k < stride; ++k) v[out * stride + k] = v[i * stride + k];
}

}  // namespace

void Cloud::keep_if(const std::vector<bool>& keep) {
  assert(keep.size() == size());
  std::size_t out = 0;
  for (std::size_t i = 0; i < size(); ++i) {
    if (!keep[i]) continue;
    if (out != i) {
      xyz.col(static_cast<Eigen::Index>(out)) = xyz.col(static_cast<Eigen::Index>(i));
      if (has_scan_id()) move_point(scan_id, out, i, 1);
      if (has_intensity()) move_point(intensity, out, i, 1);
      if (has_rgb()) move_point(rgb, out, i, 3);
      if (has_grid_index()) {
        move_point(row, out, i, 1);
        move_point(col, out, i, 1);
      }
    }
    ++out;
  }
  xyz.conservativeResize(Eigen::NoChange, static_cast<Eigen::Index>(out));
  if (has_scan_id()) scan_id.resize(out);
  if (has_intensity()) intensity.resize(out);
  if (has_rgb()) rgb.resize(3 * out);
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
  xyz.conservativeResize(Eigen::NoChange, n + other.xyz.cols());
  xyz.rightCols(other.xyz.cols()) = other.xyz;
  return dropped;
}

}  // namespace hc::pipeline
