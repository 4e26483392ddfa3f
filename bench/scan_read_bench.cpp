// Read rate of the scan readers on the same points: the merged Happy Buddha (1.1 M points) written
// once, at start-up, as a binary little-endian PLY (float x y z) and as E57 files (one scan,
// uncompressed Float single and Float double coordinates) by the small writers below, then read
// through load_cloud (file read + parse, page cache warm). Counter Mpts_per_s = million points per
// second. Wall time (UseRealTime), 5 repetitions; read the medians. Not part of ctest.
// Run: build/release/bench/scan_read_bench [--benchmark_filter=...]

#include "hc/pipeline/ingest.hpp"
#include "hc/tools/e57_pages.hpp"

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

namespace {

namespace fs = std::filesystem;
using hc::pipeline::Cloud;

const fs::path kBuddha = fs::path(HC_SOURCE_DIR) / "data" / "scans" / "happy_buddha" / "happy_stand_merged_1099005pts.ply.gz";

template <class T>
void put(std::string& s, T v) {
  s.append(reinterpret_cast<const char*>(&v), sizeof(T));
}

using hc::tools::e57_physical;

/// One-scan E57 (ASTM E2807): header, one CompressedVector section of data packets holding
/// cartesianX/Y/Z as Float (T = float: single, double: double), the XML, 1024-byte pages with
/// their big-endian CRC-32C.
template <class T>
std::string write_e57(const Cloud& c) {
  const std::size_t n = c.size();
  const std::size_t per_packet = 64000 / (3 * sizeof(T));
  std::string log(48, '\0');
  std::string body;
  for (std::size_t i0 = 0; i0 < n; i0 += per_packet) {
    const std::size_t m = std::min(per_packet, n - i0);
    std::string pk;
    put<std::uint8_t>(pk, 1);
    put<std::uint8_t>(pk, 0);
    put<std::uint16_t>(pk, 0);
    put<std::uint16_t>(pk, 3);
    for (int a = 0; a < 3; ++a) put<std::uint16_t>(pk, static_cast<std::uint16_t>(sizeof(T) * m));
    for (int a = 0; a < 3; ++a)
      for (std::size_t i = i0; i < i0 + m; ++i) put<T>(pk, static_cast<T>(c.xyz(a, static_cast<Eigen::Index>(i))));
    while (pk.size() % 4) pk += '\0';
    const auto l1 = static_cast<std::uint16_t>(pk.size() - 1);
    std::memcpy(pk.data() + 2, &l1, 2);
    body += pk;
  }
  put<std::uint8_t>(log, 1);
  log.append(7, '\0');
  put<std::uint64_t>(log, 32 + body.size());
  put<std::uint64_t>(log, e57_physical(48 + 32));
  put<std::uint64_t>(log, 0);
  log += body;
  const char* precision = sizeof(T) == 4 ? "single" : "double";
  std::string xml = "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<e57Root type=\"Structure\" "
                    "xmlns=\"http://www.astm.org/COMMIT/E57/2010-e57-v1.0\"><data3D type=\"Vector\">"
                    "<vectorChild type=\"Structure\"><points type=\"CompressedVector\" fileOffset=\"48\" recordCount=\"" +
                    std::to_string(n) + "\"><prototype type=\"Structure\">";
  for (const char* axis : {"cartesianX", "cartesianY", "cartesianZ"})
    xml += std::string("<") + axis + " type=\"Float\" precision=\"" + precision + "\"/>";
  xml += "</prototype><codecs type=\"Vector\"/></points></vectorChild></data3D></e57Root>\n";
  while (log.size() % 4) log += '\0';
  const std::size_t xml_at = log.size();
  log += xml;
  while (log.size() % 1020) log += '\0';
  std::string h = "ASTM-E57";
  put<std::uint32_t>(h, 1);
  put<std::uint32_t>(h, 0);
  put<std::uint64_t>(h, log.size() / 1020 * 1024);
  put<std::uint64_t>(h, e57_physical(xml_at));
  put<std::uint64_t>(h, xml.size());
  put<std::uint64_t>(h, 1024);
  log.replace(0, 48, h);
  return hc::tools::e57_pages(log);
}

std::string write_ply(const Cloud& c) {
  std::string s = "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(c.size()) +
                  "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  for (std::size_t i = 0; i < c.size(); ++i)
    for (int a = 0; a < 3; ++a) put<float>(s, static_cast<float>(c.xyz(a, static_cast<Eigen::Index>(i))));
  return s;
}

struct Files {
  fs::path ply, e57_float, e57_double;
  std::size_t points = 0;
};

const Files& files() {
  static const Files f = [] {
    const Cloud c = hc::pipeline::load_cloud(kBuddha).value;
    Files out;
    out.points = c.size();
    const fs::path dir = fs::temp_directory_path() / "hc_scan_read_bench";
    fs::create_directories(dir);
    auto write = [](const fs::path& p, const std::string& b) {
      std::ofstream o(p, std::ios::binary);
      o.write(b.data(), static_cast<std::streamsize>(b.size()));
    };
    out.ply = dir / "buddha.ply";
    out.e57_float = dir / "buddha_float.e57";
    out.e57_double = dir / "buddha_double.e57";
    write(out.ply, write_ply(c));
    write(out.e57_float, write_e57<float>(c));
    write(out.e57_double, write_e57<double>(c));
    return out;
  }();
  return f;
}

void read_rate(benchmark::State& state, const fs::path& p) {
  const std::size_t n = files().points;
  for (auto _ : state) {
    auto r = hc::pipeline::load_cloud(p);
    if (r.value.size() != n) state.SkipWithError("point count differs from the Buddha's");
    benchmark::DoNotOptimize(r);
  }
  state.counters["Mpts_per_s"] = benchmark::Counter(static_cast<double>(n) * 1e-6 * static_cast<double>(state.iterations()),
                                                    benchmark::Counter::kIsRate);
  state.counters["file_MB"] = static_cast<double>(fs::file_size(p)) * 1e-6;
}

void BM_ReadPlyBinaryFloat(benchmark::State& s) { read_rate(s, files().ply); }
void BM_ReadE57Float(benchmark::State& s) { read_rate(s, files().e57_float); }
void BM_ReadE57Double(benchmark::State& s) { read_rate(s, files().e57_double); }

#define HC_BENCH_SETTINGS Unit(benchmark::kMillisecond)->UseRealTime()->Repetitions(5)->ReportAggregatesOnly(true)
BENCHMARK(BM_ReadPlyBinaryFloat)->HC_BENCH_SETTINGS;
BENCHMARK(BM_ReadE57Float)->HC_BENCH_SETTINGS;
BENCHMARK(BM_ReadE57Double)->HC_BENCH_SETTINGS;

}  // namespace

BENCHMARK_MAIN();
