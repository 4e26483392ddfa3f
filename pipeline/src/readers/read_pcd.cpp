// PCD reader (PCD v0.5/v0.7, as PCL's pcd_io.cpp writes and reads it). The header and the
// amount of data are checked here first (PCL's PCDReader crashed on some malformed files, a
// garbage file without FIELDS for example, and accepts a non-numeric ASCII token silently); the
// body is then read here too, whole (read_pcd) or in chunks (open_pcd_stream) by the same
// decoders: a DATA binary body's records (PCL crashed on a fuzzed binary file with a sound
// header), a binary_compressed one's LZF block (lzf_reader.hpp, which the streamed read needs
// anyway) and an ascii body's lines (since 2026-11-27, forty-second session: before, PCL parsed the whole read's and
// an integer axis kept the file from streaming), each with its packed rgb/rgba colour and its
// intensity field. PCL's own reader is the tests' oracle (tests/support/pcl_pcd_writer.hpp).

#include "byte_source.hpp"
#include "line_stream.hpp"
#include "lzf_reader.hpp"
#include "readers.hpp"
#include "text_parse.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/cloud.hpp"

#include <locale.h>

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

namespace hc::pipeline::detail {


namespace {

template <class T>
double read_as_double(const std::uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return static_cast<double>(v);
}

// PCD header check. PCL's PCDReader crashes on some malformed files (a garbage file without
// FIELDS, for example), so the header and the amount of data are checked here first.

/// Where x, y, z sit in a point record, and what the header declared.
struct PcdLayout {
  std::string data;             ///< ascii | binary | binary_compressed
  std::size_t pos = 0;          ///< first byte after the header
  std::size_t n = 0;            ///< points
  std::size_t point_bytes = 0;  ///< record size of a binary point
  std::size_t values = 0;       ///< numbers on an ascii data line (the fields' counts summed)
  std::size_t header_lines = 0; ///< lines up to and with the DATA line (an ascii body's first line is the next)
  struct Axis {
    std::size_t offset = 0;     ///< byte offset in the record
    std::size_t value = 0;      ///< place among an ascii line's numbers (from 0)
    char type = 'F';            ///< F, I or U
    int size = 4;               ///< bytes
    std::size_t field_bytes = 4;  ///< the field's bytes in a record: SIZE × COUNT (the first value is the axis)
  } axis[3];
  /// The colour: the first field named rgb or rgba of SIZE 4 (any TYPE: PCL packs 0x00RRGGBB or
  /// 0xAARRGGBB into its four bytes, little-endian, a float's or an integer's alike).
  bool has_rgb = false;
  Axis rgb;
  std::string rgb_name;         ///< rgb or rgba, for messages
  /// When the first field named rgb or rgba has a SIZE other than 4 (no packed colour): a note
  /// that says it is not read; else empty.
  std::string colour_note;
  /// The intensity: the first field named intensity (its first value, as the scanner stored it).
  bool has_intensity = false;
  Axis intensity;
};

/// One value of a binary record: type F/I/U and size in bytes (as the header declared).
double binary_value(const std::uint8_t* p, char type, int size) {
  if (type == 'F') return size == 8 ? read_as_double<double>(p) : read_as_double<float>(p);
  if (type == 'I') {
    switch (size) {
      case 1: return read_as_double<std::int8_t>(p);
      case 2: return read_as_double<std::int16_t>(p);
      case 4: return read_as_double<std::int32_t>(p);
      default: return read_as_double<std::int64_t>(p);
    }
  }
  switch (size) {
    case 1: return read_as_double<std::uint8_t>(p);
    case 2: return read_as_double<std::uint16_t>(p);
    case 4: return read_as_double<std::uint32_t>(p);
    default: return read_as_double<std::uint64_t>(p);
  }
}

/// An intensity field's value as Cloud::intensity holds it (a float; the scanner's scale).
inline float intensity_value(const std::uint8_t* p, const PcdLayout::Axis& f) { return static_cast<float>(binary_value(p, f.type, f.size)); }

/// A packed PCL colour's R G B (its four bytes at p, little-endian 0x??RRGGBB: B first) into out.
inline void packed_rgb(const std::uint8_t* p, std::uint8_t* out) {
  out[0] = p[2];
  out[1] = p[1];
  out[2] = p[0];
}

/// Points 0 .. n − 1 of `out` (xyz, and rgb and intensity when the layout has them, sized to
/// n) from n records of l.point_bytes bytes at base, laid out as the
/// header declares (DATA binary): x y z by binary_value, the colour by packed_rgb, the
/// intensity by intensity_value.
void decode_records(const std::uint8_t* base, std::size_t n, const PcdLayout& l, Cloud& out) {
  out.xyz.resize(3, static_cast<Eigen::Index>(n));
  if (l.has_rgb) out.rgb.resize(3 * n);
  if (l.has_intensity) out.intensity.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint8_t* rec = base + i * l.point_bytes;
    for (int a = 0; a < 3; ++a) {
      out.xyz(a, static_cast<Eigen::Index>(i)) = binary_value(rec + l.axis[a].offset, l.axis[a].type, l.axis[a].size);
    }
    if (l.has_rgb) packed_rgb(rec + l.rgb.offset, out.rgb.data() + 3 * i);
    if (l.has_intensity) out.intensity[i] = intensity_value(rec + l.intensity.offset, l.intensity);
  }
}

/// The fields a body is read by: x, y, z, then the colour and the intensity when the layout has
/// them (a binary_compressed body's columns, an ascii line's values). A fixed list: an ascii
/// body takes it once a line.
enum class Column { kX, kY, kZ, kColour, kIntensity };
struct Columns {
  std::array<Column, 5> at{};
  std::size_t n = 0;
  std::size_t size() const { return n; }
  Column operator[](std::size_t i) const { return at[i]; }
  const Column* begin() const { return at.data(); }
  const Column* end() const { return at.data() + n; }
};
Columns columns_of(const PcdLayout& l) {
  Columns c;
  for (const Column k : {Column::kX, Column::kY, Column::kZ}) c.at[c.n++] = k;
  if (l.has_rgb) c.at[c.n++] = Column::kColour;
  if (l.has_intensity) c.at[c.n++] = Column::kIntensity;
  return c;
}
/// The field a column reads.
const PcdLayout::Axis& field_of(const PcdLayout& l, Column c) {
  return c == Column::kColour ? l.rgb : c == Column::kIntensity ? l.intensity : l.axis[static_cast<int>(c)];
}

/// n values of column c from base (one every field_bytes, as a binary_compressed body's columns
/// hold them) into points 0 .. n − 1 of `out`, whose xyz, rgb or intensity the caller sized.
void decode_column(Column c, const PcdLayout& l, const std::uint8_t* base, std::size_t n, Cloud& out) {
  const PcdLayout::Axis& f = field_of(l, c);
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint8_t* v = base + i * f.field_bytes;
    switch (c) {
      case Column::kColour: packed_rgb(v, out.rgb.data() + 3 * i); break;
      case Column::kIntensity: out.intensity[i] = intensity_value(v, f); break;
      default: out.xyz(static_cast<Eigen::Index>(c), static_cast<Eigen::Index>(i)) = binary_value(v, f.type, f.size);
    }
  }
}

