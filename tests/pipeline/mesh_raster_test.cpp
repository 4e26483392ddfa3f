// Meshes as surfaces: the z-buffer rasteriser (rasterise_mesh) against a brute-force ray-cast
// oracle, the PLY / OBJ face, colour and texture readers, `input.as_points`, and the real
// meshes (bunny, Balinese mask) through the pipeline.
#include "hc/pipeline/mesh_raster.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/transform.hpp"

#include "test_paths.hpp"
#include "stage_figure.hpp"
#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <string>
#include <vector>

namespace hc::pipeline {
namespace {

using hc::test::figure;

namespace fs = std::filesystem;

// ---------------------------------------------------------------------------------------------
// The oracle: a ray from above each node, along −z, against every triangle (Möller–Trumbore in
// double). A hit is "clear" when all three barycentric coordinates exceed kEdgeBand, "clear
// miss" when one is below −kEdgeBand; nodes within the band of any triangle's edge are
// ambiguous (either answer is right there) and skipped.

constexpr double kEdgeBand = 1e-9;

struct Hit {
  bool ambiguous = false;
  std::optional<double> z;  // front-most clear hit
  double u = 0, v = 0;      // its barycentrics (of corners 1 and 2)
  std::size_t tri = 0;
};

// Möller–Trumbore for the ray o + t·(0, 0, −1); returns false for a triangle parallel to the
// ray. u, v: barycentric coordinates of corners 1 and 2.
bool moller_trumbore(const Eigen::Vector3d& o, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                     const Eigen::Vector3d& c, double& t, double& u, double& v) {
  const Eigen::Vector3d d(0, 0, -1);
  const Eigen::Vector3d e1 = b - a, e2 = c - a;
  const Eigen::Vector3d p = d.cross(e2);
  const double det = e1.dot(p);
  if (std::abs(det) < 1e-300) return false;
  const double inv = 1.0 / det;
  const Eigen::Vector3d s = o - a;
  u = s.dot(p) * inv;
  const Eigen::Vector3d q = s.cross(e1);
  v = d.dot(q) * inv;
  t = e2.dot(q) * inv;
  return true;
}

struct Oracle {
  const Cloud& mesh;
  GridGeometry g;
  double z_top;
  // Triangles bucketed by the nodes of their x-y box (only to make the oracle affordable on
  // real meshes; every triangle whose box holds the node is tested).
  std::vector<std::vector<std::uint32_t>> bucket;

  Oracle(const Cloud& m, const GridGeometry& geometry) : mesh(m), g(geometry) {
    z_top = m.xyz.row(2).maxCoeff() + 1.0;
    bucket.resize(g.cell_count());
    for (std::size_t t = 0; t < m.mesh.triangles.size(); ++t) {
      double xl = 1e300, xh = -1e300, yl = 1e300, yh = -1e300;
      for (auto i : m.mesh.triangles[t]) {
        xl = std::min(xl, m.xyz(0, i));
        xh = std::max(xh, m.xyz(0, i));
        yl = std::min(yl, m.xyz(1, i));
        yh = std::max(yh, m.xyz(1, i));
      }
      const int c0 = std::max(0, static_cast<int>(std::floor(g.col_of_x(xl))) - 1);
      const int c1 = std::min(g.cols - 1, static_cast<int>(std::ceil(g.col_of_x(xh))) + 1);
      const int r0 = std::max(0, static_cast<int>(std::floor((yl - g.y0_m) / g.cell_size_m)) - 1);
      const int r1 = std::min(g.rows - 1, static_cast<int>(std::ceil((yh - g.y0_m) / g.cell_size_m)) + 1);
      for (int r = r0; r <= r1; ++r)
        for (int c = c0; c <= c1; ++c) bucket[static_cast<std::size_t>(r) * g.cols + c].push_back(static_cast<std::uint32_t>(t));
    }
  }

  Hit at(int r, int c) const {
    Hit h;
    const Eigen::Vector3d o(g.x_of_col(c), g.y_of_row(r), z_top);
    for (const std::uint32_t t : bucket[static_cast<std::size_t>(r) * g.cols + c]) {
      const auto& tri = mesh.mesh.triangles[t];
      double tt, u, v;
      if (!moller_trumbore(o, mesh.xyz.col(tri[0]), mesh.xyz.col(tri[1]), mesh.xyz.col(tri[2]), tt, u, v)) continue;
      const double m = std::min({u, v, 1.0 - u - v});
      if (std::abs(m) <= kEdgeBand) h.ambiguous = true;
      if (m > kEdgeBand) {
        const double z = z_top - tt;
        if (!h.z || z > *h.z) {
          h.z = z;
          h.u = u;
          h.v = v;
          h.tri = t;
        }
      }
    }
    return h;
  }
};

struct Agreement {
  std::size_t covered = 0, covered_valid = 0, uncovered_valid = 0, ambiguous = 0, depth_off = 0;
  double max_dz = 0;
};

Agreement compare_with_oracle(const Cloud& mesh, const DepthGrid& grid, double z_tol) {
  const GridGeometry& g = grid.depth.geometry();
  const Oracle oracle(mesh, g);
  Agreement a;
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      const Hit h = oracle.at(r, c);
      if (h.ambiguous) {
        ++a.ambiguous;
        continue;
      }
      const float z = grid.depth.at(r, c);
      if (h.z) {
        ++a.covered;
        if (std::isnan(z)) continue;
        ++a.covered_valid;
        const double dz = std::abs(static_cast<double>(z) - *h.z);
        a.max_dz = std::max(a.max_dz, dz);
        a.depth_off += dz > z_tol ? 1 : 0;
      } else if (!std::isnan(z)) {
        ++a.uncovered_valid;
      }
    }
  }
  return a;
}

