#pragma once
/// @file pcl_pcd_writer.hpp
/// PCD files written and read by PCL itself, for the reader tests' oracles
/// (tests/pipeline/pcl_pcd_writer.cpp).

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace hc::test {

/// A PCD field as its header declares it: TYPE (F, I or U), SIZE [bytes], COUNT.
struct PcdField {
  std::string name;
  char type = 'F';
  int size = 4;
  int count = 1;
};

/// Writes width × height records to `p` as DATA binary_compressed with PCL's own writer
/// (pcl::PCDWriter::writeBinaryCompressed, PCL 1.13: its LZF compressor and its "xxyyzz" column
/// layout), or with compressed false as DATA binary (pcl::PCDWriter::writeBinary). `records`:
/// the points one after another, each the fields' values in order, packed (a record is the sum
/// of SIZE × COUNT bytes), little-endian.
/// @throws std::runtime_error when PCL fails or `records` is not width × height records.
void write_pcl_compressed_pcd(const std::filesystem::path& p, const std::vector<PcdField>& fields, const std::string& records,
                              std::uint32_t width, std::uint32_t height = 1, bool compressed = true);

/// Writes width × height records (laid out as for write_pcl_compressed_pcd) to `p` as DATA
/// ascii with PCL's own writer (pcl::PCDWriter::writeASCII, PCL 1.13, `precision` significant
/// digits for floats; an rgb field of TYPE F as its integer bits, as PCL writes it).
/// @throws std::runtime_error when PCL fails or `records` is not width × height records.
void write_pcl_ascii_pcd(const std::filesystem::path& p, const std::vector<PcdField>& fields, const std::string& records,
                         std::uint32_t width, std::uint32_t height = 1, int precision = 8);

/// What PCL's own reader (pcl::PCDReader into a pcl::PCLPointCloud2, PCL 1.13) gives for `p`:
/// x y z of every point as doubles (3 per point, each field's declared type converted); when a
/// field of 4 bytes is named rgb (else rgba), R G B from its packed value (0x??RRGGBB; else empty); when one
/// is named intensity, its values as floats (else empty).
/// @throws std::runtime_error when PCL cannot read the file or it lacks x, y or z.
void read_pcl_pcd(const std::filesystem::path& p, std::vector<double>& xyz, std::vector<std::uint8_t>& rgb,
                  std::vector<float>& intensity);

}  // namespace hc::test