/// DATA binary, read here (PCL's reader crashed on a fuzzed binary file whose header was sound):
/// n records of point_bytes bytes, little-endian as PCL writes them (decode_records).
Cloud read_binary_body(const std::string& raw, const PcdLayout& l) {
  Cloud cloud;
  decode_records(reinterpret_cast<const std::uint8_t*>(raw.data()) + l.pos, l.n, l, cloud);
  return cloud;
}

std::string compressed_what(const std::string& name);

/// DATA binary_compressed, read here: the LZF block (validate_pcd checked its sizes) decoded
/// once (LzfReader, which checks it as liblzf and PCL do) into the fields' columns (PCL's
/// "xxyyzz": field f's n values from n × its record offset), each read by decode_column. The
/// whole body is held (n × point_bytes bytes), as PCL held it.
Cloud read_compressed_body(const std::string& raw, const PcdLayout& l, const std::string& name) {
  std::uint32_t sizes[2] = {0, 0};
  std::memcpy(sizes, raw.data() + l.pos, 8);
  std::size_t at = l.pos + 8;
  LzfReader lzf(sizes[0], sizes[1], [&](char* out, std::size_t k) {
    std::memcpy(out, raw.data() + at, k);  // k ≤ the bytes left of the block (LzfReader), within raw (validate_pcd)
    at += k;
    return k;
  }, compressed_what(name));
  std::string body(sizes[1], '\0');
  lzf.read(body.data(), body.size());
  lzf.finish();
  Cloud cloud;
  cloud.xyz.resize(3, static_cast<Eigen::Index>(l.n));
  if (l.has_rgb) cloud.rgb.resize(3 * l.n);
  if (l.has_intensity) cloud.intensity.resize(l.n);
  const auto* base = reinterpret_cast<const std::uint8_t*>(body.data());
  for (const Column c : columns_of(l)) decode_column(c, l, base + l.n * field_of(l, c).offset, l.n, cloud);
  return cloud;
}

// An ascii data line's problem, or an empty string: exactly `values` numbers
// (check_numeric_line), separated by blanks and tabs only, as PCL splits the line (a comma,
// vertical tab or form feed would be part of a number there: PCL would read "1 2 ,3" as 1 2 0).
std::string check_ascii_line(const char* b, const char* e, std::size_t values) {
  for (const char* p = b; p < e; ++p) {
    if (*p == ',' || *p == '\v' || *p == '\f') {
      return std::string("'") + (*p == ',' ? "," : *p == '\v' ? "\\v" : "\\f") +
             "' between values (PCD separates them by blanks or tabs)";
    }
  }
  return check_numeric_line(b, e, values);
}

// The start of a binary_compressed body's errors (LzfReader's `what`).
std::string compressed_what(const std::string& name) { return "load_cloud: " + name + ": the binary_compressed body (LZF)"; }

// The largest point record PCL takes (its point_step is 32-bit) [bytes].
constexpr std::size_t kMaxRecordBytes = 0xFFFFFFFFu;

