#pragma once
/// @file e57_writer.hpp
/// A small E57 writer for the read-rate benchmarks (not part of the library: hapticloud reads
/// E57, it never writes it). Written from ASTM E2807-11 ("E57 3D Imaging Data Exchange, v1.0"):
///   - § 7.2 file header, 48 bytes at physical offset 0: "ASTM-E57", major 1, minor 0 (u32 each),
///     file physical length, XML physical offset, XML logical length, page size (u64 each);
///   - § 7.3 pages of 1024 bytes: 1020 logical bytes, then the CRC-32C (Castagnoli) of those
///     bytes, big-endian (hc/tools/e57_pages.hpp);
///   - § 9 one CompressedVector binary section right after the header (logical 48): a 32-byte
///     section header (id 1, 7 reserved bytes, section logical length, data physical offset,
///     index physical offset 0 = no index), then data packets (type 1, flags 0, logical length
///     − 1, bytestream count, one u16 buffer length per bytestream, the buffers, zero padding to
///     a multiple of 4 bytes; at most 64 KiB each). Every packet holds whole records:
///     kRecordsPerPacket is a multiple of 64, so a bit-packed stream never splits a value or a
///     64-bit word across packets;
///   - § 8 the XML section after the binary section: e57Root (formatName, guid, versionMajor,
///     versionMinor, data3D with one scan, empty images2D); the scan's points prototype holds
///     cartesianX/Y/Z either as Float precision="single" (4 bytes each, little-endian) or as
///     ScaledInteger (minimum/maximum raw integers, scale, offset 0; value = raw · scale, stored
///     as raw − minimum in ceil(log2(maximum − minimum + 1)) bits, least significant bit first).
/// The cloud's coordinates are written as they are (no pose); the caller checks the round trip.

#include "hc/pipeline/cloud.hpp"
#include "hc/tools/e57_pages.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>

namespace hc::bench {

struct E57Options {
  bool scaled = false;         ///< ScaledInteger (true) or Float single (false) coordinates
  double scale_m = 1e-6;       ///< ScaledInteger: metres per count
};

namespace e57_detail {

inline constexpr std::size_t kPage = hc::tools::kE57PageBytes, kPayload = hc::tools::kE57PagePayloadBytes, kRecordsPerPacket = 4096;

template <class T>
void append(std::string& s, T v) {
  s.append(reinterpret_cast<const char*>(&v), sizeof v);
}
template <class T>
void put(std::string& s, std::size_t at, T v) {
  std::memcpy(s.data() + at, &v, sizeof v);
}

using hc::tools::e57_physical;

inline std::string number(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

}  // namespace e57_detail

/// The raw ScaledInteger count of coordinate v (what the writer stores before subtracting the
/// minimum); the reader gives back static_cast<double>(raw) * scale_m.
inline std::int64_t e57_raw(double v, double scale_m) { return std::llround(v / scale_m); }

/// The bytes of a one-scan E57 file holding c's coordinates (see the file comment).
inline std::string e57_bytes(const hc::pipeline::Cloud& c, const E57Options& o) {
  using namespace e57_detail;
  const std::size_t n = c.size();
  std::int64_t lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
  unsigned bits[3] = {0, 0, 0};
  if (o.scaled) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = INT64_MAX;
      hi[a] = INT64_MIN;
      for (std::size_t i = 0; i < n; ++i) {
        const std::int64_t r = e57_raw(c.xyz(a, static_cast<Eigen::Index>(i)), o.scale_m);
        lo[a] = std::min(lo[a], r);
        hi[a] = std::max(hi[a], r);
      }
      if (n == 0) lo[a] = hi[a] = 0;
      bits[a] = static_cast<unsigned>(std::bit_width(static_cast<std::uint64_t>(hi[a] - lo[a])));
    }
  }
  // Logical stream: header placeholder, section header, packets, XML.
  std::string log(48 + 32, '\0');
  const std::size_t section_at = 48, data_at = 48 + 32;
  for (std::size_t i0 = 0; i0 < n; i0 += kRecordsPerPacket) {
    const std::size_t m = std::min(kRecordsPerPacket, n - i0);
    const std::size_t start = log.size();
    append<std::uint8_t>(log, 1);  // data packet
    append<std::uint8_t>(log, 0);
    append<std::uint16_t>(log, 0);  // logical length − 1, set below
    append<std::uint16_t>(log, 3);
    std::size_t len[3];
    for (int a = 0; a < 3; ++a) len[a] = o.scaled ? (m * bits[a] + 7) / 8 : 4 * m;
    for (int a = 0; a < 3; ++a) append<std::uint16_t>(log, static_cast<std::uint16_t>(len[a]));
    for (int a = 0; a < 3; ++a) {
      if (!o.scaled) {
        for (std::size_t i = i0; i < i0 + m; ++i) append<float>(log, static_cast<float>(c.xyz(a, static_cast<Eigen::Index>(i))));
        continue;
      }
      const std::size_t at = log.size();
      log.append(len[a], '\0');
      auto* p = reinterpret_cast<unsigned char*>(log.data() + at);
      std::uint64_t bit = 0;
      for (std::size_t i = i0; i < i0 + m; ++i, bit += bits[a]) {
        const auto v = static_cast<std::uint64_t>(e57_raw(c.xyz(a, static_cast<Eigen::Index>(i)), o.scale_m) - lo[a]);
        for (unsigned k = 0; k < bits[a]; ++k) {
          if ((v >> k) & 1u) p[(bit + k) >> 3] = static_cast<unsigned char>(p[(bit + k) >> 3] | (1u << ((bit + k) & 7u)));
        }
      }
    }
    while ((log.size() - start) % 4) log += '\0';
    put<std::uint16_t>(log, start + 2, static_cast<std::uint16_t>(log.size() - start - 1));
  }
  log[section_at] = 1;  // CompressedVector section
  put<std::uint64_t>(log, section_at + 8, log.size() - section_at);
  put<std::uint64_t>(log, section_at + 16, e57_physical(data_at));
  put<std::uint64_t>(log, section_at + 24, 0);

