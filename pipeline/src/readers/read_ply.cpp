// PLY reader (ascii, binary_little_endian, binary_big_endian), without PCL.
//
// Header: `obj_info` lines (Stanford range scans) and stray lines such as `bye` are skipped
// (num_cols / num_rows are kept for the range grid). Declared counts are checked against the
// bytes or lines actually present.
// Elements after `vertex`: `face` (its vertex_indices list, polygons fan-split into
// Cloud::mesh) and `range_grid` (Stanford range scans: each vertex's scanner row/column) are
// read; others are skipped. A face or range_grid element that cannot be used (truncated, bad
// counts, indices out of range) never fails the read: it is dropped with a note naming why.
// Vertex colours (red/green/blue, or diffuse_*) become Cloud::rgb.
//
// Vertex data is read in each property's own type (float32 stays the float nearest to the text,
// double stays double):
//   * binary, vertex element without list properties: a fixed-stride copy (about 20x faster
//     than PCL's PLY reader on the 1.1 M-point Buddha);
//   * binary, vertex element with list properties (any position): record by record, each
//     list's count read in its count type and its items skipped (streamed in chunks the same
//     way: ListPlyStream);
//   * ascii: one line per element instance, numbers parsed with std::from_chars (PCL's ASCII
//     reader accepts a non-numeric token silently and is about 10x slower); a list property
//     takes its count and then that many values.
// Elements before the vertex element are skipped the same way (lines in ASCII; records, lists
// included, in binary).
// Issue 15 D2: PCL's PLY reader, used before for list layouts, misplaced the columns of a
// vertex element with a scalar before a list (x read from y, y from z) and the run succeeded;
// list properties are therefore parsed here and PCL reads no PLY any more.
// tests/pipeline/ingest_test.cpp checks the direct reads against PCL's reader on the layouts
// PCL reads correctly, and the list layouts against the values the test wrote.

#include "readers.hpp"
#include "byte_source.hpp"
#include "line_stream.hpp"
#include "text_lines.hpp"
#include "text_parse.hpp"
#include "../stage_util.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/point_stream.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <limits>
#include <optional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace hc::pipeline::detail {