// A binary_compressed body's two sizes (compressed, then unpacked: sizes, or nullptr when
// fewer than 8 bytes follow the header) against the layout and the `have` bytes after the header.
void check_compressed_sizes(const std::string& name, const PcdLayout& l, std::size_t have, const std::uint32_t* sizes) {
  auto fail = [&](const std::string& what) { return InputError("load_cloud: " + name + ": " + what); };
  if (sizes == nullptr) throw fail("truncated: no compressed block after the header");
  std::size_t body = 0;
  if (__builtin_mul_overflow(l.n, l.point_bytes, &body) || sizes[1] != body) {
    throw fail("the compressed block unpacks to " + std::to_string(sizes[1]) + " bytes, expected " + std::to_string(l.n) + " x " +
               std::to_string(l.point_bytes));
  }
  // LZF gives at most 88 bytes a compressed byte (a back reference of 264 bytes in 3): a
  // larger size is refused before anything is allocated for it.
  if (sizes[1] > 88ULL * sizes[0]) {
    throw fail("the compressed block of " + std::to_string(sizes[0]) + " bytes cannot unpack to " + std::to_string(sizes[1]) +
               " (LZF gives at most 88 bytes a compressed byte)");
  }
  if (have - 8 < sizes[0]) {
    throw fail("truncated: the compressed block needs " + std::to_string(sizes[0]) + " bytes, " + std::to_string(have - 8) + " follow");
  }
}

