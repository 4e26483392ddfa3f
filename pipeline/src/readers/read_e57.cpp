// E57 reader (ASTM E2807-11, "Standard Specification for 3D Imaging Data Exchange, Version 1.0"),
// written clean room from the public specification: the file header (§ 7.2 / Table 1), the paged
// physical layout with a CRC-32C per page (§ 7.3), the XML section (§ 8) parsed with pugixml, and
// the CompressedVector binary sections (§ 9: section header, data / index / empty packets,
// bit-packed integer, scaled-integer and float bytestreams) of every data3D scan (§ 8.4.x,
// Data3D, PointRecord, Pose, IntensityLimits, ColorLimits).

#include "byte_io.hpp"
#include "byte_source.hpp"
#include "../posix_io.hpp"
#include "readers.hpp"
#include "text_parse.hpp"

#include "hc/common/error.hpp"

#include <pugixml.hpp>

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <tuple>
#include <vector>

#include <cerrno>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#if defined(__x86_64__) && defined(__GNUC__)
#include <nmmintrin.h>
#define HC_E57_HW_CRC 1
#endif

namespace hc::pipeline::detail {

namespace {

// E57 stores integers little-endian; this reader loads them with memcpy.
static_assert(std::endian::native == std::endian::little, "read_e57 assumes a little-endian host");

// ---------------------------------------------------------------------------------------------
// CRC-32C (Castagnoli, reflected polynomial 0x82F63B78, initial value and final xor 0xFFFFFFFF),
// the checksum of E2807 § 7.3. Hardware (SSE 4.2 crc32) when the CPU has it, else slicing-by-8.

struct Crc32cTables {
  std::array<std::array<std::uint32_t, 256>, 8> t{};
  Crc32cTables() {
    for (std::uint32_t i = 0; i < 256; ++i) {
      std::uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c >> 1) ^ ((c & 1U) ? 0x82F63B78U : 0U);
      t[0][i] = c;
    }
    for (std::size_t s = 1; s < 8; ++s)
      for (std::size_t i = 0; i < 256; ++i) t[s][i] = (t[s - 1][i] >> 8) ^ t[0][t[s - 1][i] & 0xFFU];
  }
};

std::uint32_t crc32c_soft(const unsigned char* p, std::size_t n) {
  static const Crc32cTables tables;
  const auto& t = tables.t;
  std::uint32_t crc = 0xFFFFFFFFU;
  while (n >= 8) {
    std::uint64_t w;
    std::memcpy(&w, p, 8);
    w ^= crc;
    crc = t[7][w & 0xFF] ^ t[6][(w >> 8) & 0xFF] ^ t[5][(w >> 16) & 0xFF] ^ t[4][(w >> 24) & 0xFF] ^
          t[3][(w >> 32) & 0xFF] ^ t[2][(w >> 40) & 0xFF] ^ t[1][(w >> 48) & 0xFF] ^ t[0][w >> 56];
    p += 8;
    n -= 8;
  }
  while (n-- > 0) crc = (crc >> 8) ^ t[0][(crc ^ *p++) & 0xFFU];
  return crc ^ 0xFFFFFFFFU;
}

#ifdef HC_E57_HW_CRC
__attribute__((target("sse4.2"))) std::uint32_t crc32c_hw(const unsigned char* p, std::size_t n) {
  std::uint64_t crc = 0xFFFFFFFFU;
  while (n >= 8) {
    std::uint64_t w;
    std::memcpy(&w, p, 8);
    crc = _mm_crc32_u64(crc, w);
    p += 8;
    n -= 8;
  }
  auto c = static_cast<std::uint32_t>(crc);
  while (n-- > 0) c = _mm_crc32_u8(c, *p++);
  return c ^ 0xFFFFFFFFU;
}
#endif

std::uint32_t crc32c(const unsigned char* p, std::size_t n) {
#ifdef HC_E57_HW_CRC
  static const bool hw = __builtin_cpu_supports("sse4.2");
  if (hw) return crc32c_hw(p, n);
#endif
  return crc32c_soft(p, n);
}

std::string hex(std::uint64_t v) {
  char buf[24];
  std::snprintf(buf, sizeof buf, "0x%llx", static_cast<unsigned long long>(v));
  return buf;
}

// ---------------------------------------------------------------------------------------------
// The paged file (E2807 § 7.3): each page of `page` bytes holds page − 4 bytes of logical data
// followed by the CRC-32C of those bytes, stored big-endian. Every page is checked the first
// time any of its bytes is read.

class PagedFile {
 public:
  /// The paged file held in memory: `bytes` (at least the E57 file length long; the pages of
  /// whole page size within it are read).
  PagedFile(const std::string& bytes, std::uint64_t page, std::string name)
      : data_(reinterpret_cast<const unsigned char*>(bytes.data())),
        size_(bytes.size()),
        page_(page),
        payload_(page - 4),
        name_(std::move(name)),
        checked_((bytes.size() + page - 1) / page, false) {}
  /// The paged file read from `fd` (not owned) with pread, one page at a time, the first `size`
  /// bytes of it; a page is checked every time it is read from the file.
  PagedFile(int fd, std::uint64_t size, std::uint64_t page, std::string name)
      : fd_(fd), size_(size), page_(page), payload_(page - 4), name_(std::move(name)), buffer_(page) {}

  std::uint64_t payload() const { return payload_; }
  std::uint64_t logical_size() const { return (size_ / page_) * payload_; }
  /// Physical offset → logical offset (the physical offset must not point into a CRC).
  std::uint64_t to_logical(std::uint64_t phys) const { return (phys / page_) * payload_ + phys % page_; }

  /// Copies `n` logical bytes starting at logical offset `logical` into `dst`, checking pages.
  /// `what` names the structure read, for the error when it runs past the end of the file.
  void read(std::uint64_t logical, std::size_t n, unsigned char* dst, const std::string& what) {
    if (logical > logical_size() || n > logical_size() - logical) {
      throw InputError("load_cloud: " + name_ + ": " + what + " at logical offset " +
                       std::to_string(logical) + " (" + std::to_string(n) +
                       " bytes) runs past the end of the file (" + std::to_string(logical_size()) +
                       " logical bytes): the file is truncated or corrupt");
    }
    while (n > 0) {
      const std::uint64_t pg = logical / payload_;
      const std::uint64_t in = logical % payload_;
      const unsigned char* p = page_data(pg);
      const std::size_t take = static_cast<std::size_t>(std::min<std::uint64_t>(n, payload_ - in));
      std::memcpy(dst, p + in, take);
      dst += take;
      n -= take;
      logical += take;
    }
  }

  /// Page pg's bytes, its checksum checked (in memory: the first time; from a file: at every read).
  const unsigned char* page_data(std::uint64_t pg) {
    if (data_ != nullptr) {
      const unsigned char* p = data_ + pg * page_;
      if (!checked_[pg]) {
        verify(p, pg);
        checked_[pg] = true;
      }
      return p;
    }
    if (pg != cached_) {
      if (!pread_full(fd_, buffer_.data(), page_, pg * page_)) {
        throw InputError("load_cloud: " + name_ + ": the page at physical offset " + std::to_string(pg * page_) +
                         " cannot be read (the file is truncated or unreadable)");
      }
      cached_ = std::numeric_limits<std::uint64_t>::max();
      verify(buffer_.data(), pg);
      cached_ = pg;
    }
    return buffer_.data();
  }

 private:
  void verify(const unsigned char* p, std::uint64_t pg) const {
    const std::uint32_t stored = (std::uint32_t{p[payload_]} << 24) | (std::uint32_t{p[payload_ + 1]} << 16) |
                                 (std::uint32_t{p[payload_ + 2]} << 8) | std::uint32_t{p[payload_ + 3]};
    const std::uint32_t computed = crc32c(p, payload_);
    if (stored != computed) {
      throw InputError("load_cloud: " + name_ + ": bad page checksum: the page at physical offset " +
                       std::to_string(pg * page_) + " stores CRC-32C " + hex(stored) + " but its " +
                       std::to_string(payload_) + " data bytes give " + hex(computed) +
                       " (E57 pages end in the CRC-32C of their data): the file is corrupt");
    }
  }

