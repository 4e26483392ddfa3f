// OBJ reader (Wavefront OBJ, the geometry subset): `v x y z [w]` or `v x y z r g b` (vertex
// colour in [0, 1]), `vt u v [w]`, `f` with `i`, `i/t`, `i/t/n` or `i//n` corners (1-based,
// negative = relative to the last one defined; polygons fan-split (c0, c_k, c_k+1)),
// `mtllib` and `usemtl` (the material's `map_Kd` image is read with OpenCV). Everything else
// (vn, g, o, s, l, p, ...) is ignored. PCL's OBJReader stores x, y, z as float32; this keeps
// the text's double precision.
//
// A face corner naming a vertex that does not exist drops that face (counted in a note); a
// face token that is not an index is an error naming the line. The texture is used when every
// face has texture coordinates and its material's map_Kd is one and the same image; otherwise
// (no MTL, several images, an unreadable image) the faces keep their geometry without colour
// and a note says why.
// Sources: Wavefront OBJ and MTL file format descriptions (Appendix B1/B2 of the Advanced
// Visualizer manual): vt's v axis points up the image, so v = 0 is the image's bottom row.

#include "../image_io.hpp"
#include "byte_source.hpp"
#include "line_stream.hpp"
#include "readers.hpp"
#include "text_lines.hpp"
#include "text_parse.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/point_stream.hpp"


#include <algorithm>
#include <charconv>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <system_error>