  std::string proto;
  const char* axes[3] = {"cartesianX", "cartesianY", "cartesianZ"};
  for (int a = 0; a < 3; ++a) {
    if (o.scaled) {
      proto += std::string("<") + axes[a] + " type=\"ScaledInteger\" minimum=\"" + std::to_string(lo[a]) +
               "\" maximum=\"" + std::to_string(hi[a]) + "\" scale=\"" + number(o.scale_m) + "\" offset=\"0\"/>";
    } else {
      proto += std::string("<") + axes[a] + " type=\"Float\" precision=\"single\"/>";
    }
  }
  const std::string xml =
      "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
      "<e57Root type=\"Structure\" xmlns=\"http://www.astm.org/COMMIT/E57/2010-e57-v1.0\">"
      "<formatName type=\"String\"><![CDATA[ASTM E57 3D Imaging Data File]]></formatName>"
      "<guid type=\"String\"><![CDATA[{5c2a3e0e-7d43-4b8e-9f57-000000000001}]]></guid>"
      "<versionMajor type=\"Integer\">1</versionMajor><versionMinor type=\"Integer\">0</versionMinor>"
      "<data3D type=\"Vector\" allowHeterogeneousChildren=\"1\"><vectorChild type=\"Structure\">"
      "<guid type=\"String\"><![CDATA[{5c2a3e0e-7d43-4b8e-9f57-000000000002}]]></guid>"
      "<name type=\"String\"><![CDATA[hapticloud read-rate bench]]></name>"
      "<points type=\"CompressedVector\" fileOffset=\"" + std::to_string(e57_physical(section_at)) +
      "\" recordCount=\"" + std::to_string(n) + "\"><prototype type=\"Structure\">" + proto +
      "</prototype><codecs type=\"Vector\" allowHeterogeneousChildren=\"1\"></codecs></points>"
      "</vectorChild></data3D><images2D type=\"Vector\" allowHeterogeneousChildren=\"1\"></images2D></e57Root>\n";
  while (log.size() % 4) log += '\0';
  const std::size_t xml_at = log.size();
  log += xml;
  while (log.size() % kPayload) log += '\0';

  std::string h = "ASTM-E57";
  append<std::uint32_t>(h, 1);
  append<std::uint32_t>(h, 0);
  append<std::uint64_t>(h, log.size() / kPayload * kPage);
  append<std::uint64_t>(h, e57_physical(xml_at));
  append<std::uint64_t>(h, xml.size());
  append<std::uint64_t>(h, kPage);
  log.replace(0, 48, h);

  return hc::tools::e57_pages(log);
}

}  // namespace hc::bench