Cloud mesh_of(const std::vector<Eigen::Vector3d>& v, const std::vector<std::array<std::uint32_t, 3>>& t) {
  Cloud c;
  c.xyz.resize(3, static_cast<Eigen::Index>(v.size()));
  for (std::size_t i = 0; i < v.size(); ++i) c.xyz.col(static_cast<Eigen::Index>(i)) = v[i];
  c.mesh.triangles = t;
  return c;
}

ReprojectOptions options_with_n(int n) {
  ReprojectOptions o;
  o.grid.n_long_side = n;
  return o;
}

// A UV sphere of radius rad: closed, every edge shared by two triangles.
Cloud uv_sphere(double rad, int rings, int segments, double tilt) {
  std::vector<Eigen::Vector3d> v;
  std::vector<std::array<std::uint32_t, 3>> t;
  const Eigen::Matrix3d R = Eigen::AngleAxisd(tilt, Eigen::Vector3d(1, 2, 0.5).normalized()).toRotationMatrix();
  v.push_back(R * Eigen::Vector3d(0, 0, rad));
  for (int i = 1; i < rings; ++i) {
    const double th = M_PI * i / rings;
    for (int j = 0; j < segments; ++j) {
      const double ph = 2 * M_PI * j / segments;
      v.push_back(R * Eigen::Vector3d(rad * std::sin(th) * std::cos(ph), rad * std::sin(th) * std::sin(ph), rad * std::cos(th)));
    }
  }
  v.push_back(R * Eigen::Vector3d(0, 0, -rad));
  const auto S = static_cast<std::uint32_t>(segments);
  auto ring = [&](int i, int j) { return 1 + static_cast<std::uint32_t>(i - 1) * S + static_cast<std::uint32_t>(j % segments); };
  for (int j = 0; j < segments; ++j) t.push_back({0, ring(1, j), ring(1, j + 1)});
  for (int i = 1; i + 1 < rings; ++i) {
    for (int j = 0; j < segments; ++j) {
      t.push_back({ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)});
      t.push_back({ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)});
    }
  }
  const auto south = static_cast<std::uint32_t>(v.size() - 1);
  for (int j = 0; j < segments; ++j) t.push_back({south, ring(rings - 1, j + 1), ring(rings - 1, j)});
  return mesh_of(v, t);
}

void write_text(const fs::path& p, const std::string& s) {
  std::ofstream out(p, std::ios::binary);
  out << s;
}

bool has_note(const StageReport& r, const std::string& needle) {
  return std::any_of(r.notes.begin(), r.notes.end(), [&](const std::string& n) { return n.find(needle) != std::string::npos; });
}

// ---------------------------------------------------------------------------------------------
// The rasteriser against the oracle

TEST(MeshRaster, RandomTriangleSoupsMatchTheRayCastOracle) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    std::vector<Eigen::Vector3d> v;
    std::vector<std::array<std::uint32_t, 3>> t;
    const int n_tri = 5 + trial * 3;
    for (int k = 0; k < n_tri; ++k) {
      const auto b = static_cast<std::uint32_t>(v.size());
      for (int j = 0; j < 3; ++j) v.emplace_back(U(rng), U(rng), U(rng));
      t.push_back({b, b + 1, b + 2});
    }
    const Cloud m = mesh_of(v, t);
    const auto r = rasterise_mesh(m, options_with_n(37 + trial));
    const Agreement a = compare_with_oracle(m, r.value, 1e-6);
    SCOPED_TRACE("trial " + std::to_string(trial));
    EXPECT_GT(a.covered, 50u);
    EXPECT_EQ(a.covered_valid, a.covered) << "covered nodes the rasteriser missed";
    EXPECT_EQ(a.uncovered_valid, 0u) << "nodes the rasteriser filled outside every triangle";
    EXPECT_EQ(a.depth_off, 0u) << "max |dz| " << a.max_dz;
    EXPECT_LT(a.ambiguous, 3u);
  }
}

TEST(MeshRaster, ClosedSphereAndTetrahedronMatchTheOracleWithoutPinholes) {
  for (const double tilt : {0.0, 0.3, 1.1}) {
    const Cloud sphere = uv_sphere(0.05, 24, 40, tilt);
    const auto r = rasterise_mesh(sphere, options_with_n(161));
    const Agreement a = compare_with_oracle(sphere, r.value, 1e-7);
    EXPECT_GT(a.covered, 15000u);
    EXPECT_EQ(a.covered_valid, a.covered) << "tilt " << tilt;
    EXPECT_EQ(a.uncovered_valid, 0u) << "tilt " << tilt;
    EXPECT_EQ(a.depth_off, 0u) << "tilt " << tilt << " max |dz| " << a.max_dz;
    // Front-most: the visible half, never the far side. The polyhedron's outline runs within
    // one ring of the equator, so z ≥ −r·sin(π / rings) wherever it covers a node.
    const float z_min = static_cast<float>(-0.05 * std::sin(M_PI / 24));
    for (float z : r.value.depth.values()) {
      if (!std::isnan(z)) {
        EXPECT_GE(z, z_min);
      }
    }
  }
  const Cloud tet = mesh_of({{0, 0, 0}, {1, 0.1, 0.2}, {0.3, 0.9, 0.1}, {0.4, 0.35, 0.8}},
                            {{0, 2, 1}, {0, 1, 3}, {1, 2, 3}, {2, 0, 3}});
  const auto r = rasterise_mesh(tet, options_with_n(201));
  const Agreement a = compare_with_oracle(tet, r.value, 1e-7);
  EXPECT_GT(a.covered, 10000u);
  EXPECT_EQ(a.covered_valid, a.covered);
  EXPECT_EQ(a.uncovered_valid, 0u);
  EXPECT_EQ(a.depth_off, 0u) << a.max_dz;
}