namespace {

enum class PlyType { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

struct PlyProperty {
  std::string name;
  bool is_list = false;
  PlyType type = PlyType::kFloat32;  // scalar: its type; list: the item type
  std::size_t size_bytes = 0;        // scalar: its size; list: the item size
  PlyType count_type = PlyType::kUint8;  // list only
  std::size_t count_bytes = 0;           // list only
};

struct PlyElement {
  std::string name;
  std::size_t count = 0;
  std::vector<PlyProperty> properties;
  bool has_list() const {
    return std::any_of(properties.begin(), properties.end(), [](const PlyProperty& p) { return p.is_list; });
  }
  // Bytes of one binary record (scalar properties only).
  std::size_t stride() const {
    std::size_t s = 0;
    for (const auto& p : properties) s += p.size_bytes;
    return s;
  }
};

bool parse_ply_type(const std::string& t, PlyType& type, std::size_t& size) {
  static const std::pair<const char*, std::pair<PlyType, std::size_t>> kTypes[] = {
      {"char", {PlyType::kInt8, 1}},      {"int8", {PlyType::kInt8, 1}},       {"uchar", {PlyType::kUint8, 1}},
      {"uint8", {PlyType::kUint8, 1}},    {"short", {PlyType::kInt16, 2}},     {"int16", {PlyType::kInt16, 2}},
      {"ushort", {PlyType::kUint16, 2}},  {"uint16", {PlyType::kUint16, 2}},   {"int", {PlyType::kInt32, 4}},
      {"int32", {PlyType::kInt32, 4}},    {"uint", {PlyType::kUint32, 4}},     {"uint32", {PlyType::kUint32, 4}},
      {"float", {PlyType::kFloat32, 4}},  {"float32", {PlyType::kFloat32, 4}}, {"double", {PlyType::kFloat64, 8}},
      {"float64", {PlyType::kFloat64, 8}}};
  for (const auto& [n, ts] : kTypes) {
    if (t == n) {
      type = ts.first;
      size = ts.second;
      return true;
    }
  }
  return false;
}

struct PlyLayout {
  std::string format;  // ascii, binary_little_endian, binary_big_endian
  std::vector<PlyElement> elements;
  std::size_t vertex_index = 0;
  std::size_t body = 0;          // offset of the first data byte
  std::size_t header_lines = 0;  // line number of end_header
  std::size_t skipped_lines = 0;
  long long num_cols = -1, num_rows = -1;  // Stanford range scans: `obj_info num_cols N`
  const PlyElement& vertex() const { return elements[vertex_index]; }
};

// The whole read's check that the data after the header can hold `count` vertices (each takes
// one byte at least): parse_ply_header's, and the streams' under gzip, where the data's size is
// learnt only at their end. @throws InputError naming the file, the count and the bytes.
void require_bytes_for_vertices(const std::string& name, std::size_t count, std::uint64_t bytes_after_header) {
  if (count <= bytes_after_header) return;
  throw InputError("load_cloud: " + name + ": truncated: the header declares " + std::to_string(count) + " vertices but only " +
                   std::to_string(bytes_after_header) + " bytes follow it");
}

// `file_size`: the whole file's size when `raw` holds only its beginning (a streamed read);
// npos = raw is the whole file.
PlyLayout parse_ply_header(const std::string& raw, const std::string& name, std::size_t file_size = std::string::npos) {
  const std::size_t size = file_size == std::string::npos ? raw.size() : file_size;
  auto fail = [&](const std::string& what) -> InputError {
    return InputError("load_cloud: " + name + ": " + what);
  };
  if (raw.size() < 4 || raw.compare(0, 3, "ply") != 0 || (raw[3] != '\n' && raw[3] != '\r')) {
    throw fail("not a PLY file (the first line is not 'ply')");
  }
  PlyLayout out;
  std::size_t pos = raw.find('\n') + 1;
  std::size_t line_no = 1;
  bool ended = false;
  std::string line;
  while (next_line(raw, pos, line, /*accept_unterminated=*/false)) {
    ++line_no;
    std::istringstream ls(line);
    std::string kw;
    ls >> kw;
    if (kw == "end_header") {
      ended = true;
      break;
    }
    const std::string where = "header line " + std::to_string(line_no) + ": ";
    if (kw == "format") {
      std::string version;
      ls >> out.format >> version;
      if (out.format != "ascii" && out.format != "binary_little_endian" && out.format != "binary_big_endian") {
        throw fail(where + "unknown PLY format '" + out.format + "'");
      }
    } else if (kw == "comment") {
      continue;
    } else if (kw == "element") {
      PlyElement el;
      long long count = -1;
      ls >> el.name >> count;
      if (!ls || count < 0) throw fail(where + "malformed '" + line + "'");
      el.count = static_cast<std::size_t>(count);
      out.elements.push_back(std::move(el));
    } else if (kw == "property") {
      if (out.elements.empty()) throw fail(where + "property before any element");
      PlyProperty pr;
      std::string type;
      ls >> type;
      if (type == "list") {
        std::string count_type, item_type;
        ls >> count_type >> item_type >> pr.name;
        pr.is_list = true;
        if (pr.name.empty()) throw fail(where + "malformed '" + line + "'");
        const std::string what = "list property '" + pr.name + "' of element '" + out.elements.back().name + "'";
        if (!parse_ply_type(count_type, pr.count_type, pr.count_bytes) || pr.count_type == PlyType::kFloat32 ||
            pr.count_type == PlyType::kFloat64) {
          throw fail(where + what + " has count type '" + count_type +
                     "' (expected an integer type: char, uchar, short, ushort, int, uint)");
        }
        if (!parse_ply_type(item_type, pr.type, pr.size_bytes)) {
          throw fail(where + what + " has an unknown item type '" + item_type + "'");
        }
      } else {
        ls >> pr.name;
        if (!parse_ply_type(type, pr.type, pr.size_bytes)) throw fail(where + "unknown property type '" + type + "'");
      }
      if (pr.name.empty()) throw fail(where + "malformed '" + line + "'");
      out.elements.back().properties.push_back(std::move(pr));
    } else {
      // obj_info (Stanford range scans), stray lines such as `bye`, blank lines: not data.
      if (kw == "obj_info") {  // the range grid's size, used to place range_grid records
        std::string key;
        long long v = -1;
        ls >> key >> v;
        if (ls && key == "num_cols") out.num_cols = v;
        if (ls && key == "num_rows") out.num_rows = v;
      }
      ++out.skipped_lines;
    }
  }
  if (!ended) throw fail("the header has no 'end_header' line (file truncated or not PLY)");
  if (out.format.empty()) throw fail("the header has no 'format' line");
  out.body = pos;
  out.header_lines = line_no;

  out.vertex_index = out.elements.size();
  for (std::size_t i = 0; i < out.elements.size(); ++i) {
    if (out.elements[i].name == "vertex") {
      out.vertex_index = i;
      break;
    }
  }
  if (out.vertex_index == out.elements.size()) throw fail("the header declares no 'vertex' element");
  const PlyElement& vertex = out.vertex();
  if (vertex.count == 0) throw fail("the header declares 0 vertices");
  require_bytes_for_vertices(name, vertex.count, size - out.body);
  for (const char* axis : {"x", "y", "z"}) {
    const auto n = std::count_if(vertex.properties.begin(), vertex.properties.end(),
                                 [&](const PlyProperty& p) { return p.name == axis; });
    const bool scalar = std::any_of(vertex.properties.begin(), vertex.properties.end(),
                                    [&](const PlyProperty& p) { return p.name == axis && !p.is_list; });
    if (!scalar) throw fail(std::string("the vertex element has no '") + axis + "' property");
    if (n > 1) throw fail(std::string("the vertex element declares the property '") + axis + "' twice");
  }
  return out;
}

// Slot of each vertex property: 0, 1, 2 for x, y, z; 3, 4, 5 for red, green, blue (or
// diffuse_red, ...) when all three are scalars, each given once; -1 for the others.
std::vector<int> axes_of(const PlyElement& v) {
  std::vector<int> axis_of(v.properties.size(), -1);
  int colour_found[3] = {0, 0, 0};
  auto colour_slot = [](const std::string& n) {
    const std::string c = n.rfind("diffuse_", 0) == 0 ? n.substr(8) : n;
    return c == "red" ? 0 : c == "green" ? 1 : c == "blue" ? 2 : -1;
  };
  for (std::size_t j = 0; j < v.properties.size(); ++j) {
    const std::string& n = v.properties[j].name;
    axis_of[j] = n == "x" ? 0 : n == "y" ? 1 : n == "z" ? 2 : -1;
    const int c = colour_slot(n);
    if (c >= 0) colour_found[c] += v.properties[j].is_list ? 2 : 1;
  }
  if (colour_found[0] == 1 && colour_found[1] == 1 && colour_found[2] == 1) {
    for (std::size_t j = 0; j < v.properties.size(); ++j) {
      const int c = colour_slot(v.properties[j].name);
      if (c >= 0) axis_of[j] = 3 + c;
    }
  }
  return axis_of;
}

bool has_colour(const std::vector<int>& axis_of) {
  return std::find(axis_of.begin(), axis_of.end(), 3) != axis_of.end();
}

// A colour channel in its PLY type to 8 bit: 1-byte integers as they are, 2-byte integers
// scaled by 255/65535, wider integers clamped to [0, 255], floats in [0, 1] scaled by 255.
std::uint8_t colour_byte(double v, PlyType t) {
  double c = v;
  if (t == PlyType::kFloat32 || t == PlyType::kFloat64) {
    c = v * 255.0;
  } else if (t == PlyType::kInt16 || t == PlyType::kUint16) {
    c = v / 257.0;
  }
  if (!(c > 0.0)) return 0;
  return static_cast<std::uint8_t>(std::lround(std::min(c, 255.0)));
}

template <class T>
double load_scalar(const char* p, bool swap) {
  char b[sizeof(T)];
  std::memcpy(b, p, sizeof(T));
  if (swap) std::reverse(b, b + sizeof(T));
  T v;
  std::memcpy(&v, b, sizeof(T));
  return static_cast<double>(v);
}

double load_ply_scalar(const char* p, PlyType t, bool swap) {
  switch (t) {
    case PlyType::kInt8: return load_scalar<std::int8_t>(p, swap);
    case PlyType::kUint8: return load_scalar<std::uint8_t>(p, swap);
    case PlyType::kInt16: return load_scalar<std::int16_t>(p, swap);
    case PlyType::kUint16: return load_scalar<std::uint16_t>(p, swap);
    case PlyType::kInt32: return load_scalar<std::int32_t>(p, swap);
    case PlyType::kUint32: return load_scalar<std::uint32_t>(p, swap);
    case PlyType::kFloat32: return load_scalar<float>(p, swap);
    case PlyType::kFloat64: return load_scalar<double>(p, swap);
  }
  return std::numeric_limits<double>::quiet_NaN();
}

bool needs_swap(const PlyLayout& ply) {
  return (ply.format == "binary_big_endian") != (std::endian::native == std::endian::big);
}

// ---------------------------------------------------------------------------------------------
// Binary

// Walks one binary record of `el` that starts at p: stores the value of every property j with
// axis_of[j] >= 0 into xyz[axis_of[j]] (when axis_of is given) and returns the first byte after
// the record, or nullptr when the data ends inside it. A list's count is read in its count
// type; a negative count is an error naming the element, record and property.
const char* walk_binary_record(const char* p, const char* end, const PlyElement& el, std::size_t record, bool swap,
                               const int* axis_of, double* xyz, const std::string& name) {
  for (std::size_t j = 0; j < el.properties.size(); ++j) {
    const PlyProperty& pr = el.properties[j];
    if (!pr.is_list) {
      if (static_cast<std::size_t>(end - p) < pr.size_bytes) return nullptr;
      if (axis_of && axis_of[j] >= 0) xyz[axis_of[j]] = load_ply_scalar(p, pr.type, swap);
      p += pr.size_bytes;
      continue;
    }
    if (static_cast<std::size_t>(end - p) < pr.count_bytes) return nullptr;
    const double count = load_ply_scalar(p, pr.count_type, swap);
    if (count < 0.0) {
      throw InputError("load_cloud: " + name + ": " + el.name + " " + std::to_string(record) + ": list property '" +
                       pr.name + "' has the negative item count " + std::to_string(static_cast<long long>(count)));
    }
    p += pr.count_bytes;
    const auto items = static_cast<std::size_t>(count);  // an integer type: exact
    if (items > static_cast<std::size_t>(end - p) / pr.size_bytes) return nullptr;
    p += items * pr.size_bytes;
  }
  return p;
}

// The error of data that end inside element `el` before the vertex element, after `whole` of
// its records.
InputError truncated_before_vertices(const std::string& name, const PlyElement& el, std::size_t whole) {
  return InputError("load_cloud: " + name + ": truncated: the data ends inside element '" + el.name + "' (" +
                    std::to_string(whole) + " of " + std::to_string(el.count) + " records), before the vertex element");
}

// Offset of the vertex data in a binary body: the elements before it are skipped record by
// record when they hold lists, else by their fixed stride.
std::size_t binary_vertex_offset(const std::string& raw, const PlyLayout& ply, const std::string& name) {
  const bool swap = needs_swap(ply);
  const char* const begin = raw.data();
  const char* const end = begin + raw.size();
  const char* p = begin + ply.body;
  for (std::size_t i = 0; i < ply.vertex_index; ++i) {
    const PlyElement& el = ply.elements[i];
    auto truncated = [&](std::size_t whole) { return truncated_before_vertices(name, el, whole); };
    if (!el.has_list()) {
      const std::size_t stride = el.stride();
      const auto have = static_cast<std::size_t>(end - p);
      if (stride > 0 && el.count > have / stride) throw truncated(have / stride);
      p += stride * el.count;
      continue;
    }
    for (std::size_t r = 0; r < el.count; ++r) {
      p = walk_binary_record(p, end, el, r, swap, nullptr, nullptr, name);
      if (!p) throw truncated(r);
    }
  }
  return static_cast<std::size_t>(p - begin);
}

// binary_vertex_offset over a source instead of the whole file's bytes: the elements before the
// vertex element walked from the body's first byte (src.seek(ply.body)) in blocks of at least 1
// MiB, record by record (walk_binary_record) where they hold lists, by their stride where not,
// with the same errors in the same words (a negative list count; "truncated: the data ends
// inside element ..."). src is left somewhere past the offset returned. Memory: a block and the
// longest record. Used by open_ply_stream at each pass: a file whose elements with lists come
// before its vertices streams instead of being read whole (until 2026-11-26 it was read whole).
// Under gzip, the stream's seek back to the offset inflates the data from the start again
// (ByteSource::seek): the elements before the vertices twice a pass.
std::uint64_t streamed_vertex_offset(ByteSource& src, const PlyLayout& ply, const std::string& name) {
  const bool swap = needs_swap(ply);
  src.seek(ply.body);
  std::vector<char> buf;
  std::size_t at = 0;               // buf[at, size) not walked yet
  std::uint64_t base = ply.body;    // the data offset of buf[0]
  bool ended = false;
  // Drops the walked bytes and reads at least 1 MiB more (false at the data's end).
  auto more = [&] {
    if (ended) return false;
    buf.erase(buf.begin(), buf.begin() + static_cast<std::ptrdiff_t>(at));
    base += at;
    at = 0;
    const std::size_t old = buf.size(), want = std::max<std::size_t>(std::size_t{1} << 20, old);
    buf.resize(old + want);
    const std::size_t got = src.read(buf.data() + old, want);
    buf.resize(old + got);
    ended = got < want;
    return got > 0;
  };
  for (std::size_t i = 0; i < ply.vertex_index; ++i) {
    const PlyElement& el = ply.elements[i];
    // The data end inside this element after `whole` records: under gzip their size is known
    // only now, and the whole read's header check (a byte a vertex at least) comes first (for a
    // plain file it ran when the stream opened).
    auto truncated = [&](std::size_t whole) {
      require_bytes_for_vertices(name, ply.vertex().count, base + buf.size() - ply.body);
      return truncated_before_vertices(name, el, whole);
    };
    if (!el.has_list()) {
      const std::size_t stride = el.stride();
      std::size_t r = 0;  // records skipped
      while (r < el.count) {
        const std::size_t have = stride > 0 ? (buf.size() - at) / stride : el.count;
        const std::size_t take = std::min(have, el.count - r);
        at += take * stride;
        r += take;
        if (r < el.count && !more()) throw truncated(r);  // every whole record in the data taken
      }
      continue;
    }
    for (std::size_t r = 0; r < el.count; ++r) {
      for (;;) {
        const char* p = walk_binary_record(buf.data() + at, buf.data() + buf.size(), el, r, swap, nullptr, nullptr, name);
        if (p) {
          at = static_cast<std::size_t>(p - buf.data());
          break;
        }
        if (!more()) throw truncated(r);
      }
    }
  }
  return base + at;
}

// Where the coordinates and colours sit in a fixed-stride binary vertex record.
struct FixedRecords {
  std::size_t stride = 0;
  std::size_t field_off[6] = {0, 0, 0, 0, 0, 0};
  PlyType field_type[6] = {PlyType::kFloat32, PlyType::kFloat32, PlyType::kFloat32,
                           PlyType::kUint8,   PlyType::kUint8,   PlyType::kUint8};
  bool swap = false;
  bool colour = false;
  bool plain_float = false;

