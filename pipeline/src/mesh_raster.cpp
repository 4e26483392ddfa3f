// Stage 5 for meshes: z-buffer rasterisation of triangles into the Monge grid.
//
// Design (the why, in one place):
//  * Same grid as the points. grid_geometry_of (reproject.cpp) sizes the grid from the x-y box
//    of all finite vertices, so `input.as_points: true` and the mesh path give the same grid and
//    the cross-check (which uses the vertices) sees the same geometry.
//  * Exact shared edges. A pinhole appears where a node on (or within rounding of) an edge
//    shared by two triangles is rejected by both. The edge function of an edge is evaluated with
//    its endpoints in lexicographic (x, y) order, and negated for the triangle that runs the
//    edge the other way: both triangles see the same double, bit for bit, so a node is on the
//    inside of exactly one of them, or on the edge (E == 0) of both. Ties go by the symbolic
//    perturbation p + (ε, ε²): the triangle whose inward edge normal n has n.x > 0, or n.x == 0
//    and n.y > 0, owns the node; the neighbour's normal is −n, so exactly one owns it. The same
//    perturbation settles nodes on a shared vertex (the perturbed point lies inside exactly one
//    triangle of a closed fan). Edges are compared by coordinates, not vertex indices, so
//    meshes with duplicated vertices along UV seams close too.
//  * Depth in double; the winner's triangle and two barycentric coordinates are kept per node,
//    and colour / intensity are computed once per node at the end.

#include "grid_geometry.hpp"
#include "stage_util.hpp"
#include "hc/pipeline/mesh_raster.hpp"

#include "hc/common/error.hpp"
#include "hc/common/format.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>
#include <vector>