  const unsigned char* data_ = nullptr;
  int fd_ = -1;
  std::uint64_t size_, page_, payload_;
  std::string name_;
  std::vector<bool> checked_;
  std::vector<unsigned char> buffer_;
  std::uint64_t cached_ = std::numeric_limits<std::uint64_t>::max();
};

// ---------------------------------------------------------------------------------------------
// XML helpers (E2807 § 8: element types Integer, ScaledInteger, Float, String, Structure, Vector,
// CompressedVector, Blob; values as element text, attributes for bounds and scaling).

std::string_view trim(std::string_view s) {
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
  return s;
}

template <class T>
std::optional<T> parse_text(std::string_view s) {
  s = trim(s);
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  if (s.empty()) return std::nullopt;
  T v{};
  const auto r = std::from_chars(s.data(), s.data() + s.size(), v);
  if (r.ec != std::errc() || r.ptr != s.data() + s.size()) return std::nullopt;
  return v;
}

class Xml {
 public:
  explicit Xml(std::string name) : name_(std::move(name)) {}

  [[noreturn]] void fail(const pugi::xml_node& node, const std::string& what) const {
    throw InputError("load_cloud: " + name_ + ": XML element <" + path(node) + ">: " + what);
  }

  static std::string path(pugi::xml_node n) {
    std::string p;
    for (; n && n.type() == pugi::node_element; n = n.parent()) p = p.empty() ? n.name() : std::string(n.name()) + "/" + p;
    return p;
  }

  /// An attribute as a number; `fallback` when absent; an error when present but not a number.
  template <class T>
  T attr(const pugi::xml_node& node, const char* key, T fallback) const {
    const pugi::xml_attribute a = node.attribute(key);
    if (!a) return fallback;
    const auto v = parse_text<T>(a.value());
    if (!v) fail(node, std::string("attribute ") + key + "=\"" + a.value() + "\" is not a number");
    return *v;
  }

  /// The value of a terminal element (Integer, ScaledInteger → scaled, Float); an empty element
  /// is 0 (the default of § 8).
  double number(const pugi::xml_node& node) const {
    const std::string type = node.attribute("type").value();
    const std::string_view text = trim(node.child_value());
    if (type == "Integer") {
      if (text.empty()) return 0.0;
      const auto v = parse_text<std::int64_t>(text);
      if (!v) fail(node, "Integer value '" + std::string(text) + "' is not an integer");
      return static_cast<double>(*v);
    }
    if (type == "ScaledInteger") {
      std::int64_t raw = 0;
      if (!text.empty()) {
        const auto v = parse_text<std::int64_t>(text);
        if (!v) fail(node, "ScaledInteger value '" + std::string(text) + "' is not an integer");
        raw = *v;
      }
      return static_cast<double>(raw) * attr<double>(node, "scale", 1.0) + attr<double>(node, "offset", 0.0);
    }
    if (type == "Float") {
      if (text.empty()) return 0.0;
      const auto v = parse_text<double>(text);
      if (!v) fail(node, "Float value '" + std::string(text) + "' is not a number");
      return *v;
    }
    fail(node, "type '" + type + "' found, expected Integer, ScaledInteger or Float");
  }

  /// The number held by child `key` of `parent`, or `fallback` when there is no such child.
  double child_number(const pugi::xml_node& parent, const char* key, double fallback) const {
    const pugi::xml_node c = parent.child(key);
    return c ? number(c) : fallback;
  }

 private:
  std::string name_;
};

// ---------------------------------------------------------------------------------------------
// One field of a CompressedVector prototype (E2807 § 9.3: one bytestream per terminal element,
// in document order).

struct Field {
  enum class Kind { Integer, ScaledInteger, Float } kind = Kind::Float;
  std::string name;
  bool single = false;                                      // Float precision="single"
  std::int64_t minimum = std::numeric_limits<std::int64_t>::min();
  std::int64_t maximum = std::numeric_limits<std::int64_t>::max();
  double scale = 1.0, offset = 0.0;                         // ScaledInteger
  double fmin = -std::numeric_limits<double>::max();        // Float bounds
  double fmax = std::numeric_limits<double>::max();
  unsigned bits = 0;                                         // Integer kinds: packed width

