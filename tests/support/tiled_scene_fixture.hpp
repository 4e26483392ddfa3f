#pragma once
// A small scene with every layer, written tiled (scene_io.hpp format 3) with its stored levels:
// the tiled-scene tests' fixture (tiled_scene_test.cpp; tiled_scene_gdal_test.cpp, whose GDAL
// oracle lives in hc_pipeline_oracle_tests, tests/CMakeLists.txt).

#include "hc/common/scene.hpp"
#include "hc/pipeline/level_builder.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <random>
#include <utility>

namespace hc::test {

/// A scene of rows × cols samples: a wavy surface with random relief, no data in the block
/// [hole_r0, hole_r0 + hole) × [hole_c0, hole_c0 + hole) and along the last column; colour
/// from the position; layers (envelope, texture, μ) and the cross-check error as smooth fields.
inline hc::Scene wavy_scene(int rows, int cols, int hole_r0, int hole_c0, int hole) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> noise(-1e-4f, 1e-4f);
  hc::Scene s;
  s.geometry = hc::GridGeometry{rows, cols, -0.1, -0.05, 0.001};
  hc::HeightField d(s.geometry), env(s.geometry), tex(s.geometry), mud(s.geometry), mus(s.geometry), err(s.geometry);
  s.layers.colour_rgb8.assign(3 * s.geometry.cell_count(), 0);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      const std::size_t i = static_cast<std::size_t>(r) * static_cast<std::size_t>(cols) + static_cast<std::size_t>(c);
      const bool hole_cell = (r >= hole_r0 && r < hole_r0 + hole && c >= hole_c0 && c < hole_c0 + hole) || c == cols - 1;
      const float e = static_cast<float>(0.01 * std::sin(0.05 * r) * std::cos(0.03 * c));
      const float t = noise(rng);
      d.data()[i] = hole_cell ? std::numeric_limits<float>::quiet_NaN() : e + t;
      env.data()[i] = hole_cell ? std::numeric_limits<float>::quiet_NaN() : e;
      tex.data()[i] = hole_cell ? std::numeric_limits<float>::quiet_NaN() : t;
      mud.data()[i] = hole_cell ? std::numeric_limits<float>::quiet_NaN() : 0.3f + 0.1f * static_cast<float>(std::sin(0.2 * c));
      mus.data()[i] = hole_cell ? std::numeric_limits<float>::quiet_NaN() : 0.4f;
      err.data()[i] = hole_cell ? std::numeric_limits<float>::quiet_NaN() : 1e-4f * static_cast<float>(r % 7);
      if (!hole_cell) {
        s.layers.colour_rgb8[3 * i] = static_cast<std::uint8_t>(r % 256);
        s.layers.colour_rgb8[3 * i + 1] = static_cast<std::uint8_t>(c % 256);
        s.layers.colour_rgb8[3 * i + 2] = static_cast<std::uint8_t>((r + c) % 256);
      }
    }
  }
  s.layers.depth = std::move(d);
  s.layers.envelope = std::move(env);
  s.layers.texture = std::move(tex);
  s.layers.mu_d = std::move(mud);
  s.layers.mu_s = std::move(mus);
  s.layers.cell_error = std::move(err);
  s.lod.min_cells = 16;
  s.lod.window_cells = 40;
  return s;
}

/// Writes `s` as a tiled scene with every level of its pyramid (the streaming level builder,
/// which level_builder_test checks bit for bit against the in-memory pyramid).
inline std::filesystem::path write_tiled(const hc::Scene& s, const std::filesystem::path& dir, int tile) {
  const std::filesystem::path scene_dir = dir / "scene";
  hc::pipeline::write_scene(s, scene_dir, hc::SceneStorage{tile, hc::pipeline::lod_level_count(s.geometry, s.lod.min_cells)});
  (void)hc::pipeline::build_stored_levels(scene_dir, dir / "scratch");
  return scene_dir;
}

}  // namespace hc::test