namespace hc::pipeline::detail {

namespace {

std::string_view trim(const char* b, const char* e) {
  while (b < e && is_space(*b)) ++b;
  while (e > b && (is_space(e[-1]) || e[-1] == '\r')) --e;
  return {b, static_cast<std::size_t>(e - b)};
}

// The keyword at the start of a line and a pointer just after it (leading blanks skipped).
std::string_view keyword(const char*& p, const char* e) {
  while (p < e && (*p == ' ' || *p == '\t')) ++p;
  const char* k = p;
  while (p < e && *p != ' ' && *p != '\t' && *p != '\r') ++p;
  return {k, static_cast<std::size_t>(p - k)};
}

// Parses one OBJ index ("-3", "12"); false if the text is not an integer.
bool parse_index(std::string_view t, long long& v) {
  if (t.empty()) return false;
  const auto [ptr, ec] = std::from_chars(t.data(), t.data() + t.size(), v);
  return ec == std::errc() && ptr == t.data() + t.size();
}

// map_Kd of every material in an MTL file (the last token of the line: options such as
// `-s 1 1 1` come before the file name). Empty when the file cannot be read.
std::map<std::string, std::string> read_mtl(const std::filesystem::path& file) {
  std::map<std::string, std::string> out;
  std::error_code ec;
  if (!std::filesystem::is_regular_file(file, ec)) return out;
  std::ifstream in(file, std::ios::binary);
  std::string line, current;
  while (std::getline(in, line)) {
    std::istringstream ls(line);
    std::string kw;
    ls >> kw;
    if (kw == "newmtl") {
      ls >> current;
    } else if (kw == "map_Kd" && !current.empty()) {
      std::string tok, last;
      while (ls >> tok) last = tok;
      if (!last.empty()) out[current] = last;
    }
  }
  return out;
}

// The error of a bad line: InputError naming the file and line.
InputError bad_line(const std::string& name, std::size_t line_no, const std::string& what) {
  return InputError("load_cloud: " + name + " line " + std::to_string(line_no) + ": " + what);
}

// A `v` line after its keyword: x y z into xyz3 and up to four more numbers into extra. Returns
// the count of those (3 is a colour r g b), or -1 when fewer than three coordinates parse, with
// p left at the token that failed. Never throws: the stream's first look reads every line with
// it, and the errors come from parse_vertex, in file order.
int read_vertex(const char*& p, const char* e, double (&xyz3)[3], double (&extra)[4]) {
  for (double& v : xyz3) {
    if (!parse_double(p, e, v)) return -1;
  }
  int n_extra = 0;
  while (n_extra < 4 && parse_double(p, e, extra[n_extra])) ++n_extra;
  return n_extra;
}

// read_vertex, x y z appended to xyz. @throws bad_line for fewer than three numbers.
int parse_vertex(const char* p, const char* e, std::vector<double>& xyz, double (&extra)[4], const std::string& name,
                 std::size_t line_no) {
  double c[3];
  const int n_extra = read_vertex(p, e, c, extra);
  if (n_extra < 0) {
    const std::string_view tok = first_token(p, e);
    throw bad_line(name, line_no,
                   "malformed vertex line (" +
                       (tok.empty() ? std::string("fewer than 3 coordinates") : "'" + std::string(tok.substr(0, 40)) + "' is not a number") +
                       "), expected 'v x y z'");
  }
  xyz.insert(xyz.end(), c, c + 3);
  return n_extra;
}

// A `vt` line after its keyword: u and v (0 when absent). @throws bad_line without u.
void parse_texture_coordinate(const char* p, const char* e, double& u, double& v, const std::string& name, std::size_t line_no) {
  if (!parse_double(p, e, u)) throw bad_line(name, line_no, "malformed texture coordinate line, expected 'vt u v'");
  if (!parse_double(p, e, v)) v = 0.0;  // 'vt u' is allowed: v defaults to 0
}

struct Corner {
  long long v, t;  // absolute, 0-based; t = -1 without a texture coordinate
};

// An `f` line after its keyword: its corners into `face` (cleared), relative indices counted
// back from nv vertices and nt texture coordinates defined so far. @throws bad_line for a
// corner that is not v, v/vt, v/vt/vn or v//vn with non-zero integer indices.
void parse_face(const char* p, const char* e, long long nv, long long nt, std::vector<Corner>& face, const std::string& name,
                std::size_t line_no) {
  face.clear();
  while (true) {
    const std::string_view tok = first_token(p, e);
    if (tok.empty()) break;
    p = tok.data() + tok.size();
    const std::size_t s1 = tok.find('/');
    const std::string_view vs = tok.substr(0, s1);
    std::string_view ts;
    if (s1 != std::string_view::npos) {
      const std::string_view rest = tok.substr(s1 + 1);
      ts = rest.substr(0, rest.find('/'));
    }
    long long vi = 0, ti = 0;
    if (!parse_index(vs, vi) || vi == 0 || (!ts.empty() && (!parse_index(ts, ti) || ti == 0))) {
      throw bad_line(name, line_no,
                     "malformed face corner '" + std::string(tok.substr(0, 40)) +
                         "', expected v, v/vt, v/vt/vn or v//vn with non-zero integer indices");
    }
    // 1-based; negative counts back from the last vertex defined so far.
    face.push_back({vi > 0 ? vi - 1 : nv + vi, ts.empty() ? -1 : (ti > 0 ? ti - 1 : nt + ti)});
  }
}

// A vertex colour as read_obj keeps it: the value as float, clamped to [0, 1], to 8 bits.
std::uint8_t colour_byte(double c) {
  return static_cast<std::uint8_t>(std::lround(std::clamp(static_cast<float>(c), 0.0f, 1.0f) * 255.0f));
}

}  // namespace

ReadResult read_obj(const ScanSource& source) {
  const std::string& text = source.bytes;
  const std::string& name = source.display_name;
  std::vector<double> xyz;
  std::vector<float> vrgb;  // per vertex, when every `v` line has r g b
  bool all_colour = true;
  std::vector<float> vt;
  xyz.reserve(text.size() / 24);
  std::vector<Corner> corners;          // every face's corners, face after face (absolute, 0-based)
  std::vector<std::uint32_t> face_size;
  std::vector<int> face_material;       // index into materials, -1 = none
  std::vector<std::string> materials, mtllibs;
  int current_material = -1;
  std::vector<Corner> face;
  // Every line, blank ones too (TextLines: the streams' line numbers and line limit).
  const auto on_line = [&](const char* b, const char* e, std::size_t line_no) {
    const char* p = b;
    const std::string_view kw = keyword(p, e);
    if (kw == "v") {
      double extra[4];
      const int n_extra = parse_vertex(p, e, xyz, extra, name, line_no);
      if (n_extra == 3 && all_colour) {
        for (int k = 0; k < 3; ++k) vrgb.push_back(static_cast<float>(extra[k]));
      } else {
        all_colour = false;
      }
    } else if (kw == "vt") {
      double u = 0.0, v = 0.0;
      parse_texture_coordinate(p, e, u, v, name, line_no);
      vt.push_back(static_cast<float>(u));
      vt.push_back(static_cast<float>(v));
    } else if (kw == "f") {
      parse_face(p, e, static_cast<long long>(xyz.size() / 3), static_cast<long long>(vt.size() / 2), face, name, line_no);
      face_size.push_back(static_cast<std::uint32_t>(face.size()));
      face_material.push_back(current_material);
      corners.insert(corners.end(), face.begin(), face.end());
    } else if (kw == "usemtl") {
      const std::string m(trim(p, e));
      const auto it = std::find(materials.begin(), materials.end(), m);
      current_material = static_cast<int>(it - materials.begin());
      if (it == materials.end()) materials.push_back(m);
    } else if (kw == "mtllib") {
      const std::string_view lib = trim(p, e);
      if (!lib.empty()) mtllibs.emplace_back(lib);
    }
  };
  TextLines lines(text, name, 0, /*skip_blank=*/false);
  for (const char *b = nullptr, *e = nullptr; lines.next(b, e);) on_line(b, e, lines.line_no());
  if (xyz.empty()) throw InputError("load_cloud: " + name + " holds no vertices ('v x y z' lines)");
  ReadResult result{cloud_from(xyz), {"OBJ vertex lines"}};
  Cloud& cloud = result.cloud;
  const std::size_t nv = xyz.size() / 3, nt = vt.size() / 2;
  if (all_colour && vrgb.size() == 3 * nv) {
    cloud.rgb.resize(3 * nv);
    for (std::size_t i = 0; i < 3 * nv; ++i) cloud.rgb[i] = colour_byte(vrgb[i]);
    result.notes.push_back("vertex colours (v x y z r g b) read as 8-bit RGB");
  }
  if (face_size.empty()) return result;
  if (nv > 0xFFFFFFFEu) {
    result.notes.push_back("dropped every OBJ face: more than 2^32 - 2 vertices cannot be indexed");
    return result;
  }

  // Faces → triangles, with corner UVs while every corner has a valid vt.
  bool uv = nt > 0;
  std::size_t at = 0, bad_index = 0, too_short = 0, polygons = 0;
  std::vector<int> tri_material;
  for (std::size_t f = 0; f < face_size.size(); ++f) {
    const Corner* c = corners.data() + at;
    const std::uint32_t n = face_size[f];
    at += n;
    if (n < 3) {
      ++too_short;
      continue;
    }
    bool ok = true;
    for (std::uint32_t k = 0; k < n; ++k) ok = ok && c[k].v >= 0 && static_cast<std::size_t>(c[k].v) < nv;
    if (!ok) {
      ++bad_index;
      continue;
    }
    polygons += n > 3 ? 1 : 0;
    for (std::uint32_t k = 1; k + 1 < n; ++k) {
      const Corner* tri[3] = {&c[0], &c[k], &c[k + 1]};
      cloud.mesh.triangles.push_back({static_cast<std::uint32_t>(tri[0]->v), static_cast<std::uint32_t>(tri[1]->v),
                                      static_cast<std::uint32_t>(tri[2]->v)});
      tri_material.push_back(face_material[f]);
      for (const Corner* q : tri) {
        if (!uv) break;
        if (q->t < 0 || static_cast<std::size_t>(q->t) >= nt) {
          uv = false;
          cloud.mesh.corner_uv.clear();
          break;
        }
        cloud.mesh.corner_uv.push_back(vt[2 * static_cast<std::size_t>(q->t)]);
        cloud.mesh.corner_uv.push_back(vt[2 * static_cast<std::size_t>(q->t) + 1]);
      }
    }
  }
  result.notes.push_back("OBJ faces: " + std::to_string(face_size.size()) + " faces, " +
                         std::to_string(cloud.mesh.triangles.size()) + " triangles" +
                         (polygons > 0 ? " (" + std::to_string(polygons) + " polygons fan-split)" : ""));
  if (bad_index > 0) {
    result.notes.push_back("dropped " + std::to_string(bad_index) + " OBJ faces naming a vertex that does not exist (" +
                           std::to_string(nv) + " vertices)");
  }
  if (too_short > 0) result.notes.push_back("dropped " + std::to_string(too_short) + " OBJ faces with fewer than 3 corners");
  if (cloud.mesh.triangles.empty()) return result;

  // The texture: one map_Kd image shared by every face's material.
  auto no_texture = [&](const std::string& why) {
    cloud.mesh.corner_uv.clear();
    result.notes.push_back("no texture colour: " + why);
  };
  if (!uv) {
    if (nt > 0 || !mtllibs.empty()) no_texture("not every face corner has a texture coordinate (vt)");
    return result;
  }
  if (mtllibs.empty()) {
    no_texture("no mtllib line");
    return result;
  }
  const std::filesystem::path folder = source.path.parent_path();
  std::map<std::string, std::string> map_kd;
  for (const auto& lib : mtllibs) {
    const auto m = read_mtl(folder / lib);
    if (m.empty()) result.notes.push_back("material library '" + lib + "' is missing or names no map_Kd");
    map_kd.insert(m.begin(), m.end());
  }
  std::string image;
  for (const int m : tri_material) {
    const auto it = m >= 0 ? map_kd.find(materials[static_cast<std::size_t>(m)]) : map_kd.end();
    if (it == map_kd.end()) {
      no_texture("a face's material has no map_Kd image");
      return result;
    }
    if (!image.empty() && it->second != image) {
      no_texture("the faces use more than one map_Kd image ('" + image + "', '" + it->second + "')");
      return result;
    }
    image = it->second;
  }
  if (source.options && source.options->as_points) {
    no_texture("not read (input.as_points)");
    return result;
  }
  const std::filesystem::path image_path = folder / image;
  Image8 img;
  std::error_code ec;
  const std::string why = std::filesystem::is_regular_file(image_path, ec) ? read_rgb_image(image_path, img)
                                                                            : std::string("no such file");
  if (!why.empty()) {
    no_texture("the map_Kd image " + quoted(image_path) + " is missing or not readable (" + why +
               "; PNG, JPEG, BMP, TGA, GIF, PNM are read)");
    return result;
  }
  auto tex = std::make_shared<TextureImage>();
  tex->width = img.width;
  tex->height = img.height;
  tex->source = image_path.string();
  tex->rgb = std::move(img.pixels);
  cloud.mesh.texture = std::move(tex);
  result.notes.push_back("texture " + quoted(image_path) + " (" + std::to_string(img.width) + " × " +
                         std::to_string(img.height) + ", map_Kd)");
  return result;
}

namespace {

// An OBJ file's vertices read in blocks of lines (point_stream.hpp). The first look counts the
// `v` lines and whether each holds r g b (read_vertex; read_obj keeps colour only when every
// one does) and whether any `f` line is there, without keeping anything; a later stream of the
// same unchanged large file reuses it. The stream then parses every line as read_obj does (a
// bad `v`, `vt` or `f` line is read_obj's error, in file order) and hands out the vertices.
class ObjStream final : public LineStream {
 public:
  ObjStream(const std::filesystem::path& path, const std::string& name, bool gz) : LineStream(ByteSource::open(path, name, gz)) {
    const auto look = first_look(*src_, "obj_look", [&] {
      FileLines lines(*src_);
      std::uint64_t vertices = 0;
      bool all_colour = true, faces = false;
      const char* b = nullptr;
      const char* e = nullptr;
      while (lines.next(b, e)) {
        const char* p = b;
        const std::string_view kw = keyword(p, e);
        if (kw == "v") {
          ++vertices;
          double c[3], extra[4];
          all_colour = all_colour && read_vertex(p, e, c, extra) == 3;  // r g b, as read_obj decides
        } else if (kw == "f") {
          faces = true;
        }
      }
      return std::array<std::uint64_t, 2>{vertices, (all_colour ? 1U : 0U) | (faces ? 2U : 0U)};
    });
    total_ = look[0];
    all_colour_ = (look[1] & 1U) != 0 && total_ > 0;
    faces_ = (look[1] & 2U) != 0;
    start_lines();
    notes_ = {"OBJ vertex lines"};
    if (all_colour_) notes_.push_back("vertex colours (v x y z r g b) read as 8-bit RGB");
    if (faces_) notes_.push_back("faces not read (input.as_points: the vertices only)");
    notes_.push_back("lines streamed in chunks");
  }