// The header (and for ascii and binary_compressed bodies, the data) of a PCD file checked.
// `raw` holds the file from its start: the whole file, or, with header_only, at least its lines
// up to the DATA line; file_bytes is the whole file's size (raw.size() for a whole file).
// header_only: an ascii or binary_compressed body is not checked (the layout says which it is);
// a binary body's size is checked against file_bytes as for a whole file.
PcdLayout validate_pcd(const std::string& raw, const std::string& name, std::size_t file_bytes, bool header_only) {
  PcdLayout layout;
  auto fail = [&](const std::string& what) -> InputError {
    return InputError("load_cloud: " + name + ": " + what);
  };
  std::vector<std::string> fields, sizes, types, counts;
  long long width = -1, height = 1, points = -1;
  std::string data;
  std::size_t pos = 0;
  std::size_t line_no = 0;
  std::string line;
  while (data.empty() && next_line(raw, pos, line, /*accept_unterminated=*/true)) {
    ++line_no;
    // A PCD header is text: control bytes (a binary blob in a comment, a NUL) make PCL's own header
    // parser read counts out of garbage (a fuzzed file crashed it), so they are refused here.
    for (const char ch : line) {
      const auto c = static_cast<unsigned char>(ch);
      if ((c < 0x20 && c != '\t' && c != '\r') || c == 0x7f) {
        throw fail("header line " + std::to_string(line_no) + " holds a control byte (0x" +
                   std::string(1, "0123456789abcdef"[c >> 4]) + std::string(1, "0123456789abcdef"[c & 0xF]) +
                   "): expected a text header up to the DATA line");
      }
    }
    std::istringstream ls(line);
    std::string kw;
    if (!(ls >> kw) || kw[0] == '#') continue;
    std::vector<std::string> rest;
    for (std::string t; ls >> t;) rest.push_back(t);
    auto one_int = [&](long long& v) {
      if (rest.size() != 1) throw fail("header line " + std::to_string(line_no) + ": malformed '" + line + "'");
      const char* b = rest[0].data();
      const auto r = std::from_chars(b, b + rest[0].size(), v);
      if (r.ec != std::errc() || r.ptr != b + rest[0].size() || v < 0) {
        throw fail("header line " + std::to_string(line_no) + ": '" + rest[0] + "' is not a count");
      }
    };
    if (kw == "VERSION" || kw == "VIEWPOINT") continue;
    if (kw == "FIELDS" || kw == "COLUMNS") fields = rest;
    else if (kw == "SIZE") sizes = rest;
    else if (kw == "TYPE") types = rest;
    else if (kw == "COUNT") counts = rest;
    else if (kw == "WIDTH") one_int(width);
    else if (kw == "HEIGHT") one_int(height);
    else if (kw == "POINTS") one_int(points);
    else if (kw == "DATA") data = rest.empty() ? std::string("?") : rest[0];
    else throw fail("header line " + std::to_string(line_no) + ": unknown PCD keyword '" + kw.substr(0, 40) + "'");
  }
  if (data.empty()) throw fail("not a PCD file (no DATA line in the header)");
  if (fields.empty()) throw fail("the PCD header has no FIELDS line");
  if (counts.empty()) counts.assign(fields.size(), "1");
  if (sizes.size() != fields.size() || types.size() != fields.size() || counts.size() != fields.size()) {
    throw fail("the PCD header lists " + std::to_string(fields.size()) + " FIELDS but " + std::to_string(sizes.size()) +
               " SIZE, " + std::to_string(types.size()) + " TYPE and " + std::to_string(counts.size()) + " COUNT entries");
  }
  for (const char* axis : {"x", "y", "z"}) {
    if (std::find(fields.begin(), fields.end(), axis) == fields.end()) {
      throw fail(std::string("the PCD header has no '") + axis + "' field");
    }
  }
  std::size_t point_bytes = 0, values = 0;
  bool axis_seen[3] = {false, false, false};
  for (std::size_t i = 0; i < fields.size(); ++i) {
    const std::string& t = types[i];
    const std::string& z = sizes[i];
    const bool ok = (t == "F" && (z == "4" || z == "8")) ||
                    ((t == "I" || t == "U") && (z == "1" || z == "2" || z == "4" || z == "8"));
    long long c = 0;
    const auto r = std::from_chars(counts[i].data(), counts[i].data() + counts[i].size(), c);
    if (!ok || r.ec != std::errc() || c < 1) {
      throw fail("field '" + fields[i] + "' has TYPE " + t + ", SIZE " + z + ", COUNT " + counts[i] +
                 " (expected F 4|8 or I/U 1|2|4|8 and a count >= 1)");
    }
    // A record of at most 2^32 − 1 bytes (PCL's point_step is 32-bit): no product or sum of
    // sizes below can wrap.
    const auto field_size = static_cast<std::size_t>(std::stoi(z));
    if (static_cast<unsigned long long>(c) > kMaxRecordBytes / field_size || point_bytes + field_size * static_cast<std::size_t>(c) > kMaxRecordBytes) {
      throw fail("field '" + fields[i] + "' has SIZE " + z + " and COUNT " + counts[i] + ": a point record of more than " +
                 std::to_string(kMaxRecordBytes) + " bytes (PCL's limit)");
    }
    if (fields[i] == "intensity" && !layout.has_intensity) {
      layout.has_intensity = true;
      layout.intensity = {point_bytes, values, t[0], std::stoi(z), static_cast<std::size_t>(std::stoi(z)) * static_cast<std::size_t>(c)};
    }
    if ((fields[i] == "rgb" || fields[i] == "rgba") && z == "4" && !layout.has_rgb) {
      layout.has_rgb = true;
      layout.rgb = {point_bytes, values, t[0], 4, 4 * static_cast<std::size_t>(c)};
      layout.rgb_name = fields[i];
    }
    if ((fields[i] == "rgb" || fields[i] == "rgba") && z != "4" && !layout.has_rgb && layout.colour_note.empty()) {
      layout.colour_note = "PCD: field '" + fields[i] + "' has SIZE " + z + ", not a packed colour's 4 bytes: not read as colour";
    }
    for (int a = 0; a < 3; ++a) {
      if (fields[i] == std::string(1, static_cast<char>('x' + a)) && !axis_seen[a]) {
        axis_seen[a] = true;
        layout.axis[a] = {point_bytes, values, t[0], std::stoi(z), static_cast<std::size_t>(std::stoi(z)) * static_cast<std::size_t>(c)};
      }
    }
    point_bytes += static_cast<std::size_t>(std::stoi(z)) * static_cast<std::size_t>(c);
    values += static_cast<std::size_t>(c);
  }
  if (width < 0) throw fail("the PCD header has no WIDTH line");
  const auto bytes = static_cast<long long>(file_bytes);
  if (width > bytes || height > bytes || points > bytes) {  // every point takes at least one byte
    throw fail("truncated: the header declares WIDTH " + std::to_string(width) + ", HEIGHT " + std::to_string(height) +
               (points >= 0 ? ", POINTS " + std::to_string(points) : std::string()) + " in a file of " +
               std::to_string(file_bytes) + " bytes");
  }
  if (points < 0) points = width * height;
  if (points != width * height) {
    throw fail("the PCD header declares POINTS " + std::to_string(points) + " but WIDTH x HEIGHT = " +
               std::to_string(width * height));
  }
  if (points == 0) throw fail("the PCD header declares 0 points");
  const auto n = static_cast<std::size_t>(points);
  pos = std::min(pos, file_bytes);  // a DATA line the file ends in, unterminated: the body is empty
  const std::size_t have = file_bytes - pos;
  // An ascii data line takes at least 2 bytes a value (a digit and a blank or the line's end):
  // a header declaring more points than the body can hold is refused before anything is sized
  // for them.
  if (data == "ascii" && n > (have + 1) / (2 * values)) {
    throw fail("truncated: the header declares " + std::to_string(n) + " points of " + std::to_string(values) +
               " values, but the " + std::to_string(have) + " bytes after it hold at most " + std::to_string((have + 1) / (2 * values)) +
               " data lines");
  }
  layout.data = data;
  layout.pos = pos;
  layout.header_lines = line_no;
  layout.n = n;
  layout.point_bytes = point_bytes;
  layout.values = values;
  if (header_only && data != "binary") return layout;  // a binary_compressed body's sizes: PcdCompressedStream
  if (data == "ascii") {
    // its lines are checked as they are decoded (read_ascii_body, PcdAsciiStream)
  } else if (data == "binary") {
    std::size_t body = 0;
    if (__builtin_mul_overflow(n, point_bytes, &body) || have < body) {
      throw fail("truncated: the header declares " + std::to_string(n) + " points (" + std::to_string(n) + " x " + std::to_string(point_bytes) +
                 " bytes) but only " + std::to_string(have) + " bytes follow");
    }
  } else if (data == "binary_compressed") {
    std::uint32_t sizes_lz[2] = {0, 0};
    if (have >= 8) std::memcpy(sizes_lz, raw.data() + pos, 8);
    check_compressed_sizes(name, layout, have, have >= 8 ? sizes_lz : nullptr);
  } else {
    throw fail("unknown PCD DATA type '" + data + "' (expected ascii, binary or binary_compressed)");
  }
  return layout;
}

bool float32_axes(const PcdLayout& l) {
  bool float32 = true;
  for (const auto& a : l.axis) float32 = float32 && a.type == 'F' && a.size == 4;
  return float32;
}

constexpr const char* kBinaryNote = "PCD (binary, read directly)";
constexpr const char* kCompressedNote = "PCD (binary_compressed, read directly)";
constexpr const char* kAsciiNote = "PCD (ascii, read directly)";