namespace hc::pipeline {

namespace {

constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
constexpr std::uint32_t kPointBit = 0x80000000u;  // winner is a binned point, not a triangle

struct P2 {
  double x, y;
};

bool before(const P2& a, const P2& b) { return a.x < b.x || (a.x == b.x && a.y < b.y); }

// Edge function of the directed edge a → b at p: (b − a) × (p − a), positive to the left.
// Evaluated with the endpoints in (x, y) order, so the edge b → a gives exactly the negation.
double edge(const P2& a, const P2& b, double px, double py) {
  if (before(b, a)) {
    return -((a.x - b.x) * (py - b.y) - (a.y - b.y) * (px - b.x));
  }
  return (b.x - a.x) * (py - a.y) - (b.y - a.y) * (px - a.x);
}

// Whether a node exactly on the directed edge a → b (of a counter-clockwise triangle) belongs
// to the triangle: inward normal n = (−dy, dx); owned if n.x > 0 or (n.x == 0 and n.y > 0).
bool owns_ties(const P2& a, const P2& b) {
  const double dx = b.x - a.x, dy = b.y - a.y;
  return -dy > 0.0 || (dy == 0.0 && dx > 0.0);
}

// Bilinear texel sample with wrap (repeat) addressing; OBJ v up → image row 0 at v = 1.
void sample_texture(const TextureImage& t, double u, double v, double out[3]) {
  const double x = u * t.width - 0.5, y = (1.0 - v) * t.height - 0.5;
  const double xf = std::floor(x), yf = std::floor(y);
  const double fx = x - xf, fy = y - yf;
  auto wrap = [](double i, int n) {
    const double m = std::fmod(i, static_cast<double>(n));
    return static_cast<std::size_t>(m < 0 ? m + n : m);
  };
  const std::size_t x0 = wrap(xf, t.width), x1 = wrap(xf + 1, t.width);
  const std::size_t y0 = wrap(yf, t.height), y1 = wrap(yf + 1, t.height);
  const auto w = static_cast<std::size_t>(t.width);
  const std::uint8_t* p00 = t.rgb.data() + 3 * (y0 * w + x0);
  const std::uint8_t* p01 = t.rgb.data() + 3 * (y0 * w + x1);
  const std::uint8_t* p10 = t.rgb.data() + 3 * (y1 * w + x0);
  const std::uint8_t* p11 = t.rgb.data() + 3 * (y1 * w + x1);
  for (int c = 0; c < 3; ++c) {
    out[c] = (1 - fy) * ((1 - fx) * p00[c] + fx * p01[c]) + fy * ((1 - fx) * p10[c] + fx * p11[c]);
  }
}

std::uint8_t to_byte(double v) { return static_cast<std::uint8_t>(std::clamp(std::lround(v), 0L, 255L)); }

}  // namespace

StageResult<DepthGrid> rasterise_mesh(const Cloud& mesh_m, const ReprojectOptions& options, double layer_blend_m) {
  const auto t0 = std::chrono::steady_clock::now();
  const Mesh& mesh = mesh_m.mesh;
  const std::size_t n_points = mesh_m.size(), n_tri = mesh.triangles.size();
  if (n_tri == 0) throw InputError("rasterise_mesh: the cloud has no triangles (expected a mesh)");
  if (n_tri >= kPointBit || n_points >= kPointBit) {
    throw ResourceError("rasterise_mesh: " + std::to_string(n_tri) + " triangles and " + std::to_string(n_points) +
                        " points; at most 2^31 - 1 of each supported");
  }
  for (std::size_t t = 0; t < n_tri; ++t) {
    for (const std::uint32_t v : mesh.triangles[t]) {
      if (v >= n_points) {
        throw InputError("rasterise_mesh: triangle " + std::to_string(t) + " names point " + std::to_string(v) +
                         " of " + std::to_string(n_points));
      }
    }
  }
  if ((mesh_m.has_rgb() && mesh_m.rgb.size() != 3 * n_points) ||
      (mesh_m.has_intensity() && mesh_m.intensity.size() != n_points) ||
      (!mesh.corner_uv.empty() && mesh.corner_uv.size() != 6 * n_tri)) {
    throw InputError("rasterise_mesh: the mesh's attributes are misaligned (" + std::to_string(n_points) + " points, " +
                     std::to_string(mesh_m.rgb.size()) + " rgb bytes, " + std::to_string(mesh_m.intensity.size()) +
                     " intensities, " + std::to_string(n_tri) + " triangles, " +
                     std::to_string(mesh.corner_uv.size()) + " UV values)");
  }
  if (mesh.texture && mesh.has_texture() &&
      (mesh.texture->width <= 0 || mesh.texture->height <= 0 ||
       mesh.texture->rgb.size() != 3 * static_cast<std::size_t>(mesh.texture->width) *
                                       static_cast<std::size_t>(mesh.texture->height))) {
    throw InputError("rasterise_mesh: the texture image " + mesh.texture->source + " has a size that does not match its pixels");
  }
  if (!(layer_blend_m >= 0.0) || !std::isfinite(layer_blend_m)) {
    throw ConfigError("rasterise_mesh: layer_blend_m = " + std::to_string(layer_blend_m) +
                      ": expected a depth in metres >= 0 (0 = front-most face only)");
  }
  const GridGeometry g = detail::grid_geometry_of(mesh_m, options);
  const std::size_t cells = g.cell_count();
  const auto cols = static_cast<std::size_t>(g.cols);

  std::vector<double> zbuf(cells, -std::numeric_limits<double>::infinity());
  std::vector<std::uint32_t> winner(cells, kNone);
  std::vector<float> bary(2 * cells, 0.0f);  // λ of corners 1 and 2 (λ0 = 1 − λ1 − λ2)
  std::size_t edge_on = 0, non_finite = 0, rasterised = 0;
  const double* xyz = mesh_m.xyz.data();
  const double inv = 1.0 / g.cell_size_m;
  // Visits every node a finite, not edge-on triangle covers (top-left rule): f(i, zn, l0, l1,
  // l2, k) with the node's index, the interpolated z, the barycentrics in counter-clockwise
  // corner order and that order's map k to the triangle's own corners. Returns whether the
  // triangle covered a node; counts degenerate triangles when `count` is set.
  auto for_each_node = [&](std::size_t t, bool count, auto&& f) {
    const auto& tri = mesh.triangles[t];
    const double* q[3] = {xyz + 3 * static_cast<std::size_t>(tri[0]), xyz + 3 * static_cast<std::size_t>(tri[1]),
                          xyz + 3 * static_cast<std::size_t>(tri[2])};
    bool finite = true;
    for (const double* p : q) finite = finite && std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
    if (!finite) {
      if (count) ++non_finite;
      return false;
    }
    // Corner order k[] makes the triangle counter-clockwise in x-y (y up).
    int k[3] = {0, 1, 2};
    P2 v[3] = {{q[0][0], q[0][1]}, {q[1][0], q[1][1]}, {q[2][0], q[2][1]}};
    const double area = edge(v[0], v[1], v[2].x, v[2].y);
    if (area == 0.0) {
      if (count) ++edge_on;
      return false;
    }
    if (area < 0.0) {
      std::swap(v[1], v[2]);
      std::swap(k[1], k[2]);
    }
    const double z[3] = {q[k[0]][2], q[k[1]][2], q[k[2]][2]};
    const bool own[3] = {owns_ties(v[1], v[2]), owns_ties(v[2], v[0]), owns_ties(v[0], v[1])};
    const double x_lo = std::min({v[0].x, v[1].x, v[2].x}), x_hi = std::max({v[0].x, v[1].x, v[2].x});
    const double y_lo = std::min({v[0].y, v[1].y, v[2].y}), y_hi = std::max({v[0].y, v[1].y, v[2].y});
    // Candidate nodes: one node of margin either side; the edge test decides.
    const long long c_lo = std::max(0LL, static_cast<long long>(std::floor((x_lo - g.x0_m) * inv)));
    const long long c_hi = std::min<long long>(g.cols - 1, static_cast<long long>(std::ceil((x_hi - g.x0_m) * inv)));
    const long long r_lo = std::max(0LL, static_cast<long long>(std::floor((y_lo - g.y0_m) * inv)));
    const long long r_hi = std::min<long long>(g.rows - 1, static_cast<long long>(std::ceil((y_hi - g.y0_m) * inv)));
    bool any = false;
    for (long long r = r_lo; r <= r_hi; ++r) {
      const double py = g.y_of_row(static_cast<double>(r));
      for (long long c = c_lo; c <= c_hi; ++c) {
        const double px = g.x_of_col(static_cast<double>(c));
        const double e0 = edge(v[1], v[2], px, py);  // opposite corner 0
        const double e1 = edge(v[2], v[0], px, py);
        const double e2 = edge(v[0], v[1], px, py);
        if (e0 < 0.0 || e1 < 0.0 || e2 < 0.0) continue;
        if ((e0 == 0.0 && !own[0]) || (e1 == 0.0 && !own[1]) || (e2 == 0.0 && !own[2])) continue;
        const double sum = e0 + e1 + e2;
        if (!(sum > 0.0)) continue;
        const double l0 = e0 / sum, l1 = e1 / sum, l2 = e2 / sum;
        const double zn = l0 * z[0] + l1 * z[1] + l2 * z[2];
        const std::size_t i = static_cast<std::size_t>(r) * cols + static_cast<std::size_t>(c);
        any = true;
        f(i, zn, l0, l1, l2, k);
      }
    }
    return any;
  };
  for (std::size_t t = 0; t < n_tri; ++t) {
    const bool any = for_each_node(t, true, [&](std::size_t i, double zn, double l0, double l1, double l2, const int* k) {
      if (zn > zbuf[i]) {
        zbuf[i] = zn;
        winner[i] = static_cast<std::uint32_t>(t);
        // Barycentrics in the triangle's own corner order (1 and 2).
        double lam[3];
        lam[k[0]] = l0;
        lam[k[1]] = l1;
        lam[k[2]] = l2;
        bary[2 * i] = static_cast<float>(lam[1]);
        bary[2 * i + 1] = static_cast<float>(lam[2]);
      }
    });
    rasterised += any ? 1 : 0;
  }
  // Layer blending (organised scans of several views): the mean z of every face within
  // layer_blend_m of the front-most one at each node, so the front surface seen by several
  // scans is their average, not the front-most scan's (registration offsets and noise of one
  // view would otherwise decide every node). The colour stays the front-most face's.
  std::size_t blended = 0;
  if (layer_blend_m > 0.0) {
    std::vector<double> sum(cells, 0.0);
    std::vector<std::uint16_t> count(cells, 0);
    for (std::size_t t = 0; t < n_tri; ++t) {
      for_each_node(t, false, [&](std::size_t i, double zn, double, double, double, const int*) {
        if (zn >= zbuf[i] - layer_blend_m && count[i] < std::numeric_limits<std::uint16_t>::max()) {
          sum[i] += zn;
          ++count[i];
        }
      });
    }
    for (std::size_t i = 0; i < cells; ++i) {
      if (count[i] < 2) continue;
      zbuf[i] = sum[i] / count[i];
      ++blended;
    }
  }

  // Points on no triangle (an organised scan's isolated samples and the ends of cut edges; a
  // mesh file's stray vertices) are binned like points: front-most z at their nearest node.
  std::vector<bool> referenced(n_points, false);
  for (const auto& tri : mesh.triangles) {
    for (const std::uint32_t v : tri) referenced[v] = true;
  }
  std::size_t unreferenced = 0, binned = 0;
  for (std::size_t i = 0; i < n_points; ++i) {
    if (referenced[i]) continue;
    ++unreferenced;
    const double* p = xyz + 3 * i;
    if (!(std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]))) continue;
    const long long c = std::llround(g.col_of_x(p[0])), r = std::llround((p[1] - g.y0_m) * inv);
    if (c < 0 || r < 0 || c >= g.cols || r >= g.rows) continue;
    const std::size_t k = static_cast<std::size_t>(r) * cols + static_cast<std::size_t>(c);
    ++binned;
    if (p[2] > zbuf[k]) {
      zbuf[k] = p[2];
      winner[k] = kPointBit | static_cast<std::uint32_t>(i);
    }
  }

  StageResult<DepthGrid> result;
  DepthGrid& out = result.value;
  out.depth = HeightField(g, kNoData);
  out.flags.assign(cells, kCellEmpty);
  const bool texture = mesh.has_texture();
  const bool rgb = texture || mesh_m.has_rgb();
  const bool inten = mesh_m.has_intensity();
  if (rgb) out.colour_rgb8.assign(3 * cells, 0);
  if (inten) out.intensity = HeightField(g, kNoData);
  std::size_t valid = 0;
  for (std::size_t i = 0; i < cells; ++i) {
    const std::uint32_t t = winner[i];
    if (t == kNone) continue;
    ++valid;
    out.depth.data()[i] = static_cast<float>(zbuf[i]);
    out.flags[i] = kCellMeasured;
    if (!rgb && !inten) continue;
    if (t & kPointBit) {  // a binned point: its own attributes (a texture needs a face: black)
      const std::size_t pt = t & ~kPointBit;
      if (rgb && mesh_m.has_rgb()) std::copy_n(mesh_m.rgb.data() + 3 * pt, 3, out.colour_rgb8.data() + 3 * i);
      if (inten) out.intensity.data()[i] = mesh_m.intensity[pt];
      continue;
    }
    const double l1 = bary[2 * i], l2 = bary[2 * i + 1], l0 = 1.0 - l1 - l2;
    const double lam[3] = {l0, l1, l2};
    const auto& tri = mesh.triangles[t];
    if (texture) {
      const float* uv = mesh.corner_uv.data() + 6 * static_cast<std::size_t>(t);
      const double u = l0 * uv[0] + l1 * uv[2] + l2 * uv[4], vv = l0 * uv[1] + l1 * uv[3] + l2 * uv[5];
      double c[3];
      sample_texture(*mesh.texture, u, vv, c);
      for (int ch = 0; ch < 3; ++ch) out.colour_rgb8[3 * i + static_cast<std::size_t>(ch)] = to_byte(c[ch]);
    } else if (rgb) {
      for (int ch = 0; ch < 3; ++ch) {
        double acc = 0.0;
        for (int kk = 0; kk < 3; ++kk) acc += lam[kk] * mesh_m.rgb[3 * static_cast<std::size_t>(tri[static_cast<std::size_t>(kk)]) + static_cast<std::size_t>(ch)];
        out.colour_rgb8[3 * i + static_cast<std::size_t>(ch)] = to_byte(acc);
      }
    }
    if (inten) {
      double acc = 0.0;
      for (int kk = 0; kk < 3; ++kk) acc += lam[kk] * static_cast<double>(mesh_m.intensity[tri[static_cast<std::size_t>(kk)]]);
      out.intensity.data()[i] = static_cast<float>(acc);
    }
  }
  StageReport& rep = result.report;
  rep.stage = "reproject";
  rep.count_in = n_points;
  rep.count_out = valid;
  rep.figure("rows", g.rows);
  rep.figure("cols", g.cols);
  rep.figure("cell_size_mm", g.cell_size_m * 1e3);
  rep.figure("cells", static_cast<double>(cells));
  rep.figure("cells_valid", static_cast<double>(valid));
  rep.figure("cells_measured", static_cast<double>(valid));
  rep.figure("triangles", static_cast<double>(n_tri));
  rep.figure("triangles_covering_a_node", static_cast<double>(rasterised));
  rep.figure("triangles_edge_on", static_cast<double>(edge_on));
  rep.figure("triangles_non_finite", static_cast<double>(non_finite));
  rep.figure("vertices_unreferenced", static_cast<double>(unreferenced));
  rep.figure("vertices_binned_as_points", static_cast<double>(binned));
  if (layer_blend_m > 0.0) {
    rep.figure("layer_blend_mm", layer_blend_m * 1e3);
    rep.figure("cells_blended", static_cast<double>(blended));
    rep.notes.emplace_back("organised scans: each node's z is the mean of the faces within " +
                           format_number(layer_blend_m * 1e3) + " mm of the front-most one (" +
                           std::to_string(blended) + " nodes had more than one)");
  }
  rep.notes.emplace_back("mesh: " + std::to_string(n_tri) +
                         " triangles rasterised with a z-buffer (front-most z by barycentric interpolation at each node)");
  if (options.splat_radius_cells > 0.0 || options.see_through_depth_m > 0.0 || options.upsample_factor != 1) {
    rep.notes.emplace_back(
        "grid.splat_radius_cells, grid.see_through_depth_m and grid.upsample are point options: ignored for a mesh");
  }
  if (rgb) rep.notes.emplace_back(texture ? "colour sampled from the texture " + mesh.texture->source
                                          : std::string("colour interpolated from the vertex colours"));
  if (inten) rep.notes.emplace_back("intensity interpolated from the vertices");
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

}  // namespace hc::pipeline

