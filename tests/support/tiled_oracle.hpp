#pragma once
/// @file tiled_oracle.hpp
/// The tiled run's scene against the in-core run's of the same config (issue 14: "the result
/// equals the in-core run"): every layer bit for bit, the cross-check's point figures equal (the
/// RMS to the last bits: another summation order), its cell-to-point figures and error map to
/// float rounding of the coordinates, and the spill folder gone.

#include "hc/common/height_field.hpp"
#include "hc/pipeline/cross_check.hpp"
#include "hc/pipeline/honest_check.hpp"
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
  // (b): each tile searches in the whole grid's float frame, at its sample positions, and
  // searches again over other tiles with the same float arithmetic (since 2026-11-30): the error
  // map, its figures and the supported fraction are the in-core ones bit for bit.
  EXPECT_EQ(x.cell_to_point.count, y.cell_to_point.count);
  EXPECT_EQ(x.cell_to_point.p50_mm, y.cell_to_point.p50_mm);
  EXPECT_EQ(x.cell_to_point.p95_mm, y.cell_to_point.p95_mm);
  EXPECT_EQ(x.cell_to_point.p99_mm, y.cell_to_point.p99_mm);
  EXPECT_EQ(x.cell_to_point.max_mm, y.cell_to_point.max_mm);
  EXPECT_NEAR(x.cell_to_point.rms_mm, y.cell_to_point.rms_mm, 1e-9 * x.cell_to_point.rms_mm);  // summed in another order
  EXPECT_EQ(x.supported_fraction, y.supported_fraction);
  // The tiled run's map is its scene's layer, moved there (no copy in the summary).
  EXPECT_EQ(y.cell_error_m.values().size(), 0U);
  const hc::HeightField& y_error = tiled.scene.layers.cell_error;
  ASSERT_EQ(y_error.values().size(), x.cell_error_m.values().size());
  EXPECT_EQ(differing_bits(in.scene.layers.cell_error, x.cell_error_m), 0U) << "in core: the scene's layer is the summary's map";
  EXPECT_EQ(differing_bits(in.scene.layers.cell_error, y_error), 0U) << "the error map, in core and tiled";
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

/// Expects the honest check's point classes and far points of `tiled` to be those of `in`
/// (the in-core run's InputCheck): every point in the same class in both runs.
inline void expect_same_point_classes(const hc::pipeline::InputCheck& in, const hc::pipeline::InputCheck& tiled) {
  EXPECT_EQ(tiled.points, in.points);
  EXPECT_EQ(tiled.removed, in.removed);
  EXPECT_EQ(tiled.on_surface, in.on_surface);
  EXPECT_EQ(tiled.off_surface, in.off_surface);
  EXPECT_EQ(tiled.hidden, in.hidden);
  EXPECT_EQ(tiled.no_data, in.no_data);
  EXPECT_EQ(tiled.outside, in.outside);
  EXPECT_EQ(tiled.far, in.far);
}

}  // namespace hc::test
