#include "run_internal.hpp"
#include "stage_util.hpp"
#include "tiled_layers.hpp"
#include "hc/pipeline/run.hpp"

#include "hc/common/error.hpp"
#include "hc/common/format.hpp"
#include "hc/common/units.hpp"
#include "hc/pipeline/filters.hpp"
#include "hc/pipeline/honest_check.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/level_builder.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/lod_report.hpp"
#include "hc/pipeline/mesh_raster.hpp"
#include "hc/pipeline/pcl_filters.hpp"
#include "hc/pipeline/preview.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/robust_outliers.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/pipeline/surface_layers.hpp"
#include "hc/pipeline/synthetic.hpp"
#include "hc/pipeline/tiling.hpp"
#include "hc/pipeline/transform.hpp"

#include <nlohmann/json.hpp>
#include <openssl/evp.h>
#include <sys/resource.h>
#include <sys/sysinfo.h>

#ifdef __GLIBC__
#include <malloc.h>
#endif

#include <algorithm>
#include <array>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <future>
#include <iomanip>
#include <limits>
#include <memory>
#include <optional>
#include <sstream>

namespace hc::pipeline {
namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

/// An OpenSSL SHA-256 context fed by `feed(ctx)`, as lower-case hex (64 characters).
template <typename Feed>
std::string sha256_hex(Feed&& feed) {
  std::unique_ptr<EVP_MD_CTX, decltype(&EVP_MD_CTX_free)> ctx(EVP_MD_CTX_new(), EVP_MD_CTX_free);
  EVP_DigestInit_ex(ctx.get(), EVP_sha256(), nullptr);
  feed(ctx.get());
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int len = 0;
  EVP_DigestFinal_ex(ctx.get(), digest, &len);
  std::ostringstream os;
  for (unsigned int i = 0; i < len; ++i) os << std::hex << std::setw(2) << std::setfill('0') << int(digest[i]);
  return os.str();
}

}  // namespace

namespace {

/// sha256_file that gives up between 1 MiB reads once `stop` is set (its result is then
/// meaningless): the checksums hashed beside an ingest that failed must not hold up its error.
std::string sha256_file_until(const fs::path& file, const std::atomic<bool>& stop) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw InputError(file.string() + ": cannot open to compute its checksum");
  return sha256_hex([&](EVP_MD_CTX* ctx) {
    std::vector<char> buf(1 << 20);
    while (in && !stop.load(std::memory_order_relaxed)) {
      in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
      EVP_DigestUpdate(ctx, buf.data(), static_cast<std::size_t>(in.gcount()));
    }
  });
}

}  // namespace

std::string sha256_file(const fs::path& file) {
  const std::atomic<bool> never{false};
  return sha256_file_until(file, never);
}

namespace {

/// SHA-256 of a cloud's coordinates (the 3 × N doubles as stored, little-endian on x86-64),
/// the provenance checksum of an in-memory input.
std::string coordinates_sha256(const Cloud& cloud) {
  return sha256_hex([&](EVP_MD_CTX* ctx) {
    EVP_DigestUpdate(ctx, cloud.xyz.data(), static_cast<std::size_t>(cloud.xyz.size()) * sizeof(double));
  });
}

using detail::Clock;
using detail::seconds_since;

/// Text for a JSON string: valid UTF-8 is kept; other bytes are written as \\xHH (file names
/// on POSIX are bytes, and nlohmann::json refuses invalid UTF-8 when dumping).
std::string json_text(const std::string& s) {
  std::string out;
  out.reserve(s.size());
  for (std::size_t i = 0; i < s.size();) {
    const auto c = static_cast<unsigned char>(s[i]);
    std::size_t n = c < 0x80 ? 1 : (c >> 5) == 0x6 ? 2 : (c >> 4) == 0xE ? 3 : (c >> 3) == 0x1E ? 4 : 0;
    bool ok = n > 0 && i + n <= s.size();
    for (std::size_t k = 1; ok && k < n; ++k) ok = (static_cast<unsigned char>(s[i + k]) >> 6) == 0x2;
    if (ok) {
      out.append(s, i, n);
      i += n;
    } else {
      static const char* hex = "0123456789abcdef";
      out += "\\x";
      out += hex[c >> 4];
      out += hex[c & 0xF];
      ++i;
    }
  }
  return out;
}

}  // namespace

namespace detail {

/// Resets the process's resident-memory high-water mark (Linux, proc(5): writing "5" to
/// /proc/self/clear_refs resets VmHWM). @return false when it cannot (then peak_rss() is the
/// peak since the process started, or since the last reset).
namespace {
std::atomic<bool> g_measure_stage_memory{false};
}  // namespace

bool reset_peak_rss() {
  if (!g_measure_stage_memory.load(std::memory_order_relaxed)) return false;
  std::FILE* f = std::fopen("/proc/self/clear_refs", "w");
  if (!f) return false;
  const bool ok = std::fputs("5", f) >= 0;
  return std::fclose(f) == 0 && ok;
}

namespace {
std::atomic<int> g_heap_release_holders{0};
}  // namespace

// The M_MMAP_THRESHOLD keep_freed_heap_for_reuse set [bytes]; 0: the C library's own.
std::atomic<int> g_kept_mmap_threshold{0};

namespace {
// Live LargeBlocksMapped guards that changed the threshold: the first sets it, the last restores
// the threshold recorded when the first set it.
std::atomic<int> g_mapped_holders{0};
std::atomic<int> g_mapped_restore{0};
}  // namespace

LargeBlocksMapped::LargeBlocksMapped(std::size_t threshold_bytes) {
#ifdef __GLIBC__
  const int kept = g_kept_mmap_threshold.load(std::memory_order_relaxed);
  if (kept <= 0 || g_heap_release_holders.load(std::memory_order_relaxed) <= 0) return;
  const auto want = static_cast<int>(std::min<std::size_t>(threshold_bytes, static_cast<std::size_t>(kept)));
  if (g_mapped_holders.fetch_add(1, std::memory_order_acq_rel) == 0) {
    g_mapped_restore.store(kept, std::memory_order_relaxed);
    if (mallopt(M_MMAP_THRESHOLD, want) != 1) {
      g_mapped_holders.fetch_sub(1, std::memory_order_acq_rel);
      return;
    }
  }
  active_ = true;
#else
  (void)threshold_bytes;
#endif
}

LargeBlocksMapped::~LargeBlocksMapped() {
#ifdef __GLIBC__
  if (active_ && g_mapped_holders.fetch_sub(1, std::memory_order_acq_rel) == 1) {
    (void)mallopt(M_MMAP_THRESHOLD, g_mapped_restore.load(std::memory_order_relaxed));
  }
#endif
}

StageHeapRelease::StageHeapRelease() { g_heap_release_holders.fetch_add(1, std::memory_order_relaxed); }
StageHeapRelease::~StageHeapRelease() { g_heap_release_holders.fetch_sub(1, std::memory_order_relaxed); }

void release_freed_heap_if_asked() {
#ifdef __GLIBC__
  if (g_heap_release_holders.load(std::memory_order_relaxed) > 0) (void)malloc_trim(0);
#endif
}

TileHeapBudget::TileHeapBudget(std::size_t budget_bytes) : budget_(budget_bytes), base_(resident_bytes()) {}

bool TileHeapBudget::before_tile() {
  if (g_heap_release_holders.load(std::memory_order_relaxed) <= 0) return false;
  const std::size_t now = resident_bytes();
  if (now == 0 || now <= base_ + budget_) return false;
  return release_now();
}

bool TileHeapBudget::release_now() {
  if (g_heap_release_holders.load(std::memory_order_relaxed) <= 0) return false;
#ifdef __GLIBC__
  (void)malloc_trim(0);
#endif
  base_ = resident_bytes();
  ++releases_;
  return true;
}

namespace {
/// The field `key` (e.g. "VmHWM:", with its colon) of /proc/self/status, given there in kB
/// (proc(5)), in bytes; 0 if unreadable or absent.
std::size_t status_field_bytes(const char* key) {
  std::FILE* f = std::fopen("/proc/self/status", "r");
  if (!f) return 0;
  const std::size_t len = std::strlen(key);
  char line[256];
  std::size_t kb = 0;
  while (std::fgets(line, sizeof line, f)) {
    if (std::strncmp(line, key, len) == 0) {
      kb = static_cast<std::size_t>(std::strtoull(line + len, nullptr, 10));
      break;
    }
  }
  std::fclose(f);
  return kb * 1024;
}
}  // namespace

/// VmHWM of /proc/self/status [bytes]: the peak resident memory since the last reset; 0 if
/// unreadable.
std::size_t peak_rss() { return status_field_bytes("VmHWM:"); }

std::size_t resident_bytes() { return status_field_bytes("VmRSS:"); }

double process_cpu_seconds() {
  rusage u{};
  if (getrusage(RUSAGE_SELF, &u) != 0) return 0.0;
  auto s = [](const timeval& t) { return static_cast<double>(t.tv_sec) + 1e-6 * static_cast<double>(t.tv_usec); };
  return s(u.ru_utime) + s(u.ru_stime);
}

}  // namespace detail

namespace {
using detail::peak_rss;
using detail::reset_peak_rss;
using detail::stage;

json stats_json(const ErrorStats& s) {
  return {{"count", s.count}, {"rms_mm", s.rms_mm}, {"p50_mm", s.p50_mm}, {"p95_mm", s.p95_mm},
          {"p99_mm", s.p99_mm}, {"max_mm", s.max_mm}};
}

/// The report's numbers: `precision` decimals (hc::format_number, fixed style).
std::string fmt(double v, int precision = 3) { return format_number(v, precision, NumberStyle::kFixed); }

std::string stats_row(const std::string& what, const ErrorStats& s) {
  return "| " + what + " | " + std::to_string(s.count) + " | " + fmt(s.rms_mm) + " | " + fmt(s.p50_mm) +
         " | " + fmt(s.p95_mm) + " | " + fmt(s.p99_mm) + " | " + fmt(s.max_mm) + " |\n";
}

void write_text(const fs::path& file, const std::string& text) {
  std::ofstream out(file);
  out << text;
  if (!out) throw InputError(file.string() + ": cannot write");
}

/// A point filter skipped for a mesh: the cloud unchanged, with a note naming the key.
StageResult<Cloud> skip_for_mesh(Cloud cloud, const char* key) {
  StageResult<Cloud> r;
  r.report.count_in = r.report.count_out = cloud.size();
  r.report.notes.push_back(std::string("skipped for a mesh (") + key +
                           " would remove vertices and open holes in its faces; input.as_points: true applies it)");
  r.value = std::move(cloud);
  return r;
}

/// How far a filter may have moved the point that stands for an input point [m], for the honest
/// cross-check's removal test (check_input's voxel_leaf_m): the voxel leaf, and the leaf or
/// search radius of the filters.pcl stages that output new points, summed (chained moving
/// filters move a point by up to the sum of their reaches); 0 when every filter only drops
/// points (removal then judged by exact coordinates).
double removal_displacement_m(const RunConfig& config) {
  double d = config.filters.voxel_m;
  for (const PclFilterSpec& spec : config.filters.pcl) d += pcl_filter_displacement_m(spec);
  return d;
}

}  // namespace

