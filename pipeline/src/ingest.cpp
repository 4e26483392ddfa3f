// Stage 1: reading scans. This file holds everything that does not need PCL headers: file
// reading, gzip decompression (zlib, in memory), the PLY header parser and direct PLY vertex
// readers, the PCD header check, the OBJ-vertex and XYZ-text parsers, the scanalyze .conf reader
// and the multi-view merge. PCD files, and PLYs whose vertex layout needs list parsing, are read
// by PCL in ingest_pcl.cpp.

#include "stage_util.hpp"
#include "hc/pipeline/ingest.hpp"

#include "hc/common/error.hpp"

#include <zlib.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cctype>
#include <charconv>
#include <chrono>
#include <cstring>
#include <exception>
#include <fstream>
#include <limits>
#include <sstream>
#include <string_view>
#include <system_error>
#include <thread>

namespace hc::pipeline {

namespace detail {
// Defined in ingest_pcl.cpp (the only ingest file that includes PCL headers).
Cloud read_ply_body_with_pcl(const std::string& ply_bytes, const std::string& display_name,
                             std::size_t expected_points);
Cloud read_pcd_with_pcl(const std::string& bytes, const std::filesystem::path& original_path,
                        bool from_memory, const std::string& display_name);
}  // namespace detail

namespace {

using detail::Clock;
using detail::seconds_since;

std::string quoted(const std::filesystem::path& p) {
  std::string s(1, '\'');  // built by appending: GCC 12 -O3 flags "'" + str + "'" (-Wrestrict)
  s += p.string();
  s += '\'';
  return s;
}

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

// ---------------------------------------------------------------------------------------------
// Whole-file reading and gzip.

std::string read_whole_file(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    throw InputError("load_cloud: file " + quoted(path) + " does not exist");
  }
  if (std::filesystem::is_directory(path, ec)) {
    throw InputError("load_cloud: " + quoted(path) + " is a directory, expected a scan file");
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError("load_cloud: cannot open " + quoted(path) + " for reading");
  in.seekg(0, std::ios::end);
  const std::streamoff size = in.tellg();
  if (size < 0) throw InputError("load_cloud: cannot determine the size of " + quoted(path));
  in.seekg(0, std::ios::beg);
  std::string bytes(static_cast<std::size_t>(size), '\0');
  if (size > 0 && !in.read(bytes.data(), size)) {
    throw InputError("load_cloud: read error on " + quoted(path));
  }
  if (bytes.empty()) throw InputError("load_cloud: file " + quoted(path) + " is empty (0 bytes)");
  return bytes;
}

// Inflates a gzip (or zlib) stream held in memory; concatenated gzip members are all inflated.
std::string gunzip(const std::string& packed, const std::filesystem::path& path) {
  z_stream zs{};
  // 15 + 32: maximum window, detect gzip or zlib header automatically.
  if (inflateInit2(&zs, 15 + 32) != Z_OK) {
    throw ResourceError("load_cloud: zlib could not initialise an inflate stream for " + quoted(path));
  }
  std::string out;
  // A gzip member ends with its uncompressed size mod 2^32 (ISIZE): size the output from it
  // when it is plausible, else guess twice the input; grow geometrically if needed.
  std::size_t guess = packed.size() * 2;
  if (packed.size() >= 18 && static_cast<unsigned char>(packed[0]) == 0x1f &&
      static_cast<unsigned char>(packed[1]) == 0x8b) {
    std::uint32_t isize = 0;
    for (std::size_t i = 1; i <= 4; ++i) isize = (isize << 8) | static_cast<unsigned char>(packed[packed.size() - i]);
    // Trusted only up to 16x the input (a corrupt trailer must not allocate gigabytes).
    if (isize >= packed.size() / 2 && isize / 16 <= packed.size()) guess = static_cast<std::size_t>(isize) + 1;
  }
  out.resize(std::max<std::size_t>(guess, 1 << 16));
  zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(packed.data()));
  std::size_t in_left = packed.size();
  std::size_t produced = 0;
  int rc = Z_OK;
  for (;;) {
    if (produced == out.size()) out.resize(out.size() * 2);
    const std::size_t in_chunk = std::min<std::size_t>(in_left, std::numeric_limits<uInt>::max());
    const std::size_t out_chunk = std::min<std::size_t>(out.size() - produced, std::numeric_limits<uInt>::max());
    zs.avail_in = static_cast<uInt>(in_chunk);
    zs.next_out = reinterpret_cast<Bytef*>(out.data() + produced);
    zs.avail_out = static_cast<uInt>(out_chunk);
    rc = inflate(&zs, Z_NO_FLUSH);
    in_left -= in_chunk - zs.avail_in;
    produced += out_chunk - zs.avail_out;
    if (rc == Z_STREAM_END) {
      if (in_left == 0) break;
      // Another gzip member follows (as `cat a.gz b.gz` produces).
      if (inflateReset(&zs) != Z_OK) break;
      continue;
    }
    if (rc == Z_BUF_ERROR && in_left == 0 && zs.avail_out != 0) break;  // input ended early
    if (rc != Z_OK && rc != Z_BUF_ERROR) break;
  }
  const std::string msg = zs.msg ? zs.msg : "";
  inflateEnd(&zs);
  if (rc != Z_STREAM_END) {
    if (rc == Z_BUF_ERROR || rc == Z_OK) {
      throw InputError("load_cloud: gzip data of " + quoted(path) + " is truncated (stream ended after " +
                       std::to_string(packed.size()) + " compressed bytes)");
    }
    throw InputError("load_cloud: " + quoted(path) + " is not valid gzip data" +
                     (msg.empty() ? std::string() : " (zlib: " + msg + ")"));
  }
  out.resize(produced);
  if (out.empty()) throw InputError("load_cloud: " + quoted(path) + " decompresses to 0 bytes");
  return out;
}

// ---------------------------------------------------------------------------------------------
// Number parsing shared by the text readers.

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f' || c == ','; }

// Parses one double starting at p (after skipping separators); advances p. false if no number.
// Parses one number (double or float) starting at p, after skipping separators; advances p.
// false if there is no number, it is out of range, or it runs into other characters ("1.5abc").
template <class T>
bool parse_number(const char*& p, const char* end, T& value) {
  while (p < end && is_space(*p)) ++p;
  if (p >= end) return false;
  const char* start = p;
  if (*start == '+') ++start;  // from_chars rejects a leading '+'
  const auto res = std::from_chars(start, end, value);
  if (res.ec != std::errc()) return false;
  if (res.ptr < end && !is_space(*res.ptr)) return false;
  p = res.ptr;
  return true;
}

bool parse_double(const char*& p, const char* end, double& value) { return parse_number(p, end, value); }

std::string_view first_token(const char* p, const char* end) {
  while (p < end && is_space(*p)) ++p;
  const char* q = p;
  while (q < end && !is_space(*q)) ++q;
  return {p, static_cast<std::size_t>(q - p)};
}

// Checks that [b, e) holds exactly `expected` numbers; returns a description of the first
// problem, or an empty string. (PCL's ASCII PLY and PCD readers accept a non-numeric token
// silently, so ASCII data is checked here before PCL parses it.)
std::string check_numeric_line(const char* b, const char* e, std::size_t expected) {
  std::size_t found = 0;
  const char* p = b;
  for (;;) {
    while (p < e && is_space(*p)) ++p;
    if (p >= e) break;
    const char* t = p;
    double v = 0.0;
    if (!parse_double(p, e, v)) {
      return "'" + std::string(first_token(t, e).substr(0, 40)) + "' is not a number";
    }
    ++found;
  }
  if (found != expected) {
    return std::to_string(found) + " values where the header declares " + std::to_string(expected);
  }
  return {};
}

// Iterates over the lines of a buffer: f(line_begin, line_end, line_number) with '\n' removed.
template <class F>
void for_each_line(const std::string& text, F&& f) {
  const char* p = text.data();
  const char* const end = p + text.size();
  std::size_t line_no = 0;
  while (p < end) {
    const void* nl = std::memchr(p, '\n', static_cast<std::size_t>(end - p));
    const char* e = nl ? static_cast<const char*>(nl) : end;
    ++line_no;
    f(p, e, line_no);
    p = nl ? e + 1 : end;
  }
}

Cloud cloud_from(std::vector<double>&& xyz) {
  Cloud c;
  c.xyz = Eigen::Map<const Eigen::Matrix3Xd>(xyz.data(), 3, static_cast<Eigen::Index>(xyz.size() / 3));
  return c;
}

// ---------------------------------------------------------------------------------------------
// XYZ text: x y z per line, extra columns ignored, '#' comments and blank lines skipped.

Cloud parse_xyz_text(const std::string& text, const std::string& name) {
  std::vector<double> xyz;
  xyz.reserve(text.size() / 16);
  for_each_line(text, [&](const char* b, const char* e, std::size_t line_no) {
    if (const void* hash = std::memchr(b, '#', static_cast<std::size_t>(e - b))) e = static_cast<const char*>(hash);
    const char* p = b;
    while (p < e && is_space(*p)) ++p;
    if (p == e) return;  // blank or comment-only line
    for (int a = 0; a < 3; ++a) {
      double v = 0.0;
      if (!parse_double(p, e, v)) {
        const std::string_view tok = first_token(p, e);
        throw InputError("load_cloud: " + name + " line " + std::to_string(line_no) + ": " +
                         (tok.empty() ? std::string("expected 3 numbers (x y z), found only ") + std::to_string(a)
                                      : "'" + std::string(tok.substr(0, 40)) + "' is not a number (expected x y z)"));
      }
      xyz.push_back(v);
    }
  });
  if (xyz.empty()) throw InputError("load_cloud: " + name + " holds no points (no 'x y z' line)");
  return cloud_from(std::move(xyz));
}

// ---------------------------------------------------------------------------------------------
// OBJ: only `v x y z [w]` lines; everything else (vn, vt, f, g, usemtl, ...) is ignored.
// PCL's OBJReader stores x, y, z as float32; this keeps the text's double precision.

Cloud parse_obj_vertices(const std::string& text, const std::string& name) {
  std::vector<double> xyz;
  xyz.reserve(text.size() / 24);
  for_each_line(text, [&](const char* b, const char* e, std::size_t line_no) {
    const char* p = b;
    while (p < e && (*p == ' ' || *p == '\t')) ++p;
    if (e - p < 2 || p[0] != 'v' || (p[1] != ' ' && p[1] != '\t')) return;
    p += 2;
    for (int a = 0; a < 3; ++a) {
      double v = 0.0;
      if (!parse_double(p, e, v)) {
        const std::string_view tok = first_token(p, e);
        throw InputError("load_cloud: " + name + " line " + std::to_string(line_no) + ": malformed vertex line (" +
                         (tok.empty() ? std::string("fewer than 3 coordinates")
                                      : "'" + std::string(tok.substr(0, 40)) + "' is not a number") +
                         "), expected 'v x y z'");
      }
      xyz.push_back(v);
    }
  });
  if (xyz.empty()) throw InputError("load_cloud: " + name + " holds no vertices ('v x y z' lines)");
  return cloud_from(std::move(xyz));
}

// ---------------------------------------------------------------------------------------------
// PLY. The header is parsed here: `obj_info` lines (Stanford range scans) and stray lines such
// as `bye` are skipped, and elements after `vertex` (range_grid, face) are ignored. Declared
// counts are checked against the bytes or lines actually present.
// Vertex data of scalar properties (the common case) is read directly, in each property's own
// type: binary records by a fixed-stride copy (about 20x faster than PCL's PLY reader on the
// 1.1 M-point Buddha), ASCII lines with std::from_chars (PCL's ASCII reader accepts a
// non-numeric token silently and is about 10x slower). tests/pipeline/ingest_test.cpp checks
// both against PCL's reader. Other layouts (list properties in or before the vertex element)
// go to PCL with a clean header: PCL warns about unknown header lines and turns a `range_grid`
// element into an organised cloud with NaN cells.

enum class PlyType { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64, kList };

struct PlyProperty {
  std::string line;  // the header line as written (re-emitted verbatim)
  std::string name;
  PlyType type = PlyType::kList;
  int size_bytes = 0;  // scalar size (0 for lists)
};

struct PlyElement {
  std::string name;
  std::size_t count = 0;
  std::vector<PlyProperty> properties;
  bool has_list() const {
    return std::any_of(properties.begin(), properties.end(), [](const PlyProperty& p) { return p.type == PlyType::kList; });
  }
  std::size_t stride() const {
    std::size_t s = 0;
    for (const auto& p : properties) s += static_cast<std::size_t>(p.size_bytes);
    return s;
  }
};

bool parse_ply_type(const std::string& t, PlyType& type, int& size) {
  static const std::pair<const char*, std::pair<PlyType, int>> kTypes[] = {
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
  std::vector<std::string> comments;
  std::size_t vertex_index = 0;
  std::size_t body = 0;         // offset of the first data byte
  std::size_t header_lines = 0;  // line number of end_header
  std::size_t skipped_lines = 0;
  const PlyElement& vertex() const { return elements[vertex_index]; }
};

/// Header line reader shared by the PLY and PCD header parsers: copies the line that starts at
/// `pos` into `line` (without its '\n' and a trailing '\r') and moves `pos` past it. Returns
/// false when no line is left; an unterminated last line counts only if accept_unterminated.
bool next_line(const std::string& raw, std::size_t& pos, std::string& line, bool accept_unterminated) {
  if (pos >= raw.size()) return false;
  std::size_t nl = raw.find('\n', pos);
  if (nl == std::string::npos) {
    if (!accept_unterminated) return false;
    nl = raw.size();
  }
  line.assign(raw, pos, nl - pos);
  pos = nl + 1;
  if (!line.empty() && line.back() == '\r') line.pop_back();
  return true;
}

PlyLayout parse_ply_header(const std::string& raw, const std::string& name) {
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
    if (kw == "format") {
      std::string version;
      ls >> out.format >> version;
      if (out.format != "ascii" && out.format != "binary_little_endian" && out.format != "binary_big_endian") {
        throw fail("header line " + std::to_string(line_no) + ": unknown PLY format '" + out.format + "'");
      }
    } else if (kw == "comment") {
      out.comments.push_back(line);
    } else if (kw == "element") {
      PlyElement el;
      long long count = -1;
      ls >> el.name >> count;
      if (!ls || count < 0) throw fail("header line " + std::to_string(line_no) + ": malformed '" + line + "'");
      el.count = static_cast<std::size_t>(count);
      out.elements.push_back(std::move(el));
    } else if (kw == "property") {
      if (out.elements.empty()) throw fail("header line " + std::to_string(line_no) + ": property before any element");
      PlyProperty pr;
      pr.line = line;
      std::string type;
      ls >> type;
      if (type == "list") {
        std::string count_type, item_type;
        ls >> count_type >> item_type >> pr.name;
        pr.type = PlyType::kList;
      } else {
        ls >> pr.name;
        if (!parse_ply_type(type, pr.type, pr.size_bytes)) {
          throw fail("header line " + std::to_string(line_no) + ": unknown property type '" + type + "'");
        }
      }
      if (pr.name.empty()) throw fail("header line " + std::to_string(line_no) + ": malformed '" + line + "'");
      out.elements.back().properties.push_back(std::move(pr));
    } else {
      // obj_info (Stanford range scans), stray lines such as `bye`, blank lines: not data.
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
  if (vertex.count > raw.size() - out.body) {  // every vertex takes at least one byte
    throw fail("truncated: the header declares " + std::to_string(vertex.count) + " vertices but only " +
               std::to_string(raw.size() - out.body) + " bytes follow it");
  }
  for (const char* axis : {"x", "y", "z"}) {
    const bool found = std::any_of(vertex.properties.begin(), vertex.properties.end(),
                                   [&](const PlyProperty& p) { return p.name == axis && p.type != PlyType::kList; });
    if (!found) throw fail(std::string("the vertex element has no '") + axis + "' property");
  }
  return out;
}

// Offset of the vertex data in a binary body, or npos when an earlier element has lists.
std::size_t binary_vertex_offset(const PlyLayout& ply) {
  std::size_t off = ply.body;
  for (std::size_t i = 0; i < ply.vertex_index; ++i) {
    if (ply.elements[i].has_list()) return std::string::npos;
    off += ply.elements[i].stride() * ply.elements[i].count;
  }
  return off;
}

void check_binary_length(const std::string& raw, const PlyLayout& ply, std::size_t vertex_offset,
                         const std::string& name) {
  const PlyElement& v = ply.vertex();
  const std::size_t stride = v.stride();
  const std::size_t have = raw.size() > vertex_offset ? raw.size() - vertex_offset : 0;
  if (have < stride * v.count) {
    throw InputError("load_cloud: " + name + ": truncated: the header declares " + std::to_string(v.count) +
                     " vertices (" + std::to_string(stride * v.count) + " bytes) but only " + std::to_string(have) +
                     " bytes of vertex data follow (" + std::to_string(have / stride) + " whole vertices)");
  }
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
    case PlyType::kList: break;
  }
  return std::numeric_limits<double>::quiet_NaN();
}

// Direct read of binary vertex records (scalar properties only).
Cloud read_binary_ply_vertices(const std::string& raw, const PlyLayout& ply, std::size_t offset) {
  const PlyElement& v = ply.vertex();
  const std::size_t stride = v.stride();
  std::size_t field_off[3] = {0, 0, 0};
  PlyType field_type[3] = {PlyType::kFloat32, PlyType::kFloat32, PlyType::kFloat32};
  std::size_t at = 0;
  for (const auto& pr : v.properties) {
    for (int a = 0; a < 3; ++a) {
      if (pr.name == std::string(1, static_cast<char>('x' + a))) {
        field_off[a] = at;
        field_type[a] = pr.type;
      }
    }
    at += static_cast<std::size_t>(pr.size_bytes);
  }
  const bool swap = (ply.format == "binary_big_endian") != (std::endian::native == std::endian::big);
  Cloud cloud;
  cloud.xyz.resize(3, static_cast<Eigen::Index>(v.count));
  double* out = cloud.xyz.data();
  const char* base = raw.data() + offset;
  const bool plain_float = !swap && field_type[0] == PlyType::kFloat32 && field_type[1] == PlyType::kFloat32 &&
                           field_type[2] == PlyType::kFloat32;
  for (std::size_t i = 0; i < v.count; ++i) {
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
  return cloud;
}

// Direct read of ASCII vertex lines (one vertex per line, scalar properties): each number is
// parsed in the property's own type (float32 properties give the float nearest to the text,
// as PCL's reader does), and any non-numeric token is an error naming the line.
Cloud read_ascii_ply_vertices(const std::string& raw, const PlyLayout& ply, const std::string& name) {
  auto fail = [&](const std::string& what) -> InputError {
    return InputError("load_cloud: " + name + ": " + what);
  };
  const PlyElement& v = ply.vertex();
  std::size_t skip = 0;
  for (std::size_t i = 0; i < ply.vertex_index; ++i) skip += ply.elements[i].count;
  int axis_of[64];
  const std::size_t nprop = v.properties.size();
  if (nprop > 64) throw fail("the vertex element has more than 64 properties");
  for (std::size_t j = 0; j < nprop; ++j) {
    const std::string& n = v.properties[j].name;
    axis_of[j] = n == "x" ? 0 : n == "y" ? 1 : n == "z" ? 2 : -1;
  }
  Cloud cloud;
  cloud.xyz.resize(3, static_cast<Eigen::Index>(v.count));
  double* out = cloud.xyz.data();
  const char* p = raw.data() + ply.body;
  const char* const end = raw.data() + raw.size();
  std::size_t line = 0;
  std::size_t vertex = 0;
  while (vertex < v.count && p < end) {
    const void* nl = std::memchr(p, '\n', static_cast<std::size_t>(end - p));
    const char* e = nl ? static_cast<const char*>(nl) : end;
    if (line >= skip) {
      const char* q = p;
      for (std::size_t j = 0; j < nprop; ++j) {
        const char* t = q;
        bool ok;
        double value = 0.0;
        if (v.properties[j].type == PlyType::kFloat32) {
          float f = 0.0f;
          ok = parse_number(q, e, f);
          value = static_cast<double>(f);
        } else {
          ok = parse_number(q, e, value);
        }
        if (!ok) {
          const std::string_view tok = first_token(t, e);
          throw fail("line " + std::to_string(ply.header_lines + line + 1) + " (vertex " + std::to_string(vertex) +
                     "): " +
                     (tok.empty() ? std::to_string(j) + " values where the header declares " + std::to_string(nprop)
                                  : "'" + std::string(tok.substr(0, 40)) + "' is not a number"));
        }
        if (axis_of[j] >= 0) out[3 * vertex + static_cast<std::size_t>(axis_of[j])] = value;
      }
      while (q < e && is_space(*q)) ++q;
      if (q != e) {
        throw fail("line " + std::to_string(ply.header_lines + line + 1) + " (vertex " + std::to_string(vertex) +
                   "): more values than the " + std::to_string(nprop) + " the header declares");
      }
      ++vertex;
    }
    ++line;
    p = nl ? e + 1 : end;
  }
  if (vertex < v.count) {
    throw fail("truncated: the header declares " + std::to_string(v.count) + " vertices but only " +
               std::to_string(vertex) + " vertex lines follow");
  }
  return cloud;
}

// Clean header plus body cut after the vertex element, for PCL. Also checks the ASCII vertex
// lines (count and numbers: PCL's ASCII reader accepts a non-numeric token silently).
std::string sanitised_ply_for_pcl(const std::string& raw, const PlyLayout& ply, const std::string& name,
                                  std::vector<std::string>& dropped) {
  auto fail = [&](const std::string& what) -> InputError {
    return InputError("load_cloud: " + name + ": " + what);
  };
  const PlyElement& vertex = ply.vertex();
  std::size_t cut = raw.size();
  bool keep_all_elements = false;
  if (ply.format == "ascii") {
    // One line per element instance (PCL reads it so too).
    std::size_t lines_needed = 0;
    for (std::size_t i = 0; i <= ply.vertex_index; ++i) lines_needed += ply.elements[i].count;
    const std::size_t first_vertex_line = lines_needed - vertex.count;
    const bool check = !vertex.has_list();
    std::size_t p = ply.body;
    std::size_t lines = 0;
    while (lines < lines_needed && p < raw.size()) {
      const void* nl = std::memchr(raw.data() + p, '\n', raw.size() - p);
      const std::size_t e = nl ? static_cast<std::size_t>(static_cast<const char*>(nl) - raw.data()) : raw.size();
      if (check && lines >= first_vertex_line) {
        const std::string problem = check_numeric_line(raw.data() + p, raw.data() + e, vertex.properties.size());
        if (!problem.empty()) {
          throw fail("line " + std::to_string(ply.header_lines + lines + 1) + " (vertex " +
                     std::to_string(lines - first_vertex_line) + "): " + problem);
        }
      }
      p = e < raw.size() ? e + 1 : raw.size();
      ++lines;
    }
    if (lines < lines_needed) {
      throw fail("truncated: the header declares " + std::to_string(vertex.count) + " vertices but only " +
                 std::to_string(lines > first_vertex_line ? lines - first_vertex_line : 0) + " vertex lines follow");
    }
    cut = p;
  } else {
    const std::size_t off = binary_vertex_offset(ply);
    if (off == std::string::npos || vertex.has_list()) {
      keep_all_elements = true;  // sizes unknown without parsing the lists: let PCL do it all
    } else {
      check_binary_length(raw, ply, off, name);
      cut = off + vertex.stride() * vertex.count;
    }
  }
  std::string header = "ply\nformat " + ply.format + " 1.0\n";
  for (const auto& c : ply.comments) header += c + "\n";
  const std::size_t last = keep_all_elements ? ply.elements.size() - 1 : ply.vertex_index;
  for (std::size_t i = 0; i < ply.elements.size(); ++i) {
    if (i > last) {
      dropped.push_back(ply.elements[i].name);
      continue;
    }
    header += "element " + ply.elements[i].name + " " + std::to_string(ply.elements[i].count) + "\n";
    for (const auto& pr : ply.elements[i].properties) header += pr.line + "\n";
  }
  header += "end_header\n";
  std::string out;
  out.reserve(header.size() + (cut - ply.body));
  out = header;
  if (ply.format == "ascii") {
    // Drop carriage returns (CRLF files): PCL's ASCII reader expects '\n' line ends.
    for (std::size_t i = ply.body; i < cut; ++i) {
      if (raw[i] != '\r') out.push_back(raw[i]);
    }
  } else {
    out.append(raw, ply.body, cut - ply.body);
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// PCD header check. PCL's PCDReader crashes on some malformed files (a garbage file without
// FIELDS, for example), so the header and the amount of data are checked here first.

void validate_pcd(const std::string& raw, const std::string& name) {
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
    point_bytes += static_cast<std::size_t>(std::stoi(z)) * static_cast<std::size_t>(c);
    values += static_cast<std::size_t>(c);
  }
  if (width < 0) throw fail("the PCD header has no WIDTH line");
  const auto bytes = static_cast<long long>(raw.size());
  if (width > bytes || height > bytes || points > bytes) {  // every point takes at least one byte
    throw fail("truncated: the header declares WIDTH " + std::to_string(width) + ", HEIGHT " + std::to_string(height) +
               (points >= 0 ? ", POINTS " + std::to_string(points) : std::string()) + " in a file of " +
               std::to_string(raw.size()) + " bytes");
  }
  if (points < 0) points = width * height;
  if (points != width * height) {
    throw fail("the PCD header declares POINTS " + std::to_string(points) + " but WIDTH x HEIGHT = " +
               std::to_string(width * height));
  }
  if (points == 0) throw fail("the PCD header declares 0 points");
  const auto n = static_cast<std::size_t>(points);
  const std::size_t have = pos < raw.size() ? raw.size() - pos : 0;
  if (data == "ascii") {
    std::size_t lines = 0;
    std::size_t p = pos;
    while (p < raw.size() && lines < n) {
      std::size_t nl = raw.find('\n', p);
      if (nl == std::string::npos) nl = raw.size();
      std::size_t tokens = 0;
      bool in = false;
      for (std::size_t i = p; i < nl; ++i) {
        const bool sp = is_space(raw[i]);
        if (!sp && !in) ++tokens;
        in = !sp;
      }
      if (tokens > 0) {
        ++lines;
        const std::string problem = check_numeric_line(raw.data() + p, raw.data() + nl, values);
        if (!problem.empty()) throw fail("data line " + std::to_string(lines) + ": " + problem);
      }
      p = nl + 1;
    }
    if (lines < n) {
      throw fail("truncated: the header declares " + std::to_string(n) + " points but only " + std::to_string(lines) +
                 " data lines follow");
    }
  } else if (data == "binary") {
    if (have < n * point_bytes) {
      throw fail("truncated: the header declares " + std::to_string(n) + " points (" + std::to_string(n * point_bytes) +
                 " bytes) but only " + std::to_string(have) + " bytes follow");
    }
  } else if (data == "binary_compressed") {
    std::uint32_t sizes_lz[2] = {0, 0};
    if (have < 8) throw fail("truncated: no compressed block after the header");
    std::memcpy(sizes_lz, raw.data() + pos, 8);
    if (sizes_lz[1] != n * point_bytes) {
      throw fail("the compressed block unpacks to " + std::to_string(sizes_lz[1]) + " bytes, expected " +
                 std::to_string(n * point_bytes));
    }
    if (have - 8 < sizes_lz[0]) {
      throw fail("truncated: the compressed block needs " + std::to_string(sizes_lz[0]) + " bytes, " +
                 std::to_string(have - 8) + " follow");
    }
  } else {
    throw fail("unknown PCD DATA type '" + data + "' (expected ascii, binary or binary_compressed)");
  }
}

bool ends_with(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

std::string strip_gz(const std::string& file_name) {
  return ends_with(lower(file_name), ".gz") ? file_name.substr(0, file_name.size() - 3) : file_name;
}

}  // namespace

StageResult<Cloud> load_cloud(const std::filesystem::path& path) {
  const auto t0 = Clock::now();
  StageReport report;
  report.stage = "load";
  const std::string name = quoted(path);

  std::string file_name = lower(path.filename().string());
  const bool gz = ends_with(file_name, ".gz");
  if (gz) file_name.resize(file_name.size() - 3);
  const std::string ext = std::filesystem::path(file_name).extension().string();
  const bool known = ext == ".ply" || ext == ".pcd" || ext == ".obj" || ext == ".xyz" || ext == ".txt";
  if (!known) {
    throw InputError("load_cloud: " + name + " has an unknown extension '" + ext +
                     "' (expected .ply, .pcd, .obj, .xyz or .txt, optionally followed by .gz)");
  }

  std::string bytes = read_whole_file(path);
  report.figure("file_bytes", static_cast<double>(bytes.size()));
  if (gz) {
    const auto tz = Clock::now();
    bytes = gunzip(bytes, path);
    report.figure("decompressed_bytes", static_cast<double>(bytes.size()));
    report.figure("decompress_s", seconds_since(tz));
  }

  const auto tp = Clock::now();
  Cloud cloud;
  if (ext == ".ply") {
    const PlyLayout ply = parse_ply_header(bytes, name);
    std::vector<std::string> dropped;
    const std::size_t offset = ply.format == "ascii" ? std::string::npos : binary_vertex_offset(ply);
    const bool ascii_direct = ply.format == "ascii" && !ply.vertex().has_list();
    if (ascii_direct) {
      cloud = read_ascii_ply_vertices(bytes, ply, name);
      for (std::size_t i = ply.vertex_index + 1; i < ply.elements.size(); ++i) dropped.push_back(ply.elements[i].name);
      report.notes.push_back("PLY ascii, " + std::to_string(ply.vertex().count) + " vertices (lines parsed directly)");
    } else if (offset != std::string::npos && !ply.vertex().has_list()) {
      check_binary_length(bytes, ply, offset, name);
      cloud = read_binary_ply_vertices(bytes, ply, offset);
      for (std::size_t i = ply.vertex_index + 1; i < ply.elements.size(); ++i) dropped.push_back(ply.elements[i].name);
      report.notes.push_back("PLY " + ply.format + ", " + std::to_string(ply.vertex().count) +
                             " vertices (fixed-stride records read directly)");
    } else {
      const std::string clean = sanitised_ply_for_pcl(bytes, ply, name, dropped);
      bytes.clear();
      bytes.shrink_to_fit();
      cloud = detail::read_ply_body_with_pcl(clean, name, ply.vertex().count);
      report.notes.push_back("PLY " + ply.format + ", " + std::to_string(ply.vertex().count) +
                             " vertices (read by PCL)");
    }
    if (ply.skipped_lines > 0) {
      report.notes.push_back("skipped " + std::to_string(ply.skipped_lines) +
                             " non-standard header lines (obj_info and stray lines)");
    }
    for (const auto& e : dropped) report.notes.push_back("ignored PLY element '" + e + "'");
  } else if (ext == ".pcd") {
    validate_pcd(bytes, name);
    cloud = detail::read_pcd_with_pcl(bytes, path, gz, name);
    report.notes.push_back("PCD");
  } else if (ext == ".obj") {
    cloud = parse_obj_vertices(bytes, name);
    report.notes.push_back("OBJ vertex lines");
  } else {
    cloud = parse_xyz_text(bytes, name);
    report.notes.push_back("XYZ text");
  }
  report.figure("parse_s", seconds_since(tp));
  if (cloud.size() == 0) throw InputError("load_cloud: " + name + " holds no points");
  report.count_in = cloud.size();
  report.count_out = cloud.size();
  report.seconds = seconds_since(t0);
  return {std::move(cloud), std::move(report)};
}

Eigen::Affine3d ScanPose::scan_to_world() const {
  Eigen::Affine3d m = Eigen::Affine3d::Identity();
  m.linear() = rotation.normalized().toRotationMatrix().transpose();
  m.translation() = translation;
  return m;
}

std::vector<ScanPose> read_scanalyze_conf(const std::filesystem::path& conf_path) {
  const std::string name = quoted(conf_path);
  std::error_code ec;
  if (!std::filesystem::exists(conf_path, ec)) {
    throw InputError("read_scanalyze_conf: file " + name + " does not exist");
  }
  std::ifstream in(conf_path);
  if (!in) throw InputError("read_scanalyze_conf: cannot open " + name);
  std::vector<ScanPose> poses;
  std::string line;
  std::size_t line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ls(line);
    std::string kw;
    if (!(ls >> kw) || kw[0] == '#') continue;
    if (kw == "camera" || kw == "mesh") continue;
    const std::string where = "read_scanalyze_conf: " + name + " line " + std::to_string(line_no) + ": ";
    if (kw != "bmesh") {
      throw InputError(where + "unknown keyword '" + kw + "' (expected bmesh, mesh or camera)");
    }
    ScanPose pose;
    std::vector<std::string> tok;
    std::string t;
    ls >> pose.file;
    while (ls >> t) tok.push_back(t);
    if (pose.file.empty() || tok.size() != 7) {
      throw InputError(where + "malformed bmesh line '" + line + "' (expected 'bmesh FILE tx ty tz qx qy qz qw')");
    }
    double v[7];
    for (int i = 0; i < 7; ++i) {
      const char* p = tok[static_cast<std::size_t>(i)].data();
      const char* e = p + tok[static_cast<std::size_t>(i)].size();
      if (!parse_double(p, e, v[i]) || p != e || !std::isfinite(v[i])) {
        throw InputError(where + "malformed bmesh line: '" + tok[static_cast<std::size_t>(i)] +
                         "' is not a finite number (expected 'bmesh FILE tx ty tz qx qy qz qw')");
      }
    }
    pose.translation = Eigen::Vector3d(v[0], v[1], v[2]);
    const Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);  // scanalyze writes w last
    const double norm = q.norm();
    if (std::abs(norm - 1.0) > 1e-3) {
      throw InputError(where + "the quaternion (" + tok[3] + ", " + tok[4] + ", " + tok[5] + ", " + tok[6] +
                       ") has norm " + std::to_string(norm) + ", expected a unit quaternion");
    }
    pose.rotation = q.normalized();
    poses.push_back(std::move(pose));
  }
  if (poses.empty()) throw InputError("read_scanalyze_conf: " + name + " has no 'bmesh' line");
  return poses;
}

StageResult<Cloud> load_and_merge_scans(const std::vector<std::filesystem::path>& scans,
                                        const std::filesystem::path& conf_path) {
  const auto t0 = Clock::now();
  if (scans.empty()) throw InputError("load_and_merge_scans: no scan files given (conf " + quoted(conf_path) + ")");
  if (scans.size() > std::numeric_limits<std::uint16_t>::max()) {
    throw InputError("load_and_merge_scans: " + std::to_string(scans.size()) + " scans given, at most 65535 supported");
  }
  const std::vector<ScanPose> poses = read_scanalyze_conf(conf_path);
  StageReport report;
  report.stage = "load";

  // Resolve every pose before reading any scan, so a missing pose fails fast.
  std::vector<const ScanPose*> matched;
  for (const auto& scan : scans) {
    const std::string want = strip_gz(scan.filename().string());
    const ScanPose* found = nullptr;
    for (const auto& pose : poses) {
      if (strip_gz(std::filesystem::path(pose.file).filename().string()) == want) {
        found = &pose;
        break;
      }
    }
    if (!found) {
      throw InputError("load_and_merge_scans: scan " + quoted(scan) + " has no bmesh line named '" + want +
                       "' in " + quoted(conf_path));
    }
    matched.push_back(found);
  }

  // Scans are read and moved into the common frame on two threads; the first error (in scan
  // order) is rethrown.
  std::vector<Cloud> parts(scans.size());
  std::vector<std::exception_ptr> errors(scans.size());
  std::atomic<std::size_t> next{0};
  auto worker = [&] {
    for (std::size_t i; (i = next.fetch_add(1)) < scans.size();) {
      try {
        Cloud c = load_cloud(scans[i]).value;
        const Eigen::Affine3d m = matched[i]->scan_to_world();
        c.xyz = (m.linear() * c.xyz).colwise() + m.translation();
        parts[i] = std::move(c);
      } catch (...) {
        errors[i] = std::current_exception();
      }
    }
  };
  {
    std::thread helper;
    if (scans.size() > 1) helper = std::thread(worker);
    worker();
    if (helper.joinable()) helper.join();
  }
  for (const auto& e : errors) {
    if (e) std::rethrow_exception(e);
  }
  std::size_t total = 0;
  for (std::size_t i = 0; i < scans.size(); ++i) {
    total += parts[i].size();
    report.notes.push_back(scans[i].filename().string() + ": " + std::to_string(parts[i].size()) + " points");
  }

  Cloud merged;
  merged.xyz.resize(3, static_cast<Eigen::Index>(total));
  merged.scan_id.resize(total);
  Eigen::Index at = 0;
  for (std::size_t i = 0; i < parts.size(); ++i) {
    const Eigen::Index n = parts[i].xyz.cols();
    merged.xyz.middleCols(at, n) = parts[i].xyz;
    std::fill_n(merged.scan_id.begin() + at, n, static_cast<std::uint16_t>(i));
    at += n;
  }
  report.figure("scans", static_cast<double>(scans.size()));
  report.count_in = total;
  report.count_out = total;
  report.seconds = seconds_since(t0);
  return {std::move(merged), std::move(report)};
}

}  // namespace hc::pipeline
