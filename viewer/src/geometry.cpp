/// CPU-side meshes (geometry.hpp).

#include "geometry.hpp"

#include "hc/viewer/viewer.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <numbers>

namespace hc::viewer {

namespace {

void push_vertex(MeshData& m, const Eigen::Vector3d& p, const Eigen::Vector3d& n) {
  m.vertices.insert(m.vertices.end(), {static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()),
                                       static_cast<float>(n.x()), static_cast<float>(n.y()), static_cast<float>(n.z())});
}

std::uint32_t vertex_count(const MeshData& m) { return static_cast<std::uint32_t>(m.vertices.size() / 6); }

}  // namespace

MeshData height_field_mesh(const HeightField& field, int max_side, const std::vector<float>* sample_rgb) {
  MeshData m;
  const int rows = field.rows(), cols = field.cols();
  if (rows < 2 || cols < 2) return m;
  const int stride = std::max(1, (std::max(rows, cols) + max_side - 2) / std::max(1, max_side - 1));
  std::vector<int> rs, cs;
  for (int r = 0; r < rows; r += stride) rs.push_back(r);
  if (rs.back() != rows - 1) rs.push_back(rows - 1);
  for (int c = 0; c < cols; c += stride) cs.push_back(c);
  if (cs.back() != cols - 1) cs.push_back(cols - 1);
  const GridGeometry& g = field.geometry();
  const auto z = [&](int r, int c) { return static_cast<double>(field.at(r, c)); };
  // Slope along one axis from the nearest valid neighbours (central, else one-sided, else 0).
  const auto slope = [&](int r, int c, int dr, int dc) {
    const int r0 = r - dr, c0 = c - dc, r1 = r + dr, c1 = c + dc;
    const bool lo = r0 >= 0 && c0 >= 0 && field.valid(r0, c0);
    const bool hi = r1 < rows && c1 < cols && field.valid(r1, c1);
    const double h = g.cell_size_m * stride;
    if (lo && hi) return (z(r1, c1) - z(r0, c0)) / (2.0 * h);
    if (hi) return (z(r1, c1) - z(r, c)) / h;
    if (lo) return (z(r, c) - z(r0, c0)) / h;
    return 0.0;
  };
  const auto nr = static_cast<int>(rs.size()), nc = static_cast<int>(cs.size());
  m.vertices.reserve(static_cast<std::size_t>(nr) * static_cast<std::size_t>(nc) * 6);
  const bool coloured = sample_rgb != nullptr && sample_rgb->size() == 3 * field.values().size();
  if (coloured) m.colours.reserve(static_cast<std::size_t>(nr) * static_cast<std::size_t>(nc) * 3);
  for (int i = 0; i < nr; ++i) {
    for (int j = 0; j < nc; ++j) {
      const int r = rs[static_cast<std::size_t>(i)], c = cs[static_cast<std::size_t>(j)];
      const bool ok = field.valid(r, c);
      const Eigen::Vector3d p(g.x_of_col(c), g.y_of_row(r), ok ? z(r, c) : 0.0);
      Eigen::Vector3d n(0, 0, 1);
      if (ok) {
        // Steps of `stride` samples along x (columns) and y (rows).
        const auto sx = [&] {
          const int c0 = std::max(0, c - stride), c1 = std::min(cols - 1, c + stride);
          const bool lo = c0 < c && field.valid(r, c0), hi = c1 > c && field.valid(r, c1);
          if (lo && hi) return (z(r, c1) - z(r, c0)) / (g.cell_size_m * (c1 - c0));
          if (hi) return (z(r, c1) - z(r, c)) / (g.cell_size_m * (c1 - c));
          if (lo) return (z(r, c) - z(r, c0)) / (g.cell_size_m * (c - c0));
          return slope(r, c, 0, 1);
        }();
        const auto sy = [&] {
          const int r0 = std::max(0, r - stride), r1 = std::min(rows - 1, r + stride);
          const bool lo = r0 < r && field.valid(r0, c), hi = r1 > r && field.valid(r1, c);
          if (lo && hi) return (z(r1, c) - z(r0, c)) / (g.cell_size_m * (r1 - r0));
          if (hi) return (z(r1, c) - z(r, c)) / (g.cell_size_m * (r1 - r));
          if (lo) return (z(r, c) - z(r0, c)) / (g.cell_size_m * (r - r0));
          return slope(r, c, 1, 0);
        }();
        n = Eigen::Vector3d(-sx, -sy, 1.0).normalized();
      }
      push_vertex(m, p, n);
      if (coloured) {
        const std::size_t k = 3 * (static_cast<std::size_t>(r) * static_cast<std::size_t>(cols) + static_cast<std::size_t>(c));
        m.colours.insert(m.colours.end(), {(*sample_rgb)[k], (*sample_rgb)[k + 1], (*sample_rgb)[k + 2]});
      }
    }
  }
  for (int i = 0; i + 1 < nr; ++i) {
    for (int j = 0; j + 1 < nc; ++j) {
      const int r0 = rs[static_cast<std::size_t>(i)], r1 = rs[static_cast<std::size_t>(i + 1)];
      const int c0 = cs[static_cast<std::size_t>(j)], c1 = cs[static_cast<std::size_t>(j + 1)];
      if (!field.valid(r0, c0) || !field.valid(r0, c1) || !field.valid(r1, c0) || !field.valid(r1, c1)) continue;
      const auto a = static_cast<std::uint32_t>(i * nc + j), b = a + 1;
      const auto d = static_cast<std::uint32_t>((i + 1) * nc + j), e = d + 1;
      m.indices.insert(m.indices.end(), {a, b, e, a, e, d});
      ++m.quads;
    }
  }
  return m;
}