namespace detail {


StoredPrecision stored_precision(const Cloud& cloud, double unit_m, const std::string& file) {
  StoredPrecision p;
  p.float32 = cloud.float32_xyz;
  p.file = file;
  p.crs = cloud.crs;
  if (!p.float32) return p;
  // One pass over the columns, the maxima in registers (three strided passes with the maximum
  // kept in memory took 10 ms of the Buddha's serial ingest); distinct values are looked for
  // only while fewer than kDistinctCap have been seen on that axis.
  std::array<std::vector<double>, 3> seen;
  double m0 = 0.0, m1 = 0.0, m2 = 0.0;
  bool all_seen = false;
  const double* xyz = cloud.xyz.data();
  const auto n = static_cast<std::size_t>(cloud.xyz.cols());
  for (std::size_t i = 0; i < n; ++i) {
    const double x = xyz[3 * i], y = xyz[3 * i + 1], z = xyz[3 * i + 2];
    // A non-finite value counts on no axis (the other axes of its point still count).
    if (std::isfinite(x)) m0 = std::abs(x) > m0 ? std::abs(x) : m0;
    if (std::isfinite(y)) m1 = std::abs(y) > m1 ? std::abs(y) : m1;
    if (std::isfinite(z)) m2 = std::abs(z) > m2 ? std::abs(z) : m2;
    if (all_seen) continue;
    for (std::size_t a = 0; a < 3; ++a) {
      const double v = xyz[3 * i + a];
      std::vector<double>& s = seen[a];
      if (std::isfinite(v) && static_cast<int>(s.size()) < kDistinctCap && std::find(s.begin(), s.end(), v) == s.end()) {
        s.push_back(v);
      }
    }
    all_seen = static_cast<int>(std::min({seen[0].size(), seen[1].size(), seen[2].size()})) >= kDistinctCap;
  }
  p.max_abs_m = Eigen::Vector3d(m0, m1, m2) * unit_m;
  for (std::size_t a = 0; a < 3; ++a) p.distinct[static_cast<Eigen::Index>(a)] = static_cast<int>(seen[a].size());
  return p;
}

/// The float-precision check once the cell size is known: a warning when a float-stored
/// coordinate cannot resolve a tenth of a cell (|x|·2⁻²⁴ > cell/10), an error naming the cause
/// when the points along a grid axis (an axis not along the view direction) have collapsed onto
/// fewer than kCollapsedDistinct distinct values.
void check_stored_precision(const StoredPrecision& p, double cell_m, const Eigen::Matrix3d& view_rotation,
                            StageReport& report, std::vector<std::string>& warnings) {
  if (!p.float32) return;
  const char* names = "xyz";
  const double ulp_factor = std::ldexp(1.0, -24);
  for (int a = 0; a < 3; ++a) {
    const double step_m = p.max_abs_m[a] * ulp_factor;
    if (!(step_m > cell_m / 10.0)) continue;
    const std::string what = p.file + ": coordinates are stored as 32-bit floats and reach |" + names[a] +
                             "| = " + format_number(p.max_abs_m[a]) + " m, where float32 resolves only about " +
                             format_number(step_m * 1e3) + " mm (|" + names[a] + "|·2^-24), more than a tenth of the " +
                             format_number(cell_m * 1e3) + " mm grid cell";
    // Grid axis: the file axis contributes to grid x or y (not only to the depth).
    const bool grid_axis = std::abs(view_rotation(2, a)) < 0.9;
    if (grid_axis && p.distinct[a] < kCollapsedDistinct) {
      throw DegenerateInputError(what + "; the points take only " + std::to_string(p.distinct[a]) +
                                 " distinct " + names[a] + " values, so the grid collapses. Store the coordinates "
                                 "as double (or subtract the georeferencing offset before saving as float)");
    }
    report.notes.push_back("warning: " + what + "; store them as double or subtract the offset before saving");
    warnings.push_back(report.notes.back().substr(9));
  }
}

/// Ingest, units and recentring, view transform and filters, each recorded as a stage.
/// `inputs` gets the input files with their checksums, `offset_m` the recentring offset.
/// `as_read`, when given, gets a copy of the coordinates after the view transform, before any
/// filter (24 bytes per point: 26 MB for the 1.1 M-point Buddha), for the honest cross-check;
/// the points filters.crop removes are NaN in it (counted as removed, not classified).
/// `in_memory`, when given, replaces ingest: its points (moved from) are the input, in
/// config.input.units, and input.files, conf and synthetic are not read. The input files'
/// SHA-256 is computed on a second thread while ingest runs (given up if ingest throws).

}  // namespace detail

namespace {
using detail::StoredPrecision;
using detail::check_stored_precision;
using detail::stored_precision;

Cloud prepare_points_staged(const RunConfig& config, std::vector<StageReport>& reports, const ProgressFn& progress,
                            std::vector<SceneInput>& scene_inputs, Eigen::Vector3d& offset_m,
                            StoredPrecision* precision = nullptr,
                            Eigen::Matrix3Xd* as_read = nullptr, Cloud* in_memory = nullptr, double* sample_spacing_m = nullptr) {
  // The input files' checksums (provenance) on a thread of their own while ingest inflates and
  // parses on this one: ingest is serial, and hashing the Buddha's 12 MB took 6 ms after it.
  // Should ingest throw, `stop` (set by the guard, destroyed before the future) makes the
  // hashing give up at its next 1 MiB read, so the error is not held up by a full read.
  std::atomic<bool> stop_hashing{false};
  std::future<std::vector<SceneInput>> checksums;
  if (!in_memory) {
    checksums = std::async(std::launch::async, [&config, &stop_hashing] {
      std::vector<SceneInput> sums;
      for (const auto& f : config.input.files) sums.push_back({f.string(), sha256_file_until(f, stop_hashing)});
      if (config.input.conf) {
        sums.push_back({config.input.conf->string(), sha256_file_until(*config.input.conf, stop_hashing)});
      }
      return sums;
    });
  }
  struct StopOnExit {
    std::atomic<bool>& stop;
    ~StopOnExit() { stop.store(true, std::memory_order_relaxed); }
  } const stop_on_exit{stop_hashing};
  // 1. Ingest.
  Cloud cloud = stage("ingest", reports, progress, [&] {
    if (in_memory) {
      StageResult<Cloud> r{std::move(*in_memory), {}};
      const Cloud& c = r.value;
      const std::size_t n = c.size();
      const auto wrong = [&](const char* name, std::size_t have, std::size_t per_point) {
        if (have != 0 && have != per_point * n) {
          throw InputError("build_scene: the in-memory cloud has " + std::to_string(n) + " points but its " + name +
                           " holds " + std::to_string(have) + " values (expected 0 or " + std::to_string(per_point * n) + ")");
        }
      };
      wrong("intensity", c.intensity.size(), 1);
      wrong("rgb", c.rgb.size(), 3);
      wrong("normal", c.normal.size(), 3);
      wrong("curvature", c.curvature.size(), 1);
      wrong("scan_id", c.scan_id.size(), 1);
      wrong("row", c.row.size(), 1);
      wrong("col", c.col.size(), 1);
      if (!c.curvature.empty() && c.normal.empty()) {
        throw InputError("build_scene: the in-memory cloud has curvature but no normals (expected both or neither)");
      }
      r.report.count_in = r.report.count_out = r.value.size();
      r.report.notes.push_back("in-memory cloud handed to build_scene (input.files, input.conf and input.synthetic not read)");
      return r;
    }
    if (config.input.synthetic) return StageResult<Cloud>{generate_surface(*config.input.synthetic), {}};
    const LoadOptions load_options{config.input.las_drop_classes, config.input.as_points};
    if (config.input.conf) return load_and_merge_scans(config.input.files, *config.input.conf, load_options);
    if (config.input.shared_frame) return load_files_in_one_frame(config.input.files, load_options);
    if (config.input.files.size() > 1) {  // a RunConfig made in code: the YAML reader refuses it
      throw ConfigError("input.files lists " + std::to_string(config.input.files.size()) +
                        " files without input.conf or input.shared_frame: expected one of them");
    }
    return load_cloud(config.input.files.front(), load_options);
  });
  if (reports.back().count_out == 0) reports.back().count_out = cloud.size();
  const std::size_t ingest_index = reports.size() - 1;
  struct {
    bool rgb, intensity, grid_index, scan_id, normals;
  } const ingest_attrs{cloud.has_rgb(), cloud.has_intensity(), cloud.has_grid_index(), cloud.has_scan_id(),
                       cloud.has_normals()};
  const std::size_t ingest_triangles = cloud.mesh.triangles.size();
  if (in_memory) {
    scene_inputs.push_back({"(in-memory cloud, " + std::to_string(cloud.size()) + " points)", coordinates_sha256(cloud)});
  } else {
    for (SceneInput& in : checksums.get()) scene_inputs.push_back(std::move(in));
  }

  // 2. Units and recentring (double precision), 3. view transform.
  const double unit_m = metres_per_unit(config.input.units);
  if (precision != nullptr && (in_memory || !config.input.files.empty())) {
    *precision = stored_precision(cloud, unit_m, in_memory ? std::string("in-memory cloud") : detail::inputs_label(config.input.files));
  }
  cloud = stage("recentre", reports, progress,
                [&] { return to_metres_and_recentre(std::move(cloud), unit_m, &offset_m, config.input.max_extent_m); });
  cloud = stage("transform", reports, progress, [&] { return apply_view_transform(std::move(cloud), config.view); });
  if (as_read) *as_read = cloud.xyz;

  // 4. Filters.
  cloud = stage("non_finite", reports, progress, [&] { return remove_non_finite(std::move(cloud)); });
  if (config.filters.crop_m) {
    cloud = stage("crop", reports, progress, [&] {
      return crop_box(std::move(cloud), config.filters.crop_m->first, config.filters.crop_m->second);
    });
    // The honest check judges the scan within the crop: a point outside it counts as removed and
    // is not classified (NaN, as a non-finite point), as in a tiled run, whose passes drop it
    // before the spill. Until 2026-11-30 it was classified: a far stray cropped as the
    // far_points warning advises still warned, and cropped points changed the isolated count
    // (found by tests/pipeline/tiled_differential_test.cpp).
    if (as_read) {
      for (Eigen::Index i = 0; i < as_read->cols(); ++i) {
        if (as_read->col(i).allFinite() && !inside_box(as_read->col(i), config.filters.crop_m->first, config.filters.crop_m->second)) {
          as_read->col(i).setConstant(std::numeric_limits<double>::quiet_NaN());
        }
      }
    }
  }
  // Meshes: the point filters that would delete vertices (and so open holes in the faces) or
  // replace them (voxel centroids carry no faces) are skipped, with a note (mesh_raster.hpp).
  const bool mesh = cloud.has_mesh();
  if (config.filters.voxel_m > 0.0) {
    cloud = stage("voxel", reports, progress, [&] {
      return mesh ? skip_for_mesh(std::move(cloud), "filters.voxel_m") : voxel_downsample(std::move(cloud), config.filters.voxel_m);
    });
  }
  // filters.pcl: PCL's own classes, in the config's order, each its own stage (pcl_filters.hpp).
  for (std::size_t i = 0; i < config.filters.pcl.size(); ++i) {
    const PclFilterSpec& spec = config.filters.pcl[i];
    const std::string name = "pcl:" + spec.name;
    cloud = stage(name.c_str(), reports, progress, [&] {
      if (mesh) return skip_for_mesh(std::move(cloud), "filters.pcl");
      return apply_pcl_filter(std::move(cloud), spec);
    });
  }
  if (config.filters.outliers.enabled) {
    RobustScale robust_scale;  // the robust test's (spacing_m 0 until it has one)
    cloud = stage("outliers", reports, progress, [&] {
      if (mesh) return skip_for_mesh(std::move(cloud), "filters.outliers");
      const OutlierConfig& oc = config.filters.outliers;
      if (oc.method == OutlierMethod::kRobust) {
        RobustOutlierOptions ro;
        ro.k = oc.k;
        ro.local_ratio = oc.local_ratio;
        ro.mad_multiplier = oc.mad_multiplier;
        ro.off_surface_ratio = oc.off_surface_ratio;
        return remove_outliers_robust(std::move(cloud), ro, oc.far_clusters, &robust_scale);
      }
      if (config.filters.outliers.scope == OutlierScope::kFront) {
        return remove_front_statistical_outliers(std::move(cloud), config.filters.outliers.k,
                                                 config.filters.outliers.std_multiplier, config.grid.reproject);
      }
      return remove_statistical_outliers(std::move(cloud), config.filters.outliers.k,
                                         config.filters.outliers.std_multiplier);
    });
    // The robust test keeps coherent sparse regions; stray points with almost no neighbour at
    // the scan's own spacing go here, by the same rule the verdict uses for "spikes kept".
    if (!mesh && config.filters.outliers.method == OutlierMethod::kRobust) {
      // At the spacing the robust test's sample measured (a tiled run's tiles take the same).
      HonestCheckOptions isolation = config.cross_check.honest;
      isolation.spacing_m = robust_scale.spacing_m;
      isolation.frame_centre_m = robust_scale.centre_m;  // the frame a tiled run's windows take
      cloud = stage("isolated", reports, progress, [&] { return remove_isolated_points(std::move(cloud), isolation); });
      if (sample_spacing_m != nullptr) *sample_spacing_m = robust_scale.spacing_m;
    }
  }

  // What per-point attributes the scan carried and what reached the grid (the ingest report).
  {
    StageReport& ingest = reports[ingest_index];
    std::string found, kept;
    auto item = [](std::string& list, const char* name) { list += (list.empty() ? "" : ", ") + std::string(name); };
    if (ingest_attrs.rgb) item(found, "colour (rgb)");
    if (ingest_attrs.intensity) item(found, "intensity");
    if (ingest_attrs.grid_index) item(found, "row/col");
    if (ingest_attrs.scan_id) item(found, "scan_id");
    if (ingest_attrs.normals) item(found, "normals");
    if (cloud.has_rgb()) item(kept, "colour (rgb)");
    if (cloud.has_intensity()) item(kept, "intensity");
    if (cloud.has_grid_index()) item(kept, "row/col");
    if (cloud.has_scan_id()) item(kept, "scan_id");
    if (cloud.has_normals()) item(kept, "normals");
    ingest.notes.push_back("per-point attributes found: " + (found.empty() ? std::string("none") : found) +
                           "; kept through the filters: " + (kept.empty() ? std::string("none") : kept) +
                           " (colour and intensity go to the scene's layers; row/col and scan_id are used by the grid only with "
                           "grid.organised: mesh; normals only travel to the filtered cloud)");
    if (ingest_triangles > 0) {
      ingest.notes.push_back("mesh: " + std::to_string(ingest_triangles) + " triangles read, " +
                             std::to_string(cloud.mesh.triangles.size()) +
                             " rasterised (a triangle with a vertex removed by a filter is dropped)");
    }
  }
  return cloud;
}

/// Layer `name` of stored level `level` of the tiled scene folder `scene_dir` (grid `g`, that
/// level's), read whole into `out` (g.cell_count() floats, or × 3 bytes for `samples` kRgb8).
/// @throws hc::InputError naming the file when it is missing, not a tiled TIFF of g's size and
///         sample type, or unreadable.
void read_stored_layer(const fs::path& scene_dir, int level, const std::string& name, const GridGeometry& g,
                       detail::TileSamples samples, void* out) {
  const fs::path file = detail::stored_layer_file(scene_dir, level, name);
  const std::string why = detail::read_tiled_layer(file, g, samples, [out] { return out; });
  if (!why.empty()) {
    throw InputError(file.string() + ": cannot read level " + std::to_string(level) + "'s layer '" + name +
                     "' (expected a tiled " + std::to_string(g.cols) + "x" + std::to_string(g.rows) +
                     (samples == detail::TileSamples::kRgb8 ? " RGB" : " float") + " TIFF; " + why + ")");
  }
}

/// The run folder's previews (previews/*.png) of one level: its layers in memory (level 0 as
/// built) or in a tiled scene's files (read when each preview is drawn).
struct PreviewLevel {
  int level = 0;
  GridGeometry g;
  fs::path scene_dir;  ///< stored layers (empty: in memory)
  const HeightField *depth = nullptr, *cell_error = nullptr, *texture = nullptr, *mu_d = nullptr, *mu_s = nullptr;
  const CellBuffer<std::uint8_t>* colour = nullptr;