namespace hc::pipeline {

StageResult<Cloud> mesh_organised_scans(Cloud cloud, double max_edge_factor) {
  const auto t0 = std::chrono::steady_clock::now();
  if (!(max_edge_factor >= 1.0 && max_edge_factor <= 100.0)) {
    throw ConfigError("mesh_organised_scans: max_edge_factor = " + std::to_string(max_edge_factor) +
                      " (expected 1 to 100, a multiple of the median sample spacing)");
  }
  const std::size_t n = cloud.size();
  if (!cloud.has_grid_index() || cloud.row.size() != n || cloud.col.size() != n ||
      (cloud.has_scan_id() && cloud.scan_id.size() != n)) {
    throw InputError("mesh_organised_scans: the cloud has no (or misaligned) scanner row/col: " + std::to_string(n) +
                     " points, " + std::to_string(cloud.row.size()) + " rows, " + std::to_string(cloud.col.size()) +
                     " columns, " + std::to_string(cloud.scan_id.size()) + " scan ids");
  }
  if (n > 0xFFFFFFFEu) throw InputError("mesh_organised_scans: more than 2^32 - 2 points cannot be indexed");
  std::uint16_t scans = 1;
  for (const auto s : cloud.scan_id) scans = std::max<std::uint16_t>(scans, static_cast<std::uint16_t>(s + 1));
  std::vector<std::vector<std::uint32_t>> members(scans);
  for (std::size_t i = 0; i < n; ++i) members[cloud.has_scan_id() ? cloud.scan_id[i] : 0].push_back(static_cast<std::uint32_t>(i));

  Mesh mesh;
  std::size_t cut = 0, skipped_scans = 0;
  std::vector<double> spacings;
  StageResult<Cloud> result;
  const double* p = cloud.xyz.data();
  auto dist = [&](std::uint32_t a, std::uint32_t b) {
    const double dx = p[3 * a] - p[3 * b], dy = p[3 * a + 1] - p[3 * b + 1], dz = p[3 * a + 2] - p[3 * b + 2];
    return std::sqrt(dx * dx + dy * dy + dz * dz);
  };
  for (std::uint16_t s = 0; s < scans; ++s) {
    const auto& idx = members[s];
    if (idx.size() < 3) continue;
    std::int32_t r0 = std::numeric_limits<std::int32_t>::max(), r1 = std::numeric_limits<std::int32_t>::min();
    std::int32_t c0 = r0, c1 = r1;
    for (const auto i : idx) {
      r0 = std::min(r0, cloud.row[i]);
      r1 = std::max(r1, cloud.row[i]);
      c0 = std::min(c0, cloud.col[i]);
      c1 = std::max(c1, cloud.col[i]);
    }
    const auto rows = static_cast<std::size_t>(static_cast<std::int64_t>(r1) - r0 + 1);
    const auto cols = static_cast<std::size_t>(static_cast<std::int64_t>(c1) - c0 + 1);
    if (rows * cols > std::max<std::size_t>(64 * idx.size(), 1u << 22)) {  // sparse or bogus indices
      ++skipped_scans;
      result.report.notes.push_back("scan " + std::to_string(s) + ": row/col span " + std::to_string(rows) + " × " +
                                    std::to_string(cols) + " for " + std::to_string(idx.size()) +
                                    " points: not meshed (its points have no triangles)");
      continue;
    }
    std::vector<std::uint32_t> at(rows * cols, kNone);
    for (const auto i : idx) {
      at[static_cast<std::size_t>(cloud.row[i] - r0) * cols + static_cast<std::size_t>(cloud.col[i] - c0)] = i;
    }
    std::vector<double> d;
    for (std::size_t r = 0; r < rows; ++r) {
      for (std::size_t c = 0; c < cols; ++c) {
        const std::uint32_t a = at[r * cols + c];
        if (a == kNone) continue;
        if (c + 1 < cols && at[r * cols + c + 1] != kNone) d.push_back(dist(a, at[r * cols + c + 1]));
        if (r + 1 < rows && at[(r + 1) * cols + c] != kNone) d.push_back(dist(a, at[(r + 1) * cols + c]));
      }
    }
    if (d.empty()) continue;
    std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2), d.end());
    const double spacing = d[d.size() / 2];
    spacings.push_back(spacing);
    const double limit = max_edge_factor * spacing;
    auto add = [&](std::uint32_t a, std::uint32_t b, std::uint32_t c) {
      if (dist(a, b) <= limit && dist(b, c) <= limit && dist(c, a) <= limit) {
        mesh.triangles.push_back({a, b, c});
      } else {
        ++cut;
      }
    };
    for (std::size_t r = 0; r + 1 < rows; ++r) {
      for (std::size_t c = 0; c + 1 < cols; ++c) {
        const std::uint32_t a = at[r * cols + c], b = at[r * cols + c + 1];
        const std::uint32_t e = at[(r + 1) * cols + c], f = at[(r + 1) * cols + c + 1];
        const int present = (a != kNone) + (b != kNone) + (e != kNone) + (f != kNone);
        if (present < 3) continue;
        if (present == 4) {
          if (dist(a, f) <= dist(b, e)) {
            add(a, b, f);
            add(a, f, e);
          } else {
            add(a, b, e);
            add(b, f, e);
          }
        } else if (a == kNone) {
          add(b, f, e);
        } else if (b == kNone) {
          add(a, f, e);
        } else if (e == kNone) {
          add(a, b, f);
        } else {
          add(a, b, e);
        }
      }
    }
  }
  std::sort(spacings.begin(), spacings.end());
  StageReport& rep = result.report;
  rep.count_in = n;
  rep.count_out = n;
  rep.figure("scans", scans);
  rep.figure("triangles", static_cast<double>(mesh.triangles.size()));
  rep.figure("triangles_cut", static_cast<double>(cut));
  rep.figure("median_spacing_mm", spacings.empty() ? std::numeric_limits<double>::quiet_NaN() : 1e3 * spacings[spacings.size() / 2]);
  rep.notes.push_back("each scan meshed on its own row/column grid; triangles with an edge over " +
                      std::to_string(max_edge_factor) + " × the scan's median spacing cut (depth jumps)");
  if (skipped_scans > 0) rep.notes.push_back(std::to_string(skipped_scans) + " scans not meshed");
  cloud.mesh = std::move(mesh);
  result.value = std::move(cloud);
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

