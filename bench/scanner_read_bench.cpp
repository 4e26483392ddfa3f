// Read rate of the scanner-format readers against the binary PLY reader, on the same points
// (tracker issue #12): the merged Happy Buddha (1,099,005 points) is read once, then written by
// the small writers below and in e57_writer.hpp as a binary little-endian PLY (float x y z), as
// LAS 1.2 point format 0 and LAS 1.4 point format 7 (scale 1e-6 m, intensity, RGB for format 7),
// and as E57 (ASTM E2807, one scan, uncompressed values: cartesianX/Y/Z as Float single, or as
// ScaledInteger of 1e-6 m bit-packed in 17 or 18 bits), into a temporary folder. The E57 round trip is
// checked at set-up (every coordinate read back exactly as stored, else the program stops).
// Each benchmark times load_cloud on one file (whole file read from the page cache, parse,
// attributes). The counter Mpt/s is million points per CPU second (CPU time: the build machines
// are shared, so wall time measures the load); 5 repetitions, read the medians. Not part of
// ctest. Run: build/release/bench/scanner_read_bench (LAS vs LAZ only: --benchmark_filter=Autzen).
//
// Memory: a reader's cost includes first-touching its output and file buffers (page faults).
// glibc returns big freed blocks to the kernel (mmap above 32 MiB, heap trimming), so whether a
// repeated read pays those faults again depends on the buffer sizes, not on the parser: the
// 13 MB PLY reuses its pages, the 22–40 MB LAS files and the E57 reader's buffers do not.
// `--warm-heap` (first argument) turns both off (mallopt M_MMAP_MAX = 0, M_TRIM_THRESHOLD =
// max) so every format is measured with warm pages (parser cost); without it, the default
// allocator (as one `hapticloud run`).
//
// Measured 2026-11-22 05:13 UTC on the 2-core Sapphire Rapids build VM (about 2 GHz) at a load
// average of 7.6 falling to 5.5 (a fuzzer on one core, other builds), branch read-rate at
// dce797e. Default allocator: median over 3 runs of the 5-repetition medians, range of the 3 in
// brackets; cost = CPU time relative to the reference read in the same run (PLY for the
// Buddha, LAS for the Autzen trim); warm heap: one run.
//
//   file                        default: Mpt/s       cost ×            CPU ms | warm: Mpt/s  cost ×
//   Buddha, 1,099,005 points
//   PLY binary float  13.2 MB   134.8 [134.3–137.1]   1                  8.2  | 149.3  1
//   LAS 1.2 pf0       22.0 MB    24.6 [23.2–26.5]     5.6 [5.1–5.8]     44.7  |  92.6  1.6
//   LAS 1.4 pf7       39.6 MB    24.2 [23.8–27.4]     5.6 [5.0–5.6]     45.4  |  46.0  3.3
//   E57 Float single  13.2 MB    21.4 [21.1–22.2]     6.4 [6.1–6.4]     51.5  |  51.3  2.9
//   E57 ScaledInteger  7.2 MB    66.6 [64.5–73.8]     2.0 [1.9–2.1]     16.5  |  58.7  2.5
//   Autzen trim, 110,000 points
//   LAS 1.4 pf7        4.0 MB    40.3 [38.0–46.5]     1                  2.7  |  38.5  1
//   LAZ 1.2 pf3        0.6 MB     1.91 [1.87–2.02]   20 [20–25]         57.6  |   1.68 23
//
// Against the aims of #12: only LAS pf0 with warm pages (1.6×) is clearly within 2× of the
// binary PLY reader; E57 ScaledInteger is at the limit (2.0× by default; 2.5× in the single,
// noisier warm-heap run); LAS pf7 and E57 Float are about 3× even with warm pages. With the default allocator the LAS files and E57 Float spend half
// or more of their CPU time on fresh pages (default minus warm-heap CPU time), so the next step
// for them is the buffers (reuse, or decoding straight from the file bytes), not the parsers.
// LAZ: 1.9 Mpt/s per CPU second on this loaded VM, short of 5 (below).

#include "e57_writer.hpp"
#include "hc/pipeline/ingest.hpp"

#include <benchmark/benchmark.h>
#include <malloc.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
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

