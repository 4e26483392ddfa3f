#pragma once
/// @file cloud_fixtures.hpp
/// Small point-cloud builders shared by the pipeline tests.

#include "hc/pipeline/cloud.hpp"

#include <Eigen/Core>

#include <vector>

namespace hc::test {

/// A Cloud (3 × N, same units as the input) holding `pts` in order, without scan ids.
inline pipeline::Cloud cloud_of(const std::vector<Eigen::Vector3d>& pts) {
  pipeline::Cloud c;
  c.xyz.resize(3, static_cast<Eigen::Index>(pts.size()));
  for (std::size_t i = 0; i < pts.size(); ++i) c.xyz.col(static_cast<Eigen::Index>(i)) = pts[i];
  return c;
}

}  // namespace hc::test