  /// Calls f with layer `name` (the in-memory one, or read from level `level`'s file).
  template <class F>
  void with(const char* name, const HeightField* in_memory, F&& f) const {
    if (in_memory != nullptr) return f(*in_memory);
    HeightField read(g);
    read_stored_layer(scene_dir, level, name, g, detail::TileSamples::kFloat32, read.data());
    f(read);
  }
  /// " (level k, 1 sample : 2^k cells)" for a level above 0, else "".
  std::string title_suffix() const {
    return level == 0 ? std::string() : " (level " + std::to_string(level) + ", 1 sample : " + std::to_string(1 << level) + " cells)";
  }
};

/// Which previews add_previews draws: depth (and its hillshade), colour (plain and over the
/// hillshade), the cross-check error, the surface layers (texture, mu_d, mu_s).
struct PreviewKinds {
  bool depth = false, colour = false, cell_error = false, surface_layers = false;
};

/// Adds to `tasks` one task per preview `wanted` of `pl` into `dir` (each reads the layers it
/// draws when it runs, so two tasks on two threads hold two layers): the cross-check error with
/// `marks` (level-0 (row, col), moved to the level's nearest sample); `friction_name` titles
/// mu_d. `pl` must outlive the tasks. @throws (when run) hc::InputError from the reads and writes.
void add_previews(std::vector<std::function<void()>>& tasks, const PreviewLevel& pl, const PreviewKinds& wanted,
                  const fs::path& dir, const std::vector<std::array<int, 2>>& marks, const std::string& friction_name) {
  const std::string sfx = pl.title_suffix();
  if (wanted.colour) {
    for (const bool shaded : {false, true}) {
      tasks.emplace_back([&pl, dir, shaded] {
        const fs::path png = dir / (shaded ? "colour_hillshade.png" : "colour.png");
        pl.with("depth", pl.depth, [&](const HeightField& d) {
          if (pl.colour != nullptr) return write_rgb_preview(d, *pl.colour, png, shaded);
          std::vector<std::uint8_t> rgb(3 * pl.g.cell_count());
          read_stored_layer(pl.scene_dir, pl.level, "colour", pl.g, detail::TileSamples::kRgb8, rgb.data());
          write_rgb_preview(d, rgb, png, shaded);
        });
      });
    }
  }
  if (wanted.cell_error) {
    tasks.emplace_back([&pl, dir, sfx, marks] {
      const std::vector<std::array<int, 2>> at = marks_on_level(marks, pl.level, pl.g);
      // Above level 0 the stored error is level 0's averaged by the anti-aliasing kernel
      // (LodLevel::cell_error_m), so a one-cell spike shows weaker than it is: the title says so.
      const std::string what = pl.level == 0 ? std::string("cross-check: grid sample to nearest point")
                                             : std::string("cross-check: grid sample to nearest point, level 0's averaged");
      pl.with("cell_error", pl.cell_error, [&](const HeightField& e) {
        write_colour_preview(e, dir / "cross_check_error.png",
                             (at.empty() ? what : what + " (circles: spikes, pits, islands)") + sfx, "mm", 1000.0, at);
      });
    });
  }
  if (wanted.depth) {
    tasks.emplace_back([&pl, dir, sfx] {
      pl.with("depth", pl.depth, [&](const HeightField& d) { write_colour_preview(d, dir / "depth.png", "depth z" + sfx, "mm", 1000.0); });
    });
    tasks.emplace_back([&pl, dir, sfx] {
      pl.with("depth", pl.depth, [&](const HeightField& d) { write_hillshade_preview(d, dir / "hillshade.png", "hillshade" + sfx); });
    });
  }
  if (wanted.surface_layers) {
    tasks.emplace_back([&pl, dir, sfx] {
      pl.with("texture", pl.texture, [&](const HeightField& f) {
        write_colour_preview(f, dir / "texture.png", "texture h = f - f_b" + sfx, "mm", 1000.0);
      });
    });
    tasks.emplace_back([&pl, dir, sfx, friction_name] {
      pl.with("mu_d", pl.mu_d, [&](const HeightField& f) {
        write_colour_preview(f, dir / "mu_d.png", "dynamic friction mu_d (" + friction_name + ")" + sfx, "-", 1.0);
      });
    });
    tasks.emplace_back([&pl, dir, sfx] {
      pl.with("mu_s", pl.mu_s, [&](const HeightField& f) { write_colour_preview(f, dir / "mu_s.png", "static friction mu_s" + sfx, "-", 1.0); });
    });
  }
}

/// Whether write_run's stage scene_levels can make level 0's surface layers for `config` and a
/// level 0 of grid `g` (SurfaceLayersAt::kSceneLevels): layers on, a tiled scene, and no levels
/// table (whose in-memory pyramid holds level 0's layers anyway).
bool level0_layers_by_builder(const RunConfig& config, const GridGeometry& g) {
  return config.layers.enabled && writes_tiled_scene(config.scale, g) && !config.lod.report;
}

/// The level a tiled scene's previews are drawn from: 0 when level 0's longer side is at most
/// `max_side` samples, else the finest level that fits, or the coarsest of `stored_levels`.
int preview_level_of(const GridGeometry& g0, int stored_levels, int max_side) {
  int level = 0;
  while (level + 1 < stored_levels) {
    const GridGeometry g = lod_level_geometry(g0, level);
    if (std::max(g.rows, g.cols) <= max_side) break;
    ++level;
  }
  return level;
}

/// The report's summary: the verdict, the input's classes and every reason (report.md, top).
std::string verdict_markdown(const RunSummary& summary) {
  std::ostringstream md;
  const Verdict& v = *summary.verdict;
  std::string status = v.status;
  for (char& ch : status) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
  auto pct = [](double f) { return format_number(100.0 * f, 2, NumberStyle::kFixed) + " %"; };
  md << "**Verdict: " << status << "**";
  if (summary.input_check) {
    const InputCheck& in = *summary.input_check;
    md << ". Input as read (" << in.points << " points): " << pct(in.fraction(in.on_surface)) << " on the surface, "
       << pct(in.fraction(in.removed)) << " removed by the filters, " << pct(in.fraction(in.hidden))
       << " hidden (behind the surface), " << pct(in.fraction(in.no_data)) << " on no-data cells, "
       << pct(in.fraction(in.off_surface)) << " off the surface, " << pct(in.fraction(in.outside))
       << " outside the grid; surface lost " << in.surface_lost << " points (max gap "
       << format_number(in.surface_lost_max_gap_m * 1e3, 3) << " mm); spikes kept " << in.spikes_kept << " cells";
  }
  if (summary.grid_spikes) {
    md << "; grid spikes " << summary.grid_spikes->spikes << ", pits " << summary.grid_spikes->pits << ", island cells "
       << summary.grid_spikes->island_cells;
  }
  md << ".\n\n";
  for (const VerdictReason& r : v.reasons) md << "- " << r.level << " (" << r.code << "): " << r.message << "\n";
  if (!v.reasons.empty()) md << "\n";
  return md.str();
}

}  // namespace