  explicit FixedRecords(const PlyLayout& ply) {
    const PlyElement& v = ply.vertex();
    stride = v.stride();
    const std::vector<int> axis_of = axes_of(v);
    std::size_t at = 0;
    for (std::size_t j = 0; j < v.properties.size(); ++j) {
      if (axis_of[j] >= 0) {
        field_off[axis_of[j]] = at;
        field_type[axis_of[j]] = v.properties[j].type;
      }
      at += v.properties[j].size_bytes;
    }
    swap = needs_swap(ply);
    colour = has_colour(axis_of);
    plain_float = !swap && field_type[0] == PlyType::kFloat32 && field_type[1] == PlyType::kFloat32 &&
                  field_type[2] == PlyType::kFloat32;
  }

  // Decodes n records from base into xyz (3·n doubles) and, with colour, rgb (3·n bytes).
  void decode(const char* base, std::size_t n, double* out, std::uint8_t* rgb) const {
    if (colour) {
      for (std::size_t i = 0; i < n; ++i) {
        const char* rec = base + i * stride;
        for (std::size_t a = 0; a < 3; ++a) {
          rgb[3 * i + a] = colour_byte(load_ply_scalar(rec + field_off[3 + a], field_type[3 + a], swap), field_type[3 + a]);
        }
      }
    }
    for (std::size_t i = 0; i < n; ++i) {
      const char* rec = base + i * stride;
      if (plain_float) {
        for (std::size_t a = 0; a < 3; ++a) {
          float f;
          std::memcpy(&f, rec + field_off[a], sizeof f);
          out[3 * i + a] = static_cast<double>(f);
        }
      } else {
        for (std::size_t a = 0; a < 3; ++a) out[3 * i + a] = load_ply_scalar(rec + field_off[a], field_type[a], swap);
      }
    }
  }
};

std::string truncated_vertices(const std::string& name, std::size_t count, std::size_t stride, std::size_t have) {
  return "load_cloud: " + name + ": truncated: the header declares " + std::to_string(count) + " vertices (" +
         std::to_string(stride * count) + " bytes) but only " + std::to_string(have) +
         " bytes of vertex data follow (" + std::to_string(have / stride) + " whole vertices)";
}

// Fixed-stride read of binary vertex records (scalar properties only).
Cloud read_binary_fixed(const std::string& raw, const PlyLayout& ply, std::size_t offset, const std::string& name) {
  const PlyElement& v = ply.vertex();
  const FixedRecords rec(ply);
  const std::size_t have = raw.size() > offset ? raw.size() - offset : 0;
  if (have < rec.stride * v.count) throw InputError(truncated_vertices(name, v.count, rec.stride, have));
  Cloud cloud;
  cloud.xyz.resize(3, static_cast<Eigen::Index>(v.count));
  if (rec.colour) cloud.rgb.resize(3 * v.count);
  // Above 2^17 records on two threads, each decoding a contiguous half of the records into its
  // own half of the arrays (and taking its own half of the page faults): the same values.
  const char* const base = raw.data() + offset;
  double* const xyz = cloud.xyz.data();
  std::uint8_t* const rgb = rec.colour ? cloud.rgb.data() : nullptr;
  if (v.count > (std::size_t{1} << 17)) {
    const std::size_t half = v.count / 2;
    run_two([&] { rec.decode(base + half * rec.stride, v.count - half, xyz + 3 * half, rgb ? rgb + 3 * half : nullptr); },
            [&] { rec.decode(base, half, xyz, rgb); });
  } else {
    rec.decode(base, v.count, xyz, rgb);
  }
  return cloud;
}

// The whole read's words for vertex data that end inside vertex `i` of `count`.
InputError truncated_inside_vertex(const std::string& name, std::size_t count, std::uint64_t i) {
  return InputError("load_cloud: " + name + ": truncated: the header declares " + std::to_string(count) +
                    " vertices but the data ends inside vertex " + std::to_string(i) + " (" + std::to_string(i) + " whole vertices)");
}

// Binary vertex records with list properties (records of their own lengths): where the
// coordinates and colours sit, and one record's decoding, for the whole read
// (read_binary_records) and the stream (ListPlyStream) alike.
struct ListRecords {
  const PlyElement* v = nullptr;
  std::vector<int> axis_of;
  bool swap = false;
  bool colour = false;
  PlyType colour_type[3] = {PlyType::kUint8, PlyType::kUint8, PlyType::kUint8};

