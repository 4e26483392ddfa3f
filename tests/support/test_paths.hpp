#pragma once
/// @file test_paths.hpp
/// Where tests find real scans (data/scans, filled by data/get-data) and where they may write.

#include <gtest/gtest.h>

#include <filesystem>
#include <string>

namespace hc::test {

/// Path of a scan under data/scans (for example "bunny/bun000.ply"). A missing scan fails the
/// calling test with a message to run data/get-data: it is never skipped silently.
inline std::filesystem::path scan_path(const std::string& relative) {
  const std::filesystem::path p = std::filesystem::path(HC_SOURCE_DIR) / "data" / "scans" / relative;
  if (!std::filesystem::exists(p)) {
    ADD_FAILURE() << "missing test scan " << p << ": run data/get-data first";
  }
  return p;
}

/// A fresh, empty folder under the build tree for this test's output.
inline std::filesystem::path temp_dir(const std::string& name) {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::filesystem::path p = std::filesystem::path(HC_BINARY_DIR) / "test-output" /
                            (std::string(info ? info->test_suite_name() : "x") + "." +
                             (info ? info->name() : "y") + "." + name);
  std::filesystem::remove_all(p);
  std::filesystem::create_directories(p);
  return p;
}

/// True when a file or folder in `dir` (not below it) has `text` in its name, e.g. the
/// ".part-" of a temporary an export or a recording left behind.
inline bool has_entry_named_with(const std::filesystem::path& dir, const std::string& text) {
  for (const auto& e : std::filesystem::directory_iterator(dir))
    if (e.path().filename().string().find(text) != std::string::npos) return true;
  return false;
}

}  // namespace hc::test