MeshData sphere_mesh(int slices, int stacks) {
  MeshData m;
  for (int i = 0; i <= stacks; ++i) {
    const double phi = std::numbers::pi * i / stacks;
    for (int j = 0; j <= slices; ++j) {
      const double theta = 2 * std::numbers::pi * j / slices;
      const Eigen::Vector3d p(std::sin(phi) * std::cos(theta), std::sin(phi) * std::sin(theta), std::cos(phi));
      push_vertex(m, p, p);
    }
  }
  const auto w = static_cast<std::uint32_t>(slices + 1);
  for (std::uint32_t i = 0; i < static_cast<std::uint32_t>(stacks); ++i) {
    for (std::uint32_t j = 0; j < static_cast<std::uint32_t>(slices); ++j) {
      const std::uint32_t a = i * w + j, b = a + 1, d = a + w, e = d + 1;
      m.indices.insert(m.indices.end(), {a, d, e, a, e, b});
    }
  }
  return m;
}

MeshData arrow_mesh(int slices) {
  MeshData m;
  const double shaft_r = 0.03, cone_r = 0.08, cone_z = 0.75;
  const auto ring = [&](double radius, double z_m, double nz) {
    const std::uint32_t first = vertex_count(m);
    for (int j = 0; j <= slices; ++j) {
      const double t = 2 * std::numbers::pi * j / slices;
      const Eigen::Vector3d dir(std::cos(t), std::sin(t), 0);
      push_vertex(m, Eigen::Vector3d(radius * dir.x(), radius * dir.y(), z_m), (dir + Eigen::Vector3d(0, 0, nz)).normalized());
    }
    return first;
  };
  const auto strip = [&](std::uint32_t lo, std::uint32_t hi) {
    for (std::uint32_t j = 0; j < static_cast<std::uint32_t>(slices); ++j) {
      m.indices.insert(m.indices.end(), {lo + j, lo + j + 1, hi + j + 1, lo + j, hi + j + 1, hi + j});
    }
  };
  strip(ring(shaft_r, 0.0, 0.0), ring(shaft_r, cone_z, 0.0));
  const double slope = cone_r / (1.0 - cone_z);
  strip(ring(cone_r, cone_z, slope), ring(1e-4, 1.0, slope));
  // Base of the cone (a disc facing −z).
  const std::uint32_t centre = vertex_count(m);
  push_vertex(m, Eigen::Vector3d(0, 0, cone_z), Eigen::Vector3d(0, 0, -1));
  const std::uint32_t rim = vertex_count(m);
  for (int j = 0; j <= slices; ++j) {
    const double t = 2 * std::numbers::pi * j / slices;
    push_vertex(m, Eigen::Vector3d(cone_r * std::cos(t), cone_r * std::sin(t), cone_z), Eigen::Vector3d(0, 0, -1));
  }
  for (std::uint32_t j = 0; j < static_cast<std::uint32_t>(slices); ++j) {
    m.indices.insert(m.indices.end(), {centre, rim + j + 1, rim + j});
  }
  return m;
}

