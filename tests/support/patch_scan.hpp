#pragma once
/// @file patch_scan.hpp
/// A small generated scan for the tiled run's tests: a plane patch with points added after it.

#include <array>
#include <filesystem>
#include <fstream>
#include <vector>

namespace hc::test {

/// Writes `file` as an ASCII PLY (x y z as doubles [m]): a 1 m × 1 m patch of 100 × 100 points
/// 1 cm apart (x, y in 0..0.99 m, z in 0..4 mm by the pattern (7i + 3j) mod 5 mm), then `extra`.
inline void write_patch_with(const std::filesystem::path& file, const std::vector<std::array<double, 3>>& extra) {
  std::ofstream out(file);
  out << "ply\nformat ascii 1.0\nelement vertex " << 100 * 100 + extra.size()
      << "\nproperty double x\nproperty double y\nproperty double z\nend_header\n";
  for (int i = 0; i < 100; ++i)
    for (int j = 0; j < 100; ++j) out << 0.01 * i << " " << 0.01 * j << " " << 0.001 * ((i * 7 + j * 3) % 5) << "\n";
  for (const auto& p : extra) out << p[0] << " " << p[1] << " " << p[2] << "\n";
}

}  // namespace hc::test