/// The round trip of an E57 file written by e57_bytes: the reader must give back every point,
/// in order, exactly as stored (float(x) for Float single, raw · scale for ScaledInteger);
/// a benchmark of a file that reads back wrong would measure nothing, so the program stops.
void check_e57_round_trip(const fs::path& file, const Cloud& c, const hc::bench::E57Options& o) {
  const Cloud r = load_cloud(file).value;
  std::size_t bad = c.size();
  if (r.size() == c.size()) {
    bad = 0;
    for (std::size_t i = 0; i < c.size(); ++i) {
      for (int a = 0; a < 3; ++a) {
        const auto k = static_cast<Eigen::Index>(i);
        const double want = o.scaled ? static_cast<double>(hc::bench::e57_raw(c.xyz(a, k), o.scale_m)) * o.scale_m
                                     : static_cast<double>(static_cast<float>(c.xyz(a, k)));
        if (r.xyz(a, k) != want) {
          if (bad++ < 3) std::fprintf(stderr, "%s: point %zu axis %d reads %.17g, wrote %.17g\n", file.c_str(), i, a, r.xyz(a, k), want);
        }
      }
    }
  }
  if (r.size() != c.size() || bad != 0) {
    std::fprintf(stderr, "%s: E57 round trip failed: %zu of %zu points read back, %zu coordinates differ\n", file.c_str(),
                 r.size(), c.size(), bad);
    std::exit(1);
  }
}

struct Files {
  fs::path dir, ply, las0, las7, e57f, e57s;
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
    const hc::bench::E57Options as_float{false}, as_scaled{true, 1e-6};
    r->e57f = r->dir / "buddha_float.e57";
    r->e57s = r->dir / "buddha_scaled.e57";
    write_file(r->e57f, hc::bench::e57_bytes(c, as_float));
    write_file(r->e57s, hc::bench::e57_bytes(c, as_scaled));
    check_e57_round_trip(r->e57f, c, as_float);
    check_e57_round_trip(r->e57s, c, as_scaled);
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
void BM_Read_E57_Float(benchmark::State& state) { read_rate(state, files().e57f); }
void BM_Read_E57_Scaled(benchmark::State& state) { read_rate(state, files().e57s); }

// LAZ against LAS on the same points: PDAL's Autzen trim (110,000 points) as LAS 1.2 format 3
// compressed by LASzip (point-wise chunked, 50,000-point chunks) and its uncompressed LAS 1.4
// format 7 twin (data/scans/scanner_samples/, data/README.md). No classes dropped, so both
// deliver every point. There is no LAZ writer here (a LASzip-compatible encoder is a project of
// its own), so the Buddha is not compared as LAZ: the Autzen twin is the LAZ comparison.
// LAZ decoder cost, callgrind instructions inside decompress_laz per point (5 decodes of this
// file; repeatable to the instruction): 1,747 before the laz-speed branch, 1,590 after it,
// 1,295 after read-rate (fused point-wise loop with the decoder state in locals, typed item
// state, table walk with about one table entry per symbol, known-table symbol calls, no
// zero-fill of the records). CPU time, 4 runs alternating with the main build (same load):
// main 58–65 ms, read-rate 50–63 ms (medians 61.6 and 50.2 ms: 1.8 and 2.2 Mpt/s per CPU
// second). The aim of 5 Mpt/s on one core is not met: with about 15 adaptive-model symbols per
// point (POINT10 + GPSTIME11 + RGB12; a callgrind estimate) each symbol would have to cost
// under 30 cycles of this VM, a division on the decoder's serial path included.
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

#define HC_SETTINGS Unit(benchmark::kMillisecond)->Repetitions(5)->ReportAggregatesOnly(true)
BENCHMARK(BM_Read_PlyBinary)->HC_SETTINGS;
BENCHMARK(BM_Read_Las12_Pf0)->HC_SETTINGS;
BENCHMARK(BM_Read_Las14_Pf7)->HC_SETTINGS;
BENCHMARK(BM_Read_E57_Float)->HC_SETTINGS;
BENCHMARK(BM_Read_E57_Scaled)->HC_SETTINGS;
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
