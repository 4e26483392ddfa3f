#pragma once
/// @file fuzz_support.hpp
/// Shared by the libFuzzer targets (tests/fuzz/*_fuzz.cpp) and the regression test that replays
/// their saved inputs in the normal suite (tests/pipeline/fuzz_regression_test.cpp).
///
/// Each target is one function `void NAME(const std::uint8_t* data, std::size_t size)` in
/// tests/fuzz/targets/NAME.cpp that hands the bytes to one public reader. A reader may accept
/// the bytes or throw an hc::Error (the function swallows those); anything else — another
/// exception, a crash, a sanitizer report, a hang — is a finding.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace hc::fuzz {

/// A folder private to this process under the system temp folder, created on first use and
/// removed at exit. Readers that take a path get the fuzz input written here.
const std::filesystem::path& scratch_dir();

/// Writes `size` bytes to scratch_dir()/name and returns that path (replaces any earlier file).
std::filesystem::path write_scratch(const std::string& name, const std::uint8_t* data, std::size_t size);

/// A target: its name (also the folder name under tests/fuzz/corpus and tests/fuzz/regressions)
/// and its entry point.
struct Target {
  std::string_view name;
  void (*run)(const std::uint8_t* data, std::size_t size);
};

/// Every target, for the regression test.
const std::vector<Target>& all_targets();

// The targets (one file each under tests/fuzz/targets/).
void ply(const std::uint8_t* data, std::size_t size);
void pcd(const std::uint8_t* data, std::size_t size);
void obj(const std::uint8_t* data, std::size_t size);
void xyz(const std::uint8_t* data, std::size_t size);
void scanalyze_conf(const std::uint8_t* data, std::size_t size);
void run_config(const std::uint8_t* data, std::size_t size);
void scene_yaml(const std::uint8_t* data, std::size_t size);
void scene_tiff(const std::uint8_t* data, std::size_t size);
void scene_tiled(const std::uint8_t* data, std::size_t size);
void falcon_frames(const std::uint8_t* data, std::size_t size);
void e57(const std::uint8_t* data, std::size_t size);
void las(const std::uint8_t* data, std::size_t size);
void laz(const std::uint8_t* data, std::size_t size);
void ptx(const std::uint8_t* data, std::size_t size);
void pts(const std::uint8_t* data, std::size_t size);

}  // namespace hc::fuzz