  // `vertex` must outlive this (it is read at every decode); `swap_bytes`: needs_swap.
  ListRecords(const PlyElement& vertex, bool swap_bytes) : v(&vertex), axis_of(axes_of(vertex)), swap(swap_bytes), colour(has_colour(axis_of)) {
    for (std::size_t j = 0; j < v->properties.size(); ++j) {
      if (axis_of[j] >= 3) colour_type[axis_of[j] - 3] = v->properties[j].type;
    }
  }

  // Vertex `record` at p (the data end at `end`): x y z into xyz [3] and, with colour, r g b
  // into rgb [3]. @return the first byte after it, nullptr when the data end inside it.
  // @throws InputError for a negative list count (walk_binary_record).
  const char* decode(const char* p, const char* end, std::size_t record, double* xyz, std::uint8_t* rgb, const std::string& name) const {
    double slots[6] = {0, 0, 0, 0, 0, 0};
    p = walk_binary_record(p, end, *v, record, swap, axis_of.data(), slots, name);
    if (p == nullptr) return nullptr;
    std::copy_n(slots, 3, xyz);
    for (std::size_t a = 0; colour && a < 3; ++a) rgb[a] = colour_byte(slots[3 + a], colour_type[a]);
    return p;
  }
};

// Record-by-record read of binary vertex records with list properties.
Cloud read_binary_records(const std::string& raw, const PlyLayout& ply, std::size_t offset, const std::string& name,
                          std::size_t* end_offset) {
  const ListRecords rec(ply.vertex(), needs_swap(ply));
  const std::size_t count = ply.vertex().count;
  Cloud cloud;
  cloud.xyz.resize(3, static_cast<Eigen::Index>(count));
  if (rec.colour) cloud.rgb.resize(3 * count);
  const char* p = raw.data() + offset;
  const char* const end = raw.data() + raw.size();
  for (std::size_t i = 0; i < count; ++i) {
    p = rec.decode(p, end, i, cloud.xyz.data() + 3 * i, rec.colour ? cloud.rgb.data() + 3 * i : nullptr, name);
    if (p == nullptr) throw truncated_inside_vertex(name, count, i);
  }
  *end_offset = static_cast<std::size_t>(p - raw.data());
  return cloud;
}

// ---------------------------------------------------------------------------------------------
// ASCII

// The vertex lines (one vertex per line; the elements before it take one line per instance),
// over a line source that gives every line (TextLines or FileLines with skip_blank false, from
// the first line after the header). Each number is parsed in the property's own type (float32
// properties give the float nearest to the text, as PCL's reader does); a list takes its count,
// a non-negative integer, then that many numbers. Any non-numeric token is an error naming the
// line. Read whole (read_ascii_vertices) or in chunks (AsciiPlyStream): the same vertices and
// errors.
template <class LineSource>
class AsciiVertexParser {
 public:
  AsciiVertexParser(LineSource& lines, const PlyLayout& ply, const std::string& name)
      : lines_(lines), ply_(ply), v_(ply.vertex()), name_(name), axis_of_(axes_of(v_)), colour_(has_colour(axis_of_)) {
    for (std::size_t i = 0; i < ply.vertex_index; ++i) skip_ += ply.elements[i].count;
  }

  bool colour() const { return colour_; }

  /// Appends up to `max` (≥ 1) vertices: x y z to xyz, r g b to rgb when the vertex has colour.
  /// @return false once every vertex has been read (the last may have come with this call).
  /// @throws hc::InputError naming the file, the line and the vertex for a bad token or count,
  /// and when the file ends before the header's vertex count.
  bool read(std::size_t max, std::vector<double>& xyz, std::vector<std::uint8_t>& rgb) {
    const std::size_t nprop = v_.properties.size();
    const bool lists = v_.has_list();
    std::size_t taken = 0;
    const char* b = nullptr;
    const char* e = nullptr;
    while (vertex_ < v_.count && taken < max) {
      if (!lines_.next(b, e)) {
        throw InputError("load_cloud: " + name_ + ": truncated: the header declares " + std::to_string(v_.count) +
                         " vertices but only " + std::to_string(vertex_) + " vertex lines follow");
      }
      if (lines_.line_no() <= skip_) continue;  // an element before the vertex element
      auto fail = [&](const std::string& what) {
        return InputError("load_cloud: " + name_ + ": line " + std::to_string(ply_.header_lines + lines_.line_no()) + " (vertex " +
                          std::to_string(vertex_) + "): " + what);
      };
      // The token at t is not a number, or the line ended before property j.
      auto bad_value = [&](const char* t, std::size_t j) {
        const std::string_view tok = first_token(t, e);
        if (!tok.empty()) return fail("'" + std::string(tok.substr(0, 40)) + "' is not a number");
        return fail(lists ? "the line ends before property '" + v_.properties[j].name + "'"
                          : std::to_string(j) + " values where the header declares " + std::to_string(nprop));
      };
      const char* q = b;
      double p[3] = {0.0, 0.0, 0.0};
      std::uint8_t c3[3] = {0, 0, 0};
      for (std::size_t j = 0; j < nprop; ++j) {
        const PlyProperty& pr = v_.properties[j];
        const char* t = q;
        if (pr.is_list) {
          double count = 0.0;
          if (!parse_number(q, e, count)) throw bad_value(t, j);
          if (!(count >= 0.0) || count > 1e15 || count != std::floor(count)) {
            throw fail("list property '" + pr.name + "': item count '" + std::string(first_token(t, e).substr(0, 40)) +
                       "' is not a non-negative integer");
          }
          const auto items = static_cast<long long>(count);
          for (long long k = 0; k < items; ++k) {
            const char* ti = q;
            double item = 0.0;
            if (!parse_number(q, e, item)) {
              if (!first_token(ti, e).empty()) throw bad_value(ti, j);
              throw fail("list property '" + pr.name + "' declares " + std::to_string(items) + " items but the line ends after " +
                         std::to_string(k));
            }
          }
          continue;
        }
        bool ok;
        double value = 0.0;
        if (pr.type == PlyType::kFloat32) {
          float fv = 0.0f;
          ok = parse_number(q, e, fv);
          value = static_cast<double>(fv);
        } else {
          ok = parse_number(q, e, value);
        }
        if (!ok) throw bad_value(t, j);
        if (axis_of_[j] >= 3) {
          c3[static_cast<std::size_t>(axis_of_[j] - 3)] = colour_byte(value, pr.type);
        } else if (axis_of_[j] >= 0) {
          p[static_cast<std::size_t>(axis_of_[j])] = value;
        }
      }
      while (q < e && is_space(*q)) ++q;
      if (q != e) {
        throw fail(lists ? std::string("more values than the header declares")
                         : "more values than the " + std::to_string(nprop) + " the header declares");
      }
      xyz.insert(xyz.end(), p, p + 3);
      if (colour_) rgb.insert(rgb.end(), c3, c3 + 3);
      ++vertex_;
      ++taken;
    }
    return vertex_ < v_.count;
  }