// The chunking both binary streams share: n points handed out in chunks of up to max_points (at
// least 1), each filled by fill() once chunk.xyz has its columns; finished() after the last
// point; a failure sticks (StickyFailure).
class PcdChunks : public PointStream {
 public:
  std::uint64_t total_points() const override { return l_.n; }
  const std::vector<std::string>& notes() const override { return notes_; }
  bool streamed() const override { return true; }

  bool next(Cloud& chunk, std::size_t max_points) final {
    return sticky_.run(name_, chunk, [&] {
      const std::size_t n = std::min(std::max<std::size_t>(max_points, 1), l_.n - done_);
      if (n == 0) return false;
      chunk.xyz.resize(3, static_cast<Eigen::Index>(n));
      fill(chunk, n);
      chunk.float32_xyz = float32_axes(l_);
      done_ += n;
      if (done_ == l_.n) finished();
      return true;
    });
  }

 protected:
  PcdChunks(std::string name, const PcdLayout& l) : name_(std::move(name)), l_(l) {}
  // chunk.xyz's n columns: points done_ .. done_ + n − 1.
  virtual void fill(Cloud& chunk, std::size_t n) = 0;
  virtual void finished() = 0;

  std::string name_;
  PcdLayout l_;
  std::size_t done_ = 0;  // points handed out
  std::vector<std::string> notes_;

 private:
  StickyFailure sticky_;
};

// A DATA binary PCD read in chunks (point_stream.hpp): its fixed-size records after the header,
// each axis decoded by binary_value as read_binary_body decodes it.
class PcdStream final : public PcdChunks {
 public:
  PcdStream(std::unique_ptr<ByteSource> src, const PcdLayout& l) : PcdChunks(src->name(), l), src_(std::move(src)) {
    notes_.push_back(kBinaryNote);
    if (!l_.colour_note.empty()) notes_.push_back(l_.colour_note);
    notes_.push_back("PCD binary, " + std::to_string(l_.n) + " points (fixed-size records streamed in chunks)");
    src_->seek(l_.pos);
  }

 private:
  void fill(Cloud& chunk, std::size_t n) override {
    buffer_.resize(n * l_.point_bytes);
    const std::size_t got = src_->read(buffer_.data(), buffer_.size()) / l_.point_bytes;
    if (got != n) {  // checked against the size when opened: the file changed since
      throw InputError("load_cloud: " + name_ + ": truncated or unreadable after " + std::to_string(done_ + got) + " of " +
                       std::to_string(l_.n) + " points");
    }
    decode_records(reinterpret_cast<const std::uint8_t*>(buffer_.data()), n, l_, chunk);
  }
  void finished() override { src_->drain(); }

  std::unique_ptr<ByteSource> src_;
  std::vector<char> buffer_;
};

// A DATA binary_compressed PCD read in chunks (point_stream.hpp). The body is one LZF block
// (lzf_reader.hpp) that unpacks to the fields one after another, each as n values of the field's
// SIZE × COUNT bytes (PCL's pcd_io.cpp "xxyyzz": field f's column starts at n × its offset in
// a record). So each column read (columns_of) has a decoder of its own, over a source of its own, that decodes and
// drops the columns before its own and then hands out its column's values chunk by chunk:
// memory about 350 KiB a column, whatever the file's size, for decoding work of up to five
// times the block's with colour and intensity (the whole read decodes it once, into memory of
// the whole body). After the
// last point, the decoder of the farthest column decodes the rest and checks the block's sizes,
// as the whole read (read_compressed_body) does; the values are decode_column's, as the whole
// read's (PCL's reader is the tests' oracle, tests/pipeline/point_stream_test.cpp).
class PcdCompressedStream final : public PcdChunks {
 public:
  // file_bytes: the data's size (under gzip, inflated).
  PcdCompressedStream(const std::filesystem::path& path, bool gz, std::uint64_t file_bytes, std::unique_ptr<ByteSource> first,
                      const PcdLayout& l)
      : PcdChunks(first->name(), l) {
    notes_.push_back(kCompressedNote);
    if (!l_.colour_note.empty()) notes_.push_back(l_.colour_note);
    notes_.push_back("PCD binary_compressed, " + std::to_string(l_.n) + " points (one LZF block decoded as it is read, a decoder per column)");
    // The block's sizes (validate_pcd checked the header's: the file holds the block, which
    // unpacks to n records' bytes).
    first->seek(l_.pos);
    std::uint32_t sizes[2] = {0, 0};
    const bool whole = first->read(reinterpret_cast<char*>(sizes), sizeof sizes) == sizeof sizes;
    check_compressed_sizes(name_, l_, file_bytes > l_.pos ? static_cast<std::size_t>(file_bytes - l_.pos) : 0, whole ? sizes : nullptr);
    kinds_ = columns_of(l_);
    for (std::size_t a = 0; a < kinds_.size(); ++a) {
      Axis& ax = axes_[a];
      ax.src = a == 0 ? std::move(first) : ByteSource::open(path, name_, gz);
      ax.src->seek(l_.pos + 8);
      ByteSource* src = ax.src.get();
      ax.lzf = std::make_unique<LzfReader>(sizes[0], sizes[1], [src](char* out, std::size_t k) { return src->read(out, k); },
                                           compressed_what(name_));
    }
    for (std::size_t a = 1; a < kinds_.size(); ++a) {
      if (field_of(l_, kinds_[a]).offset > field_of(l_, kinds_[last_]).offset) last_ = a;
    }
  }

