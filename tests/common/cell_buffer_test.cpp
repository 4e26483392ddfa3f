#include "hc/common/cell_buffer.hpp"
#include "hc/common/error.hpp"
#include "hc/common/height_field.hpp"

#include <gtest/gtest.h>
#include "resident_bytes.hpp"

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>

#include <unistd.h>

namespace {

namespace fs = std::filesystem;

// A fresh empty folder under the system's temporary one, removed at the end.
struct TempDir {
  fs::path path;
  TempDir() {
    std::string t = (fs::temp_directory_path() / "hc-cell-buffer-XXXXXX").string();
    if (::mkdtemp(t.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
    path = t;
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};

using hc::test::resident_bytes_of_mapping;

TEST(CellBuffer, AFileBackedLayerLeavesNothingInItsFolderAndKeepsWhatWasWrittenWhenItsPagesGoBack) {
  TempDir dir;
  constexpr std::size_t n = 16u << 20;  // 64 MiB of floats
  hc::CellBuffer<float> b(dir.path, n, hc::kNoData, "a test layer");
  ASSERT_TRUE(b.file_backed());
  ASSERT_EQ(b.size(), n);
  // The file is unlinked once mapped: the folder stays empty.
  EXPECT_TRUE(fs::is_empty(dir.path));
  for (std::size_t i = 0; i < n; ++i) ASSERT_TRUE(std::isnan(b[i])) << i;
  for (std::size_t i = 0; i < n; ++i) b[i] = static_cast<float>(i % 100003) * 0.25f;
  const long long before = resident_bytes_of_mapping(b.data());
  ASSERT_GE(before, static_cast<long long>(n * sizeof(float)) - (1 << 20)) << "every page written is resident";
  b.release_resident();
  const long long after = resident_bytes_of_mapping(b.data());
  EXPECT_LE(after, 1 << 20) << "release_resident drops the mapping's pages from the resident set";
  // What was written comes back from the page cache (or the file).
  for (std::size_t i = 0; i < n; ++i) ASSERT_EQ(b[i], static_cast<float>(i % 100003) * 0.25f) << i;
  // A copy is on the heap and equal; a move keeps the mapping.
  const hc::CellBuffer<float> copy = b;
  EXPECT_FALSE(copy.file_backed());
  EXPECT_TRUE(copy == b);
  const float* at = b.data();
  hc::CellBuffer<float> moved = std::move(b);
  EXPECT_TRUE(moved.file_backed());
  EXPECT_EQ(moved.data(), at);
  EXPECT_TRUE(b.empty());  // NOLINT(bugprone-use-after-move): a moved-from buffer is empty
  moved[7] = -1.0f;
  EXPECT_FALSE(copy == moved);
}

TEST(CellBuffer, ARangeGivesBackTheWholePagesInsideItAndNoOthers) {
  TempDir dir;
  constexpr std::size_t n = 16u << 20;  // 64 MiB of floats
  hc::CellBuffer<float> b(dir.path, n, 0.0f, "a test layer");
  for (std::size_t i = 0; i < n; ++i) b[i] = static_cast<float>(i % 7919);
  const auto page = static_cast<long long>(::sysconf(_SC_PAGESIZE));
  const long long all = resident_bytes_of_mapping(b.data());
  ASSERT_GE(all, static_cast<long long>(n * sizeof(float)) - page);
  // Cells [n/4 + 1, n/2 + 1): their bytes start 4 bytes into a page and end 4 bytes into one,
  // so the whole pages inside are those of [n/4, n/2) less the first: 16 MiB less one page.
  b.release_resident(n / 4 + 1, n / 4);
  const long long after = resident_bytes_of_mapping(b.data());
  EXPECT_EQ(all - after, static_cast<long long>(n / 4 * sizeof(float)) - page);
  // A range past the end is clipped; the last quarter goes.
  b.release_resident(3 * n / 4, n);
  EXPECT_EQ(after - resident_bytes_of_mapping(b.data()), static_cast<long long>(n / 4 * sizeof(float)));
  for (std::size_t i = 0; i < n; ++i) ASSERT_EQ(b[i], static_cast<float>(i % 7919)) << i;
}

TEST(CellBuffer, AFileBackedByteLayerHoldsItsFillZeroOrNot) {
  TempDir dir;
  // A zero fill is not written (the reserved file reads as zeros); any other fill is.
  const hc::CellBuffer<std::uint8_t> zeros(dir.path, 3u << 20, 0, "zeros"), sevens(dir.path, 3u << 20, 7, "sevens");
  ASSERT_TRUE(zeros.file_backed() && sevens.file_backed());
  for (std::size_t i = 0; i < zeros.size(); ++i) ASSERT_EQ(zeros[i], 0) << i;
  for (std::size_t i = 0; i < sevens.size(); ++i) ASSERT_EQ(sevens[i], 7) << i;
}

TEST(CellBuffer, AHeapBufferIsAVectorsCellsAndItsReleaseDoesNothing) {
  hc::CellBuffer<std::uint8_t> b(1000, 7);
  EXPECT_FALSE(b.file_backed());
  b.release_resident();
  for (const std::uint8_t v : b) ASSERT_EQ(v, 7);
  std::vector<float> v = {1.0f, 2.0f, 3.0f};
  hc::CellBuffer<float> f;
  f = std::move(v);
  ASSERT_EQ(f.size(), 3u);
  EXPECT_EQ(f[2], 3.0f);
  // NaN cells are unequal, as in std::vector<float>.
  hc::CellBuffer<float> a(2, hc::kNoData), c(2, hc::kNoData);
  EXPECT_FALSE(a == c);
}

TEST(CellBuffer, AFolderThatCannotTakeTheFileIsAResourceErrorNamingItAndTheLayer) {
  TempDir dir;
  const fs::path missing = dir.path / "no-such-folder";
  try {
    const hc::HeightField h(hc::GridGeometry{4, 5, 0.0, 0.0, 0.001}, hc::kNoData, missing, "level 0's depth");
    FAIL() << "expected a ResourceError";
  } catch (const hc::ResourceError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find(missing.string()), std::string::npos) << m;
    EXPECT_NE(m.find("level 0's depth"), std::string::npos) << m;
    EXPECT_EQ(m.rfind("cannot create a file of ", 0), 0U) << m;
  }
}

TEST(CellBuffer, AFileBackedHeightFieldReadsAndWritesAsOneOnTheHeap) {
  TempDir dir;
  const hc::GridGeometry g{37, 53, -0.2, 0.1, 0.004};
  hc::HeightField heap(g), file(g, hc::kNoData, dir.path, "a test layer");
  ASSERT_TRUE(file.file_backed());
  ASSERT_FALSE(heap.file_backed());
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c) {
      if ((r * 7 + c) % 5 == 0) continue;  // left no data
      const float z = static_cast<float>(std::sin(0.1 * r) * std::cos(0.07 * c));
      heap.at(r, c) = z;
      file.at(r, c) = z;
    }
  file.values().release_resident();
  EXPECT_EQ(file.valid_count(), heap.valid_count());
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c) {
      const float a = heap.at(r, c), b = file.at(r, c);
      ASSERT_TRUE(a == b || (std::isnan(a) && std::isnan(b))) << r << " " << c;
    }
}

}  // namespace