TEST(MeshRaster, NodesExactlyOnSharedEdgesAndVerticesAreCovered) {
  // A tessellated square whose vertices and diagonals pass exactly through grid nodes (cell
  // 1/16, vertices at multiples of 1/8): the oracle is ambiguous on every edge, so the property
  // is checked directly: every node off the square's outer border holds data, at the plane's z.
  // Diagonals alternate so that both kinds of shared edge and 4- and 8-triangle fans occur.
  std::vector<Eigen::Vector3d> v;
  std::vector<std::array<std::uint32_t, 3>> t;
  auto plane = [](double x, double y) { return 0.25 * x - 0.125 * y + 0.5; };
  for (int i = 0; i <= 8; ++i)
    for (int j = 0; j <= 8; ++j) v.emplace_back(j / 8.0, i / 8.0, plane(j / 8.0, i / 8.0));
  auto id = [](int i, int j) { return static_cast<std::uint32_t>(i * 9 + j); };
  for (int i = 0; i < 8; ++i) {
    for (int j = 0; j < 8; ++j) {
      if ((i + j) % 2 == 0) {
        t.push_back({id(i, j), id(i, j + 1), id(i + 1, j + 1)});
        t.push_back({id(i, j), id(i + 1, j + 1), id(i + 1, j)});
      } else {
        t.push_back({id(i, j), id(i, j + 1), id(i + 1, j)});
        t.push_back({id(i + 1, j), id(i, j + 1), id(i + 1, j + 1)});  // clockwise on purpose
      }
    }
  }
  const Cloud m = mesh_of(v, t);
  const auto r = rasterise_mesh(m, options_with_n(17));
  const auto& g = r.value.depth.geometry();
  ASSERT_EQ(g.cols, 17);
  ASSERT_EQ(g.cell_size_m, 1.0 / 16.0);
  ASSERT_EQ(g.x0_m, 0.0);
  for (int rr = 1; rr + 1 < g.rows; ++rr) {
    for (int c = 1; c + 1 < g.cols; ++c) {
      const float z = r.value.depth.at(rr, c);
      ASSERT_FALSE(std::isnan(z)) << "pinhole at node " << rr << ", " << c;
      EXPECT_NEAR(z, plane(c / 16.0, rr / 16.0), 1e-6);
    }
  }
}

// Layer blending (organised scans of several views): three square sheets over the unit square,
// each two triangles, as three views of one surface: A at z = 0, B at z = 0.4 mm over the left
// half only (x ≤ 0.5), C 10 mm behind. With layer_blend_m = 1 mm the nodes under A and B take
// their mean, 0.2 mm; the nodes under A alone keep 0; C (beyond the blend depth) never enters.
// Without blending the front-most sheet wins (0.4 mm on the left).
TEST(MeshRaster, LayerBlendAveragesTheFacesNearTheFrontOnly) {
  auto sheet = [](double x1, double z, std::vector<Eigen::Vector3d>& v, std::vector<std::array<std::uint32_t, 3>>& t) {
    const auto b = static_cast<std::uint32_t>(v.size());
    v.insert(v.end(), {{0, 0, z}, {x1, 0, z}, {0, 1, z}, {x1, 1, z}});
    t.push_back({b, b + 1, b + 2});
    t.push_back({b + 1, b + 3, b + 2});
  };
  std::vector<Eigen::Vector3d> v;
  std::vector<std::array<std::uint32_t, 3>> t;
  sheet(1.0, 0.0, v, t);
  sheet(0.5, 0.0004, v, t);
  sheet(1.0, -0.01, v, t);
  const Cloud m = mesh_of(v, t);
  const auto front = rasterise_mesh(m, options_with_n(21));
  const auto blend = rasterise_mesh(m, options_with_n(21), 0.001);
  const GridGeometry& g = blend.value.depth.geometry();
  ASSERT_EQ(g.cols, 21);
  std::size_t both = 0;
  for (int r = 1; r + 1 < g.rows; ++r) {  // interior nodes: the outer edges follow the fill rule
    for (int c = 1; c + 1 < g.cols; ++c) {
      const double x = g.x_of_col(c);
      ASSERT_TRUE(blend.value.depth.valid(r, c)) << r << "," << c;
      if (x < 0.5 - 1e-9) {  // strictly inside B's x range: A and B both cover the node
        ++both;
        EXPECT_NEAR(blend.value.depth.at(r, c), 0.0002, 1e-7) << r << "," << c;
        EXPECT_NEAR(front.value.depth.at(r, c), 0.0004, 1e-7) << r << "," << c;
      } else if (x > 0.5 + 1e-9) {
        EXPECT_NEAR(blend.value.depth.at(r, c), 0.0, 1e-7) << r << "," << c;
      }
    }
  }
  EXPECT_EQ(both, 9u * static_cast<std::size_t>(g.rows - 2));  // x = 0.05 … 0.45
  EXPECT_GE(figure(blend.report, "cells_blended"), static_cast<double>(both));
  EXPECT_THROW((void)rasterise_mesh(m, options_with_n(21), -0.001), ConfigError);
  EXPECT_THROW((void)rasterise_mesh(m, options_with_n(21), std::numeric_limits<double>::quiet_NaN()), ConfigError);
}