namespace detail {

Eigen::Affine3d scene_from_grid(DepthGrid& grid, const RunConfig& config, std::vector<StageReport>& reports,
                                const ProgressFn& progress, const StoredPrecision& precision,
                                const Eigen::Vector3d& offset_m, std::size_t grid_report, BuiltScene& built) {
  RunSummary& summary = built.summary;
  Scene& scene = built.scene;
  check_stored_precision(precision, grid.depth.geometry().cell_size_m, config.view.matrix().rotation(),
                         reports.at(grid_report), summary.warnings);
  // Scan-line corrugation of the grid (before hole filling), for the report.
  (void)stage("corrugation", reports, progress, [&] { return corrugation(grid); });
  if (config.grid.hole_fill_max_cells > 0) {
    grid = stage("hole_fill", reports, progress, [&] { return fill_holes(std::move(grid), config.grid.hole_fill_max_cells, config.grid.hole_fill_max_step_m); });
  }
  const double unit_m = metres_per_unit(config.input.units);
  const Eigen::Affine3d model_to_grid =
      config.view.matrix() * Eigen::Translation3d(-offset_m) * Eigen::Scaling(unit_m);
  grid.depth.model_to_grid = model_to_grid;
  summary.grid = grid.depth.geometry();
  summary.valid_cells = grid.depth.valid_count();
  scene.geometry = grid.depth.geometry();
  scene.model_to_grid = model_to_grid;
  scene.layers.flags = std::move(grid.flags);
  // Colour and intensity of the front-most point per cell (reproject), hole-filled like depth.
  scene.layers.colour_rgb8 = std::move(grid.colour_rgb8);
  if (grid.has_intensity()) {
    scene.layers.intensity = std::move(grid.intensity);
    scene.layers.intensity.model_to_grid = model_to_grid;
  }

  return model_to_grid;
}

void scene_surface_layers(const HeightField& depth, const RunConfig& config, std::vector<StageReport>& reports,
                          const ProgressFn& progress, BuiltScene& built) {
  Scene& scene = built.scene;
  // 6. Surface layers (texture, curvature, friction): here on the whole grid (in core right
  // after the hole fill; a tiled run after its checks), or left to the tiled scene's level
  // builder in write_run (SurfaceLayersAt::kSceneLevels: a tiled scene without the levels
  // table, whose pyramid would hold level 0's layers anyway).
  if (!level0_layers_by_builder(config, scene.geometry)) built.surface_layers_at = SurfaceLayersAt::kMemory;
  if (built.surface_layers_at == SurfaceLayersAt::kSceneLevels) {
    // What compute_surface_layers records; the layers themselves come in stage scene_levels.
    scene.friction_model = config.layers.options.friction_model;
  } else if (config.layers.enabled) {
    // The curvature maps (8 bytes a sample) go inside the stage, so that its end gives their
    // heap back: the scene does not keep them.
    SurfaceLayers layers = stage("surface_layers", reports, progress, [&] {
      auto r = compute_surface_layers(depth, config.layers.options, config.lod.window_cells);
      r.value.mean_curvature_per_m = HeightField();
      r.value.gaussian_curvature_per_m2 = HeightField();
      return r;
    });
    scene.friction_model = layers.friction_model;
    scene.layers.envelope = std::move(layers.envelope_m);
    scene.layers.texture = std::move(layers.texture_m);
    scene.layers.mu_d = std::move(layers.mu_d);
    scene.layers.mu_s = std::move(layers.mu_s);  // each with depth's model_to_grid (compute_surface_layers)
  }
}

}  // namespace detail

Cloud prepare_points(const RunConfig& config) {
  std::vector<StageReport> reports;
  std::vector<SceneInput> inputs;
  Eigen::Vector3d offset_m = Eigen::Vector3d::Zero();
  return prepare_points_staged(config, reports, {}, inputs, offset_m);
}

namespace {
BuiltScene build_scene_impl(const RunConfig& config, bool keep_cloud, const ProgressFn& progress, Cloud* in_memory);
}  // namespace

void set_stage_memory_measurement(bool on) { detail::g_measure_stage_memory.store(on, std::memory_order_relaxed); }

HeapPolicyTaken keep_freed_heap_for_reuse() noexcept {
  HeapPolicyTaken taken;
#ifdef __GLIBC__
  constexpr int kOneGiB = 1 << 30;
  taken.mmap_threshold_set = mallopt(M_MMAP_THRESHOLD, kOneGiB) == 1;
  taken.trim_threshold_set = mallopt(M_TRIM_THRESHOLD, kOneGiB) == 1;
  if (taken.mmap_threshold_set) detail::g_kept_mmap_threshold.store(kOneGiB, std::memory_order_relaxed);
#endif
  return taken;
}

namespace detail {

std::uint64_t memory_limit_from(const std::string& proc_self_cgroup, const std::filesystem::path& cgroup_root,
                                std::uint64_t ram_and_swap_bytes) {
  std::uint64_t limit = ram_and_swap_bytes;
  const auto lower_to = [&limit](const std::filesystem::path& file) {
    std::ifstream f(file);
    std::string text;
    if (!(f >> text) || text.empty() || !std::all_of(text.begin(), text.end(), [](char ch) { return ch >= '0' && ch <= '9'; })) return;
    errno = 0;
    const std::uint64_t cg = std::strtoull(text.c_str(), nullptr, 10);
    if (errno == 0 && cg > 0 && (limit == 0 || cg < limit)) limit = cg;
  };
  std::istringstream lines(proc_self_cgroup);
  for (std::string line; std::getline(lines, line);) {
    // "<id>:<controllers>:<path>"; the path may hold ':' itself.
    const auto a = line.find(':');
    const auto b = a == std::string::npos ? a : line.find(':', a + 1);
    if (b == std::string::npos) continue;
    const std::string id = line.substr(0, a), controllers = line.substr(a + 1, b - a - 1);
    const std::filesystem::path path = std::filesystem::path(line.substr(b + 1)).relative_path();
    std::vector<std::pair<std::filesystem::path, const char*>> where;  // (mount, limit file)
    if (id == "0" && controllers.empty()) {  // cgroup v2: the unified mount, or on a hybrid host its own
      where = {{cgroup_root, "memory.max"}, {cgroup_root / "unified", "memory.max"}};
    } else {
      bool memory = false;
      std::istringstream names(controllers);
      for (std::string n; std::getline(names, n, ',');) memory = memory || n == "memory";
      if (!memory) continue;
      where = {{cgroup_root / "memory", "memory.limit_in_bytes"}};
      if (controllers != "memory") where.emplace_back(cgroup_root / controllers, "memory.limit_in_bytes");  // "cpuset,memory"
    }
    for (const auto& [mount, name] : where) {
      for (std::filesystem::path dir = path;; dir = dir.parent_path()) {
        lower_to(mount / dir / name);
        if (dir.empty()) break;
      }
    }
  }
  return limit;
}

}  // namespace detail

std::uint64_t memory_limit_bytes() noexcept {
  try {
    std::uint64_t ram_swap = 0;
    struct sysinfo si {};
    if (sysinfo(&si) == 0) {
      ram_swap = (static_cast<std::uint64_t>(si.totalram) + static_cast<std::uint64_t>(si.totalswap)) * si.mem_unit;
    }
    std::ifstream f("/proc/self/cgroup");
    std::ostringstream text;
    text << f.rdbuf();
    return detail::memory_limit_from(text.str(), "/sys/fs/cgroup", ram_swap);
  } catch (...) {
    return 0;
  }
}

void check_in_core_fits(const RunConfig& config, std::uint64_t limit_bytes, const std::string& way_out) {
  if (limit_bytes == 0) return;
  const std::optional<std::uint64_t> points = counted_input_points(config, true);
  if (!points) return;
  const auto need = static_cast<long double>(*points) * static_cast<long double>(kInCoreBytesPerPointAtLeast);
  if (need <= static_cast<long double>(limit_bytes)) return;
  std::string files;
  for (const auto& f : config.input.files) files += (files.empty() ? "" : ", ") + f.string();
  const auto gb = [](long double b) { return format_number(static_cast<double>(b / 1e9), 3) + " GB"; };
  throw ResourceError(files + ": " + std::to_string(*points) + " points read whole (in core) need at least " + gb(need) +
                      " (" + std::to_string(kInCoreBytesPerPointAtLeast) + " bytes a point), more than the " +
                      gb(static_cast<long double>(limit_bytes)) + " of memory this process may use (RAM and swap, or "
                      "its memory cgroup's limit): " + way_out);
}

void check_in_core_run_fits(const RunConfig& config, bool keep_cloud, std::uint64_t limit_bytes) {
  std::string why;
  if (config.scale.tiled == ScaleConfig::Tiled::kOff) {
    why = "scale.tiled is off; set it to auto or on, and the tiled run streams the scan in chunks (docs/scale.md)";
  } else if (const std::string refusal = tiled_run_refusal(config); !refusal.empty()) {
    why = "the run stays in core because " + refusal + ", which the tiled run does not support yet; without it the "
          "tiled run streams the scan in chunks (docs/scale.md)";
  } else if (keep_cloud) {
    why = "the caller keeps the whole cloud (the levels table's cross-check in core); set scale.tiled: on, whose "
          "run keeps a sample of the points instead";
  } else {
    why = "scale.tiled_above_points (" + std::to_string(config.scale.tiled_above_points) +
          ") keeps it in core; lower it or set scale.tiled: on to stream the scan in chunks";
  }
  check_in_core_fits(config, limit_bytes, why);
}

