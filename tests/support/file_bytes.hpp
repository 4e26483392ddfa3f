#pragma once
/// @file file_bytes.hpp
/// Whole-file byte helpers shared by the reader tests (they build variants of real files).

#include <zlib.h>

#include <algorithm>
#include <cstddef>
#include <cstring>
#include <stdexcept>
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

/// Writes `bytes` to `p` gzip-compressed (zlib), as `members` concatenated gzip members of about
/// equal size (`cat a.gz b.gz` makes such a file). @throws std::runtime_error when it cannot.
inline void write_gzip(const std::filesystem::path& p, const std::string& bytes, int members = 1) {
  std::filesystem::remove(p);
  const std::size_t part = bytes.size() / static_cast<std::size_t>(members) + 1;
  for (int m = 0; m < members; ++m) {
    const std::size_t from = std::min(bytes.size(), static_cast<std::size_t>(m) * part);
    const std::size_t n = std::min(part, bytes.size() - from);
    gzFile f = gzopen(p.string().c_str(), m == 0 ? "wb" : "ab");
    if (f == nullptr) throw std::runtime_error("write_gzip: cannot open " + p.string());
    const bool ok = n == 0 || gzwrite(f, bytes.data() + from, static_cast<unsigned>(n)) == static_cast<int>(n);
    if (gzclose(f) != Z_OK || !ok) throw std::runtime_error("write_gzip: cannot write " + p.string());
  }
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
