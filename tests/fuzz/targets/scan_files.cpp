// Fuzz targets for the scan readers: the bytes as a file of the format's extension through
// hc::pipeline::load_cloud (hc/pipeline/ingest.hpp), which dispatches on the extension, and
// through open_point_stream (hc/pipeline/point_stream.hpp), read to the end in chunks. A clear
// hc::Error is a correct answer to bad bytes; anything else (a crash, another exception, a leak,
// a hang) is a finding, and so is a natively streamed file whose points, colours or intensities
// differ from load_cloud's when both accept it (reported as std::logic_error).
#include "../fuzz_support.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/point_stream.hpp"
#include "hc/pipeline/tiling.hpp"

#include "../../support/file_bytes.hpp"

#include <algorithm>
#include <stdexcept>
#include <string>
#include <vector>

namespace hc::fuzz {
namespace {

// A gzipped E57 has no stream (its reader seeks), but scale.tiled: auto counts it by its XML
// section, inflated up to it (tiled_run.cpp, gzipped_e57_count): where the plain file's stream
// opens with n >= 2 points, the gzipped copy must be decided as the plain file is at the
// thresholds n - 1 and n (std::logic_error otherwise).
void e57_gzip_count(const std::filesystem::path& plain, std::uint64_t n) {
  if (n < 2) return;
  const auto gz = plain.parent_path() / "scan_copy.e57.gz";
  hc::test::write_gzip(gz, hc::test::read_bytes(plain));
  for (const std::uint64_t above : {n - 1, n}) {
    const auto decide = [&](const std::filesystem::path& f) {
      return pipeline::runs_tiled(pipeline::parse_run_config("input: {files: [" + f.filename().string() + "], units: m}\n",
                                                             plain.parent_path() / "run.yaml",
                                                             {"scale.tiled_above_points=" + std::to_string(above)}));
    };
    if (decide(gz) != decide(plain)) throw std::logic_error("a gzipped E57 is counted otherwise than its plain file's stream");
  }
}

void scan_file(const char* extension, const std::uint8_t* data, std::size_t size) {
  const auto path = write_scratch(std::string("scan") + extension, data, size);
  pipeline::Cloud whole;
  bool whole_ok = false;
  try {
    whole = pipeline::load_cloud(path).value;
    whole_ok = true;
  } catch (const hc::Error&) {
    // refused with a message naming the file and what was expected
  }
  try {
    auto stream = pipeline::open_point_stream(path);
    if (std::string(extension) == ".e57") e57_gzip_count(path, stream->total_points());
    std::vector<double> xyz;
    std::vector<std::uint8_t> rgb;
    std::vector<float> intensity;
    pipeline::Cloud chunk;
    while (stream->next(chunk, 97)) {
      xyz.insert(xyz.end(), chunk.xyz.data(), chunk.xyz.data() + chunk.xyz.size());
      rgb.insert(rgb.end(), chunk.rgb.begin(), chunk.rgb.end());
      intensity.insert(intensity.end(), chunk.intensity.begin(), chunk.intensity.end());
    }
    if (whole_ok && stream->streamed()) {
      const auto same_value = [](double a, double b) { return a == b || (a != a && b != b); };  // NaN equals NaN here
      const bool same = xyz.size() == static_cast<std::size_t>(whole.xyz.size()) && std::equal(xyz.begin(), xyz.end(), whole.xyz.data(), same_value);
      if (!same) throw std::logic_error(std::string("the stream's points differ from load_cloud's (") + extension + ")");
      if (rgb != whole.rgb) throw std::logic_error(std::string("the stream's colours differ from load_cloud's (") + extension + ")");
      if (intensity.size() != whole.intensity.size() || !std::equal(intensity.begin(), intensity.end(), whole.intensity.begin(), same_value)) {
        throw std::logic_error(std::string("the stream's intensities differ from load_cloud's (") + extension + ")");
      }
    }
  } catch (const hc::Error&) {
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