  bool has_faces() const { return faces_; }

 private:
  void fill(std::size_t max) override {
    std::size_t taken = 0;
    const char* b = nullptr;
    const char* e = nullptr;
    while (taken < max) {
      if (!lines_->next(b, e)) {
        if (vertices_ == 0) throw InputError("load_cloud: " + name_ + " holds no vertices ('v x y z' lines)");
        return;
      }
      const char* p = b;
      const std::string_view kw = keyword(p, e);
      if (kw == "v") {
        double extra[4];
        const int n_extra = parse_vertex(p, e, xyz_, extra, name_, lines_->line_no());
        if (all_colour_) {
          if (n_extra != 3) throw InputError("load_cloud: " + name_ + " changed while it was read (a vertex's colour)");
          for (int k = 0; k < 3; ++k) rgb_.push_back(colour_byte(extra[k]));
        }
        ++vertices_;
        ++taken;
      } else if (kw == "vt") {
        double u = 0.0, v = 0.0;
        parse_texture_coordinate(p, e, u, v, name_, lines_->line_no());
        ++texture_coordinates_;
      } else if (kw == "f") {
        parse_face(p, e, vertices_, texture_coordinates_, face_, name_, lines_->line_no());
      }
    }
  }

  bool all_colour_ = false, faces_ = false;
  long long vertices_ = 0, texture_coordinates_ = 0;
  std::vector<Corner> face_;
};

}  // namespace

std::unique_ptr<PointStream> open_obj_stream(const std::filesystem::path& path, const std::string& name, bool as_points, bool gz) {
  auto s = std::make_unique<ObjStream>(path, name, gz);
  if (s->has_faces() && !as_points) return nullptr;  // a mesh: rasterised in core
  return s;
}

}  // namespace hc::pipeline::detail