 private:
  void fill(Cloud& chunk, std::size_t n) override {
    if (l_.has_rgb) chunk.rgb.resize(3 * n);
    if (l_.has_intensity) chunk.intensity.resize(n);
    for (std::size_t a = 0; a < kinds_.size(); ++a) {
      const PcdLayout::Axis& f = field_of(l_, kinds_[a]);
      LzfReader& lzf = *axes_[a].lzf;
      if (done_ == 0) lzf.read(nullptr, l_.n * f.offset);  // the columns before this one
      buffer_.resize(n * f.field_bytes);
      lzf.read(buffer_.data(), buffer_.size());
      decode_column(kinds_[a], l_, reinterpret_cast<const std::uint8_t*>(buffer_.data()), n, chunk);
    }
  }
  void finished() override {
    axes_[last_].lzf->finish();
    axes_[last_].src->drain();
  }

  struct Axis {
    std::unique_ptr<ByteSource> src;
    std::unique_ptr<LzfReader> lzf;
  };
  std::array<Axis, 5> axes_;  // a decoder per column (kinds_)
  Columns kinds_;
  std::size_t last_ = 0;  // the column that comes last in the block: its decoder checks the block's end
  std::vector<char> buffer_;
};

/// One number of an ascii data line (a token check_numeric_line read, without PCL's
/// separators in it) as PCL's ASCII reader (pcl::PCDReader::readBodyASCII, copyStringValue in
/// pcl/io/file_io.h, PCL 1.13) stores it in an F field: "nan" in any case is the quiet NaN;
/// else the C locale's strtof (SIZE 4) or strtod (SIZE 8), which libstdc++'s istream >> float
/// calls, a value beyond float's range ±inf as PCL's atof fallback then gives.
double ascii_value(const char* b, const char* e, int size) {
  const std::size_t len = static_cast<std::size_t>(e - b);
  if (len == 3 && (b[0] | 0x20) == 'n' && (b[1] | 0x20) == 'a' && (b[2] | 0x20) == 'n') {
    return size == 4 ? static_cast<double>(std::numeric_limits<float>::quiet_NaN()) : std::numeric_limits<double>::quiet_NaN();
  }
  // std::from_chars rounds correctly, as strtof and strtod do: the same value wherever it
  // gives one (a leading '+' skipped, which strtof takes); strtof_l decides the rest (a value
  // beyond float's range or under its smallest subnormal).
  const char* f = *b == '+' ? b + 1 : b;
  if (size == 4) {
    float v = 0.0f;
    const auto r = std::from_chars(f, e, v);
    if (r.ec == std::errc() && r.ptr == e) return static_cast<double>(v);
  } else {
    double v = 0.0;
    const auto r = std::from_chars(f, e, v);
    if (r.ec == std::errc() && r.ptr == e) return v;
  }
  static const locale_t c_locale = ::newlocale(LC_ALL_MASK, "C", static_cast<locale_t>(nullptr));
  const std::string token(b, e);  // terminated for strtof_l (rare: out of range)
  return size == 4 ? static_cast<double>(::strtof_l(token.c_str(), nullptr, c_locale)) : ::strtod_l(token.c_str(), nullptr, c_locale);
}

/// One integer value of an ascii data line (a token check_numeric_line read) as an I or U field
/// of `size` bytes holds it: its little-endian bytes into out[0 .. size). Taken: an integer of
/// the field's range in decimal digits (a leading '+', and "-0" on U, as PCL's stream parse
/// takes them), or a decimal number whose value is such an integer and at most 2^53 in
/// magnitude, exactly a double ("255.000000", "1e3": a writer's %f or %g in every column). Returns
/// an empty string, or the problem: a fraction, "nan", or a value past the range (PCL's reader
/// would cut 1.5 to 1 and give a value out of range through a cast of atof's double, undefined
/// in C++; refused here instead, naming the value and the range).
std::string ascii_integer(const char* b, const char* e, const PcdLayout::Axis& f, const char* field, std::uint8_t* out) {
  const char* s = *b == '+' ? b + 1 : b;
  const int bits = 8 * f.size;
  const std::int64_t i_hi = bits == 64 ? std::numeric_limits<std::int64_t>::max() : (std::int64_t{1} << (bits - 1)) - 1;
  const std::uint64_t u_hi = bits == 64 ? std::numeric_limits<std::uint64_t>::max() : (std::uint64_t{1} << bits) - 1;
  bool ok = false;
  if (f.type == 'I') {
    std::int64_t v = 0;
    const auto r = std::from_chars(s, e, v);
    bool whole = r.ec == std::errc() && r.ptr == e;
    if (!whole && r.ptr != e) {  // not digits alone: a decimal whose value is an integer
      double d = 0.0;
      const auto rd = std::from_chars(s, e, d);
      whole = rd.ec == std::errc() && rd.ptr == e && std::abs(d) <= 0x1p53 && d == std::trunc(d);
      v = whole ? static_cast<std::int64_t>(d) : 0;
    }
    ok = whole && v <= i_hi && v >= -i_hi - 1;
    if (ok) std::memcpy(out, &v, static_cast<std::size_t>(f.size));  // the low bytes: two's complement, little-endian
  } else {
    std::uint64_t v = 0;
    const bool minus_zero = s < e && *s == '-';
    const auto r = std::from_chars(minus_zero ? s + 1 : s, e, v);
    bool whole = r.ec == std::errc() && r.ptr == e && (!minus_zero || v == 0);
    if (!whole && r.ptr != e) {
      double d = 0.0;
      const auto rd = std::from_chars(s, e, d);
      whole = rd.ec == std::errc() && rd.ptr == e && d >= 0.0 && d <= 0x1p53 && d == std::trunc(d);
      v = whole ? static_cast<std::uint64_t>(d) : 0;
    }
    ok = whole && v <= u_hi;
    if (ok) std::memcpy(out, &v, static_cast<std::size_t>(f.size));
  }
  if (ok) return {};
  const std::string lo = f.type == 'U' ? "0" : std::to_string(-i_hi - 1);
  const std::string hi = f.type == 'U' ? std::to_string(u_hi) : std::to_string(i_hi);
  std::string problem = std::string("field '") + field + "' (TYPE ";
  problem += f.type;
  problem += " SIZE " + std::to_string(f.size) + ") holds '" + std::string(b, static_cast<std::size_t>(std::min<std::ptrdiff_t>(e - b, 40))) +
             "': expected an integer from " + lo + " to " + hi;
  return problem;
}