namespace {
/// build_scene's choice: scans too large for memory take the streaming tiled run (tiling.hpp;
/// it keeps no cloud, so a caller that asks for the cloud stays in core unless scale.tiled is on).
bool takes_tiled_run(const RunConfig& config, bool keep_cloud) {
  const bool auto_mode = config.scale.tiled == ScaleConfig::Tiled::kAuto;
  return !(keep_cloud && auto_mode) && runs_tiled(config);
}
}  // namespace

BuiltScene build_scene(const RunConfig& config, bool keep_cloud, const ProgressFn& progress) {
  if (takes_tiled_run(config, keep_cloud)) return build_scene_tiled(config, progress);
  check_in_core_run_fits(config, keep_cloud, memory_limit_bytes());  // before minutes of reading, not after
  return build_scene_impl(config, keep_cloud, progress, nullptr);
}

BuiltScene build_scene(Cloud cloud, const RunConfig& config, bool keep_cloud, const ProgressFn& progress) {
  return build_scene_impl(config, keep_cloud, progress, &cloud);
}

namespace {
BuiltScene build_scene_impl(const RunConfig& config, bool keep_cloud, const ProgressFn& progress, Cloud* in_memory) {
  const auto t_start = Clock::now();
  BuiltScene built;
  RunSummary& summary = built.summary;
  auto& reports = summary.stages;
  Scene& scene = built.scene;
  SceneProvenance& prov = scene.provenance;
  Eigen::Vector3d offset_m = Eigen::Vector3d::Zero();
  StoredPrecision precision;
  Eigen::Matrix3Xd as_read;  // for the honest cross-check; freed after it
  double sample_spacing_m = 0.0;  // the robust test's sample's (0: it did not run)
  Cloud cloud = prepare_points_staged(config, reports, progress, prov.inputs, offset_m, &precision,
                                      config.cross_check.enabled ? &as_read : nullptr, in_memory, &sample_spacing_m);
  prov.crs = precision.crs;

  // 5. Reprojection and hole filling.
  // Organised scans (row/col) meshed per scan on their own grid (grid.organised: mesh).
  bool organised_meshed = false;
  if (config.grid.organised_mesh && cloud.has_grid_index() && !cloud.has_mesh()) {
    organised_meshed = true;
    cloud = stage("organised_mesh", reports, progress, [&] {
      return mesh_organised_scans(std::move(cloud), config.grid.organised_max_edge_factor);
    });
  } else if (config.grid.organised_mesh && !cloud.has_mesh()) {
    reports.back().notes.push_back("grid.organised: mesh, but the points carry no scanner row/col: gridded as points");
  }
  // Meshes are rasterised (z-buffer over the faces); points are binned and splatted.
  const bool rasterised = cloud.has_mesh();
  // Gridding that names the far points stretching the grid (a passer-by, a distant wall), if any,
  // when the grid degenerates.
  auto naming_far_points = [&](auto&& grid_points) {
    try {
      return grid_points();
    } catch (const DegenerateInputError& e) {
      const std::string far = describe_far_points(cloud);
      if (far.empty()) throw;
      throw DegenerateInputError(e.what() + far);
    }
  };
  auto grid_it = [&] {
    if (cloud.has_mesh()) return rasterise_mesh(cloud, config.grid.reproject, organised_meshed ? config.grid.organised_blend_m : 0.0);
    return naming_far_points([&] { return reproject(cloud, config.grid.reproject); });
  };
  DepthGrid grid = stage("reproject", reports, progress, grid_it);
  std::size_t reproject_report = reports.size() - 1;  // the report of the grid in use
  // The robust filter judges each point by its neighbours; a stray point a few millimetres in
  // front of the surface has the surface among them. Here the grid judges it: points that make
  // spikes or islands and have no neighbour at the spike's scale go, and the grid is made again.
  if (!rasterised && config.filters.outliers.enabled && config.filters.outliers.method == OutlierMethod::kRobust &&
      config.filters.outliers.despike) {
    double k = 1.0;  // a point's disc spans splat radius × K grid cells when upsampled
    for (const auto& [name, value] : reports[reproject_report].figures)
      if (name == "upsample_factor" && value >= 1.0) k = value;
    double spacing_m = 0.0;  // the isolated stage's estimate of the scan's spacing
    for (const StageReport& rep : reports) {
      if (rep.stage != "isolated") continue;
      for (const auto& [name, value] : rep.figures)
        if (name == "spacing_mm" && value > 0.0 && std::isfinite(value)) spacing_m = value * 1e-3;
    }
    const std::size_t before = cloud.size();
    RemovedPoints removed;
    cloud = stage("despike", reports, progress, [&] {
      return remove_spike_points(std::move(cloud), grid.depth, config.cross_check.honest,
                                 std::max(1.0, config.grid.reproject.splat_radius_cells) * k, spacing_m, k, &removed);
    });
    if (cloud.size() < before) {
      // Made again only about the removed points (the same grid and figures as a whole reproject).
      const StageReport had = reports[reproject_report];
      grid = stage("reproject", reports, progress, [&] {
        return naming_far_points([&] {
          return reproject_after_removal(cloud, removed, StageResult<DepthGrid>{std::move(grid), had}, config.grid.reproject);
        });
      });
      reproject_report = reports.size() - 1;
    }
  }
  const Eigen::Affine3d model_to_grid =
      detail::scene_from_grid(grid, config, reports, progress, precision, offset_m, reproject_report, built);
  detail::scene_surface_layers(grid.depth, config, reports, progress, built);

  // 7. Cross-check.
  if (config.cross_check.enabled) {
    summary.cross_check = stage("cross_check", reports, progress,
                                [&] {
                                  return cross_check(cloud, grid.depth, config.cross_check.tolerance_m,
                                                     config.cross_check.hidden_band_m);
                                });
    summary.cross_check->cell_error_m.model_to_grid = model_to_grid;
    const auto& ro = config.grid.reproject;
    if (config.cross_check.compare_naive &&
        (ro.splat_radius_cells > 0.0 || ro.see_through_depth_m > 0.0 || config.grid.hole_fill_max_cells > 0)) {
      summary.naive_cross_check = stage("cross_check_naive", reports, progress, [&] {
        ReprojectOptions naive;
        naive.grid = ro.grid;
        const DepthGrid naive_grid = reproject(cloud, naive).value;
        return cross_check(cloud, naive_grid.depth, config.cross_check.tolerance_m, config.cross_check.hidden_band_m);
      });
      summary.naive_cross_check->cell_error_m = HeightField();  // the figures are enough
    }
    scene.layers.cell_error = summary.cross_check->cell_error_m;

    // 7b. The honest cross-check: the input as read, the grid's own spikes, the verdict.
    struct Honest {
      InputCheck input;
      GridSpikes spikes;
    };
    Honest honest = stage("honest_check", reports, progress, [&] {
      StageResult<Honest> r;
      // The reproject stage's actual upsample factor K.
      double k = 1.0;
      for (const StageReport& rep : reports) {
        if (rep.stage != "reproject") continue;
        for (const auto& [name, value] : rep.figures)
          if (name == "upsample_factor" && value >= 1.0) k = value;
      }
      HonestCheckOptions honest_options = detail::honest_options_for(config, rasterised, k, grid.depth.geometry().cell_size_m);
      // The scan's spacing of the robust test's sample, when it ran (the tiled run's too).
      // Not when a voxel or PCL filter thinned the cloud before the robust test: its spacing
      // is then the thinned cloud's, and the check tests the points as read.
      honest_options.spacing_m = config.filters.voxel_m > 0.0 || !config.filters.pcl.empty() ? 0.0 : sample_spacing_m;
      r.value.spikes = find_grid_spikes(grid.depth, honest_options);
      r.value.input = check_input(as_read, cloud, grid.depth, honest_options, removal_displacement_m(config),
                                  &r.value.spikes, &scene.layers.flags);
      detail::add_honest_figures(r.value.input, r.value.spikes, r.report);
      r.report.figure("as_read_copy_mb", static_cast<double>(as_read.size() * sizeof(double)) / 1e6);
      return r;
    });
    double supported = summary.cross_check->supported_fraction;
    summary.verdict = decide_verdict(honest.input, honest.spikes, supported, reports, config.cross_check.honest);
    summary.input_check = std::move(honest.input);
    summary.grid_spikes = std::move(honest.spikes);
    as_read = Eigen::Matrix3Xd();
  }
  scene.layers.depth = std::move(grid.depth);

  // Typed metadata: what made the layers, and where the scan came from.
  scene.layer_options = config.layers.options;
  scene.lod = config.lod;
  prov.tool = std::string("hapticloud ") + HC_VERSION;
  prov.config_file = config.source.string();
  prov.units = config.input.units;
  prov.recentre_offset_m = offset_m;
  if (config.input.synthetic && in_memory == nullptr) prov.synthetic = to_string(config.input.synthetic->kind);
  prov.resolved_config_yaml = config.resolved_yaml;

  // A tiled scene stores the levels table's points (points_sample.bin, lod_report.hpp): every
  // ⌈N / lod.report_sample_points⌉-th filtered point, as the tiled run keeps its sample.
  if (!keep_cloud && config.cross_check.enabled && cloud.size() > 0 && writes_tiled_scene(config.scale, scene.geometry)) {
    built.point_sample = every_nth_point(cloud, level_sample_stride(cloud.size(), config.lod.report_sample_points));
    built.point_sample_of = cloud.size();
  }
  if (keep_cloud) built.cloud = std::move(cloud);
  summary.total_seconds = seconds_since(t_start);
  return built;
}
}  // namespace

