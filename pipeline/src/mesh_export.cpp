// Height field → triangle mesh (PLY, STL, OBJ). See mesh_export.hpp.

#include "image_io.hpp"
#include "hc/pipeline/mesh_export.hpp"

#include "hc/common/file_output.hpp"

#include "hc/common/error.hpp"


#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <stdexcept>
#include <system_error>
#include <cerrno>
#include <sys/stat.h>
#include <unistd.h>

namespace hc::pipeline {

namespace {

constexpr std::uint32_t kNoVertex = std::numeric_limits<std::uint32_t>::max();

template <class T>
void put_le(std::ofstream& out, T value) {
  static_assert(std::is_trivially_copyable_v<T>);
  std::array<char, sizeof(T)> bytes{};
  std::memcpy(bytes.data(), &value, sizeof(T));
  if constexpr (std::endian::native == std::endian::big) std::reverse(bytes.begin(), bytes.end());
  out.write(bytes.data(), static_cast<std::streamsize>(sizeof(T)));
}

void write_ply(std::ofstream& out, const HeightMesh& m, const std::vector<std::string>& comments) {
  const bool rgb = !m.rgb8.empty();
  out << "ply\nformat binary_little_endian 1.0\ncomment hapticloud height field, grid frame, metres\n";
  for (const std::string& c : comments) out << "comment " << c << "\n";
  out << "element vertex " << m.vertex_count() << "\nproperty float x\nproperty float y\nproperty float z\n";
  if (rgb) out << "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  out << "element face " << m.triangle_count() << "\nproperty list uchar uint vertex_indices\nend_header\n";
  for (std::size_t v = 0; v < m.vertex_count(); ++v) {
    for (int a = 0; a < 3; ++a) put_le(out, static_cast<float>(m.xyz_m[3 * v + static_cast<std::size_t>(a)]));
    if (rgb) out.write(reinterpret_cast<const char*>(m.rgb8.data() + 3 * v), 3);
  }
  for (std::size_t t = 0; t < m.triangle_count(); ++t) {
    put_le(out, std::uint8_t{3});
    for (int k = 0; k < 3; ++k) put_le(out, m.triangles[3 * t + static_cast<std::size_t>(k)]);
  }
}

void write_stl(std::ofstream& out, const HeightMesh& m) {
  std::array<char, 80> header{};
  const char* text = "hapticloud height field, grid frame, millimetres";
  std::memcpy(header.data(), text, std::strlen(text));
  out.write(header.data(), header.size());
  if (m.triangle_count() > std::numeric_limits<std::uint32_t>::max()) {
    throw ResourceError("export: " + std::to_string(m.triangle_count()) + " triangles (binary STL holds at most 2^32 - 1)");
  }
  put_le(out, static_cast<std::uint32_t>(m.triangle_count()));
  for (std::size_t t = 0; t < m.triangle_count(); ++t) {
    std::array<std::array<double, 3>, 3> p{};
    for (int k = 0; k < 3; ++k)
      for (int a = 0; a < 3; ++a) p[static_cast<std::size_t>(k)][static_cast<std::size_t>(a)] = m.xyz_m[3 * m.triangles[3 * t + static_cast<std::size_t>(k)] + static_cast<std::size_t>(a)];
    const std::array<double, 3> u{p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]};
    const std::array<double, 3> w{p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]};
    std::array<double, 3> n{u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
    const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (double& x : n) x = len > 0.0 ? x / len : 0.0;
    for (double x : n) put_le(out, static_cast<float>(x));
    for (const auto& q : p)
      for (double x : q) put_le(out, static_cast<float>(1e3 * x));  // millimetres, as slicers read STL
    put_le(out, std::uint16_t{0});
  }
}

void write_obj(std::ofstream& out, const HeightMesh& m, const std::vector<std::string>& comments, const std::string& mtl_name) {
  out << "# hapticloud height field, grid frame, metres\n";
  for (const std::string& c : comments) out << "# " << c << "\n";
  const bool tex = !mtl_name.empty();
  if (tex) out << "mtllib " << mtl_name << "\n";
  out.precision(9);
  for (std::size_t v = 0; v < m.vertex_count(); ++v)
    out << "v " << m.xyz_m[3 * v] << " " << m.xyz_m[3 * v + 1] << " " << m.xyz_m[3 * v + 2] << "\n";
  if (tex) {
    for (std::size_t v = 0; v < m.vertex_count(); ++v) out << "vt " << m.uv[2 * v] << " " << m.uv[2 * v + 1] << "\n";
    out << "usemtl colour\n";
  }
  for (std::size_t t = 0; t < m.triangle_count(); ++t) {
    out << "f";
    for (int k = 0; k < 3; ++k) {
      const std::uint64_t i = std::uint64_t{m.triangles[3 * t + static_cast<std::size_t>(k)]} + 1;
      out << " " << i;
      if (tex) out << "/" << i;
    }
    out << "\n";
  }
}

// Writes `body` to a fresh temporary file beside `file` (create_temporary_beside) and
// returns its path (linked into place by the caller). On any failure the temporary is removed
// and the exception passed on.
template <class Body>
std::filesystem::path write_temporary(const std::filesystem::path& file, Body&& body) {
  namespace fs = std::filesystem;
  const fs::path tmp = create_temporary_beside(file);
  try {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) throw InputError("export: cannot open " + tmp.string());
    body(out);
    out.flush();
    if (!out) throw InputError("export: writing " + tmp.string() + " failed (disk full?)");
  } catch (...) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw;
  }
  return tmp;
}

}  // namespace


