// Height field → mesh export, read back with PCL's readers (pcl::io::loadPLYFile, PCL's own
// PLY parser; VTK's vtkSTLReader for STL): independent of the writer. The oracle
// is the construction: which cells have four valid corners, and the node positions.

#include "hc/pipeline/mesh_export.hpp"

#include "hc/common/error.hpp"

#include "test_paths.hpp"
#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <pcl/PolygonMesh.h>
#include <pcl/conversions.h>
#include <pcl/io/obj_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_types.h>
#include <vtkCell.h>
#include <vtkNew.h>
#include <vtkPolyData.h>
#include <vtkSTLReader.h>

#include <array>
#include <cstring>
#include <iterator>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <string>
#include <vector>

namespace hc::pipeline {
namespace {

namespace fs = std::filesystem;

// 6 rows × 7 columns of 2 mm cells, z = 1 mm + 0.1·x − 0.05·y, with a no-data node at (2, 3)
// (its 4 cells open) and a no-data row 5 except column 0 (an isolated valid node: no vertex).
struct Fixture {
  HeightField depth;
  std::vector<std::uint8_t> rgb;
  Fixture() : depth(GridGeometry{6, 7, 0.01, -0.02, 0.002}) {
    const GridGeometry& g = depth.geometry();
    rgb.resize(3 * g.cell_count());
    for (int r = 0; r < g.rows; ++r)
      for (int c = 0; c < g.cols; ++c) {
        depth.at(r, c) = static_cast<float>(0.001 + 0.1 * g.x_of_col(c) - 0.05 * g.y_of_row(r));
        const std::size_t i = static_cast<std::size_t>(r * g.cols + c);
        rgb[3 * i] = static_cast<std::uint8_t>(10 * r);
        rgb[3 * i + 1] = static_cast<std::uint8_t>(20 * c);
        rgb[3 * i + 2] = 7;
      }
    depth.at(2, 3) = std::numeric_limits<float>::quiet_NaN();
    for (int c = 1; c < g.cols; ++c) depth.at(5, c) = std::numeric_limits<float>::quiet_NaN();
  }
  bool quad(int r, int c) const {
    return depth.valid(r, c) && depth.valid(r, c + 1) && depth.valid(r + 1, c) && depth.valid(r + 1, c + 1);
  }
};

// The node (r, c) whose position a vertex has, by exact float match; (-1, -1) if none.
// `scale`: file units per metre (1000 for STL's millimetres).
std::array<int, 2> node_of(const GridGeometry& g, const HeightField& d, float x, float y, float z, double scale = 1.0) {
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c)
      if (d.valid(r, c) && static_cast<float>(scale * g.x_of_col(c)) == x && static_cast<float>(scale * g.y_of_row(r)) == y &&
          static_cast<float>(scale * static_cast<double>(d.at(r, c))) == z)
        return {r, c};
  return {-1, -1};
}

// Checks the triangles (as node triples) against the construction: each valid quad exactly
// twice, nothing else, counter-clockwise seen from +z.
void expect_triangles_tile_the_valid_quads(const Fixture& f, const std::vector<std::array<std::array<int, 2>, 3>>& tris) {
  const GridGeometry& g = f.depth.geometry();
  std::map<std::pair<int, int>, int> per_quad;
  for (const auto& t : tris) {
    int r0 = 1 << 30, c0 = 1 << 30;
    for (const auto& n : t) {
      ASSERT_GE(n[0], 0) << "a vertex is not a valid node";
      r0 = std::min(r0, n[0]);
      c0 = std::min(c0, n[1]);
    }
    for (const auto& n : t) {
      EXPECT_LE(n[0] - r0, 1);
      EXPECT_LE(n[1] - c0, 1);
    }
    EXPECT_TRUE(f.quad(r0, c0)) << r0 << "," << c0;
    ++per_quad[{r0, c0}];
    // Orientation in x-y (x = column, y = row, both increasing): positive signed area.
    const double ax = t[1][1] - t[0][1], ay = t[1][0] - t[0][0], bx = t[2][1] - t[0][1], by = t[2][0] - t[0][0];
    EXPECT_GT(ax * by - ay * bx, 0.0);
  }
  std::size_t quads = 0;
  for (int r = 0; r + 1 < g.rows; ++r)
    for (int c = 0; c + 1 < g.cols; ++c)
      if (f.quad(r, c)) {
        ++quads;
        EXPECT_EQ((per_quad[{r, c}]), 2) << r << "," << c;
      }
  EXPECT_EQ(tris.size(), 2 * quads);
  EXPECT_EQ(quads, 5u * 6u - 4u - 6u);  // 30 cells less the 4 around the hole and the 6 touching row 5
}

TEST(MeshExport, PlyReadBackByPclHasTheValidNodesTheirColoursAndTwoTrianglesPerValidCell) {
  const Fixture f;
  const GridGeometry& g = f.depth.geometry();
  const HeightMesh m = triangulate_height_field(f.depth, f.rgb);
  const fs::path file = hc::test::temp_dir("mesh_export") / "grid.ply";
  fs::remove(file);
  write_mesh(m, file, MeshFormat::kPly, {"recentre_offset_m 1 2 3"});
  pcl::PolygonMesh mesh;
  ASSERT_EQ(pcl::io::loadPLYFile(file.string(), mesh), 0);
  pcl::PointCloud<pcl::PointXYZRGB> cloud;
  pcl::fromPCLPointCloud2(mesh.cloud, cloud);
  // Vertices: every node that is a corner of a valid cell (the isolated node (5, 0) is not).
  std::set<std::pair<int, int>> corners;
  for (int r = 0; r + 1 < g.rows; ++r)
    for (int c = 0; c + 1 < g.cols; ++c)
      if (f.quad(r, c)) corners.insert({{r, c}, {r, c + 1}, {r + 1, c}, {r + 1, c + 1}});
  ASSERT_EQ(cloud.size(), corners.size());
  std::vector<std::array<int, 2>> node(cloud.size());
  for (std::size_t v = 0; v < cloud.size(); ++v) {
    const auto& p = cloud[v];
    node[v] = node_of(g, f.depth, p.x, p.y, p.z);
    ASSERT_GE(node[v][0], 0) << v;
    EXPECT_TRUE(corners.count({node[v][0], node[v][1]}));
    const std::size_t i = static_cast<std::size_t>(node[v][0] * g.cols + node[v][1]);
    EXPECT_EQ(p.r, f.rgb[3 * i]);
    EXPECT_EQ(p.g, f.rgb[3 * i + 1]);
    EXPECT_EQ(p.b, f.rgb[3 * i + 2]);
  }
  std::vector<std::array<std::array<int, 2>, 3>> tris;
  for (const auto& poly : mesh.polygons) {
    ASSERT_EQ(poly.vertices.size(), 3u);
    tris.push_back({node[poly.vertices[0]], node[poly.vertices[1]], node[poly.vertices[2]]});
  }
  expect_triangles_tile_the_valid_quads(f, tris);
}

TEST(MeshExport, StlReadBackThroughVtkIsInMillimetresWithTwoTrianglesPerValidCellFacingTheViewer) {
  const Fixture f;
  const GridGeometry& g = f.depth.geometry();
  const fs::path file = hc::test::temp_dir("mesh_export") / "grid.stl";
  fs::remove(file);
  write_mesh(triangulate_height_field(f.depth, {}), file, MeshFormat::kStl);
  // Binary STL: 80 + 4 + 50 bytes per triangle, the count at bytes 80-83 (little-endian), and
  // every stored normal facing the viewer (+z), read from the bytes directly.
  std::ifstream raw(file, std::ios::binary);
  std::vector<char> bytes((std::istreambuf_iterator<char>(raw)), std::istreambuf_iterator<char>());
  ASSERT_GE(bytes.size(), 84u);
  std::uint32_t tri_count = 0;
  std::memcpy(&tri_count, bytes.data() + 80, 4);
  EXPECT_EQ(bytes.size(), 84 + 50 * std::size_t{tri_count});
  for (std::uint32_t t = 0; t < tri_count && 84 + 50 * std::size_t{t} + 12 <= bytes.size(); ++t) {
    float n[3];
    std::memcpy(n, bytes.data() + 84 + 50 * std::size_t{t}, 12);
    EXPECT_GT(n[2], 0.0f) << t;
    EXPECT_NEAR(n[0] * n[0] + n[1] * n[1] + n[2] * n[2], 1.0f, 1e-5f) << t;
  }
  // VTK's reader directly: pcl::io::loadPolygonFileSTL frees, in our code (C++17 or later: aligned new), a PointCloud
  // that Debian's (C++14) libpcl allocated with Eigen's aligned malloc, an alloc-dealloc
  // mismatch under AddressSanitizer (harmless in release, where both reach glibc's free).
  vtkNew<vtkSTLReader> reader;
  reader->SetFileName(file.c_str());
  reader->Update();
  vtkPolyData* poly = reader->GetOutput();
  ASSERT_NE(poly, nullptr);
  ASSERT_GT(poly->GetNumberOfCells(), 0);
  std::vector<std::array<std::array<int, 2>, 3>> tris;
  for (vtkIdType cell = 0; cell < poly->GetNumberOfCells(); ++cell) {
    vtkCell* tri = poly->GetCell(cell);
    ASSERT_EQ(tri->GetNumberOfPoints(), 3);
    std::array<std::array<int, 2>, 3> t{};
    for (int k = 0; k < 3; ++k) {
      double p[3];
      poly->GetPoint(tri->GetPointId(k), p);
      t[static_cast<std::size_t>(k)] = node_of(g, f.depth, static_cast<float>(p[0]), static_cast<float>(p[1]),
                                               static_cast<float>(p[2]), 1000.0);  // millimetres
    }
    tris.push_back(t);
  }
  EXPECT_EQ(tris.size(), tri_count);
  expect_triangles_tile_the_valid_quads(f, tris);
}

TEST(MeshExport, ObjReadBackByPclWithItsTextureGivesEveryVertexItsNodesColour) {
  const Fixture f;
  const GridGeometry& g = f.depth.geometry();
  const fs::path dir = hc::test::temp_dir("mesh_export_obj");
  for (const char* name : {"grid.obj", "grid.mtl", "grid.png"}) fs::remove(dir / name);
  write_mesh(triangulate_height_field(f.depth, f.rgb), dir / "grid.obj", MeshFormat::kObj);
  ASSERT_TRUE(fs::exists(dir / "grid.mtl"));
  ASSERT_TRUE(fs::exists(dir / "grid.png"));
  pcl::TextureMesh mesh;
  ASSERT_EQ(pcl::io::loadOBJFile((dir / "grid.obj").string(), mesh), 0);
  pcl::PointCloud<pcl::PointXYZ> cloud;
  pcl::fromPCLPointCloud2(mesh.cloud, cloud);
  ASSERT_EQ(mesh.tex_polygons.size(), 1u);
  ASSERT_EQ(mesh.tex_materials.size(), 1u);
  EXPECT_EQ(fs::path(mesh.tex_materials[0].tex_file).filename(), "grid.png");
  // The texture read by OpenCV, sampled (nearest texel) at each vertex's (u, v), v from the
  // image's bottom, is the colour layer at the vertex's node.
  const cv::Mat bgr = cv::imread((dir / "grid.png").string(), cv::IMREAD_COLOR);
  ASSERT_EQ(bgr.rows, g.rows);
  ASSERT_EQ(bgr.cols, g.cols);
  ASSERT_EQ(mesh.tex_coordinates.size(), 1u);
  std::vector<std::array<std::array<int, 2>, 3>> tris;
  ASSERT_EQ(mesh.tex_coord_indices.size(), 1u);
  for (std::size_t t = 0; t < mesh.tex_polygons[0].size(); ++t) {
    const auto& poly = mesh.tex_polygons[0][t];
    ASSERT_EQ(poly.vertices.size(), 3u);
    std::array<std::array<int, 2>, 3> tri{};
    for (int k = 0; k < 3; ++k) {
      const auto& p = cloud[poly.vertices[static_cast<std::size_t>(k)]];
      const auto node = node_of(g, f.depth, p.x, p.y, p.z);  // 9 significant digits: exact in float
      tri[static_cast<std::size_t>(k)] = node;
      ASSERT_GE(node[0], 0);
      const Eigen::Vector2f uv = mesh.tex_coordinates[0][mesh.tex_coord_indices[0][t].vertices[static_cast<std::size_t>(k)]];
      const int col = static_cast<int>(std::floor(uv.x() * static_cast<float>(g.cols)));
      const int row = g.rows - 1 - static_cast<int>(std::floor(uv.y() * static_cast<float>(g.rows)));
      const cv::Vec3b px = bgr.at<cv::Vec3b>(row, col);
      const std::size_t i = static_cast<std::size_t>(node[0] * g.cols + node[1]);
      EXPECT_EQ(px[2], f.rgb[3 * i]);
      EXPECT_EQ(px[1], f.rgb[3 * i + 1]);
      EXPECT_EQ(px[0], f.rgb[3 * i + 2]);
    }
    tris.push_back(tri);
  }
  expect_triangles_tile_the_valid_quads(f, tris);
}

TEST(MeshExport, AnExistingFileIsNeverOverwrittenAndBadArgumentsAreNamed) {
  const Fixture f;
  const fs::path dir = hc::test::temp_dir("mesh_export_refuse");
  const fs::path file = dir / "mine.ply";
  { std::ofstream(file) << "the user's file"; }
  try {
    write_mesh(triangulate_height_field(f.depth, f.rgb), file, MeshFormat::kPly);
    ADD_FAILURE() << "no error";
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("exists already"), std::string::npos) << e.what();
  }
  std::ifstream in(file);
  std::string text;
  std::getline(in, text);
  EXPECT_EQ(text, "the user's file");
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator{}), 1);  // no temporary left
  EXPECT_THROW(write_mesh(triangulate_height_field(f.depth, f.rgb), dir / "no_such_folder" / "a.stl", MeshFormat::kStl),
               hc::InputError);
  try {
    (void)parse_mesh_format("gltf");
    ADD_FAILURE() << "no error";
  } catch (const hc::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("'gltf': expected one of: ply, stl, obj"), std::string::npos) << e.what();
  }
  EXPECT_THROW((void)triangulate_height_field(f.depth, std::vector<std::uint8_t>(5)), std::invalid_argument);
  // An OBJ whose texture name is taken: refused before anything is written.
  { std::ofstream(dir / "tex.png") << "the user's picture"; }
  EXPECT_THROW(write_mesh(triangulate_height_field(f.depth, f.rgb), dir / "tex.obj", MeshFormat::kObj), hc::InputError);
  EXPECT_FALSE(fs::exists(dir / "tex.obj"));
  EXPECT_FALSE(fs::exists(dir / "tex.mtl"));
  EXPECT_EQ(fs::file_size(dir / "tex.png"), std::string("the user's picture").size());
  // --out naming a companion.
  EXPECT_THROW(write_mesh(triangulate_height_field(f.depth, f.rgb), dir / "x.png", MeshFormat::kObj), hc::InputError);
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator{}), 2);  // mine.ply, tex.png only
}

}  // namespace
}  // namespace hc::pipeline