StageResult<int> corrugation(const DepthGrid& grid) {
  StageResult<int> result;
  const HeightField& h = grid.depth;
  const GridGeometry& g = h.geometry();
  const double step = 2.0 * g.cell_size_m;
  const bool flags = grid.flags.size() == g.cell_count();
  auto usable = [&](int r, int c) {
    const std::size_t i = static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(c);
    return !std::isnan(h.data()[i]) && (!flags || grid.flags[i] != kCellFilled);
  };
  double e[2] = {0.0, 0.0};
  std::size_t count[2] = {0, 0};
  for (int r = 0; r < g.rows; ++r) {
    // A file-backed level 0's rows given back as the sweep passes (cell_buffer.hpp).
    if (r % 256 == 255) grid.release_resident();
    for (int c = 0; c < g.cols; ++c) {
      if (!usable(r, c)) continue;
      const double z = h.at(r, c);
      for (int axis = 0; axis < 2; ++axis) {
        const int dr = axis, dc = 1 - axis;
        if (r - dr < 0 || c - dc < 0 || r + dr >= g.rows || c + dc >= g.cols) continue;
        if (!usable(r - dr, c - dc) || !usable(r + dr, c + dc)) continue;
        const double zm = h.at(r - dr, c - dc), zp = h.at(r + dr, c + dc);
        if (std::abs(z - zm) > step || std::abs(zp - z) > step) continue;
        const double d2 = zm - 2.0 * z + zp;
        e[axis] += d2 * d2;
        ++count[axis];
      }
    }
  }
  grid.release_resident();
  const double ex = count[0] ? e[0] / static_cast<double>(count[0]) : 0.0;
  const double ey = count[1] ? e[1] / static_cast<double>(count[1]) : 0.0;
  StageReport& rep = result.report;
  rep.figure("d2_energy_x_um2", ex * 1e12);
  rep.figure("d2_energy_y_um2", ey * 1e12);
  rep.figure("triples_x", static_cast<double>(count[0]));
  rep.figure("triples_y", static_cast<double>(count[1]));
  rep.figure("corrugation_um2", std::max(ex, ey) * 1e12);
  const bool enough = count[0] >= 100 && count[1] >= 100 && std::min(ex, ey) > 0.0;
  const double aniso = enough ? std::max(ex, ey) / std::min(ex, ey) - 1.0 : std::numeric_limits<double>::quiet_NaN();
  rep.figure("corrugation_anisotropy", aniso);
  rep.notes.push_back("second-difference energy of z along x and y (slopes <= 2, filled cells excluded); "
                      "anisotropy max/min - 1: scan-line ribbing along a grid axis raises it");
  result.value = 0;
  return result;
}

}  // namespace hc::pipeline
