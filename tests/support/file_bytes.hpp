#pragma once
/// @file file_bytes.hpp
/// Whole-file byte helpers shared by the reader tests (they build variants of real files).

#include <cstddef>
#include <cstring>
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

/// The T stored little-endian at byte `at` of `b` (the test machines are little-endian, as LAS
/// and E57 are); the caller keeps `at + sizeof(T) <= b.size()`.
template <class T>
T le(const std::string& b, std::size_t at) {
  T v{};
  std::memcpy(&v, b.data() + at, sizeof v);
  return v;
}

}  // namespace hc::test