TEST(MeshRaster, VertexColoursAndIntensityInterpolateBarycentrically) {
  Cloud m = mesh_of({{0, 0, 0}, {1, 0, 0.5}, {0.2, 1, 1}}, {{0, 1, 2}});
  m.rgb = {255, 0, 0, 0, 255, 0, 0, 0, 255};
  m.intensity = {0.0f, 1.0f, 0.5f};
  const auto r = rasterise_mesh(m, options_with_n(23));
  ASSERT_TRUE(r.value.has_colour());
  ASSERT_TRUE(r.value.has_intensity());
  const Oracle oracle(m, r.value.depth.geometry());
  const auto& g = r.value.depth.geometry();
  int checked = 0;
  for (int rr = 0; rr < g.rows; ++rr) {
    for (int c = 0; c < g.cols; ++c) {
      const Hit h = oracle.at(rr, c);
      if (!h.z || h.ambiguous) continue;
      const std::size_t i = static_cast<std::size_t>(rr) * g.cols + c;
      const double l[3] = {1 - h.u - h.v, h.u, h.v};
      for (int ch = 0; ch < 3; ++ch) EXPECT_NEAR(r.value.colour_rgb8[3 * i + ch], 255.0 * l[ch], 0.51);
      EXPECT_NEAR(r.value.intensity.at(rr, c), l[1] * 1.0 + l[2] * 0.5, 1e-6);
      EXPECT_NEAR(r.value.depth.at(rr, c), 0.5 * l[1] + 1.0 * l[2], 1e-6);
      ++checked;
    }
  }
  EXPECT_GT(checked, 150);
}

TEST(MeshRaster, TexturedObjGivesTheTexelColoursAtTexelCentres) {
  // A 4 × 4 texture with a distinct colour per texel; a unit square with vt = (x, y), so the
  // node at (x, y) samples u = x, v = y. At N = 9 (cell 1/8) the nodes with odd row and column
  // sit on texel centres: image column (c − 1)/2 and, v pointing up, image row (7 − r)/2.
  const fs::path dir = hc::test::temp_dir("tex");
  cv::Mat img(4, 4, CV_8UC3);
  auto colour = [](int row, int col) { return cv::Vec3b(static_cast<uchar>(10 + 60 * col), static_cast<uchar>(20 + 50 * row), static_cast<uchar>(200 - 13 * (row * 4 + col))); };  // RGB
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 4; ++x) {
      const cv::Vec3b rgb = colour(y, x);
      img.at<cv::Vec3b>(y, x) = cv::Vec3b(rgb[2], rgb[1], rgb[0]);  // OpenCV stores BGR
    }
  ASSERT_TRUE(cv::imwrite((dir / "checker.png").string(), img));
  write_text(dir / "sq.mtl", "newmtl stone\nKd 1 1 1\nmap_Kd -s 1 1 1 checker.png\n");
  write_text(dir / "sq.obj",
             "mtllib sq.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl stone\n"
             "f 1/1 2/2 3/3 4/4\n");
  const auto loaded = load_cloud(dir / "sq.obj");
  const Cloud& m = loaded.value;
  ASSERT_EQ(m.mesh.triangles.size(), 2u);
  ASSERT_TRUE(m.mesh.has_texture()) << ::testing::PrintToString(loaded.report.notes);
  EXPECT_TRUE(has_note(loaded.report, "polygons fan-split"));
  const auto r = rasterise_mesh(m, options_with_n(9));
  ASSERT_TRUE(r.value.has_colour());
  for (int rr = 1; rr < 9; rr += 2) {
    for (int c = 1; c < 9; c += 2) {
      const std::size_t i = static_cast<std::size_t>(rr) * 9 + c;
      const cv::Vec3b want = colour((7 - rr) / 2, (c - 1) / 2);
      for (int ch = 0; ch < 3; ++ch) EXPECT_EQ(r.value.colour_rgb8[3 * i + ch], want[ch]) << rr << ", " << c << " ch " << ch;
    }
  }
  // Between two texel centres (node (1, 2): u = 0.25, halfway between image columns 0 and 1).
  const std::size_t i = 1 * 9 + 2;
  const cv::Vec3b a = colour(3, 0), b = colour(3, 1);
  for (int ch = 0; ch < 3; ++ch) EXPECT_NEAR(r.value.colour_rgb8[3 * i + ch], 0.5 * (a[ch] + b[ch]), 0.51);
}

// ---------------------------------------------------------------------------------------------
// Readers: faces, polygons, colours, and drops that are never silent

