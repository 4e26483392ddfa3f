// DATA binary PCD bodies are read by the project (PCL's reader crashed on a fuzzed binary file whose
// header was sound): values of every type land exactly, in the record layout the header declares.

#include "hc/pipeline/ingest.hpp"

#include <gtest/gtest.h>

#include "test_paths.hpp"

#include <cstdint>
#include <cstring>
#include <fstream>
#include <string>

namespace {

template <class T>
void put(std::string& s, T v) {
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  s.append(b, sizeof(T));
}

TEST(PcdBinary, MixedTypesAndAnExtraFieldAreReadExactly) {
  const auto dir = hc::test::temp_dir("pcd");
  // rgb (U4) before x (F8), y (F4), an unused I2 pair, z (I4): offsets 4, 12, 16 + 4 = 20.
  std::string f = "# .PCD v0.7\nVERSION 0.7\nFIELDS rgb x y pad z\nSIZE 4 8 4 2 4\nTYPE U F F I I\n"
                  "COUNT 1 1 1 2 1\nWIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA binary\n";
  const double xs[3] = {0.1, -2.5e-7, 123456.789012345};
  const float ys[3] = {1.5f, -0.25f, 3.0e-5f};
  const std::int32_t zs[3] = {-7, 0, 2147483647};
  for (int i = 0; i < 3; ++i) {
    put<std::uint32_t>(f, 0xFF00FFu);
    put<double>(f, xs[i]);
    put<float>(f, ys[i]);
    put<std::int16_t>(f, 1);
    put<std::int16_t>(f, -1);
    put<std::int32_t>(f, zs[i]);
  }
  { std::ofstream(dir / "mixed.pcd", std::ios::binary) << f; }
  const auto cloud = hc::pipeline::load_cloud(dir / "mixed.pcd").value;
  ASSERT_EQ(cloud.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(cloud.xyz(0, i), xs[i]);
    EXPECT_EQ(cloud.xyz(1, i), static_cast<double>(ys[i]));
    EXPECT_EQ(cloud.xyz(2, i), static_cast<double>(zs[i]));
  }
}

}  // namespace
