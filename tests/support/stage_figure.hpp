#pragma once
/// @file stage_figure.hpp
/// Reading one named figure out of a pipeline stage report in tests.

#include "hc/pipeline/cloud.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

namespace hc::test {

/// The figure `name` of stage report `r`; a missing figure fails the calling test and gives NaN.
inline double figure(const pipeline::StageReport& r, const std::string& name) {
  for (const auto& [k, v] : r.figures) {
    if (k == name) return v;
  }
  ADD_FAILURE() << "no figure " << name << " in stage " << r.stage;
  return std::nan("");
}

}  // namespace hc::test
