#pragma once
/// @file stage_figure.hpp
/// Reading one named figure out of a pipeline stage report in tests.

#include "hc/pipeline/cloud.hpp"
#include "hc/pipeline/run.hpp"

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

/// The figure `name` of stage `stage` in a built scene's summary; -1 when there is none (the
/// tests ask for figures that some runs leave out, and the values asked for are never negative).
inline double stage_figure(const pipeline::BuiltScene& b, const std::string& stage, const std::string& name) {
  for (const auto& s : b.summary.stages) {
    if (s.stage != stage) continue;
    for (const auto& [n, v] : s.figures) {
      if (n == name) return v;
    }
  }
  return -1.0;
}

}  // namespace hc::test
