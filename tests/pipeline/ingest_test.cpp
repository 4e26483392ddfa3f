// Stage 1 tests: every supported format on real scans and small generated fixtures, the
// scanalyze pose convention on neighbouring Buddha views, and bad input.

#include "hc/common/error.hpp"
#include "hc/pipeline/ingest.hpp"
#include "error_of.hpp"
#include "test_paths.hpp"
#include "file_bytes.hpp"

#include <gtest/gtest.h>
#include <nanoflann.hpp>
#include <pcl/PCLPointCloud2.h>
#include <pcl/io/ply_io.h>
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

namespace hp = hc::pipeline;
namespace fs = std::filesystem;

namespace {

using hc::test::read_bytes;

void write_text(const fs::path& p, const std::string& text) {
  std::ofstream out(p, std::ios::binary);
  out << text;
}

using hc::test::write_gzip;

// Three points with georeferenced double coordinates (not representable in float).
const double kGeo[3][3] = {{450000.123456789, 5200000.987654321, 310.000000001},
                           {450001.5, 5200002.25, 311.125},
                           {-0.1, 1e-9, 123456.789012345}};

std::string double_ply_ascii() {
  std::string s = "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\n"
                  "end_header\n";
  char buf[128];
  for (const auto& p : kGeo) {
    std::snprintf(buf, sizeof buf, "%.17g %.17g %.17g\n", p[0], p[1], p[2]);
    s += buf;
  }
  return s;
}

// Binary little-endian PLY of n vertices (float x, y, z, uchar flag), followed by a face list.
std::string float_ply_binary(int n, int declared) {
  std::string s = "ply\nformat binary_little_endian 1.0\ncomment made by a test\nelement vertex " +
                  std::to_string(declared) +
                  "\nproperty float x\nproperty float y\nproperty float z\nproperty uchar flag\n"
                  "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
  for (int i = 0; i < n; ++i) {
    const float v[3] = {0.001f * static_cast<float>(i), -0.5f * static_cast<float>(i), 2.0f};
    s.append(reinterpret_cast<const char*>(v), sizeof v);
    s.push_back(static_cast<char>(i & 0x7f));
  }
  const unsigned char count = 3;
  const int idx[3] = {0, 1, 2};
  s.push_back(static_cast<char>(count));
  s.append(reinterpret_cast<const char*>(idx), sizeof idx);
  return s;
}

using hc::test::error_of;

// Appends the bytes of v to s, most significant first (PLY binary_big_endian).
template <class T>
void append_big_endian(std::string& s, T v) {
  char b[sizeof v];
  std::memcpy(b, &v, sizeof v);
  if constexpr (std::endian::native == std::endian::little) std::reverse(b, b + sizeof v);
  s.append(b, sizeof v);
}

// Median distance from each point of `a` to its nearest neighbour in `b`, over the points
// whose nearest neighbour lies within `overlap_m` (the overlap of two views).
struct Overlap {
  double median_m = 0;
  std::size_t pairs = 0;
};

struct Points {
  std::vector<double> p;
  std::size_t kdtree_get_point_count() const { return p.size() / 3; }
  double kdtree_get_pt(std::size_t i, int d) const { return p[3 * i + static_cast<std::size_t>(d)]; }
  template <class B>
  bool kdtree_get_bbox(B&) const {
    return false;
  }
};

Overlap overlap(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b, double overlap_m) {
  Points pb;
  pb.p.assign(b.data(), b.data() + b.size());
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, Points>, Points, 3>;
  Tree tree(3, pb, nanoflann::KDTreeSingleIndexAdaptorParams(16));
  std::vector<double> d;
  for (Eigen::Index i = 0; i < a.cols(); ++i) {
    std::uint32_t idx = 0;
    double d2 = 0;
    const Eigen::Vector3d q = a.col(i);
    tree.knnSearch(q.data(), 1, &idx, &d2);
    if (std::sqrt(d2) <= overlap_m) d.push_back(std::sqrt(d2));
  }
  Overlap o;
  o.pairs = d.size();
  if (d.empty()) return o;
  std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2), d.end());
  o.median_m = d[d.size() / 2];
  return o;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Real scans

TEST(Ingest, ReadsBunnyRangeScanPlyWithObjInfoAndRangeGrid) {
  const auto r = hp::load_cloud(hc::test::scan_path("bunny/bun000.ply"));
  const hp::Cloud& c = r.value;
  ASSERT_EQ(c.size(), 40256u);
  EXPECT_FALSE(c.has_scan_id());
  // First vertex line of the file: -0.06325 0.0359793 0.0420873 (float properties).
  EXPECT_EQ(c.xyz(0, 0), static_cast<double>(-0.06325f));
  EXPECT_EQ(c.xyz(1, 0), static_cast<double>(0.0359793f));
  EXPECT_EQ(c.xyz(2, 0), static_cast<double>(0.0420873f));
  const Eigen::Vector3d lo = c.xyz.rowwise().minCoeff(), hi = c.xyz.rowwise().maxCoeff();
  EXPECT_NEAR(lo.x(), -0.0948, 1e-4);
  EXPECT_NEAR(lo.y(), 0.0357, 1e-4);
  EXPECT_NEAR(hi.y(), 0.1879, 1e-4);
  EXPECT_NEAR(hi.z(), 0.0587, 1e-4);
  EXPECT_EQ(r.report.count_in, 40256u);
  EXPECT_EQ(r.report.count_out, 40256u);
  EXPECT_GT(r.report.seconds, 0.0);
  const auto& notes = r.report.notes;
  EXPECT_TRUE(std::any_of(notes.begin(), notes.end(),
                          [](const std::string& s) { return s.find("range_grid") != std::string::npos; }));
}

TEST(Ingest, ReadsGzippedBuddhaScansWithStrayByeHeaderLines) {
  // Views 0, 48, 72 and 96 have three `bye` lines in their headers.
  const std::pair<const char*, std::size_t> views[] = {{"happyStandRight_0.ply.gz", 78056},
                                                       {"happyStandRight_48.ply.gz", 69158},
                                                       {"happyStandRight_72.ply.gz", 61872},
                                                       {"happyStandRight_96.ply.gz", 62682}};
  for (const auto& [file, count] : views) {
    const auto r = hp::load_cloud(hc::test::scan_path(std::string("happy_buddha/raw_scans/") + file));
    EXPECT_EQ(r.value.size(), count) << file;
    EXPECT_TRUE(r.value.xyz.allFinite()) << file;
    const Eigen::Vector3d lo = r.value.xyz.rowwise().minCoeff(), hi = r.value.xyz.rowwise().maxCoeff();
    EXPECT_GT(lo.y(), 0.049) << file;
    EXPECT_LT(hi.y(), 0.250) << file;
  }
}