 private:
  LineSource& lines_;
  const PlyLayout& ply_;
  const PlyElement& v_;
  const std::string& name_;
  std::vector<int> axis_of_;
  bool colour_;
  std::size_t skip_ = 0;  // lines of the elements before the vertex element
  std::uint64_t vertex_ = 0;
};

// Reads the vertex lines whole (AsciiVertexParser); *end_offset: the first byte after the last
// vertex line (where the elements after the vertex element begin).
Cloud read_ascii_vertices(const std::string& raw, const PlyLayout& ply, const std::string& name, std::size_t* end_offset) {
  TextLines lines(raw, name, ply.body, false);
  AsciiVertexParser<TextLines> parser(lines, ply, name);
  std::vector<double> xyz;
  std::vector<std::uint8_t> rgb;
  xyz.reserve(3 * ply.vertex().count);
  if (parser.colour()) rgb.reserve(3 * ply.vertex().count);
  (void)parser.read(std::numeric_limits<std::size_t>::max(), xyz, rgb);
  Cloud cloud = cloud_from(xyz);
  cloud.rgb = std::move(rgb);
  *end_offset = lines.offset();
  return cloud;
}


// ---------------------------------------------------------------------------------------------
// Elements after the vertex element: faces and the range grid.
//
// Both are lists of vertex indices, one list per record. They are read without throwing: a
// problem (truncated data, a bad token, a negative count) makes the element unusable and is
// returned as text for a note, and the vertices are used as they are. Elements after an
// unusable one cannot be located and are reported as not read.

/// The `vertex_indices` (or `vertex_index`) list of every record of one element.
struct IndexLists {
  std::vector<std::uint32_t> counts;  // items per record
  std::vector<std::int64_t> items;    // all items, record after record
};

struct AfterVertex {
  std::optional<IndexLists> face, range_grid;
  std::vector<std::string> notes;
};

bool is_index_list(const PlyProperty& pr) {
  return pr.is_list && (pr.name == "vertex_indices" || pr.name == "vertex_index") && pr.type != PlyType::kFloat32 &&
         pr.type != PlyType::kFloat64;
}

// Walks the elements after the vertex element from byte `start` (binary: the first byte after
// the vertex records; ASCII: the first line after the vertex lines).
AfterVertex read_after_vertex(const std::string& raw, const PlyLayout& ply, std::size_t start) {
  AfterVertex out;
  const bool ascii = ply.format == "ascii";
  const bool swap = needs_swap(ply);
  const char* p = raw.data() + std::min(start, raw.size());
  const char* const end = raw.data() + raw.size();
  for (std::size_t ei = ply.vertex_index + 1; ei < ply.elements.size(); ++ei) {
    const PlyElement& el = ply.elements[ei];
    const bool wanted = el.name == "face" || el.name == "range_grid";
    std::size_t list_at = el.properties.size();
    for (std::size_t j = 0; wanted && j < el.properties.size(); ++j) {
      if (is_index_list(el.properties[j])) {
        list_at = j;
        break;
      }
    }
    if (wanted && list_at == el.properties.size()) {
      out.notes.push_back("dropped PLY element '" + el.name + "': it has no integer list property 'vertex_indices'");
    }
    IndexLists lists;
    const bool capture = wanted && list_at < el.properties.size();
    if (capture) lists.counts.reserve(std::min<std::size_t>(el.count, raw.size()));
    std::string problem;
    for (std::size_t r = 0; r < el.count && problem.empty(); ++r) {
      if (ascii) {
        if (p >= end) {
          problem = "the file ends after " + std::to_string(r) + " of its " + std::to_string(el.count) + " lines";
          break;
        }
        const void* nl = std::memchr(p, '\n', static_cast<std::size_t>(end - p));
        const char* e = nl ? static_cast<const char*>(nl) : end;
        const char* q = p;
        for (std::size_t j = 0; j < el.properties.size() && problem.empty(); ++j) {
          const PlyProperty& pr = el.properties[j];
          double v = 0.0;
          if (!parse_number(q, e, v)) {
            problem = "line " + std::to_string(r) + " of the element is not " + std::to_string(el.properties.size()) +
                      " numbers";
            break;
          }
          if (!pr.is_list) continue;
          if (!(v >= 0.0) || v != std::floor(v) || v > 1e9) {
            problem = "record " + std::to_string(r) + " has the list count " + std::string(first_token(p, e).substr(0, 20));
            break;
          }
          const auto items = static_cast<std::size_t>(v);
          if (capture && j == list_at) lists.counts.push_back(static_cast<std::uint32_t>(items));
          for (std::size_t k = 0; k < items; ++k) {
            double item = 0.0;
            if (!parse_number(q, e, item) || item != std::floor(item)) {
              problem = "record " + std::to_string(r) + " has fewer list items than its count or a non-integer item";
              break;
            }
            if (capture && j == list_at) lists.items.push_back(std::abs(item) < 9e18 ? static_cast<std::int64_t>(item) : -1);
          }
        }
        p = nl ? e + 1 : end;
        continue;
      }
      for (std::size_t j = 0; j < el.properties.size() && problem.empty(); ++j) {
        const PlyProperty& pr = el.properties[j];
        if (!pr.is_list) {
          if (static_cast<std::size_t>(end - p) < pr.size_bytes) problem = "the data ends inside record " + std::to_string(r);
          p += problem.empty() ? pr.size_bytes : 0;
          continue;
        }
        if (static_cast<std::size_t>(end - p) < pr.count_bytes) {
          problem = "the data ends inside record " + std::to_string(r);
          break;
        }
        const double count = load_ply_scalar(p, pr.count_type, swap);
        p += pr.count_bytes;
        if (count < 0.0) {
          problem = "record " + std::to_string(r) + " has the negative list count " + std::to_string(static_cast<long long>(count));
          break;
        }
        const auto items = static_cast<std::size_t>(count);
        if (items > static_cast<std::size_t>(end - p) / pr.size_bytes) {
          problem = "the data ends inside record " + std::to_string(r);
          break;
        }
        if (capture && j == list_at) {
          lists.counts.push_back(static_cast<std::uint32_t>(items));
          for (std::size_t k = 0; k < items; ++k) {
            const double item = load_ply_scalar(p + k * pr.size_bytes, pr.type, swap);
            lists.items.push_back(static_cast<std::int64_t>(item));
          }
        }
        p += items * pr.size_bytes;
      }
    }
    if (!problem.empty()) {
      out.notes.push_back("dropped PLY element '" + el.name + "' (" + std::to_string(el.count) +
                          " records): " + problem);
      for (std::size_t rest = ei + 1; rest < ply.elements.size(); ++rest) {
        out.notes.push_back("did not read PLY element '" + ply.elements[rest].name + "' (after an unreadable element)");
      }
      break;
    }
    if (capture && el.name == "face" && !out.face) {
      out.face = std::move(lists);
    } else if (capture && el.name == "range_grid" && !out.range_grid) {
      out.range_grid = std::move(lists);
    } else if (!wanted) {
      out.notes.push_back("ignored PLY element '" + el.name + "'");
    }
  }
  return out;
}

// Fan-splits the face lists into triangles (v0, v_k, v_k+1). Faces with fewer than 3 vertices
// or an index outside [0, vertices) are dropped and counted in the notes.
void add_faces(const IndexLists& faces, std::size_t vertices, Cloud& cloud, std::vector<std::string>& notes) {
  std::size_t at = 0, bad_index = 0, too_short = 0, polygons = 0;
  auto& tris = cloud.mesh.triangles;
  tris.reserve(faces.counts.size());
  for (const std::uint32_t n : faces.counts) {
    const std::int64_t* f = faces.items.data() + at;
    at += n;
    if (n < 3) {
      ++too_short;
      continue;
    }
    bool ok = true;
    for (std::uint32_t k = 0; k < n; ++k) ok = ok && f[k] >= 0 && static_cast<std::uint64_t>(f[k]) < vertices;
    if (!ok) {
      ++bad_index;
      continue;
    }
    polygons += n > 3 ? 1 : 0;
    for (std::uint32_t k = 1; k + 1 < n; ++k) {
      tris.push_back({static_cast<std::uint32_t>(f[0]), static_cast<std::uint32_t>(f[k]), static_cast<std::uint32_t>(f[k + 1])});
    }
  }
  notes.push_back("PLY face element: " + std::to_string(faces.counts.size()) + " faces, " + std::to_string(tris.size()) +
                  " triangles" + (polygons > 0 ? " (" + std::to_string(polygons) + " polygons fan-split)" : ""));
  if (bad_index > 0) {
    notes.push_back("dropped " + std::to_string(bad_index) + " PLY faces with a vertex index outside [0, " +
                    std::to_string(vertices) + ")");
  }
  if (too_short > 0) notes.push_back("dropped " + std::to_string(too_short) + " PLY faces with fewer than 3 vertices");
}

// Places each vertex of a Stanford range grid on its scanner row and column: record k of the
// range_grid element is row k / num_cols, column k % num_cols (obj_info num_cols / num_rows),
// and holds 0 (no sample) or 1 vertex index. Anything else leaves row/col empty, with a note.
void add_range_grid(const IndexLists& grid, const PlyLayout& ply, std::size_t vertices, Cloud& cloud,
                    std::vector<std::string>& notes) {
  const long long cols = ply.num_cols, rows = ply.num_rows;
  if (cols <= 0 || rows <= 0 || static_cast<unsigned long long>(cols) * static_cast<unsigned long long>(rows) != grid.counts.size()) {
    notes.push_back("range_grid not used: obj_info num_cols × num_rows (" + std::to_string(cols) + " × " +
                    std::to_string(rows) + ") does not match its " + std::to_string(grid.counts.size()) + " records");
    return;
  }
  std::vector<std::int32_t> row(vertices, -1), col(vertices, -1);
  std::size_t at = 0, placed = 0;
  for (std::size_t k = 0; k < grid.counts.size(); ++k) {
    const std::uint32_t n = grid.counts[k];
    if (n > 1) {
      notes.push_back("range_grid not used: record " + std::to_string(k) + " lists " + std::to_string(n) +
                      " vertices (expected 0 or 1)");
      return;
    }
    if (n == 1) {
      const std::int64_t v = grid.items[at];
      if (v < 0 || static_cast<std::uint64_t>(v) >= vertices || row[static_cast<std::size_t>(v)] >= 0) {
        notes.push_back("range_grid not used: record " + std::to_string(k) + " holds the vertex index " +
                        std::to_string(v) + " (out of range or placed twice)");
        return;
      }
      row[static_cast<std::size_t>(v)] = static_cast<std::int32_t>(static_cast<long long>(k) / cols);
      col[static_cast<std::size_t>(v)] = static_cast<std::int32_t>(static_cast<long long>(k) % cols);
      ++placed;
    }
    at += n;
  }
  if (placed != vertices) {
    notes.push_back("range_grid not used: it places " + std::to_string(placed) + " of the " +
                    std::to_string(vertices) + " vertices");
    return;
  }
  cloud.row = std::move(row);
  cloud.col = std::move(col);
  notes.push_back("range_grid: every vertex placed on the scanner's " + std::to_string(rows) + " × " +
                  std::to_string(cols) + " grid (row/col)");
}

}  // namespace

ReadResult read_ply(const ScanSource& source) {
  const std::string& bytes = source.bytes;
  const std::string& name = source.display_name;
  const PlyLayout ply = parse_ply_header(bytes, name);
  const PlyElement& vertex = ply.vertex();
  ReadResult result;
  std::string how;
  std::size_t vertex_end = 0;
  if (ply.format == "ascii") {
    result.cloud = read_ascii_vertices(bytes, ply, name, &vertex_end);
    how = "lines parsed directly";
  } else {
    const std::size_t offset = binary_vertex_offset(bytes, ply, name);
    if (vertex.has_list()) {
      result.cloud = read_binary_records(bytes, ply, offset, name, &vertex_end);
      how = "records with list properties parsed directly";
    } else {
      result.cloud = read_binary_fixed(bytes, ply, offset, name);
      vertex_end = offset + vertex.stride() * vertex.count;
      how = "fixed-stride records read directly";
    }
  }
  result.notes.push_back("PLY " + ply.format + ", " + std::to_string(vertex.count) + " vertices (" + how + ")");
  {
    const std::vector<int> axis_of = axes_of(vertex);
    int float_axes = 0;
    for (std::size_t j = 0; j < vertex.properties.size(); ++j) {
      if (axis_of[j] >= 0 && vertex.properties[j].type == PlyType::kFloat32) ++float_axes;
    }
    result.cloud.float32_xyz = float_axes == 3;
  }
  for (const auto& pr : vertex.properties) {
    if (pr.is_list) result.notes.push_back("skipped the vertex list property '" + pr.name + "'");
  }
  if (ply.skipped_lines > 0) {
    result.notes.push_back("skipped " + std::to_string(ply.skipped_lines) +
                           " non-standard header lines (obj_info and stray lines)");
  }
  if (result.cloud.has_rgb()) result.notes.push_back("vertex colours (red, green, blue) read as 8-bit RGB");
  if (ply.vertex_index + 1 < ply.elements.size()) {
    AfterVertex after = read_after_vertex(bytes, ply, vertex_end);
    result.notes.insert(result.notes.end(), after.notes.begin(), after.notes.end());
    if (after.face && vertex.count > 0xFFFFFFFEu) {
      result.notes.push_back("dropped PLY element 'face': more than 2^32 - 2 vertices cannot be indexed");
    } else if (after.face) {
      add_faces(*after.face, vertex.count, result.cloud, result.notes);
    }
    if (after.range_grid) add_range_grid(*after.range_grid, ply, vertex.count, result.cloud, result.notes);
  }
  return result;
}

namespace {

// A binary PLY stream's notes: its first (`how` the vertices are read), then the whole read's
// (read_ply), in its order: the vertex list properties skipped, the non-standard header lines,
// the colour; then that the elements after the vertices are not read.
std::vector<std::string> stream_notes(const PlyLayout& ply, const std::string& how, bool colour) {
  std::vector<std::string> notes{"PLY " + ply.format + ", " + std::to_string(ply.vertex().count) + " vertices (" + how + ")"};
  for (const auto& pr : ply.vertex().properties) {
    if (pr.is_list) notes.push_back("skipped the vertex list property '" + pr.name + "'");
  }
  if (ply.skipped_lines > 0) {
    notes.push_back("skipped " + std::to_string(ply.skipped_lines) + " non-standard header lines (obj_info and stray lines)");
  }
  if (colour) notes.push_back("vertex colours (red, green, blue) read as 8-bit RGB");
  if (ply.vertex_index + 1 < ply.elements.size()) {
    notes.push_back("elements after 'vertex' (" + ply.elements[ply.vertex_index + 1].name +
                    ", ...) not read: a streamed scan is taken as points");
  }
  return notes;
}

// A binary PLY read record block by record block (point_stream.hpp).
class PlyStream final : public PointStream {
 public:
  PlyStream(std::unique_ptr<ByteSource> src, const PlyLayout& ply, std::size_t offset)
      : src_(std::move(src)), name_(src_->name()), rec_(ply), total_(ply.vertex().count), before_(offset - ply.body) {
    notes_ = stream_notes(ply, "fixed-stride records streamed in chunks", rec_.colour);
    src_->seek(offset);
  }
  ~PlyStream() override = default;
  PlyStream(const PlyStream&) = delete;
  PlyStream& operator=(const PlyStream&) = delete;

