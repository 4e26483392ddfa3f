// LAS reader: ASPRS LAS 1.0–1.4 (LAS Specification 1.4 R15, with the 1.0–1.3 header layouts),
// uncompressed point data formats 0–10. Written from the specification (clean room). The header
// parsing and the record decoding are shared with the LAZ reader (las_records.hpp).
//
// Public header block (little-endian; offsets in bytes, spec R15 table 3):
//   0 "LASF" · 24 version major, 25 minor · 26 system identifier char[32] · 58 generating
//   software char[32] · 94 header size u16 · 96 offset to point data u32 · 100 number of VLRs
//   u32 · 104 point data format u8 · 105 point record length u16 · 107 legacy point count u32 ·
//   131 x/y/z scale f64 · 155 x/y/z offset f64 · 179 max x, min x, max y, min y, max z, min z f64.
//   1.3 adds 227 start of waveform data u64 (header 235 bytes); 1.4 adds 235 start of first
//   EVLR u64, 243 number of EVLRs u32, 247 point count u64, 255 points by return u64[15]
//   (header 375 bytes).
// VLR header: 54 bytes (reserved u16, user id char[16], record id u16, length after header u16,
// description char[32]); EVLR header: 60 bytes (the length is u64).
// Point records (spec R15 tables 7–17): X Y Z int32 at 0, 4, 8 (x = X·scale + offset, in
// double); intensity u16 at 12; classification: formats 0–5 the low 5 bits of byte 15, formats
// 6–10 the byte at 16; RGB u16 ×3 at 20 (format 2), 28 (3, 5), 30 (7, 8, 10). Base record
// sizes 20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67 bytes; a longer record carries extra bytes
// (skipped here).
// CRS: VLR user id "LASF_Projection", record 2112 (OGC WKT) or the GeoTIFF keys 34735
// (GeoKeyDirectoryTag, u16), 34736 (GeoDoubleParamsTag, f64), 34737 (GeoAsciiParamsTag).

#include "byte_io.hpp"
#include "las_records.hpp"
#include "readers.hpp"
#include "text_parse.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cstdio>
#include <memory>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <sstream>
#include <string_view>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