TEST(MeshReaders, ObjFacesWithNegativeIndicesPolygonsAndBadCorners) {
  const fs::path dir = hc::test::temp_dir("obj");
  write_text(dir / "m.obj",
             "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 1.5 0\n"
             "f -5 -4 -3\n"           // triangle 1 2 3 by relative indices
             "f 1//1 3//1 4//1 5//1\n"  // quadrilateral → 2 triangles
             "f 1 2 9\n");            // vertex 9 does not exist: dropped, with a note
  const auto r = load_cloud(dir / "m.obj");
  ASSERT_EQ(r.value.mesh.triangles.size(), 3u);
  EXPECT_EQ(r.value.mesh.triangles[0], (std::array<std::uint32_t, 3>{0, 1, 2}));
  EXPECT_EQ(r.value.mesh.triangles[1], (std::array<std::uint32_t, 3>{0, 2, 3}));
  EXPECT_EQ(r.value.mesh.triangles[2], (std::array<std::uint32_t, 3>{0, 3, 4}));
  EXPECT_TRUE(has_note(r.report, "dropped 1 OBJ faces"));
  write_text(dir / "bad.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 x\n");
  try {
    (void)load_cloud(dir / "bad.obj");
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("line 4"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("bad.obj"), std::string::npos) << e.what();
  }
}