  /// Bytes the bytestream needs for `count` records.
  std::uint64_t bytes_needed(std::uint64_t count) const {
    if (kind == Kind::Float) return count * (single ? 4U : 8U);
    return (count * bits + 7) / 8;
  }
  /// The value range in the field's own units (scaled for ScaledInteger).
  std::pair<double, double> bounds() const {
    if (kind == Kind::Float) return {fmin, fmax};
    const double a = static_cast<double>(minimum), b = static_cast<double>(maximum);
    if (kind == Kind::Integer) return {a, b};
    const double sa = a * scale + offset, sb = b * scale + offset;
    return {std::min(sa, sb), std::max(sa, sb)};
  }
  std::string describe() const {
    switch (kind) {
      case Kind::Float: return name + ":Float" + (single ? "32" : "64");
      case Kind::Integer: return name + ":Integer(" + std::to_string(bits) + " bit)";
      case Kind::ScaledInteger: return name + ":ScaledInteger(" + std::to_string(bits) + " bit)";
    }
    return name;
  }
};

/// Packed width of an integer field: ceil(log2(maximum − minimum + 1)) bits (E2807 § 9.3.3).
unsigned packed_bits(std::int64_t minimum, std::int64_t maximum) {
  const std::uint64_t range = static_cast<std::uint64_t>(maximum) - static_cast<std::uint64_t>(minimum);
  return range == 0 ? 0U : static_cast<unsigned>(std::bit_width(range));
}

void collect_fields(const Xml& xml, const pugi::xml_node& node, std::vector<Field>& out) {
  for (const pugi::xml_node c : node.children()) {
    if (c.type() != pugi::node_element) continue;
    const std::string type = c.attribute("type").value();
    Field f;
    f.name = c.name();
    if (type == "Structure") {  // nested structures: their terminals, in order
      collect_fields(xml, c, out);
      continue;
    }
    if (type == "Integer" || type == "ScaledInteger") {
      f.kind = type == "Integer" ? Field::Kind::Integer : Field::Kind::ScaledInteger;
      f.minimum = xml.attr<std::int64_t>(c, "minimum", f.minimum);
      f.maximum = xml.attr<std::int64_t>(c, "maximum", f.maximum);
      if (f.maximum < f.minimum) xml.fail(c, "maximum is below minimum");
      f.scale = xml.attr<double>(c, "scale", 1.0);
      f.offset = xml.attr<double>(c, "offset", 0.0);
      f.bits = packed_bits(f.minimum, f.maximum);
    } else if (type == "Float") {
      const std::string precision = c.attribute("precision") ? c.attribute("precision").value() : "double";
      if (precision != "single" && precision != "double")
        xml.fail(c, "precision '" + precision + "' found, expected single or double");
      f.single = precision == "single";
      const double lim = f.single ? static_cast<double>(std::numeric_limits<float>::max())
                                  : std::numeric_limits<double>::max();
      f.fmin = xml.attr<double>(c, "minimum", -lim);
      f.fmax = xml.attr<double>(c, "maximum", lim);
    } else {
      xml.fail(c, "prototype field of type '" + type +
                      "' found, expected Integer, ScaledInteger, Float or Structure (this reader does "
                      "not decode " + type + " fields)");
    }
    out.push_back(std::move(f));
  }
}

/// Decodes `count` values of one field from bytestream bytes `p`, the first value starting at
/// bit `bit0` (a multiple of 8 for Float fields and byte-wide integers; `p` carries 16 bytes of
/// zero padding after the last byte a value needs). Bit packing: value i occupies bits
/// [bit0 + i·b, bit0 + (i+1)·b) of the stream, least significant bit first (E2807 § 9.3.3);
/// value = minimum + raw, then raw·scale + offset for ScaledInteger. Value i goes to
/// out[i · stride].
void decode_field(const Field& f, const unsigned char* p, std::uint64_t bit0, std::size_t count, double* out,
                  std::size_t stride) {
  if (f.kind == Field::Kind::Float) {
    p += bit0 / 8;
    if (f.single) {
      for (std::size_t i = 0; i < count; ++i) out[i * stride] = static_cast<double>(std::bit_cast<float>(load_le<std::uint32_t>(p + 4 * i)));
    } else {
      for (std::size_t i = 0; i < count; ++i) out[i * stride] = std::bit_cast<double>(load_le<std::uint64_t>(p + 8 * i));
    }
    return;
  }
  const unsigned b = f.bits;
  const bool scaled = f.kind == Field::Kind::ScaledInteger;
  const auto umin = static_cast<std::uint64_t>(f.minimum);
  auto finish = [&](std::uint64_t raw) {
    const auto v = static_cast<std::int64_t>(umin + raw);
    return scaled ? static_cast<double>(v) * f.scale + f.offset : static_cast<double>(v);
  };
  if (b == 0) {
    for (std::size_t i = 0; i < count; ++i) out[i * stride] = finish(0);
    return;
  }
  if (b == 8 || b == 16 || b == 32 || b == 64) {  // byte-aligned widths
    p += bit0 / 8;
    const unsigned nb = b / 8;
    for (std::size_t i = 0; i < count; ++i) {
      std::uint64_t raw = 0;
      switch (nb) {
        case 1: raw = p[i]; break;
        case 2: raw = load_le<std::uint16_t>(p + 2 * i); break;
        case 4: raw = load_le<std::uint32_t>(p + 4 * i); break;
        default: raw = load_le<std::uint64_t>(p + 8 * i); break;
      }
      out[i * stride] = finish(raw);
    }
    return;
  }
  const std::uint64_t mask = (std::uint64_t{1} << b) - 1;  // b < 64 here
  std::uint64_t bit = bit0;
  for (std::size_t i = 0; i < count; ++i, bit += b) {
    const std::uint64_t byte = bit >> 3;
    const unsigned shift = static_cast<unsigned>(bit & 7U);
    std::uint64_t w = load_le<std::uint64_t>(p + byte) >> shift;
    if (shift + b > 64) w |= std::uint64_t{p[byte + 8]} << (64 - shift);
    out[i * stride] = finish(w & mask);
  }
}

// ---------------------------------------------------------------------------------------------
// One data3D scan.

struct Pose {
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  bool has_rotation = false, has_translation = false;
};

Pose read_pose(const Xml& xml, const pugi::xml_node& scan) {
  Pose pose;
  const pugi::xml_node node = scan.child("pose");
  if (!node) return pose;
  if (const pugi::xml_node r = node.child("rotation")) {
    pose.has_rotation = true;
    const double w = xml.child_number(r, "w", 1.0), x = xml.child_number(r, "x", 0.0),
                 y = xml.child_number(r, "y", 0.0), z = xml.child_number(r, "z", 0.0);
    const double norm = std::sqrt(w * w + x * x + y * y + z * z);
    if (!(norm > 0.0) || !std::isfinite(norm)) xml.fail(r, "rotation quaternion has zero or non-finite norm");
    pose.q = Eigen::Quaterniond(w / norm, x / norm, y / norm, z / norm);
  }
  if (const pugi::xml_node t = node.child("translation")) {
    pose.has_translation = true;
    pose.t = {xml.child_number(t, "x", 0.0), xml.child_number(t, "y", 0.0), xml.child_number(t, "z", 0.0)};
  }
  return pose;
}

/// The bytestreams of one CompressedVector (E2807 § 9: a binary section header, then packets
/// from dataPhysicalOffset to the end of the section), read packet by packet as its values are
/// asked for: each field's buffers are queued as the packets come and dropped once decoded, so
/// the memory is the records asked for at once (and what the packets hold ahead of them), not
/// the scan. Fields not `wanted` are read too when `read_all` (their pages checked, as a whole
/// read of every bytestream checks them) and their bytes dropped.
/// The errors, in the order a read of every packet meets them: the section header, a packet's
/// header, type or length, a page's CRC; then (finish(), or a field asked for more records than
/// the packets held) a bytestream shorter than recordCount needs: the first field so in
/// prototype order, among every field when `read_all`, else among the wanted ones.
class BytestreamCursor {
 public:
  BytestreamCursor(PagedFile& file, const Xml& xml, const pugi::xml_node& points, const std::vector<Field>& fields,
                   std::uint64_t count, const std::string& name, std::vector<bool> wanted, bool read_all)
      : file_(file), fields_(fields), count_(count), name_(name), wanted_(std::move(wanted)), read_all_(read_all),
        queue_(fields.size()), total_(fields.size(), 0) {
    if (count == 0) return;  // no section is read for an empty scan
    const auto section_phys = xml.attr<std::uint64_t>(points, "fileOffset", 0);
    if (!points.attribute("fileOffset")) xml.fail(points, "CompressedVector without fileOffset");
    const std::uint64_t section_log = file.to_logical(section_phys);
    unsigned char hdr[32];
    file.read(section_log, 32, hdr, "the CompressedVector section header");
    if (hdr[0] != 1) {
      throw InputError("load_cloud: " + name + ": the binary section at physical offset " + std::to_string(section_phys) +
                       " has section id " + std::to_string(hdr[0]) + ", expected 1 (CompressedVector)");
    }
    const auto section_len = load_le<std::uint64_t>(hdr + 8);
    const auto data_phys = load_le<std::uint64_t>(hdr + 16);
    end_ = section_log + section_len;
    pos_ = file.to_logical(data_phys);
    if (section_len < 32 || pos_ < section_log + 32 || pos_ > end_) {
      throw InputError("load_cloud: " + name + ": the binary section at physical offset " + std::to_string(section_phys) +
                       " has length " + std::to_string(section_len) + " and data offset " + std::to_string(data_phys) +
                       ", expected the data inside the section");
    }
  }

  /// Reserves each wanted queue for the next n records (what a packet holds past them
  /// included, and the decoder's padding), so that a large request (the whole read's: every
  /// record) fills its queues without growing them packet by packet.
  void expect(std::uint64_t n) {
    for (std::size_t k = 0; k < fields_.size(); ++k) {
      if (!wanted_[k]) continue;
      const std::uint64_t want = queue_[k].bytes.size() + fields_[k].bytes_needed(std::min(n, count_)) + 65536 + 16;
      if (want > queue_[k].bytes.capacity()) queue_[k].bytes.reserve(static_cast<std::size_t>(want));
    }
  }

  /// Decodes the next n values of wanted field k into out[i · stride] (decode_field), reading
  /// packets until its queue holds them. @throws as the class says.
  void decode(std::size_t k, std::size_t n, double* out, std::size_t stride) {
    Queue& q = queue_[k];
    const Field& f = fields_[k];
    const std::uint64_t bits = f.kind == Field::Kind::Float ? (f.single ? 32U : 64U) : f.bits;
    const std::uint64_t need_bits = q.bit + bits * n;
    while (static_cast<std::uint64_t>(q.bytes.size()) * 8 < need_bits) {
      if (!read_packet()) {
        check_lengths();  // throws: this field (or an earlier one) is short
        throw std::logic_error("BytestreamCursor: field " + f.name + " ran out of bytes that its length check allows");
      }
    }
    q.bytes.append(16, '\0');  // padding for the 8-byte loads of the bit unpacker
    decode_field(f, reinterpret_cast<const unsigned char*>(q.bytes.data()), q.bit, n, out, stride);
    q.bytes.resize(q.bytes.size() - 16);
    q.bit += bits * n;
    q.bytes.erase(0, static_cast<std::size_t>(q.bit / 8));
    q.bit %= 8;
  }

  /// Decodes the next n values of wanted field k in blocks of at most `block` values, calling
  /// each(const std::vector<double>& values) per block until it returns false.
  /// @return false when `each` stopped it. @throws as decode.
  template <class Each>
  bool each_block(std::size_t k, std::uint64_t n, std::size_t block, Each&& each) {
    std::vector<double> v;
    for (std::uint64_t done = 0; done < n;) {
      v.resize(static_cast<std::size_t>(std::min<std::uint64_t>(n - done, block)));
      decode(k, v.size(), v.data(), 1);
      if (!each(v)) return false;
      done += v.size();
    }
    return true;
  }

  /// Reads the packets left (their errors) and checks the bytestreams' lengths against
  /// recordCount. @throws as the class says.
  void finish() {
    while (read_packet()) {
    }
    check_lengths();
  }

 private:
  struct Queue {
    std::string bytes;   // the field's bytes not yet decoded, from the byte holding bit `bit`
    std::uint64_t bit = 0;
  };