HeightMesh triangulate_height_field(const HeightField& depth, std::span<const std::uint8_t> colour_rgb8) {
  const GridGeometry& g = depth.geometry();
  const std::size_t cells = g.cell_count();
  if (!colour_rgb8.empty() && colour_rgb8.size() != 3 * cells) {
    throw std::invalid_argument("triangulate_height_field: colour layer of " + std::to_string(colour_rgb8.size()) +
                                " bytes for " + std::to_string(cells) + " cells (expected 0 or 3 per cell)");
  }
  auto at = [&](int r, int c) { return static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(c); };
  auto quad_valid = [&](int r, int c) {
    return depth.valid(r, c) && depth.valid(r, c + 1) && depth.valid(r + 1, c) && depth.valid(r + 1, c + 1);
  };
  // A node becomes a vertex when it is a corner of a valid quad.
  std::vector<std::uint8_t> used(cells, 0);
  for (int r = 0; r + 1 < g.rows; ++r)
    for (int c = 0; c + 1 < g.cols; ++c)
      if (quad_valid(r, c)) used[at(r, c)] = used[at(r, c + 1)] = used[at(r + 1, c)] = used[at(r + 1, c + 1)] = 1;
  HeightMesh m;
  std::vector<std::uint32_t> index(cells, kNoVertex);
  std::size_t n = 0;
  for (std::size_t i = 0; i < cells; ++i) n += used[i];
  if (n >= kNoVertex) throw ResourceError("triangulate_height_field: " + std::to_string(n) + " vertices (at most 2^32 - 2)");
  m.xyz_m.reserve(3 * n);
  if (!colour_rgb8.empty()) m.rgb8.reserve(3 * n);
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c) {
      const std::size_t i = at(r, c);
      if (!used[i]) continue;
      index[i] = static_cast<std::uint32_t>(m.xyz_m.size() / 3);
      m.xyz_m.insert(m.xyz_m.end(), {g.x_of_col(c), g.y_of_row(r), static_cast<double>(depth.at(r, c))});
      if (!colour_rgb8.empty()) m.rgb8.insert(m.rgb8.end(), colour_rgb8.begin() + static_cast<std::ptrdiff_t>(3 * i), colour_rgb8.begin() + static_cast<std::ptrdiff_t>(3 * i + 3));
    }
  if (!colour_rgb8.empty()) {
    m.texture_rows = g.rows;
    m.texture_cols = g.cols;
    m.texture_rgb8.resize(3 * cells);
    for (int r = 0; r < g.rows; ++r)  // grid row r → image row rows − 1 − r (upright)
      std::copy_n(colour_rgb8.begin() + static_cast<std::ptrdiff_t>(3 * at(r, 0)), 3 * static_cast<std::size_t>(g.cols),
                  m.texture_rgb8.begin() + static_cast<std::ptrdiff_t>(3 * at(g.rows - 1 - r, 0)));
    m.uv.reserve(2 * n);
    for (int r = 0; r < g.rows; ++r)
      for (int c = 0; c < g.cols; ++c) {
        if (!used[at(r, c)]) continue;
        m.uv.push_back(static_cast<float>((c + 0.5) / g.cols));
        m.uv.push_back(static_cast<float>((r + 0.5) / g.rows));
      }
  }
  for (int r = 0; r + 1 < g.rows; ++r)
    for (int c = 0; c + 1 < g.cols; ++c) {
      if (!quad_valid(r, c)) continue;
      const std::uint32_t a = index[at(r, c)], b = index[at(r, c + 1)], d = index[at(r + 1, c)], e = index[at(r + 1, c + 1)];
      m.triangles.insert(m.triangles.end(), {a, b, e, a, e, d});  // counter-clockwise seen from +z (y grows with r)
    }
  return m;
}

