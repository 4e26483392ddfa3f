#pragma once
/// @file tiled_oracle.hpp
/// The tiled run's scene against the in-core run's of the same config (issue 14: "the result
/// equals the in-core run"): every layer bit for bit, the cross-check's point figures equal (the
/// RMS to the last bits: another summation order), its cell-to-point figures and error map to
/// float rounding of the coordinates, and the spill folder gone.

#include "hc/common/height_field.hpp"
#include "hc/pipeline/cross_check.hpp"
#include "hc/pipeline/run.hpp"

#include "height_field_bits.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

namespace hc::test {

/// Expects `tiled` (a tiled run of a config, its spill under `scratch`) to be `in` (the in-core
/// run of the same config). Failures are the calling test's (GoogleTest EXPECT).
inline void expect_tiled_scene_equals_in_core(const hc::pipeline::BuiltScene& in, const hc::pipeline::BuiltScene& tiled,
                                              const std::filesystem::path& scratch) {
  namespace fs = std::filesystem;
  // write_run gives freed heap back after each stage of the tiled run's scene only.
  EXPECT_FALSE(in.from_tiled_run);
  EXPECT_TRUE(tiled.from_tiled_run);
  expect_same_layers(in.scene.layers, tiled.scene.layers);
  EXPECT_EQ(in.scene.model_to_grid.matrix(), tiled.scene.model_to_grid.matrix());
  ASSERT_TRUE(in.summary.cross_check && tiled.summary.cross_check);
  const auto& x = *in.summary.cross_check;
  const auto& y = *tiled.summary.cross_check;
  for (const auto& [s, t] : {std::pair{x.point_vertical, y.point_vertical}, std::pair{x.point_normal, y.point_normal}}) {
    EXPECT_EQ(s.count, t.count);
    EXPECT_EQ(s.p50_mm, t.p50_mm);
    EXPECT_EQ(s.p95_mm, t.p95_mm);
    EXPECT_EQ(s.p99_mm, t.p99_mm);
    EXPECT_EQ(s.max_mm, t.max_mm);
    EXPECT_NEAR(s.rms_mm, t.rms_mm, 1e-9 * s.rms_mm);
  }
  EXPECT_EQ(x.points_on_surface, y.points_on_surface);
  EXPECT_EQ(x.points_hidden, y.points_hidden);
  EXPECT_EQ(x.points_off_surface, y.points_off_surface);
  EXPECT_EQ(x.points_outside, y.points_outside);
  // (b): each tile searches in its own float frame: the same nearest points, distances to float
  // rounding of the coordinates (about 1e-7 of the scene's extent).
  EXPECT_EQ(x.cell_to_point.count, y.cell_to_point.count);
  const double extent_mm = 1e3 * in.scene.geometry.cell_size_m * std::max(in.scene.geometry.rows, in.scene.geometry.cols);
  for (const auto& [s, t] : {std::pair{x.cell_to_point.p50_mm, y.cell_to_point.p50_mm}, std::pair{x.cell_to_point.p95_mm, y.cell_to_point.p95_mm},
                             std::pair{x.cell_to_point.max_mm, y.cell_to_point.max_mm}, std::pair{x.cell_to_point.rms_mm, y.cell_to_point.rms_mm}}) {
    EXPECT_NEAR(s, t, 1e-6 * extent_mm);
  }
  // One cell within float rounding of the tolerance may count otherwise (b's distances above).
  std::size_t valid = 0;
  for (const float z : in.scene.layers.depth.values()) valid += std::isnan(z) ? 0U : 1U;
  EXPECT_NEAR(x.supported_fraction, y.supported_fraction, std::max(1e-4, 1.0 / static_cast<double>(std::max<std::size_t>(valid, 1)) + 1e-12));
  // The tiled run's map is its scene's layer, moved there (no copy in the summary).
  EXPECT_EQ(y.cell_error_m.values().size(), 0U);
  const hc::HeightField& y_error = tiled.scene.layers.cell_error;
  ASSERT_EQ(y_error.values().size(), x.cell_error_m.values().size());
  EXPECT_EQ(differing_bits(in.scene.layers.cell_error, x.cell_error_m), 0U) << "in core: the scene's layer is the summary's map";
  std::size_t far = 0;
  for (std::size_t i = 0; i < x.cell_error_m.values().size(); ++i) {
    const float u = x.cell_error_m.values()[i], v = y_error.values()[i];
    if (std::isnan(u) != std::isnan(v) || (!std::isnan(u) && std::abs(u - v) > 1e-9 * extent_mm)) ++far;
  }
  EXPECT_EQ(far, 0U) << "cells whose nearest point differs";
  // The tiled run's cell-to-point figures (radix selection over its error map, no copy) are
  // error_stats_mm_of_floats of its supported cells' errors bit for bit.
  {
    std::vector<float> supported;
    const hc::HeightField& depth = tiled.scene.layers.depth;
    for (std::size_t i = 0; i < y_error.values().size(); ++i) {
      if (!std::isnan(depth.values()[i]) && !std::isnan(y_error.values()[i])) supported.push_back(y_error.values()[i]);
    }
    const hc::pipeline::ErrorStats e = hc::pipeline::error_stats_mm_of_floats(std::move(supported));
    EXPECT_EQ(y.cell_to_point.count, e.count);
    EXPECT_EQ(y.cell_to_point.p50_mm, e.p50_mm);
    EXPECT_EQ(y.cell_to_point.p95_mm, e.p95_mm);
    EXPECT_EQ(y.cell_to_point.p99_mm, e.p99_mm);
    EXPECT_EQ(y.cell_to_point.max_mm, e.max_mm);
    EXPECT_EQ(y.cell_to_point.rms_mm, e.rms_mm);
  }
  for (const std::string& w : tiled.summary.warnings) EXPECT_EQ(w.find("the kept points span"), std::string::npos) << w;
  // The spill folder is gone.
  EXPECT_TRUE(fs::is_empty(scratch));
}

}  // namespace hc::test