  /// Appends the next data packet's buffers to the queues (index and empty packets skipped);
  /// false at the section's end.
  bool read_packet() {
    while (pos_ + 4 <= end_) {
      unsigned char ph[4];
      file_.read(pos_, 4, ph, "a packet header");
      const std::uint64_t plen = std::uint64_t{load_le<std::uint16_t>(ph + 2)} + 1;
      const std::string where = "the packet at logical offset " + std::to_string(pos_);
      if (pos_ + plen > end_) {
        throw InputError("load_cloud: " + name_ + ": " + where + " (" + std::to_string(plen) +
                         " bytes) runs past the end of its binary section (logical " + std::to_string(end_) +
                         "): the file is corrupt");
      }
      const std::uint64_t at_packet = pos_;
      pos_ += plen;
      if (ph[0] == 1) {  // data packet: type, flags, length − 1, bytestream count, buffer lengths
        if (plen < 6) throw InputError("load_cloud: " + name_ + ": " + where + " is shorter than a data packet header");
        unsigned char cnt[2];
        file_.read(at_packet + 4, 2, cnt, "a data packet header");
        const std::size_t nstreams = load_le<std::uint16_t>(cnt);
        if (nstreams != fields_.size()) {
          throw InputError("load_cloud: " + name_ + ": " + where + " holds " + std::to_string(nstreams) +
                           " bytestreams, expected " + std::to_string(fields_.size()) + " (one per prototype field)");
        }
        std::uint64_t at = 6 + 2 * nstreams;
        if (at > plen) throw InputError("load_cloud: " + name_ + ": " + where + " is shorter than its header");
        lengths_.resize(2 * nstreams);
        file_.read(at_packet + 6, lengths_.size(), lengths_.data(), "a data packet header");
        for (std::size_t k = 0; k < nstreams; ++k) {
          const std::uint64_t len = load_le<std::uint16_t>(lengths_.data() + 2 * k);
          if (at + len > plen) {
            throw InputError("load_cloud: " + name_ + ": " + where + ": bytestream " + std::to_string(k) + " (" +
                             fields_[k].name + ") of " + std::to_string(len) + " bytes runs past the packet's end");
          }
          if (wanted_[k] || read_all_) {
            total_[k] += len;
            std::string& into = wanted_[k] ? queue_[k].bytes : scratch_;
            const std::size_t old = wanted_[k] ? into.size() : 0;
            into.resize(old + len);
            file_.read(at_packet + at, len, reinterpret_cast<unsigned char*>(into.data() + old), "a bytestream buffer");
          }
          at += len;
        }
        return true;
      }
      if (ph[0] != 0 && ph[0] != 2) {  // 0 index packet, 2 empty packet: skipped
        throw InputError("load_cloud: " + name_ + ": " + where + " has packet type " + std::to_string(ph[0]) +
                         ", expected 0 (index), 1 (data) or 2 (empty)");
      }
    }
    return false;
  }

  void check_lengths() const {
    for (std::size_t k = 0; k < fields_.size(); ++k) {
      if (!(wanted_[k] || read_all_)) continue;
      const std::uint64_t needed = fields_[k].bytes_needed(count_);
      if (total_[k] < needed) {
        throw InputError("load_cloud: " + name_ + ": the bytestream of field '" + fields_[k].name + "' holds " +
                         std::to_string(total_[k]) + " bytes, expected " + std::to_string(needed) + " for recordCount " +
                         std::to_string(count_) + ": the file is truncated or corrupt");
      }
    }
  }

  PagedFile& file_;
  const std::vector<Field>& fields_;
  std::uint64_t count_;
  const std::string& name_;
  std::vector<bool> wanted_;
  bool read_all_;
  std::vector<Queue> queue_;
  std::vector<std::uint64_t> total_;  // bytes seen per field
  std::uint64_t pos_ = 0, end_ = 0;   // logical offsets: the next packet, the section's end
  std::vector<unsigned char> lengths_;
  std::string scratch_;
};

const char* const kKnownFields[] = {"cartesianX",     "cartesianY",           "cartesianZ",
                                    "sphericalRange", "sphericalAzimuth",     "sphericalElevation",
                                    "cartesianInvalidState", "sphericalInvalidState", "intensity",
                                    "colorRed",       "colorGreen",           "colorBlue",
                                    "rowIndex",       "columnIndex"};

struct ScanOut {
  Cloud cloud;
  std::vector<std::string> notes;
};

/// One data3D scan (E2807 § 8.4) decoded in order, any number of records at a time (the whole
/// read: all at once; the stream: a chunk's worth), with the same values either way: each
/// record's point and attributes depend on that record and on values fixed before the first
/// (pose, limits). Points: cartesian, or spherical turned cartesian (§ 8.4.20), in the file
/// frame by the scan's pose; records of invalid state 1 or 2 skipped. Intensity normalised to
/// [0, 1] with intensityLimits, else the prototype's bounds, else the data's own range (the
/// least and greatest non-NaN intensity of the scan's records, from a first pass over its
/// bytestreams); colour scaled to 8 bit with colorLimits, else the prototype's bounds, else
/// [0, 255]; row/col with `grid_index`. The scan's notes come from finish().
/// @throws hc::InputError naming the file as read_e57 (a bad scan element, packet, page or
/// bytestream; BytestreamCursor).
class ScanReader {
 public:
  ScanReader(PagedFile& file, const Xml& xml, const pugi::xml_node& scan, std::size_t index, const std::string& name,
             bool grid_index)
      : name_(name), grid_index_(grid_index) {
    label_ = "scan " + std::to_string(index) + (scan.child("name") ? " '" + std::string(trim(scan.child("name").child_value())) + "'" : "");
    const pugi::xml_node points = scan.child("points");
    if (!points) xml.fail(scan, "data3D scan without a 'points' CompressedVector");
    if (std::string(points.attribute("type").value()) != "CompressedVector")
      xml.fail(points, "type '" + std::string(points.attribute("type").value()) + "' found, expected CompressedVector");
    if (!points.attribute("recordCount")) xml.fail(points, "CompressedVector without recordCount");
    count_ = xml.attr<std::uint64_t>(points, "recordCount", 0);
    const pugi::xml_node proto = points.child("prototype");
    if (!proto) xml.fail(points, "CompressedVector without a prototype");
    collect_fields(xml, proto, fields_);
    for (std::size_t k = 0; k < fields_.size(); ++k) at_.emplace(fields_[k].name, k);
    cart_ = has("cartesianX") && has("cartesianY") && has("cartesianZ");
    const bool sph = has("sphericalRange") && has("sphericalAzimuth") && has("sphericalElevation");
    if (!cart_ && !sph) {
      std::string list;
      for (const auto& f : fields_) list += (list.empty() ? "" : ", ") + f.name;
      xml.fail(proto, "no coordinates: found fields {" + list + "}, expected cartesianX/Y/Z or sphericalRange/Azimuth/Elevation");
    }
    if (count_ > std::numeric_limits<std::uint32_t>::max())
      xml.fail(points, "recordCount " + std::to_string(count_) + " is larger than this reader accepts");

    pose_ = read_pose(xml, scan);
    rot_ = pose_.q.toRotationMatrix();
    identity_ = !pose_.has_rotation && !pose_.has_translation;
    // Stored precision: single-precision floats in the file's own frame (a pose moves the points
    // away from what was stored, so only an identity pose tells the loader the stored magnitudes).
    float32_ = cart_ && identity_ && fields_[at_["cartesianX"]].single && fields_[at_["cartesianY"]].single &&
               fields_[at_["cartesianZ"]].single && fields_[at_["cartesianX"]].kind == Field::Kind::Float;
    direct_ = cart_ && !has("cartesianInvalidState");  // every record a point: decoded in place
    state_ = field_of(cart_ ? "cartesianInvalidState" : "sphericalInvalidState");
    intensity_ = field_of("intensity");
    rgb_ = has("colorRed") && has("colorGreen") && has("colorBlue");
    row_col_ = has("rowIndex") && has("columnIndex");

    // What is decoded: the coordinates, state, intensity, colour and (grid_index) row/col.
    std::vector<bool> wanted(fields_.size(), false);
    for (const char* key : {"cartesianX", "cartesianY", "cartesianZ"})
      if (cart_) wanted[at_[key]] = true;
    for (const char* key : {"sphericalRange", "sphericalAzimuth", "sphericalElevation"})
      if (!cart_) wanted[at_[key]] = true;
    if (state_ != kNone) wanted[state_] = true;
    if (intensity_ != kNone) wanted[intensity_] = true;
    if (rgb_)
      for (const char* key : {"colorRed", "colorGreen", "colorBlue"}) wanted[at_[key]] = true;
    if (row_col_ && grid_index_)
      for (const char* key : {"rowIndex", "columnIndex"}) wanted[at_[key]] = true;

    if (intensity_ != kNone) {  // normalised with intensityLimits, else the prototype's bounds
      const Field& f = fields_[intensity_];
      std::tie(i_lo_, i_hi_) = f.bounds();
      i_source_ = "prototype bounds";
      if (const pugi::xml_node lim = scan.child("intensityLimits")) {
        i_lo_ = xml.child_number(lim, "intensityMinimum", i_lo_);
        i_hi_ = xml.child_number(lim, "intensityMaximum", i_hi_);
        i_source_ = "intensityLimits";
      }
      if (!(i_hi_ > i_lo_) || !std::isfinite(i_hi_ - i_lo_)) {
        // The data's own range: a first pass over every bytestream (their errors as the read's).
        i_lo_ = 0.0;
        i_hi_ = 1.0;
        bool any = false;
        std::vector<bool> only(fields_.size(), false);
        only[intensity_] = true;
        BytestreamCursor first(file, xml, points, fields_, count_, name_, only, true);
        (void)first.each_block(intensity_, count_, std::size_t{1} << 16, [&](const std::vector<double>& v) {
          for (const double x : v) {
            if (std::isnan(x)) continue;
            i_lo_ = any ? std::min(i_lo_, x) : x;
            i_hi_ = any ? std::max(i_hi_, x) : x;
            any = true;
          }
          return true;
        });
        first.finish();
        i_source_ = "the data's own range (no usable limits)";
      }
      i_inv_ = i_hi_ > i_lo_ ? 1.0 / (i_hi_ - i_lo_) : 0.0;
    }
    if (rgb_) {
      const char* keys[3] = {"colorRed", "colorGreen", "colorBlue"};
      const char* lim_keys[3][2] = {{"colorRedMinimum", "colorRedMaximum"},
                                    {"colorGreenMinimum", "colorGreenMaximum"},
                                    {"colorBlueMinimum", "colorBlueMaximum"}};
      const pugi::xml_node lim = scan.child("colorLimits");
      colour_limits_ = static_cast<bool>(lim);
      for (int ch = 0; ch < 3; ++ch) {
        auto [lo, hi] = fields_[at_[keys[ch]]].bounds();
        if (lim) {
          lo = xml.child_number(lim, lim_keys[ch][0], lo);
          hi = xml.child_number(lim, lim_keys[ch][1], hi);
        }
        if (!(hi > lo) || !std::isfinite(hi - lo)) {
          lo = 0.0;
          hi = 255.0;
        }
        c_lo_[ch] = lo;
        c_k_[ch] = 255.0 / (hi - lo);
      }
    }
    cursor_.emplace(file, xml, points, fields_, count_, name_, std::move(wanted), true);
  }