  std::uint64_t total_points() const override { return total_; }
  const std::vector<std::string>& notes() const override { return notes_; }
  bool streamed() const override { return true; }

  bool next(Cloud& chunk, std::size_t max_points) override {
    chunk = Cloud();
    const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(std::max<std::size_t>(max_points, 1), total_ - done_));
    if (n == 0) return false;
    buffer_.resize(n * rec_.stride);
    const std::size_t bytes = src_->read(buffer_.data(), n * rec_.stride);
    const std::size_t got = bytes / rec_.stride;
    if (got != n && gz_) {
      // The data's size was unknown when opened: the bytes after the vertex offset are those read
      // so far, and the whole read's message says so (its header check, a byte a vertex at
      // least, first).
      const std::uint64_t vertex_bytes = done_ * rec_.stride + bytes;
      require_bytes_for_vertices(name_, total_, before_ + vertex_bytes);
      throw InputError(truncated_vertices(name_, total_, rec_.stride, vertex_bytes));
    }
    if (got != n) {  // checked against the file's size when opened: the file changed since
      throw InputError("load_cloud: " + name_ + ": truncated or unreadable after " + std::to_string(done_ + got) + " of " +
                       std::to_string(total_) + " vertices");
    }
    chunk.xyz.resize(3, static_cast<Eigen::Index>(n));
    if (rec_.colour) chunk.rgb.resize(3 * n);
    rec_.decode(buffer_.data(), n, chunk.xyz.data(), chunk.rgb.data());
    chunk.float32_xyz = float32_;
    done_ += n;
    if (done_ == total_) src_->drain();
    return true;
  }

