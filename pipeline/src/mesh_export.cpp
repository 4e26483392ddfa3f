// Height field → triangle mesh (PLY, STL). See mesh_export.hpp.

#include "hc/pipeline/mesh_export.hpp"

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
  out << "element face " << m.triangle_count() << "\nproperty list uchar int vertex_indices\nend_header\n";
  for (std::size_t v = 0; v < m.vertex_count(); ++v) {
    for (int a = 0; a < 3; ++a) put_le(out, static_cast<float>(m.xyz_m[3 * v + static_cast<std::size_t>(a)]));
    if (rgb) out.write(reinterpret_cast<const char*>(m.rgb8.data() + 3 * v), 3);
  }
  for (std::size_t t = 0; t < m.triangle_count(); ++t) {
    put_le(out, std::uint8_t{3});
    for (int k = 0; k < 3; ++k) put_le(out, static_cast<std::int32_t>(m.triangles[3 * t + static_cast<std::size_t>(k)]));
  }
}

void write_stl(std::ofstream& out, const HeightMesh& m) {
  std::array<char, 80> header{};
  const char* text = "hapticloud height field, grid frame, metres";
  std::memcpy(header.data(), text, std::strlen(text));
  out.write(header.data(), header.size());
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
      for (double x : q) put_le(out, static_cast<float>(x));
    put_le(out, std::uint16_t{0});
  }
}

}  // namespace

HeightMesh triangulate_height_field(const HeightField& depth, const std::vector<std::uint8_t>& colour_rgb8) {
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
  throw ConfigError("export --format = '" + name + "': expected one of: ply, stl");
}

void write_mesh(const HeightMesh& mesh, const std::filesystem::path& file, MeshFormat format,
                const std::vector<std::string>& comments) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::exists(file, ec)) throw InputError("export: " + file.string() + " exists already (not overwritten; choose another --out)");
  const fs::path folder = file.has_parent_path() ? file.parent_path() : fs::path(".");
  if (!fs::is_directory(folder, ec)) throw InputError("export: folder " + folder.string() + " of " + file.string() + " does not exist");
  const fs::path tmp = folder / (file.filename().string() + ".part-" + std::to_string(::getpid()));
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) throw InputError("export: cannot create " + tmp.string());
    if (format == MeshFormat::kPly) {
      write_ply(out, mesh, comments);
    } else {
      write_stl(out, mesh);
    }
    out.flush();
    if (!out) {
      out.close();
      fs::remove(tmp, ec);
      throw InputError("export: writing " + tmp.string() + " failed (disk full?)");
    }
  }
  fs::rename(tmp, file, ec);
  if (ec) {
    std::error_code ignore;
    fs::remove(tmp, ignore);
    throw InputError("export: cannot rename " + tmp.string() + " to " + file.string() + ": " + ec.message());
  }
}

}  // namespace hc::pipeline