  ScanReader(const ScanReader&) = delete;  // its cursor refers to its fields
  ScanReader& operator=(const ScanReader&) = delete;

  /// Whether the scan's coordinates are single-precision floats in the file frame (Cloud::float32_xyz).
  bool float32_xyz() const { return float32_; }
  /// Records not decoded yet.
  std::uint64_t left() const { return count_ - done_; }

  /// Decodes the next min(n, left()) records into `out` (replaced): their kept points, and
  /// intensity, rgb and (grid_index) row/col where the scan has them.
  void next(std::size_t n, Cloud& out) {
    n = static_cast<std::size_t>(std::min<std::uint64_t>(n, left()));
    cursor_->expect(n);
    out = Cloud();
    out.float32_xyz = float32_;
    std::vector<std::size_t> keep;
    if (direct_) {
      out.xyz.resize(3, static_cast<Eigen::Index>(n));
      const char* axes[3] = {"cartesianX", "cartesianY", "cartesianZ"};
      for (std::size_t k = 0; k < 3; ++k) cursor_->decode(at_[axes[k]], n, out.xyz.data() + k, 3);
      if (!identity_) {
        for (Eigen::Index j = 0; j < out.xyz.cols(); ++j) out.xyz.col(j) = rot_ * out.xyz.col(j) + pose_.t;
      }
      if (intensity_ != kNone || rgb_ || (row_col_ && grid_index_)) {  // index for the attributes
        keep.resize(n);
        for (std::size_t i = 0; i < n; ++i) keep[i] = i;
      }
    } else {
      std::vector<double> a(n), b(n), c(n), state;
      if (cart_) {
        cursor_->decode(at_["cartesianX"], n, a.data(), 1);
        cursor_->decode(at_["cartesianY"], n, b.data(), 1);
        cursor_->decode(at_["cartesianZ"], n, c.data(), 1);
      } else {
        std::vector<double> r(n), az(n), el(n);
        cursor_->decode(at_["sphericalRange"], n, r.data(), 1);
        cursor_->decode(at_["sphericalAzimuth"], n, az.data(), 1);
        cursor_->decode(at_["sphericalElevation"], n, el.data(), 1);
        for (std::size_t i = 0; i < n; ++i) {  // E2807 § 8.4.20: x = r cos(el) cos(az), ...
          const double ce = std::cos(el[i]);
          a[i] = r[i] * ce * std::cos(az[i]);
          b[i] = r[i] * ce * std::sin(az[i]);
          c[i] = r[i] * std::sin(el[i]);
        }
      }
      if (state_ != kNone) {
        state.resize(n);
        cursor_->decode(state_, n, state.data(), 1);
      }
      keep.reserve(n);
      for (std::size_t i = 0; i < n; ++i) {
        const double s = state_ != kNone ? state[i] : 0.0;
        if (s == 0.0) {
          keep.push_back(i);
        } else if (s == 1.0) {
          ++direction_only_;
        } else {
          ++no_point_;
        }
      }
      out.xyz.resize(3, static_cast<Eigen::Index>(keep.size()));
      for (std::size_t j = 0; j < keep.size(); ++j) {
        const std::size_t i = keep[j];
        out.xyz.col(static_cast<Eigen::Index>(j)) = rot_ * Eigen::Vector3d(a[i], b[i], c[i]) + pose_.t;
      }
    }
    const std::size_t m = static_cast<std::size_t>(out.xyz.cols());
    std::vector<double> v(n);
    if (intensity_ != kNone) {
      cursor_->decode(intensity_, n, v.data(), 1);
      out.intensity.resize(m);
      for (std::size_t j = 0; j < m; ++j) out.intensity[j] = static_cast<float>(std::clamp((v[keep[j]] - i_lo_) * i_inv_, 0.0, 1.0));
    }
    if (rgb_) {
      out.rgb.resize(3 * m);
      const char* keys[3] = {"colorRed", "colorGreen", "colorBlue"};
      for (int ch = 0; ch < 3; ++ch) {
        cursor_->decode(at_[keys[ch]], n, v.data(), 1);
        for (std::size_t j = 0; j < m; ++j)
          out.rgb[3 * j + static_cast<std::size_t>(ch)] =
              static_cast<std::uint8_t>(std::lround(std::clamp((v[keep[j]] - c_lo_[ch]) * c_k_[ch], 0.0, 255.0)));
      }
    }
    if (row_col_ && grid_index_) {
      std::vector<double> col(n);
      cursor_->decode(at_["rowIndex"], n, v.data(), 1);
      cursor_->decode(at_["columnIndex"], n, col.data(), 1);
      out.row.resize(m);
      out.col.resize(m);
      for (std::size_t j = 0; j < m; ++j) {
        out.row[j] = static_cast<std::int32_t>(v[keep[j]]);
        out.col[j] = static_cast<std::int32_t>(col[keep[j]]);
      }
    }
    done_ += n;
  }