MeshFormat parse_mesh_format(const std::string& name) {
  if (name == "ply") return MeshFormat::kPly;
  if (name == "stl") return MeshFormat::kStl;
  if (name == "obj") return MeshFormat::kObj;
  throw ConfigError("export --format = '" + name + "': expected one of: ply, stl, obj");
}

void write_mesh(const HeightMesh& mesh, const std::filesystem::path& file, MeshFormat format,
                const std::vector<std::string>& comments) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path target = file.has_parent_path() ? file : fs::path(".") / file;
  const fs::path folder = target.parent_path();
  if (!fs::is_directory(folder, ec)) throw InputError("export: folder " + folder.string() + " of " + file.string() + " does not exist");
  const bool textured = format == MeshFormat::kObj && !mesh.texture_rgb8.empty();
  const fs::path mtl = fs::path(target).replace_extension(".mtl"), png = fs::path(target).replace_extension(".png");
  std::vector<fs::path> targets = {target};
  if (textured) {
    if (target == mtl || target == png) {
      throw InputError("export: --out " + file.string() + " would be its own texture or material file; use a .obj name");
    }
    targets.insert(targets.end(), {mtl, png});
  }
  for (const fs::path& t : targets)
    if (fs::exists(t, ec)) throw InputError("export: " + t.string() + " exists already (not overwritten; choose another --out)");
  std::vector<std::pair<fs::path, fs::path>> done;  // temporary → target, renamed at the end
  auto discard = [&] {
    for (const auto& [tmp, t] : done) fs::remove(tmp, ec);
  };
  try {
    if (textured) {
      done.emplace_back(write_temporary(png, [&](std::ofstream& out) {
        std::string why;
        const std::vector<std::uint8_t> bytes =
            detail::encode_png(mesh.texture_rgb8.data(), mesh.texture_cols, mesh.texture_rows, detail::PixelFormat::kRgb, &why);
        if (bytes.empty()) throw InputError("export: cannot encode the texture " + png.string() + ": " + why);
        out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
      }), png);
      done.emplace_back(write_temporary(mtl, [&](std::ofstream& out) {
        out << "# hapticloud colour layer\nnewmtl colour\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum 1\nmap_Kd "
            << png.filename().string() << "\n";
      }), mtl);
    }
    done.emplace_back(write_temporary(target, [&](std::ofstream& out) {
      if (format == MeshFormat::kPly) {
        write_ply(out, mesh, comments);
      } else if (format == MeshFormat::kStl) {
        write_stl(out, mesh);
      } else {
        write_obj(out, mesh, comments, textured ? mtl.filename().string() : std::string());
      }
    }), target);
  } catch (...) {
    discard();
    throw;
  }
  std::vector<fs::path> placed;
  for (const auto& [tmp, t] : done) {  // the mesh itself last: its companions exist when it appears
    if (!link_into_place(tmp, t)) {
      const std::string why = errno == EEXIST ? "it exists already (not overwritten)" : std::strerror(errno);
      discard();
      for (const fs::path& r : placed) fs::remove(r, ec);  // ours, written just now
      throw InputError("export: cannot put " + t.string() + " in place: " + why);
    }
    placed.push_back(t);
  }
}

}  // namespace hc::pipeline