  bool float32_ = false;
  bool gz_ = false;  ///< the data are gzip-compressed (their size unknown when opened)

 private:
  std::unique_ptr<ByteSource> src_;
  std::string name_;
  FixedRecords rec_;
  std::uint64_t total_ = 0, done_ = 0;
  std::uint64_t before_ = 0;  // data bytes between the header and the vertices
  std::vector<char> buffer_;
  std::vector<std::string> notes_;
};

// A binary PLY whose vertex element holds list properties (records of their own lengths), read
// in blocks of at least 1 MiB and walked record by record with the whole read's own
// record decoding (ListRecords, as read_binary_records): the same points, colour and errors (a
// negative list count names its vertex; data that end inside a vertex give the whole read's
// message), raised where the read reaches them; every later call fails too (StickyFailure). Memory: a
// block (1 MiB, or as much as one record needs: a list count past the data's end reads the rest
// of the data, doubling the block, before it fails, as the whole read held all of it) and one
// chunk's points. Since 2026-11-27 (until then read whole at every pass).
class ListPlyStream final : public PointStream {
 public:
  ListPlyStream(std::unique_ptr<ByteSource> src, const PlyLayout& ply, std::size_t offset)
      : src_(std::move(src)), name_(src_->name()), v_(ply.vertex()), rec_(v_, needs_swap(ply)), total_(v_.count), before_(offset - ply.body) {
    notes_ = stream_notes(ply, "records with list properties streamed in chunks", rec_.colour);
    src_->seek(offset);
  }
  ~ListPlyStream() override = default;
  ListPlyStream(const ListPlyStream&) = delete;
  ListPlyStream& operator=(const ListPlyStream&) = delete;

  std::uint64_t total_points() const override { return total_; }
  const std::vector<std::string>& notes() const override { return notes_; }
  bool streamed() const override { return true; }

  bool next(Cloud& chunk, std::size_t max_points) override {
    return sticky_.run(name_, chunk, [&] {
      const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(std::max<std::size_t>(max_points, 1), total_ - done_));
      if (n == 0) return false;
      chunk.xyz.resize(3, static_cast<Eigen::Index>(n));
      if (rec_.colour) chunk.rgb.resize(3 * n);
      for (std::size_t i = 0; i < n; ++i) {
        std::uint8_t* rgb = rec_.colour ? chunk.rgb.data() + 3 * i : nullptr;
        const auto decode = [&] { return rec_.decode(buf_.data() + at_, buf_.data() + buf_.size(), done_ + i, chunk.xyz.data() + 3 * i, rgb, name_); };
        const char* q = decode();
        while (q == nullptr && more()) q = decode();  // the record goes past the block: read more
        if (q == nullptr) {
          // The data end inside vertex done_ + i: under gzip their size is known only now, and
          // the whole read's header check comes first (for a plain file it ran when opened).
          require_bytes_for_vertices(name_, total_, before_ + read_);
          throw truncated_inside_vertex(name_, total_, done_ + i);
        }
        at_ = static_cast<std::size_t>(q - buf_.data());
      }
      chunk.float32_xyz = float32_;
      done_ += n;
      if (done_ == total_) src_->drain();
      return true;
    });
  }

