#pragma once
// Reads a single-band float32 TIFF with libtiff directly (not through the program's readers):
// the integration tests' independent view of the scene layers and the GeoTIFF export.

#include <gtest/gtest.h>
#include <tiffio.h>

#include <cstdint>
#include <filesystem>
#include <vector>

namespace hc::test {

struct FloatTiff {
  int rows = 0, cols = 0;
  std::vector<float> v;  ///< row-major, file row 0 first
  float at(int r, int c) const { return v[static_cast<std::size_t>(r) * static_cast<std::size_t>(cols) + static_cast<std::size_t>(c)]; }
};

/// The pixels of `path` (a stripped, single-band, 32-bit IEEE float TIFF); rows = 0 and a test
/// failure when it cannot be read.
inline FloatTiff read_float_tiff(const std::filesystem::path& path) {
  FloatTiff l;
  TIFFSetWarningHandler(nullptr);  // GeoTIFF's tags are unknown to libtiff itself: not a problem here
  TIFF* tif = TIFFOpen(path.c_str(), "r");
  EXPECT_NE(tif, nullptr) << path;
  if (tif == nullptr) return l;
  std::uint32_t w = 0, h = 0;
  std::uint16_t bits = 0, format = 0;
  TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &w);
  TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &h);
  TIFFGetField(tif, TIFFTAG_BITSPERSAMPLE, &bits);
  TIFFGetField(tif, TIFFTAG_SAMPLEFORMAT, &format);
  EXPECT_EQ(bits, 32) << path;
  EXPECT_EQ(format, SAMPLEFORMAT_IEEEFP) << path;
  l.rows = static_cast<int>(h);
  l.cols = static_cast<int>(w);
  l.v.resize(static_cast<std::size_t>(w) * h);
  for (std::uint32_t r = 0; r < h; ++r) EXPECT_EQ(TIFFReadScanline(tif, &l.v[static_cast<std::size_t>(r) * w], r), 1);
  TIFFClose(tif);
  return l;
}

}  // namespace hc::test