namespace {
// write_run; with `movable` (the same scene, owned by the caller and not needed afterwards) the
// levels pyramid takes level 0's layers from it instead of copying them (issue 14: a copy of
// six layers is 200 MB at N = 4096).
RunSummary write_run_impl(const BuiltScene& built, BuiltScene* movable, const RunConfig& config, const fs::path& out_dir,
                          const ProgressFn& progress, ExistingOutput existing, const LevelTimingFn& level_timing) {
  const auto t_start = Clock::now();
  const Scene& scene = built.scene;
  // Level 0's surface layers left to stage scene_levels (SurfaceLayersAt::kSceneLevels): only
  // into the tiled scene without the levels table it was built for (checked before anything
  // is moved out of `movable`).
  const bool layers_by_builder = built.surface_layers_at == SurfaceLayersAt::kSceneLevels;
  if (layers_by_builder && !level0_layers_by_builder(config, scene.geometry)) {
    throw std::invalid_argument(
        "write_run: the scene's surface layers were left to the tiled scene's level builder, but this config "
        "has layers off, writes no tiled scene or asks for the levels table (lod.report): build it with "
        "SurfaceLayersAt::kMemory");
  }
  const double built_seconds = built.summary.total_seconds;
  std::optional<detail::StageHeapRelease> heap_release;
  if (built.from_tiled_run) heap_release.emplace();
  // The output folder first: a refused one must leave the caller's scene whole.
  StagingDir staging(out_dir, existing);
  // Moved from `movable` (it aliases `built`): its cross-check error grid is not copied.
  RunSummary summary = movable != nullptr ? std::move(movable->summary) : built.summary;
  auto& reports = summary.stages;

  // 8. Scene, previews and report, all inside the staging folder.
  const auto t_write = Clock::now();
  StageReport write_report;
  write_report.stage = "write";
  if (progress) progress(write_report, false);
  const bool write_measured = reset_peak_rss();
  const double write_cpu0 = detail::process_cpu_seconds();
  const SceneProvenance& prov = scene.provenance;
  json inputs = json::array();
  for (const SceneInput& in : prov.inputs) inputs.push_back({{"file", json_text(in.file)}, {"sha256", in.sha256}});
  json provenance = {{"tool", prov.tool}, {"inputs", inputs},
                     {"recentre_offset_m", {prov.recentre_offset_m.x(), prov.recentre_offset_m.y(), prov.recentre_offset_m.z()}},
                     {"units", prov.units}};
  if (!prov.crs.empty()) provenance["crs"] = json_text(prov.crs);
  // The tiled scene (issue 14): level 0 in tiles now, the coarser levels after the levels stage.
  const bool tiled_scene = writes_tiled_scene(config.scale, scene.geometry);
  SceneStorage storage;
  if (tiled_scene) storage = {config.scale.scene_tile_cells, lod_level_count(scene.geometry, config.lod.min_cells)};
  const fs::path previews = staging.path() / "previews";
  // One level only: an interrupt may have removed the staging folder, which must stay removed.
  std::error_code previews_ec;
  fs::create_directory(previews, previews_ec);
  if (previews_ec) throw InputError(previews.string() + ": cannot create the previews folder: " + previews_ec.message());
  const HeightField& depth = scene.depth();
  const std::string friction_name = scene.friction_model ? to_string(*scene.friction_model) : std::string();
  // Previews: of level 0 in memory here; of a stored level after stage scene_levels when level
  // 0 is wider than scale.preview_max_side (preview_level > 0), and of level 0's surface layers
  // there when the level builder makes them (layers_by_builder).
  const int preview_level = tiled_scene ? preview_level_of(scene.geometry, storage.stored_levels, config.scale.preview_max_side) : 0;
  // Marked on the cross-check preview: the grid's spikes, pits and islands, and the cells kept
  // only by isolated points (level 0's rows and columns).
  std::vector<std::array<int, 2>> marks;
  if (summary.grid_spikes) marks = summary.grid_spikes->marked;
  if (summary.input_check) {
    marks.insert(marks.end(), summary.input_check->spikes_kept_cells.begin(), summary.input_check->spikes_kept_cells.end());
  }
  PreviewLevel level0_previews;
  level0_previews.g = scene.geometry;
  level0_previews.depth = &depth;
  level0_previews.colour = &scene.layers.colour_rgb8;
  // The scene's layer: a tiled run's summary holds no copy of it (RunSummary::cross_check).
  if (summary.cross_check) {
    level0_previews.cell_error =
        scene.layers.cell_error.rows() > 0 ? &scene.layers.cell_error : &summary.cross_check->cell_error_m;
  }
  level0_previews.texture = &scene.layers.texture;
  level0_previews.mu_d = &scene.layers.mu_d;
  level0_previews.mu_s = &scene.layers.mu_s;
  PreviewKinds now;
  if (preview_level == 0) {
    now.depth = true;
    now.colour = !scene.layers.colour_rgb8.empty();
    now.cell_error = summary.cross_check.has_value();
    now.surface_layers = scene.layers.has_surface_layers();
  }
  // The scene's files and the previews are independent files: two threads take them in turn,
  // the scene first (the longest), then the previews (each writes its own PNG).
  std::vector<std::function<void()>> files;
  files.emplace_back([&] {
    write_scene(scene, staging.path() / "scene", storage);
    // The levels table's points beside a tiled scene, or any scene of a tiled run, so that
    // `hapticloud levels` cross-checks it without reading the scan again (lod_report.hpp): the
    // run's sample, or every s-th point of its cloud. (A scene of an in-core run that is not
    // stored tiled has none: its scan fits in memory, and levels reads it through the config.)
    if (!summary.cross_check) return;
    if (built.point_sample && (tiled_scene || built.from_tiled_run)) {
      write_level_point_sample(staging.path() / "scene", *built.point_sample,
                               std::max<std::uint64_t>(built.point_sample_of, built.point_sample->size()));
    } else if (tiled_scene && built.cloud && built.cloud->size() > 0) {
      const Cloud& c = *built.cloud;
      write_level_point_sample(staging.path() / "scene", every_nth_point(c, level_sample_stride(c.size(), config.lod.report_sample_points)),
                               c.size());
    }
  });
  add_previews(files, level0_previews, now, previews, marks, friction_name);
  if (!scene.layers.intensity.values().empty()) {
    files.emplace_back([&] {
      // Not stored in the levels: level 0's, one sample in 2^k along each axis for a level k.
      if (preview_level == 0) {
        return write_colour_preview(scene.layers.intensity, previews / "intensity.png", "scanner intensity (as stored)", "-", 1.0);
      }
      const GridGeometry g = lod_level_geometry(scene.geometry, preview_level);
      HeightField every(g);
      for (int r = 0; r < g.rows; ++r)
        for (int c = 0; c < g.cols; ++c) every.at(r, c) = scene.layers.intensity.at(r << preview_level, c << preview_level);
      write_colour_preview(every, previews / "intensity.png",
                           "scanner intensity (as stored; level 0's every " + std::to_string(1 << preview_level) +
                               " samples, on level " + std::to_string(preview_level) + ")",
                           "-", 1.0);
    });
  }
  detail::run_tasks_on_two(files);
  write_report.seconds = seconds_since(t_write);
  write_report.cpu_seconds = detail::process_cpu_seconds() - write_cpu0;
  if (write_measured) write_report.peak_rss_bytes = peak_rss();
  detail::release_freed_heap_if_asked();
  reports.push_back(write_report);
  if (progress) progress(write_report, true);

  // What the report says of the layers, taken before level 0 may be moved into the pyramid.
  const bool has_surface_layers = scene.layers.has_surface_layers() || layers_by_builder;
  const bool has_colour = !scene.layers.colour_rgb8.empty();
  const bool has_intensity = !scene.layers.intensity.values().empty();
  // A tiled scene without the levels table reads nothing of level 0's grids from here on (the
  // level builder reads the stored tiles; the report wants the flags' counts only): a movable
  // scene lets them go before stage scene_levels (issue 14: 16-40 bytes a cell).
  if (movable != nullptr && tiled_scene && !config.lod.report) {
    SceneLayers& l = movable->scene.layers;
    for (HeightField* f : {&l.depth, &l.envelope, &l.texture, &l.mu_d, &l.mu_s, &l.cell_error, &l.region_id, &l.intensity}) {
      *f = HeightField();
    }
    l.colour_rgb8.clear();
    if (summary.cross_check) summary.cross_check->cell_error_m = HeightField();
    // Given back now, not at scene_levels' end: with the batch heap policy (thresholds of 1 GiB)
    // freed layers inside the heap stay resident until a trim, and stage scene_levels held them
    // as its own (fifty-sixth session: 490 MB at 134 M cells once the error map was no longer
    // copied, the copy's freeing having pushed the heap's top past the trim threshold before).
    detail::release_freed_heap_if_asked();
  }

  // 9. Levels of detail (issue 4): speed against error per level, with previews side by side.
  std::vector<LevelRow> lod_rows;
  std::vector<std::string> lod_previews;
  // The pyramid of the levels table and of the tiled scene's stored levels: made once, from level
  // 0's layers (moved out of `movable`, else copied; the cross-check error too when stored).
  std::shared_ptr<LodPyramid> pyramid;
  const auto make_pyramid = [&] {
    LodLevel l0;
    if (movable != nullptr) {
      SceneLayers& from = movable->scene.layers;
      l0.depth_m = std::move(from.depth);
      l0.colour_rgb8 = std::move(from.colour_rgb8);
      if (tiled_scene) l0.cell_error_m = std::move(from.cell_error);
      if (has_surface_layers) {
        l0.envelope_m = std::move(from.envelope);
        l0.texture_m = std::move(from.texture);
        l0.mu_d = std::move(from.mu_d);
        l0.mu_s = std::move(from.mu_s);
        l0.has_layers = true;
      }
    } else {
      l0.depth_m = scene.layers.depth;
      l0.colour_rgb8 = scene.layers.colour_rgb8;
      if (tiled_scene) l0.cell_error_m = scene.layers.cell_error;
      if (has_surface_layers) {
        l0.envelope_m = scene.layers.envelope;
        l0.texture_m = scene.layers.texture;
        l0.mu_d = scene.layers.mu_d;
        l0.mu_s = scene.layers.mu_s;
        l0.has_layers = true;
      }
    }
    return std::make_shared<LodPyramid>(std::move(l0), config.layers.options, config.lod);
  };
  if (config.lod.report) {
    lod_rows = stage("levels", reports, progress, [&] {
      pyramid = make_pyramid();
      LevelTableOptions to;
      // Every filtered point in core; the tiled run's strided sample otherwise (no support then).
      const Cloud* level_points = built.cloud ? &*built.cloud : built.point_sample ? &*built.point_sample : nullptr;
      to.cross_check = config.lod.report_cross_check && level_points != nullptr;
      // A sample that holds every point (a small tiled run) is the whole set (level_table):
      // support measured.
      if (!built.cloud && built.point_sample) to.points_represent = built.point_sample_of;
      to.tolerance_m = config.cross_check.tolerance_m;
      to.hidden_band_m = config.cross_check.hidden_band_m;
      to.sample_points = config.lod.report_sample_points;
      if (summary.cross_check) to.level0_cross_check = *summary.cross_check;
      // The previews are written while the table is measured (the pyramid is thread-safe and
      // builds each level once); the servo timing runs alone afterwards.
      StageResult<std::vector<LevelRow>> r;
      double previews_s = 0.0;
      detail::run_two(
          [&] {
            const auto t_previews = detail::Clock::now();
            lod_previews = write_level_previews(*pyramid, previews);
            previews_s = detail::seconds_since(t_previews);
          },
          [&] { r.value = level_table(pyramid, level_points, to); });
      double build_s = 0.0, check_s = 0.0;
      for (const LevelRow& row : r.value) {
        build_s += row.build_seconds;
        check_s += row.cross_check_seconds;
      }
      r.report.figure("build_s", build_s);
      r.report.figure("cross_check_s", check_s);
      r.report.figure("previews_s", previews_s);
      const auto t_timing = detail::Clock::now();
      if (level_timing) level_timing(pyramid, r.value);
      r.report.figure("servo_timing_s", detail::seconds_since(t_timing));
      r.report.count_in = summary.valid_cells;
      r.report.count_out = r.value.size();
      return r;
    });
  }
  if (tiled_scene) {
    // The streaming level builder (level_builder.hpp): every coarser level made tile by tile from
    // the stored level above, in memory bounded by a tile and its halo (the in-memory pyramid's
    // levels, bit for bit).
    stage("scene_levels", reports, progress, [&] {
      StageResult<std::uint64_t> r;
      std::error_code ec;
      const fs::path scratch = config.scale.scratch.empty() ? fs::temp_directory_path(ec) : config.scale.scratch;
      // The builder's passes (level k's depth, its layers' fill range, envelope and friction),
      // each with its fraction and time left, at most once per scale.progress_interval_s.
      std::string pass;
      std::optional<detail::PassProgress> tick;
      const LevelProgress tell = [&](const std::string& what, double fraction) {
        if (what != pass) {
          pass = what;
          tick.emplace(progress, "scene_levels", what + ", this pass", config.scale.progress_interval_s);
        }
        (*tick)(fraction);
      };
      const fs::path scene_dir = staging.path() / "scene";
      const StoredLevelsReport built_levels = build_stored_levels(
          scene_dir, scratch, tell, layers_by_builder ? Level0Layers::kSceneFolder : Level0Layers::kLevelsFolder);
      if (layers_by_builder && built_levels.level0_layers) {
        r.report.figure("level0_layers_s", built_levels.layers_seconds.at(0));
        r.report.notes.push_back("level 0's surface layers made here tile by tile from the stored depth (no whole-grid "
                                 "surface_layers stage; SurfaceLayersAt::kSceneLevels)");
      }
      if (preview_level > 0 || layers_by_builder) {
        // Previews from the stored files, each task reading its layers (two at a time): level
        // preview_level's every preview, or level 0's surface layers, which were never in memory.
        const auto t_previews = Clock::now();
        PreviewLevel stored;
        stored.level = preview_level;
        stored.g = lod_level_geometry(scene.geometry, preview_level);
        stored.scene_dir = scene_dir;
        PreviewKinds later;
        later.surface_layers = has_surface_layers;
        if (preview_level > 0) {
          later.depth = true;
          later.colour = has_colour;
          later.cell_error = summary.cross_check.has_value() && fs::exists(detail::stored_layer_file(scene_dir, preview_level, "cell_error"));
        }
        std::vector<std::function<void()>> tasks;
        add_previews(tasks, stored, later, previews, marks, friction_name);
        // Each preview's layer and canvas (up to scale.preview_max_side² × 4 and × 3 bytes) are
        // mapped on their own and given back when freed, so the kept heap does not grow by
        // them (detail::LargeBlocksMapped; a tiled run only).
        const detail::LargeBlocksMapped mapped(std::size_t{4} << 20);
        detail::run_tasks_on_two(tasks);
        r.report.figure("previews_level", preview_level);
        r.report.figure("previews_s", seconds_since(t_previews));
        if (preview_level > 0) {
          r.report.notes.push_back("previews drawn from stored level " + std::to_string(preview_level) + " (" +
                                   std::to_string(stored.g.cols) + " x " + std::to_string(stored.g.rows) +
                                   "): level 0 is wider than scale.preview_max_side = " +
                                   std::to_string(config.scale.preview_max_side) + " samples");
        }
      }
      r.value = built_levels.bytes;
      r.report.count_in = static_cast<std::size_t>(storage.stored_levels);
      r.report.count_out = static_cast<std::size_t>(storage.stored_levels);
      r.report.figure("tile_cells", storage.tile_cells);
      r.report.figure("levels_bytes_mb", static_cast<double>(r.value) / (1024.0 * 1024.0));
      r.report.figure("peak_buffer_mb", static_cast<double>(built_levels.peak_buffer_bytes) / (1024.0 * 1024.0));
      r.report.figure("scratch_mb", static_cast<double>(built_levels.scratch_bytes) / (1024.0 * 1024.0));
      double depth_s = 0.0, layers_s = 0.0;
      for (double v : built_levels.depth_seconds) depth_s += v;
      for (double v : built_levels.layers_seconds) layers_s += v;
      r.report.figure("depth_s", depth_s);
      r.report.figure("layers_s", layers_s);
      r.report.notes.push_back("levels built tile by tile from the stored level above (streaming level builder)");
      return r;
    });
  }
  summary.total_seconds = built_seconds + seconds_since(t_start);

  // Report: JSON for machines, Markdown for people; both from the same figures.
  const GridGeometry& g = summary.grid;
  std::size_t n_filled = 0, n_see_through = 0, n_splatted = 0;
  for (auto f : scene.layers.flags) {
    n_filled += f == kCellFilled;
    n_see_through += f == kCellSeeThrough;
    n_splatted += f == kCellSplatted;
  }
  scene.layers.flags.release_resident();  // a file-backed layer's pages given back (cell_buffer.hpp)
  json j;
  j["name"] = json_text(config.name);
  j["tool"] = std::string("hapticloud ") + HC_VERSION;
  j["config_file"] = json_text(config.source.string());
  j["provenance"] = provenance;
  // What the C library's allocator was asked for (hapticloud run adds glibc.malloc.hugetlb=1
  // where it helps, apps/hapticloud/commands.hpp): it moves the run's CPU time by several per
  // cent, so a report's times are read with it.
  const char* tunables = std::getenv("GLIBC_TUNABLES");
  j["process"] = {{"glibc_tunables", json_text(tunables != nullptr ? tunables : "")}};
  j["grid"] = {{"rows", g.rows}, {"cols", g.cols}, {"cell_size_m", g.cell_size_m}, {"x0_m", g.x0_m},
               {"y0_m", g.y0_m}, {"valid_cells", summary.valid_cells}, {"filled_cells", n_filled},
               {"see_through_cells", n_see_through}, {"splatted_cells", n_splatted}};
  j["stages"] = json::array();
  for (const auto& s : reports) {
    json js = {{"stage", s.stage}, {"count_in", s.count_in}, {"count_out", s.count_out}, {"seconds", s.seconds}};
    if (s.cpu_seconds > 0.0) js["cpu_seconds"] = s.cpu_seconds;
    if (s.peak_rss_bytes > 0) js["peak_rss_mb"] = static_cast<double>(s.peak_rss_bytes) / 1e6;
    for (const auto& [k, v] : s.figures) js["figures"][k] = v;
    if (!s.notes.empty()) js["notes"] = s.notes;
    j["stages"].push_back(js);
  }
  j["total_seconds"] = summary.total_seconds;
  j["warnings"] = json::array();
  for (const std::string& w : summary.warnings) j["warnings"].push_back(json_text(w));
  if (summary.cross_check) {
    const CrossCheck& c = *summary.cross_check;
    j["cross_check"] = {{"point_vertical", stats_json(c.point_vertical)},
                        {"point_normal", stats_json(c.point_normal)},
                        {"cell_to_point", stats_json(c.cell_to_point)},
                        {"points_on_surface", c.points_on_surface},
                        {"points_off_surface", c.points_off_surface},
                        {"points_hidden", c.points_hidden},
                        {"hidden_band_m", c.hidden_band_m},
                        {"supported_fraction", c.supported_fraction},
                        {"tolerance_m", c.tolerance_m}};
    if (summary.naive_cross_check) {
      const CrossCheck& n = *summary.naive_cross_check;
      j["cross_check_naive"] = {{"point_vertical", stats_json(n.point_vertical)},
                                {"cell_to_point", stats_json(n.cell_to_point)},
                                {"supported_fraction", n.supported_fraction}};
    }
  }
  if (summary.verdict) {
    json reasons = json::array();
    for (const VerdictReason& r : summary.verdict->reasons) {
      reasons.push_back({{"code", r.code}, {"level", r.level}, {"message", r.message}});
    }
    j["verdict"] = {{"status", summary.verdict->status}, {"reasons", reasons}};
  }
  if (summary.input_check) {
    const InputCheck& in = *summary.input_check;
    j["input_check"] = {{"points", in.points}, {"on_surface", in.on_surface}, {"removed", in.removed},
                        {"hidden", in.hidden}, {"no_data", in.no_data}, {"off_surface", in.off_surface},
                        {"outside", in.outside}, {"far", in.far}, {"far_max_distance_m", in.far_max_distance_m},
                        {"removal_exact", in.removal_exact}, {"spacing_m", in.spacing_m},
                        {"isolation_radius_m", in.isolation_radius_m}, {"isolated", in.isolated},
                        {"surface_lost", in.surface_lost}, {"surface_lost_fraction", in.fraction(in.surface_lost)},
                        {"surface_lost_max_gap_m", in.surface_lost_max_gap_m}, {"removed_in_front", in.removed_in_front},
                        {"spikes_kept", in.spikes_kept}};
  }
  if (summary.grid_spikes) {
    const GridSpikes& sp = *summary.grid_spikes;
    json worst = json::array();
    for (const GridAnomaly& a : sp.worst) {
      worst.push_back({{"row", a.row}, {"col", a.col}, {"height_m", a.height_m}, {"deviation_m", a.deviation_m}});
    }
    j["grid_spikes"] = {{"spikes", sp.spikes}, {"pits", sp.pits}, {"confirmed", sp.confirmed}, {"tested", sp.tested}, {"islands", sp.islands},
                        {"island_cells", sp.island_cells}, {"worst", worst}};
  }
  if (scene.friction_model) j["friction_model"] = friction_name;
  if (!lod_rows.empty()) {
    j["levels"] = json::array();
    for (const LevelRow& r : lod_rows) {
      json jr = {{"level", r.level}, {"rows", r.rows}, {"cols", r.cols}, {"cell_size_m", r.cell_size_m},
                 {"valid_cells", r.valid_cells}, {"build_seconds", r.build_seconds}};
      if (r.timed) {
        jr["tick_p50_ns"] = r.tick_p50_ns;
        jr["tick_p99_ns"] = r.tick_p99_ns;
        jr["switch_ms"] = r.switch_ms;
      }
      if (r.point_vertical) {
        jr["point_vertical"] = stats_json(*r.point_vertical);
        jr["points_checked"] = r.points_checked;
        jr["points_total"] = r.points_total;
        jr["sampled"] = r.points_checked < r.points_total;
        if (r.support_measured) jr["supported_fraction"] = r.supported_fraction;
      }
      if (r.mu_d) {
        jr["mu_d"] = {{"valid", r.mu_d->valid}, {"at_min", r.mu_d->at_min}, {"at_max", r.mu_d->at_max},
                      {"bins", r.mu_d->bins}, {"mu_min", config.layers.options.mu_min},
                      {"mu_max", config.layers.options.mu_max}};
      }
      j["levels"].push_back(jr);
    }
  }
  // Bytes that are not UTF-8 (file names are bytes on POSIX) are written as U+FFFD, never a throw.
  write_text(staging.path() / "report.json", j.dump(2, ' ', false, json::error_handler_t::replace) + "\n");

  std::ostringstream md;
  md << "# hapticloud run report: " << config.name << "\n\n";
  md << "Config: `" << config.source.string() << "`. Tool: hapticloud " << HC_VERSION << ".\n\n";
  if (!summary.warnings.empty()) {
    md << "## Warnings\n\n";
    for (const std::string& w : summary.warnings) md << "- **warning:** " << w << "\n";
    md << "\n";
  }
  if (summary.verdict) md << verdict_markdown(summary) << "\n";
  md << "## Input\n\n";
  if (config.input.synthetic) md << "- synthetic surface: " << to_string(config.input.synthetic->kind) << "\n";
  for (const SceneInput& in : prov.inputs) md << "- `" << in.file << "` (sha256 " << in.sha256.substr(0, 16) << "…)\n";
  if (!prov.crs.empty()) md << "- CRS: `" << prov.crs << "`\n";
  md << "\n## Grid\n\n";
  md << "| rows | cols | cell size (mm) | valid cells | filled | see-through (removed) |\n|---|---|---|---|---|---|\n";
  md << "| " << g.rows << " | " << g.cols << " | " << fmt(g.cell_size_m * 1000.0, 4) << " | " << summary.valid_cells
     << " | " << n_filled << " | " << n_see_through << " |\n\n";
  md << "## Stages (speed)\n\n| stage | points/cells in | out | time (ms) | figures |\n|---|---|---|---|---|\n";
  for (const auto& s : reports) {
    md << "| " << s.stage << " | " << s.count_in << " | " << s.count_out << " | " << fmt(s.seconds * 1000.0, 1) << " | ";
    for (const auto& [k, v] : s.figures) md << k << " = " << std::setprecision(5) << std::defaultfloat << v << "; ";
    for (const auto& note : s.notes) md << note << "; ";
    md << " |\n";
  }
  md << "| **total (file to written scene and previews)** | | | **" << fmt(summary.total_seconds * 1000.0, 1) << "** | |\n\n";
  {
    const StageReport* peak = nullptr;
    for (const auto& s : reports)
      if (s.peak_rss_bytes > 0 && (!peak || s.peak_rss_bytes > peak->peak_rss_bytes)) peak = &s;
    if (peak) {
      md << "Peak resident memory: " << fmt(static_cast<double>(peak->peak_rss_bytes) / 1e6, 0) << " MB, in stage "
         << peak->stage << " (per stage: `peak_rss_mb` in report.json).\n\n";
    }
  }
  if (summary.cross_check) {
    const CrossCheck& c = *summary.cross_check;
    md << "## Cross-check (accuracy)\n\n| measure | count | RMS (mm) | p50 | p95 | p99 | max |\n|---|---|---|---|---|---|---|\n";
    md << stats_row("(a) points vs bilinear surface, vertical", c.point_vertical);
    md << stats_row("(a) points vs bilinear surface, along normal", c.point_normal);
    md << stats_row("(b) grid samples vs nearest point", c.cell_to_point);
    if (summary.naive_cross_check) {
      const CrossCheck& n = *summary.naive_cross_check;
      md << stats_row("naive front-most grid: (a) vertical", n.point_vertical);
      md << stats_row("naive front-most grid: (b) samples vs points", n.cell_to_point);
    }
    md << "\n(a) uses the input points that lie on the visible surface: " << c.points_on_surface
       << " points; " << c.points_hidden << " lie more than " << fmt(c.hidden_band_m * 1000.0, 1)
       << " mm behind it (hidden: the back and undercuts of the object, not part of a Monge surface) and "
       << c.points_off_surface << " fall on no-data cells. (b) Cells supported by a point within "
       << fmt(c.tolerance_m * 1000.0, 3) << " mm: " << fmt(100.0 * c.supported_fraction, 2) << " %.\n\n";
    if (summary.grid_spikes && !summary.grid_spikes->worst.empty()) {
      md << "Spikes and pits of the grid (largest first; deviation from the median of the cell's window):\n\n"
            "| row | col | height (mm) | deviation (mm) |\n|---|---|---|---|\n";
      for (const GridAnomaly& a : summary.grid_spikes->worst) {
        md << "| " << a.row << " | " << a.col << " | " << format_number(a.height_m * 1e3, 4) << " | "
           << format_number(a.deviation_m * 1e3, 4) << " |\n";
      }
      md << "\n";
    }
    md << "## Speed against error\n\n| N (long side) | cell (mm) | total time (ms) | RMS (mm) | p95 (mm) |\n|---|---|---|---|---|\n";
    md << "| " << std::max(g.rows, g.cols) << " | " << fmt(g.cell_size_m * 1000.0, 4) << " | "
       << fmt(summary.total_seconds * 1000.0, 1) << " | " << fmt(c.point_vertical.rms_mm) << " | "
       << fmt(c.point_vertical.p95_mm) << " |\n\n";
    md << "(Benchmarks over N = 200…1600: `build/release/bench/pipeline_bench`.)\n\n";
  }
  if (scene.friction_model) {
    md << "## Surface layers\n\nFriction model: **" << friction_name
       << "** (see docs/friction.md for paper vs curvature).\n\n";
  }
  if (!lod_rows.empty()) {
    md << "## Levels of detail\n\nEach level halves the resolution of the one before after an anti-aliasing "
          "Gaussian (σ = " << config.lod.antialias_sigma_cells << " fine samples, no data handled by normalised "
          "convolution; docs/lod.md); texture and friction are computed per level. Build = smoothing, decimation "
          "and layers; RMS and p95 = cross-check (a) of the input points against the level's bilinear surface; "
          "tick = servo tick compute (median, 99th percentile) on a " << config.lod.window_cells << "-sample window of the level; switch = "
          "request to the first servo tick on the new window (level cached).\n\n"
       << level_table_markdown(lod_rows) << "\n";
    for (std::size_t i = 0; i + 1 < lod_previews.size(); ++i) md << "![level " << i << "](previews/" << lod_previews[i] << ")";
    md << "\n\n![all levels side by side](previews/" << lod_previews.back() << ")\n\n";
  }
  md << "## Previews\n\n![depth](previews/depth.png)\n![hillshade](previews/hillshade.png)\n";
  // Linked only when drawn: a tiled scene's capped preview needs the stored level's error layer.
  if (summary.cross_check && fs::exists(staging.path() / "previews" / "cross_check_error.png")) {
    md << "![cross-check error](previews/cross_check_error.png)\n";
  }
  if (has_surface_layers) md << "![texture](previews/texture.png)\n![mu_d](previews/mu_d.png)\n![mu_s](previews/mu_s.png)\n";
  if (has_colour) {
    md << "![colour (front-most point per cell)](previews/colour.png)\n![colour over hillshade](previews/colour_hillshade.png)\n";
  }
  if (has_intensity) md << "![intensity](previews/intensity.png)\n";
  write_text(staging.path() / "report.md", md.str());

  staging.commit();
  summary.out_dir = out_dir;
  summary.moved_aside = staging.moved_aside();
  return summary;
}
}  // namespace

