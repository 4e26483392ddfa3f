#pragma once
/// @file e57_pages.hpp
/// The page layer of an E57 file (ASTM E2807-11 § 7.3), for the writers of generated scans:
/// hc-gen-relief's .e57 output (relief.cpp) and the read-rate benchmarks' writers (bench/).
/// hapticloud reads E57 (pipeline/src/readers/read_e57.cpp, which checks these pages); it
/// never writes it. A page is 1024 bytes: 1020 bytes of the logical stream, then the CRC-32C
/// (Castagnoli) of those bytes, stored big-endian. Logical offset L lies at physical offset
/// (L / 1020)·1024 + L % 1020.

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

namespace hc::tools {

inline constexpr std::uint64_t kE57PageBytes = 1024;        ///< physical bytes of a page
inline constexpr std::uint64_t kE57PagePayloadBytes = 1020;  ///< logical bytes a page holds

/// CRC-32C (Castagnoli: reflected polynomial 0x82F63B78, initial value and final xor
/// 0xFFFFFFFF) of n bytes at p, table-driven (about 0.5 GB/s). Source: E2807 § 7.3 names it
/// the page checksum; RFC 3720 App. B.4 gives the polynomial and check values. No errors.
std::uint32_t e57_crc32c(const unsigned char* p, std::size_t n);

/// The physical offset [bytes] of logical offset `logical` [bytes] (E2807 § 7.3).
constexpr std::uint64_t e57_physical(std::uint64_t logical) {
  return logical / kE57PagePayloadBytes * kE57PageBytes + logical % kE57PagePayloadBytes;
}

/// Seals one page in place: page[0 .. 1020) is its logical data; page[1020 .. 1024) receives
/// their CRC-32C, most significant byte first. `page` must hold 1024 bytes. No errors.
void e57_seal_page(unsigned char* page);

/// The file's bytes for a whole logical stream: pages of its 1020-byte slices, each sealed.
/// Size: logical.size() / 1020 · 1024.
/// @throws std::invalid_argument when logical.size() is not a multiple of 1020 (pad it first).
std::string e57_pages(std::string_view logical);

}  // namespace hc::tools
