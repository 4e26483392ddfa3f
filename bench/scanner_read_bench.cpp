// Read rate of the scanner-format readers against the binary PLY reader, on the same points:
// the merged Happy Buddha (1,099,005 points) is read once, then written by the small writers
// below as a binary little-endian PLY (float x y z) and as LAS 1.2 point format 0 and LAS 1.4
// point format 7 (scale 1e-6 m, intensity, RGB for format 7), into a temporary folder. Each
// benchmark times load_cloud on one of these files (whole file read from the page cache, parse,
// attributes); the counter Mpt/s is million points per second. Wall time, 5 repetitions; read
// the medians. Not part of ctest. Run: build/release/bench/scanner_read_bench
// (LAS vs LAZ only: --benchmark_filter=Autzen).
//
// Memory: a reader's cost includes first-touching its output and file buffers (page faults).
// glibc returns big freed blocks to the kernel (mmap above 32 MiB, heap trimming), so whether a
// repeated read pays those faults again depends on the buffer sizes, not on the parser: the
// 13 MB PLY reuses its pages, the 22–40 MB LAS files do not. `--warm-heap` (first argument)
// turns both off (mallopt M_MMAP_MAX = 0, M_TRIM_THRESHOLD = max) so every format is measured
// with warm pages (parser cost); without it, the default allocator (as one `hapticloud run`).

#include "hc/pipeline/ingest.hpp"

#include <benchmark/benchmark.h>
#include <malloc.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <string>

namespace {

namespace fs = std::filesystem;
using namespace hc::pipeline;

const fs::path kBuddha =
    fs::path(HC_SOURCE_DIR) / "data" / "scans" / "happy_buddha" / "happy_stand_merged_1099005pts.ply.gz";

template <class T>
void put(std::string& b, std::size_t at, T v) {
  std::memcpy(b.data() + at, &v, sizeof v);
}

void write_file(const fs::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!out) throw std::runtime_error("cannot write " + p.string());
}

/// Binary little-endian PLY, float x y z.
std::string ply_bytes(const Cloud& c) {
  const std::string header = "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(c.size()) +
                             "\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  std::string b = header;
  b.resize(header.size() + 12 * c.size());
  for (std::size_t i = 0; i < c.size(); ++i) {
    for (int a = 0; a < 3; ++a) {
      put(b, header.size() + 12 * i + 4 * static_cast<std::size_t>(a), static_cast<float>(c.xyz(a, static_cast<Eigen::Index>(i))));
    }
  }
  return b;
}

/// LAS (ASPRS LAS 1.4 R15 layout): version 1.2 with point format 0 (20-byte records) or 1.4
/// with point format 7 (36-byte records, RGB); no VLRs; scale 1e-6, offset 0.
std::string las_bytes(const Cloud& c, int format) {
  const bool v14 = format >= 6;
  const std::size_t header = v14 ? 375 : 227, len = format == 7 ? 36 : 20;
  std::string b(header + len * c.size(), '\0');
  std::memcpy(b.data(), "LASF", 4);
  b[24] = 1;
  b[25] = v14 ? 4 : 2;
  std::memcpy(b.data() + 58, "hapticloud bench", 16);
  put(b, 94, static_cast<std::uint16_t>(header));
  put(b, 96, static_cast<std::uint32_t>(header));
  b[104] = static_cast<char>(format);
  put(b, 105, static_cast<std::uint16_t>(len));
  put(b, 107, static_cast<std::uint32_t>(v14 ? 0 : c.size()));
  const double scale = 1e-6;
  Eigen::Vector3d lo = c.xyz.rowwise().minCoeff(), hi = c.xyz.rowwise().maxCoeff();
  for (int a = 0; a < 3; ++a) {
    put(b, 131 + 8 * static_cast<std::size_t>(a), scale);
    put(b, 155 + 8 * static_cast<std::size_t>(a), 0.0);
    put(b, 179 + 16 * static_cast<std::size_t>(a), hi[a]);
    put(b, 187 + 16 * static_cast<std::size_t>(a), lo[a]);
  }
  if (v14) put(b, 247, static_cast<std::uint64_t>(c.size()));
  for (std::size_t i = 0; i < c.size(); ++i) {
    const std::size_t at = header + len * i;
    for (int a = 0; a < 3; ++a) {
      put(b, at + 4 * static_cast<std::size_t>(a),
          static_cast<std::int32_t>(std::lround(c.xyz(a, static_cast<Eigen::Index>(i)) / scale)));
    }
    put(b, at + 12, static_cast<std::uint16_t>(i & 0xFFFF));
    b[at + (format <= 5 ? 15 : 16)] = 2;  // ground
    if (format == 7) {
      for (std::size_t k = 0; k < 3; ++k) put(b, at + 30 + 2 * k, static_cast<std::uint16_t>((i * (k + 1)) & 0xFFFF));
    }
  }
  return b;
}

struct Files {
  fs::path dir, ply, las0, las7;
  std::size_t points = 0;
};