  bool float32_ = false;

 private:
  // Drops the walked bytes and reads at least 1 MiB more (or as much again as a record left
  // unwalked needs); false at the data's end.
  bool more() {
    if (ended_) return false;
    buf_.erase(buf_.begin(), buf_.begin() + static_cast<std::ptrdiff_t>(at_));
    at_ = 0;
    const std::size_t old = buf_.size(), want = std::max<std::size_t>(std::size_t{1} << 20, old);
    buf_.resize(old + want);
    const std::size_t got = src_->read(buf_.data() + old, want);
    buf_.resize(old + got);
    read_ += got;
    ended_ = got < want;
    return got > 0;
  }

  std::unique_ptr<ByteSource> src_;
  std::string name_;
  PlyElement v_;
  ListRecords rec_;  // reads v_ (declared before it)
  std::uint64_t total_ = 0, done_ = 0;
  std::uint64_t before_ = 0;  // data bytes between the header and the vertices
  std::uint64_t read_ = 0;    // bytes read from the vertices' start
  std::vector<char> buf_;
  std::size_t at_ = 0;  // buf_[at_, size) not walked yet
  bool ended_ = false;
  StickyFailure sticky_;  // once next() failed, every later call fails too
  std::vector<std::string> notes_;
};

// An ASCII PLY read in blocks of lines (point_stream.hpp): AsciiVertexParser over FileLines
// from the first line after the header.
class AsciiPlyStream final : public LineStream {
 public:
  AsciiPlyStream(std::unique_ptr<ByteSource> src, PlyLayout ply) : LineStream(std::move(src)), ply_(std::move(ply)) {
    total_ = ply_.vertex().count;
    notes_.push_back("PLY ascii, " + std::to_string(total_) + " vertices (lines streamed in chunks)");
    if (ply_.vertex_index + 1 < ply_.elements.size()) {
      notes_.push_back("elements after 'vertex' (" + ply_.elements[ply_.vertex_index + 1].name +
                       ", ...) not read: a streamed scan is taken as points");
    }
    src_->seek(ply_.body);
    start_lines(false);
    parser_ = std::make_unique<AsciiVertexParser<FileLines>>(*lines_, ply_, name_);
    int float_axes = 0;
    const std::vector<int> axis_of = axes_of(ply_.vertex());
    for (std::size_t j = 0; j < ply_.vertex().properties.size(); ++j) {
      if (axis_of[j] >= 0 && ply_.vertex().properties[j].type == PlyType::kFloat32) ++float_axes;
    }
    float32_ = float_axes == 3;
  }

 private:
  void fill(std::size_t max) override {
    if (!parser_->read(max, xyz_, rgb_)) src_->drain();
  }
  void shape(Cloud& chunk) override { chunk.float32_xyz = float32_; }

  PlyLayout ply_;
  bool float32_ = false;
  std::unique_ptr<AsciiVertexParser<FileLines>> parser_;
};

}  // namespace

std::unique_ptr<PointStream> open_ply_stream(const std::filesystem::path& path, const std::string& name, bool points_only,
                                             bool gz) {
  std::unique_ptr<ByteSource> src;
  try {
    src = ByteSource::open(path, name, gz);
  } catch (const InputError&) {
    return nullptr;  // load_cloud's whole read says why
  }
  // The header: read until its "end_header" line (at most 16 MB): the first line whose first
  // word is end_header, as parse_ply_header decides; the word elsewhere (a comment "...
  // end_header ...") does not end it.
  std::string head;
  const std::size_t end_at = read_header_until_word(*src, "end_header", head, /*unterminated_last=*/false);
  // The data's size: the file's, or unknown under gzip (a short file then fails in next()).
  std::error_code ec;
  const std::uintmax_t file_size = gz ? std::numeric_limits<std::size_t>::max() / 2 : std::filesystem::file_size(path, ec);
  if (end_at == std::string::npos || ec || head.compare(0, 3, "ply") != 0) {
    return nullptr;  // not PLY as far as streaming goes: load_cloud's whole read says why
  }
  head.resize(end_at);
  PlyLayout ply = parse_ply_header(head, name, static_cast<std::size_t>(file_size));
  if (ply.format == "ascii") {
    // Lines: list properties anywhere are parsed or skipped line by line. A mesh is read whole
    // (its faces kept) unless taken as points.
    bool mesh = false;
    for (std::size_t i = ply.vertex_index + 1; !points_only && i < ply.elements.size(); ++i) mesh = mesh || ply.elements[i].name == "face";
    if (mesh) return nullptr;
    return std::make_unique<AsciiPlyStream>(std::move(src), std::move(ply));
  }
  // A mesh (a face element after the vertices) is read whole, so that its faces are kept.
  for (std::size_t i = ply.vertex_index + 1; !points_only && i < ply.elements.size(); ++i) {
    if (ply.elements[i].name == "face") return nullptr;
  }
  // The vertex records' offset: the elements before them skipped by stride, or walked record by
  // record from the source where they hold lists (streamed_vertex_offset, with the whole read's
  // errors); a size that overflows is no layout to stream (the whole read says what is wrong).
  bool lists_before = false;
  for (std::size_t i = 0; i < ply.vertex_index; ++i) lists_before = lists_before || ply.elements[i].has_list();
  std::size_t offset = ply.body;
  // Under gzip the elements before the vertices are walked too (a seek inflates them anyway),
  // so that data ending inside one fail with the whole read's words; so are a plain file's whose
  // strides pass its end.
  bool walk = lists_before || (gz && ply.vertex_index > 0);
  if (!walk) {  // fixed strides: summed
    for (std::size_t i = 0; i < ply.vertex_index; ++i) {
      std::size_t bytes = 0;
      if (__builtin_mul_overflow(ply.elements[i].stride(), ply.elements[i].count, &bytes) || __builtin_add_overflow(offset, bytes, &offset)) {
        return nullptr;
      }
    }
    walk = offset > file_size;
  }
  if (walk) {
    const std::uint64_t at = streamed_vertex_offset(*src, ply, name);
    if (at > std::numeric_limits<std::size_t>::max() / 2) return nullptr;
    offset = static_cast<std::size_t>(at);
  }
  const PlyElement& v = ply.vertex();
  int float_axes = 0;
  const std::vector<int> axis_of = axes_of(v);
  for (std::size_t j = 0; j < v.properties.size(); ++j) {
    if (axis_of[j] >= 0 && v.properties[j].type == PlyType::kFloat32) ++float_axes;
  }
  if (v.has_list()) {
    // Records of their own lengths: walked as they are read (ListPlyStream), a truncation found
    // where the read reaches it.
    auto stream = std::make_unique<ListPlyStream>(std::move(src), ply, offset);
    stream->float32_ = float_axes == 3;
    return stream;
  }
  std::size_t vertex_bytes = 0;
  if (__builtin_mul_overflow(v.stride(), v.count, &vertex_bytes)) return nullptr;
  const std::size_t have = file_size > offset ? static_cast<std::size_t>(file_size) - offset : 0;
  if (have < vertex_bytes) throw InputError(truncated_vertices(name, v.count, v.stride(), have));
  auto stream = std::make_unique<PlyStream>(std::move(src), ply, offset);
  stream->float32_ = float_axes == 3;
  stream->gz_ = gz;
  return stream;
}

}  // namespace hc::pipeline::detail