  /// After the last record (left() == 0): reads the scan's packets left and checks its
  /// bytestreams (BytestreamCursor::finish), and returns its notes, those of read_e57.
  std::vector<std::string> finish() {
    if (left() != 0) throw std::logic_error("ScanReader::finish: " + std::to_string(left()) + " records not read");
    cursor_->finish();
    std::vector<std::string> notes;
    std::string kept_attrs;
    if (intensity_ != kNone) {
      char buf[160];
      std::snprintf(buf, sizeof buf, "intensity normalised from [%g, %g] (%s)", i_lo_, i_hi_, i_source_.c_str());
      kept_attrs += buf;
    }
    if (rgb_) {
      kept_attrs += std::string(kept_attrs.empty() ? "" : "; ") + "colour scaled to 8 bit" +
                    (colour_limits_ ? " with colorLimits" : " with the prototype's bounds");
    } else if (has("colorRed") || has("colorGreen") || has("colorBlue")) {
      notes.push_back(label_ + ": colour dropped: the prototype lacks one of colorRed/Green/Blue");
    }
    if (row_col_) {
      kept_attrs += std::string(kept_attrs.empty() ? "" : "; ") + "rowIndex/columnIndex kept";
    } else if (has("rowIndex") || has("columnIndex")) {
      notes.push_back(label_ + ": grid index dropped: the prototype has only one of rowIndex/columnIndex");
    }
    std::string proto_list, skipped;
    for (const auto& f : fields_) {
      proto_list += (proto_list.empty() ? "" : ", ") + f.describe();
      if (std::find_if(std::begin(kKnownFields), std::end(kKnownFields), [&](const char* k) { return f.name == k; }) ==
          std::end(kKnownFields))
        skipped += (skipped.empty() ? "" : ", ") + f.name;
      else if (cart_ && f.name.rfind("spherical", 0) == 0)
        skipped += (skipped.empty() ? "" : ", ") + f.name + " (cartesian used)";
    }
    std::string pose_text = "no pose (identity)";
    if (pose_.has_rotation || pose_.has_translation) {
      char buf[200];
      std::snprintf(buf, sizeof buf, "pose q(w x y z) = (%.9g %.9g %.9g %.9g)%s, t = (%.9g %.9g %.9g) m%s", pose_.q.w(),
                    pose_.q.x(), pose_.q.y(), pose_.q.z(), pose_.has_rotation ? "" : " [no rotation: identity]", pose_.t.x(),
                    pose_.t.y(), pose_.t.z(), pose_.has_translation ? "" : " [no translation]");
      pose_text = buf;
    }
    notes.push_back(label_ + ": " + std::to_string(count_) + " records, " + (cart_ ? "cartesian" : "spherical") +
                    " coordinates, prototype {" + proto_list + "}, " + pose_text);
    if (!kept_attrs.empty()) notes.push_back(label_ + ": " + kept_attrs);
    if (!skipped.empty()) notes.push_back(label_ + ": fields skipped: " + skipped);
    if (direction_only_ > 0) {
      notes.push_back(label_ + ": " + std::to_string(direction_only_) + " records with invalid state 1 (direction only, no range) skipped");
    }
    if (no_point_ > 0) {
      notes.push_back(label_ + ": " + std::to_string(no_point_) + " records with invalid state 2 (no point) skipped");
    }
    return notes;
  }

 private:
  static constexpr std::size_t kNone = std::numeric_limits<std::size_t>::max();
  bool has(const char* key) const { return at_.count(key) > 0; }
  std::size_t field_of(const char* key) const {
    const auto it = at_.find(key);
    return it == at_.end() ? kNone : it->second;
  }

