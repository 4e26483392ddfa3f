#pragma once
/// @file file_bytes.hpp
/// Whole-file byte helpers shared by the reader tests (they build variants of real files).

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

namespace hc::test {

/// The whole content of `p` as bytes (empty when the file cannot be opened).
inline std::string read_bytes(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

/// Writes `bytes` to `p`, replacing it (a test-owned file under the build tree).
inline void write_bytes(const std::filesystem::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

}  // namespace hc::test