TEST(MeshReaders, PlyFacesAndVertexColoursInAsciiAndBinary) {
  const fs::path dir = hc::test::temp_dir("ply");
  const std::string head =
      "element vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\n"
      "property uchar green\nproperty uchar blue\nelement face 2\nproperty list uchar int vertex_indices\n"
      "end_header\n";
  write_text(dir / "a.ply", "ply\nformat ascii 1.0\n" + head +
                                "0 0 0 255 0 0\n1 0 0 0 255 0\n1 1 0 0 0 255\n0 1 0 9 8 7\n4 0 1 2 3\n3 0 2 3\n");
  std::string bin = "ply\nformat binary_little_endian 1.0\n" + head;
  const float xyz[4][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  const unsigned char rgb[4][3] = {{255, 0, 0}, {0, 255, 0}, {0, 0, 255}, {9, 8, 7}};
  for (int i = 0; i < 4; ++i) {
    bin.append(reinterpret_cast<const char*>(xyz[i]), 12);
    bin.append(reinterpret_cast<const char*>(rgb[i]), 3);
  }
  const int f0[4] = {0, 1, 2, 3}, f1[3] = {0, 2, 3};
  bin.push_back(4);
  bin.append(reinterpret_cast<const char*>(f0), sizeof f0);
  bin.push_back(3);
  bin.append(reinterpret_cast<const char*>(f1), sizeof f1);
  write_text(dir / "b.ply", bin);
  for (const char* name : {"a.ply", "b.ply"}) {
    const auto r = load_cloud(dir / name);
    ASSERT_EQ(r.value.size(), 4u) << name;
    ASSERT_EQ(r.value.mesh.triangles.size(), 3u) << name;  // the quad fan-split + the triangle
    EXPECT_EQ(r.value.mesh.triangles[1], (std::array<std::uint32_t, 3>{0, 2, 3})) << name;
    EXPECT_EQ(r.value.mesh.triangles[2], (std::array<std::uint32_t, 3>{0, 2, 3})) << name;
    ASSERT_EQ(r.value.rgb.size(), 12u) << name;
    EXPECT_EQ(r.value.rgb[9], 9) << name;
    EXPECT_EQ(r.value.rgb[11], 7) << name;
  }
}

TEST(MeshReaders, UnusableOrDroppedFacesAreNotedNeverSilent) {
  const fs::path dir = hc::test::temp_dir("drop");
  // Truncated face element: the vertices are read, the faces are dropped with a note.
  write_text(dir / "t.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                            "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
                            "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
  auto r = load_cloud(dir / "t.ply");
  EXPECT_EQ(r.value.size(), 3u);
  EXPECT_FALSE(r.value.has_mesh());
  EXPECT_TRUE(has_note(r.report, "dropped PLY element 'face'")) << ::testing::PrintToString(r.report.notes);
  // An index out of range drops that face.
  write_text(dir / "i.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                            "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
                            "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 7\n");
  r = load_cloud(dir / "i.ply");
  EXPECT_EQ(r.value.mesh.triangles.size(), 1u);
  EXPECT_TRUE(has_note(r.report, "dropped 1 PLY faces with a vertex index outside"));
  // input.as_points: the faces are dropped, and the report says so.
  LoadOptions points;
  points.as_points = true;
  r = load_cloud(dir / "i.ply", points);
  EXPECT_FALSE(r.value.has_mesh());
  EXPECT_TRUE(has_note(r.report, "input.as_points: dropped the 1 triangles"));
}

TEST(MeshReaders, KeepIfDropsTrianglesOfRemovedPointsAndRenumbers) {
  Cloud m = mesh_of({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}}, {{0, 1, 2}, {1, 3, 2}});
  m.mesh.corner_uv = {0, 0, 1, 0, 0, 1, 1, 0, 1, 1, 0, 1};
  m.keep_if({false, true, true, true});
  ASSERT_EQ(m.mesh.triangles.size(), 1u);
  EXPECT_EQ(m.mesh.triangles[0], (std::array<std::uint32_t, 3>{0, 2, 1}));
  EXPECT_EQ(m.mesh.corner_uv, (std::vector<float>{1, 0, 1, 1, 0, 1}));
}

// ---------------------------------------------------------------------------------------------
// Real meshes

Cloud recentred(Cloud c) { return to_metres_and_recentre(std::move(c), 1.0, nullptr).value; }

TEST(MeshRasterRealData, BunnyMeshAtN300CoversTheOracleSilhouette) {
  const auto loaded = load_cloud(hc::test::scan_path("bunny/bun_zipper_res2.ply"));
  ASSERT_EQ(loaded.value.mesh.triangles.size(), 16301u);  // the header's `element face 16301`
  const Cloud m = recentred(loaded.value);
  const auto r = rasterise_mesh(m, options_with_n(300));
  const Agreement a = compare_with_oracle(m, r.value, 1e-6);
  EXPECT_GT(a.covered, 40000u);
  EXPECT_EQ(a.covered_valid, a.covered);
  // The file's vertices on no face are binned as points: each may set (or lie in front at)
  // one node the faces leave empty (or lower); nothing else departs from the oracle.
  const double binned = figure(r.report, "vertices_binned_as_points");
  EXPECT_LE(static_cast<double>(a.uncovered_valid + a.depth_off), binned) << a.max_dz;
  EXPECT_LT(binned, 100.0);
  // The vertices as points (today's path) cover a small part of the same silhouette.
  const auto points = reproject(m, options_with_n(300));
  EXPECT_GT(figure(r.report, "cells_valid"), 5.0 * figure(points.report, "cells_valid"));
}

TEST(MeshRasterRealData, TexturedMaskObjCoversAtLeast99PercentOfItsSilhouette) {
  const fs::path obj = hc::test::scan_path("scanner_samples/mesh/balinese_mask/mask.obj");
  const auto loaded = load_cloud(obj);
  ASSERT_EQ(loaded.value.mesh.triangles.size(), 100000u);  // 100 000 `f` lines of 3 corners
  ASSERT_TRUE(loaded.value.mesh.has_texture()) << ::testing::PrintToString(loaded.report.notes);
  EXPECT_EQ(loaded.value.mesh.texture->width, 4096);
  const Cloud m = recentred(loaded.value);
  const auto r = rasterise_mesh(m, options_with_n(400));
  const Agreement a = compare_with_oracle(m, r.value, 1e-6);
  EXPECT_GT(a.covered, 50000u);
  EXPECT_GE(static_cast<double>(a.covered_valid), 0.99 * static_cast<double>(a.covered));
  EXPECT_EQ(a.covered_valid, a.covered);
  EXPECT_EQ(a.uncovered_valid, 0u);
  EXPECT_EQ(a.depth_off, 0u) << a.max_dz;
  ASSERT_TRUE(r.value.has_colour());
  // Textured, not flat: the colours of the valid cells vary.
  std::size_t distinct_red = 0;
  std::vector<bool> seen(256, false);
  for (std::size_t i = 0; i < r.value.flags.size(); ++i) {
    if (r.value.flags[i] != kCellMeasured) continue;
    const auto red = r.value.colour_rgb8[3 * i];
    distinct_red += seen[red] ? 0 : 1;
    seen[red] = true;
  }
  EXPECT_GT(distinct_red, 50u);
}

TEST(MeshRasterRealData, BuildSceneRasterisesTheBunnyMeshAndAsPointsKeepsTheVertices) {
  const fs::path file = hc::test::scan_path("bunny/bun_zipper_res2.ply");
  const std::string yaml = "input: {files: [" + file.string() + "], units: m}\ngrid: {n: 300}\n"
                           "filters: {outliers: {enabled: true}}\nlayers: {enabled: false}\n";
  const RunConfig mesh_cfg = parse_run_config(yaml, fs::path(HC_BINARY_DIR) / "mesh.yaml");
  EXPECT_FALSE(mesh_cfg.input.as_points);
  const BuiltScene mesh = build_scene(mesh_cfg);
  const RunConfig pts_cfg = parse_run_config(yaml, fs::path(HC_BINARY_DIR) / "mesh.yaml", {"input.as_points=true"});
  const BuiltScene pts = build_scene(pts_cfg);
  const double cells = static_cast<double>(mesh.summary.grid.cell_count());
  EXPECT_EQ(mesh.summary.grid.cell_count(), pts.summary.grid.cell_count());  // same grid rule
  // The figure for the vertices as points: 7.5 % of the cells; the faces cover the
  // silhouette (oracle: BunnyMeshAtN300CoversTheOracleSilhouette), several times more.
  EXPECT_LT(static_cast<double>(pts.summary.valid_cells) / cells, 0.10);
  EXPECT_GT(mesh.summary.valid_cells, 5 * pts.summary.valid_cells);
  auto stage = [](const BuiltScene& b, const std::string& name) -> const StageReport& {
    for (const auto& s : b.summary.stages)
      if (s.stage == name) return s;
    throw std::runtime_error("no stage " + name);
  };
  EXPECT_TRUE(has_note(stage(mesh, "ingest"), "16301 triangles read, 16301 rasterised"));
  EXPECT_TRUE(has_note(stage(mesh, "outliers"), "skipped for a mesh"));
  EXPECT_TRUE(has_note(stage(pts, "ingest"), "input.as_points: dropped the 16301 triangles"));
  ASSERT_TRUE(mesh.summary.cross_check.has_value());
  EXPECT_GT(mesh.summary.cross_check->point_normal.count, 1000u);  // the vertices as points
}

// ---------------------------------------------------------------------------------------------
// Scan-aware reconstruction: organised scans meshed on their own grid

TEST(OrganisedScans, NeighboursAreJoinedAndDepthJumpsCut) {
  // One scan, 20 × 20 samples 1 mm apart on z = 0, columns ≥ 10 raised by 10 mm (a step 10×
  // the spacing), sample (5, 5) missing. 19 × 19 quads: the 19 quads across the step lose both
  // triangles (38 cut); the 4 quads around the missing sample keep one triangle each (4 lost,
  // not cut: never formed). Kept: 2·(361 − 19 − 4) + 4 = 680.
  Cloud c;
  std::vector<Eigen::Vector3d> pts;
  for (int r = 0; r < 20; ++r) {
    for (int col = 0; col < 20; ++col) {
      if (r == 5 && col == 5) continue;
      pts.emplace_back(1e-3 * col, 1e-3 * r, col >= 10 ? 0.01 : 0.0);
      c.row.push_back(r);
      c.col.push_back(col);
    }
  }
  c.xyz.resize(3, static_cast<Eigen::Index>(pts.size()));
  for (std::size_t i = 0; i < pts.size(); ++i) c.xyz.col(static_cast<Eigen::Index>(i)) = pts[i];
  const auto m = mesh_organised_scans(c, 4.0);
  EXPECT_EQ(m.value.mesh.triangles.size(), 680u);
  EXPECT_EQ(figure(m.report, "triangles_cut"), 38.0);
  EXPECT_NEAR(figure(m.report, "median_spacing_mm"), 1.0, 1e-9);
  // No triangle joins the two levels.
  for (const auto& t : m.value.mesh.triangles) {
    const double z0 = m.value.xyz(2, t[0]);
    EXPECT_EQ(m.value.xyz(2, t[1]), z0);
    EXPECT_EQ(m.value.xyz(2, t[2]), z0);
  }
  // Rasterised: both levels covered, the step's gap (one cell at 0.5 mm cells) left open.
  const auto g = rasterise_mesh(m.value, options_with_n(39));
  EXPECT_TRUE(std::isnan(g.value.depth.at(10, 19)));  // x = 9.5 mm: between the levels
  EXPECT_NEAR(g.value.depth.at(10, 21), 0.01, 1e-7);
  EXPECT_NEAR(g.value.depth.at(10, 17), 0.0, 1e-7);
  // Sample (5, 5) is missing: its 4 quads keep one triangle each, leaving a diamond hole
  // around it (for hole filling to close), while its neighbours hold data.
  // In nodes (two per sample), the hole is the diamond |dr| + |dc| < 2 around node (10, 10);
  // |dr| + |dc| = 2 is its border (the tie rule decides), farther nodes lie inside triangles.
  for (int dr = -3; dr <= 3; ++dr) {
    for (int dc = -3; dc <= 3; ++dc) {
      const int d = std::abs(dr) + std::abs(dc);
      if (d < 2) {
        EXPECT_TRUE(std::isnan(g.value.depth.at(10 + dr, 10 + dc))) << dr << ", " << dc;
      } else if (d > 2) {
        EXPECT_FALSE(std::isnan(g.value.depth.at(10 + dr, 10 + dc))) << dr << ", " << dc;
      }
    }
  }
  // Without row/col: a clear error.
  Cloud plain;
  plain.xyz = c.xyz;
  EXPECT_THROW((void)mesh_organised_scans(plain, 4.0), InputError);
}

TEST(OrganisedScans, StanfordRangeGridGivesEachVertexItsScannerRowAndColumn) {
  const auto r = load_cloud(hc::test::scan_path("bunny/bun000.ply"));
  const Cloud& c = r.value;
  ASSERT_TRUE(c.has_grid_index()) << ::testing::PrintToString(r.report.notes);
  // obj_info num_cols 512, num_rows 400.
  EXPECT_EQ(*std::max_element(c.row.begin(), c.row.end()) < 400, true);
  EXPECT_EQ(*std::max_element(c.col.begin(), c.col.end()) < 512, true);
  // Grid neighbours are spatial neighbours: the median distance between samples one column
  // apart is far below the scan's extent (0.15 m) and near the 0.5 mm sample step (echo_lgincr).
  std::map<std::pair<int, int>, std::size_t> at;
  for (std::size_t i = 0; i < c.size(); ++i) at[{c.row[i], c.col[i]}] = i;
  std::vector<double> d;
  for (std::size_t i = 0; i < c.size(); ++i) {
    const auto it = at.find({c.row[i], c.col[i] + 1});
    if (it != at.end()) d.push_back((c.xyz.col(static_cast<Eigen::Index>(i)) - c.xyz.col(static_cast<Eigen::Index>(it->second))).norm());
  }
  ASSERT_GT(d.size(), 30000u);
  std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2), d.end());
  EXPECT_LT(d[d.size() / 2], 0.002);
}