  const std::string& name_;
  bool grid_index_;
  std::string label_;
  std::uint64_t count_ = 0, done_ = 0;
  std::vector<Field> fields_;
  std::map<std::string, std::size_t> at_;
  bool cart_ = false, direct_ = false, identity_ = true, float32_ = false, rgb_ = false, row_col_ = false;
  bool colour_limits_ = false;
  std::size_t state_ = kNone, intensity_ = kNone;
  Pose pose_;
  Eigen::Matrix3d rot_ = Eigen::Matrix3d::Identity();
  double i_lo_ = 0.0, i_hi_ = 1.0, i_inv_ = 0.0;
  std::string i_source_;
  double c_lo_[3] = {0.0, 0.0, 0.0}, c_k_[3] = {1.0, 1.0, 1.0};
  std::size_t direction_only_ = 0, no_point_ = 0;
  std::optional<BytestreamCursor> cursor_;
};

/// One data3D scan read whole (read_e57): every record decoded at once.
ScanOut read_scan(PagedFile& file, const Xml& xml, const pugi::xml_node& scan, std::size_t index, const std::string& name) {
  ScanReader reader(file, xml, scan, index, name, true);
  ScanOut out;
  reader.next(static_cast<std::size_t>(reader.left()), out.cloud);
  out.notes = reader.finish();
  return out;
}

/// The E57 file header (E2807 § 7.2) of the first 48 bytes `u` of a file of `file_size` bytes,
/// checked: signature, version 1, page size, file length (within the file, a multiple of the
/// page size). Throws hc::InputError naming the file and the field.
struct E57Header {
  std::uint32_t major = 0, minor = 0;
  std::uint64_t phys_len = 0, xml_off = 0, xml_len = 0, page = 0;
};

E57Header parse_e57_header(const unsigned char* u, std::uint64_t file_size, const std::string& name) {
  if (file_size < 48) {
    throw InputError("load_cloud: " + name + " is " + std::to_string(file_size) +
                     " bytes long, shorter than the 48-byte E57 file header");
  }
  if (std::memcmp(u, "ASTM-E57", 8) != 0) {
    throw InputError("load_cloud: " + name + " does not start with the E57 signature 'ASTM-E57'");
  }
  E57Header h;
  h.major = load_le<std::uint32_t>(u + 8);
  h.minor = load_le<std::uint32_t>(u + 12);
  h.phys_len = load_le<std::uint64_t>(u + 16);
  h.xml_off = load_le<std::uint64_t>(u + 24);
  h.xml_len = load_le<std::uint64_t>(u + 32);
  h.page = load_le<std::uint64_t>(u + 40);
  if (h.major != 1) {
    throw InputError("load_cloud: " + name + " is E57 version " + std::to_string(h.major) + "." +
                     std::to_string(h.minor) + ", expected major version 1");
  }
  if (h.page < 64 || h.page > (1U << 20) || h.page % 4 != 0) {
    throw InputError("load_cloud: " + name + ": the E57 header gives page size " + std::to_string(h.page) +
                     ", expected 1024");
  }
  if (file_size < h.phys_len) {
    throw InputError("load_cloud: " + name + " is " + std::to_string(file_size) +
                     " bytes long but its E57 header says " + std::to_string(h.phys_len) +
                     " bytes: the file is truncated");
  }
  if (h.phys_len % h.page != 0 || h.phys_len == 0) {
    throw InputError("load_cloud: " + name + ": the E57 header gives file length " + std::to_string(h.phys_len) +
                     ", expected a positive multiple of the page size " + std::to_string(h.page));
  }
  return h;
}

/// The XML tree of an E57 file and its data3D scans, with the notes of the whole read up to the
/// first scan's. Not movable (the scans point into the document).
struct E57Document {
  pugi::xml_document doc;
  pugi::xml_node root;
  std::vector<pugi::xml_node> scans;
  std::vector<std::string> notes;
  std::string crs;  ///< e57Root/coordinateMetadata, trimmed; empty when absent
};

/// Reads and parses the XML section (E2807 § 8) through `file` and lists the data3D scans.
/// Throws hc::InputError as read_e57.
void load_e57_document(PagedFile& file, const E57Header& h, std::uint64_t file_size, const std::string& name,
                       E57Document& d) {
  (void)file.page_data(0);
  d.notes.push_back("E57 version " + std::to_string(h.major) + "." + std::to_string(h.minor) + ", " +
                    std::to_string(h.phys_len) + " bytes in pages of " + std::to_string(h.page) +
                    " (CRC-32C checked on every page read); coordinates in metres");
  if (file_size > h.phys_len) {
    d.notes.push_back(std::to_string(file_size - h.phys_len) + " bytes after the E57 file length ignored");
  }
  std::string text(static_cast<std::size_t>(std::min<std::uint64_t>(h.xml_len, file.logical_size())), '\0');
  if (h.xml_len > file.logical_size()) {
    throw InputError("load_cloud: " + name + ": the XML section (" + std::to_string(h.xml_len) +
                     " bytes) is longer than the file: the file is truncated or corrupt");
  }
  file.read(file.to_logical(h.xml_off), text.size(), reinterpret_cast<unsigned char*>(text.data()), "the XML section");
  const pugi::xml_parse_result parsed = d.doc.load_buffer(text.data(), text.size(), pugi::parse_default, pugi::encoding_utf8);
  if (!parsed) {
    throw InputError("load_cloud: " + name + ": the XML section does not parse: " + parsed.description() +
                     " at XML byte " + std::to_string(parsed.offset) + " (expected the E57 XML tree)");
  }
  d.root = d.doc.child("e57Root");
  if (!d.root) throw InputError("load_cloud: " + name + ": the XML section has no <e57Root> element");

  const pugi::xml_node data3d = d.root.child("data3D");
  if (data3d)
    for (const pugi::xml_node c : data3d.children("vectorChild")) d.scans.push_back(c);
  if (d.scans.empty()) {
    throw InputError("load_cloud: " + name + " holds no scans (data3D is " +
                     std::string(data3d ? "empty" : "absent") + "): expected at least one data3D scan");
  }
  if (d.scans.size() > std::numeric_limits<std::uint16_t>::max()) {
    throw InputError("load_cloud: " + name + " holds " + std::to_string(d.scans.size()) +
                     " scans, more than the 65535 scan ids a cloud carries");
  }
  if (const pugi::xml_node images = d.root.child("images2D")) {
    const auto n_images = static_cast<std::size_t>(std::distance(images.children("vectorChild").begin(),
                                                                 images.children("vectorChild").end()));
    if (n_images > 0) d.notes.push_back(std::to_string(n_images) + " images2D skipped (images are not read)");
  }
  d.notes.push_back(std::to_string(d.scans.size()) + " data3D scan" + (d.scans.size() == 1 ? "" : "s") +
                    (d.scans.size() > 1 ? ", each placed by its pose into the file frame and merged" : ""));
  // ASTM E2807 §8.4: e57Root/coordinateMetadata, a String describing the CRS (e.g. WKT).
  if (const pugi::xml_node cm = d.root.child("coordinateMetadata")) d.crs = std::string(trim(cm.child_value()));
}

std::string crs_note(const std::string& crs) {
  return "CRS (coordinateMetadata): " + crs + " [carried into the scene's provenance]";
}

/// Whether scan's records carry an attribute, from its prototype (as read_scan decodes them):
/// intensity; colour (all three channels); a grid index (both); and whether its coordinates
/// are stored single-precision in the file frame (ScanOut's float32_xyz).
struct ScanAttributes {
  bool intensity = false, rgb = false, row_col = false, float32 = false;
};

ScanAttributes scan_attributes(const Xml& xml, const pugi::xml_node& scan) {
  ScanAttributes a;
  const pugi::xml_node proto = scan.child("points").child("prototype");
  std::vector<Field> fields;
  if (proto) collect_fields(xml, proto, fields);
  std::map<std::string, const Field*> at;
  for (const Field& f : fields) at.emplace(f.name, &f);
  const auto has = [&](const char* k) { return at.count(k) > 0; };
  a.intensity = has("intensity");
  a.rgb = has("colorRed") && has("colorGreen") && has("colorBlue");
  a.row_col = has("rowIndex") && has("columnIndex");
  const bool cart = has("cartesianX") && has("cartesianY") && has("cartesianZ");
  const Pose pose = read_pose(xml, scan);
  a.float32 = cart && !pose.has_rotation && !pose.has_translation && at["cartesianX"]->single &&
              at["cartesianY"]->single && at["cartesianZ"]->single && at["cartesianX"]->kind == Field::Kind::Float;
  return a;
}

/// Whether read_scan keeps a record of `scan`: recordCount > 0 and, with an invalid-state field
/// (cartesianInvalidState, or sphericalInvalidState for spherical coordinates), a record of state
/// 0. Only that field's bytestream is read, and only up to its first 0 (the first packet of a
/// scanner's file, most often; the whole field for a scan of invalid records only, checked for
/// its length then). A scan read_scan will refuse counts as keeping one (the refusal comes when
/// it is read).
bool keeps_a_record(PagedFile& file, const Xml& xml, const pugi::xml_node& scan, const std::string& name) {
  const pugi::xml_node points = scan.child("points");
  const auto count = xml.attr<std::uint64_t>(points, "recordCount", 0);
  const pugi::xml_node proto = points.child("prototype");
  if (count == 0 || !proto || count > std::numeric_limits<std::uint32_t>::max()) return count > 0;
  std::vector<Field> fields;
  collect_fields(xml, proto, fields);
  std::map<std::string, std::size_t> at;
  for (std::size_t k = 0; k < fields.size(); ++k) at.emplace(fields[k].name, k);
  const bool cart = at.count("cartesianX") && at.count("cartesianY") && at.count("cartesianZ");
  const auto state = at.find(cart ? "cartesianInvalidState" : "sphericalInvalidState");
  if (state == at.end()) return true;
  std::vector<bool> only(fields.size(), false);
  only[state->second] = true;
  BytestreamCursor cursor(file, xml, points, fields, count, name, only, false);
  const bool none = cursor.each_block(state->second, count, 4096, [](const std::vector<double>& v) {
    return std::find(v.begin(), v.end(), 0.0) == v.end();  // go on while no record is valid
  });
  if (!none) return true;
  cursor.finish();
  return false;
}

/// A scan's recordCount as E57Stream::total_points counts it (at most 2^32 − 1: read_scan
/// refuses more).
std::uint64_t counted_records(std::uint64_t record_count) {
  return std::min<std::uint64_t>(record_count, std::numeric_limits<std::uint32_t>::max());
}

// An E57 file read scan by scan (point_stream.hpp): pages come from the file with pread (each
// checked), one data3D scan is decoded at a time and handed out in chunks; the attributes kept
// are those every scan's prototype carries, as the whole read's merge keeps them.
class E57Stream final : public PointStream {
 public:
  E57Stream(int fd, std::uint64_t file_size, const E57Header& h, std::string name)
      : fd_(fd), name_(std::move(name)), xml_(name_), file_(fd, h.phys_len, h.page, name_) {
    load_e57_document(file_, h, file_size, name_, doc_);
    notes_ = doc_.notes;
    // The merge of the whole read (read_e57 and Cloud::append), on the prototypes and, with
    // several scans, whether each keeps a record (a scan with none carries no attribute): an
    // attribute some scans lack is dropped, with a note at each scan where the two sides differ.
    const bool several = doc_.scans.size() > 1;
    bool intensity = false, rgb = false, row = false, col = false, scan_id = false, float32 = false;
    bool merged = false;  // a scan before keeps a record
    for (std::size_t s = 0; s < doc_.scans.size(); ++s) {
      const ScanAttributes a = scan_attributes(xml_, doc_.scans[s]);
      const std::uint64_t records = xml_.attr<std::uint64_t>(doc_.scans[s].child("points"), "recordCount", 0);
      total_ += counted_records(records);
      const bool some = several ? keeps_a_record(file_, xml_, doc_.scans[s], name_) : records > 0;
      std::vector<std::string> dropped;
      drop_notes_.push_back({});
      if (!merged) {  // the first scan, or everything before it was empty: taken whole
        intensity = a.intensity && some;
        rgb = a.rgb && some;
        row = col = a.row_col && some;
        scan_id = several && some;
        float32 = a.float32;
      } else {
        const auto join = [&](bool& mine, bool theirs, const char* attr) {
          if (mine != theirs) {
            dropped.push_back(attr);
            mine = false;
          }
        };
        join(scan_id, several && some, "scan_id");
        join(intensity, a.intensity && some, "intensity");
        join(rgb, a.rgb && some, "rgb");
        join(row, a.row_col && some, "row");
        join(col, a.row_col && some, "col");
        float32 = float32 || a.float32;
        for (const std::string& d : dropped) {
          drop_notes_.back().push_back("attribute '" + d + "' dropped: not every scan carries it (at scan " +
                                       std::to_string(s) + ")");
        }
      }
      merged = merged || some;
    }
    (void)row;
    (void)col;
    (void)scan_id;
    keep_intensity_ = intensity;
    keep_rgb_ = rgb;
    float32_ = float32;
    notes_.push_back("data3D scans read one at a time");
  }
  ~E57Stream() override { ::close(fd_); }
  E57Stream(const E57Stream&) = delete;
  E57Stream& operator=(const E57Stream&) = delete;

  std::uint64_t total_points() const override { return total_; }
  const std::vector<std::string>& notes() const override { return notes_; }
  bool streamed() const override { return true; }
  std::string crs() const override { return doc_.crs; }

