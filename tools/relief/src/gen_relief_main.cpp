// hc-gen-relief: writes a generated carved-wall scan (relief.hpp) of any size as binary PLY or
// LAS, in chunks, for the scaling benchmark (bench/scale.py, docs/scale.md).
//
//   hc-gen-relief wall_1e8.ply --points 1e8
//   hc-gen-relief wall.las --points 2e7 --rgb --width 4 --height 3
//
// Exit codes: 0 written; 1 bad input, an existing output, a write failure; 2 bad command line;
// 128 + the signal's number after SIGINT, SIGTERM or SIGHUP, the half-written temporary removed.

#include "hc/common/error.hpp"
#include "hc/tools/relief.hpp"

#include <CLI/CLI.hpp>

#include <cmath>
#include <csignal>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <mutex>
#include <string>
#include <thread>

#include <pthread.h>
#include <unistd.h>

namespace {

// The temporary write_relief is filling, for the signal watcher (empty: none).
std::mutex g_part_mutex;
std::filesystem::path g_part;

// SIGINT, SIGTERM and SIGHUP blocked in every thread (set before any other thread starts) and
// taken by one watcher thread, which removes the temporary and ends the process: a generator
// stopped half-way leaves no `.part-*` file of gigabytes behind.
void watch_signals() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGTERM);
  sigaddset(&set, SIGHUP);
  if (pthread_sigmask(SIG_BLOCK, &set, nullptr) != 0) return;  // default actions then
  std::thread([set] {
    int sig = 0;
    if (sigwait(&set, &sig) != 0) return;
    const std::lock_guard<std::mutex> lock(g_part_mutex);  // held to the end: no new temporary
    if (!g_part.empty()) {
      std::error_code ec;
      std::filesystem::remove(g_part, ec);
      std::fprintf(stderr, "\nhc-gen-relief: stopped by signal %d; %s removed\n", sig, g_part.c_str());
    } else {
      std::fprintf(stderr, "\nhc-gen-relief: stopped by signal %d\n", sig);
    }
    std::_Exit(128 + sig);
  }).detach();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Write a generated carved-wall scan (binary PLY or LAS 1.2) in chunks, for scaling tests."};
  hc::tools::ReliefSpec spec;
  std::string out;
  double points = static_cast<double>(spec.points);
  double noise_mm = spec.noise_sigma_m * 1e3;
  std::size_t chunk = 1u << 20;
  unsigned threads = 0;
  bool quiet = false;
  app.add_option("out", out, "Output file, .ply, .las or .e57 (never replaced if it exists)")->required();
  app.add_option("--points", points, "Number of points, e.g. 1e8 (an integer >= 1)")->capture_default_str();
  app.add_option("--width", spec.width_m, "Wall width along x [m]")->capture_default_str();
  app.add_option("--height", spec.height_m, "Wall height along y [m]")->capture_default_str();
  app.add_option("--relief-depth", spec.relief_depth_m, "Rosette relief [m]")->capture_default_str();
  app.add_option("--noise-mm", noise_mm, "Gaussian range noise sigma [mm]")->capture_default_str();
  app.add_option("--back-fraction", spec.back_fraction, "Share of points on the back face")->capture_default_str();
  app.add_option("--outlier-fraction", spec.outlier_fraction, "Share of outliers")->capture_default_str();
  app.add_option("--thickness", spec.thickness_m, "Wall thickness [m] (back face at z = -thickness)")->capture_default_str();
  app.add_option("--seed", spec.seed, "Random seed")->capture_default_str();
  app.add_flag("--rgb", spec.rgb, "Write a colour per point (PLY uchar rgb, LAS point format 2)");
  app.add_flag("--scan-order", spec.scan_order,
               "Points in a scanner's order (vertical profiles left to right) instead of uniformly at random");
  app.add_flag("--sorted", spec.sorted,
               "The default order's points sorted into a scanner's order (holds 12 bytes a point while sorting)");
  app.add_option("--chunk", chunk, "Points per chunk (the writer's memory: chunk x 12-26 bytes, and 12 bytes a point with --sorted)")->capture_default_str();
  app.add_option("--threads", threads, "Generator threads (0 = all cores)")->capture_default_str();
  app.add_flag("-q,--quiet", quiet, "No progress on stderr");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }
  if (!(points >= 1.0) || points != std::floor(points) || points > 1.8e19) {
    std::fprintf(stderr, "hc-gen-relief: --points %g (expected an integer >= 1)\n", points);
    return 2;
  }
  spec.points = static_cast<std::uint64_t>(points);
  spec.noise_sigma_m = noise_mm * 1e-3;
  try {
    int last_pct = -1;
    const auto progress = [&](std::uint64_t done, std::uint64_t total) {
      const int pct = static_cast<int>(100.0 * static_cast<double>(done) / static_cast<double>(total));
      if (quiet || pct == last_pct) return;
      last_pct = pct;
      std::fprintf(stderr, "\rhc-gen-relief: %3d %%", pct);
      if (done == total) std::fputc('\n', stderr);
    };
    watch_signals();
    const auto temporary = [](const std::filesystem::path& part) {
      const std::lock_guard<std::mutex> lock(g_part_mutex);
      g_part = part;
    };
    const hc::tools::ReliefWriteStats s = hc::tools::write_relief(spec, out, chunk, threads, progress, temporary);
    std::printf("%s: %llu points (front %llu, back %llu, outliers %llu), %.1f MB in %.2f s (%.1f M points/s), buffer %.1f MB\n",
                out.c_str(), static_cast<unsigned long long>(s.points), static_cast<unsigned long long>(s.front),
                static_cast<unsigned long long>(s.back), static_cast<unsigned long long>(s.outliers),
                static_cast<double>(s.bytes) / 1e6, s.seconds, static_cast<double>(s.points) / s.seconds / 1e6,
                static_cast<double>(s.buffer_bytes) / 1e6);
  } catch (const hc::Error& e) {
    std::fprintf(stderr, "hc-gen-relief: %s\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hc-gen-relief: %s\n", e.what());
    return 1;
  }
  return 0;
}
