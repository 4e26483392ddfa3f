// Fuzz targets for the scan readers: the bytes as a file of the format's extension through
// hc::pipeline::load_cloud (hc/pipeline/ingest.hpp), which dispatches on the extension. A clear
// hc::Error is a correct answer to bad bytes; anything else (a crash, another exception, a leak,
// a hang) is a finding.
#include "../fuzz_support.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/ingest.hpp"

#include <string>

namespace hc::fuzz {
namespace {

void scan_file(const char* extension, const std::uint8_t* data, std::size_t size) {
  const auto path = write_scratch(std::string("scan") + extension, data, size);
  try {
    (void)pipeline::load_cloud(path);
  } catch (const hc::Error&) {
    // refused with a message naming the file and what was expected
  }
}

}  // namespace

/// a PLY, ASCII and binary (the header says which) scan file
void ply(const std::uint8_t* data, std::size_t size) { scan_file(".ply", data, size); }
/// a PCD (ASCII, binary and binary_compressed) scan file
void pcd(const std::uint8_t* data, std::size_t size) { scan_file(".pcd", data, size); }
/// a OBJ (vertex lines) scan file
void obj(const std::uint8_t* data, std::size_t size) { scan_file(".obj", data, size); }
/// a XYZ text (x y z per line) scan file
void xyz(const std::uint8_t* data, std::size_t size) { scan_file(".xyz", data, size); }
/// a .e57 scan file
void e57(const std::uint8_t* data, std::size_t size) { scan_file(".e57", data, size); }
/// a .las scan file
void las(const std::uint8_t* data, std::size_t size) { scan_file(".las", data, size); }
/// a .laz (LASzip-compressed LAS, COPC included) scan file
void laz(const std::uint8_t* data, std::size_t size) { scan_file(".laz", data, size); }
/// a .ptx scan file
void ptx(const std::uint8_t* data, std::size_t size) { scan_file(".ptx", data, size); }
/// a .pts scan file
void pts(const std::uint8_t* data, std::size_t size) { scan_file(".pts", data, size); }

}  // namespace hc::fuzz