/// One value of an ascii data line as field f holds it in a binary record: its f.size
/// little-endian bytes into out (F by ascii_value, I and U by ascii_integer), so that the
/// record decoders (binary_value, packed_rgb, intensity_value) read it as they read a binary
/// body's. A packed colour in an F field is the float's bits (PCL's reader parses the token as
/// a float; PCL 1.13's writer declares rgb U and writes the integer). Returns the problem, or "".
std::string ascii_field(const char* b, const char* e, const PcdLayout::Axis& f, const char* field, std::uint8_t* out) {
  if (f.type != 'F') return ascii_integer(b, e, f, field, out);
  if (f.size == 4) {
    const auto v = static_cast<float>(ascii_value(b, e, 4));
    std::memcpy(out, &v, 4);
  } else {
    const double v = ascii_value(b, e, 8);
    std::memcpy(out, &v, 8);
  }
  return {};
}

/// The values an ascii data line [b, e) holds for the fields read (x, y, z, and the colour and
/// the intensity when the layout has them): x y z into xyz, R G B into rgb, the intensity into
/// *intensity. The line was checked (check_ascii_line: `values` numbers). Returns the problem
/// (ascii_field's), or "".
std::string decode_ascii_line(const char* b, const char* e, const PcdLayout& l, double* xyz, std::uint8_t* rgb, float* intensity) {
  static const char* const kNames[5] = {"x", "y", "z", "", "intensity"};  // the colour's: l.rgb_name
  const Columns cols = columns_of(l);
  const std::size_t n_cols = cols.size();
  std::array<const char*, 5> tb{}, te{};
  std::size_t at = 0, found = 0;
  for (const char* p = b; found < n_cols; ++at) {
    while (p < e && is_space(*p)) ++p;
    if (p >= e) break;
    const char* q = p;
    while (q < e && !is_space(*q)) ++q;
    for (std::size_t c = 0; c < n_cols; ++c) {
      if (field_of(l, cols[c]).value == at) tb[c] = p, te[c] = q, ++found;
    }
    p = q;
  }
  std::uint8_t bytes[8];
  for (std::size_t c = 0; c < n_cols; ++c) {
    const PcdLayout::Axis& f = field_of(l, cols[c]);
    const std::string problem = ascii_field(tb[c], te[c], f, cols[c] == Column::kColour ? l.rgb_name.c_str() : kNames[static_cast<int>(cols[c])], bytes);
    if (!problem.empty()) return problem;
    switch (cols[c]) {
      case Column::kColour: packed_rgb(bytes, rgb); break;
      case Column::kIntensity: *intensity = intensity_value(bytes, f); break;
      default: xyz[static_cast<int>(cols[c])] = binary_value(bytes, f.type, f.size);
    }
  }
  return {};
}

/// DATA ascii, read here as the stream reads it: the first n data lines after the header
/// (lines with a token: validate_pcd's rule), each checked (check_ascii_line) and decoded
/// (decode_ascii_line). @throws hc::InputError naming the file and the data line, or the lines
/// missing, or a line longer than kMaxTextLineBytes (TextLines: the stream's words, the line's
/// number in the file).
Cloud read_ascii_body(const std::string& raw, const PcdLayout& l, const std::string& name) {
  Cloud cloud;
  cloud.xyz.resize(3, static_cast<Eigen::Index>(l.n));
  if (l.has_rgb) cloud.rgb.resize(3 * l.n);
  if (l.has_intensity) cloud.intensity.resize(l.n);
  std::size_t lines = 0;
  // Every line after the header, numbered as in the file (TextLines: the stream's line limit).
  TextLines text(raw, name, l.pos, /*skip_blank=*/false, l.header_lines);
  for (const char *b = nullptr, *e = nullptr; lines < l.n && text.next(b, e);) {
    if (first_token(b, e).empty()) continue;
    std::string problem = check_ascii_line(b, e, l.values);
    if (problem.empty()) {
      problem = decode_ascii_line(b, e, l, cloud.xyz.col(static_cast<Eigen::Index>(lines)).data(),
                                  l.has_rgb ? cloud.rgb.data() + 3 * lines : nullptr, l.has_intensity ? &cloud.intensity[lines] : nullptr);
    }
    ++lines;
    if (!problem.empty()) throw InputError("load_cloud: " + name + ": data line " + std::to_string(lines) + ": " + problem);
  }
  if (lines < l.n) {
    throw InputError("load_cloud: " + name + ": truncated: the header declares " + std::to_string(l.n) + " points but only " +
                     std::to_string(lines) + " data lines follow");
  }
  return cloud;
}