struct SplatVsMesh {
  double corrugation_splat = 0, corrugation_mesh = 0, normal_rms_splat = 0, normal_rms_mesh = 0;
  double cell_rms_splat = 0, cell_rms_mesh = 0;
};

SplatVsMesh splat_vs_mesh(const RunConfig& splat, const RunConfig& mesh) {
  SplatVsMesh out;
  for (const RunConfig* cfg : {&splat, &mesh}) {
    const BuiltScene b = build_scene(*cfg);
    double corr = std::numeric_limits<double>::quiet_NaN();
    for (const auto& s : b.summary.stages)
      if (s.stage == "corrugation") corr = figure(s, "corrugation_um2");
    EXPECT_TRUE(b.summary.cross_check.has_value());
    const double rms = b.summary.cross_check ? b.summary.cross_check->point_normal.rms_mm : 0.0;
    (cfg == &splat ? out.corrugation_splat : out.corrugation_mesh) = corr;
    (cfg == &splat ? out.normal_rms_splat : out.normal_rms_mesh) = rms;
    (cfg == &splat ? out.cell_rms_splat : out.cell_rms_mesh) =
        b.summary.cross_check ? b.summary.cross_check->cell_to_point.rms_mm : 0.0;
  }
  return out;
}

TEST(OrganisedScansRealData, RawBunnyScansMeshedCorrugateFiveTimesLessWithoutLargerNormalError) {
  const fs::path dir = hc::test::scan_path("bunny");
  const std::string yaml = "input: {files: [" + (dir / "bun000.ply").string() + ", " + (dir / "bun045.ply").string() +
                           "], conf: " + (dir / "bun.conf").string() + "}\n"
                           "grid: {n: 300, splat_radius_cells: 1, see_through_depth_m: 0.003, hole_fill_max_cells: 32}\n"
                           "cross_check: {tolerance_m: 0.001}\nlayers: {enabled: false}\n";
  const fs::path origin = fs::path(HC_BINARY_DIR) / "bunny2.yaml";
  const SplatVsMesh r = splat_vs_mesh(parse_run_config(yaml, origin), parse_run_config(yaml, origin, {"grid.organised=mesh"}));
  EXPECT_GE(r.corrugation_splat, 5.0 * r.corrugation_mesh) << r.corrugation_splat << " vs " << r.corrugation_mesh;
  EXPECT_LE(r.normal_rms_mesh, r.normal_rms_splat) << r.normal_rms_mesh << " vs " << r.normal_rms_splat;
}