namespace hc::pipeline::detail {

namespace {

static_assert(std::endian::native == std::endian::little, "the LAS reader assumes a little-endian host");

constexpr std::array<std::uint16_t, 11> kBaseRecordLength = {20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67};
constexpr std::size_t kVlrHeader = 54;
constexpr std::size_t kEvlrHeader = 60;

/// Byte offset of R, G, B in a record of `format`, or 0 if the format has no colour.
std::size_t rgb_offset(int format) {
  switch (format) {
    case 2: return 20;
    case 3: case 5: return 28;
    case 7: case 8: case 10: return 30;
    default: return 0;
  }
}

std::string fixed_text(const char* p, std::size_t n) {
  std::size_t len = 0;
  while (len < n && p[len] != '\0') ++len;
  std::string s(p, len);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.pop_back();
  return s;
}

std::string fmt_g(double v) {
  std::ostringstream os;
  os.precision(12);
  os << v;
  return os.str();
}

std::string geokey_name(std::uint16_t id) {
  switch (id) {
    case 1024: return "GTModelTypeGeoKey";
    case 1025: return "GTRasterTypeGeoKey";
    case 1026: return "GTCitationGeoKey";
    case 2048: return "GeographicTypeGeoKey";
    case 2049: return "GeogCitationGeoKey";
    case 2050: return "GeogGeodeticDatumGeoKey";
    case 2054: return "GeogAngularUnitsGeoKey";
    case 3072: return "ProjectedCSTypeGeoKey";
    case 3073: return "PCSCitationGeoKey";
    case 3076: return "ProjLinearUnitsGeoKey";
    case 4096: return "VerticalCSTypeGeoKey";
    case 4097: return "VerticalCitationGeoKey";
    case 4098: return "VerticalDatumGeoKey";
    case 4099: return "VerticalUnitsGeoKey";
    default: return "GeoKey" + std::to_string(id);
  }
}

std::string linear_unit_name(unsigned code) {
  switch (code) {
    case 9001: return "metre";
    case 9002: return "foot";
    case 9003: return "US survey foot";
    default: return {};
  }
}

/// GeoTIFF keys (34735, with 34736 doubles and 34737 ASCII) as one line of text.
std::string summarise_geokeys(const Vlr& dir, const Vlr* doubles, const Vlr* ascii) {
  const std::size_t n_u16 = dir.length / 2;
  if (n_u16 < 4) return "GeoTIFF key directory (VLR 34735) too short (" + std::to_string(dir.length) + " bytes)";
  const auto u16 = [&](std::size_t i) { return load_le<std::uint16_t>(dir.data + 2 * i); };
  const std::size_t n_keys = u16(3);
  std::string out;
  for (std::size_t k = 0; k < n_keys && 4 + 4 * k + 3 < n_u16; ++k) {
    const std::uint16_t id = u16(4 + 4 * k), loc = u16(5 + 4 * k), count = u16(6 + 4 * k), value = u16(7 + 4 * k);
    std::string text;
    if (loc == 0) {
      text = std::to_string(value);
      const std::string unit = (id == 3076 || id == 4099 || id == 2052) ? linear_unit_name(value) : std::string();
      if (!unit.empty()) text += " (" + unit + ")";
    } else if (loc == 34736 && doubles && (static_cast<std::size_t>(value) + count) * 8 <= doubles->length) {
      for (std::size_t j = 0; j < count; ++j) {
        if (j) text += ',';
        text += fmt_g(load_le<double>(doubles->data + 8 * (value + j)));
      }
    } else if (loc == 34737 && ascii && static_cast<std::size_t>(value) + count <= ascii->length) {
      std::string s(ascii->data + value, count);
      while (!s.empty() && (s.back() == '|' || s.back() == '\0')) s.pop_back();
      text.assign(1, '\'');  // built by appending: GCC 12 -O3 flags "'" + str (-Wrestrict)
      text += s;
      text += '\'';
    } else {
      text = "(tag " + std::to_string(loc) + " not found)";
    }
    if (!out.empty()) out += "; ";
    out += geokey_name(id);
    out += '=';
    out += text;
  }
  return out;
}

/// The last UNIT["name", factor] of a WKT string (the projected CRS's linear unit in WKT1), or "".
std::string wkt_last_unit(const std::string& wkt) {
  const std::size_t at = wkt.rfind("UNIT[");
  if (at == std::string::npos) return {};
  const std::size_t close = wkt.find(']', at);
  std::string unit = wkt.substr(at + 5, close == std::string::npos ? std::string::npos : close - at - 5);
  return unit;
}

}  // namespace

std::uint64_t las_header_point_count(const char* b) {
  const std::uint64_t legacy = load_le<std::uint32_t>(b + 107);
  if (static_cast<unsigned char>(b[25]) < 4) return legacy;
  const std::uint64_t count64 = load_le<std::uint64_t>(b + 247);
  return count64 == 0 && legacy != 0 ? legacy : count64;
}

LasHeader parse_las_header(const ScanSource& source, bool compressed) {
  return parse_las_header(std::string_view(source.bytes), source.display_name, compressed);
}

LasHeader parse_las_header(std::string_view bytes, const std::string& name, bool compressed) {
  const std::size_t size = bytes.size();
  const char* const b = bytes.data();
  const auto fail = [&](const std::string& what) -> void { throw InputError("load_cloud: " + name + " " + what); };

  if (size < 227) {
    fail("is " + std::to_string(size) + " bytes long: too short for a LAS public header (at least 227 bytes)");
  }
  if (std::memcmp(b, "LASF", 4) != 0) {
    fail("does not start with the LAS signature 'LASF' (found '" + fixed_text(b, 4) + "'): expected a LAS file");
  }
  const int major = static_cast<unsigned char>(b[24]);
  const int minor = static_cast<unsigned char>(b[25]);
  const std::string version = std::to_string(major) + "." + std::to_string(minor);
  if (major != 1 || minor > 4) fail("has LAS version " + version + ": expected 1.0 to 1.4");
  const std::size_t min_header = minor <= 2 ? 227 : minor == 3 ? 235 : 375;
  const std::size_t header_size = load_le<std::uint16_t>(b + 94);
  if (header_size < min_header) {
    fail("declares a header size of " + std::to_string(header_size) + " bytes: LAS " + version + " needs at least " +
         std::to_string(min_header));
  }
  if (header_size > size) {
    fail("declares a header size of " + std::to_string(header_size) + " bytes but the file holds " +
         std::to_string(size) + " bytes");
  }
  const std::size_t offset = load_le<std::uint32_t>(b + 96);
  const std::size_t n_vlr = load_le<std::uint32_t>(b + 100);
  const int format_byte = static_cast<unsigned char>(b[104]);
  const std::size_t record_length = load_le<std::uint16_t>(b + 105);
  if (!compressed && (format_byte & 0xC0)) {
    fail("has point data format byte " + std::to_string(format_byte) + " (compression bit set): compressed LAZ data; "
         "expected uncompressed LAS point data (format 0 to 10; a .laz file is read by the LAZ reader)");
  }
  // LASzip sets bit 7 of the format byte (bit 6 by older writers) in compressed files.
  const int format = compressed ? (format_byte & 0x3F) : format_byte;
  if (format > 10) fail("has point data format " + std::to_string(format) + ": expected 0 to 10 (LAS 1.4 R15)");
  const std::size_t base = kBaseRecordLength[static_cast<std::size_t>(format)];
  if (record_length < base) {
    fail("declares point records of " + std::to_string(record_length) + " bytes: point data format " +
         std::to_string(format) + " needs at least " + std::to_string(base));
  }
  const std::uint64_t legacy_count = load_le<std::uint32_t>(b + 107);
  const std::uint64_t count = las_header_point_count(b);
  std::vector<std::string> notes;
  if (minor >= 4) {
    const std::uint64_t count64 = load_le<std::uint64_t>(b + 247);
    if (count64 == 0 && legacy_count != 0) {
      notes.push_back("LAS 1.4 header: the 64-bit point count is 0, the legacy count " + std::to_string(legacy_count) +
                      " is used");
    } else if (legacy_count != 0 && legacy_count != count64) {
      fail("has a legacy point count of " + std::to_string(legacy_count) + " and a 64-bit point count of " +
           std::to_string(count64) + ": expected equal counts (or a legacy count of 0)");
    }
  }
  if (offset < header_size || offset > size) {
    fail("declares its point data at byte " + std::to_string(offset) + ": expected an offset between the header size " +
         std::to_string(header_size) + " and the file size " + std::to_string(size));
  }
  const std::uint64_t room = (size - offset) / record_length;
  if (!compressed && count > room) {
    fail("declares " + std::to_string(count) + " point records of " + std::to_string(record_length) +
         " bytes from byte " + std::to_string(offset) + ", but the file (" + std::to_string(size) +
         " bytes) holds room for only " + std::to_string(room) + ": truncated file or wrong header counts");
  }
  if (count == 0) fail("declares 0 point records: expected at least one point");

  double scale[3], shift[3];
  for (int a = 0; a < 3; ++a) {
    scale[a] = load_le<double>(b + 131 + 8 * a);
    shift[a] = load_le<double>(b + 155 + 8 * a);
    if (!std::isfinite(scale[a]) || scale[a] == 0.0 || !std::isfinite(shift[a])) {
      fail(std::string("has ") + "xyz"[a] + " scale " + fmt_g(scale[a]) + " and offset " + fmt_g(shift[a]) +
           ": expected a finite, non-zero scale and a finite offset");
    }
  }

  // Variable-length records between the header and the point data; EVLRs (1.4) after it.
  std::vector<Vlr> vlrs;
  std::size_t at = header_size;
  for (std::size_t i = 0; i < n_vlr; ++i) {
    if (at + kVlrHeader > offset) {
      fail("declares " + std::to_string(n_vlr) + " VLRs but VLR " + std::to_string(i) + " at byte " +
           std::to_string(at) + " runs past the start of the point data (byte " + std::to_string(offset) + ")");
    }
    Vlr v{fixed_text(b + at + 2, 16), load_le<std::uint16_t>(b + at + 18), b + at + kVlrHeader, load_le<std::uint16_t>(b + at + 20)};
    if (at + kVlrHeader + v.length > offset) {
      fail("has VLR " + std::to_string(i) + " ('" + v.user_id + "' " + std::to_string(v.record_id) + ") of " +
           std::to_string(v.length) + " bytes at byte " + std::to_string(at) +
           ", running past the start of the point data (byte " + std::to_string(offset) + ")");
    }
    at += kVlrHeader + v.length;
    vlrs.push_back(std::move(v));
  }
  if (minor >= 4) {
    const std::uint64_t evlr_start = load_le<std::uint64_t>(b + 235);
    const std::uint64_t n_evlr = load_le<std::uint32_t>(b + 243);
    std::uint64_t e = evlr_start;
    for (std::uint64_t i = 0; i < n_evlr; ++i) {
      if (e < offset || e > size || size - e < kEvlrHeader) {
        fail("declares " + std::to_string(n_evlr) + " EVLRs from byte " + std::to_string(evlr_start) + " but EVLR " +
             std::to_string(i) + " at byte " + std::to_string(e) + " lies outside the file (" + std::to_string(size) +
             " bytes)");
      }
      const std::uint64_t len = load_le<std::uint64_t>(b + e + 20);
      if (len > size - e - kEvlrHeader) {
        fail("has EVLR " + std::to_string(i) + " of " + std::to_string(len) + " bytes at byte " + std::to_string(e) +
             ", running past the end of the file (" + std::to_string(size) + " bytes)");
      }
      vlrs.push_back({fixed_text(b + e + 2, 16), load_le<std::uint16_t>(b + e + 18), b + e + kEvlrHeader,
                      static_cast<std::size_t>(len)});
      e += kEvlrHeader + len;
    }
  }

  LasHeader h;
  h.version = version;
  h.system_id = fixed_text(b + 26, 32);
  h.software = fixed_text(b + 58, 32);
  h.minor = minor;
  h.header_size = header_size;
  h.offset = offset;
  h.format = format;
  h.record_length = record_length;
  h.base_length = base;
  h.count = count;
  for (int a = 0; a < 3; ++a) {
    h.scale[a] = scale[a];
    h.shift[a] = shift[a];
  }
  h.vlrs = std::move(vlrs);
  h.notes = std::move(notes);
  return h;
}

LasRecordDecoder::LasRecordDecoder(const LasHeader& header, const LoadOptions* options)
    : record_length_(header.record_length),
      class_at_(header.format <= 5 ? 15 : 16),
      class_mask_(header.format <= 5 ? 0x1Fu : 0xFFu),
      rgb_at_(rgb_offset(header.format)),
      drop_classes_(options ? options->las_drop_classes : LoadOptions{}.las_drop_classes) {
  for (int a = 0; a < 3; ++a) {
    scale_[a] = header.scale[a];
    shift_[a] = header.shift[a];
  }
  for (int c : drop_classes_) {
    if (c >= 0 && c <= 255) drop_[static_cast<std::size_t>(c)] = true;
  }
}

std::uint16_t LasRecordDecoder::rgb_max(const char* p, std::size_t n) const {
  std::uint16_t m = 0;
  if (!rgb_at_) return m;
  for (std::size_t i = 0; i < n; ++i, p += record_length_) {
    if (drop_[static_cast<unsigned char>(p[class_at_]) & class_mask_]) continue;
    for (std::size_t c = 0; c < 3; ++c) m = std::max(m, load_le<std::uint16_t>(p + rgb_at_ + 2 * c));
  }
  return m;
}

std::size_t LasRecordDecoder::decode(const char* p, std::size_t n, bool rgb_low_bytes, double* xyz, float* intensity,
                                     std::uint8_t* rgb) {
  std::size_t k = 0;
  // Locals, so the compiler keeps them in registers (stores through xyz could alias the arrays).
  const double sx = scale_[0], sy = scale_[1], sz = scale_[2], ox = shift_[0], oy = shift_[1], oz = shift_[2];
  const std::size_t rgb_at = rgb_at_, low = rgb_low_bytes ? 0 : 1;  // the byte taken of each u16
  for (std::size_t i = 0; i < n; ++i, p += record_length_) {
    const unsigned cls = static_cast<unsigned char>(p[class_at_]) & class_mask_;
    if (drop_[cls]) {
      ++dropped_[cls];
      continue;
    }
    xyz[3 * k + 0] = load_le<std::int32_t>(p + 0) * sx + ox;
    xyz[3 * k + 1] = load_le<std::int32_t>(p + 4) * sy + oy;
    xyz[3 * k + 2] = load_le<std::int32_t>(p + 8) * sz + oz;
    intensity[k] = static_cast<float>(load_le<std::uint16_t>(p + 12));
    if (rgb_at) {
      // Little-endian u16: the high byte is the second (16-bit colour scaled to 8 bit), the low
      // byte the first (8-bit values stored in the 16-bit fields).
      for (std::size_t c = 0; c < 3; ++c) rgb[3 * k + c] = static_cast<std::uint8_t>(p[rgb_at + 2 * c + low]);
    }
    ++k;
  }
  kept_ += k;
  return k;
}

std::string LasRecordDecoder::dropped_note() const {
  std::uint64_t n_dropped = 0;
  std::string dropped_text;
  for (std::size_t c = 0; c < 256; ++c) {
    if (dropped_[c] == 0) continue;
    n_dropped += dropped_[c];
    dropped_text += (dropped_text.empty() ? "" : ", ") + std::string("class ") + std::to_string(c) + ": " +
                    std::to_string(dropped_[c]);
  }
  std::string list;
  for (int c : drop_classes_) list += (list.empty() ? "" : ", ") + std::to_string(c);
  return "dropped " + std::to_string(n_dropped) + " points by classification (input.las.drop_classes = [" + list + "]" +
         (dropped_text.empty() ? "" : "; " + dropped_text) + ")";
}

std::string LasRecordDecoder::nothing_kept_message(std::uint64_t count) {
  return "holds " + std::to_string(count) + " points, all of a classification in input.las.drop_classes: expected "
         "at least one point to keep";
}

std::vector<std::string> las_format_notes(const LasHeader& header) {
  std::vector<std::string> notes;
  notes.push_back("LAS " + header.version + ", point data format " + std::to_string(header.format) + " (" +
                  std::to_string(header.record_length) + "-byte records), " + std::to_string(header.count) +
                  " point records; system '" + header.system_id + "', software '" + header.software + "'");
  notes.push_back("scale " + fmt_g(header.scale[0]) + " " + fmt_g(header.scale[1]) + " " + fmt_g(header.scale[2]) +
                  ", offset " + fmt_g(header.shift[0]) + " " + fmt_g(header.shift[1]) + " " + fmt_g(header.shift[2]) +
                  " (file units)");
  if (header.record_length > header.base_length) {
    notes.push_back(std::to_string(header.record_length - header.base_length) + " extra bytes per record (beyond format " +
                    std::to_string(header.format) + "'s " + std::to_string(header.base_length) + ") skipped");
  }
  return notes;
}

std::string las_rgb_note(bool rgb_low_bytes) {
  return rgb_low_bytes ? "RGB kept; every value is at most 255 (8-bit values stored in the 16-bit fields), used as is"
                       : "RGB kept, 16-bit scaled to 8-bit (high byte)";
}

std::string las_crs(const LasHeader& header, std::vector<std::string>& notes) {
  std::string crs;
  const Vlr* wkt = nullptr;
  const Vlr* keys = nullptr;
  const Vlr* key_doubles = nullptr;
  const Vlr* key_ascii = nullptr;
  std::string others;
  for (const Vlr& v : header.vlrs) {
    if (v.user_id == "LASF_Projection") {
      if (v.record_id == 2112 && !wkt) wkt = &v;
      else if (v.record_id == 34735) keys = &v;
      else if (v.record_id == 34736) key_doubles = &v;
      else if (v.record_id == 34737) key_ascii = &v;
      continue;
    }
    others += (others.empty() ? "" : ", ") + ("'" + v.user_id + "' " + std::to_string(v.record_id));
  }
  if (wkt) {
    std::string text(wkt->data, wkt->length);
    while (!text.empty() && text.back() == '\0') text.pop_back();
    std::string note = "CRS (OGC WKT, VLR 2112): " + text;
    const std::string unit = wkt_last_unit(text);
    if (!unit.empty()) note += " [last UNIT in the WKT: " + unit + "; check input.units]";
    notes.push_back(note);
    crs = text;
  } else if (keys) {
    const std::string summary = summarise_geokeys(*keys, key_doubles, key_ascii);
    notes.push_back("CRS (GeoTIFF keys, VLR 34735): " + summary + " [check input.units against the linear unit]");
    crs = "GeoTIFF keys: " + summary;
  } else {
    notes.push_back("no CRS record (no LASF_Projection VLR 2112 or 34735): set input.units from the data's source");
  }
  if (!crs.empty()) notes.push_back("the CRS is carried into the scene's provenance (scene.yaml provenance.crs)");
  if (!others.empty()) notes.push_back("other VLRs ignored: " + others);
  return crs;
}

std::size_t LasRecordDecoder::decode_chunk(const char* p, std::size_t n, bool rgb_low_bytes, Cloud& chunk) {
  chunk.xyz.resize(3, static_cast<Eigen::Index>(n));
  chunk.intensity.resize(n);
  chunk.rgb.resize(has_rgb() ? 3 * n : 0);
  const std::size_t k = decode(p, n, rgb_low_bytes, chunk.xyz.data(), chunk.intensity.data(), chunk.rgb.data());
  if (k < n) {  // points were dropped (conservativeResize reallocates: only when needed)
    chunk.xyz.conservativeResize(3, static_cast<Eigen::Index>(k));
    chunk.intensity.resize(k);
    if (has_rgb()) chunk.rgb.resize(3 * k);
  }
  return k;
}

ReadResult decode_las_records(const ScanSource& source, LasHeader&& header, const char* records) {
  const std::string& name = source.display_name;
  std::vector<std::string> notes = std::move(header.notes);
  LasRecordDecoder decoder(header, source.options);
  const std::size_t n = static_cast<std::size_t>(header.count);
  // Colour: 16-bit values scaled to 8 bit by their high byte, unless every kept value fits in
  // 8 bits (then the low bytes, as stored).
  const std::uint16_t rgb_max = decoder.rgb_max(records, n);
  const bool rgb_low_bytes = decoder.has_rgb() && rgb_max <= 255;
  Cloud cloud;
  cloud.xyz.resize(3, static_cast<Eigen::Index>(n));
  cloud.intensity.resize(n);
  cloud.rgb.resize(decoder.has_rgb() ? 3 * n : 0);
  const std::size_t k = decoder.decode(records, n, rgb_low_bytes, cloud.xyz.data(), cloud.intensity.data(), cloud.rgb.data());
  if (k < n) {  // points were dropped (conservativeResize reallocates: only when needed)
    cloud.xyz.conservativeResize(3, static_cast<Eigen::Index>(k));
    cloud.intensity.resize(k);
    if (decoder.has_rgb()) cloud.rgb.resize(3 * k);
  }
  for (std::string& note : las_format_notes(header)) notes.push_back(std::move(note));
  notes.push_back(decoder.dropped_note());
  if (k == 0) throw InputError("load_cloud: " + name + " " + LasRecordDecoder::nothing_kept_message(header.count));
  if (decoder.has_rgb()) notes.push_back(las_rgb_note(rgb_low_bytes));
  notes.push_back("intensity kept (raw 0..65535)");
  cloud.crs = las_crs(header, notes);
  return {std::move(cloud), std::move(notes)};
}

ReadResult read_las(const ScanSource& source) {
  LasHeader header = parse_las_header(source, false);
  const char* records = source.bytes.data() + header.offset;
  return decode_las_records(source, std::move(header), records);
}

LasRecordStream::LasRecordStream(std::string name, const LasHeader& header, const LoadOptions* options,
                                 std::vector<std::string> format_notes, std::vector<std::string> crs_notes,
                                 std::string crs, std::optional<FileKey> key)
    : name_(std::move(name)), record_length_(header.record_length), total_(header.count), decoder_(header, options),
      key_(key), format_notes_(std::move(format_notes)), crs_notes_(std::move(crs_notes)), crs_(std::move(crs)) {
  assemble_notes();
}

bool LasRecordStream::next(Cloud& chunk, std::size_t max_points) {
  // The position in the file and the counts no longer agree after a failure: StickyFailure.
  return sticky_.run(name_, chunk, [&] {
    if (!colour_decided_) decide_colour();
    while (done_ < total_) {
      const char* records = nullptr;
      const std::size_t n = next_records(
          static_cast<std::size_t>(std::min<std::uint64_t>(std::max<std::size_t>(max_points, 1), total_ - done_)), records);
      const std::size_t k = decoder_.decode_chunk(records, n, rgb_low_bytes_, chunk);
      done_ += n;
      if (done_ == total_) {
        assemble_notes();
        if (decoder_.kept() == 0) throw InputError("load_cloud: " + name_ + " " + LasRecordDecoder::nothing_kept_message(total_));
      }
      if (k > 0) return true;
    }
    chunk = Cloud();
    return false;
  });
}

// Before the first chunk (so that opening a stream to count its points stays cheap).
void LasRecordStream::decide_colour() {
  // The drop classes change which records count: they are part of what is remembered.
  std::string what = "las_rgb";
  for (const int c : decoder_.drop_classes()) {
    what.push_back(' ');
    what += std::to_string(c);
  }
  std::array<std::uint64_t, 2> known{};
  if (decoder_.has_rgb() && key_ && recall_first_pass(*key_, what, known)) {
    rgb_low_bytes_ = known[0] != 0;
  } else if (decoder_.has_rgb()) {
    std::uint16_t rgb_max = 0;
    each_record_block([&](const char* records, std::size_t n) { rgb_max = std::max(rgb_max, decoder_.rgb_max(records, n)); });
    rgb_low_bytes_ = rgb_max <= 255;
    if (key_) remember_first_pass(*key_, what, {rgb_low_bytes_ ? 1U : 0U, 0U});
  }
  colour_decided_ = true;
  assemble_notes();
}

// decode_las_records' notes, in its order, as far as they are known.
void LasRecordStream::assemble_notes() {
  notes_ = format_notes_;
  if (done_ == total_) notes_.push_back(decoder_.dropped_note());
  if (decoder_.has_rgb() && colour_decided_) notes_.push_back(las_rgb_note(rgb_low_bytes_));
  notes_.push_back("intensity kept (raw 0..65535)");
  notes_.insert(notes_.end(), crs_notes_.begin(), crs_notes_.end());
  notes_.push_back("point records streamed in chunks");
}

namespace {

// An uncompressed LAS file read record block by record block (point_stream.hpp).
class LasStream final : public LasRecordStream {
 public:
  using File = std::unique_ptr<std::FILE, int (*)(std::FILE*)>;
  LasStream(File f, std::string name, const LasHeader& header, const LoadOptions* options,
            std::vector<std::string> format_notes, std::vector<std::string> crs_notes, std::string crs)
      : LasRecordStream(std::move(name), header, options, std::move(format_notes), std::move(crs_notes), std::move(crs),
                        large_file_key(fileno(f.get()))),
        f_(std::move(f)), offset_(header.offset) {
    seek_records();
  }