RunSummary write_run(const BuiltScene& built, const RunConfig& config, const fs::path& out_dir,
                     const ProgressFn& progress, ExistingOutput existing, const LevelTimingFn& level_timing) {
  return write_run_impl(built, nullptr, config, out_dir, progress, existing, level_timing);
}

RunSummary write_run(BuiltScene&& built, const RunConfig& config, const fs::path& out_dir, const ProgressFn& progress,
                     ExistingOutput existing, const LevelTimingFn& level_timing) {
  return write_run_impl(built, &built, config, out_dir, progress, existing, level_timing);
}

RunSummary run_pipeline(const RunConfig& config, const fs::path& out_dir, const ProgressFn& progress,
                        ExistingOutput existing, const LevelTimingFn& level_timing) {
  check_output_target(out_dir, existing);  // refuse before hours of work, not after
  // The levels table's cross-check wants the points; a tiled run keeps a sample of them instead
  // (BuiltScene::point_sample), so that is no reason to stay in core.
  const bool keep_cloud = config.lod.report && config.lod.report_cross_check && !runs_tiled(config);
  // A tiled run leaves level 0's surface layers to stage scene_levels when it writes a tiled
  // scene (SurfaceLayersAt): build_scene, with that request.
  BuiltScene built = takes_tiled_run(config, keep_cloud)
                         ? build_scene_tiled(config, progress, SurfaceLayersAt::kSceneLevels)
                         : build_scene(config, keep_cloud, progress);
  return write_run(std::move(built), config, out_dir, progress, existing, level_timing);
}

}  // namespace hc::pipeline