// --- audio-region outlines ------------------------------------------------------------------

std::vector<RegionSegment> region_outline_segments(const HeightField& region_id) {
  const int rows = region_id.rows(), cols = region_id.cols();
  std::vector<RegionSegment> out;
  if (rows <= 0 || cols <= 0) return out;
  const GridGeometry& g = region_id.geometry();
  const double h = 0.5 * g.cell_size_m;
  const auto id = [&](int r, int c) -> std::int32_t {
    if (r < 0 || c < 0 || r >= rows || c >= cols) return -1;
    const float v = region_id.at(r, c);
    return std::isfinite(v) && v >= 0.0F ? static_cast<std::int32_t>(std::lround(v)) : -1;
  };
  // Vertical boundaries at x = x(c) − h, between columns c − 1 and c (c = 0 .. cols), pieces of
  // one row each joined along r; then horizontal ones the same way with rows and columns
  // exchanged. `side` 0 takes the region before the boundary, 1 the one after it.
  for (int pass = 0; pass < 2; ++pass) {
    const bool vertical = pass == 0;
    const int lines = vertical ? cols + 1 : rows + 1, along = vertical ? rows : cols;
    for (int k = 0; k < lines; ++k) {
      for (int side = 0; side < 2; ++side) {
        std::int32_t open = -1;
        int start = 0;
        for (int j = 0; j <= along; ++j) {
          std::int32_t here = -1;
          if (j < along) {
            const std::int32_t before = vertical ? id(j, k - 1) : id(k - 1, j);
            const std::int32_t after = vertical ? id(j, k) : id(k, j);
            if (before != after) here = side == 0 ? before : after;
          }
          if (here == open) continue;
          if (open >= 0) {
            RegionSegment s;
            s.region = open;
            if (vertical) {
              s.x0_m = s.x1_m = g.x_of_col(k) - h;
              s.y0_m = g.y_of_row(start) - h;
              s.y1_m = g.y_of_row(j - 1) + h;
            } else {
              s.y0_m = s.y1_m = g.y_of_row(k) - h;
              s.x0_m = g.x_of_col(start) - h;
              s.x1_m = g.x_of_col(j - 1) + h;
            }
            out.push_back(s);
          }
          open = here;
          start = j;
        }
      }
    }
  }
  return out;
}

Eigen::Vector3f region_colour(std::int32_t index) {
  // Hue in golden-angle steps from orange; saturation 0.85, value 1 (HSV → RGB).
  const double hue = std::fmod(0.08 + 0.618033988749895 * static_cast<double>(std::max(index, 0)), 1.0) * 6.0;
  const double s = 0.85, v = 1.0;
  const int sector = static_cast<int>(hue) % 6;
  const double f = hue - std::floor(hue);
  const double p = v * (1 - s), q = v * (1 - s * f), t = v * (1 - s * (1 - f));
  double r = v, gr = t, b = p;
  switch (sector) {
    case 0: r = v, gr = t, b = p; break;
    case 1: r = q, gr = v, b = p; break;
    case 2: r = p, gr = v, b = t; break;
    case 3: r = p, gr = q, b = v; break;
    case 4: r = t, gr = p, b = v; break;
    default: r = v, gr = p, b = q; break;
  }
  return {static_cast<float>(r), static_cast<float>(gr), static_cast<float>(b)};
}

}  // namespace hc::viewer