 private:
  std::size_t next_records(std::size_t max, const char*& records) override {
    buffer_.resize(max * record_length_);
    const std::size_t got = std::fread(buffer_.data(), record_length_, max, f_.get());
    if (got != max) {
      throw InputError("load_cloud: " + name_ + ": truncated or unreadable after " + std::to_string(read_ + got) +
                       " of " + std::to_string(total_) + " point records");
    }
    read_ += max;
    records = buffer_.data();
    return max;
  }

  void each_record_block(const std::function<void(const char*, std::size_t)>& f) override {
    for (std::uint64_t done = 0; done < total_;) {
      const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(65536, total_ - done));
      buffer_.resize(n * record_length_);
      if (std::fread(buffer_.data(), record_length_, n, f_.get()) != n) {
        throw InputError("load_cloud: " + name_ + ": truncated or unreadable in its point records");
      }
      f(buffer_.data(), n);
      done += n;
    }
    seek_records();
  }

  void seek_records() {
    if (fseeko(f_.get(), static_cast<off_t>(offset_), SEEK_SET) != 0) {
      throw InputError("load_cloud: " + name_ + ": cannot seek to its point records");
    }
    read_ = 0;
  }

  File f_;
  std::size_t offset_;
  std::uint64_t read_ = 0;
  std::vector<char> buffer_;
};


}  // namespace

std::unique_ptr<PointStream> open_las_stream(const std::filesystem::path& path, const std::string& name,
                                             const LoadOptions* options) {
  FileMapping map;
  {
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return nullptr;
    const bool mapped = map.map(fd);
    ::close(fd);
    if (!mapped) return nullptr;
  }
  // Only the header, the VLRs and the EVLRs are touched through the mapping.
  LasHeader header = parse_las_header(map.bytes(), name, false);
  std::vector<std::string> format_notes = std::move(header.notes);
  for (std::string& note : las_format_notes(header)) format_notes.push_back(std::move(note));
  std::vector<std::string> crs_notes;
  std::string crs = las_crs(header, crs_notes);
  header.vlrs.clear();  // they point into the mapping

  LasStream::File f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) return nullptr;
  return std::make_unique<LasStream>(std::move(f), name, header, options, std::move(format_notes), std::move(crs_notes),
                                     std::move(crs));
}

}  // namespace hc::pipeline::detail