// A DATA ascii PCD read in blocks of lines (point_stream.hpp): the first `n` data lines (lines
// with a token; validate_pcd's rule), each checked and decoded as the whole read
// (read_ascii_body) does it (check_ascii_line, decode_ascii_line; the same words, "data line
// K"): x y z, and the colour and the intensity when the header has them. PCL's reader is the
// tests' oracle (tests/pipeline/point_stream_test.cpp).
class PcdAsciiStream final : public LineStream {
 public:
  PcdAsciiStream(std::unique_ptr<ByteSource> src, const PcdLayout& l) : LineStream(std::move(src)), l_(l) {
    total_ = l_.n;
    src_->seek(l_.pos);
    start_lines(true, l_.header_lines);  // a line over 64 MiB named by its line in the file, as read_ascii_body does
    notes_ = {kAsciiNote};
    if (!l_.colour_note.empty()) notes_.push_back(l_.colour_note);
    notes_.push_back("PCD ascii, " + std::to_string(l_.n) + " points (lines streamed in chunks)");
  }

 private:
  void fill(std::size_t max) override {
    const char* b = nullptr;
    const char* e = nullptr;
    double xyz[3];
    std::uint8_t rgb[3];
    float intensity = 0.0f;
    while (max > 0 && done_ < l_.n) {
      if (!lines_->next(b, e)) {
        throw InputError("load_cloud: " + name_ + ": truncated: the header declares " + std::to_string(l_.n) +
                         " points but only " + std::to_string(done_) + " data lines follow");
      }
      ++done_;
      std::string problem = check_ascii_line(b, e, l_.values);
      if (problem.empty()) problem = decode_ascii_line(b, e, l_, xyz, rgb, &intensity);
      if (!problem.empty()) throw InputError("load_cloud: " + name_ + ": data line " + std::to_string(done_) + ": " + problem);
      xyz_.insert(xyz_.end(), xyz, xyz + 3);
      if (l_.has_rgb) rgb_.insert(rgb_.end(), rgb, rgb + 3);
      if (l_.has_intensity) intensity_.push_back(intensity);
      --max;
    }
  }
  void shape(Cloud& chunk) override { chunk.float32_xyz = float32_axes(l_); }

  PcdLayout l_;
  std::size_t done_ = 0;  // data lines read
};

}  // namespace

std::unique_ptr<PointStream> open_pcd_stream(const std::filesystem::path& path, const std::string& name, bool gz) {
  std::unique_ptr<ByteSource> src;
  try {
    src = ByteSource::open(path, name, gz);
  } catch (const InputError&) {
    return nullptr;  // load_cloud's whole read says why
  }
  // The data's size: the file's, or under gzip a first look that inflates it all (so that bad
  // gzip data fail first, as the whole read inflates before it reads the header).
  std::uint64_t file_bytes = 0;
  if (gz) {
    file_bytes = first_look(*src, "pcd_bytes", [&] {
      std::vector<char> block(1u << 20);
      std::uint64_t total = 0;
      for (std::size_t got; (got = src->read(block.data(), block.size())) > 0;) total += got;
      return std::array<std::uint64_t, 2>{total, 0};
    })[0];
  } else {
    std::error_code ec;
    file_bytes = std::filesystem::file_size(path, ec);
    if (ec) return nullptr;
  }
  // The header: the lines up to the first whose first word is DATA (validate_pcd's rule), at
  // most 16 MB; the whole read says what is wrong with a file that has none.
  std::string head;
  const std::size_t end_at = read_header_until_word(*src, "DATA", head, /*unterminated_last=*/true);
  if (end_at == std::string::npos) return nullptr;
  head.resize(end_at);
  const PcdLayout layout = validate_pcd(head, name, static_cast<std::size_t>(file_bytes), /*header_only=*/true);
  if (layout.data == "ascii") return std::make_unique<PcdAsciiStream>(std::move(src), layout);
  if (layout.data == "binary_compressed") return std::make_unique<PcdCompressedStream>(path, gz, file_bytes, std::move(src), layout);
  if (layout.data != "binary") return nullptr;  // an unknown DATA type: the whole read refuses it, naming it
  return std::make_unique<PcdStream>(std::move(src), layout);
}

ReadResult read_pcd(const ScanSource& source) {
  const PcdLayout layout = validate_pcd(source.bytes, source.display_name, source.bytes.size(), /*header_only=*/false);
  ReadResult r = layout.data == "binary"              ? ReadResult{read_binary_body(source.bytes, layout), {kBinaryNote}}
                 : layout.data == "binary_compressed" ? ReadResult{read_compressed_body(source.bytes, layout, source.display_name), {kCompressedNote}}
                                                      : ReadResult{read_ascii_body(source.bytes, layout, source.display_name), {kAsciiNote}};
  if (!layout.colour_note.empty()) r.notes.push_back(layout.colour_note);
  r.cloud.float32_xyz = float32_axes(layout);
  return r;
}

}  // namespace hc::pipeline::detail