TEST(OrganisedScansRealData, RawBuddhaScansMeshedCorrugateFiveTimesLess) {
  (void)hc::test::scan_path("happy_buddha/raw_scans/happyStandRight.conf");
  const fs::path cfg = fs::path(HC_SOURCE_DIR) / "configs" / "buddha_raw_scans.yaml";
  const std::vector<std::string> common = {"layers.enabled=false"};
  auto with = [&](std::vector<std::string> extra) {
    extra.insert(extra.end(), common.begin(), common.end());
    return load_run_config(cfg, extra);
  };
  const SplatVsMesh r = splat_vs_mesh(with({"grid.organised=splat"}), with({"grid.organised=mesh"}));
  EXPECT_GE(r.corrugation_splat, 5.0 * r.corrugation_mesh) << r.corrugation_splat << " vs " << r.corrugation_mesh;
  // KNOWN GAP (issue "A surface you can trust"): the points-to-surface RMS along the normal
  // grows here (0.264 → 0.361 mm at N = 800): strips of the front surface narrower than a cell
  // at silhouettes cover no node, so their points float above the bilinear surface, where the
  // splats' 1.2-cell dilation covered them. The grid-to-points RMS is larger too (splat 0.131 mm,
  // mesh 0.162 mm, 2026-11-23). It was smaller (splat 0.199 mm) only while the splat grid's
  // hole filling bridged occlusion gaps (the config's grid.hole_fill_max_step_m now leaves
  // them empty). Recorded, not asserted, until the rasteriser handles sub-cell strips
  // (conservative coverage).
  RecordProperty("normal_rms_splat_mm", std::to_string(r.normal_rms_splat));
  RecordProperty("normal_rms_mesh_mm", std::to_string(r.normal_rms_mesh));
  RecordProperty("cell_rms_splat_mm", std::to_string(r.cell_rms_splat));
  RecordProperty("cell_rms_mesh_mm", std::to_string(r.cell_rms_mesh));
}

// Unorganised: the merged Buddha (1.1 M points of 15 registered views, no scan grid) with the
// example config; "mesh" in SplatVsMesh is here the plane splats.
TEST(UnorganisedScansRealData, MergedBuddhaPlaneSplatsCorrugateFiveTimesLessWithoutLargerNormalError) {
  (void)hc::test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz");
  const fs::path cfg = fs::path(HC_SOURCE_DIR) / "configs" / "happy_buddha.yaml";
  const SplatVsMesh r = splat_vs_mesh(load_run_config(cfg, {"layers.enabled=false", "grid.splat_mode=disc"}),
                                      load_run_config(cfg, {"layers.enabled=false", "grid.splat_mode=plane"}));
  EXPECT_GE(r.corrugation_splat, 5.0 * r.corrugation_mesh) << r.corrugation_splat << " vs " << r.corrugation_mesh;
  EXPECT_LE(r.normal_rms_mesh, r.normal_rms_splat) << r.normal_rms_mesh << " vs " << r.normal_rms_splat;
  RecordProperty("corrugation_disc_um2", std::to_string(r.corrugation_splat));
  RecordProperty("corrugation_plane_um2", std::to_string(r.corrugation_mesh));
}

}  // namespace
}  // namespace hc::pipeline