TEST(Ingest, ReadsMergedBinaryBuddhaPlyGz) {
  const auto r = hp::load_cloud(hc::test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz"));
  const hp::Cloud& c = r.value;
  ASSERT_EQ(c.size(), 1099005u);
  const Eigen::Vector3d lo = c.xyz.rowwise().minCoeff(), hi = c.xyz.rowwise().maxCoeff();
  const Eigen::Vector3d want_lo(-0.0467, 0.0490, -0.0478), want_hi(0.0358, 0.2490, 0.0346);
  for (int a = 0; a < 3; ++a) {
    EXPECT_NEAR(lo[a], want_lo[a], 1e-4);
    EXPECT_NEAR(hi[a], want_hi[a], 1e-4);
  }
  EXPECT_FALSE(c.has_scan_id());  // per-file loads leave scan_id empty
}

// The direct fixed-stride read of binary PLY vertices against PCL's PLY reader (the oracle) on
// the whole merged Buddha: every coordinate identical.
TEST(Ingest, DirectBinaryPlyReadEqualsPclReader) {
  const fs::path gz = hc::test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz");
  const auto ours = hp::load_cloud(gz);
  const fs::path dir = hc::test::temp_dir("oracle");
  {
    gzFile f = gzopen(gz.string().c_str(), "rb");
    ASSERT_NE(f, nullptr);
    std::ofstream out(dir / "merged.ply", std::ios::binary);
    std::vector<char> buf(1 << 20);
    for (int n; (n = gzread(f, buf.data(), static_cast<unsigned>(buf.size()))) > 0;) out.write(buf.data(), n);
    gzclose(f);
  }
  pcl::PCLPointCloud2 pc;
  pcl::PLYReader reader;
  ASSERT_EQ(reader.read((dir / "merged.ply").string(), pc), 0);
  fs::remove_all(dir);
  ASSERT_EQ(static_cast<std::size_t>(pc.width) * pc.height, ours.value.size());
  ASSERT_EQ(pc.fields.size(), 4u);  // x, y, z float32 and scan_id uint8
  std::size_t mismatches = 0;
  for (std::size_t i = 0; i < ours.value.size(); ++i) {
    for (int a = 0; a < 3; ++a) {
      float v;
      std::memcpy(&v, pc.data.data() + i * pc.point_step + pc.fields[static_cast<std::size_t>(a)].offset, 4);
      mismatches += static_cast<double>(v) == ours.value.xyz(a, static_cast<Eigen::Index>(i)) ? 0u : 1u;
    }
  }
  EXPECT_EQ(mismatches, 0u);
}

// The direct ASCII read against PCL's PLY reader on a raw range scan: PCL returns the range
// grid (NaN where empty); its valid cells in grid order are the vertices in file order.
TEST(Ingest, DirectAsciiPlyReadEqualsPclReader) {
  const fs::path file = hc::test::scan_path("bunny/bun000.ply");
  const auto ours = hp::load_cloud(file);
  pcl::PCLPointCloud2 pc;
  pcl::PLYReader reader;
  ASSERT_EQ(reader.read(file.string(), pc), 0);
  std::vector<Eigen::Vector3d> theirs;
  for (std::size_t i = 0; i < static_cast<std::size_t>(pc.width) * pc.height; ++i) {
    float v[3];
    for (int a = 0; a < 3; ++a) {
      std::memcpy(&v[a], pc.data.data() + i * pc.point_step + pc.fields[static_cast<std::size_t>(a)].offset, 4);
    }
    if (std::isfinite(v[0])) theirs.emplace_back(v[0], v[1], v[2]);
  }
  ASSERT_EQ(theirs.size(), ours.value.size());
  std::size_t mismatches = 0;
  for (std::size_t i = 0; i < theirs.size(); ++i) {
    mismatches += theirs[i] == ours.value.xyz.col(static_cast<Eigen::Index>(i)) ? 0u : 1u;
  }
  EXPECT_EQ(mismatches, 0u);
}

TEST(Ingest, ReadsBigEndianBinaryPlyWithMixedTypes) {
  const fs::path dir = hc::test::temp_dir("be");
  std::string s = "ply\nformat binary_big_endian 1.0\nelement camera 1\nproperty float f\n"
                  "element vertex 2\nproperty short z\nproperty uchar r\nproperty double x\nproperty int y\n"
                  "end_header\n";
  auto put = [&](auto v) { append_big_endian(s, v); };
  put(1.5f);
  put(std::int16_t{-7});
  put(std::uint8_t{200});
  put(450000.123456789);
  put(std::int32_t{-123456});
  put(std::int16_t{300});
  put(std::uint8_t{1});
  put(-2.5);
  put(std::int32_t{42});
  write_text(dir / "be.ply", s);
  const auto r = hp::load_cloud(dir / "be.ply");
  ASSERT_EQ(r.value.size(), 2u);
  EXPECT_EQ(r.value.xyz.col(0), Eigen::Vector3d(450000.123456789, -123456, -7));
  EXPECT_EQ(r.value.xyz.col(1), Eigen::Vector3d(-2.5, 42, 300));
}

// Above 2^17 vertices the fixed-stride read decodes two halves of the records on two threads.
// A big-endian file of 200 001 vertices (odd: the halves differ in size) with mixed types and
// 8-bit colour, each vertex's values a function of its index: every coordinate and colour byte
// is the one written, on both sides of the split.
TEST(Ingest, ABigBinaryPlyWithColourIsReadWholeOnBothHalves) {
  const fs::path dir = hc::test::temp_dir("big_be");
  constexpr int kVertices = 200001;
  std::string s = "ply\nformat binary_big_endian 1.0\nelement vertex " + std::to_string(kVertices) +
                  "\nproperty double x\nproperty int y\nproperty short z\nproperty uchar red\nproperty uchar green"
                  "\nproperty uchar blue\nend_header\n";
  auto put = [&](auto v) { append_big_endian(s, v); };
  auto x_of = [](int i) { return 1000.25 + 0.5 * i; };
  auto y_of = [](int i) { return static_cast<std::int32_t>(-3 * i); };
  auto z_of = [](int i) { return static_cast<std::int16_t>(i % 30000 - 15000); };
  for (int i = 0; i < kVertices; ++i) {
    put(x_of(i));
    put(y_of(i));
    put(z_of(i));
    put(static_cast<std::uint8_t>(i & 0xff));
    put(static_cast<std::uint8_t>((i >> 8) & 0xff));
    put(static_cast<std::uint8_t>(255 - (i & 0xff)));
  }
  write_text(dir / "big.ply", s);
  const auto r = hp::load_cloud(dir / "big.ply");
  ASSERT_EQ(r.value.size(), static_cast<std::size_t>(kVertices));
  ASSERT_EQ(r.value.rgb.size(), 3U * kVertices);
  std::size_t wrong_xyz = 0, wrong_rgb = 0;
  for (int i = 0; i < kVertices; ++i) {
    const Eigen::Vector3d want(x_of(i), y_of(i), z_of(i));
    wrong_xyz += r.value.xyz.col(i) == want ? 0U : 1U;
    const auto k = 3 * static_cast<std::size_t>(i);
    wrong_rgb += r.value.rgb[k] == (i & 0xff) && r.value.rgb[k + 1] == ((i >> 8) & 0xff) &&
                         r.value.rgb[k + 2] == 255 - (i & 0xff)
                     ? 0U
                     : 1U;
  }
  EXPECT_EQ(wrong_xyz, 0U);
  EXPECT_EQ(wrong_rgb, 0U);
}

TEST(Ingest, ReadsOldVersionPcd) {
  const auto r = hp::load_cloud(hc::test::scan_path("bunny/pcl_bunny.pcd"));
  ASSERT_EQ(r.value.size(), 397u);
  EXPECT_EQ(r.value.xyz(0, 0), static_cast<double>(0.0054216f));
  EXPECT_EQ(r.value.xyz(2, 1), static_cast<double>(0.041273f));
  const Eigen::Vector3d lo = r.value.xyz.rowwise().minCoeff(), hi = r.value.xyz.rowwise().maxCoeff();
  EXPECT_NEAR(lo.x(), -0.0939, 1e-4);
  EXPECT_NEAR(hi.y(), 0.1845, 1e-4);
}

TEST(Ingest, ReadsVerticesOfAPlyMeshWithFacesAndExtraProperties) {
  const auto r = hp::load_cloud(hc::test::scan_path("bunny/bun_zipper_res2.ply"));
  ASSERT_EQ(r.value.size(), 8171u);
  EXPECT_EQ(r.value.xyz(0, 0), static_cast<double>(-0.036872f));
  EXPECT_EQ(r.value.xyz(2, 2), static_cast<double>(0.0366018f));
}

// ---------------------------------------------------------------------------------------------
// Generated fixtures

TEST(Ingest, KeepsDoublePropertiesExactlyInAsciiBinaryAndGzipPly) {
  const fs::path dir = hc::test::temp_dir("double");
  write_text(dir / "geo.ply", double_ply_ascii());
  std::string bin = "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
                    "property double z\nend_header\n";
  for (const auto& p : kGeo) bin.append(reinterpret_cast<const char*>(p), sizeof p);
  write_text(dir / "geo_bin.ply", bin);
  write_gzip(dir / "geo_bin.ply.gz", bin);
  write_gzip(dir / "geo.PLY.GZ", double_ply_ascii());
  for (const char* name : {"geo.ply", "geo_bin.ply", "geo_bin.ply.gz", "geo.PLY.GZ"}) {
    const auto r = hp::load_cloud(dir / name);
    ASSERT_EQ(r.value.size(), 3u) << name;
    for (int i = 0; i < 3; ++i)
      for (int a = 0; a < 3; ++a) EXPECT_EQ(r.value.xyz(a, i), kGeo[i][a]) << name << " point " << i;
  }
}

TEST(Ingest, ReadsBinaryPlyWithExtraPropertiesAndTrailingFaces) {
  const fs::path dir = hc::test::temp_dir("bin");
  write_text(dir / "v.ply", float_ply_binary(100, 100));
  const auto r = hp::load_cloud(dir / "v.ply");
  ASSERT_EQ(r.value.size(), 100u);
  EXPECT_EQ(r.value.xyz(0, 37), static_cast<double>(0.001f * 37.0f));
  EXPECT_EQ(r.value.xyz(1, 99), -49.5);
  EXPECT_EQ(r.value.xyz(2, 50), 2.0);
}

TEST(Ingest, ReadsCrlfAsciiPly) {
  const fs::path dir = hc::test::temp_dir("crlf");
  write_text(dir / "crlf.ply",
             "ply\r\nformat ascii 1.0\r\nobj_info something\r\nelement vertex 2\r\nproperty float x\r\n"
             "property float y\r\nproperty float z\r\nend_header\r\n1 2 3\r\n4 5 6\r\n");
  const auto r = hp::load_cloud(dir / "crlf.ply");
  ASSERT_EQ(r.value.size(), 2u);
  EXPECT_EQ(r.value.xyz(2, 1), 6.0);
}

TEST(Ingest, ReadsPlyWithAListPropertyInTheVertexElement) {
  const fs::path dir = hc::test::temp_dir("vlist");
  write_text(dir / "vlist.ply", "ply\nformat ascii 1.0\nobj_info x\nelement vertex 2\nproperty float x\nproperty float y\n"
                                "property float z\nproperty list uchar int tags\nelement face 0\n"
                                "property list uchar int vertex_indices\nend_header\n1 2 3 2 7 8\n4 5 6 0\n");
  const auto r = hp::load_cloud(dir / "vlist.ply");
  ASSERT_EQ(r.value.size(), 2u);
  EXPECT_EQ(r.value.xyz.col(1), Eigen::Vector3d(4, 5, 6));
  const auto& notes = r.report.notes;
  EXPECT_TRUE(std::any_of(notes.begin(), notes.end(), [](const std::string& n) {
    return n.find("skipped the vertex list property 'tags'") != std::string::npos;
  }));
}

// Issue 15 D2: a scalar property before a list property in the vertex element. PCL's PLY
// reader (used before for list layouts) shifted the columns (x read from y, y from z) and the
// run succeeded. The oracle is the values written here.
namespace {

struct D2Vertex {
  unsigned char red;
  std::vector<float> extra;  // the list property, of varying length
  float x, y, z;
};

const std::vector<D2Vertex>& d2_vertices() {
  static const std::vector<D2Vertex> v = {
      {7, {0.5f, 1.5f}, 1.25f, -2.5f, 3.0f},
      {255, {}, 0.1f, 0.2f, 0.3f},
      {0, {9.0f, 8.0f, 7.0f, 6.0f}, -1000.125f, 450000.0f, 1e-6f},
      {42, {-4.0f}, 12.0f, 13.0f, 14.0f},
  };
  return v;
}

const char* const kD2Header =
    "element vertex 4\nproperty uchar red\nproperty list uchar float extra\nproperty float x\n"
    "property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";

template <class T>
void append_binary(std::string& s, T v, bool big_endian) {
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  if (big_endian != (std::endian::native == std::endian::big)) std::reverse(b, b + sizeof(T));
  s.append(b, sizeof(T));
}

std::string d2_ply_binary(bool big_endian) {
  std::string s = std::string("ply\nformat ") + (big_endian ? "binary_big_endian" : "binary_little_endian") +
                  " 1.0\n" + kD2Header;
  for (const auto& v : d2_vertices()) {
    s.push_back(static_cast<char>(v.red));
    s.push_back(static_cast<char>(v.extra.size()));
    for (const float e : v.extra) append_binary(s, e, big_endian);
    append_binary(s, v.x, big_endian);
    append_binary(s, v.y, big_endian);
    append_binary(s, v.z, big_endian);
  }
  s.push_back(3);
  for (const int i : {0, 1, 2}) append_binary(s, i, big_endian);
  return s;
}

std::string d2_ply_ascii() {
  std::string s = std::string("ply\nformat ascii 1.0\n") + kD2Header;
  char buf[64];
  for (const auto& v : d2_vertices()) {
    s += std::to_string(v.red) + " " + std::to_string(v.extra.size());
    for (const float e : v.extra) {
      std::snprintf(buf, sizeof buf, " %.9g", static_cast<double>(e));
      s += buf;
    }
    std::snprintf(buf, sizeof buf, " %.9g %.9g %.9g\n", static_cast<double>(v.x), static_cast<double>(v.y),
                  static_cast<double>(v.z));
    s += buf;
  }
  s += "3 0 1 2\n";
  return s;
}

void expect_d2_points(const hp::Cloud& c, const std::string& what) {
  const auto& v = d2_vertices();
  ASSERT_EQ(c.size(), v.size()) << what;
  for (std::size_t i = 0; i < v.size(); ++i) {
    const auto col = static_cast<Eigen::Index>(i);
    EXPECT_EQ(c.xyz(0, col), static_cast<double>(v[i].x)) << what << " vertex " << i;
    EXPECT_EQ(c.xyz(1, col), static_cast<double>(v[i].y)) << what << " vertex " << i;
    EXPECT_EQ(c.xyz(2, col), static_cast<double>(v[i].z)) << what << " vertex " << i;
  }
}

}  // namespace

TEST(IngestPlyLists, ScalarBeforeListInTheVertexElementGivesTheWrittenXyz) {
  const fs::path dir = hc::test::temp_dir("d2");
  write_text(dir / "d2_ascii.ply", d2_ply_ascii());
  write_text(dir / "d2_le.ply", d2_ply_binary(false));
  write_text(dir / "d2_be.ply", d2_ply_binary(true));
  write_gzip(dir / "d2_le.ply.gz", d2_ply_binary(false));
  for (const char* name : {"d2_ascii.ply", "d2_le.ply", "d2_be.ply", "d2_le.ply.gz"}) {
    const auto r = hp::load_cloud(dir / name);
    expect_d2_points(r.value, name);
    const auto& notes = r.report.notes;
    EXPECT_TRUE(std::any_of(notes.begin(), notes.end(), [](const std::string& n) {
      return n.find("skipped the vertex list property 'extra'") != std::string::npos;
    })) << name;
  }
}

TEST(IngestPlyLists, ListsInAnElementBeforeTheVertexElementAreSkipped) {
  // A binary element with a list property (int16 count, double items) and an ASCII one come
  // before the vertex element; the vertex element has its list last.
  const fs::path dir = hc::test::temp_dir("d2_before");
  const std::string elements =
      "element camera 2\nproperty list short double params\nproperty uint id\n"
      "element vertex 2\nproperty double x\nproperty double y\nproperty double z\nproperty list uint uchar tag\n"
      "end_header\n";
  std::string bin = "ply\nformat binary_little_endian 1.0\n" + elements;
  append_binary<std::int16_t>(bin, 3, false);
  for (const double d : {1.0, 2.0, 3.0}) append_binary(bin, d, false);
  append_binary<std::uint32_t>(bin, 11, false);
  append_binary<std::int16_t>(bin, 0, false);
  append_binary<std::uint32_t>(bin, 12, false);
  for (int i = 0; i < 2; ++i) {
    for (const double d : kGeo[i]) append_binary(bin, d, false);
    append_binary<std::uint32_t>(bin, 2, false);
    bin += "ab";
  }
  write_text(dir / "before.ply", bin);
  std::string ascii = "ply\nformat ascii 1.0\n" + elements + "3 1 2 3 11\n0 12\n";
  char buf[128];
  for (int i = 0; i < 2; ++i) {
    std::snprintf(buf, sizeof buf, "%.17g %.17g %.17g 2 97 98\n", kGeo[i][0], kGeo[i][1], kGeo[i][2]);
    ascii += buf;
  }
  write_text(dir / "before_ascii.ply", ascii);
  for (const char* name : {"before.ply", "before_ascii.ply"}) {
    const auto r = hp::load_cloud(dir / name);
    ASSERT_EQ(r.value.size(), 2u) << name;
    for (int i = 0; i < 2; ++i)
      for (int a = 0; a < 3; ++a) EXPECT_EQ(r.value.xyz(a, i), kGeo[i][a]) << name << " point " << i;
  }
}

TEST(IngestPlyLists, MalformedListsAreInputErrorsNamingFileAndProperty) {
  const fs::path dir = hc::test::temp_dir("d2_bad");
  // Binary: the data ends inside vertex 2's list.
  std::string cut = d2_ply_binary(false);
  const std::size_t body = cut.find("end_header\n") + 11;
  write_text(dir / "cut.ply", cut.substr(0, body + 2 * 1 + 2 * 1 + 2 * 4 + 6 * 4 + 1 + 1 + 5));
  std::string msg = error_of([&] { hp::load_cloud(dir / "cut.ply"); });
  EXPECT_NE(msg.find("cut.ply"), std::string::npos) << msg;
  EXPECT_NE(msg.find("truncated"), std::string::npos) << msg;
  EXPECT_NE(msg.find("inside vertex 2"), std::string::npos) << msg;
  // Binary: a negative count (signed count type).
  std::string neg = "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty char n\n"
                    "property list char float extra\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  neg.push_back(1);
  neg.push_back(static_cast<char>(-2));
  neg.append(16, '\0');
  write_text(dir / "negative.ply", neg);
  msg = error_of([&] { hp::load_cloud(dir / "negative.ply"); });
  EXPECT_NE(msg.find("negative.ply"), std::string::npos) << msg;
  EXPECT_NE(msg.find("list property 'extra'"), std::string::npos) << msg;
  EXPECT_NE(msg.find("negative item count -2"), std::string::npos) << msg;
  // ASCII: a count that is not an integer, and a list longer than its line.
  const std::string ascii_head = std::string("ply\nformat ascii 1.0\n") + kD2Header;
  write_text(dir / "frac.ply", ascii_head + "1 1.5 2 3 4 5\n");
  msg = error_of([&] { hp::load_cloud(dir / "frac.ply"); });
  EXPECT_NE(msg.find("frac.ply"), std::string::npos) << msg;
  EXPECT_NE(msg.find("line 12 (vertex 0): list property 'extra': item count '1.5' is not a non-negative integer"),
            std::string::npos)
      << msg;
  write_text(dir / "long.ply", ascii_head + "1 9 2 3 4\n");
  msg = error_of([&] { hp::load_cloud(dir / "long.ply"); });
  EXPECT_NE(msg.find("list property 'extra' declares 9 items but the line ends after 3"), std::string::npos) << msg;
  // Header: a floating-point count type cannot be placed.
  write_text(dir / "float_count.ply", "ply\nformat binary_little_endian 1.0\nelement vertex 1\n"
                                      "property list float float extra\nproperty float x\nproperty float y\n"
                                      "property float z\nend_header\n0123456789abcdef");
  msg = error_of([&] { hp::load_cloud(dir / "float_count.ply"); });
  EXPECT_NE(msg.find("float_count.ply"), std::string::npos) << msg;
  EXPECT_NE(msg.find("list property 'extra' of element 'vertex' has count type 'float'"), std::string::npos) << msg;
}

TEST(Ingest, GzipOfAFileGivesTheSameCloud) {
  const fs::path dir = hc::test::temp_dir("gz");
  const std::string raw = read_bytes(hc::test::scan_path("bunny/bun045.ply"));
  write_gzip(dir / "bun045.ply.gz", raw);
  const auto plain = hp::load_cloud(hc::test::scan_path("bunny/bun045.ply"));
  const auto packed = hp::load_cloud(dir / "bun045.ply.gz");
  ASSERT_EQ(plain.value.size(), 40097u);
  EXPECT_EQ(plain.value.xyz, packed.value.xyz);
  const auto& f = packed.report.figures;
  EXPECT_TRUE(std::any_of(f.begin(), f.end(), [&](const auto& x) {
    return x.first == "decompressed_bytes" && x.second == static_cast<double>(raw.size());
  }));
  // A gzipped PCD too.
  write_gzip(dir / "b.pcd.gz", read_bytes(hc::test::scan_path("bunny/pcl_bunny.pcd")));
  EXPECT_EQ(hp::load_cloud(dir / "b.pcd.gz").value.size(), 397u);
}

TEST(Ingest, ReadsObjVertexLinesInDouble) {
  const fs::path dir = hc::test::temp_dir("obj");
  std::string obj = "# a mesh\nmtllib x.mtl\no thing\n";
  char buf[128];
  for (const auto& p : kGeo) {
    std::snprintf(buf, sizeof buf, "v %.17g %.17g %.17g 1.0\n", p[0], p[1], p[2]);
    obj += buf;
  }
  obj += "vn 0 0 1\nvt 0.5 0.5\nf 1 2 3\n  v\t1e-3 +2 -3E2\n";
  write_text(dir / "m.obj", obj);
  const auto r = hp::load_cloud(dir / "m.obj");
  ASSERT_EQ(r.value.size(), 4u);
  for (int i = 0; i < 3; ++i)
    for (int a = 0; a < 3; ++a) EXPECT_EQ(r.value.xyz(a, i), kGeo[i][a]);
  EXPECT_EQ(r.value.xyz.col(3), Eigen::Vector3d(1e-3, 2.0, -300.0));
}

TEST(Ingest, ReadsXyzTextWithCommentsBlankLinesAndExtraColumns) {
  const fs::path dir = hc::test::temp_dir("xyz");
  std::string xyz = "# x y z intensity\n\n";
  char buf[160];
  for (const auto& p : kGeo) {
    std::snprintf(buf, sizeof buf, "%.17g\t%.17g %.17g 0.75 12  # comment\n", p[0], p[1], p[2]);
    xyz += buf;
  }
  xyz += "1,2,3\n   \n4 5 6";  // comma separators; last line without '\n'
  write_text(dir / "p.xyz", xyz);
  write_text(dir / "p.txt", xyz);
  for (const char* name : {"p.xyz", "p.txt"}) {
    const auto r = hp::load_cloud(dir / name);
    ASSERT_EQ(r.value.size(), 5u);
    for (int i = 0; i < 3; ++i)
      for (int a = 0; a < 3; ++a) EXPECT_EQ(r.value.xyz(a, i), kGeo[i][a]);
    EXPECT_EQ(r.value.xyz.col(3), Eigen::Vector3d(1, 2, 3));
    EXPECT_EQ(r.value.xyz.col(4), Eigen::Vector3d(4, 5, 6));
  }
}

// ---------------------------------------------------------------------------------------------
// Bad input: each a clear InputError naming the file.

TEST(IngestBadInput, MissingFile) {
  const std::string msg = error_of([] { hp::load_cloud("/nonexistent/dir/scan_xyz123.ply"); });
  EXPECT_NE(msg.find("scan_xyz123.ply"), std::string::npos) << msg;
  EXPECT_NE(msg.find("does not exist"), std::string::npos) << msg;
}

TEST(IngestBadInput, EmptyFiles) {
  const fs::path dir = hc::test::temp_dir("empty");
  for (const char* name : {"e.ply", "e.pcd", "e.xyz", "e.obj", "e.ply.gz"}) {
    write_text(dir / name, "");
    const std::string msg = error_of([&] { hp::load_cloud(dir / name); });
    EXPECT_NE(msg.find(name), std::string::npos) << msg;
    EXPECT_NE(msg.find("empty"), std::string::npos) << msg;
  }
  // Files with content but no points.
  write_text(dir / "comments.xyz", "# nothing here\n\n");
  EXPECT_NE(error_of([&] { hp::load_cloud(dir / "comments.xyz"); }).find("no points"), std::string::npos);
  write_text(dir / "faces.obj", "f 1 2 3\n");
  EXPECT_NE(error_of([&] { hp::load_cloud(dir / "faces.obj"); }).find("no vertices"), std::string::npos);
  write_text(dir / "zero.ply", "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
                               "property float z\nend_header\n");
  EXPECT_NE(error_of([&] { hp::load_cloud(dir / "zero.ply"); }).find("0 vertices"), std::string::npos);
}

TEST(IngestBadInput, TruncatedBinaryPly) {
  const fs::path dir = hc::test::temp_dir("trunc");
  std::string full = float_ply_binary(100, 100);
  const std::size_t header = full.find("end_header\n") + 11;
  write_text(dir / "cut.ply", full.substr(0, header + 13 * 40 + 7));  // 40 whole vertices and a bit
  const std::string msg = error_of([&] { hp::load_cloud(dir / "cut.ply"); });
  EXPECT_NE(msg.find("cut.ply"), std::string::npos) << msg;
  EXPECT_NE(msg.find("truncated"), std::string::npos) << msg;
  EXPECT_NE(msg.find("40 whole vertices"), std::string::npos) << msg;
  // Cut inside the header.
  write_text(dir / "cut_header.ply", full.substr(0, 60));
  EXPECT_NE(error_of([&] { hp::load_cloud(dir / "cut_header.ply"); }).find("end_header"), std::string::npos);
  // A truncated gzip stream.
  const std::string plain = read_bytes(hc::test::scan_path("bunny/pcl_bunny.pcd"));
  write_gzip(dir / "whole.pcd.gz", plain);
  const std::string gz = read_bytes(dir / "whole.pcd.gz");
  write_text(dir / "cut.pcd.gz", gz.substr(0, gz.size() / 2));
  const std::string gz_msg = error_of([&] { hp::load_cloud(dir / "cut.pcd.gz"); });
  EXPECT_NE(gz_msg.find("cut.pcd.gz"), std::string::npos) << gz_msg;
  EXPECT_NE(gz_msg.find("truncated"), std::string::npos) << gz_msg;
  // Not gzip at all.
  write_text(dir / "fake.ply.gz", "ply\nthis is not gzip\n");
  EXPECT_NE(error_of([&] { hp::load_cloud(dir / "fake.ply.gz"); }).find("not valid gzip"), std::string::npos);
}

// Concatenated gzip members (`cat a.gz b.gz`) inflate to the concatenation, also when the last
// member, whose trailer sizes the output, is far smaller than the first (the buffer grows).
TEST(IngestGzip, ConcatenatedMembersOfVeryDifferentSizesInflateToTheWholeFile) {
  const fs::path dir = hc::test::temp_dir("members");
  const std::string plain = read_bytes(hc::test::scan_path("bunny/pcl_bunny.pcd"));
  ASSERT_GT(plain.size(), 10000U);
  write_gzip(dir / "a.gz", plain.substr(0, plain.size() - 100));
  write_gzip(dir / "b.gz", plain.substr(plain.size() - 100));
  write_text(dir / "two.pcd.gz", read_bytes(dir / "a.gz") + read_bytes(dir / "b.gz"));
  write_text(dir / "one.pcd", plain);
  const hp::Cloud whole = hp::load_cloud(dir / "one.pcd").value;
  const hp::Cloud two = hp::load_cloud(dir / "two.pcd.gz").value;
  ASSERT_EQ(two.size(), whole.size());
  EXPECT_TRUE(two.xyz == whole.xyz);
}

TEST(IngestBadInput, HeaderPromisesMoreVerticesThanTheFileHolds) {
  const fs::path dir = hc::test::temp_dir("promise");
  // Binary: 60 vertices present, 100 declared, no trailing face data.
  std::string bin = float_ply_binary(60, 100);
  bin.resize(bin.size() - 13);  // drop the face record
  write_text(dir / "short_bin.ply", bin);
  std::string msg = error_of([&] { hp::load_cloud(dir / "short_bin.ply"); });
  EXPECT_NE(msg.find("short_bin.ply"), std::string::npos) << msg;
  EXPECT_NE(msg.find("declares 100 vertices"), std::string::npos) << msg;
  EXPECT_NE(msg.find("60 whole vertices"), std::string::npos) << msg;
  // ASCII: 10 declared, 4 present.
  write_text(dir / "short_ascii.ply", "ply\nformat ascii 1.0\nelement vertex 10\nproperty float x\nproperty float y\n"
                                      "property float z\nend_header\n1 2 3\n4 5 6\n7 8 9\n1 1 1\n");
  msg = error_of([&] { hp::load_cloud(dir / "short_ascii.ply"); });
  EXPECT_NE(msg.find("short_ascii.ply"), std::string::npos) << msg;
  EXPECT_NE(msg.find("declares 10 vertices but only 4"), std::string::npos) << msg;
  // ASCII range scan whose vertex section is short but followed by range_grid lines.
  write_text(dir / "short_grid.ply",
             "ply\nformat ascii 1.0\nobj_info num_cols 2\nelement vertex 5\nproperty float x\nproperty float y\n"
             "property float z\nelement range_grid 6\nproperty list uchar int vertex_indices\nend_header\n"
             "1 2 3\n4 5 6\n0\n1 0\n0\n1 1\n0\n0\n");
  msg = error_of([&] { hp::load_cloud(dir / "short_grid.ply"); });
  EXPECT_NE(msg.find("short_grid.ply"), std::string::npos) << msg;
}

TEST(IngestBadInput, AbsurdDeclaredCountsAreTruncationNotAllocation) {
  const fs::path dir = hc::test::temp_dir("absurd");
  write_text(dir / "huge.ply", "ply\nformat binary_little_endian 1.0\nelement vertex 999999999999999\n"
                               "property float x\nproperty float y\nproperty float z\nend_header\n0123456789ab");
  std::string msg = error_of([&] { hp::load_cloud(dir / "huge.ply"); });
  EXPECT_NE(msg.find("huge.ply"), std::string::npos) << msg;
  EXPECT_NE(msg.find("truncated"), std::string::npos) << msg;
  write_text(dir / "huge.pcd", "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                               "WIDTH 4000000000000000000\nHEIGHT 4000000000000000000\nDATA binary\n0123");
  msg = error_of([&] { hp::load_cloud(dir / "huge.pcd"); });
  EXPECT_NE(msg.find("huge.pcd"), std::string::npos) << msg;
  EXPECT_NE(msg.find("truncated"), std::string::npos) << msg;
}

TEST(IngestBadInput, UnknownExtension) {
  const fs::path dir = hc::test::temp_dir("ext");
  write_text(dir / "scan.rcp", "1 2 3\n");
  const std::string msg = error_of([&] { hp::load_cloud(dir / "scan.rcp"); });
  EXPECT_NE(msg.find("scan.rcp"), std::string::npos) << msg;
  EXPECT_NE(msg.find("unknown extension '.rcp'"), std::string::npos) << msg;
  write_text(dir / "noext", "1 2 3\n");
  EXPECT_NE(error_of([&] { hp::load_cloud(dir / "noext"); }).find("unknown extension"), std::string::npos);
}

TEST(IngestBadInput, PcdWithGarbage) {
  const fs::path dir = hc::test::temp_dir("pcd");
  write_text(dir / "garbage.pcd", "this is not a point cloud\n\x01\x02\x03 random bytes\n");
  std::string msg = error_of([&] { hp::load_cloud(dir / "garbage.pcd"); });
  EXPECT_NE(msg.find("garbage.pcd"), std::string::npos) << msg;
  // A valid header whose ASCII data holds a non-number.
  write_text(dir / "bad_data.pcd", "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\n"
                                   "HEIGHT 1\nPOINTS 2\nDATA ascii\n1 2 3\n4 five 6\n");
  msg = error_of([&] { hp::load_cloud(dir / "bad_data.pcd"); });
  EXPECT_NE(msg.find("bad_data.pcd"), std::string::npos) << msg;
  EXPECT_NE(msg.find("data line 2: 'five' is not a number"), std::string::npos) << msg;
  // Fewer data lines than POINTS, and a binary body shorter than declared.
  write_text(dir / "short.pcd", "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\n"
                                "HEIGHT 1\nPOINTS 3\nDATA ascii\n1 2 3\n");
  msg = error_of([&] { hp::load_cloud(dir / "short.pcd"); });
  // (6 bytes cannot hold 3 lines of 3 values: refused from the header's count and the body's size)
  EXPECT_NE(msg.find("truncated: the header declares 3 points of 3 values, but the 6 bytes after it hold at most 1 data lines"),
            std::string::npos)
      << msg;
  write_text(dir / "short_bin.pcd", "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\n"
                                    "HEIGHT 1\nPOINTS 3\nDATA binary\n0123456789");
  msg = error_of([&] { hp::load_cloud(dir / "short_bin.pcd"); });
  EXPECT_NE(msg.find("truncated"), std::string::npos) << msg;
}

TEST(IngestBadInput, GarbagePly) {
  const fs::path dir = hc::test::temp_dir("plyg");
  write_text(dir / "not.ply", "solid ascii stl\nfacet normal 0 0 1\n");
  EXPECT_NE(error_of([&] { hp::load_cloud(dir / "not.ply"); }).find("not a PLY file"), std::string::npos);
  write_text(dir / "bad_number.ply", "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                                     "property float z\nend_header\n1 2 3\n4 oops 6\n");
  // PCL's ASCII reader would accept this silently; the value check names the line.
  const std::string msg = error_of([&] { hp::load_cloud(dir / "bad_number.ply"); });
  EXPECT_NE(msg.find("bad_number.ply"), std::string::npos) << msg;
  EXPECT_NE(msg.find("line 9 (vertex 1): 'oops' is not a number"), std::string::npos) << msg;
  write_text(dir / "no_z.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                               "end_header\n1 2\n");
  EXPECT_NE(error_of([&] { hp::load_cloud(dir / "no_z.ply"); }).find("no 'z' property"), std::string::npos);
}

TEST(IngestBadInput, XyzWithANonNumericTokenNamesTheLine) {
  const fs::path dir = hc::test::temp_dir("xyzbad");
  write_text(dir / "bad.xyz", "# header\n1 2 3\n4 5 six\n7 8 9\n");
  std::string msg = error_of([&] { hp::load_cloud(dir / "bad.xyz"); });
  EXPECT_NE(msg.find("bad.xyz"), std::string::npos) << msg;
  EXPECT_NE(msg.find("line 3"), std::string::npos) << msg;
  EXPECT_NE(msg.find("'six'"), std::string::npos) << msg;
  write_text(dir / "short.xyz", "1 2 3\n4 5\n");
  msg = error_of([&] { hp::load_cloud(dir / "short.xyz"); });
  EXPECT_NE(msg.find("line 2"), std::string::npos) << msg;
  write_text(dir / "bad.obj", "v 1 2 3\nv 1 x 3\n");
  msg = error_of([&] { hp::load_cloud(dir / "bad.obj"); });
  EXPECT_NE(msg.find("bad.obj"), std::string::npos) << msg;
  EXPECT_NE(msg.find("line 2"), std::string::npos) << msg;
}

TEST(IngestBadInput, CloudOfOnlyNanIsReadAsIs) {
  // NaN is a value, not a format error: load keeps it, remove_non_finite counts it
  // (filters_test), and the next stage rejects the empty cloud.
  const fs::path dir = hc::test::temp_dir("nan");
  write_text(dir / "nan.xyz", "nan nan nan\nnan 1 2\n");
  const auto r = hp::load_cloud(dir / "nan.xyz");
  ASSERT_EQ(r.value.size(), 2u);
  EXPECT_FALSE(r.value.xyz.allFinite());
}

// ---------------------------------------------------------------------------------------------
// scanalyze .conf and multi-view merge

TEST(ScanalyzeConf, ReadsBuddhaPoses) {
  const auto poses = hp::read_scanalyze_conf(hc::test::scan_path("happy_buddha/raw_scans/happyStandRight.conf"));
  ASSERT_EQ(poses.size(), 15u);
  EXPECT_EQ(poses[1].file, "happyStandRight_24.ply");
  EXPECT_DOUBLE_EQ(poses[1].translation.x(), -0.0011319518);
  // bmesh happyStandRight_24.ply ... qx qy qz qw = 9.6516655e-05 -0.21082219 0.0010512398 0.97752386
  EXPECT_NEAR(poses[1].rotation.w(), 0.97752386, 1e-7);
  EXPECT_NEAR(poses[1].rotation.y(), -0.21082219, 1e-7);
  const Eigen::Affine3d m = poses[1].scan_to_world();
  EXPECT_TRUE(m.linear().isApprox(poses[1].rotation.toRotationMatrix().transpose(), 1e-12));
  EXPECT_EQ(m.translation(), poses[1].translation);
}

TEST(ScanalyzeConf, MalformedLinesNameTheLine) {
  const fs::path dir = hc::test::temp_dir("conf");
  write_text(dir / "bad.conf", "camera 0 0 0 0 0 0 1\nbmesh a.ply 0 0 0 0 0 0 1\nbmesh b.ply 0 0 0 0 0 1\n");
  std::string msg = error_of([&] { hp::read_scanalyze_conf(dir / "bad.conf"); });
  EXPECT_NE(msg.find("bad.conf"), std::string::npos) << msg;
  EXPECT_NE(msg.find("line 3"), std::string::npos) << msg;
  EXPECT_NE(msg.find("bmesh FILE tx ty tz qx qy qz qw"), std::string::npos) << msg;
  write_text(dir / "nan.conf", "bmesh a.ply 0 0 zero 0 0 0 1\n");
  msg = error_of([&] { hp::read_scanalyze_conf(dir / "nan.conf"); });
  EXPECT_NE(msg.find("line 1"), std::string::npos) << msg;
  EXPECT_NE(msg.find("'zero'"), std::string::npos) << msg;
  write_text(dir / "norm.conf", "\nbmesh a.ply 0 0 0 0 0 0 2\n");
  EXPECT_NE(error_of([&] { hp::read_scanalyze_conf(dir / "norm.conf"); }).find("line 2"), std::string::npos);
  write_text(dir / "none.conf", "camera 0 0 0 0 0 0 1\n");
  EXPECT_NE(error_of([&] { hp::read_scanalyze_conf(dir / "none.conf"); }).find("no 'bmesh' line"),
            std::string::npos);
  EXPECT_NE(error_of([&] { hp::read_scanalyze_conf(dir / "missing.conf"); }).find("does not exist"),
            std::string::npos);
}

TEST(ScanalyzeConf, ScanWithoutPoseNamesBothFiles) {
  const fs::path dir = hc::test::temp_dir("nopose");
  write_text(dir / "one.conf", "bmesh other.ply 0 0 0 0 0 0 1\n");
  write_text(dir / "scan.xyz", "1 2 3\n");
  const std::string msg = error_of([&] { hp::load_and_merge_scans({dir / "scan.xyz"}, dir / "one.conf"); });
  EXPECT_NE(msg.find("scan.xyz"), std::string::npos) << msg;
  EXPECT_NE(msg.find("one.conf"), std::string::npos) << msg;
  // A scan that fails to load (read on the second thread or not) names itself.
  write_text(dir / "two.conf", "bmesh scan.xyz 0 0 0 0 0 0 1\nbmesh gone.xyz 0 0 0 0 0 0 1\nbmesh bad.xyz 0 0 0 0 0 0 1\n");
  write_text(dir / "bad.xyz", "1 2 x\n");
  const std::string missing =
      error_of([&] { hp::load_and_merge_scans({dir / "scan.xyz", dir / "gone.xyz", dir / "bad.xyz"}, dir / "two.conf"); });
  EXPECT_NE(missing.find("gone.xyz"), std::string::npos) << missing;
  EXPECT_THROW(hp::load_and_merge_scans({}, dir / "two.conf"), hc::InputError);
}

// Colour and intensity survive a merge when every scan has them (until 2026-11-26 they were
// dropped); a scan without colour drops it, naming that scan. Oracle: the values written.
TEST(ScanalyzeConf, MergeKeepsColourAndIntensityWhenEveryScanHasThem) {
  const fs::path dir = hc::test::temp_dir("merge_colour");
  write_text(dir / "poses.conf", "bmesh a.pts 0 0 0 0 0 0 1\nbmesh b.pts 1 0 0 0 0 0 1\nbmesh c.xyz 2 0 0 0 0 0 1\n");
  write_text(dir / "a.pts", "2\n0 0 0 10 1 2 3\n0 1 0 20 4 5 6\n");
  write_text(dir / "b.pts", "1\n0 0 1 30 7 8 9\n");
  write_text(dir / "c.xyz", "0 0 2\n");
  const auto ab = hp::load_and_merge_scans({dir / "a.pts", dir / "b.pts"}, dir / "poses.conf");
  EXPECT_EQ(ab.value.rgb, (std::vector<std::uint8_t>{1, 2, 3, 4, 5, 6, 7, 8, 9}));
  EXPECT_EQ(ab.value.intensity, (std::vector<float>{10, 20, 30}));
  EXPECT_EQ(ab.value.xyz(0, 2), 1.0) << "b's pose applied";
  const auto abc = hp::load_and_merge_scans({dir / "a.pts", dir / "b.pts", dir / "c.xyz"}, dir / "poses.conf");
  EXPECT_TRUE(abc.value.rgb.empty());
  EXPECT_TRUE(abc.value.intensity.empty());
  const auto& notes = abc.report.notes;
  EXPECT_NE(std::find(notes.begin(), notes.end(), "input.conf: rgb dropped: c.xyz has none"), notes.end());
  EXPECT_NE(std::find(notes.begin(), notes.end(), "input.conf: intensity dropped: c.xyz has none"), notes.end());
}

TEST(ScanalyzeConf, MergeMatchesNamesIgnoringGzAndAppliesTheInverseRotation) {
  const fs::path dir = hc::test::temp_dir("merge");
  // A 90° turn about y: q = (w, x, y, z) = (cos 45°, 0, sin 45°, 0), written w last.
  write_text(dir / "poses.conf", "bmesh a.xyz 1 2 3 0 0.70710678118654752 0 0.70710678118654752\n"
                                 "bmesh b.xyz.gz 0 0 0 0 0 0 1\n");
  write_text(dir / "a.xyz", "1 0 0\n0 0 1\n");
  write_gzip(dir / "b.xyz.gz", "5 6 7\n");
  write_text(dir / "b.xyz", "5 6 7\n");
  for (const char* b : {"b.xyz", "b.xyz.gz"}) {
    const auto r = hp::load_and_merge_scans({dir / "a.xyz", dir / b}, dir / "poses.conf");
    ASSERT_EQ(r.value.size(), 3u);
    ASSERT_EQ(r.value.scan_id, (std::vector<std::uint16_t>{0, 0, 1}));
    // R(q) maps x to -z; Rᵀ maps x to +z and z to -x; then + t.
    EXPECT_TRUE(r.value.xyz.col(0).isApprox(Eigen::Vector3d(1, 2, 4), 1e-12)) << r.value.xyz.col(0).transpose();
    EXPECT_TRUE(r.value.xyz.col(1).isApprox(Eigen::Vector3d(0, 2, 3), 1e-12)) << r.value.xyz.col(1).transpose();
    EXPECT_EQ(r.value.xyz.col(2), Eigen::Vector3d(5, 6, 7));
    EXPECT_EQ(r.report.count_out, 3u);
  }
}

// The pose convention, proven on real data: neighbouring Buddha views (0° and 24°) overlap to a
// median nearest-neighbour distance of at most 0.3 mm with p_world = R(q)ᵀ·p + t, and the other
// reading (R(q)·p + t) is clearly worse.
TEST(ScanalyzeConf, NeighbouringBuddhaViewsAlignThroughTheConf) {
  const fs::path raw = hc::test::scan_path("happy_buddha/raw_scans");
  const fs::path conf = raw / "happyStandRight.conf";
  const auto merged = hp::load_and_merge_scans({raw / "happyStandRight_0.ply.gz", raw / "happyStandRight_24.ply.gz"}, conf);
  const hp::Cloud& m = merged.value;
  ASSERT_EQ(m.size(), 78056u + 75582u);
  std::vector<Eigen::Index> ia, ib;
  for (Eigen::Index i = 0; i < m.xyz.cols(); ++i) (m.scan_id[static_cast<std::size_t>(i)] == 0 ? ia : ib).push_back(i);
  ASSERT_EQ(ia.size(), 78056u);
  const Eigen::Matrix3Xd a = m.xyz(Eigen::all, ia), b = m.xyz(Eigen::all, ib);
  const Overlap good = overlap(a, b, 0.002);
  EXPECT_GT(good.pairs, 20000u);
  RecordProperty("overlap_median_um", static_cast<int>(good.median_m * 1e6));
  EXPECT_LE(good.median_m, 0.3e-3) << "median " << good.median_m * 1e3 << " mm over " << good.pairs << " pairs";

  // The opposite reading, from the raw scans.
  const auto poses = hp::read_scanalyze_conf(conf);
  auto other = [&](const char* file, const hp::ScanPose& pose) {
    hp::Cloud c = hp::load_cloud(raw / file).value;
    return Eigen::Matrix3Xd((pose.rotation.toRotationMatrix() * c.xyz).colwise() + pose.translation);
  };
  const Eigen::Matrix3Xd a2 = other("happyStandRight_0.ply.gz", poses[0]);
  const Eigen::Matrix3Xd b2 = other("happyStandRight_24.ply.gz", poses[1]);
  const Overlap bad = overlap(a2, b2, 0.002);
  RecordProperty("opposite_convention_median_um", static_cast<int>(bad.median_m * 1e6));
  // Within 2 mm any misfit looks like ~1 mm, so also compare how much overlaps at all, and the
  // median over every point (measured: 69k vs 15k pairs; 0.24 mm vs 5.0 mm).
  EXPECT_LT(bad.pairs * 3, good.pairs);
  const double all_good = overlap(a, b, 1.0).median_m, all_bad = overlap(a2, b2, 1.0).median_m;
  EXPECT_GT(all_bad, 10.0 * all_good) << all_bad * 1e3 << " mm vs " << all_good * 1e3 << " mm";
  EXPECT_GT(bad.median_m, 1.0e-3) << "median " << bad.median_m * 1e3 << " mm over " << bad.pairs << " pairs";
}
