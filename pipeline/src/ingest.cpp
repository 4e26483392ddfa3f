// Stage 1: reading scans. This file holds everything that does not need PCL headers: file
// reading, gzip decompression (zlib), the PLY header sanitiser, the OBJ-vertex and XYZ-text
// parsers, the scanalyze .conf reader and the multi-view merge. PLY and PCD bodies are parsed by
// PCL in ingest_pcl.cpp.

#include "hc/pipeline/ingest.hpp"

#include "hc/common/error.hpp"

#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <chrono>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>
#include <string_view>
#include <system_error>

namespace hc::pipeline {

namespace detail {
// Defined in ingest_pcl.cpp (the only ingest file that includes PCL headers).
Cloud read_ply_body_with_pcl(const std::string& ply_bytes, const std::string& display_name,
                             std::size_t expected_points);
Cloud read_pcd_with_pcl(const std::string& bytes, const std::filesystem::path& original_path,
                        bool from_memory, const std::string& display_name);
}  // namespace detail

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

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
  // Typical compression ratios of scans are 1.2x to 4x; grow geometrically.
  out.resize(std::max<std::size_t>(packed.size() * 2, 1 << 16));
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
bool parse_double(const char*& p, const char* end, double& value) {
  while (p < end && is_space(*p)) ++p;
  if (p >= end) return false;
  const char* start = p;
  if (*start == '+') ++start;  // from_chars rejects a leading '+'
  const auto res = std::from_chars(start, end, value);
  if (res.ec != std::errc()) return false;  // not a number, or beyond the range of double
  if (res.ptr < end && !is_space(*res.ptr)) return false;  // "1.5abc"
  p = res.ptr;
  return true;
}

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
// PLY header sanitiser. PCL's PLY parser warns about (and skips) unknown header lines, and turns
// a `range_grid` element into an organised cloud with NaN cells. We rebuild a clean header that
// keeps only the elements up to and including `vertex`, cut the body right after the vertex
// data, and check the declared counts against the bytes or lines that are actually there.

struct PlyProperty {
  std::string line;  // the header line as written (re-emitted verbatim)
  std::string name;
  bool is_list = false;
  int size_bytes = 0;  // scalar size (0 for lists)
};

struct PlyElement {
  std::string name;
  std::size_t count = 0;
  std::vector<PlyProperty> properties;
};

int ply_type_size(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "int32" || t == "uint32" || t == "float" || t == "float32") return 4;
  if (t == "double" || t == "float64") return 8;
  return 0;
}

struct SanitisedPly {
  std::string bytes;             // clean header + body cut after the vertex element
  std::size_t vertex_count = 0;  // as declared
  std::string format;            // ascii, binary_little_endian, binary_big_endian
  std::size_t skipped_lines = 0;
  std::vector<std::string> dropped_elements;
};

