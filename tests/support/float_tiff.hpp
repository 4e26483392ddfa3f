#pragma once
// Reads a single-band float32 TIFF with libtiff directly (not through the program's readers):
// the integration tests' independent view of the scene layers and the GeoTIFF export.

#include <gtest/gtest.h>
#include <tiffio.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
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

/// The values of a TIFF tag of type DOUBLE that libtiff does not know (GeoTIFF's
/// ModelPixelScaleTag 33550, ModelTiepointTag 33922: read as anonymous fields); empty when absent.
inline std::vector<double> read_tiff_doubles(const std::filesystem::path& path, std::uint32_t tag) {
  std::vector<double> out;
  TIFFSetWarningHandler(nullptr);
  TIFF* tif = TIFFOpen(path.c_str(), "r");
  if (tif == nullptr) return out;
  std::uint32_t count = 0;
  double* data = nullptr;
  if (TIFFGetField(tif, tag, &count, &data) == 1 && data != nullptr) out.assign(data, data + count);
  TIFFClose(tif);
  return out;
}

/// The number after `key: ` at the start of a line (after indentation) of a scene.yaml; with
/// `index`, element `index` of a flow list `key: [a, b, c]`. A test failure and 0 when absent.
inline double yaml_number(const std::filesystem::path& scene_yaml, const std::string& key, int index = -1) {
  std::ifstream in(scene_yaml);
  for (std::string line; std::getline(in, line);) {
    const auto at = line.find(key + ": ");
    if (at == std::string::npos || line.find_first_not_of(' ') != at) continue;
    std::string rest = line.substr(at + key.size() + 2);
    if (index < 0) return std::stod(rest);
    std::size_t pos = rest.find('[');
    for (int k = 0; k < index && pos != std::string::npos; ++k) pos = rest.find(',', pos + 1);
    if (pos != std::string::npos) return std::stod(rest.substr(pos + 1));
  }
  ADD_FAILURE() << "no " << key << (index >= 0 ? "[" + std::to_string(index) + "]" : std::string()) << " in " << scene_yaml;
  return 0.0;
}

}  // namespace hc::test
