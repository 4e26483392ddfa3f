#include "hc/pipeline/cloud.hpp"

#include <cassert>

namespace hc::pipeline {

void Cloud::keep_if(const std::vector<bool>& keep) {
  assert(keep.size() == size());
  Eigen::Index out = 0;
  for (Eigen::Index i = 0; i < xyz.cols(); ++i) {
    if (!keep[static_cast<std::size_t>(i)]) continue;
    if (out != i) {
      xyz.col(out) = xyz.col(i);
      if (has_scan_id()) scan_id[static_cast<std::size_t>(out)] = scan_id[static_cast<std::size_t>(i)];
    }
    ++out;
  }
  xyz.conservativeResize(Eigen::NoChange, out);
  if (has_scan_id()) scan_id.resize(static_cast<std::size_t>(out));
}

}  // namespace hc::pipeline
