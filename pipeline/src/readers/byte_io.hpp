#pragma once
/// @file byte_io.hpp
/// Unaligned little-endian loads and stores of fixed-size fields, shared by the LAS and LAZ
/// readers (ASPRS LAS 1.4 R15 §2: every field is little-endian; the readers assert a
/// little-endian host). Private to the pipeline (not installed).

#include <cstdint>
#include <cstring>

namespace hc::pipeline::detail {

/// The T stored at `p` (sizeof(T) bytes, no alignment needed).
template <class T>
T load_le(const void* p) {
  T v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

/// Writes `v` at `p` (sizeof(T) bytes, no alignment needed).
template <class T>
void store_le(void* p, T v) {
  std::memcpy(p, &v, sizeof v);
}

/// k with its lowest bit cleared (LASzip's per-context model index of a pair of contexts).
inline std::uint32_t even_index(std::uint32_t k) { return k & ~1u; }

}  // namespace hc::pipeline::detail