namespace hc::pipeline::detail {

HonestCheckOptions honest_options_for(const RunConfig& config, bool rasterised, double upsample_factor, double cell_m) {
  HonestCheckOptions o = config.cross_check.honest;
  if (o.confirm_by_splat_footprint && !rasterised && config.grid.reproject.splat_mode == SplatMode::kDisc) {
    // A splatted cell holds the front-most z of a measured cell within the disc, whose point
    // lies up to half a cell diagonal from that cell's node; radii count the scan's cells, K
    // times the grid's when the grid is upsampled.
    o.confirm_footprint_m = (config.grid.reproject.splat_radius_cells + 0.5 * std::sqrt(2.0)) * upsample_factor * cell_m;
  }
  return o;
}

void add_honest_figures(const InputCheck& in, const GridSpikes& sp, StageReport& report) {
  report.count_in = in.points;
  report.count_out = in.on_surface;
  report.figure("input_points", static_cast<double>(in.points));
  report.figure("input_on_surface_fraction", in.fraction(in.on_surface));
  report.figure("input_removed_fraction", in.fraction(in.removed));
  report.figure("input_hidden_fraction", in.fraction(in.hidden));
  report.figure("input_no_data_fraction", in.fraction(in.no_data));
  report.figure("input_off_surface_fraction", in.fraction(in.off_surface));
  report.figure("input_outside_fraction", in.fraction(in.outside));
  report.figure("input_far", static_cast<double>(in.far));
  report.figure("input_spacing_mm", in.spacing_m * 1e3);
  report.figure("isolated", static_cast<double>(in.isolated));
  report.figure("surface_lost", static_cast<double>(in.surface_lost));
  report.figure("surface_lost_max_gap_mm", in.surface_lost_max_gap_m * 1e3);
  report.figure("removed_in_front", static_cast<double>(in.removed_in_front));
  report.figure("spikes_kept", static_cast<double>(in.spikes_kept));
  report.figure("grid_spikes", static_cast<double>(sp.spikes));
  report.figure("grid_pits", static_cast<double>(sp.pits));
  report.figure("grid_spikes_pits_confirmed", static_cast<double>(sp.confirmed));
  report.figure("island_cells", static_cast<double>(sp.island_cells));
  if (!in.removal_exact) {
    report.notes.push_back("voxel filter on: a point counts as removed when no kept centroid lies within one voxel diagonal");
  }
}

}  // namespace hc::pipeline::detail