SanitisedPly sanitise_ply(const std::string& raw, const std::string& name) {
  auto fail = [&](const std::string& what) -> InputError {
    return InputError("load_cloud: " + name + ": " + what);
  };
  if (raw.size() < 4 || raw.compare(0, 3, "ply") != 0 || (raw[3] != '\n' && raw[3] != '\r')) {
    throw fail("not a PLY file (the first line is not 'ply')");
  }
  SanitisedPly out;
  std::vector<PlyElement> elements;
  std::vector<std::string> comments;
  std::size_t pos = raw.find('\n') + 1;
  std::size_t line_no = 1;
  bool ended = false;
  while (pos < raw.size()) {
    std::size_t nl = raw.find('\n', pos);
    if (nl == std::string::npos) break;
    std::string line = raw.substr(pos, nl - pos);
    pos = nl + 1;
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
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
      comments.push_back(line);
    } else if (kw == "element") {
      PlyElement el;
      long long count = -1;
      ls >> el.name >> count;
      if (!ls || count < 0) throw fail("header line " + std::to_string(line_no) + ": malformed '" + line + "'");
      el.count = static_cast<std::size_t>(count);
      elements.push_back(std::move(el));
    } else if (kw == "property") {
      if (elements.empty()) throw fail("header line " + std::to_string(line_no) + ": property before any element");
      PlyProperty pr;
      pr.line = line;
      std::string type;
      ls >> type;
      if (type == "list") {
        std::string count_type, item_type;
        ls >> count_type >> item_type >> pr.name;
        pr.is_list = true;
      } else {
        ls >> pr.name;
        pr.size_bytes = ply_type_size(type);
        if (pr.size_bytes == 0) {
          throw fail("header line " + std::to_string(line_no) + ": unknown property type '" + type + "'");
        }
      }
      if (pr.name.empty()) throw fail("header line " + std::to_string(line_no) + ": malformed '" + line + "'");
      elements.back().properties.push_back(std::move(pr));
    } else {
      // obj_info (Stanford range scans), stray lines such as `bye`, blank lines: not data.
      ++out.skipped_lines;
    }
  }
  if (!ended) throw fail("the header has no 'end_header' line (file truncated or not PLY)");
  if (out.format.empty()) throw fail("the header has no 'format' line");

  std::size_t vertex_index = elements.size();
  for (std::size_t i = 0; i < elements.size(); ++i) {
    if (elements[i].name == "vertex") {
      vertex_index = i;
      break;
    }
  }
  if (vertex_index == elements.size()) throw fail("the header declares no 'vertex' element");
  const PlyElement& vertex = elements[vertex_index];
  out.vertex_count = vertex.count;
  if (vertex.count == 0) throw fail("the header declares 0 vertices");
  for (const char* axis : {"x", "y", "z"}) {
    const bool found = std::any_of(vertex.properties.begin(), vertex.properties.end(),
                                   [&](const PlyProperty& p) { return p.name == axis; });
    if (!found) throw fail(std::string("the vertex element has no '") + axis + "' property");
  }

  // Where does the vertex data end? ASCII: one line per element instance (PCL reads it so too).
  // Binary: instance size is fixed when no element up to `vertex` has a list property.
  const std::size_t body = pos;
  std::size_t cut = raw.size();
  bool keep_all_elements = false;
  if (out.format == "ascii") {
    std::size_t lines_needed = 0;
    for (std::size_t i = 0; i <= vertex_index; ++i) lines_needed += elements[i].count;
    std::size_t p = body;
    std::size_t lines = 0;
    const std::size_t first_vertex_line = lines_needed - vertex.count;
    const bool check = std::none_of(vertex.properties.begin(), vertex.properties.end(),
                                    [](const PlyProperty& pr) { return pr.is_list; });
    while (lines < lines_needed && p < raw.size()) {
      const void* nl = std::memchr(raw.data() + p, '\n', raw.size() - p);
      const std::size_t e = nl ? static_cast<std::size_t>(static_cast<const char*>(nl) - raw.data()) : raw.size();
      if (check && lines >= first_vertex_line) {
        const std::string problem = check_numeric_line(raw.data() + p, raw.data() + e, vertex.properties.size());
        if (!problem.empty()) {
          throw fail("line " + std::to_string(line_no + lines + 1) + " (vertex " +
                     std::to_string(lines - first_vertex_line) + "): " + problem);
        }
      }
      p = e < raw.size() ? e + 1 : raw.size();
      ++lines;
    }
    if (lines < lines_needed) {
      const std::size_t before = lines_needed - vertex.count;
      throw fail("truncated: the header declares " + std::to_string(vertex.count) + " vertices but only " +
                 std::to_string(lines > before ? lines - before : 0) + " vertex lines follow");
    }
    cut = p;
  } else {
    std::size_t bytes_needed = 0;
    for (std::size_t i = 0; i <= vertex_index && !keep_all_elements; ++i) {
      std::size_t stride = 0;
      for (const auto& pr : elements[i].properties) {
        if (pr.is_list) keep_all_elements = true;
        stride += static_cast<std::size_t>(pr.size_bytes);
      }
      bytes_needed += stride * elements[i].count;
    }
    if (!keep_all_elements) {
      if (raw.size() - body < bytes_needed) {
        std::size_t stride = 0;
        for (const auto& pr : vertex.properties) stride += static_cast<std::size_t>(pr.size_bytes);
        const std::size_t have = raw.size() - body;
        const std::size_t before = bytes_needed - stride * vertex.count;
        throw fail("truncated: the header declares " + std::to_string(vertex.count) + " vertices (" +
                   std::to_string(stride * vertex.count) + " bytes) but only " +
                   std::to_string(have > before ? have - before : 0) + " bytes of vertex data follow (" +
                   std::to_string(have > before ? (have - before) / stride : 0) + " whole vertices)");
      }
      cut = body + bytes_needed;
    }
  }

  std::string header = "ply\nformat " + out.format + " 1.0\n";
  for (const auto& c : comments) header += c + "\n";
  const std::size_t last = keep_all_elements ? elements.size() - 1 : vertex_index;
  for (std::size_t i = 0; i < elements.size(); ++i) {
    if (i > last) {
      out.dropped_elements.push_back(elements[i].name);
      continue;
    }
    header += "element " + elements[i].name + " " + std::to_string(elements[i].count) + "\n";
    for (const auto& pr : elements[i].properties) header += pr.line + "\n";
  }
  header += "end_header\n";
  out.bytes.reserve(header.size() + (cut - body));
  out.bytes = header;
  if (out.format == "ascii") {
    // Drop carriage returns (CRLF files): PCL's ASCII reader expects '\n' line ends.
    for (std::size_t i = body; i < cut; ++i) {
      if (raw[i] != '\r') out.bytes.push_back(raw[i]);
    }
  } else {
    out.bytes.append(raw, body, cut - body);
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
  while (pos < raw.size() && data.empty()) {
    std::size_t nl = raw.find('\n', pos);
    if (nl == std::string::npos) nl = raw.size();
    std::string line = raw.substr(pos, nl - pos);
    pos = nl + 1;
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
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
    SanitisedPly ply = sanitise_ply(bytes, name);
    bytes.clear();
    bytes.shrink_to_fit();
    cloud = detail::read_ply_body_with_pcl(ply.bytes, name, ply.vertex_count);
    report.notes.push_back("PLY " + ply.format + ", " + std::to_string(ply.vertex_count) + " vertices");
    if (ply.skipped_lines > 0) {
      report.notes.push_back("skipped " + std::to_string(ply.skipped_lines) +
                             " non-standard header lines (obj_info and stray lines)");
    }
    for (const auto& e : ply.dropped_elements) report.notes.push_back("ignored PLY element '" + e + "'");
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

  std::vector<Cloud> parts;
  parts.reserve(scans.size());
  std::size_t total = 0;
  for (std::size_t i = 0; i < scans.size(); ++i) {
    auto loaded = load_cloud(scans[i]);
    const Eigen::Affine3d m = matched[i]->scan_to_world();
    Cloud& c = loaded.value;
    c.xyz = (m.linear() * c.xyz).colwise() + m.translation();
    total += c.size();
    report.notes.push_back(scans[i].filename().string() + ": " + std::to_string(c.size()) + " points");
    parts.push_back(std::move(c));
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