const Files& files() {
  static const std::unique_ptr<Files> f = [] {
    auto r = std::make_unique<Files>();
    const Cloud c = load_cloud(kBuddha).value;
    r->points = c.size();
    r->dir = fs::temp_directory_path() / "hc_scanner_read_bench";
    fs::create_directories(r->dir);
    r->ply = r->dir / "buddha.ply";
    r->las0 = r->dir / "buddha_pf0.las";
    r->las7 = r->dir / "buddha_pf7.las";
    write_file(r->ply, ply_bytes(c));
    write_file(r->las0, las_bytes(c, 0));
    write_file(r->las7, las_bytes(c, 7));
    return r;
  }();
  return *f;
}

void read_rate(benchmark::State& state, const fs::path& file) {
  const Files& f = files();
  std::size_t n = 0;
  for (auto _ : state) {
    auto r = load_cloud(file);
    n = r.value.size();
    benchmark::DoNotOptimize(r);
  }
  if (n != f.points) state.SkipWithError("point count differs from the Buddha's");
  state.counters["Mpt/s"] = benchmark::Counter(static_cast<double>(n) * static_cast<double>(state.iterations()) / 1e6,
                                               benchmark::Counter::kIsRate);
  state.counters["MB"] = static_cast<double>(fs::file_size(file)) / 1e6;
}

void BM_Read_PlyBinary(benchmark::State& state) { read_rate(state, files().ply); }
void BM_Read_Las12_Pf0(benchmark::State& state) { read_rate(state, files().las0); }
void BM_Read_Las14_Pf7(benchmark::State& state) { read_rate(state, files().las7); }

// LAZ against LAS on the same points: PDAL's Autzen trim (110,000 points) as LAS 1.2 format 3
// compressed by LASzip (point-wise chunked, 50,000-point chunks) and its uncompressed LAS 1.4
// format 7 twin (data/scans/scanner_samples/, data/README.md). No classes dropped, so both
// deliver every point. There is no LAZ writer here, so the Buddha cannot be compared as LAZ.
// Measured 2026-11-22 on the 2-core Xeon build VM under a load average of 13 (other builds and
// a fuzzer), medians of 5: LAS 8.7 ms wall / 2.7 ms CPU (41 Mpt/s per CPU second), LAZ 258 ms
// wall / 82 ms CPU (1.3 Mpt/s per CPU second, 31x the LAS cost); the 5 Mpt/s goal is not shown
// on that machine: re-measure on an idle one before concluding.
// After the laz-speed branch (model refresh out of line, integer decoder inlined), same day,
// same VM at load 7–8: callgrind counts 1,747 -> 1,590 instructions per point inside
// decompress_laz (repeatable; 5 decodes of this file), while the CPU-time medians of 8
// alternating runs stay within the load's noise (before 68 ms, after 67 ms; minima 62.5 vs
// 59.5 ms): about 1.6–1.8 Mpt/s per CPU second, the 5 Mpt/s aim is still not met.
const fs::path kAutzenLaz = fs::path(HC_SOURCE_DIR) / "data" / "scans" / "scanner_samples" / "laz" / "pdal-autzen_trim.laz";
const fs::path kAutzenLas = fs::path(HC_SOURCE_DIR) / "data" / "scans" / "scanner_samples" / "las" / "pdal-autzen_trim_7.las";

void sample_read_rate(benchmark::State& state, const fs::path& file) {
  if (!fs::exists(file)) {
    state.SkipWithError("missing scanner sample (run data/get-data)");
    return;
  }
  const LoadOptions keep_all{{}};
  std::size_t n = 0;
  for (auto _ : state) {
    auto r = load_cloud(file, keep_all);
    n = r.value.size();
    benchmark::DoNotOptimize(r);
  }
  if (n != 110000) state.SkipWithError("Autzen trim: expected 110,000 points");
  state.counters["Mpt/s"] = benchmark::Counter(static_cast<double>(n) * static_cast<double>(state.iterations()) / 1e6,
                                               benchmark::Counter::kIsRate);
  state.counters["MB"] = static_cast<double>(fs::file_size(file)) / 1e6;
}

void BM_Read_Autzen_Las14_Pf7(benchmark::State& state) { sample_read_rate(state, kAutzenLas); }
void BM_Read_Autzen_Laz12_Pf3(benchmark::State& state) { sample_read_rate(state, kAutzenLaz); }

#define HC_SETTINGS UseRealTime()->Unit(benchmark::kMillisecond)->Repetitions(5)->ReportAggregatesOnly(true)
BENCHMARK(BM_Read_PlyBinary)->HC_SETTINGS;
BENCHMARK(BM_Read_Las12_Pf0)->HC_SETTINGS;
BENCHMARK(BM_Read_Las14_Pf7)->HC_SETTINGS;
BENCHMARK(BM_Read_Autzen_Las14_Pf7)->HC_SETTINGS;
BENCHMARK(BM_Read_Autzen_Laz12_Pf3)->HC_SETTINGS;

}  // namespace

int main(int argc, char** argv) {
  if (argc > 1 && std::string(argv[1]) == "--warm-heap") {
    mallopt(M_MMAP_MAX, 0);
    mallopt(M_TRIM_THRESHOLD, std::numeric_limits<int>::max());
    argv[1] = argv[0];
    ++argv;
    --argc;
  }
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