  // A chunk holds at most max_points records of one scan, and fewer points where records are
  // invalid (a chunk of none is not handed out: the next records are read).
  bool next(Cloud& chunk, std::size_t max_points) override {
    return sticky_.run(name_, chunk, [&] {
      for (;;) {
        if (!reader_) {
          if (next_scan_ == doc_.scans.size()) {
            if (given_ == 0) throw InputError("load_cloud: " + name_ + " holds no valid point in any data3D scan");
            return false;
          }
          reader_ = std::make_unique<ScanReader>(file_, xml_, doc_.scans[next_scan_], next_scan_, name_, false);
          ++next_scan_;
        }
        if (reader_->left() > 0) {
          reader_->next(std::max<std::size_t>(max_points, 1), chunk);
        } else {
          chunk = Cloud();
        }
        if (reader_->left() == 0) {  // the scan's last records: its packets left checked, its notes
          const std::size_t s = next_scan_ - 1;
          const std::vector<std::string> scan_notes = reader_->finish();
          reader_.reset();
          notes_.pop_back();
          notes_.insert(notes_.end(), scan_notes.begin(), scan_notes.end());
          notes_.insert(notes_.end(), drop_notes_[s].begin(), drop_notes_[s].end());
          if (next_scan_ == doc_.scans.size() && !doc_.crs.empty()) notes_.push_back(crs_note(doc_.crs));
          notes_.push_back("data3D scans read one at a time");
        }
        if (chunk.size() == 0) continue;
        if (!keep_intensity_) chunk.intensity.clear();
        if (!keep_rgb_) chunk.rgb.clear();
        chunk.float32_xyz = float32_;
        given_ += chunk.size();
        return true;
      }
    });
  }

 private:
  int fd_;
  std::string name_;
  Xml xml_;
  PagedFile file_;
  E57Document doc_;
  std::vector<std::vector<std::string>> drop_notes_;  // per scan
  std::uint64_t total_ = 0, given_ = 0;
  std::size_t next_scan_ = 0;
  std::unique_ptr<ScanReader> reader_;  // the scan being read
  bool keep_intensity_ = false, keep_rgb_ = false, float32_ = false;
  StickyFailure sticky_;
  std::vector<std::string> notes_;
};

}  // namespace

/// Reads an E57 file (E2807 §§ 7–9) whole from memory. Output: every valid record of every
/// data3D scan (invalid state 1 or 2 skipped with a note), 3 × N in metres, each scan's pose
/// (rotation quaternion w x y z, translation; missing parts identity) applied so all scans share
/// the file frame; scan_id per point when there are several scans; intensity normalised to
/// [0, 1] (intensityLimits, else the prototype's bounds), rgb 8 bit (colorLimits, else the
/// prototype's bounds), row/col from rowIndex/columnIndex. Errors (hc::InputError naming the
/// file): short or foreign header, truncated file, a page whose CRC-32C does not match (its
/// physical offset), XML that does not parse, zero scans, a packet or bytestream that is short.
ReadResult read_e57(const ScanSource& source) {
  const std::string& name = source.display_name;
  const std::string& bytes = source.bytes;
  const auto* u = reinterpret_cast<const unsigned char*>(bytes.data());
  const E57Header h = parse_e57_header(u, bytes.size(), name);
  const std::string view = bytes.size() == h.phys_len ? std::string() : bytes.substr(0, h.phys_len);
  PagedFile file(view.empty() ? bytes : view, h.page, name);
  E57Document d;
  load_e57_document(file, h, bytes.size(), name, d);
  std::vector<std::string> notes = std::move(d.notes);
  const Xml xml(name);

  ReadResult result;
  for (std::size_t s = 0; s < d.scans.size(); ++s) {
    ScanOut one = read_scan(file, xml, d.scans[s], s, name);
    if (d.scans.size() > 1) one.cloud.scan_id.assign(one.cloud.size(), static_cast<std::uint16_t>(s));
    notes.insert(notes.end(), one.notes.begin(), one.notes.end());
    if (result.cloud.size() == 0 && s == 0) {
      result.cloud = std::move(one.cloud);
      continue;
    }
    const std::vector<std::string> dropped = result.cloud.append(one.cloud);
    for (const auto& dd : dropped)
      notes.push_back("attribute '" + dd + "' dropped: not every scan carries it (at scan " + std::to_string(s) + ")");
  }
  if (!d.crs.empty()) {
    result.cloud.crs = d.crs;
    notes.push_back(crs_note(d.crs));
  }
  result.notes = std::move(notes);
  return result;
}

std::uint64_t e57_record_count(ByteSource& src, const std::string& name) {
  unsigned char u[48] = {};
  const std::size_t got = src.read(reinterpret_cast<char*>(u), sizeof u);
  // The header's own file length stands for the file's size, which a gzip stream does not
  // give before its end: a stream that ends early fails below, where its pages are missing.
  const E57Header h = parse_e57_header(u, got < 48 ? got : load_le<std::uint64_t>(u + 16), name);
  // The pages that hold the XML section (E2807 § 7.3: xml_len logical bytes from the physical
  // offset xml_off), kept; the pages before them read and dropped.
  const std::uint64_t first_page = h.xml_off / h.page;
  const std::uint64_t payload = h.page - 4;
  const std::uint64_t in_first = h.xml_off % h.page;
  if (in_first >= payload) {
    throw InputError("load_cloud: " + name + ": the E57 header puts the XML section at physical offset " +
                     std::to_string(h.xml_off) + ", inside a page's checksum: the file is corrupt");
  }
  const bool fits = h.phys_len <= (std::uint64_t{1} << 62) && h.xml_off < h.phys_len && h.xml_len <= h.phys_len;
  const std::uint64_t pages = fits ? (in_first + h.xml_len + payload - 1) / payload : 0;
  if (!fits || pages > h.phys_len / h.page - first_page) {
    throw InputError("load_cloud: " + name + ": the XML section (" + std::to_string(h.xml_len) + " bytes at physical offset " +
                     std::to_string(h.xml_off) + ") runs past the file length " + std::to_string(h.phys_len) +
                     " in the E57 header: the file is truncated or corrupt");
  }
  std::vector<char> skip(std::size_t{1} << 20);
  std::uint64_t at = sizeof u;
  const std::uint64_t start = first_page * h.page;
  while (at < start) {
    const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(skip.size(), start - at));
    const std::size_t r = src.read(skip.data(), n);
    if (r == 0) break;
    at += r;
  }
  // Grown as the bytes come (a header's lengths are not trusted with an allocation: a stream
  // that ends early fails having held only what it gave).
  const std::uint64_t want = pages * h.page;
  std::string bytes;
  if (start == 0) bytes.assign(reinterpret_cast<const char*>(u), sizeof u);  // the header's page: read already
  while (at >= start && bytes.size() < want) {
    const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(skip.size(), want - bytes.size()));
    const std::size_t r = src.read(skip.data(), n);
    if (r == 0) break;
    bytes.append(skip.data(), r);
  }
  if (at < start || bytes.size() < want) {
    throw InputError("load_cloud: " + name + " ends at byte " + std::to_string(at < start ? at : start + bytes.size()) +
                     ", before the end of its XML section's pages at byte " + std::to_string(start + want) +
                     ": the file is truncated");
  }
  // The kept pages as a paged file of their own: the XML section at the same offset within
  // its first page.
  PagedFile file(bytes, h.page, name);
  E57Header local = h;
  local.xml_off = in_first;
  local.phys_len = bytes.size();
  E57Document d;
  load_e57_document(file, local, bytes.size(), name, d);
  const Xml xml(name);
  std::uint64_t total = 0;
  for (const pugi::xml_node& scan : d.scans) total += counted_records(xml.attr<std::uint64_t>(scan.child("points"), "recordCount", 0));
  return total;
}

std::unique_ptr<PointStream> open_e57_stream(const std::filesystem::path& path, const std::string& name) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return nullptr;
  struct stat st {};
  unsigned char u[48] = {};
  if (::fstat(fd, &st) != 0 || st.st_size < 48 || ::pread(fd, u, 48, 0) != 48) {
    ::close(fd);
    return nullptr;  // load_cloud's whole read says why
  }
  try {
    const E57Header h = parse_e57_header(u, static_cast<std::uint64_t>(st.st_size), name);
    return std::make_unique<E57Stream>(fd, static_cast<std::uint64_t>(st.st_size), h, name);
  } catch (...) {
    ::close(fd);
    throw;
  }
}

}  // namespace hc::pipeline::detail
