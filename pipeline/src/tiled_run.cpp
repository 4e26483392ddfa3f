// The streaming tiled run (tiling.hpp, issue 14): plan, spill, per-tile gridding, the whole
// grid's layers, and the cross-check merged over tiles.

#include "hc/pipeline/tiling.hpp"
#include "hc/pipeline/lod_report.hpp"

#include "ball_set.hpp"
#include "far_cells.hpp"
#include "posix_io.hpp"
#include "voxel_keys.hpp"
#include "wanted_keys.hpp"
#include "knn_grid.hpp"
#include "near_knn.hpp"
#include "readers/byte_source.hpp"
#include "readers/las_records.hpp"
#include "readers/readers.hpp"
#include "readers/text_parse.hpp"
#include "run_internal.hpp"
#include "stage_util.hpp"

#include "hc/common/bilinear_surface.hpp"
#include "hc/common/error.hpp"
#include "hc/common/format.hpp"
#include "hc/common/units.hpp"
#include "hc/pipeline/cross_check.hpp"
#include "hc/pipeline/filters.hpp"
#include "hc/pipeline/honest_check.hpp"
#include "hc/pipeline/point_stream.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/robust_outliers.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/pipeline/transform.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <chrono>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <functional>
#include <filesystem>
#include <limits>
#include <list>
#include <memory>
#include <numeric>
#include <map>
#include <unordered_map>
#include <unordered_set>
#include <set>
#include <optional>
#include <random>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>
#include <yaml-cpp/yaml.h>
#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

namespace hc::pipeline {
namespace {

namespace fs = std::filesystem;
using detail::FarCells;
using detail::stage;

// ---------------------------------------------------------------------------------------------
// Which configs the tiled run takes.

void check_supported(const RunConfig& c) {
  if (const std::string why = tiled_run_refusal(c); !why.empty()) {
    throw ConfigError("scale.tiled: on, but " + why + " (the tiled run does not support it yet: docs/scale.md; set scale.tiled: off)");
  }
}

// ---------------------------------------------------------------------------------------------
// The spill folder and files.

// A fresh folder under `parent`, removed with its content when this goes out of scope.
class ScratchDir {
 public:
  explicit ScratchDir(const fs::path& parent) {
    std::error_code ec;
    const fs::path base = parent.empty() ? fs::temp_directory_path(ec) : parent;
    if (ec || !fs::is_directory(base, ec)) {
      throw InputError("scale.scratch: " + base.string() + " is not a folder that exists (expected one for the spill files)");
    }
    std::string templ = (base / "hapticloud-tiles-XXXXXX").string();
    if (!::mkdtemp(templ.data())) {
      throw InputError("scale.scratch: cannot create a folder in " + base.string() + ": " + std::strerror(errno));
    }
    dir_ = templ;
    // SIGINT/SIGTERM during the run (hapticloud's signal watcher) removes it too.
    try {
      register_live_scratch_dir(dir_);
    } catch (...) {
      fs::remove(dir_, ec);
      throw;
    }
  }
  ~ScratchDir() {
    unregister_live_scratch_dir(dir_);
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;
  const fs::path& path() const { return dir_; }

 private:
  fs::path dir_;
};

// A spilled point's x y z kept as the input file's own float32 coordinates (the reader stores
// float32 x y z: FileBox::float32), 12 bytes instead of the grid frame's 24. Reading takes them
// to the grid frame with to_grid_frame's arithmetic, operation for operation: x − centre, then
// × unit_m when that is not 1 (to_metres_and_recentre), then, when the view is not the identity
// (ViewTransform::is_identity), the view's linear part L and translation t as apply_view_transform's
// Eigen product sums them (Eigen 3.4, SSE2: rows 0 and 1 as one packet, (p0 + p1) + p2; row 2
// alone, p0 + (p1 + p2); pk = L(i, k)·s_k), then + t. So a record reads back the doubles the
// in-core stages compute. Spill::add checks that for every point it writes (Layout::put), and
// the spill pass runs again in doubles when one fails (another Eigen, another summing).
struct FileFloats {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();       // [file units] what to_grid_frame subtracts
  double unit_m = 1.0;                                     // [m per file unit] (input.units)
  bool turned = false;                                     // the view is not the identity
  Eigen::Matrix3d linear = Eigen::Matrix3d::Identity();    // the view's matrix().linear() (scale · R)
  Eigen::Vector3d translation_m = Eigen::Vector3d::Zero();  // the view's translation [m]
  Eigen::Matrix3d inverse = Eigen::Matrix3d::Identity();   // linear's inverse (to_file's estimate only)

  // The frame of a run: the box centre [file units], input.units [m per unit] and the view.
  static FileFloats of(const Eigen::Vector3d& centre, double unit_m, const ViewTransform& view) {
    FileFloats f;
    f.centre = centre;
    f.unit_m = unit_m;
    f.turned = !view.is_identity();
    if (f.turned) {
      const Eigen::Affine3d m = view.matrix();
      f.linear = m.linear();
      f.translation_m = m.translation();
      f.inverse = f.linear.inverse();
    }
    return f;
  }

  // The file's x y z [3] to the grid frame [m] g [3].
  // The coordinates are kept in registers and written to g one by one: staged in an array and
  // copied, the copy's 16-byte load of two 8-byte stores missed the store forwarding, a quarter
  // of the spill gathering's time on the 10^8 wall (2026-12-02).
  void to_grid(const float* f, double* g) const {
    double x = static_cast<double>(f[0]) - centre[0], y = static_cast<double>(f[1]) - centre[1],
           z = static_cast<double>(f[2]) - centre[2];
    if (unit_m != 1.0) {
      x *= unit_m;
      y *= unit_m;
      z *= unit_m;
    }
    if (!turned) {
      g[0] = x;
      g[1] = y;
      g[2] = z;
      return;
    }
    const double s[3] = {x, y, z};
    double p[3][3];
    for (int i = 0; i < 3; ++i) {
      for (int k = 0; k < 3; ++k) p[i][k] = linear(i, k) * s[k];
    }
    g[0] = (p[0][0] + p[0][1]) + p[0][2] + translation_m[0];
    g[1] = (p[1][0] + p[1][1]) + p[1][2] + translation_m[1];
    g[2] = p[2][0] + (p[2][1] + p[2][2]) + translation_m[2];
  }

  // The float x y z [3] whose to_grid is nearest g [3] [m]: g taken back through the inverse
  // and rounded; the caller checks that to_grid gives g back (Layout::put).
  void to_file(const double* g, float* f) const {
    double s[3] = {g[0], g[1], g[2]};
    if (turned) {
      const Eigen::Vector3d v = inverse * (Eigen::Vector3d(g[0], g[1], g[2]) - translation_m);
      std::copy_n(v.data(), 3, s);
    }
    for (int a = 0; a < 3; ++a) {
      if (unit_m != 1.0) s[a] /= unit_m;
      f[a] = static_cast<float>(s[a] + centre[a]);
    }
  }
};

// What a spilled point carries.
struct Layout {
  bool rgb = false, intensity = false;
  std::optional<FileFloats> floats;  // x y z as the file's floats; none: as the grid frame's doubles
  // x y z's bytes: 3 floats or 3 doubles.
  std::size_t xyz_bytes() const { return floats ? 12 : 24; }
  // A point's bytes: x y z, [r g b], [intensity float].
  std::size_t point_bytes() const { return xyz_bytes() + (rgb ? 3 : 0) + (intensity ? 4 : 0); }
  // A spill record's: a flag byte, then the point's.
  std::size_t bytes() const { return 1 + point_bytes(); }
  // Writes a point's bytes at q (x y z in the grid frame [m]; rgb3 read only with rgb). Returns
  // whether they read back as p (always in doubles; in floats, when p came from the file's
  // floats through to_grid_frame).
  bool put(char* q, const double* p, const std::uint8_t* rgb3, float v) const {
    bool exact = true;
    if (floats) {
      float f[3];
      double back[3];
      floats->to_file(p, f);
      // The floats from memory, as a reader gets them: GCC 12.2's SLP vectorizer at -O3 drops
      // the rounding to float of two lanes of such a double -> float -> double round trip
      // (bench/README, seventeenth session: a 20-line program shows it), and the check would
      // then compare p with itself or, as here, fail for a point that reads back exactly.
      asm volatile("" : : "r"(f) : "memory");
      floats->to_grid(f, back);
      exact = std::memcmp(back, p, 24) == 0;
      std::memcpy(q, f, 12);
    } else {
      std::memcpy(q, p, 24);
    }
    const std::size_t xb = xyz_bytes();
    if (rgb) std::memcpy(q + xb, rgb3, 3);
    if (intensity) std::memcpy(q + xb + (rgb ? 3 : 0), &v, 4);
    return exact;
  }
  // Reads a point's x y z at q into p [3] (the grid frame [m]).
  void xyz(const char* q, double* p) const {
    if (floats) {
      float f[3];
      std::memcpy(f, q, 12);
      floats->to_grid(f, p);
    } else {
      std::memcpy(p, q, 24);
    }
  }
  // Reads a point's bytes at q: x y z into p, the intensity into v (untouched without it);
  // returns the r g b bytes' address, nullptr without colour.
  const std::uint8_t* get(const char* q, double* p, float& v) const {
    xyz(q, p);
    const std::size_t xb = xyz_bytes();
    if (intensity) std::memcpy(&v, q + xb + (rgb ? 3 : 0), 4);
    return rgb ? reinterpret_cast<const std::uint8_t*>(q + xb) : nullptr;
  }
};

// A Cloud of the n points `each` emits, in its order, with colour and intensity where rgb and
// intensity say so: each(emit) calls emit(flag, x y z [3], r g b [3] or nullptr, intensity)
// once a point, and flag[i] = the i-th's flag (Spill::read_taken, KeptMask::select).
// @throws std::logic_error when `each` emits another number of points than n (a caller's bug).
template <class Each>
Cloud cloud_of_records(std::size_t n, bool rgb, bool intensity, std::vector<std::uint8_t>& flag, Each&& each) {
  Cloud c;
  flag.assign(n, 0);
  if (n > 0) {
    c.xyz.resize(3, static_cast<Eigen::Index>(n));
    if (rgb) c.rgb.resize(3 * n);
    if (intensity) c.intensity.resize(n);
  }
  std::size_t i = 0;
  each([&](std::uint8_t f, const double* p, const std::uint8_t* c3, float v) {
    if (i == n) throw std::logic_error("cloud_of_records: more points than " + std::to_string(n));
    flag[i] = f;
    std::memcpy(c.xyz.data() + 3 * i, p, 24);
    if (rgb) std::memcpy(c.rgb.data() + 3 * i, c3, 3);
    if (intensity) c.intensity[i] = v;
    ++i;
  });
  if (i != n) throw std::logic_error("cloud_of_records: " + std::to_string(i) + " points, not " + std::to_string(n));
  return c;
}

// Spill files, one per tile, appended through per-tile buffers (records of Layout::bytes():
// a flag byte, x y z (the file's floats or the grid frame's doubles), [r g b], [intensity float]). Points keep the input's order within
// a file. Spill record flag bits: the robust test's sampled points in their own tile, and the
// points of removed far clusters.
constexpr std::uint8_t kSampleFlag = 2;
// A point of a removed far cluster (tile_far_clusters): spilled for the honest check, which
// classifies every input point, but dropped before a tile's filters and gridding.
constexpr std::uint8_t kFarFlag = 4;

// A file per tile, dir/<prefix><t>.bin, and each one's size (Spill, KeptMask).
class TileFiles {
 public:
  TileFiles(fs::path dir, std::string prefix, std::size_t tiles) : dir_(std::move(dir)), prefix_(std::move(prefix)), bytes_(tiles, 0) {}
  fs::path file(std::size_t t) const { return dir_ / (prefix_ + std::to_string(t) + ".bin"); }
  const fs::path& dir() const { return dir_; }

  // The files a plan or tile job wrote earlier (another process): each tile's size from disk
  // (0 when its file is missing).
  void adopt_existing() {
    for (std::size_t t = 0; t < bytes_.size(); ++t) {
      std::error_code ec;
      const auto n = fs::file_size(file(t), ec);
      bytes_[t] = ec ? 0 : n;
    }
  }
  // Tile t's file's size [bytes].
  std::uintmax_t bytes(std::size_t t) const { return bytes_[t]; }

 protected:
  // Writes (mode "wb") or appends ("ab") n bytes to tile t's file and adds them to its size.
  // @throws InputError naming the file and `what` it holds when the write fails (the disk full).
  void put(std::size_t t, const char* mode, const void* data, std::size_t n, const char* what) {
    // Under the clean-up's lock: a signal's clean-up never races with a file's creation.
    std::FILE* f = open_live_scratch_file(file(t), mode);
    const bool ok = f && std::fwrite(data, 1, n, f) == n;
    const bool closed = f && std::fclose(f) == 0;
    if (!ok || !closed) {
      throw InputError(std::string("scale.scratch: cannot write the ") + what + " " + file(t).string() + ": " + std::strerror(errno) +
                       " (is the disk full?)");
    }
    bytes_[t] += n;
  }

  fs::path dir_;
  std::string prefix_;
  std::vector<std::uintmax_t> bytes_;
};

class Spill : public TileFiles {
 public:
  Spill(fs::path dir, std::string prefix, std::size_t tiles, Layout layout)
      : TileFiles(std::move(dir), std::move(prefix), tiles), layout_(layout), buf_(tiles) {}
  using TileFiles::bytes;
  const Layout& layout() const { return layout_; }

  // Appends a record to tile t's file (through its buffer): the flag, x y z [3] (the grid frame
  // [m]), rgb [3] (read with colour only), intensity. @throws NotFloats when the layout holds the
  // file's floats and p does not read back from them bit for bit (nothing of the point is
  // buffered); InputError naming the file when a buffer's write fails (TileFiles::put).
  void add(std::size_t t, std::uint8_t flag, const double* p, const std::uint8_t* rgb, float intensity) {
    std::vector<char>& b = buf_[t];
    const std::size_t at = b.size();
    // A buffer's size at once (flush gives it back): growing it record by record took about 15
    // reallocations, each a copy (and, past glibc's mmap threshold, a fresh mapping). Many tiles
    // share kTotalBuffer instead (4 KiB each at least), so the reservations stay within it.
    if (b.capacity() == 0) b.reserve(std::clamp<std::size_t>(kTotalBuffer / buf_.size(), 4096, kTileBuffer) + layout_.bytes());
    b.resize(at + layout_.bytes());
    char* q = b.data() + at;
    q[0] = static_cast<char>(flag);
    if (!layout_.put(q + 1, p, rgb, intensity)) {
      b.resize(at);
      throw NotFloats{{p[0], p[1], p[2]}};
    }
    buffered_ += layout_.bytes();
    if (b.size() >= kTileBuffer) flush(t);
    if (buffered_ >= kTotalBuffer) flush_all();
  }

  void flush_all() {
    for (std::size_t t = 0; t < buf_.size(); ++t) flush(t);
  }

  void flush(std::size_t t) {
    std::vector<char>& b = buf_[t];
    if (b.empty()) return;
    put(t, "ab", b.data(), b.size(), "spill file");
    buffered_ -= b.size();
    std::vector<char>().swap(b);
  }

  std::uintmax_t bytes() const {
    std::uintmax_t s = 0;
    for (const auto b : bytes_) s += b;
    return s;
  }

  // What add() throws when the layout holds the file's floats and a point does not read back
  // from them bit for bit: its grid-frame x y z [m] (the spill pass then runs in doubles).
  struct NotFloats {
    std::array<double, 3> xyz_m;
  };

  // Re-marks tile t's records in place (flush first): each record's flag byte becomes
  // mark(point's x y z); the records and their order stay. Only the bytes that change are
  // written (a far point, a sample mark dropped), not the file. Used when a second spill would
  // write the same records in the same order with other flags (tile_far_clusters).
  template <class Mark>
  void remark(std::size_t t, Mark&& mark) const {
    const std::size_t rec = layout_.bytes();
    const std::size_t n = static_cast<std::size_t>(bytes_[t] / rec);
    if (n == 0) return;
    // Read in chunks (records_per_read), the buffer reused, as scan_records: the whole file in
    // one buffer (47 MB for a window of 3.6 M float records) was zeroed on allocation and, given
    // back between tiles, faulted in and zeroed again by the kernel for every tile.
    const std::size_t per = records_per_read();
    std::vector<char> raw(std::min(per, n) * rec);
    errno = 0;
    const int fd = ::open(file(t).c_str(), O_RDWR | O_CLOEXEC);
    bool ok = fd >= 0;
    double p[3];
    for (std::size_t done = 0; ok && done < n;) {
      const std::size_t m = std::min(per, n - done);
      ok = detail::pread_full(fd, raw.data(), m * rec, done * rec);
      for (std::size_t i = 0; ok && i < m; ++i) {
        const char* q = raw.data() + i * rec;
        layout_.xyz(q + 1, p);
        const char flag = static_cast<char>(mark(static_cast<const double*>(p)));
        if (flag != q[0]) ok = detail::pwrite_full(fd, &flag, 1, (done + i) * rec);
      }
      done += m;
    }
    const int err = errno;
    const bool closed = fd >= 0 && ::close(fd) == 0;
    if (!ok || !closed) {
      throw InputError("scale.scratch: cannot re-mark the " + std::to_string(bytes_[t]) + " bytes of the spill file " +
                       file(t).string() + (err != 0 ? std::string(": ") + std::strerror(err) : std::string()) + " (is the disk full?)");
    }
  }

  // Records in tile t's file (flush first).
  std::size_t records(std::size_t t) const { return static_cast<std::size_t>(bytes_[t] / layout_.bytes()); }

  // Reads tile t's points back (flush first): the points and their flags, in file order.
  Cloud read(std::size_t t, std::vector<std::uint8_t>& flag) const {
    return read_taken(t, records(t), [](std::size_t, std::uint8_t f) { return static_cast<int>(f); }, flag);
  }

  // Reads the n records of tile t for which take(record number, flag byte) is 0 or more (flush
  // first): the points, in file order, and flag[i] = take's value for the i-th.
  template <class Take>
  Cloud read_taken(std::size_t t, std::size_t n, Take&& take, std::vector<std::uint8_t>& flag) const {
    return cloud_of_records(n, layout_.rgb, layout_.intensity, flag, [&](auto&& emit) {
      if (n == 0) return;
      std::size_t rec = 0;
      scan(t, [&](std::uint8_t f, const double* p, const std::uint8_t* rgb, float v) {
        const int k = take(rec++, f);
        if (k >= 0) emit(static_cast<std::uint8_t>(k), p, rgb, v);
      });
    });
  }

  // Reads tile t's records back in chunks of about 4 MB (flush first), without holding the
  // file: fn(flag, x y z [3] (the grid frame [m]), rgb [3] or nullptr, intensity) for each, in
  // file order.
  template <class Fn>
  void scan(std::size_t t, Fn&& fn) const {
    double p[3];
    float intensity = 0.0f;
    scan_records(t, [&](const char* q) {
      const std::uint8_t* rgb = layout_.get(q + 1, p, intensity);
      fn(static_cast<std::uint8_t>(q[0]), static_cast<const double*>(p), rgb, intensity);
    });
  }

  // As scan, but fn(record) gets each record's bytes (Layout::bytes(): the flag, then the point's
  // as Layout::get reads them).
  template <class Fn>
  void scan_records(std::size_t t, Fn&& fn) const {
    const std::size_t rec = layout_.bytes();
    const std::size_t n = records(t);
    if (n == 0) return;
    const std::unique_ptr<std::FILE, int (*)(std::FILE*)> file_closed(std::fopen(file(t).c_str(), "rb"), &std::fclose);
    std::FILE* f = file_closed.get();
    if (!f) throw InputError("tiled run: cannot read the spill file " + file(t).string());
    const std::size_t per = records_per_read();
    std::vector<char> raw(std::min(per, n) * rec);
    for (std::size_t done = 0; done < n;) {
      const std::size_t m = std::min(per, n - done);
      if (std::fread(raw.data(), 1, m * rec, f) != m * rec) throw InputError("tiled run: cannot read the spill file " + file(t).string());
      for (std::size_t i = 0; i < m; ++i) fn(static_cast<const char*>(raw.data() + i * rec));
      done += m;
    }
  }

  void remove(std::size_t t) {
    std::error_code ec;
    fs::remove(file(t), ec);
  }

 private:
  // Records a read of a tile's file takes at once (scan_records, remark): about 4 MB of them.
  std::size_t records_per_read() const { return std::max<std::size_t>(1, (std::size_t{4} << 20) / layout_.bytes()); }

  static constexpr std::size_t kTileBuffer = 1u << 18;
  static constexpr std::size_t kTotalBuffer = 64u << 20;

  Layout layout_;
  std::vector<std::vector<char>> buf_;
  std::size_t buffered_ = 0;
};

// Which of a tile's spilled records the tile kept, one file per tile (kept_<t>.bin): a byte per
// record of its spill (tile_<t>.bin), in the spill's order: kNotKept (removed by a filter, or a
// removed far cluster's), kInterior (kept, its node in the tile's interior) or kHalo (kept, a
// halo copy: its own tile counts it), with kNear added to a point (kept or not) that the tile's
// filters found at least cross_check.honest.isolation_min_neighbours others within the
// isolated-point filter's radius of (every point kept past that filter; a robust candidate
// whose k nearest show it): the honest check then need not test it (InputCheckScope::near).
// A tile that kept no point has no file. The kept points are
// read back from the spill through it. (Until 2026-11-25 they were a second spill of their own,
// 25 or more bytes a point: at 10^8 points 2.6 GB written and read back, where the mask is
// 0.11 GB.) The spill must therefore stay until the last read.
class KeptMask : public TileFiles {
 public:
  static constexpr std::uint8_t kNotKept = 0, kInterior = 1, kHalo = 2, kNear = 4;

  // Files dir/<prefix><t>.bin over the records of `spill` (held by reference); a file's size
  // (bytes(t)) is its spill's records, or 0 when the tile kept nothing.
  KeptMask(fs::path dir, std::string prefix, const Spill& spill, std::size_t tiles)
      : TileFiles(std::move(dir), std::move(prefix), tiles), spill_(spill) {}

  // Writes tile t's mask (one entry per record of its spill); no file when it keeps nothing.
  // @throws InputError naming the file when it cannot be written (the disk full).
  void write(std::size_t t, const std::vector<std::uint8_t>& mask) {
    bytes_[t] = 0;
    if (kept(mask) == 0) return;
    put(t, "wb", mask.data(), mask.size(), "kept-point mask");
  }

  // Tile t's kept points, in spill order, read from its spill; flag[i] = 1 for the interior's,
  // 0 for halo copies. @throws InputError naming the file when the mask cannot be read or does
  // not hold one byte per spill record.
  Cloud read(std::size_t t, std::vector<std::uint8_t>& flag) const {
    const std::vector<std::uint8_t> mask = load(t);
    return spill_.read_taken(t, kept(mask), [&](std::size_t rec, std::uint8_t) { return flag_of(mask[rec]); }, flag);
  }

  // out[r] = 1 for tile t's spill records it did not keep, 0 for those it kept (interior and
  // halo alike); near[r] = 1 for those marked kNear; one entry per record. @throws as read().
  void removed(std::size_t t, std::vector<std::uint8_t>& out, std::vector<std::uint8_t>& near) const {
    const std::vector<std::uint8_t> mask = load(t);
    out.resize(mask.size());
    near.resize(mask.size());
    for (std::size_t r = 0; r < mask.size(); ++r) {
      out[r] = (mask[r] & kKeptBits) == kNotKept ? 1 : 0;
      near[r] = (mask[r] & kNear) != 0 ? 1 : 0;
    }
  }

 private:
  static constexpr std::uint8_t kKeptBits = 3;
  // The records a mask keeps (marked kNear or not).
  static std::size_t kept(const std::vector<std::uint8_t>& mask) {
    return static_cast<std::size_t>(
        std::count_if(mask.begin(), mask.end(), [](std::uint8_t m) { return (m & kKeptBits) != kNotKept; }));
  }
  // A mask entry as a kept point's flag (1 interior, 0 halo), or −1 when not kept.
  static int flag_of(std::uint8_t m) {
    m &= kKeptBits;
    return m == kNotKept ? -1 : m == kInterior ? 1 : 0;
  }

  // Tile t's mask: its file's bytes, or every record kNotKept when it has none.
  std::vector<std::uint8_t> load(std::size_t t) const {
    const std::size_t n = spill_.records(t);
    std::vector<std::uint8_t> mask(n, kNotKept);
    if (bytes_[t] == 0) return mask;
    if (bytes_[t] != n) {
      throw InputError("tiled run: the kept-point mask " + file(t).string() + " holds " + std::to_string(bytes_[t]) +
                       " bytes, expected one per record of " + spill_.file(t).string() + " (" + std::to_string(n) + ")");
    }
    errno = 0;
    std::FILE* f = std::fopen(file(t).c_str(), "rb");
    const bool ok = f && std::fread(mask.data(), 1, n, f) == n;
    if (f) std::fclose(f);
    if (!ok) {
      throw InputError("tiled run: cannot read the " + std::to_string(n) + " bytes of the kept-point mask " + file(t).string() +
                       (errno != 0 ? std::string(": ") + std::strerror(errno) : std::string()));
    }
    for (std::size_t i = 0; i < n; ++i) {
      if ((mask[i] & ~(kKeptBits | kNear)) != 0 || (mask[i] & kKeptBits) > kHalo) {
        throw InputError("tiled run: the kept-point mask " + file(t).string() + " holds the byte " + std::to_string(mask[i]) +
                         " at offset " + std::to_string(i) + " (expected 0, 1 or 2, plus 4 or not: run tile-job " + std::to_string(t) +
                         " again, or the run)");
      }
    }
    return mask;
  }

  const Spill& spill_;
};

// ---------------------------------------------------------------------------------------------
// The tiles.

// How far past a tile's window the robust test's second look may gather points (judge_strays), in
// tiles: the balls of a tile's strays past its window; a ball a later gathering adds, past the
// window of the tile that owns its centre.
constexpr int kMaxWidenedTiles = 2;

// What a tiled run holds a grid sample for [bytes]: level 0 whole from the tile loop's merge
// through the checks, the depth, the cross-check's error map and the flags (colour 3 and
// intensity 4 more), in files of the scratch folder under scale.level0_file, in memory without
// it (docs/scale.md, "Level 0 in a file"; the hole fill's marks, a bit a cell, in memory).
constexpr double kTiledBytesPerCell = 9.0;

// grid_geometry_for_box for the tiled plan: a grid of more than grid.max_cells cells is refused
// in the tiled run's words, with what it holds for the grid (kTiledBytesPerCell a cell, besides
// its windows), not the in-core reprojection's working memory that make_geometry's message
// gives. @throws hc::ResourceError naming the grid, the key and the bytes; what
// grid_geometry_for_box throws otherwise.
GridGeometry tiled_grid_geometry(double x_min, double x_max, double y_min, double y_max, std::size_t kept, const ReprojectOptions& ro) {
  ReprojectOptions uncapped = ro;
  uncapped.grid.max_cells = std::numeric_limits<std::size_t>::max();
  const GridGeometry g = grid_geometry_for_box(x_min, x_max, y_min, y_max, kept, uncapped);
  const double cells = static_cast<double>(g.rows) * static_cast<double>(g.cols);
  if (cells > static_cast<double>(ro.grid.max_cells)) {
    throw ResourceError("tiled run: a grid of " + std::to_string(g.cols) + " x " + std::to_string(g.rows) + " = " +
                        std::to_string(static_cast<std::uint64_t>(g.rows) * static_cast<std::uint64_t>(g.cols)) + " cells (cell size " + format_number(g.cell_size_m) + " m) exceeds grid.max_cells = " +
                        std::to_string(ro.grid.max_cells) + "; a tiled run holds level 0 of the grid whole, about " +
                        format_number(kTiledBytesPerCell) + " bytes a cell (" + format_number(std::round(cells * kTiledBytesPerCell / 1e6)) +
                        " MB here; 3 more with colour, 4 with intensity) in files of the scratch folder under scale.level0_file "
                        "(in memory without it), besides its windows: raise grid.max_cells or coarsen the grid");
  }
  return g;
}

// Whether the tiles' halo holds a filter share (scale.filter_halo_cells): when the outlier
// filter or the cross-check runs.
bool filter_halo_added(const RunConfig& config) { return config.filters.outliers.enabled || config.cross_check.enabled; }

// The cells a point's disc writes, which the despike takes as its candidates' reach
// (remove_spike_points' reach_cells): the splat radius, at least 1, times the upsample factor k.
double despike_reach_cells(const RunConfig& config, int k) { return std::max(1.0, config.grid.reproject.splat_radius_cells) * k; }

// The grid stages' reach R [nodes] with upsample factor k (reproject_reach_cells): the region
// about a tile's interior whose points' final verdicts (the despike's included) the interior's
// nodes read.
int grid_reach_cells(const RunConfig& config, int k) {
  ReprojectOptions ro = config.grid.reproject;
  ro.upsample_factor = k;
  return reproject_reach_cells(ro, k);
}

// The halo's grid share [nodes] with upsample factor k: how far about a tile's interior the
// points must have the whole scan's verdicts (the decided region, tile_bounds). Without the
// despike, the grid stages' reach R (reproject_reach_cells): the interior's nodes read the
// points that far. With it, 2R + D: a point within R of the interior changes the interior when
// the despike removes it; its despike test reads the window's grid within D = ⌈max(1, r)·K⌉ +
// ⌊spike_window_cells / 2⌋ of its node (a spike cell within the candidates' reach, and that
// cell's plane window; despike_grid_reach_cells); and a node of the window's grid is the whole
// grid's where every point within R of it is there with the whole scan's verdict. (Islands
// of the despike, connected groups of up to island_max_cells, can reach farther: see below.)
// Until 2026-11-28 (fifty-first session) the share was the old reach formula alone,
// K·(2⌈r⌉ + 3 + w) + K: 11 nodes for the shipped splats, where the despike needs 12.
//
// With scale.island_halo, 2R + ⌈reach⌉ + max(spike_window_cells / 2, island_max_cells): the
// despike reads the island labels of the cells within R + ⌈reach⌉ of the interior (the
// candidates of the points within R), and a group of up to island_max_cells cells holding such
// a cell lies, with its ring of no-data cells, within R + ⌈reach⌉ + island_max_cells of the
// interior, inside the region whose window cells are the whole grid's (the decided region less
// R). Without it, process_tile stops the run where such a group runs past that region
// (window_islands; 2026-11-29, fifty-third session).
int grid_share_cells(const RunConfig& config, int k) {
  const int reach = grid_reach_cells(config, k);
  const OutlierConfig& oc = config.filters.outliers;
  if (!(oc.enabled && oc.despike)) return reach;
  const HonestCheckOptions& h = config.cross_check.honest;
  const int d = despike_grid_reach_cells(h, despike_reach_cells(config, k));  // ⌈reach⌉ + spike_window_cells / 2
  return 2 * reach + (config.scale.island_halo == ScaleConfig::Tiled::kOn ? d - h.spike_window_cells / 2 + std::max(h.spike_window_cells / 2, h.island_max_cells) : d);
}

// A tile's halo [nodes] with upsample factor k, scale.filter_halo_cells = filter_cells and, with
// auto, the despike's and the isolated filter's search radii in cells (despike_cells,
// isolated_cells; 0 with a fixed value): the decided region (tile_bounds: the halo less
// filter_cells) is max(G, R + despike_cells) + isolated_cells, the filter share then holds the
// filters' searches about its points, rounded up to a multiple of k. G: the grid share
// (grid_share_cells). R + despike_cells: the despike's verdicts are needed only within R of the
// interior (grid_reach_cells; process_tile checks its searches there), and its count searches
// about those points see the isolated filter's verdicts out to despike_cells more.
// + isolated_cells: the isolated filter's verdicts in that region count the robust test's
// verdicts out to its radius, which the robust test then checks (its decided region is this
// one; judge_strays). With a fixed filter share (despike_cells = isolated_cells = 0) the
// halo is G + filter_cells, as before 2026-11-29 (fifty-second session), when one decided
// region of G and a filter share holding every filter's search (the despike's, 4 scan cells,
// was the widest: 6 cells at the shipped settings) made 18 nodes where this makes 15; the
// isolated filter's counts near the decided region's edge then saw unchecked robust verdicts.
int tile_halo(const RunConfig& config, int k, int filter_cells, int despike_cells, int isolated_cells) {
  int halo = grid_share_cells(config, k);
  const OutlierConfig& oc = config.filters.outliers;
  if (oc.enabled && oc.despike) halo = std::max(halo, grid_reach_cells(config, k) + despike_cells);
  halo += isolated_cells;
  if (filter_halo_added(config)) halo += filter_cells;
  return (halo + k - 1) / k * k;
}

// The least scale.filter_halo_cells in [0, 4096] a user could set (a fixed value: no auto
// shares, tile_halo) whose halo [nodes] `enough` accepts; -1 when none does. For the value an
// error advises.
template <class Enough>
int least_fixed_filter_cells(const RunConfig& config, int k, Enough&& enough) {
  for (int f = 0; f <= 4096; ++f) {
    if (enough(tile_halo(config, k, f, 0, 0))) return f;
  }
  return -1;
}

// The honest check's reach about a point [m] at the scan's spacing `spacing_m`: the point test's
// radius (cross_check.isolation_radius_spacings spacings) plus the spike searches' (the largest
// of the tolerance, the spike height and the confirmation footprint).
double honest_reach_m(const HonestCheckOptions& o, double spacing_m) {
  return o.isolation_radius_spacings * spacing_m + std::max({o.tolerance_m, o.spike_min_height_m, o.confirm_footprint_m});
}

// The halo's shares that scale.filter_halo_cells: auto chooses (tile_halo): `filter` [cells],
// -1 when no value up to 4096 is enough; despike and isolated, the despike's count search and
// the isolated filter's radius in cells (each with 1 % to spare, rounded up).
struct FilterShares {
  int filter = 0;
  int despike = 0;
  int isolated = 0;
};

// The least filter halo (scale.filter_halo_cells: auto) whose tiles hold the per-tile filters'
// and the honest check's searches at the scan's spacing `spacing_m` on a grid of `cell_m` cells
// with upsample factor k: the filter share (the band between a tile's decided region and its
// window's edge, which check_within_window tests) wider than the isolated filter's radius
// (isolated_filter_radius_m) with 1 % and one cell to spare, the despike's and the isolated
// filter's radii added to the decided region (tile_halo), and the whole halo (check_honest_halo)
// at least the honest check's reach (honest_reach_m) with 1 % and a cell to spare. Without the
// outlier filter and the cross-check no filter halo is added (tile_halo): all 0. Until
// 2026-11-29 (fifty-second session) the filter share held the despike's count search too (6
// cells for 4 at the shipped settings), and the decided region was the grid share alone.
FilterShares auto_filter_shares(const RunConfig& config, int k, double cell_m, double spacing_m) {
  FilterShares s;
  if (!filter_halo_added(config)) return s;
  const HonestCheckOptions o = detail::honest_options_for(config, false, static_cast<double>(k), cell_m);
  const OutlierConfig& oc = config.filters.outliers;
  const double iso_m = oc.enabled ? isolated_filter_radius_m(o, spacing_m) : 0.0;
  const auto cells = [cell_m](double m) { return static_cast<int>(std::min(std::ceil(1.01 * m / cell_m), 4096.0)); };
  s.isolated = cells(iso_m);
  s.despike = oc.enabled && oc.despike ? cells(despike_search_radius_m(cell_m, static_cast<double>(k), spacing_m)) : 0;
  const double honest_m = config.cross_check.enabled ? honest_reach_m(o, spacing_m) : 0.0;
  for (int f = 0; f <= 4096; ++f) {
    if (f * cell_m >= 1.01 * iso_m + cell_m && tile_halo(config, k, f, s.despike, s.isolated) * cell_m >= 1.01 * honest_m + cell_m) {
      s.filter = f;
      return s;
    }
  }
  s.filter = -1;
  return s;
}

// The error when auto_filter_shares finds no value: naming the stage, the key and the
// spacing it took (`what`: "estimated", "the robust sample's").
ConfigError no_filter_halo_error(const std::string& stage, const std::string& what, double spacing_m, double cell_m) {
  return ConfigError("tiled run, stage " + stage + ": scale.filter_halo_cells auto: no halo up to 4096 cells holds the filters' "
                     "and the honest check's searches at the scan's spacing " + format_number(spacing_m * 1e3) + " mm (" + what +
                     "; the grid's cells: " + format_number(cell_m * 1e3) +
                     " mm): use a coarser grid (grid.n), grid.upsample, or a smaller cross_check.isolation_radius_spacings");
}

struct Tiles {
  GridGeometry g;
  int k = 1;        // upsample factor
  int size = 512;   // tile side [nodes], a multiple of k
  int halo = 0;     // [nodes], a multiple of k: tile_halo(config, k, filter, despike, isolated)
  int filter = 0;   // the filters' share of it [cells]: scale.filter_halo_cells, or the value auto chose
  // With scale.filter_halo_cells auto, the despike's count search and the isolated filter's
  // radius [cells] that the decided region holds besides the grid share (FilterShares); 0 with
  // a fixed value.
  int despike = 0, isolated = 0;
  int tiles_r = 0, tiles_c = 0;

  std::size_t count() const { return static_cast<std::size_t>(tiles_r) * static_cast<std::size_t>(tiles_c); }
  // Tiles of `side` nodes over g: size, and the rows and columns of tiles that cover it.
  void cut(int side) {
    size = side;
    tiles_r = (g.rows + size - 1) / size;
    tiles_c = (g.cols + size - 1) / size;
  }
  // The tile's interior: rows [r0, r1), cols [c0, c1).
  std::array<int, 4> interior(std::size_t t) const {
    const int tr = static_cast<int>(t / static_cast<std::size_t>(tiles_c)), tc = static_cast<int>(t % static_cast<std::size_t>(tiles_c));
    return {tr * size, std::min(g.rows, (tr + 1) * size), tc * size, std::min(g.cols, (tc + 1) * size)};
  }
  // The grid geometry of rows [r0, r0 + rows) and cols [c0, c0 + cols) of the whole grid.
  GridGeometry part(int r0, int c0, int rows, int cols) const {
    GridGeometry p = g;
    p.rows = rows;
    p.cols = cols;
    p.x0_m = g.x_of_col(c0);
    p.y0_m = g.y_of_row(r0);
    return p;
  }
  // The xy box [m] {x_min, x_max, y_min, y_max} of the points NodeBinner puts on nodes rows
  // [r0, r1), cols [c0, c1) (each node's cell reaches half a cell either side); a side at the
  // grid's edge, or beyond it, is at ±infinity (the binner clamps points beyond it to the edge).
  std::array<double, 4> box_m(int r0, int r1, int c0, int c1) const {
    const double inf = std::numeric_limits<double>::infinity();
    return {c0 <= 0 ? -inf : g.x_of_col(c0 - 0.5), c1 >= g.cols ? inf : g.x_of_col(c1 - 0.5),
            r0 <= 0 ? -inf : g.y_of_row(r0 - 0.5), r1 >= g.rows ? inf : g.y_of_row(r1 - 0.5)};
  }
  // The same box for a window's nodes.
  std::array<double, 4> box_m(const GridWindow& w) const { return box_m(w.row0, w.row0 + w.rows, w.col0, w.col0 + w.cols); }
  // box_m with each finite side a millionth of a cell wider: the box of nodes whose points a
  // reader must not miss. NodeBinner rounds p·(1/cell) + c where box_m rounds x0 + (c − ½)·cell,
  // so a point may lie one rounding step outside its nodes' box_m.
  std::array<double, 4> reading_box_m(int r0, int r1, int c0, int c1) const {
    const auto b = box_m(r0, r1, c0, c1);
    const double slack = 1e-6 * g.cell_size_m;
    return {b[0] - slack, b[1] + slack, b[2] - slack, b[3] + slack};
  }
  // The tile's window: its interior and halo, clipped to the grid.
  GridWindow window(std::size_t t) const {
    const auto [r0, r1, c0, c1] = interior(t);
    GridWindow w;
    w.grid = g;
    w.row0 = std::max(0, r0 - halo);
    w.col0 = std::max(0, c0 - halo);
    w.rows = std::min(g.rows, r1 + halo) - w.row0;
    w.cols = std::min(g.cols, c1 + halo) - w.col0;
    return w;
  }
};

// scale.filter_halo_cells as the errors name it: the value, or "auto, which chose" the tiles'.
std::string filter_halo_now(const RunConfig& config, const Tiles& tiles) {
  return config.scale.filter_halo_cells == ScaleConfig::kAutoFilterHalo ? "auto, which chose " + std::to_string(tiles.filter)
                                                                        : std::to_string(config.scale.filter_halo_cells);
}

int floor_div(int a, int b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

// The tiles whose window holds grid node (r, c): rows of tiles [tr0, tr1], columns [tc0, tc1].
std::array<int, 4> tiles_of(const Tiles& t, int r, int c) {
  return {std::max(0, floor_div(r - t.halo, t.size)), std::min(t.tiles_r - 1, floor_div(r + t.halo, t.size)),
          std::max(0, floor_div(c - t.halo, t.size)), std::min(t.tiles_c - 1, floor_div(c + t.halo, t.size))};
}

// A tiled run leaves grid.upsample auto's factor to the spill when the scan has at least this
// many points per grid node on average (plan_passes, spill_may_decide).
constexpr double kSpillDecidesPointsPerNode = 4.0;

// A point's grid node as reproject bins it (nearest node, clamped to the grid): what decides
// the tiles a point is spilled to, and which of them owns it.
struct NodeBinner {
  explicit NodeBinner(const GridGeometry& g)
      : inv(1.0 / g.cell_size_m), cx(0.5 - g.x0_m * inv), cy(0.5 - g.y0_m * inv), rows(g.rows), cols(g.cols) {}
  int row(const double* p) const { return std::clamp(static_cast<int>(p[1] * inv + cy), 0, rows - 1); }
  int col(const double* p) const { return std::clamp(static_cast<int>(p[0] * inv + cx), 0, cols - 1); }
  // Whether p's node lies in `in` = Tiles::interior(t): tile t owns the point.
  bool inside(const double* p, const std::array<int, 4>& in) const {
    const int r = row(p), c = col(p);
    return r >= in[0] && r < in[1] && c >= in[2] && c < in[3];
  }
  double inv, cx, cy;
  int rows, cols;
};

// Points per block of b × b grid nodes (NodeBinner's nodes; b chosen so that the table has at
// most 2048 blocks along a side), for the tile side (choose_tile_side): a window's points are at
// most the sum of the blocks it meets, from a summed-area table. The counts are 32-bit (16 MB
// at most, 8 MB for a 4 096 × 2 049 grid, which points in random order miss on nearly every
// count: add prefetches; 64-bit until 2026-11-28); the table turns 64-bit the first time a
// block would pass 2^32 − 1 points.
class BlockCounts {
 public:
  explicit BlockCounts(const GridGeometry& g)
      : node_(g), b_(std::max(1, (std::max(g.rows, g.cols) + 2047) / 2048)), br_((g.rows + b_ - 1) / b_), bc_((g.cols + b_ - 1) / b_),
        n_(static_cast<std::size_t>(br_) * static_cast<std::size_t>(bc_), 0) {}
  // Counts the n points at xyz (grid frame [m], 3·n doubles), each in the block of its node.
  // A point in random order misses the cache in the table (8 MB at 4 096 × 2 049): each point's
  // block is prefetched kAhead points before it is counted, so that the misses overlap instead of
  // stalling one by one (measured on the 10^8 wall's spill, 2026-11-28: the point-by-point loop
  // was a third of tile_spill's CPU time, nine tenths of it on the increment).
  void add(const double* xyz, std::size_t n) {
    constexpr std::size_t kAhead = 16;
    std::array<std::size_t, kAhead> ring{};
    const std::size_t lead = std::min(n, kAhead);
    for (std::size_t i = 0; i < lead; ++i) ring[i] = ahead(xyz + 3 * i);
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t b = ring[i % kAhead];
      if (i + kAhead < n) ring[i % kAhead] = ahead(xyz + 3 * (i + kAhead));
      bump(b);
    }
  }
  // After the last add: the summed-area table (at_most reads it).
  void finish() {
    sat_.assign(static_cast<std::size_t>(br_ + 1) * static_cast<std::size_t>(bc_ + 1), 0);
    const auto at = [&](int r, int c) -> std::uint64_t& { return sat_[static_cast<std::size_t>(r) * static_cast<std::size_t>(bc_ + 1) + static_cast<std::size_t>(c)]; };
    for (int r = 0; r < br_; ++r) {
      for (int c = 0; c < bc_; ++c) {
        const std::size_t i = static_cast<std::size_t>(r) * static_cast<std::size_t>(bc_) + static_cast<std::size_t>(c);
        at(r + 1, c + 1) = (wide_.empty() ? std::uint64_t{n_[i]} : wide_[i]) + at(r, c + 1) + at(r + 1, c) - at(r, c);
      }
    }
    std::vector<std::uint32_t>().swap(n_);
    std::vector<std::uint64_t>().swap(wide_);
  }
  // At least the points on nodes rows [r0, r1), cols [c0, c1) (the blocks that window meets).
  std::uint64_t at_most(int r0, int r1, int c0, int c1) const {
    const int R0 = r0 / b_, R1 = (r1 + b_ - 1) / b_, C0 = c0 / b_, C1 = (c1 + b_ - 1) / b_;
    const auto at = [&](int r, int c) { return sat_[static_cast<std::size_t>(r) * static_cast<std::size_t>(bc_ + 1) + static_cast<std::size_t>(c)]; };
    return at(R1, C1) - at(R0, C1) - at(R1, C0) + at(R0, C0);
  }

 private:
  std::size_t block_of(const double* p) const {
    return static_cast<std::size_t>(node_.row(p) / b_) * static_cast<std::size_t>(bc_) + static_cast<std::size_t>(node_.col(p) / b_);
  }
  // p's block, its counter prefetched for writing.
  std::size_t ahead(const double* p) const {
    const std::size_t i = block_of(p);
    if (wide_.empty()) __builtin_prefetch(n_.data() + i, 1);
    return i;
  }
  void bump(std::size_t i) {
    if (!wide_.empty()) {
      ++wide_[i];
    } else if (++n_[i] == 0) {  // the 2^32-th point of block i: the table turns 64-bit
      wide_.assign(n_.begin(), n_.end());
      wide_[i] = std::uint64_t{1} << 32;
      std::vector<std::uint32_t>().swap(n_);
    }
  }
  NodeBinner node_;
  int b_, br_, bc_;
  std::vector<std::uint32_t> n_;
  std::vector<std::uint64_t> wide_, sat_;
};

// The tile side for scale.tile_max_points (issue 14: a tile's memory bounded by its points, not
// by its cells alone): `configured` (scale.tile_cells, a multiple of k) when no window of tiles
// that size (the tile and `halo` nodes about it, clipped to the grid) holds more than
// `max_points` by `counts`; else the largest multiple of k found by bisection below it whose
// windows all do, but not below `floor_side` (a multiple of k), which is taken when none does.
// Returns {side, the most points a window of that side can hold by the counts}.
std::pair<int, std::uint64_t> choose_tile_side(const BlockCounts& counts, const GridGeometry& g, int configured, int k, int halo,
                                               int floor_side, std::uint64_t max_points) {
  const auto most = [&](int side) {
    std::uint64_t m = 0;
    for (int r = 0; r < g.rows; r += side) {
      for (int c = 0; c < g.cols; c += side) {
        m = std::max(m, counts.at_most(std::max(0, r - halo), std::min(g.rows, r + side + halo), std::max(0, c - halo),
                                       std::min(g.cols, c + side + halo)));
      }
    }
    return m;
  };
  const std::uint64_t at_configured = most(configured);
  if (at_configured <= max_points || configured <= floor_side) return {configured, at_configured};
  // Multiples of k: lo fits or is the floor, hi does not fit.
  int lo = floor_side / k, hi = configured / k;
  std::uint64_t at_lo = most(lo * k);
  if (at_lo > max_points) return {lo * k, at_lo};
  while (hi - lo > 1) {
    const int mid = lo + (hi - lo) / 2;
    const std::uint64_t m = most(mid * k);
    if (m <= max_points) {
      lo = mid;
      at_lo = m;
    } else {
      hi = mid;
    }
  }
  return {lo * k, at_lo};
}

// owned[i] = 1 when point i's grid node lies in tile t's interior: the tile that counts the
// point (its other copies are halo).
void owned_by(const Tiles& tiles, std::size_t t, const Cloud& pts, std::vector<std::uint8_t>& owned) {
  const auto in = tiles.interior(t);
  const NodeBinner node(tiles.g);
  owned.assign(pts.size(), 0);
  for (std::size_t i = 0; i < pts.size(); ++i) owned[i] = node.inside(pts.xyz.data() + 3 * i, in) ? 1 : 0;
}

// Tile t's spilled points (its window) as float x y z [m] for the k-NN search of stage
// tile_scale (detail::mean_knn_distances_of over floats), in file order, about a centre near
// them: the window's xy centre (grid frame) and the median z of its first 4096 records in file
// order. Float's resolution is about 6e-8 of the distance from that centre: within the window's
// xy extent (a tile and its halo) and a z span of 10 m, better than 0.6 µm; points far from the
// first records' height lose precision in proportion. sampled: the records flagged kSampleFlag
// (their positions in file order). xyz (3 floats a record) and sampled are reused buffers;
// sampled_m, when given, gets the sampled records' x y z [m] (grid frame) appended, as the
// in-core run holds them (RobustScale::centre_m).
// Returns the centre [m] (grid frame): point j lies at centre + xyz[3j .. 3j + 2].
// @throws InputError naming the spill file when it cannot be read (Spill::scan), or naming the
//         tile and the record when a coordinate about the centre overflows float.
// (Until 2026-11-25 the window was read as a Cloud of doubles, recentred and converted on each
// pass of the search: at 10^8 points, 112 M records.)
std::array<double, 3> read_window_floats(const Spill& spill, const Tiles& tiles, std::size_t t, std::vector<float>& xyz,
                                         std::vector<std::uint32_t>& sampled, std::vector<std::array<double, 3>>* sampled_m = nullptr) {
  const std::size_t n = spill.records(t);
  xyz.resize(3 * n);
  sampled.clear();
  const GridWindow w = tiles.window(t);
  double centre[3] = {tiles.g.x_of_col(w.col0 + 0.5 * (w.cols - 1)), tiles.g.y_of_row(w.row0 + 0.5 * (w.rows - 1)), 0.0};
  constexpr std::size_t kHeld = 4096;
  std::vector<double> held;  // the first kHeld records' x y z, until the z centre is known
  held.reserve(3 * std::min(n, kHeld));
  std::size_t i = 0;
  const auto put = [&](std::size_t j, const double* p) {
    for (std::size_t a = 0; a < 3; ++a) {
      const double v = p[a] - centre[a];
      if (!(std::abs(v) <= static_cast<double>(std::numeric_limits<float>::max()))) {
        throw InputError("tiled run: tile " + std::to_string(t) + "'s record " + std::to_string(j) + " of " +
                         spill.file(t).string() + " lies " + format_number(v) + " m from the window's centre, beyond float's range");
      }
      xyz[3 * j + a] = static_cast<float>(v);
    }
  };
  const auto settle = [&] {
    std::vector<double> z;
    for (std::size_t j = 2; j < held.size(); j += 3) z.push_back(held[j]);
    if (!z.empty()) {
      std::nth_element(z.begin(), z.begin() + static_cast<std::ptrdiff_t>(z.size() / 2), z.end());
      centre[2] = z[z.size() / 2];
    }
    for (std::size_t j = 0; 3 * j < held.size(); ++j) put(j, held.data() + 3 * j);
  };
  spill.scan(t, [&](std::uint8_t flag, const double* p, const std::uint8_t*, float) {
    if (flag & kSampleFlag) {
      sampled.push_back(static_cast<std::uint32_t>(i));
      if (sampled_m != nullptr) sampled_m->push_back({p[0], p[1], p[2]});
    }
    if (i < kHeld) {
      held.insert(held.end(), p, p + 3);
      if (i + 1 == std::min(n, kHeld)) settle();
    } else {
      put(i, p);
    }
    ++i;
  });
  return {centre[0], centre[1], centre[2]};
}

// ---------------------------------------------------------------------------------------------
// Passes over the input.

// Pass 1a: box of the finite points in file units, counts, stored precision.
struct FileBox {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  std::uint64_t points = 0, finite = 0;
  Layout layout;
  bool float32 = false;
  std::array<std::vector<double>, 3> distinct;
  Eigen::Vector3d max_abs = Eigen::Vector3d::Zero();
};

// Applies units, recentring and the view transform to a chunk, exactly as the in-core stages
// (to_metres_and_recentre, apply_view_transform) compute them, then non-finite and crop.
Cloud to_grid_frame(Cloud chunk, const Eigen::Vector3d& centre, double unit_m, const RunConfig& config) {
  chunk.xyz.colwise() -= centre;
  if (unit_m != 1.0) chunk.xyz *= unit_m;
  chunk = apply_view_transform(std::move(chunk), config.view).value;
  chunk = remove_non_finite(std::move(chunk)).value;
  if (config.filters.crop_m) chunk = keep_inside_box(std::move(chunk), config.filters.crop_m->first, config.filters.crop_m->second);
  return chunk;
}

struct Percentile {
  std::uint64_t rank;  // 0-based rank (nearest-rank rule of ErrorStats)
  std::uint32_t high = 0;
  std::uint64_t below = 0;  // values in lower high-bins
  std::size_t bin = 0;      // RadixPercentiles: which of its low-bit counts is high's
};

// The cross-check's on-surface residuals (vertical, normal; float pairs) of the first pass over
// the kept points, in a scratch file, so that the second pass of the exact percentiles reads
// 8 bytes a point instead of the kept points (13 or more, Layout) and computing every residual again.
// The file is removed when the object goes, whatever happened.
class ResidualFile {
 public:
  // Registered for SIGINT/SIGTERM's clean-up (the merge writes it in the plan's folder).
  explicit ResidualFile(fs::path file) : file_(std::move(file)) {}
  ResidualFile(const ResidualFile&) = delete;
  ResidualFile& operator=(const ResidualFile&) = delete;
  ~ResidualFile() {
    if (f_) std::fclose(f_);  // then file_ removes the file
  }
  void put(float vertical_m, float normal_m) {
    buf_.push_back(vertical_m);
    buf_.push_back(normal_m);
    if (buf_.size() >= kBuffer) flush();
  }
  // Ends writing; then each(f) calls f(vertical, normal) for every pair in order.
  template <class F>
  void each(F&& f) {
    flush();
    if (f_ && std::fclose(f_) != 0) fail("write");
    f_ = nullptr;
    if (written_ == 0) return;
    f_ = std::fopen(file_.path().c_str(), "rb");
    if (!f_) fail("read");
    std::uint64_t left = written_;
    while (left > 0) {
      const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(left, kBuffer));
      buf_.resize(n);
      if (std::fread(buf_.data(), sizeof(float), n, f_) != n) fail("read");
      for (std::size_t i = 0; i + 1 < n; i += 2) f(buf_[i], buf_[i + 1]);
      left -= n;
    }
    buf_.clear();
  }

 private:
  static constexpr std::size_t kBuffer = std::size_t{1} << 18;  // floats (even): 1 MiB
  void flush() {
    if (buf_.empty()) return;
    if (!f_) {
      errno = 0;
      f_ = open_live_scratch_file(file_.path(), "wb");
      if (!f_) fail("write");
    }
    if (std::fwrite(buf_.data(), sizeof(float), buf_.size(), f_) != buf_.size()) fail("write");
    written_ += buf_.size();
    buf_.clear();
  }
  [[noreturn]] void fail(const char* what) const {
    const int err = errno;
    throw InputError("scale.scratch: cannot " + std::string(what) + " the cross-check's residual file " + file_.path().string() +
                     (err != 0 ? std::string(": ") + std::strerror(err) : std::string()) + " (is the disk full?)");
  }
  LiveScratchFile file_;  // registered for the signal clean-up; removed when this goes
  std::FILE* f_ = nullptr;
  std::vector<float> buf_;
  std::uint64_t written_ = 0;  // floats
};

// Exact nearest-rank percentiles of a multiset of non-negative floats seen twice: pass 1 counts
// the top 16 bits of each value's bit pattern (non-negative floats order as their bits), pass 2
// the low 16 bits of the values in the bins holding the ranks.
class RadixPercentiles {
 public:
  void pass1(float v) {
    const std::uint32_t b = std::bit_cast<std::uint32_t>(v);
    ++high_[b >> 16];
    ++n_;
    sum_sq_ += static_cast<double>(v) * static_cast<double>(v);
    max_ = std::max(max_, v);
  }
  void prepare() {
    for (const double q : {0.50, 0.95, 0.99}) {
      Percentile p;
      const auto k = static_cast<std::uint64_t>(std::ceil(q * static_cast<double>(n_)));
      p.rank = std::clamp<std::uint64_t>(k, 1, std::max<std::uint64_t>(n_, 1)) - 1;
      std::uint64_t acc = 0;
      for (std::uint32_t h = 0; h < high_.size(); ++h) {
        if (acc + high_[h] > p.rank) {
          p.high = h;
          p.below = acc;
          break;
        }
        acc += high_[h];
      }
      p.bin = static_cast<std::size_t>(std::find(highs_.begin(), highs_.end(), p.high) - highs_.begin());
      if (p.bin == highs_.size()) {
        highs_.push_back(p.high);
        lows_.emplace_back(1u << 16, 0);
      }
      ps_.push_back(p);
    }
  }
  void pass2(float v) {
    const std::uint32_t b = std::bit_cast<std::uint32_t>(v);
    // At most three bins: a scan of them, not a search of a tree, per value.
    for (std::size_t i = 0; i < highs_.size(); ++i) {
      if (highs_[i] == b >> 16) ++lows_[i][b & 0xFFFFu];
    }
  }
  ErrorStats stats() {
    ErrorStats s;
    s.count = n_;
    if (n_ == 0) return s;
    double out[3];
    for (std::size_t i = 0; i < ps_.size(); ++i) {
      const Percentile& p = ps_[i];
      const std::vector<std::uint64_t>& low = lows_[p.bin];
      std::uint64_t acc = p.below;
      std::uint32_t l = 0;
      for (; l < low.size(); ++l) {
        if (acc + low[l] > p.rank) break;
        acc += low[l];
      }
      out[i] = static_cast<double>(std::bit_cast<float>((p.high << 16) | l)) * 1e3;
    }
    s.p50_mm = out[0];
    s.p95_mm = out[1];
    s.p99_mm = out[2];
    s.max_mm = static_cast<double>(max_) * 1e3;
    s.rms_mm = std::sqrt(sum_sq_ / static_cast<double>(n_)) * 1e3;
    return s;
  }

 private:
  std::vector<std::uint64_t> high_ = std::vector<std::uint64_t>(1u << 16, 0);
  std::vector<std::uint32_t> highs_;              // the bins holding the ranks, each once
  std::vector<std::vector<std::uint64_t>> lows_;  // per such bin, the counts of the low 16 bits
  std::vector<Percentile> ps_;
  std::uint64_t n_ = 0;
  double sum_sq_ = 0.0;
  float max_ = 0.0f;
};

// Adds the per-tile figures that are counts or seconds (a sum of thresholds or medians over
// tiles would mean nothing).
void add_figures(std::map<std::string, double>& sums, const StageReport& r) {
  static const char* const kCounts[] = {"removed", "cells", "points", "candidates", "certified", "exact_queries",
                                        "local_tests", "clusters", "far_clusters", "kept_far_clusters", "undecided_far_clusters", "spike_cells",
                                        "rim_cells", "island_cells", "coherent_above_global", "duplicates_left_out"};
  for (const auto& [name, v] : r.figures) {
    if (!std::isfinite(v)) continue;
    bool count = name.size() > 2 && name.compare(name.size() - 2, 2, "_s") == 0;
    for (const char* prefix : kCounts) count = count || name.rfind(prefix, 0) == 0;
    if (count) sums[name] += v;
  }
}

// The run's input as one stream: the scans placed by their poses (input.conf), else the files
// in one frame (input.shared_frame) or the one file.
std::unique_ptr<PointStream> open_input(const RunConfig& config, const LoadOptions& load) {
  if (config.input.conf) return open_posed_point_streams(config.input.files, *config.input.conf, load);
  return open_point_streams(config.input.files, load);
}

// One pass over the input in the grid frame: every chunk through to_grid_frame, then `body`,
// with the pass's progress by points read.
template <class Body>
void for_each_grid_chunk(const LoadOptions& load, const RunConfig& config,
                         const Eigen::Vector3d& centre, double unit_m, std::uint64_t total_points,
                         const ProgressFn& progress, const char* stage_name, const char* pass, Body&& body) {
  auto s = open_input(config, load);
  Cloud c;
  detail::PassProgress tick(progress, stage_name, pass, config.scale.progress_interval_s);
  std::uint64_t read = 0;
  while (s->next(c, config.scale.chunk_points)) {
    read += c.size();
    tick(static_cast<double>(read) / static_cast<double>(std::max<std::uint64_t>(total_points, 1)));
    body(to_grid_frame(std::move(c), centre, unit_m, config));
  }
}

// The point count in the header of a gzipped LAS or LAZ file `f`, reading only its first 375
// bytes through the gzip stream (detail::las_header_point_count, LAS 1.4 R15 Table 3); nullopt
// when those bytes are not such a header (the in-core read then says what is wrong).
std::optional<std::uint64_t> gzipped_las_count(const fs::path& f) {
  try {
    const auto src = detail::ByteSource::open(f, detail::quoted(f), true);
    std::array<char, 375> h{};
    const std::size_t got = src->read(h.data(), h.size());
    if (got < 227 || std::string_view(h.data(), 4) != "LASF") return std::nullopt;
    if (static_cast<unsigned char>(h[25]) >= 4 && got < 375) return std::nullopt;
    return detail::las_header_point_count(h.data());
  } catch (const InputError&) {
    return std::nullopt;
  }
}

// The points in a gzipped E57 file `f` as its plain file's stream counts them: the file is
// inflated up to the end of its XML section, which lies near the end (detail::e57_record_count:
// one inflate of the file, its bytes not kept, before the tiled run inflates it again into its
// scratch folder); nullopt when it is no such file (the in-core read then says what is wrong).
std::optional<std::uint64_t> gzipped_e57_count(const fs::path& f) {
  try {
    const auto src = detail::ByteSource::open(f, detail::quoted(f), true);
    return detail::e57_record_count(*src, detail::quoted(f));
  } catch (const InputError&) {
    return std::nullopt;
  }
}

}  // namespace

std::optional<std::uint64_t> counted_input_points(const RunConfig& config, bool headers_only) {
  if (config.input.synthetic || config.input.files.empty()) return std::nullopt;
  std::uint64_t total = 0;
  for (const fs::path& f : config.input.files) {
    std::string ext;
    const bool gz = detail::gz_name(f, ext);
    if (headers_only) {
      // Counts that cost a pass over the file (text lines, an inflate) are left out, and so are
      // LAS and LAZ files of which the read drops classes other than the noise ones (7 low and 18
      // high noise, LAS 1.4 R15 Table 17: the default, a few points): their headers count the
      // dropped points too.
      const bool las = ext == ".las" || ext == ".laz";
      const bool header = (!gz && (las || ext == ".ply" || ext == ".pcd" || ext == ".e57")) || (gz && las);
      const auto& drop = config.input.las_drop_classes;
      const bool drops_more = std::any_of(drop.begin(), drop.end(), [](int c) { return c != 7 && c != 18; });
      if (!header || (las && drops_more)) return std::nullopt;
    }
    // Only a natively streamed file is counted without reading it whole (a PTX, PTS or XYZ
    // file's first look reads its lines without parsing the points, an OBJ's counts the numbers
    // of its `v` lines; under gzip, decompressing them; a gzipped PCD's inflates it once for its
    // size). An OBJ with faces counts only with input.as_points (else a mesh, in core).
    // A gzipped LAS or LAZ file by its header's count, a gzipped E57 by its XML section's (the
    // tiled run inflates them once: inflate_seeking_inputs).
    const bool text = ext == ".ptx" || ext == ".pts" || ext == ".xyz" || ext == ".txt" || ext == ".obj";
    const bool gz_seeking = gz && detail::reader_seeks(ext);
    if (!(ext == ".ply" || ext == ".pcd" || text || gz_seeking || (!gz && detail::reader_seeks(ext)))) return std::nullopt;
    std::error_code ec;
    if (!fs::is_regular_file(f, ec)) return std::nullopt;  // (a FIFO would block) the in-core read reports it
    if (gz_seeking) {
      const std::optional<std::uint64_t> n = ext == ".e57" ? gzipped_e57_count(f) : gzipped_las_count(f);
      if (!n) return std::nullopt;
      total += *n;
      continue;
    }
    std::unique_ptr<PointStream> s;
    try {
      const LoadOptions load{config.input.las_drop_classes, config.input.as_points};
      s = ext == ".ply"   ? detail::open_ply_stream(f, f.string(), config.input.as_points, gz)
          : ext == ".las" ? detail::open_las_stream(f, f.string(), &load)
          : ext == ".laz" ? detail::open_laz_stream(f, f.string(), &load)
          : ext == ".ptx" ? detail::open_ptx_stream(f, f.string(), gz)
          : ext == ".pts" ? detail::open_pts_stream(f, f.string(), gz)
          : ext == ".e57" ? detail::open_e57_stream(f, f.string())
          : ext == ".pcd" ? detail::open_pcd_stream(f, f.string(), gz)
          : ext == ".obj" ? detail::open_obj_stream(f, f.string(), config.input.as_points, gz)
                          : detail::open_xyz_stream(f, f.string(), gz);
    } catch (const InputError&) {
      return std::nullopt;  // the in-core read reports the problem
    }
    if (!s) return std::nullopt;
    total += s->total_points();
  }
  return total;
}

std::string tiled_run_refusal(const RunConfig& c) {
  const auto refuse = [](const char* key, const std::string& why) { return std::string(key) + " " + why; };
  if (c.input.synthetic) return refuse("input.synthetic", "is set");
  if (c.input.files.size() != 1 && !c.input.shared_frame && !c.input.conf) {
    return refuse("input.files", "lists " + std::to_string(c.input.files.size()) + " files without input.shared_frame or input.conf");
  }
  if (c.filters.voxel_m > 0.0) return refuse("filters.voxel_m", "is > 0");
  if (!c.filters.pcl.empty()) return refuse("filters.pcl", "is not empty");
  if (c.filters.outliers.enabled && c.filters.outliers.method != OutlierMethod::kRobust) {
    return refuse("filters.outliers.method", "is not robust");
  }
  if (c.grid.organised_mesh) return refuse("grid.organised", "is mesh");
  return {};
}

bool runs_tiled(const RunConfig& config) {
  if (config.scale.tiled == ScaleConfig::Tiled::kOff) return false;
  if (config.scale.tiled == ScaleConfig::Tiled::kOn) {
    check_supported(config);
    return true;
  }
  if (config.input.files.size() > 1 && !config.input.shared_frame && !config.input.conf) return false;
  const std::optional<std::uint64_t> total = counted_input_points(config, false);
  if (!total || *total <= config.scale.tiled_above_points) return false;
  return tiled_run_refusal(config).empty();  // auto: an option the tiled run lacks keeps the run in core
}

namespace {

// ---------------------------------------------------------------------------------------------
// What the passes after the spill need: kept in memory by the in-process run, in plan.json by
// `hapticloud tile-plan` for tile jobs in other processes (tile-job, tile-merge).

struct Plan {
  Tiles tiles;
  Layout layout;
  std::optional<RobustScale> robust_scale;  // the robust test's whole-scan scale (stage tile_scale)
  std::uint64_t input_points = 0;           // points in the file (the levels sample's stride)
  std::uint64_t grid_points = 0;            // after non-finite, crop and far clusters: the points gridded
  std::uint64_t far_points = 0;             // of far clusters (tile_far_clusters), spilled marked kFarFlag
  // The whole scan's main body's box (the grid frame, tile_far_clusters' largest component),
  // against which each tile judges its own far clusters (FarClusterScope); none when that stage
  // did not run.
  std::optional<std::array<Eigen::Vector3d, 2>> far_main_box_m;
  std::uint64_t far_size_points = 0;  // N of the far clusters' size limit: the points after non-finite and crop
  // The whole scan's extent before the far clusters go (tile_far_clusters: the longest side of
  // the grid's box, two cells wider, or the z span) [m]; 0 when that stage did not run
  // (exact_far_clusters).
  double far_extent_m = 0.0;
  // grid.upsample: auto (in process and in plan.json since 2026-11-30): the coverage counts
  // of factors 1 to tiles.k (UpsampleCoverage::counts, index k − 1) over the factor_points
  // points the plan chose the factor from, for factor_may_change; empty when not known.
  std::vector<std::array<std::uint64_t, 2>> factor_counts;
  std::uint64_t factor_points = 0;
  detail::StoredPrecision precision;
  Eigen::Vector3d offset_m = Eigen::Vector3d::Zero();
  std::string crs;
  std::vector<SceneInput> inputs;    // the input files in order, with their checksums
  std::vector<StageReport> reports;  // tile_plan, tile_spill, tile_scale
};

// The despike's figures as the tiles sum them (remove_spike_points's report, and the windows'
// island groups): carried into an attempt that takes its removals over (GridBox::despike_sums).
constexpr const char* kDespikeSums[] = {"removed_spike_points", "spike_cells", "rim_cells", "island_cells",
                                        "tiles_with_a_group_past_island_max_cells"};

// An x-y box [m, grid frame] and the points it was taken over (none: empty, infinite bounds).
struct XyBox {
  double x_lo = std::numeric_limits<double>::infinity(), x_hi = -x_lo, y_lo = x_lo, y_hi = -x_lo;
  std::uint64_t points = 0;
  void add(const double* p) {
    x_lo = std::min(x_lo, p[0]);
    x_hi = std::max(x_hi, p[0]);
    y_lo = std::min(y_lo, p[1]);
    y_hi = std::max(y_hi, p[1]);
    ++points;
  }
  void merge(const XyBox& b) {
    x_lo = std::min(x_lo, b.x_lo);
    x_hi = std::max(x_hi, b.x_hi);
    y_lo = std::min(y_lo, b.y_lo);
    y_hi = std::max(y_hi, b.y_hi);
    points += b.points;
  }
};

// A grid's size, cells and origin, for notes and warnings.
std::string grid_words(const GridGeometry& g) {
  return std::to_string(g.cols) + " x " + std::to_string(g.rows) + " cells of " + format_number(g.cell_size_m * 1e3) + " mm from x " +
         format_number(g.x0_m) + ", y " + format_number(g.y0_m) + " m";
}

// The grid the in-core run lays on the points of `b` (grid_geometry_for_box, with the plan's
// upsample factor and no cell limit: the plan checked it for the first box), for
// scale.grid_on_kept_points and its warning.
GridGeometry grid_for_box(const RunConfig& config, const Tiles& tiles, const XyBox& b) {
  ReprojectOptions ro = config.grid.reproject;
  ro.upsample_factor = tiles.k;
  ro.grid.max_cells = std::numeric_limits<std::size_t>::max();
  return grid_geometry_for_box(b.x_lo, b.x_hi, b.y_lo, b.y_hi, static_cast<std::size_t>(b.points), ro);
}

// The box of the points of `pts` whose grid node lies in `inner` (a tile's interior: the points
// it owns; each point of the scan is owned by one tile).
XyBox owned_box(const Tiles& tiles, const std::array<int, 4>& inner, const Cloud& pts) {
  const NodeBinner node(tiles.g);
  XyBox b;
  for (std::size_t i = 0; i < pts.size(); ++i) {
    const double* p = pts.xyz.data() + 3 * i;
    if (node.inside(p, inner)) b.add(p);
  }
  return b;
}

// One tile's result: its interior of the grid and its figures (the levels sample is read from
// the kept points after the loop).
// Which of its spilled records it kept is in its kept-point mask (kept_<t>.bin, KeptMask).
struct TileOutput {
  std::size_t tile = 0;
  DepthGrid interior;  // the tile's interior rows × cols; empty when no point is left in it
  std::map<std::string, double> sums;
  std::uint64_t in = 0, out = 0, unjudged = 0;
  double spacing_m = 0.0;            // median nearest-neighbour spacing of the tile's input points [m]
  std::uint64_t spacing_points = 0;  // the input points it came from (its weight)
  std::uintmax_t kept_bytes = 0;   // size of the tile's kept-point mask file (0: none kept, no file)
  double seconds = 0.0;
  // The x-y box of the points the tile owns that the outlier filters keep (the robust test,
  // far clusters, the isolated filter; points of a window too sparse to judge are kept too),
  // before the despike: the in-core run lays its grid on the whole scan's
  // (scale.grid_on_kept_points). Empty with the filters off.
  XyBox kept_box;
  // The same after the despike (equal to kept_box where it removed no owned point), and the
  // owned points it removed (x y z [m] each; in a tile job's result too): build_scene_tiled and
  // tile-merge lay the grid on that box when the in-core run would.
  XyBox after_box;
  std::vector<std::array<double, 3>> despiked_m;
  // The in-core run's far-cluster cells (FarCells::link_key at edge link_m, the linking
  // distance remove_far_clusters_after takes) of the points the tile owns that its robust test
  // kept, before any far cluster goes, each with its points' count and box [m]: the merge joins
  // them, tile by tile, into the in-core run's far clusters (exact_far_clusters; sixty-sixth
  // session). Empty with the robust test or far clusters off. A window too sparse to judge sends its owned points' cells as kept
  // (its points are kept untested). link_cells_partial: a point lies beyond link_key's range,
  // so the cells cannot be the in-core ones.
  struct LinkCell {
    std::uint64_t key = 0, count = 0;
    double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
  };
  std::vector<LinkCell> link_cells;
  double link_m = 0.0;
  bool link_cells_partial = false;
  // Where the tile runs with ScaleConfig::far_cells (processed again, or an attempt that carries
  // them): the given clusters (their numbers) of which the tile removed an owned point, for the
  // merge's cluster count (in the part file since format 6, for the tiles tile-merge processes
  // again).
  std::vector<std::uint32_t> far_clusters_hit;
};

// The link cells of a tile's points (TileOutput::link_cells): open addressing on the key (a
// power of two slots, at most half full), each cell in its slot (one cache line), the slots of a
// block of points fetched ahead: a scan in random order meets a new cell at nearly every point,
// and a table of indices to the cells cost two misses a point (4.5 s of a 10⁸ run).
class LinkCellTable {
 public:
  explicit LinkCellTable(double link_m) : inv_(1.0 / link_m) {}
  // Adds the n points at xyz (x y z doubles each) whose node lies in `inner` (the tile's own);
  // false, and no more points, at one without a key (FarCells::link_key's kNoKey).
  bool add_owned(const double* xyz, std::size_t n, const NodeBinner& owner, const std::array<int, 4>& inner) {
    constexpr std::size_t kBlock = 32;
    std::array<std::uint64_t, kBlock> keys{};
    std::array<std::size_t, kBlock> at{};
    for (std::size_t b = 0; b < n; b += kBlock) {
      const std::size_t e = std::min(n, b + kBlock);
      std::size_t m = 0;
      for (std::size_t i = b; i < e; ++i) {
        const double* p = xyz + 3 * i;
        if (!owner.inside(p, inner)) continue;
        const std::uint64_t k = FarCells::link_key(p, inv_);
        if (k == FarCells::kNoKey) return false;
        __builtin_prefetch(&slots_[home(k)]);
        keys[m] = k;
        at[m++] = i;
      }
      for (std::size_t j = 0; j < m; ++j) add(keys[j], xyz + 3 * at[j]);
    }
    return true;
  }
  // The cells, in slot order (FarCells sorts a tile's cells itself).
  std::vector<TileOutput::LinkCell> take() const {
    std::vector<TileOutput::LinkCell> cells;
    cells.reserve(used_);
    for (const Slot& s : slots_) {
      if (s.key == kFree) continue;
      TileOutput::LinkCell& c = cells.emplace_back();
      c.key = s.key;
      c.count = s.count;
      for (int a = 0; a < 3; ++a) {
        c.lo[a] = s.lo[a];
        c.hi[a] = s.hi[a];
      }
    }
    return cells;
  }

 private:
  struct alignas(64) Slot {
    std::uint64_t key = FarCells::kNoKey, count = 0;
    double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
  };
  static constexpr std::uint64_t kFree = FarCells::kNoKey;
  std::size_t home(std::uint64_t k) const { return static_cast<std::size_t>((k * 0x9E3779B97F4A7C15ULL) >> (64 - bits_)); }
  void add(std::uint64_t k, const double* p) {
    const std::size_t mask = slots_.size() - 1;
    for (std::size_t i = home(k);; i = (i + 1) & mask) {
      Slot& s = slots_[i];
      if (s.key == k) {
        ++s.count;
        for (int a = 0; a < 3; ++a) {
          s.lo[a] = std::min(s.lo[a], p[a]);
          s.hi[a] = std::max(s.hi[a], p[a]);
        }
        return;
      }
      if (s.key != kFree) continue;
      s.key = k;
      s.count = 1;
      for (int a = 0; a < 3; ++a) s.lo[a] = s.hi[a] = p[a];
      if (2 * ++used_ > slots_.size()) grow();
      return;
    }
  }
  void grow() {
    std::vector<Slot> old(std::size_t{1} << (bits_ + 1));
    old.swap(slots_);
    ++bits_;
    const std::size_t mask = slots_.size() - 1;
    for (const Slot& s : old) {
      if (s.key == kFree) continue;
      std::size_t i = home(s.key);
      while (slots_[i].key != kFree) i = (i + 1) & mask;
      slots_[i] = s;
    }
  }
  double inv_;
  int bits_ = 10;
  std::vector<Slot> slots_ = std::vector<Slot>(std::size_t{1} << 10);
  std::size_t used_ = 0;
};

// The points of `pts` (any cloud in the grid frame) in the cells `far` lists (the in-core far
// clusters' cells, ScaleConfig::far_cells): their columns (increasing), x y z [m] and each one's
// cluster number in `far`. link_m: the linking distance the tile finds (far_link_m), which must
// be the one the cells were found at. @throws std::logic_error naming tile t where it is not.
RemovedPoints in_far_cells(const Cloud& pts, const ScaleConfig::FarCellKeys& far, double link_m, std::size_t t) {
  if (link_m != far.link_m) {
    throw std::logic_error("process_tile: tile " + std::to_string(t) + ": the far clusters' link is " + format_number(link_m * 1e3) +
                           " mm, the given cells' " + format_number(far.link_m * 1e3) + " mm");
  }
  RemovedPoints r;
  const double inv = 1.0 / far.link_m;
  for (std::size_t i = 0; i < pts.size() && !far.keys.empty(); ++i) {
    const double* p = pts.xyz.data() + 3 * i;
    const std::uint64_t k = FarCells::link_key(p, inv);
    const auto at = std::lower_bound(far.keys.begin(), far.keys.end(), k);
    if (k == FarCells::kNoKey || at == far.keys.end() || *at != k) continue;
    r.at.push_back(i);
    r.xyz.insert(r.xyz.end(), p, p + 3);
    r.cluster.push_back(far.cluster[static_cast<std::size_t>(at - far.keys.begin())]);
  }
  return r;
}

// Removes the columns `at` (increasing) from `pts`.
void remove_columns(Cloud& pts, const std::vector<std::size_t>& at) {
  if (at.empty()) return;
  std::vector<bool> keep(pts.size(), true);
  for (const std::size_t i : at) keep[i] = false;
  pts.keep_if(keep);
}

// The levels table's sample: every sample_stride-th interior point, in tile order (read from the
// kept points after the tile loop). 0 ("every point") would hold the whole cloud in memory, which
// the tiled run exists to avoid: it takes the default sample instead (docs/scale.md).
std::size_t sample_stride_of(const RunConfig& config, std::uint64_t input_points) {
  return level_sample_stride(input_points, config.lod.report_sample_points);
}

bool keeps_sample(const RunConfig& config) { return config.lod.report && config.lod.report_cross_check; }

// Tile t's spilled points without the far clusters' (kFarFlag, when the plan found any); `flags`
// receives the spill's flag bytes.
Cloud read_tile_points(const Plan& plan, const Spill& spill, std::size_t t, std::vector<std::uint8_t>& flags) {
  Cloud pts = spill.read(t, flags);
  if (plan.far_points == 0) return pts;
  std::vector<bool> keep(flags.size());
  for (std::size_t i = 0; i < flags.size(); ++i) keep[i] = (flags[i] & kFarFlag) == 0;
  pts.keep_if(keep);
  return pts;
}

// A ball {x, y, z, radius} [m] in the grid frame (RobustVerdicts::reach_m).
using Ball = detail::BallSet::Ball;
using detail::BallSet;

std::string attempt_tag();
// The scratch a process makes beside spill files or in a plan's folder, named with its
// attempt_tag() (remove_stale_scratch recognises them by these names):
constexpr std::string_view kBlocksPrefix = ".blocks-";     // + tag: the block copies' folder of builds before 2026-11-27
constexpr std::string_view kKeptJobPrefix = ".kept-job-";  // + tag + "-<t>.bin": a tile job's temporary kept files
constexpr std::string_view kTmpInfix = ".tmp-";            // "." + file + this + tag: write_atomically's temporary

// The robust test's strays, judged over the whole scan. A stray is a point of a tile's window
// whose verdict's k-NN searches (its own and, where the verdict used them, its neighbours')
// could end past the window (RobustVerdicts::past_halo, with the balls reach_m that must hold
// every point of the scan for its verdict to be the whole scan's). The tile loop runs in two
// sweeps over a band of tiles (run_tiles): the first (look_tile) runs each tile's robust first
// look and keeps its verdicts; judge_strays judges every stray of the band again, once, over
// the scan's points inside the balls, gathered in one pass over the spills their balls meet;
// the second sweep (process_tile) takes the verdicts and runs the tile's other steps. Until
// 2026-11-27 each tile gathered its own strays' points from its neighbours' spills, through
// block copies of those written to scratch: at 10^8 points, 15 s and 1.6 GB written to judge
// 8 399 strays (docs/scale.md).

// A window's spilled records are numbered in 32 bits (the kept mask's record numbers, Taken).
// @throws ResourceError naming the tile and the keys when tile t's window holds more.
void check_window_records(std::size_t t, std::size_t records) {
  if (records <= std::numeric_limits<std::uint32_t>::max()) return;
  throw ResourceError("tile " + std::to_string(t) + ": its window holds " + std::to_string(records) +
                      " spilled records, at most 4294967295 supported (lower scale.tile_max_points or scale.tile_cells)");
}

// The ring of a tile's interior that other tiles' decided regions reach [nodes]: the decided
// region's width (the halo less the filters' share; tile_bounds), and a node more for the
// rounding that can put a point a step inside a box its node lies outside (Tiles::box_m).
int owned_ring(const Tiles& tiles) { return std::max(0, tiles.halo - tiles.filter) + 1; }

// Node (r, c)'s index among the nodes of the interior `in` (Tiles::interior) within `w` nodes of
// its edge, row by row; kNotInRing for a node farther inside. `count`, when given, receives the
// ring's nodes.
constexpr std::uint32_t kNotInRing = std::numeric_limits<std::uint32_t>::max();
std::uint32_t ring_index(const std::array<int, 4>& in, int w, int r, int c, std::size_t* count = nullptr) {
  const int h = in[1] - in[0], wd = in[3] - in[2];
  const int top = std::min(w, h), mid = std::max(0, h - 2 * w), bottom = h - top - mid;
  const int mid_w = wd <= 2 * w ? wd : 2 * w;
  if (count) *count = static_cast<std::size_t>(top + bottom) * static_cast<std::size_t>(wd) + static_cast<std::size_t>(mid) * static_cast<std::size_t>(mid_w);
  const int lr = r - in[0], lc = c - in[2];
  if (lr < top) return static_cast<std::uint32_t>(lr * wd + lc);
  if (lr < top + mid) {
    if (wd > 2 * w && lc >= w && lc < wd - w) return kNotInRing;
    const int at = wd <= 2 * w ? lc : (lc < w ? lc : lc - (wd - 2 * w));
    return static_cast<std::uint32_t>(top * wd + (lr - top) * mid_w + at);
  }
  return static_cast<std::uint32_t>(top * wd + mid * mid_w + (lr - top - mid) * wd + lc);
}

// Per node of a window, the place in the band (run_tiles' band_at) of the tile that owns it
// (whose interior holds it), -1 outside the band, and the node's index in that tile's ring
// (ring_index with owned_ring; kNotInRing outside the band or the ring): table reads a point
// instead of divisions.
struct WindowBand {
  WindowBand(const Tiles& tiles, const GridWindow& w, const std::vector<int>& band_at)
      : row0(w.row0), col0(w.col0), rows(w.rows), cols(w.cols), place(static_cast<std::size_t>(w.rows) * static_cast<std::size_t>(w.cols)),
        local(place.size()) {
    const int ring = owned_ring(tiles);
    for (int r = 0; r < w.rows; ++r) {
      const int tr = (r + w.row0) / tiles.size;
      for (int c = 0; c < w.cols; ++c) {
        const int tc = (c + w.col0) / tiles.size;
        const std::size_t wn = static_cast<std::size_t>(r) * static_cast<std::size_t>(w.cols) + static_cast<std::size_t>(c);
        place[wn] = band_at[static_cast<std::size_t>(tr * tiles.tiles_c + tc)];
        local[wn] = place[wn] < 0 ? kNotInRing
                                  : ring_index(tiles.interior(static_cast<std::size_t>(tr * tiles.tiles_c + tc)), ring, r + w.row0, c + w.col0);
      }
    }
  }
  // Point p's node (NodeBinner) as an index in the window. @throws std::logic_error naming
  // `who` and tile t when the node lies outside the window (the spill put p in another's).
  std::size_t node_at(const NodeBinner& node, const double* p, std::size_t t, const char* who) const {
    const int r = node.row(p), c = node.col(p);
    if (r < row0 || r >= row0 + rows || c < col0 || c >= col0 + cols) {
      throw std::logic_error(std::string(who) + ": tile " + std::to_string(t) + "'s window holds a point of node (" + std::to_string(r) +
                             ", " + std::to_string(c) + "), outside it");
    }
    return static_cast<std::size_t>(r - row0) * static_cast<std::size_t>(cols) + static_cast<std::size_t>(c - col0);
  }
  // Window node wn as "(row, col)" of the whole grid, for errors.
  std::string node_text(std::size_t wn) const {
    return "(" + std::to_string(row0 + static_cast<int>(wn / static_cast<std::size_t>(cols))) + ", " +
           std::to_string(col0 + static_cast<int>(wn % static_cast<std::size_t>(cols))) + ")";
  }
  int row0, col0, rows, cols;
  std::vector<int> place;
  std::vector<std::uint32_t> local;
};

// A band tile's robust verdicts of the points it owns near its interior's edge (its ring,
// owned_ring nodes wide: the reach of other tiles' decided regions into it), for the other
// tiles of its band, whose windows hold some of them: look_tile leaves such a point, where it
// lies in its own decided region, to its owner, and process_tile takes the owner's verdict
// (docs/scale.md, "Each point judged by its owner", fiftieth session). Each ring node's points
// are held together, in the window's (input) order: the points of a node come in that order in
// every window that holds the node (a window holds whole nodes, and every spill file keeps the
// input's order), so a node's j-th point in one window is its j-th in another. Memory: a byte a
// ring point, 4 bytes a ring node that holds points and about 0.19 bytes a ring node (RingStarts).

// Where each ring node's points start in OwnedVerdicts::vn (offsets of a compressed sparse row
// layout), held by the nodes that hold points: a bit a node (whether it holds any), the count of
// such nodes before each 64-node word, and the start of each such node, then the total. A node
// without points starts where the next one with points does. About 0.19 bytes a node plus 4 a
// node with points. Until 2026-12-01 (sixty-ninth session) a dense offset per node: 4 bytes a
// node, which on a grid finer than the scan (10^7 points at N = 16384, 0.07 points a cell, a
// 166-node ring about each 512-node tile) made 470 MB for a band of 512 tiles, most of the tile
// loop's peak, for a few points each.
class RingStarts {
 public:
  // From `count`, each of the `nodes` ring nodes' points (count[a] for a < nodes).
  void assign(const std::vector<std::uint32_t>& count, std::size_t nodes) {
    bits_.assign((nodes + 63) / 64, 0);
    rank_.assign(bits_.size(), 0);
    starts_.clear();
    std::uint32_t at = 0;
    for (std::size_t a = 0; a < nodes; ++a) {
      if (a % 64 == 0) rank_[a / 64] = static_cast<std::uint32_t>(starts_.size());
      if (count[a] == 0) continue;
      bits_[a / 64] |= std::uint64_t{1} << (a % 64);
      starts_.push_back(at);
      at += count[a];
    }
    starts_.push_back(at);
    starts_.shrink_to_fit();
  }
  // Node a's first place in vn, and one past its last (a < nodes).
  std::uint32_t begin(std::size_t a) const { return starts_[rank(a)]; }
  std::uint32_t end(std::size_t a) const {
    return starts_[rank(a) + static_cast<std::size_t>((bits_[a / 64] >> (a % 64)) & 1U)];
  }
  std::uint32_t total() const { return starts_.empty() ? 0 : starts_.back(); }
  std::size_t bytes() const { return bits_.size() * 8 + rank_.size() * 4 + starts_.size() * 4; }

 private:
  // The nodes with points before node a.
  std::size_t rank(std::size_t a) const {
    const std::uint64_t below = bits_[a / 64] & ((std::uint64_t{1} << (a % 64)) - 1);
    return rank_[a / 64] + static_cast<std::size_t>(std::popcount(below));
  }
  std::vector<std::uint64_t> bits_;
  std::vector<std::uint32_t> rank_;
  std::vector<std::uint32_t> starts_;
};

struct OwnedVerdicts {
  RingStarts start;  // per ring node (ring_index), where its points are in vn
  // Per ring point, node by node: the robust verdict (RobustVerdicts::verdict, low 4 bits) and
  // the near count clamped to 15 (RobustVerdicts::near, high 4 bits; 0 when not asked).
  std::vector<std::uint8_t> vn;
  // The ring's strays (rv.past_halo): (place in vn, index in past_halo), until judge_strays has
  // given their whole-scan verdicts (run_tiles).
  std::vector<std::pair<std::uint32_t, std::uint32_t>> strays;
};

// A tile's robust first look, from look_tile to process_tile.
struct TileLook {
  bool ran = false;        // the robust test ran on the window (filter on, k + 2 points or more)
  std::size_t points = 0;  // the window's points (read_tile_points), which process_tile reads again
  // The verdicts other than 0 (kept), by window column: (column, RobustVerdicts::verdict), the
  // columns ascending. Sparse: most points are kept, and a band holds every tile's.
  std::vector<std::pair<std::uint32_t, std::uint8_t>> removed;
  RobustVerdicts rv;  // past_halo and reach_m as the first look gave them; verdict and near emptied
  // RobustVerdicts::near, two points a byte (low nibble first), each count clamped to 15: still
  // a lower bound of the others within the radius, as near promises, so every use stays sound
  // (a kept point's count short of the isolated filter's neighbours, up to 1000, only costs
  // that filter a search; cross_check.isolation_min_neighbours above 15 marks no removed
  // candidate kNear). Half of a band's memory otherwise. In a band (shares), only of the points
  // judged here, in column order (the others' counts are their owners').
  std::vector<std::uint8_t> near_nibbles;
  StageReport report;  // the first look's report
  std::vector<std::array<double, 3>> strays_m;  // rv.past_halo's points, x y z [m, the grid frame]
  std::vector<std::uint8_t> stray_verdict;      // per stray, the whole scan's verdict (judge_strays)
  double coord_m = 0.0;  // the largest |coordinate| of the window's finite box sides and points [m]
  std::map<std::string, double> sums;  // the tile's figures so far (look_tile's times)
  // In a band of more than one tile: the verdicts of the points the tile owns near its edge
  // (OwnedVerdicts), for the band's other tiles; the points that another tile of the band owns
  // in this tile's decided region were not judged here (not in `removed`, and left out of
  // near_nibbles).
  bool shares = false;
  OwnedVerdicts owned;
  bool near = false;  // the test gave near counts (RobustVerdicts::near): near_nibbles, or owned's, hold them
  // Memory held [bytes], for the band's budget where tiles do not share (run_tiles).
  std::size_t bytes() const {
    return removed.size() * sizeof(removed[0]) + near_nibbles.size() + rv.past_halo.size() * 4 + rv.reach_m.size() * 32 +
           strays_m.size() * 25 + owned.vn.size() + owned.start.bytes();
  }
};

// Tile t's window and the region whose verdicts it keeps (the halo less the filters' share):
// RobustOutlierOptions::tile.
RobustOutlierOptions::TileBounds tile_bounds(const Tiles& tiles, std::size_t t) {
  const auto inner = tiles.interior(t);
  const int grid_reach = std::max(0, tiles.halo - tiles.filter);
  return {tiles.box_m(tiles.window(t)),
          tiles.box_m(inner[0] - grid_reach, inner[1] + grid_reach, inner[2] - grid_reach, inner[3] + grid_reach), {}};
}

// The robust test's options for tile t's window, as the in-core run's (the plan's whole-scan
// scale) with the tile's bounds.
RobustOutlierOptions tile_robust_options(const RunConfig& config, const Plan& plan, std::size_t t) {
  const OutlierConfig& oc = config.filters.outliers;
  RobustOutlierOptions ropt;
  ropt.k = oc.k;
  ropt.local_ratio = oc.local_ratio;
  ropt.mad_multiplier = oc.mad_multiplier;
  ropt.off_surface_ratio = oc.off_surface_ratio;
  ropt.scale = plan.robust_scale;
  // Where a search that decides a verdict the tile keeps could end past the window, the point is
  // judged again over the whole scan (judge_strays). (Without the plan's scale, every sampled
  // point a copy of others, the test removes nothing.)
  if (plan.robust_scale) ropt.tile = tile_bounds(plan.tiles, t);
  // The window's points come back whole (the verdicts carry the result).
  ropt.verdicts_only = true;
  // Which points the test shows with the isolated-point filter's neighbours, just inside its
  // radius: the filter need not search about those that keep them (near_after_removal), nor
  // the honest check about the removed ones (KeptMask::kNear).
  const double sample_spacing_m = plan.robust_scale ? plan.robust_scale->spacing_m : 0.0;
  if (sample_spacing_m > 0.0 && config.cross_check.honest.isolation_min_neighbours >= 1) {
    ropt.near_radius_m = 0.99 * isolated_filter_radius_m(config.cross_check.honest, sample_spacing_m);
  }
  return ropt;
}

// The first sweep for tile t: its window's points read and the robust test's first look run
// over them (tile_robust_options); nothing kept but the verdicts (TileLook). A look that did
// not run (filter off, fewer than k + 2 points) leaves process_tile to do as without the filter.
// `band_at`: each tile's place in t's band, -1 outside it or not sharing (run_tiles). In a band
// of more than one tile (with the whole scan's scale), a point that another tile of the band
// owns is not judged here (RobustOutlierOptions::judge_mask): its owner judges it, with the same
// whole-scan verdict (each owner's interior lies in its decided region), and t's own points'
// verdicts go to TileLook::owned.
TileLook look_tile(const RunConfig& config, const Plan& plan, const Spill& spill, std::size_t t, const std::vector<int>& band_at) {
  TileLook look;
  const OutlierConfig& oc = config.filters.outliers;
  if (!oc.enabled) return look;
  auto lap_at = detail::Clock::now();
  auto lap = [&](const char* step) {
    const auto now = detail::Clock::now();
    look.sums[std::string("tile_") + step + "_s"] += std::chrono::duration<double>(now - lap_at).count();
    lap_at = now;
  };
  std::vector<std::uint8_t> flags;
  Cloud pts = read_tile_points(plan, spill, t, flags);
  look.points = pts.size();
  check_window_records(t, flags.size());
  lap("look_read");
  if (pts.size() < static_cast<std::size_t>(oc.k) + 2) {
    if (band_at[t] >= 0) {
      throw std::logic_error("look_tile: tile " + std::to_string(t) + " shares its points' judging with " + std::to_string(pts.size()) +
                             " points in its window, fewer than k + 2");
    }
    return look;
  }
  RobustOutlierOptions ropt = tile_robust_options(config, plan, t);
  // In a band of more than one tile: the points t owns, and those it leaves to their owners
  // (another tile of the band) where their verdicts are the whole scan's, in its decided region
  // (TileBounds::decides_m, as the test's own check of its searches bounds it). The points of
  // the band between that region and the window's edge are judged here whoever owns them: their
  // verdicts in this window (which the isolated-point and despike counts of decided points
  // see) need not be the whole scan's, and they must not depend on which tiles share a band.
  const Tiles& tiles = plan.tiles;
  look.shares = plan.robust_scale && band_at[t] >= 0 && std::count_if(band_at.begin(), band_at.end(), [](int b) { return b >= 0; }) > 1;
  std::vector<std::uint32_t> owned_col, owned_li;  // t's ring points' columns (ascending) and ring nodes (ring_index)
  std::vector<std::uint32_t> ring_count;            // per ring node: t's points, then the first place of them in vn
  std::optional<WindowBand> wb;  // with look.shares
  if (look.shares) {
    const NodeBinner node(tiles.g);
    const auto in = tiles.interior(t);
    const auto& dec = ropt.tile->decides_m;
    std::size_t ring_nodes = 0;
    (void)ring_index(in, owned_ring(tiles), in[0], in[2], &ring_nodes);
    ropt.judge_mask.assign(pts.size(), 1);
    const GridWindow w = tiles.window(t);
    wb.emplace(tiles, w, band_at);
    const int me = band_at[t];
    ring_count.assign(ring_nodes + 1, 0);  // per ring node, t's points; the last for the others (not kept)
    std::vector<std::uint32_t>& count = ring_count;
    owned_col.resize(pts.size() + 1);
    owned_li.resize(pts.size() + 1);
    std::size_t o = 0, left_out = 0;
    // Without a branch on the owner (the points come in no spatial order: a branch on it missed
    // about every other point).
    for (std::size_t i = 0; i < pts.size(); ++i) {
      const double* p = pts.xyz.data() + 3 * i;
      const std::size_t wn = wb->node_at(node, p, t, "look_tile");
      const int b = wb->place[wn];
      const std::uint32_t li = wb->local[wn];
      // 0 or 1 each, and all-ones masks from them, so that the compiler makes no branch.
      const auto ring = static_cast<std::uint32_t>(b == me) & static_cast<std::uint32_t>(li != kNotInRing);
      const auto left = static_cast<std::uint32_t>(b >= 0) & static_cast<std::uint32_t>(b != me) & static_cast<std::uint32_t>(p[0] >= dec[0]) &
                        static_cast<std::uint32_t>(p[0] < dec[1]) & static_cast<std::uint32_t>(p[1] >= dec[2]) & static_cast<std::uint32_t>(p[1] < dec[3]);
      ropt.judge_mask[i] = static_cast<std::uint8_t>(left ^ 1U);
      left_out += left;
      owned_col[o] = static_cast<std::uint32_t>(i);
      owned_li[o] = li;
      o += ring;
      const std::uint32_t keep = 0U - ring;
      ++count[(li & keep) | (static_cast<std::uint32_t>(ring_nodes) & ~keep)];
    }
    owned_col.resize(o);
    owned_li.resize(o);
    const bool all = left_out == 0;
    look.owned.start.assign(count, ring_nodes);
    // From here on, each ring node's first place in vn (dense, for this tile's scatter below).
    std::uint32_t first = 0;
    for (std::size_t a = 0; a < ring_nodes; ++a) first += std::exchange(count[a], first);
    if (all) ropt.judge_mask.clear();  // every point is t's to judge: the whole test
  }
  lap("look_mask");
  auto f1 = remove_robust_outliers(std::move(pts), ropt, &look.rv);
  look.ran = true;
  look.report = std::move(f1.report);
  lap("robust");
  const bool near = !look.rv.near.empty();
  look.near = near;
  if (look.shares) {
    // t's points' verdicts and near counts node by node, each node's in window order; the owned
    // strays' places.
    std::vector<std::uint32_t>& next = ring_count;
    look.owned.vn.assign(look.owned.start.total(), 0);
    std::size_t a = 0;  // the next stray (rv.past_halo, ascending)
    for (std::size_t o = 0; o < owned_col.size(); ++o) {
      const std::uint32_t i = owned_col[o];
      const std::uint32_t at = next[owned_li[o]]++;
      const std::uint8_t nv = near ? std::min<std::uint8_t>(look.rv.near[i], 15) : 0;
      look.owned.vn[at] = static_cast<std::uint8_t>(look.rv.verdict[i] | (nv << 4));
      while (a < look.rv.past_halo.size() && look.rv.past_halo[a] < i) ++a;
      if (a < look.rv.past_halo.size() && look.rv.past_halo[a] == i) look.owned.strays.emplace_back(at, static_cast<std::uint32_t>(a));
    }
  }
  for (std::size_t i = 0; i < look.rv.verdict.size(); ++i) {
    if (look.rv.verdict[i] != 0) look.removed.emplace_back(static_cast<std::uint32_t>(i), look.rv.verdict[i]);
  }
  std::vector<std::uint8_t>().swap(look.rv.verdict);
  if (near) {
    // The judged points' counts moved to the front in place (without a branch: which points
    // were judged follows no order), then packed.
    std::vector<std::uint8_t>& v = look.rv.near;
    const std::vector<std::uint8_t>& judged = ropt.judge_mask;  // empty: every point
    std::size_t held = v.size();
    if (!judged.empty()) {
      held = 0;
      for (std::size_t i = 0; i < v.size(); ++i) {
        v[held] = v[i];
        held += judged[i];
      }
    }
    look.near_nibbles.assign((held + 1) / 2, 0);
    for (std::size_t j = 0; j < held; ++j) {
      look.near_nibbles[j / 2] |= static_cast<std::uint8_t>(std::min<std::uint8_t>(v[j], 15) << (4 * (j % 2)));
    }
    std::vector<std::uint8_t>().swap(look.rv.near);
  }
  if (!look.rv.past_halo.empty()) {
    for (const double v : plan.tiles.box_m(plan.tiles.window(t))) look.coord_m = std::isfinite(v) ? std::max(look.coord_m, std::abs(v)) : look.coord_m;
    for (Eigen::Index i = 0; i < f1.value.xyz.cols(); ++i) look.coord_m = std::max(look.coord_m, f1.value.xyz.col(i).cwiseAbs().maxCoeff());
    for (const std::uint32_t c : look.rv.past_halo) {
      const auto p = f1.value.xyz.col(static_cast<Eigen::Index>(c));
      look.strays_m.push_back({p.x(), p.y(), p.z()});
    }
  }
  lap("look_keep");
  return look;
}

// A point's coordinates as the bits of its three doubles, and their hash: judge_strays finds a
// stray among the gathered points by them (the same spill bytes decode to the same doubles).
using PointBits = std::array<std::uint64_t, 3>;
struct PointBitsHash {
  std::size_t operator()(const PointBits& b) const {
    std::uint64_t h = b[0] * 0x9E3779B97F4A7C15ULL;
    h = (h ^ (h >> 29)) + b[1] * 0xBF58476D1CE4E5B9ULL;
    h = (h ^ (h >> 31)) + b[2] * 0x94D049BB133111EBULL;
    return static_cast<std::size_t>(h ^ (h >> 32));
  }
};
PointBits bits_of(const double* p) { return {std::bit_cast<std::uint64_t>(p[0]), std::bit_cast<std::uint64_t>(p[1]), std::bit_cast<std::uint64_t>(p[2])}; }

// The whole scan's verdicts of the strays a tile loop judged (judge_strays), by the bits of
// their coordinates, kept for the tiles processed again after that loop (the far clusters'
// fix-up, far_tiles_again): a stray's verdict is the in-core robust test's over the whole scan
// (its balls hold every point its searches need), which neither the band nor the far clusters'
// cells change, so a band whose strays all have one here needs no gathering (on the 10^8 wall
// such a band's two gatherings read 37 of the 40 spills for 4 tiles). At most kMost verdicts
// (32 bytes each: 32 MiB); past that no more are kept, and a band with a stray not kept gathers
// as before. seal() sorts them for find().
class StrayVerdicts {
 public:
  static constexpr std::size_t kMost = std::size_t{1} << 20;
  void add(const PointBits& b, std::uint8_t v) {
    if (v_.size() < kMost) v_.push_back({b, v});
  }
  void seal() {
    std::sort(v_.begin(), v_.end(), [](const Entry& a, const Entry& b) { return a.bits < b.bits; });
    sealed_ = true;
  }
  bool sealed() const { return sealed_; }
  std::size_t size() const { return v_.size(); }
  // The verdict kept for the stray at bits b, or -1 (none, or not sealed).
  int find(const PointBits& b) const {
    if (!sealed_) return -1;
    const auto it = std::lower_bound(v_.begin(), v_.end(), b, [](const Entry& e, const PointBits& k) { return e.bits < k; });
    return it != v_.end() && it->bits == b ? static_cast<int>(it->verdict) : -1;
  }

 private:
  struct Entry {
    PointBits bits;
    std::uint8_t verdict = 0;
  };
  std::vector<Entry> v_;
  bool sealed_ = false;
};

// The tile loop's first looks (TileLook, as look_tile gave them, before judge_strays), kept for
// the tiles processed again after that loop (the far clusters' fix-up, far_tiles_again): a look
// is the robust test over the tile's window, which the far clusters' cells given to the fix-up
// (ScaleConfig::far_cells) do not change, so the fix-up takes the kept look instead of reading
// the window and running the test again (the second half of each tile: reprojection, despike,
// the mask, reads the window again as before). Only looks that do not share their band's judging
// (TileLook::shares false: a shared look depends on the band's other tiles; on the 10^8 wall at
// N = 4096 none share, nor in a band of one tile), and at most kBudgetBytes (128 MiB) of them
// (TileLook::bytes; the later ones are not kept and are looked at again). In the fix-up a tile with a kept look shares with no other tile of its band (as one
// whose window may hold too few points: the others judge their points themselves). A look is
// kept in place of its release after process_tile (which takes a copy), so a band of looks holds
// no more at its start than before; after the loop the kept ones stay until the fix-up has run.
// Seventy-second session, the 10^8 wall at N = 4096: the 40 looks hold 68 MB (the tile loop's
// peak 721 -> 771 MB), the fix-up's 4 tiles 9.6 -> 3.5 CPU s (docs/scale.md).
class KeptLooks {
 public:
  static constexpr std::size_t kBudgetBytes = std::size_t{128} << 20;
  // Whether tile t's look is to be kept: none taken yet (the fix-up's own looks are not), it does
  // not share, none is kept for t, and it fits.
  bool wants(std::size_t t, const TileLook& look) const {
    return taken_ == 0 && !look.shares && looks_.count(t) == 0 && held_ + look.bytes() <= kBudgetBytes;
  }
  // Keeps tile t's look (after wants(t, look)).
  void keep(std::size_t t, TileLook&& look) {
    held_ += look.bytes();
    looks_.emplace(t, std::move(look));
  }
  // Tile t's kept look, moved out (its bytes stay counted: none is offered after the loop), or none.
  std::optional<TileLook> take(std::size_t t) {
    const auto it = looks_.find(t);
    if (it == looks_.end()) return std::nullopt;
    std::optional<TileLook> out(std::move(it->second));
    looks_.erase(it);
    ++taken_;
    return out;
  }
  bool has(std::size_t t) const { return looks_.count(t) != 0; }
  std::size_t taken() const { return taken_; }
  std::size_t bytes() const { return held_; }

 private:
  std::size_t held_ = 0, taken_ = 0;
  std::map<std::size_t, TileLook> looks_;
};

// A point of the scan a gathering took: where it is in its owner tile's spill, and where.
struct Taken {
  std::uint32_t tile = 0, rec = 0;  // process_tile refuses a window of 2^32 spilled records or more
  std::array<double, 3> xyz{};
  bool operator<(const Taken& o) const { return tile != o.tile ? tile < o.tile : rec < o.rec; }
};
static_assert(sizeof(Taken) == 32, "gather_owned's memory figure counts 32 bytes a point taken");

// Adds to `taken` the points of the scan inside `now` and inside no ball of `before`: each
// from the spill of the tile that owns it (its node in the tile's interior: NodeBinner), far
// clusters left out, so each point once. Reads, on two threads, the spills of the tiles whose
// interior a ball of `now` meets; each tile's records are tested against the balls that meet
// its interior only, and only on the nodes those balls' xy boxes cover (a table of the
// interior's nodes, a bit each: 32 KiB for 512-node tiles, per thread). Memory: the points
// taken (32 bytes each: Taken). `sums`: robust_spill_points_scanned grows by the records read.
// @throws InputError naming a spill file that cannot be read.
void gather_owned(const Plan& plan, const Spill& spill, const BallSet& now, const BallSet& before, std::vector<Taken>& taken,
                  std::map<std::string, double>& sums) {
  const Tiles& tiles = plan.tiles;
  const NodeBinner node(tiles.g);
  const Layout& lay = spill.layout();
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<std::size_t> read;
  std::vector<std::vector<Ball>> meeting;  // per tile read, the balls of `now` that meet its interior
  for (std::size_t u = 0; u < tiles.count(); ++u) {
    const auto in = tiles.interior(u);
    const auto b = tiles.reading_box_m(in[0], in[1], in[2], in[3]);
    std::vector<Ball> mine;
    for (const Ball& s : now.balls()) {
      if (detail::ball_meets(s, {b[0], b[1], b[2], b[3], -inf, inf})) mine.push_back(s);
    }
    if (mine.empty()) continue;
    read.push_back(u);
    meeting.push_back(std::move(mine));
  }
  const int threads = read.size() > 1 ? 2 : 1;
  std::vector<std::vector<Taken>> part(static_cast<std::size_t>(threads));
  std::vector<double> scanned(static_cast<std::size_t>(threads), 0.0);
  std::vector<std::exception_ptr> failed(static_cast<std::size_t>(threads));
  detail::run_parallel(threads, [&](int th) {
    try {
      for (std::size_t i = static_cast<std::size_t>(th); i < read.size(); i += static_cast<std::size_t>(threads)) {
        const std::size_t u = read[i];
        const BallSet set(meeting[i]);
        const auto in = tiles.interior(u);
        // The interior's nodes a point inside a ball can be binned to: for each ball the nodes
        // between those of its xy box's corners (NodeBinner is non-decreasing in x and in y),
        // summed from a difference table. A record on another node is passed over before the
        // ball test (most of a tile's records: the balls lie about its few strays).
        const auto rows = static_cast<std::size_t>(in[1] - in[0]), cols = static_cast<std::size_t>(in[3] - in[2]);
        std::vector<std::int32_t> diff((rows + 1) * (cols + 1), 0);
        for (const Ball& b : meeting[i]) {
          const double lo[3] = {b[0] - b[3], b[1] - b[3], 0.0}, hi[3] = {b[0] + b[3], b[1] + b[3], 0.0};
          const int r0 = std::max(node.row(lo), in[0]) - in[0], r1 = std::min(node.row(hi), in[1] - 1) - in[0];
          const int c0 = std::max(node.col(lo), in[2]) - in[2], c1 = std::min(node.col(hi), in[3] - 1) - in[2];
          if (r0 > r1 || c0 > c1) continue;
          const auto at = [&](int r, int c) -> std::int32_t& {
            return diff[static_cast<std::size_t>(r) * (cols + 1) + static_cast<std::size_t>(c)];
          };
          ++at(r0, c0);
          --at(r0, c1 + 1);
          --at(r1 + 1, c0);
          ++at(r1 + 1, c1 + 1);
        }
        // A bit per node (32 KiB for 512-node tiles: the table stays in L1 while the records
        // come in file order, which jumps about the tile).
        std::vector<std::uint64_t> hit((rows * cols + 63) / 64, 0);
        std::vector<std::int32_t> column(cols + 1, 0);  // the running sums down each column
        for (std::size_t r = 0; r < rows; ++r) {
          std::int32_t across = 0;
          for (std::size_t c = 0; c < cols; ++c) {
            column[c] += diff[r * (cols + 1) + c];
            across += column[c];
            if (across > 0) hit[(r * cols + c) >> 6] |= std::uint64_t{1} << ((r * cols + c) & 63);
          }
        }
        std::vector<std::int32_t>().swap(diff);
        std::uint64_t rec = 0;
        auto& out = part[static_cast<std::size_t>(th)];
        spill.scan_records(u, [&](const char* record) {
          const std::uint64_t r = rec++;
          if ((static_cast<std::uint8_t>(record[0]) & kFarFlag) != 0) return;
          double p[3];
          lay.xyz(record + 1, p);
          // The node's place in the interior (unsigned: a node before its first row or column
          // wraps past the end); another tile owns a point outside it.
          const auto nr = static_cast<std::size_t>(static_cast<unsigned>(node.row(p) - in[0]));
          const auto nc = static_cast<std::size_t>(static_cast<unsigned>(node.col(p) - in[2]));
          if (nr >= rows || nc >= cols) return;
          const std::size_t at = nr * cols + nc;
          if (((hit[at >> 6] >> (at & 63)) & 1U) == 0) return;
          if (!set.contains(p) || before.contains(p)) return;
          out.push_back({static_cast<std::uint32_t>(u), static_cast<std::uint32_t>(r), {p[0], p[1], p[2]}});
        });
        scanned[static_cast<std::size_t>(th)] += static_cast<double>(spill.records(u));
      }
    } catch (...) {
      failed[static_cast<std::size_t>(th)] = std::current_exception();
    }
  });
  for (const auto& e : failed) {
    if (e) std::rethrow_exception(e);
  }
  for (std::size_t th = 0; th < part.size(); ++th) {
    taken.insert(taken.end(), part[th].begin(), part[th].end());
    std::vector<Taken>().swap(part[th]);
    sums["robust_spill_points_scanned"] += scanned[th];
  }
}

// judge_strays' error for balls that reach more than kMaxWidenedTiles tiles past tile t's
// window: names the stage, the tile and the keys that help.
[[noreturn]] void throw_too_far(const Tiles& tiles, std::size_t t, std::size_t strays, double past_m, const std::string& halo_now) {
  const auto inner = tiles.interior(t);
  const int limit = kMaxWidenedTiles * tiles.size;
  throw InputError("tiled run, tile " + std::to_string(t) + " (grid rows " + std::to_string(inner[0]) + ".." +
                   std::to_string(inner[1] - 1) + ", cols " + std::to_string(inner[2]) + ".." + std::to_string(inner[3] - 1) +
                   "): stage outliers (filters.outliers, robust): the k-NN searches of " + std::to_string(strays) +
                   " points reach " + format_number(past_m * 1e3) + " mm past the tile's window (the limit is " +
                   std::to_string(limit) + " cells, " + std::to_string(kMaxWidenedTiles) +
                   " tiles): raise scale.filter_halo_cells (now " + halo_now + "), crop the strays " +
                   "(filters.crop) or run in core (scale.tiled: off)");
}

// Ball b as a gathering takes it: its radius widened by the second look's own float slack (8
// float steps of its largest recentred coordinate, at most twice coord_m, the largest coordinate
// of the points and balls [m]), so that no point is listed again for rounding alone.
Ball padded(Ball b, double coord_m) {
  b[3] = b[3] * (1.0 + 1e-4) + 64.0 * static_cast<double>(std::numeric_limits<float>::epsilon()) * coord_m;
  return b;
}

// coord_m grown to the largest |coordinate| ball b reaches [m].
double reach_coord_m(double coord_m, const Ball& b) {
  return std::max({coord_m, std::abs(b[0]) + b[3], std::abs(b[1]) + b[3], std::abs(b[2]) + b[3]});
}

// How far ball b reaches past the box {x_min, x_max, y_min, y_max} [m] (an infinite side: not
// at all), 0 when inside.
double past_box_m(const Ball& b, const std::array<double, 4>& box) {
  return std::max({0.0, box[0] - (b[0] - b[3]), b[0] + b[3] - box[1], box[2] - (b[1] - b[3]), b[1] + b[3] - box[3]});
}

// The second look for the strays of a band of tiles (`band`, their looks in `looks`, aligned):
// every stray judged again (RobustOutlierOptions::judge_only, with the whole scan's scale) over
// the scan's points inside the balls their verdicts need complete (the union of the looks'
// reach_m, each radius padded by the float slack of the second look: 8 float steps of the
// largest coordinate, at most twice the largest grid coordinate here), gathered by gather_owned
// in one pass; where the second look's own searches leave those balls, their balls are gathered
// in turn (only their points outside the balls before) and the strays judged again, at most
// scale.max_gatherings times (8; else InputError naming the tiles and the keys); a gathering of
// fewer than k + 2 points (a stray in a cluster of k + 1) is gathered again with every ball
// twice as wide. Each look's stray_verdict gets the verdicts (a stray two tiles'
// windows hold is judged once). The balls of a tile's strays may reach at most kMaxWidenedTiles
// tiles past its window, those of a later gathering (a second look's, or grown) as far past the
// window of the tile that owns their centre: else InputError (throw_too_far), naming the stage,
// the tile and the keys (a grown ball unbounded would gather all the scan within its reach). Adds
// to the looks' sums: robust_windows_widened and robust_widened_cells (per tile, its first-look
// balls); to `sums` (the band's): robust_gatherings, robust_balls_grown (the gatherings of fewer
// than k + 2 points), robust_points_gathered,
// robust_spill_points_scanned, robust_gather_s and robust_judge_again_s. `verdicts` (may be
// null): unsealed, gets every stray's verdict; sealed (the loop after), where it holds every
// stray's verdict, those are taken and nothing is gathered (figure
// robust_strays_verdicts_kept).
void judge_strays(const RunConfig& config, const Plan& plan, const Spill& spill, const std::vector<std::size_t>& band,
                  std::vector<TileLook>& looks, std::map<std::string, double>& sums, StrayVerdicts* verdicts) {
  const Tiles& tiles = plan.tiles;
  const std::string halo_now = filter_halo_now(config, tiles);
  const int limit = kMaxWidenedTiles * tiles.size;
  double coord_m = 0.0;
  std::vector<Ball> asked;  // every ball, as the searches gave them
  std::size_t strays = 0;
  for (std::size_t i = 0; i < band.size(); ++i) {
    TileLook& L = looks[i];
    if (L.rv.past_halo.empty()) continue;
    strays += L.rv.past_halo.size();
    // The tile's own check, with the pad a gathering of its balls alone would give.
    double c = L.coord_m;
    for (const Ball& b : L.rv.reach_m) c = reach_coord_m(c, b);
    const auto box = tiles.box_m(tiles.window(band[i]));
    double past_m = 0.0;
    for (const Ball& b : L.rv.reach_m) past_m = std::max(past_m, past_box_m(padded(b, c), box));
    const double cells = std::ceil(past_m / tiles.g.cell_size_m);  // in double: a stray kilometres away
    if (cells > limit) throw_too_far(tiles, band[i], L.rv.past_halo.size(), past_m, halo_now);
    L.sums["robust_windows_widened"] += 1.0;
    L.sums["robust_widened_cells"] += cells;
    coord_m = std::max(coord_m, c);
    asked.insert(asked.end(), L.rv.reach_m.begin(), L.rv.reach_m.end());
  }
  if (strays == 0) return;
  // Every stray's verdict kept from the loop before (the far clusters' fix-up): no gathering.
  if (verdicts != nullptr && verdicts->sealed()) {
    std::vector<std::vector<std::uint8_t>> kept(looks.size());
    bool all = true;
    for (std::size_t i = 0; i < looks.size() && all; ++i) {
      for (const auto& p : looks[i].strays_m) {
        const int v = verdicts->find(bits_of(p.data()));
        all = v >= 0;
        if (!all) break;
        kept[i].push_back(static_cast<std::uint8_t>(v));
      }
    }
    if (all) {
      for (std::size_t i = 0; i < looks.size(); ++i) looks[i].stray_verdict = std::move(kept[i]);
      sums["robust_strays_verdicts_kept"] += static_cast<double>(strays);
      return;
    }
  }
  const OutlierConfig& oc = config.filters.outliers;
  std::vector<Ball> balls;  // gathered so far, padded
  std::vector<Ball> fresh;  // to gather next, padded
  for (const Ball& b : asked) fresh.push_back(padded(b, coord_m));
  std::vector<Taken> taken;  // by (tile, record), each point once
  const NodeBinner node(tiles.g);
  // The strays, by their coordinates' bits (a point two tiles' windows hold is one stray).
  std::unordered_set<PointBits, PointBitsHash> wanted;
  for (const TileLook& L : looks) {
    for (const auto& p : L.strays_m) wanted.insert(bits_of(p.data()));
  }
  // A later ball (a second look's, or a ball grown for a gathering of too few points), padded:
  // within the limit past the window of the tile that owns its centre, else throw_too_far
  // naming that tile and `n` points.
  const auto check_later_ball = [&](const Ball& p, std::size_t n) {
    const double c[3] = {p[0], p[1], p[2]};
    const std::size_t owner = static_cast<std::size_t>(node.row(c) / tiles.size) * static_cast<std::size_t>(tiles.tiles_c) +
                              static_cast<std::size_t>(node.col(c) / tiles.size);
    const double past_m = past_box_m(p, tiles.box_m(tiles.window(owner)));
    if (std::ceil(past_m / tiles.g.cell_size_m) > limit) throw_too_far(tiles, owner, n, past_m, halo_now);
  };
  std::string with_strays;  // the tiles with strays, for the errors
  for (std::size_t i = 0; i < band.size(); ++i) {
    if (!looks[i].rv.past_halo.empty()) with_strays += (with_strays.empty() ? "" : ", ") + std::to_string(band[i]);
  }
  const int most = config.scale.max_gatherings;
  for (int pass = 0;; ++pass) {
    if (pass == most) {
      throw InputError("tiled run, the strays of tiles " + with_strays + ": stage outliers (filters.outliers, robust): after " +
                       std::to_string(most) + (most == 1 ? " gathering" : " gatherings") + " (scale.max_gatherings) the second look's k-NN searches about " +
                       std::to_string(strays) + " points still leave the balls gathered (or those hold fewer than k + 2 points): raise " +
                       "scale.filter_halo_cells (now " + halo_now + ") or scale.max_gatherings, crop the strays (filters.crop) or run in core (scale.tiled: off)");
    }
    const auto t_gather = detail::Clock::now();
    const std::size_t had = taken.size();
    {
      const BallSet now(fresh), before(balls);
      gather_owned(plan, spill, now, before, taken, sums);  // appends
      std::sort(taken.begin() + static_cast<std::ptrdiff_t>(had), taken.end());
      std::inplace_merge(taken.begin(), taken.begin() + static_cast<std::ptrdiff_t>(had), taken.end());
    }
    balls.insert(balls.end(), fresh.begin(), fresh.end());
    fresh.clear();
    sums["robust_gatherings"] += 1.0;
    sums["robust_points_gathered"] += static_cast<double>(taken.size() - had);
    if (taken.size() < static_cast<std::size_t>(oc.k) + 2) {
      sums["robust_balls_grown"] += 1.0;
      for (Ball b : balls) {
        b[3] = 2.0 * b[3] + tiles.g.cell_size_m;
        check_later_ball(b, strays);
        fresh.push_back(b);
      }
      sums["robust_gather_s"] += detail::seconds_since(t_gather);
      continue;
    }
    Cloud near;
    near.xyz.resize(3, static_cast<Eigen::Index>(taken.size()));
    std::unordered_map<PointBits, std::uint32_t, PointBitsHash> at;  // a stray's column in `near`
    at.reserve(wanted.size());
    for (std::size_t j = 0; j < taken.size(); ++j) {
      std::copy(taken[j].xyz.begin(), taken[j].xyz.end(), near.xyz.data() + 3 * j);
      const PointBits key = bits_of(taken[j].xyz.data());
      if (wanted.count(key) != 0) at.emplace(key, static_cast<std::uint32_t>(j));
    }
    sums["robust_gather_s"] += detail::seconds_since(t_gather);
    const auto t_judge = detail::Clock::now();
    RobustOutlierOptions wo = tile_robust_options(config, plan, band.front());
    wo.near_radius_m = 0.0;
    wo.tile->complete_m = balls;
    wo.judge_only.clear();
    for (const auto& [key, col] : at) wo.judge_only.push_back(col);
    if (at.size() != wanted.size()) {
      throw std::logic_error("judge_strays: " + std::to_string(wanted.size() - at.size()) + " of " + std::to_string(wanted.size()) +
                             " strays not among the points gathered");
    }
    std::sort(wo.judge_only.begin(), wo.judge_only.end());
    RobustVerdicts wv;
    remove_robust_outliers(std::move(near), wo, &wv);
    sums["robust_judge_again_s"] += detail::seconds_since(t_judge);
    if (wv.past_halo.empty()) {
      for (TileLook& L : looks) {
        L.stray_verdict.clear();
        for (const auto& p : L.strays_m) L.stray_verdict.push_back(wv.verdict[at.at(bits_of(p.data()))]);
      }
      if (verdicts != nullptr && !verdicts->sealed()) {
        for (const auto& [key, col] : at) verdicts->add(key, wv.verdict[col]);
      }
      return;
    }
    // The second look's searches that leave the balls: their balls next, each within the
    // limit past the window of the tile that owns its centre. When the largest coordinate grew,
    // every earlier ball again with the new pad (as a single gathering of every ball would
    // have it: the second look's float slack grows with it).
    const double coord_before = coord_m;
    for (const Ball& b : wv.reach_m) coord_m = reach_coord_m(coord_m, b);
    if (coord_m > coord_before) {
      for (const Ball& b : asked) fresh.push_back(padded(b, coord_m));
    }
    asked.insert(asked.end(), wv.reach_m.begin(), wv.reach_m.end());
    for (const Ball& b : wv.reach_m) {
      const Ball p = padded(b, coord_m);
      check_later_ball(p, wv.past_halo.size());
      fresh.push_back(p);
    }
  }
}

// The isolated-point and despike tests count a point's neighbours within a radius: a point a
// tile keeps is kept over the whole scan too (more points, more neighbours), a point it removes
// is removed there too unless its radius reaches past the window. Throws ConfigError, naming
// the stage, the tile and scale.filter_halo_cells with the value needed, when a removed point
// in the decided region (b.decides_m) lies within reach_m of the window's open sides.
void check_within_window(const Tiles& tiles, std::size_t t, const RobustOutlierOptions::TileBounds& b, const RemovedPoints& removed,
                         double reach_m, const char* stage, double spacing_m, const std::string& halo_now) {
  const auto& d = b.decides_m;
  const auto& win = b.window_m;
  std::size_t n = 0;
  for (std::size_t i = 0; i < removed.size(); ++i) {
    const double x = removed.xyz[3 * i], y = removed.xyz[3 * i + 1];
    if (!(x >= d[0] && x < d[1] && y >= d[2] && y < d[3])) continue;
    n += std::min({x - win[0], win[1] - x, y - win[2], win[3] - y}) <= reach_m ? 1U : 0U;
  }
  if (n == 0) return;
  const double cell_m = tiles.g.cell_size_m;
  throw ConfigError("tiled run, tile " + std::to_string(t) + ": stage " + stage + " removed " + std::to_string(n) +
                    " points whose neighbour count (within " + format_number(reach_m * 1e3) + " mm; spacing " +
                    format_number(spacing_m * 1e3) + " mm) reaches past the tile's window, so the whole scan may keep them: "
                    "raise scale.filter_halo_cells (now " + halo_now + ") to at least " +
                    std::to_string(static_cast<int>(std::ceil(std::min(reach_m / cell_m, 1e6) + 0.5))) +
                    " (the halo then holds the search beyond the cells the tile decides)");
}

// Removes from v the entries at the positions removed_at lists (increasing, each < v.size()),
// keeping the others' order: a filter's removed columns (RemovedPoints::at) applied to what the
// tile carries per point.
template <class T>
void erase_at(std::vector<T>& v, const std::vector<std::size_t>& removed_at) {
  std::size_t at = 0, next = 0;
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (next < removed_at.size() && removed_at[next] == i) {
      ++next;
      continue;
    }
    v[at++] = v[i];
  }
  v.resize(at);
}

// The isolated-point filter's known_near flags of `pts` (one per point) from the robust test's
// counts (RobustVerdicts::near: others shown within the radius before the removals): 1 where
// the count, less the removed points (gone_m, x y z [m] each, the same frame) within radius_m
// of the point, is still at least min_neighbours. Returns how many points had the count but
// lost it so. Voxels of edge radius_m (a thousandth wider, so that two points within the
// radius never lie two voxels apart, whatever the rounding): each removed point is listed in
// its voxel and the 26 around it; a point whose count could fall below min_neighbours (by the
// longest list) and in a voxel with a list (WantedKeys) is measured against the removed points
// in it (double distances, a millionth of the radius wider).
std::size_t near_after_removal(const Cloud& pts, const std::vector<std::uint8_t>& count, const std::vector<double>& gone_m,
                               double radius_m, int min_neighbours, std::vector<std::uint8_t>& flags) {
  const std::size_t n = count.size();
  flags.assign(n, 0);
  for (std::size_t i = 0; i < n; ++i) flags[i] = count[i] >= min_neighbours ? 1 : 0;
  const std::size_t gone = gone_m.size() / 3;
  if (gone == 0) return 0;
  const double inv = 1.0 / (radius_m * 1.001);
  auto cell = [inv](double v) { return detail::voxel_index(v, inv); };
  auto key = [](std::int64_t x, std::int64_t y, std::int64_t z) { return detail::pack_voxel21(x, y, z); };
  // (voxel, removed point) for each removed point and each voxel about its own, by voxel.
  std::vector<std::pair<std::uint64_t, std::uint32_t>> listed;
  listed.reserve(27 * gone);
  for (std::size_t g = 0; g < gone; ++g) {
    const std::int64_t x = cell(gone_m[3 * g]), y = cell(gone_m[3 * g + 1]), z = cell(gone_m[3 * g + 2]);
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) listed.emplace_back(key(x + dx, y + dy, z + dz), static_cast<std::uint32_t>(g));
  }
  std::sort(listed.begin(), listed.end());
  listed.erase(std::unique(listed.begin(), listed.end()), listed.end());
  std::vector<std::uint64_t> voxel;  // distinct voxels, ascending
  std::vector<std::uint32_t> run;    // voxel v's entries of `listed`: run[v] .. run[v + 1] − 1
  for (std::size_t e = 0; e < listed.size(); ++e) {
    if (e == 0 || listed[e].first != listed[e - 1].first) {
      voxel.push_back(listed[e].first);
      run.push_back(static_cast<std::uint32_t>(e));
    }
  }
  run.push_back(static_cast<std::uint32_t>(listed.size()));
  const detail::WantedKeys at(voxel);  // distinct, so voxel v is numbered v
  const double r2 = radius_m * radius_m * (1.0 + 2e-6);
  // Every removed point within the radius of a point is listed in the point's voxel: a point
  // whose count stays at least min_neighbours less the longest list keeps its flag unlooked
  // (the robust test's counted points, k = 16, about a few scattered removals).
  std::uint32_t longest = 0;
  for (std::size_t v = 0; v + 1 < run.size(); ++v) longest = std::max(longest, run[v + 1] - run[v]);
  const auto safe = static_cast<std::int64_t>(min_neighbours) + static_cast<std::int64_t>(longest);
  std::size_t lost = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (!flags[i] || static_cast<std::int64_t>(count[i]) >= safe) continue;
    const double* p = pts.xyz.data() + 3 * i;
    const std::uint32_t v = at.find(key(cell(p[0]), cell(p[1]), cell(p[2])));
    if (v == detail::WantedKeys::kNone) continue;  // no removed point within a voxel of it
    int removed = 0;
    for (std::uint32_t e = run[v]; e < run[v + 1]; ++e) {
      const double* q = gone_m.data() + 3 * static_cast<std::size_t>(listed[e].second);
      const double dx = p[0] - q[0], dy = p[1] - q[1], dz = p[2] - q[2];
      removed += dx * dx + dy * dy + dz * dz <= r2 ? 1 : 0;
    }
    if (static_cast<int>(count[i]) - removed < min_neighbours) {
      flags[i] = 0;
      ++lost;
    }
  }
  return lost;
}

// The robust verdicts (and near counts when `near`) that look_tile left to the owners, into
// rv.verdict and rv.near: of tile t's window points `pts` (window order), those another tile of
// its band owns inside t's decided region (tile_bounds' decides_m), from the owners'
// OwnedVerdicts (`owned`, by place in the band; band_at: each tile's place, -1 outside); left[i]
// = 1 for those (the points look_tile did not judge), 0 for the others. A node's j-th point in
// the window is its j-th in its owner's. @throws std::logic_error when a node's points in the
// window are not as many as its owner holds.
void take_owned_verdicts(const Tiles& tiles, std::size_t t, const Cloud& pts, const std::vector<int>& band_at,
                         const std::vector<OwnedVerdicts>& owned, bool near, RobustVerdicts& rv, std::vector<std::uint8_t>& left) {
  left.assign(pts.size(), 0);
  const NodeBinner node(tiles.g);
  const GridWindow w = tiles.window(t);
  const auto dec = tile_bounds(tiles, t).decides_m;
  const int mine = band_at[t];
  const WindowBand wb(tiles, w, band_at);
  // The points another tile of the band owns, with their window nodes: listed without a branch
  // on the owner (the points come in no spatial order), a chunk at a time, then taken in order.
  constexpr std::size_t kChunk = 65536;
  std::vector<std::array<std::uint32_t, 2>> theirs(kChunk + 1);
  std::vector<std::uint32_t> seen(wb.place.size(), 0);
  for (std::size_t first = 0; first < pts.size(); first += kChunk) {
    const std::size_t last = std::min(pts.size(), first + kChunk);
    std::size_t n = 0;
    for (std::size_t i = first; i < last; ++i) {
      const std::size_t wn = wb.node_at(node, pts.xyz.data() + 3 * i, t, "take_owned_verdicts");
      const int b = wb.place[wn];
      theirs[n] = {static_cast<std::uint32_t>(i), static_cast<std::uint32_t>(wn)};
      n += ((b >= 0) & (b != mine)) ? 1U : 0U;
    }
    static const std::uint8_t none = 0;
    for (std::size_t a = 0; a < n; ++a) {
      const auto [i, wn] = theirs[a];
      const double* p = pts.xyz.data() + 3 * static_cast<std::size_t>(i);
      const auto decided = static_cast<std::uint32_t>(p[0] >= dec[0]) & static_cast<std::uint32_t>(p[0] < dec[1]) &
                           static_cast<std::uint32_t>(p[1] >= dec[2]) & static_cast<std::uint32_t>(p[1] < dec[3]);
      const std::uint32_t li = wb.local[wn];
      if (li == kNotInRing) {
        if (decided == 0) continue;  // judged by t, and not in its owner's ring
        throw std::logic_error("take_owned_verdicts: tile " + std::to_string(t) + "'s decided region holds a point of node " +
                               wb.node_text(wn) + ", which its owner does not hold in its ring");
      }
      const OwnedVerdicts& ov = owned[static_cast<std::size_t>(wb.place[wn])];
      const std::size_t at = ov.start.begin(li) + seen[wn]++;
      // Taken where decided (a point past its node's count is named by the count below), without
      // a branch: read at 0 of a byte that is there otherwise.
      const auto take = decided & static_cast<std::uint32_t>(at < ov.start.end(li));
      const std::uint8_t* vn = take != 0 ? ov.vn.data() + at : &none;
      const std::uint8_t code = *vn;
      left[i] = static_cast<std::uint8_t>(decided);
      rv.verdict[i] = take != 0 ? static_cast<std::uint8_t>(code & 15) : rv.verdict[i];
      if (near) rv.near[i] = take != 0 ? static_cast<std::uint8_t>(code >> 4) : rv.near[i];
    }
  }
  for (std::size_t wn = 0; wn < wb.place.size(); ++wn) {
    const int b = wb.place[wn];
    if (b < 0 || b == mine || wb.local[wn] == kNotInRing) continue;
    const OwnedVerdicts& ov = owned[static_cast<std::size_t>(b)];
    const std::size_t held = ov.start.end(wb.local[wn]) - ov.start.begin(wb.local[wn]);
    if (seen[wn] != held) {
      throw std::logic_error("take_owned_verdicts: tile " + std::to_string(t) + "'s window holds " + std::to_string(seen[wn]) +
                             " points on node " + wb.node_text(wn) + ", its owner " + std::to_string(held));
    }
  }
}

// Step 3 for tile t (the file comment of tiling.hpp), the second sweep: its spilled points
// through the filters (the robust test's verdicts from its look, look_tile and judge_strays; in a band, the owners'
// verdicts of the points the look left to them: band_at, owned, take_owned_verdicts) and
// reproject, the interior cut out, which of its spilled records it kept written to `kept`.
// @throws std::logic_error when the window's points are not those the look judged.
TileOutput process_tile(const RunConfig& config, const Plan& plan, const Spill& spill, KeptMask& kept, std::size_t t, TileLook look,
                        const std::vector<int>& band_at, const std::vector<OwnedVerdicts>& owned) {
  const auto t0 = detail::Clock::now();
  const Tiles& tiles = plan.tiles;
  ReprojectOptions ro = config.grid.reproject;
  ro.upsample_factor = tiles.k;
  TileOutput o;
  o.tile = t;
  o.sums = std::move(look.sums);  // the look's times and widening
  const OutlierConfig& oc = config.filters.outliers;
  std::vector<std::uint8_t> flags;
  // Each step's wall time, summed over the tiles as figures `sum_tile_<step>_s`.
  auto lap_at = detail::Clock::now();
  auto lap = [&](const char* step) {
    const auto now = detail::Clock::now();
    o.sums[std::string("tile_") + step + "_s"] += std::chrono::duration<double>(now - lap_at).count();
    lap_at = now;
  };
  Cloud pts = read_tile_points(plan, spill, t, flags);
  o.in = pts.size();
  // Each point's record in the spill, carried through the filters' removals (compose_removal:
  // `removed_at`, the removed columns, increasing), so that the kept-point mask needs no second
  // read of the spill.
  check_window_records(t, flags.size());
  std::vector<std::uint32_t> rec_of;
  rec_of.reserve(pts.size());
  for (std::size_t r = 0; r < flags.size(); ++r) {
    if (plan.far_points == 0 || (flags[r] & kFarFlag) == 0) rec_of.push_back(static_cast<std::uint32_t>(r));
  }
  std::vector<std::uint8_t>().swap(flags);  // not read again
  auto compose_removal = [&](const std::vector<std::size_t>& removed_at) { erase_at(rec_of, removed_at); };
  lap("read");
  // The robust test's sample's spacing (stage tile_scale; 0 without the robust filter): the
  // isolated filter's and the honest check's, as in core.
  const double sample_spacing_m = plan.robust_scale ? plan.robust_scale->spacing_m : 0.0;
  if (config.cross_check.enabled && pts.size() >= 2 && !(sample_spacing_m > 0.0)) {
    // Without it, the honest check's spacing is the tiles' median weighted by points (finish_tiled).
    o.spacing_m = median_point_spacing(pts.xyz, 2.0 * tiles.g.cell_size_m);
    o.spacing_points = pts.size();
  }
  const GridWindow w = tiles.window(t);
  const auto inner = tiles.interior(t);
  // The window holds every point within the halo; the verdicts kept are those of the points
  // the grid stages see from the interior (the halo less the filters' share).
  const RobustOutlierOptions::TileBounds bounds = tile_bounds(tiles, t);
  double spacing_m = 0.0;  // the isolated filter's estimate of the scan's spacing (despike)
  // KeptMask::kNear marks for the honest check: with the whole scan's spacing, which the check
  // takes too, the isolated-point filter's radius is 0.9 × its test's (isolated_filter_radius_m),
  // and a point the filter keeps, or a removed candidate with as many neighbours within that
  // radius, cannot be isolated there (InputCheckScope::near).
  const int iso_min = config.cross_check.honest.isolation_min_neighbours;
  const bool near_marks = config.cross_check.enabled && sample_spacing_m > 0.0;
  bool kept_near = false;                  // the kept points passed the isolated filter at that radius
  std::vector<std::uint32_t> near_records;  // removed candidates' records with those neighbours
  std::vector<std::uint8_t> near_kept;      // the filter's input's RobustVerdicts::near counts (empty: none)
  std::vector<double> gone_m;               // the points removed before the filter, x y z [m]
  // A window of fewer than k + 2 points (a corner of stray returns) cannot be judged by the
  // k-NN tests: its points are kept as they are, counted and noted, not an error.
  const bool judgeable = pts.size() >= static_cast<std::size_t>(oc.k) + 2;
  if (oc.enabled && pts.size() > 0 && !judgeable) o.unjudged = pts.size();
  // The in-core far clusters' cells, collected in every attempt (one that carries them checks
  // that they are still the ones its kept points give).
  const bool link_cells = oc.enabled && oc.method == OutlierMethod::kRobust && oc.far_clusters.enabled && plan.robust_scale.has_value();
  const NodeBinner owner(tiles.g);
  // The owned points' in-core cells (of `kept`: the points the robust test kept, or all of a
  // window too sparse to judge), for the merge (exact_far_clusters).
  const auto collect_link_cells = [&](const Cloud& kept_pts, double link_m) {
    LinkCellTable table(link_m);
    o.link_cells_partial = !table.add_owned(kept_pts.xyz.data(), kept_pts.size(), owner, inner);
    o.link_m = link_m;
    if (!o.link_cells_partial) o.link_cells = table.take();
  };
  if (link_cells && pts.size() > 0 && !judgeable) {
    // Its points are kept untested: their cells go to the merge as kept points' (a stray far
    // from everything, which the in-core run's robust test may keep and its far clusters then
    // remove), and where an attempt carries the far clusters' cells, those in them go.
    const double link_m = far_link_m(oc.far_clusters, robust_global_threshold_m(*plan.robust_scale, tile_robust_options(config, plan, t)));
    collect_link_cells(pts, link_m);
    if (config.scale.far_cells != nullptr) {
      const RemovedPoints gone = in_far_cells(pts, *config.scale.far_cells, link_m, t);
      for (std::size_t i = 0; i < gone.size(); ++i) {
        if (!owner.inside(gone.xyz.data() + 3 * i, inner)) continue;
        o.sums["far_points_owned"] += 1.0;
        o.far_clusters_hit.push_back(gone.cluster[i]);
      }
      if (!gone.at.empty()) o.sums["removed_far_clusters"] += static_cast<double>(gone.size());
      remove_columns(pts, gone.at);
      compose_removal(gone.at);
    }
  }
  if (oc.enabled && judgeable) {
    // The robust test's verdicts, from the look (tile_robust_options), the strays' the whole
    // scan's (judge_strays).
    if (!look.ran || look.points != pts.size() || look.stray_verdict.size() != look.rv.past_halo.size()) {
      throw std::logic_error("process_tile: tile " + std::to_string(t) + ": its look judged " + std::to_string(look.points) +
                             " points (" + (look.ran ? "ran" : "did not run") + ") with " + std::to_string(look.rv.past_halo.size()) +
                             " strays and " + std::to_string(look.stray_verdict.size()) + " stray verdicts; the window holds " +
                             std::to_string(pts.size()));
    }
    RobustVerdicts rv = std::move(look.rv);
    rv.verdict.assign(pts.size(), 0);
    if (look.near) rv.near.assign(pts.size(), 0);
    std::vector<std::uint8_t> left;  // in a band: 1 for the points t left to their owners (take_owned_verdicts)
    if (look.shares) take_owned_verdicts(plan.tiles, t, pts, band_at, owned, look.near, rv, left);
    if (!look.near_nibbles.empty()) {
      // The counts of the points t judged, in column order, unpacked (one spare), then spread
      // over those points without a branch (which points t left follows no order).
      const std::size_t judged = left.empty() ? rv.near.size() : rv.near.size() - static_cast<std::size_t>(std::count(left.begin(), left.end(), std::uint8_t{1}));
      if ((judged + 1) / 2 != look.near_nibbles.size()) {
        throw std::logic_error("process_tile: tile " + std::to_string(t) + ": " + std::to_string(look.near_nibbles.size()) +
                               " bytes of near counts for " + std::to_string(judged) + " points judged");
      }
      if (left.empty()) {
        for (std::size_t i = 0; i < rv.near.size(); ++i) rv.near[i] = static_cast<std::uint8_t>((look.near_nibbles[i / 2] >> (4 * (i % 2))) & 15);
      } else {
        std::vector<std::uint8_t> counts(2 * look.near_nibbles.size() + 1, 0);
        for (std::size_t j = 0; j < 2 * look.near_nibbles.size(); ++j) counts[j] = static_cast<std::uint8_t>((look.near_nibbles[j / 2] >> (4 * (j % 2))) & 15);
        for (std::size_t i = 0, j = 0; i < rv.near.size(); ++i) {
          rv.near[i] = left[i] ? rv.near[i] : counts[j];
          j += left[i] ^ 1U;
        }
      }
      std::vector<std::uint8_t>().swap(look.near_nibbles);
    }
    for (const auto& [c, v] : look.removed) rv.verdict[c] = v;
    for (std::size_t a = 0; a < rv.past_halo.size(); ++a) rv.verdict[rv.past_halo[a]] = look.stray_verdict[a];
    StageResult<Cloud> f1{std::move(pts), std::move(look.report)};
    // The tile's points with the verdicts, and the removal counts of those (the work counts,
    // certified and exact_queries, are the first pass's).
    std::vector<bool> keep(f1.value.size());
    std::array<std::size_t, 5> by{};
    for (std::size_t i = 0; i < keep.size(); ++i) {
      keep[i] = rv.verdict[i] == 0;
      ++by[std::min<std::size_t>(rv.verdict[i], 4)];
    }
    // The kept points' near flags, and the removed points (which may have been some of the
    // neighbours the flags count).
    if (!rv.near.empty()) {
      for (std::size_t i = 0; i < keep.size(); ++i) {
        if (keep[i]) {
          near_kept.push_back(rv.near[i]);
        } else {
          const auto c = f1.value.xyz.col(static_cast<Eigen::Index>(i));
          gone_m.insert(gone_m.end(), {c.x(), c.y(), c.z()});
        }
      }
    }
    f1.value.keep_if(keep);
    f1.report.count_out = f1.value.size();
    // A removed point with the isolated filter's neighbours shown is marked kNear. (Its count is
    // a lower bound from the window that judged it: in a band, another tile's point in t's
    // decided region has its owner's, which can differ from t's own, so that bit of the
    // kept-point mask, a hint to the honest check, depends on the tiles run together.)
    std::vector<std::size_t> robust_removed;
    for (std::size_t i = 0; i < keep.size(); ++i) {
      if (keep[i]) continue;
      robust_removed.push_back(i);
      if (!rv.near.empty() && rv.near[i] >= iso_min) near_records.push_back(rec_of[i]);
    }
    compose_removal(robust_removed);
    {  // the window's verdicts (the look's own counts leave out the strays' and, in a band, the owners')
      detail::set_figure(f1.report, "removed_global", static_cast<double>(by[1]));
      detail::set_figure(f1.report, "removed_local", static_cast<double>(by[2]));
      detail::set_figure(f1.report, "removed_off_surface", static_cast<double>(by[3]));
      detail::set_figure(f1.report, "removed_robust", static_cast<double>(by[1] + by[2] + by[3]));
    }
    // Far clusters among the tile's points, judged against the whole scan's main body and point
    // count, and removed only where the tile holds all of them and every point that could link
    // to them with the whole scan's verdicts (its decided region): a fragment of the object cut
    // off by the window is never far, and no removal rests on the window's edge. Without the
    // whole scan's main body (tile_far_clusters did not run: no robust scale), none are looked for.
    const ScaleConfig::FarCellKeys* carried = config.scale.far_cells.get();
    const double link_m = far_link_m(oc.far_clusters, f1.report);
    if (link_cells) {
      collect_link_cells(f1.value, link_m);
      lap("link_cells");
    }
    FarClusterOptions fco = oc.far_clusters;
    FarClusterScope far_scope;
    if (plan.far_main_box_m) {
      far_scope.main_body_min_m = (*plan.far_main_box_m)[0];
      far_scope.main_body_max_m = (*plan.far_main_box_m)[1];
      far_scope.points = static_cast<std::size_t>(plan.far_size_points);
      far_scope.complete_xy_m = bounds.decides_m;
    } else {
      fco.enabled = false;
    }
    RemovedPoints far_removed;
    if (carried != nullptr && oc.far_clusters.enabled) {
      // The in-core far clusters' cells given (ScaleConfig::far_cells: a tile processed again, or
      // an attempt that carries them): the window's kept points in them go, as the in-core run
      // removes them; no cluster is judged.
      far_removed = in_far_cells(f1.value, *carried, link_m, t);
      remove_columns(f1.value, far_removed.at);
    }
    if (carried != nullptr) fco.enabled = false;
    auto f1f = remove_far_clusters_after(std::move(f1), fco, &far_scope, carried != nullptr ? nullptr : &far_removed);
    if (carried != nullptr) detail::set_figure(f1f.report, "removed_far_clusters", static_cast<double>(far_removed.size()));
    add_figures(o.sums, f1f.report);
    if (!far_removed.at.empty()) {
      // The whole scan's far-cluster figures (the verdict's far_points reason reads them): a
      // window's removals count the halo's copies too, and a cluster two windows hold whole is
      // removed by both. So each removed point is counted by the tile that owns it, and each
      // cluster by the tile that owns its least point (x, then y, then z). Where the tiled
      // scene equals the in-core one, each owner removed its points as the whole scan's
      // cluster (a removal is made only on a whole cluster), so the sums are the in-core counts.
      std::vector<std::array<double, 3>> least;  // per cluster of far_removed.cluster
      double points_owned = 0.0;
      for (std::size_t i = 0; i < far_removed.size(); ++i) {
        const double* p = far_removed.xyz.data() + 3 * i;
        points_owned += owner.inside(p, inner) ? 1.0 : 0.0;
        const std::uint32_t c = far_removed.cluster.at(i);
        if (c >= least.size()) least.resize(c + 1, {std::numeric_limits<double>::infinity(), 0.0, 0.0});
        least[c] = std::min(least[c], std::array<double, 3>{p[0], p[1], p[2]});
      }
      double clusters_owned = 0.0;
      for (const auto& q : least) clusters_owned += owner.inside(q.data(), inner) ? 1.0 : 0.0;
      o.sums["far_points_owned"] += points_owned;
      if (carried == nullptr) {
        o.sums["far_clusters_owned"] += clusters_owned;
      } else {  // the merge counts the carried clusters hit (a cluster may lie in several tiles)
        for (std::size_t i = 0; i < far_removed.size(); ++i) {
          if (owner.inside(far_removed.xyz.data() + 3 * i, inner)) o.far_clusters_hit.push_back(far_removed.cluster[i]);
        }
      }
    }
    compose_removal(far_removed.at);
    if (!near_kept.empty()) {
      erase_at(near_kept, far_removed.at);
      gone_m.insert(gone_m.end(), far_removed.xyz.begin(), far_removed.xyz.end());
    }
    lap("far");
    RemovedPoints isolated;
    // The spacing of the whole scan's robust sample (the plan's RobustScale, the number the
    // in-core run uses), not the window's own estimate.
    HonestCheckOptions isolation = config.cross_check.honest;
    isolation.spacing_m = sample_spacing_m;
    // And its float frame, the in-core run's (RobustScale::centre_m), not the window's median.
    if (plan.robust_scale) isolation.frame_centre_m = plan.robust_scale->centre_m;
    std::vector<std::uint8_t> known_near;
    if (!near_kept.empty()) {
      o.sums["near_lost_to_removals"] += static_cast<double>(near_after_removal(
          f1f.value, near_kept, gone_m, isolated_filter_radius_m(isolation, sample_spacing_m), iso_min, known_near));
    }
    auto f2 = remove_isolated_points(std::move(f1f.value), isolation, &isolated, known_near.empty() ? nullptr : &known_near);
    kept_near = near_marks;
    add_figures(o.sums, f2.report);
    compose_removal(isolated.at);
    spacing_m = detail::figure_of(f2.report, "spacing_mm", 0.0) * 1e-3;
    // A point the tile keeps is kept over the whole scan too (more points, more neighbours); a
    // removed one is removed there too unless its radius reaches past the window.
    check_within_window(tiles, t, bounds, isolated, detail::figure_of(f2.report, "isolation_radius_mm", 0.0) * 1e-3,
                        "isolated", spacing_m, filter_halo_now(config, tiles));
    // Under scale.filter_halo_cells auto the decided region was sized for these radii
    // (auto_filter_shares, at the plan's spacing, which the filters take): a radius past its
    // share would leave a count reading an unchecked verdict, which no window check sees.
    if (tiles.isolated > 0 || tiles.despike > 0) {
      const double cell = tiles.g.cell_size_m;
      const double iso_m = detail::figure_of(f2.report, "isolation_radius_mm", 0.0) * 1e-3;
      const double despike_m = oc.despike ? despike_search_radius_m(cell, static_cast<double>(tiles.k), spacing_m) : 0.0;
      if (iso_m > tiles.isolated * cell * (1.0 + 1e-9) || despike_m > tiles.despike * cell * (1.0 + 1e-9)) {
        throw std::logic_error("process_tile: tile " + std::to_string(t) + ": the isolated filter's radius " + format_number(iso_m * 1e3) +
                               " mm or the despike's " + format_number(despike_m * 1e3) + " mm exceeds the plan's shares (" +
                               std::to_string(tiles.isolated) + " and " + std::to_string(tiles.despike) + " cells of " +
                               format_number(cell * 1e3) + " mm)");
      }
    }
    pts = std::move(f2.value);
    lap("isolated");
  }
  if (oc.enabled) {
    // The box of the owned points kept so far (judged or too sparse to judge): their verdicts are
    // the whole scan's (the decided region holds the interior), so the tiles' boxes merge into
    // the in-core grid's box.
    o.kept_box = owned_box(tiles, inner, pts);
    o.after_box = o.kept_box;
  }
  DepthGrid part;
  if (pts.size() > 0) {
    ReprojectOptions ow = ro;
    ow.window = w;
    auto rp = reproject(pts, ow);
    add_figures(o.sums, rp.report);
    part = std::move(rp.value);
    lap("reproject");
    const ScaleConfig::GridBox* carried = config.scale.grid_box && config.scale.grid_box->despiked_m ? &*config.scale.grid_box : nullptr;
    if (oc.enabled && oc.despike && carried != nullptr) {
      // The grid lies on the box left after an earlier attempt's despike (build_scene_tiled):
      // its removals, made on the grid the in-core despike reads, are taken over, not judged
      // again on this one (the in-core run lays its grid again after its despike, no second one).
      const std::vector<std::array<double, 3>>& gone = *carried->despiked_m;  // sorted
      RemovedPoints removed;
      std::vector<bool> keep(pts.size(), true);
      const NodeBinner node(tiles.g);
      for (std::size_t i = 0; i < pts.size(); ++i) {
        const double* p = pts.xyz.data() + 3 * i;
        const std::array<double, 3> key{p[0], p[1], p[2]};
        if (!std::binary_search(gone.begin(), gone.end(), key)) continue;
        keep[i] = false;
        removed.at.push_back(i);
        removed.xyz.insert(removed.xyz.end(), p, p + 3);
        if (node.inside(p, inner)) o.sums["despike_points_taken_over"] += 1.0;  // each point once, by its owner
      }
      if (removed.size() > 0) {
        pts.keep_if(keep);
        compose_removal(removed.at);
        o.after_box = owned_box(tiles, inner, pts);
        if (pts.size() == 0) {
          part = DepthGrid();
        } else {
          part = reproject_after_removal(pts, removed, StageResult<DepthGrid>{std::move(part), rp.report}, ow).value;
        }
      }
      lap("despike");
    } else if (oc.enabled && oc.despike) {
      const std::size_t before_n = pts.size();
      RemovedPoints removed;
      // Every group of at most island_max_cells cells is an island, even the window's largest
      // (the whole grid's is larger where some window shows one: finish_tiled warns otherwise).
      HonestCheckOptions despike_options = config.cross_check.honest;
      despike_options.spare_largest_group = false;
      auto ds = remove_spike_points(std::move(pts), part.depth, despike_options, despike_reach_cells(config, tiles.k),
                                    std::isfinite(spacing_m) ? spacing_m : 0.0, tiles.k, &removed, &w);
      add_figures(o.sums, ds.report);
      const int reach = grid_reach_cells(config, tiles.k);  // R [nodes]
      // The island labels the despike reads, of the cells within R + ⌈reach⌉ of the interior
      // (the candidates of the points within R, and the spike cells it skips as islands), are
      // the whole grid's where their group lies inside the region whose cells are (the decided
      // region less R) without touching its edge, or is larger than island_max_cells there.
      {
        const int e = std::max(0, tiles.halo - tiles.filter - reach);
        const int need = reach + static_cast<int>(std::ceil(despike_reach_cells(config, tiles.k)));
        const auto clip = [&](int grow) -> std::array<int, 4> {
          return {std::max(0, inner[0] - grow - w.row0), std::min(w.rows, inner[1] + grow - w.row0),
                  std::max(0, inner[2] - grow - w.col0), std::min(w.cols, inner[3] + grow - w.col0)};
        };
        if (e < need) {  // the grid share (2R + D, D ≥ ⌈reach⌉) holds the labels read
          throw std::logic_error("process_tile: tile " + std::to_string(t) + ": the window's cells are the whole grid's within " +
                                 std::to_string(e) + " nodes of the interior, the despike reads island labels within " +
                                 std::to_string(need));
        }
        const std::array<int, 4> exact = clip(e), needed = clip(need);
        const std::array<bool, 4> open = {w.row0 + exact[0] > 0, w.row0 + exact[1] < tiles.g.rows, w.col0 + exact[2] > 0,
                                          w.col0 + exact[3] < tiles.g.cols};
        const WindowIslands wi = window_islands(part.depth, despike_options.island_max_cells, exact, needed, open);
        if (wi.undecided_groups > 0) {
          RunConfig wider = config;
          wider.scale.island_halo = ScaleConfig::Tiled::kOn;
          const int now = tiles.halo, then = tile_halo(wider, tiles.k, tiles.filter, tiles.despike, tiles.isolated);
          throw UndecidedIslandsError("tiled run, tile " + std::to_string(t) + ": stage despike: " + std::to_string(wi.undecided_groups) +
                            " group(s) of at most cross_check.island_max_cells = " + std::to_string(despike_options.island_max_cells) +
                            " valid cells near the tile's interior, the first at grid cell (" +
                            std::to_string(wi.first_undecided[0] + w.row0) + ", " + std::to_string(wi.first_undecided[1] + w.col0) +
                            "), run on past the cells its window has as the whole grid does, so the window cannot tell whether "
                            "the despike judges them as islands: set scale.island_halo: true (a halo of " + std::to_string(then) +
                            " nodes instead of " + std::to_string(now) +
                            " at this filter share; under auto only the in-process run widens it itself, a tile job keeps its "
                            "plan's), lower cross_check.island_max_cells (which changes the in-core run's islands "
                            "too), or run in core (scale.tiled: off)",
                            t, now, then, config.scale.island_halo == ScaleConfig::Tiled::kAuto);
        }
        o.sums["tiles_with_a_group_past_island_max_cells"] +=
            wi.largest_exact_group > static_cast<std::size_t>(despike_options.island_max_cells) ? 1.0 : 0.0;
      }
      compose_removal(removed.at);
      {
        const NodeBinner node(tiles.g);
        for (std::size_t j = 0; j < removed.size(); ++j) {
          const double* p = removed.xyz.data() + 3 * j;
          if (node.inside(p, inner)) o.despiked_m.push_back({p[0], p[1], p[2]});
        }
      }
      // The despike's 3-D count searches at most max(4 scan cells, 4 spacings) about a point;
      // its verdicts are needed within the grid stages' reach of the interior (tile_halo). (The
      // honest check's confirmations read kept points within its tolerance, spike height or
      // splat footprint of an interior cell, which can lie past that reach: their despike
      // verdicts are this window's, never checked as the whole scan's; before 2026-11-29 this
      // check ran to the grid share, whose verdicts were not the whole scan's either.)
      RobustOutlierOptions::TileBounds despike_bounds = bounds;
      despike_bounds.decides_m = tiles.box_m(inner[0] - reach, inner[1] + reach, inner[2] - reach, inner[3] + reach);
      check_within_window(tiles, t, despike_bounds, removed,
                          despike_search_radius_m(tiles.g.cell_size_m, static_cast<double>(tiles.k), spacing_m), "despike",
                          spacing_m, filter_halo_now(config, tiles));
      pts = std::move(ds.value);
      if (!o.despiked_m.empty()) o.after_box = owned_box(tiles, inner, pts);  // an owned point gone
      if (pts.size() == 0) {
        part = DepthGrid();  // nothing left: the tile's cells stay no data
      } else if (pts.size() < before_n) {
        // Made again only about the removed points (the window's grid bit for bit).
        part = reproject_after_removal(pts, removed, StageResult<DepthGrid>{std::move(part), rp.report}, ow).value;
      }
      lap("despike");
    }
  }
  if (part.depth.rows() > 0) {
    // The interior, cut out of the window.
    const GridGeometry ig = tiles.part(inner[0], inner[2], inner[1] - inner[0], inner[3] - inner[2]);
    DepthGrid& in = o.interior;
    in.depth = HeightField(ig);
    in.flags.assign(ig.cell_count(), kCellEmpty);
    if (part.has_colour()) in.colour_rgb8.assign(3 * ig.cell_count(), 0);
    if (part.has_intensity()) in.intensity = HeightField(ig);
    const std::size_t wc = static_cast<std::size_t>(w.cols);
    for (int r = 0; r < ig.rows; ++r) {
      for (int c = 0; c < ig.cols; ++c) {
        const std::size_t i = static_cast<std::size_t>(r + inner[0] - w.row0) * wc + static_cast<std::size_t>(c + inner[2] - w.col0);
        const std::size_t j = static_cast<std::size_t>(r) * static_cast<std::size_t>(ig.cols) + static_cast<std::size_t>(c);
        in.depth.data()[j] = part.depth.data()[i];
        in.flags[j] = part.flags[i];
        if (part.has_colour()) std::memcpy(in.colour_rgb8.data() + 3 * j, part.colour_rgb8.data() + 3 * i, 3);
        if (part.has_intensity()) in.intensity.data()[j] = part.intensity.data()[i];
      }
    }
  }
  // The kept points' records in the spill, each marked interior or halo (the levels sample from
  // the interior), by the record numbers carried through the removals. (Until 2026-11-26 the
  // kept points were matched back to the spill's records in one more read of it: the first
  // record equal in every byte to the next kept point.)
  const NodeBinner node(tiles.g);
  std::vector<std::uint8_t> mask(spill.records(t), KeptMask::kNotKept);
  if (rec_of.size() != pts.size()) {
    throw std::logic_error("process_tile: tile " + std::to_string(t) + ": " + std::to_string(rec_of.size()) +
                           " record numbers for " + std::to_string(pts.size()) + " kept points");
  }
  for (std::size_t j = 0; j < pts.size(); ++j) {
    const bool interior = node.inside(pts.xyz.data() + 3 * j, inner);
    o.out += interior ? 1U : 0U;
    mask[rec_of[j]] = static_cast<std::uint8_t>((interior ? KeptMask::kInterior : KeptMask::kHalo) | (kept_near ? KeptMask::kNear : 0));
  }
  for (const std::uint32_t r : near_records) mask[r] |= KeptMask::kNear;
  kept.write(t, mask);
  o.kept_bytes = kept.bytes(t);
  lap("mask");
  o.seconds = detail::seconds_since(t0);
  return o;
}

// Step 3 over the tiles `list` (ascending, each once), in bands of consecutive tiles: each
// band's first sweep (look_tile) until its looks hold scale.band_mb MiB or more (TileLook::bytes:
// half a byte a window point and the removed points' verdicts; at 10^8 points, 144 M window
// points, one band of the default 128 MiB, at 10^9 about six; where tiles share their points'
// judging, the band's tiles are chosen before their looks, from an estimate of those bytes),
// its strays judged
// (judge_strays, whose band figures go to the band's first tile), then its second sweep
// (process_tile), done(TileOutput, last) called for each tile in order (last: no later band
// gathers points, so no spill is read again by the loop). heap.before_tile() is called before
// each tile of either sweep; with more than one band, heap.release_now() before a gathering (a
// band with strays) and before each band's first sweep but the first's: there the fragments
// the budget lets the tiles keep served the next step poorly (at 10⁹ points, 6–7 bands, a
// gathering took RSS from 780 MB to 1.2 GB, a band's first look from 633 MB to 1.04 GB); and
// from the first band's gathering on, blocks of 8 MiB or more are mapped on their own
// (detail::LargeBlocksMapped: the 10⁹ tile loop 1 084 → 893 MB, its CPU 6 % less); `verdicts`
// as judge_strays (the in-process loop records, its far clusters' fix-up takes); `looks_kept`
// (may be null): the loop keeps its looks there (KeptLooks::wants, keep), the fix-up takes
// them instead of calling look_tile (a tile with one shares with no other tile of its band). One band
// (the 10⁸ wall) keeps its fragments: its one gathering (0.8 M points there) stayed under its
// tiles' peak, and a release would make the second sweep fault its windows in again
// (docs/scale.md, thirty-ninth and fortieth sessions). progress(fraction) is called with the
// share of both sweeps done. @return whether large blocks were mapped on their own
// (LargeBlocksMapped acted: several bands under hc::pipeline::keep_freed_heap_for_reuse's
// policy, figure `large_blocks_mapped` of `tiles`).
template <class Done>
bool run_tiles(const RunConfig& config, const Plan& plan, const Spill& spill, KeptMask& kept, const std::vector<std::size_t>& list,
               detail::TileHeapBudget& heap, const std::function<void(double)>& progress, Done&& done, StrayVerdicts* verdicts = nullptr,
               KeptLooks* looks_kept = nullptr) {
  const auto band_bytes = static_cast<std::size_t>(config.scale.band_mb * 1048576.0);
  const double steps = 2.0 * static_cast<double>(list.size());
  double step = 0.0;
  // With more than one band, from the first band's gathering on: blocks of 8 MiB or more (a
  // window's per-point arrays) mapped on their own (LargeBlocksMapped).
  constexpr std::size_t kMappedBlockBytes = std::size_t{8} << 20;
  std::optional<detail::LargeBlocksMapped> mapped;
  // Where tiles share: what a tile's look will hold [bytes], estimated from its window's
  // records before it is looked at (a band's tiles are chosen first: each look must know which
  // tiles share its band): the near counts, half a byte a point it judges (when asked), the
  // removed points' verdicts, and a byte a point of its ring (OwnedVerdicts), with the points
  // spread evenly over the nodes (judged: the window's less the other tiles' in its decided
  // region; the ring's: the points per record over all windows, of the interior's share that is
  // ring). The strays' balls are left out. Where tiles do not share, a band closes on its looks'
  // own bytes (TileLook::bytes), as before the fiftieth session.
  std::uintmax_t records = 0;
  for (std::size_t t = 0; t < plan.tiles.count(); ++t) records += spill.records(t);
  const double owned_per_record = records > 0 ? std::min(1.0, static_cast<double>(plan.grid_points) / static_cast<double>(records)) : 1.0;
  const bool near_asked = plan.robust_scale && tile_robust_options(config, plan, 0).near_radius_m > 0.0;
  // Whether the band's tiles leave to their owners the points other tiles own in their decided
  // regions (look_tile): where those are a fair part of a window. The share of a whole tile's
  // window they take, by nodes: on the 10^8 wall at N = 800 (78-node tiles, an 11-node reach
  // in a 17-node halo) 31 %, which spares 29 % of the first look's exact queries and about
  // 6 % of the run's CPU; at N = 4096 (512-node tiles) 6 %, where the bookkeeping (the mask,
  // the owners' rings, the lookups) cost more than it spared (4.6 % more CPU in three
  // alternated rounds; fiftieth session). The decided region is the halo's grid share
  // (grid_share_cells): 12 nodes with the despike on at the shipped splats since the fifty-first
  // session (76-node tiles at N = 800: 34 %), 4 with it off (92-node tiles: 12 %, no sharing);
  // since the fifty-second, under scale.filter_halo_cells auto, the halo less its 2-node filter
  // band, 13 of 15 nodes (82-node tiles at N = 800: 39 %).
  constexpr double kShareAtLeast = 0.15;
  const double share = [&] {
    const Tiles& tiles = plan.tiles;
    const double side = tiles.size, reach = std::max(0, tiles.halo - tiles.filter), halo = tiles.halo;
    return ((side + 2 * reach) * (side + 2 * reach) - side * side) / ((side + 2 * halo) * (side + 2 * halo));
  }();
  const bool sharing = share >= kShareAtLeast;
  const auto look_bytes = [&](std::size_t t) {
    const Tiles& tiles = plan.tiles;
    const auto in = tiles.interior(t);
    const GridWindow w = tiles.window(t);
    const int reach = std::max(0, tiles.halo - tiles.filter);
    const auto nodes = [&](int r0, int r1, int c0, int c1) {
      return static_cast<double>(std::max(0, std::min(r1, tiles.g.rows) - std::max(r0, 0))) *
             static_cast<double>(std::max(0, std::min(c1, tiles.g.cols) - std::max(c0, 0)));
    };
    const double interior = nodes(in[0], in[1], in[2], in[3]);
    const double decided = nodes(in[0] - reach, in[1] + reach, in[2] - reach, in[3] + reach);
    const double window = static_cast<double>(w.rows) * static_cast<double>(w.cols);
    std::size_t ring = 0;
    (void)ring_index(in, owned_ring(tiles), in[0], in[2], &ring);
    const double rec = static_cast<double>(spill.records(t));
    const double judged = window > 0.0 ? 1.0 - (decided - interior) / window : 1.0;
    // The removed points' verdicts (8 bytes each) at 0.5 % of the points judged, so that the
    // estimate grows without the near counts too. The ring's starts (RingStarts): 0.19 bytes a
    // node and 4 a node with points, at most one a ring point (left out before the sixty-ninth
    // session, when they were 4 bytes a node: a band of 512 tiles then held 470 MB of them at
    // N = 16384 where this estimate said a few MB).
    const double ring_points = interior > 0.0 ? rec * owned_per_record * static_cast<double>(ring) / interior : 0.0;
    return (near_asked ? 0.5 * rec * judged : 0.0) + 0.04 * rec * judged + ring_points +
           0.1875 * static_cast<double>(ring) + 4.0 * std::min(static_cast<double>(ring), ring_points);
  };
  std::vector<int> band_at(plan.tiles.count(), -1);  // each tile's place in the band, -1 outside
  for (std::size_t first = 0; first < list.size();) {
    std::vector<std::size_t> band;
    std::vector<TileLook> looks;
    // Where looks_kept is given: each look's figures as look_tile gave them, before judge_strays
    // adds to them (none for a look taken from looks_kept, or one that shares).
    std::vector<std::optional<std::map<std::string, double>>> look_sums;
    // Tile t's look: its kept one (the fix-up), else look_tile's, with look_sums in step.
    const auto add_look = [&](std::size_t t) {
      std::optional<TileLook> again = looks_kept != nullptr ? looks_kept->take(t) : std::nullopt;
      looks.push_back(again ? std::move(*again) : look_tile(config, plan, spill, t, band_at));
      const bool keepable = looks_kept != nullptr && !again && !looks.back().shares;
      look_sums.push_back(keepable ? std::optional(looks.back().sums) : std::nullopt);
    };
    if (first > 0) (void)heap.release_now();
    double held = 0.0;
    while (first + band.size() < list.size() && (band.empty() || held < static_cast<double>(band_bytes))) {
      const std::size_t t = list[first + band.size()];
      if (!sharing) {  // the looks' own bytes, as before the fiftieth session
        progress(step++ / steps);
        (void)heap.before_tile();
        add_look(t);
        held += static_cast<double>(looks.back().bytes());
        band.push_back(t);
        continue;
      }
      held += look_bytes(t);
      // A tile whose first look is kept (the fix-up) does not share: its look was made alone.
      const bool alone = looks_kept != nullptr && looks_kept->has(t);
      // A tile whose window could fall short of the robust test's k + 2 points (all the far
      // points in it, which read_tile_points leaves out) neither shares its points' judging nor
      // leaves its points to others: every tile that holds them judges them, as before.
      const std::uint64_t least = static_cast<std::uint64_t>(config.filters.outliers.k) + 2 + plan.far_points;
      if (config.filters.outliers.enabled && plan.robust_scale && spill.records(t) >= least && !alone) band_at[t] = static_cast<int>(band.size());
      band.push_back(t);
    }
    for (std::size_t i = looks.size(); i < band.size(); ++i) {
      progress(step++ / steps);
      (void)heap.before_tile();
      add_look(band[i]);
    }
    std::map<std::string, double> band_sums;
    const bool one_band = first == 0 && band.size() == list.size();
    if (!one_band) {
      if (!mapped) mapped.emplace(kMappedBlockBytes);
      if (std::any_of(looks.begin(), looks.end(), [](const TileLook& L) { return !L.rv.past_halo.empty(); })) (void)heap.release_now();
    }
    judge_strays(config, plan, spill, band, looks, band_sums, verdicts);
    for (const auto& [k, v] : band_sums) looks.front().sums[k] += v;
    // The owned strays' whole-scan verdicts into the owners' OwnedVerdicts, which then leave the
    // looks (the other tiles of the band take from them).
    std::vector<OwnedVerdicts> owned(band.size());
    for (std::size_t i = 0; i < band.size(); ++i) {
      TileLook& L = looks[i];
      for (const auto& [at, a] : L.owned.strays) {
        L.owned.vn[at] = static_cast<std::uint8_t>((L.owned.vn[at] & 0xF0) | L.stray_verdict[a]);
      }
      L.owned.strays.clear();
      owned[i] = std::move(L.owned);
    }
    first += band.size();
    const bool last = first == list.size();
    for (std::size_t i = 0; i < band.size(); ++i) {
      progress(step++ / steps);
      (void)heap.before_tile();
      if (look_sums[i] && looks_kept->wants(band[i], looks[i])) {
        // process_tile takes a copy; looks_kept the look as look_tile gave it (judge_strays'
        // verdicts and figures taken off again: the fix-up's judge_strays gives them anew).
        TileLook copy = looks[i];
        looks[i].sums = std::move(*look_sums[i]);
        looks[i].stray_verdict.clear();
        looks_kept->keep(band[i], std::move(looks[i]));
        done(process_tile(config, plan, spill, kept, band[i], std::move(copy), band_at, owned), last);
      } else {
        done(process_tile(config, plan, spill, kept, band[i], std::move(looks[i]), band_at, owned), last);
      }
      looks[i] = TileLook{};  // its memory back
    }
    for (const std::size_t t : band) band_at[t] = -1;
  }
  return mapped && mapped->active();
}

// A grid layer of level 0 (no data everywhere) as scale.level0_file asks: in a mapping of a
// file in `dir` (HeightField's file-backed constructor; ResourceError naming `dir` where it
// cannot be made), or on the heap.
HeightField level0_layer(const RunConfig& config, const GridGeometry& g, const fs::path& dir, const std::string& what) {
  return config.scale.level0_file ? HeightField(g, kNoData, dir, what) : HeightField(g);
}

// The same for a layer of `n` bytes of `fill` (the flags, the colour).
CellBuffer<std::uint8_t> level0_bytes(const RunConfig& config, std::size_t n, std::uint8_t fill, const fs::path& dir, const std::string& what) {
  return config.scale.level0_file ? CellBuffer<std::uint8_t>(dir, n, fill, what) : CellBuffer<std::uint8_t>(n, fill);
}

// The tiles' results gathered: the whole grid's cells, the summed figures, the levels sample.
struct TileMerge {
  DepthGrid grid;
  // The totals over the tiles, in tile order (finish(), from `parts`):
  std::map<std::string, double> sums;
  std::uint64_t in = 0, out = 0, unjudged = 0;
  std::vector<std::pair<double, std::uint64_t>> spacings;  // each tile's spacing [m] and weight
  double job_seconds = 0.0;
  XyBox kept_box, after_box;  // over the tiles (TileOutput::kept_box, after_box)
  std::vector<std::array<double, 3>> despiked_m;  // TileOutput::despiked_m of every tile
  std::set<std::uint32_t> far_clusters_hit;       // TileOutput::far_clusters_hit of every tile
  int factor_reads = 0;        // reads of the kept points for grid.upsample: auto (grid_on_kept_points)
  // The in-core run's far clusters, joined from the tiles' link cells in tile order
  // (TileOutput::link_cells; exact_far_clusters reads them, then they take no more tiles); none
  // when no tile sent cells.
  std::optional<FarCells> link_cells;
  double link_m = 0.0;
  bool link_cells_partial = false, link_cells_joined = false;
  std::uint64_t far_small_points = 0;  // the far clusters' size limit (FarClusterOptions), N the plan's
  // Each tile's output but its interior and link cells (in the grid and link_cells): the totals
  // are made from them, so that a tile processed again (the far clusters' fix-up) replaces its
  // figures. A few kB a tile.
  std::vector<TileOutput> parts;

  // Level 0 (`grid`) of the plan's grid; its layers in mappings of files in `layer_dir` under
  // scale.level0_file (level0_layer, level0_bytes).
  TileMerge(const RunConfig& config, const Plan& plan, const fs::path& layer_dir) : parts(plan.tiles.count()) {
    const FarClusterOptions& fco = config.filters.outliers.far_clusters;
    far_small_points = std::max<std::uint64_t>(fco.max_points, static_cast<std::uint64_t>(fco.max_fraction * static_cast<double>(plan.far_size_points)));
    const GridGeometry& g = plan.tiles.g;
    grid.depth = level0_layer(config, g, layer_dir, "level 0's depth");
    grid.flags = level0_bytes(config, g.cell_count(), kCellEmpty, layer_dir, "level 0's flags");
    if (plan.layout.rgb) grid.colour_rgb8 = level0_bytes(config, 3 * g.cell_count(), 0, layer_dir, "level 0's colour");
    if (plan.layout.intensity) grid.intensity = level0_layer(config, g, layer_dir, "level 0's intensity");
  }

  // Tile o.tile's output: its interior into the grid, its link cells into link_cells (tiles in
  // order, until exact_far_clusters joins them), the rest kept for finish(). A tile given again
  // replaces the one before.
  void add(const Tiles& tiles, TileOutput&& o) {
    const auto inner = tiles.interior(o.tile);
    const DepthGrid& part = o.interior;
    if (part.depth.rows() > 0) {
      const std::size_t pc = static_cast<std::size_t>(part.depth.cols()), gc = static_cast<std::size_t>(tiles.g.cols);
      for (int r = inner[0]; r < inner[1]; ++r) {
        for (int c = inner[2]; c < inner[3]; ++c) {
          const std::size_t i = static_cast<std::size_t>(r - inner[0]) * pc + static_cast<std::size_t>(c - inner[2]);
          const std::size_t j = static_cast<std::size_t>(r) * gc + static_cast<std::size_t>(c);
          grid.depth.data()[j] = part.depth.data()[i];
          grid.flags[j] = part.flags[i];
          if (part.has_colour() && grid.has_colour()) std::memcpy(grid.colour_rgb8.data() + 3 * j, part.colour_rgb8.data() + 3 * i, 3);
          if (part.has_intensity() && grid.has_intensity()) grid.intensity.data()[j] = part.intensity.data()[i];
        }
      }
    } else {  // an interior left empty (again: a tile processed again may lose its last point)
      const std::size_t gc = static_cast<std::size_t>(tiles.g.cols);
      for (int r = inner[0]; r < inner[1]; ++r) {
        for (int c = inner[2]; c < inner[3]; ++c) {
          const std::size_t j = static_cast<std::size_t>(r) * gc + static_cast<std::size_t>(c);
          grid.depth.data()[j] = kNoData;
          grid.flags[j] = kCellEmpty;
          if (grid.has_colour()) std::memset(grid.colour_rgb8.data() + 3 * j, 0, 3);
          if (grid.has_intensity()) grid.intensity.data()[j] = kNoData;
        }
      }
    }
    o.interior = DepthGrid{};
    grid.release_resident();  // the tile's rows written: the page cache holds them (scale.level0_file)
    if (!link_cells_joined) {
      link_cells_partial = link_cells_partial || o.link_cells_partial;
      if (!link_cells_partial && !o.link_cells.empty()) {
        if (!link_cells) {
          link_m = o.link_m;
          link_cells.emplace(Eigen::Vector3d::Zero(), link_m, far_small_points);
        }
        if (o.link_m != link_m) {
          throw std::logic_error("TileMerge: tile " + std::to_string(o.tile) + " linked its far-cluster cells at " + format_number(o.link_m * 1e3) +
                                 " mm, an earlier tile at " + format_number(link_m * 1e3) + " mm");
        }
        link_cells->begin_tile(static_cast<int>(o.tile / static_cast<std::size_t>(tiles.tiles_c)));
        for (const TileOutput::LinkCell& c : o.link_cells) link_cells->add_cell(c.key, static_cast<std::uint32_t>(c.count), c.lo, c.hi);
        link_cells->end_tile();
      }
    }
    std::vector<TileOutput::LinkCell>().swap(o.link_cells);
    const std::size_t t = o.tile;
    parts.at(t) = std::move(o);
  }

  // The totals from the parts, in tile order (after the loop, and again after a fix-up).
  void finish() {
    sums.clear();
    in = out = unjudged = 0;
    spacings.clear();
    job_seconds = 0.0;
    kept_box = after_box = XyBox{};
    despiked_m.clear();
    far_clusters_hit.clear();
    for (const TileOutput& o : parts) {
      for (const auto& [name, v] : o.sums) sums[name] += v;
      in += o.in;
      out += o.out;
      unjudged += o.unjudged;
      if (o.spacing_m > 0.0 && o.spacing_points > 0) spacings.emplace_back(o.spacing_m, o.spacing_points);
      job_seconds += o.seconds;
      kept_box.merge(o.kept_box);
      after_box.merge(o.after_box);
      despiked_m.insert(despiked_m.end(), o.despiked_m.begin(), o.despiked_m.end());
      far_clusters_hit.insert(o.far_clusters_hit.begin(), o.far_clusters_hit.end());
    }
    // The given clusters the tiles processed with ScaleConfig::far_cells hit (those tiles count
    // none of their own: the far step is off there, and a tile that removed a far cluster itself
    // holds its cells, so it is among them): the whole count, in process, carried, and in a
    // merge of parts a fix-up wrote (format 6).
    if (!far_clusters_hit.empty()) sums["far_clusters_owned"] += static_cast<double>(far_clusters_hit.size());
  }

  // The "tiles" stage's figures and notes.
  void report(const RunConfig& config, StageReport& r) const {
    r.count_in = in;
    r.count_out = out;
    for (const auto& [name, v] : sums) r.figure("sum_" + name, v);
    r.figure("points_in_windows_too_sparse_to_filter", static_cast<double>(unjudged));
    if (unjudged > 0) {
      r.notes.push_back(std::to_string(unjudged) + " points (halo copies included) lay in tile windows of fewer than "
                        "k + 2 points: kept unfiltered");
    }
    r.notes.push_back(config.filters.outliers.enabled
                          ? "filters.outliers (robust) ran per tile with the whole scan's scale (stage tile_scale); far "
                            "clusters and the isolated-point filter are judged per tile (docs/scale.md)"
                          : "no point filter: every tile's interior equals the in-core grid's");
  }
};

// The tiles whose windows may hold a point in one of the cells `far` lists (each cell's x-y
// extent from its key, a link wider each way, taken to nodes; tiles_of gives the windows that
// hold a node, as the spill writes them): in tile order.
std::vector<std::size_t> tiles_holding(const Tiles& tiles, const ScaleConfig::FarCellKeys& far) {
  const NodeBinner node(tiles.g);
  std::vector<char> hit(tiles.count(), 0);
  constexpr std::int64_t kShift = std::int64_t{1} << 20, kMask = (std::int64_t{1} << 21) - 1;
  for (const std::uint64_t key : far.keys) {
    const auto ix = static_cast<std::int64_t>(key >> 42) - kShift;
    const auto iy = (static_cast<std::int64_t>(key >> 21) & kMask) - kShift;
    const double lo[3] = {static_cast<double>(ix - 1) * far.link_m, static_cast<double>(iy - 1) * far.link_m, 0.0};
    const double hi[3] = {static_cast<double>(ix + 2) * far.link_m, static_cast<double>(iy + 2) * far.link_m, 0.0};
    const auto a = tiles_of(tiles, node.row(lo), node.col(lo)), b = tiles_of(tiles, node.row(hi), node.col(hi));
    for (int tr = a[0]; tr <= b[1]; ++tr) {
      for (int tc = a[2]; tc <= b[3]; ++tc) hit[static_cast<std::size_t>(tr) * static_cast<std::size_t>(tiles.tiles_c) + static_cast<std::size_t>(tc)] = 1;
    }
  }
  std::vector<std::size_t> list;
  for (std::size_t t = 0; t < hit.size(); ++t) {
    if (hit[t] != 0) list.push_back(t);
  }
  return list;
}

// After the tile loop (in process, and at tile-merge): the in-core run's far clusters among the
// points the tiles' robust test kept, joined from the tiles' link cells (TileMerge::link_cells;
// the in-core cells, linking distance, far distance and size limit, so the in-core components,
// but for a tie of the largest two), against the points the tiles removed as far (the owners'
// sum far_points_owned). The tiles judge far clusters only against the coarse whole-scan pass's
// main body, and only where a window holds them whole, so they remove a part of the in-core
// run's (docs/scale.md, "Far clusters exact"). Returns the cells of the in-core clusters where
// the tiles fell short (the tiles holding them are then processed again with them, or where the
// spills are gone the run starts again carrying them: ScaleConfig::far_cells), else
// nullptr. With cells carried, the tiles removed the points in them: this checks that the cells
// found now are the same (another attempt's grid moves the whole-scan pass's coarse cells, and
// with them the points that pass leaves), returns the new ones where they are not (unless the
// carried ones are the last: a warning), and counts the carried clusters the owners hit.
// Figures on `r` (stage tiles): exact_far_checked (1 when compared), exact_far_points,
// exact_far_clusters, link_cells.
std::shared_ptr<const ScaleConfig::FarCellKeys> exact_far_clusters(const RunConfig& config, const Plan& plan, TileMerge& merged,
                                                                   StageReport& r) {
  const ScaleConfig::FarCellKeys* carried = config.scale.far_cells.get();
  const auto it = merged.sums.find("far_points_owned");
  const double tiles_far = it != merged.sums.end() ? it->second : 0.0;
  if (carried != nullptr) {  // the clusters the owners hit are counted by TileMerge::finish
    r.notes.push_back("far clusters: the tiles removed the kept points in the " + std::to_string(carried->keys.size()) + " cells of " +
                      std::to_string(carried->clusters) + " far clusters (" + std::to_string(carried->points) +
                      " points) found by the attempt before from every tile's kept points");
    for (const std::string& n : carried->notes) r.notes.push_back(n);
  }
  const auto unchecked = [&](const std::string& why) {
    r.figure("exact_far_checked", 0.0);
    r.notes.push_back("far clusters: not compared with the whole scan's (" + why + ")");
    return nullptr;
  };
  if (!merged.link_cells) return nullptr;  // no tile sent cells: no far step, or no kept point
  if (merged.link_cells_partial) return unchecked("a point lies more than 2^20 linking distances from the frame's centre");
  const FarClusterOptions& fco = config.filters.outliers.far_clusters;
  const double far_m = fco.far_distance_m > 0.0 ? fco.far_distance_m : 10.0 * merged.link_m;
  const FarCells::Result fc = merged.link_cells->components(far_m);
  merged.link_cells_joined = true;
  // The in-core cells' edge is the link unless the robust test's kept points span more than
  // 2 097 150 links on an axis (robust_outliers.cpp, far_clusters_impl). Those the tiles kept,
  // and the whole scan's extent (plan.far_extent_m: the whole-scan pass's points too), must not.
  if (std::max((fc.box_hi - fc.box_lo).maxCoeff(), plan.far_extent_m) / 2097150.0 > merged.link_m) {
    return unchecked("the scan spans more than 2 097 150 linking distances, where the in-core cells may be wider than the link");
  }
  r.figure("exact_far_checked", 1.0);
  r.figure("exact_far_points", static_cast<double>(fc.removed_points));
  r.figure("exact_far_clusters", static_cast<double>(fc.removed_clusters));
  r.figure("link_cells", static_cast<double>(fc.cells));
  FarCells::FarCellList list = merged.link_cells->far_cells();
  const auto found = [&] {
    auto k = std::make_shared<ScaleConfig::FarCellKeys>();
    k->link_m = merged.link_m;
    k->keys = std::move(list.keys);
    k->cluster = std::move(list.cluster);
    k->points = fc.removed_points;
    k->clusters = fc.removed_clusters;
    k->notes = fc.notes;
    return k;
  };
  if (carried != nullptr) {
    if (list.keys == carried->keys) return nullptr;
    if (!carried->last) return found();
    r.notes.push_back("warning: the far clusters of the points the tiles kept (" + std::to_string(fc.removed_points) + " points in " +
                      std::to_string(fc.removed_clusters) + " clusters) are not the carried ones, which the tiles removed (" +
                      std::to_string(carried->points) + " points in " + std::to_string(carried->clusters) + ")");
    return nullptr;
  }
  if (static_cast<double>(fc.removed_points) > tiles_far) return found();
  if (static_cast<double>(fc.removed_points) < tiles_far) {  // the tiles' removals are a part of the in-core ones
    r.notes.push_back("warning: the tiles removed " + format_number(tiles_far) + " points as far, the whole scan's far clusters hold " +
                      std::to_string(fc.removed_points));
  }
  return nullptr;
}

// Throws the error naming `stage` and scale.filter_halo_cells when the tiles' halo is narrower
// than the honest check's reach at `spacing_m` (`spacing_what` says where that spacing comes
// from), with the least value whose halo holds the reach.
void check_honest_halo(const RunConfig& config, const Tiles& tiles, const HonestCheckOptions& options, double spacing_m,
                       const char* stage, const std::string& spacing_what) {
  const double reach_m = honest_reach_m(options, spacing_m);
  const double cell_m = tiles.g.cell_size_m;
  const double halo_m = tiles.halo * cell_m;
  if (!(halo_m < reach_m)) return;
  // The least scale.filter_halo_cells whose halo (rounded up to a multiple of the upsample
  // factor) holds the reach, if the key's range has one: a fixed value, so without auto's
  // shares (tile_halo), which the user's value replaces.
  const int needed = least_fixed_filter_cells(config, tiles.k, [&](int halo) { return halo * cell_m >= reach_m; });
  throw ConfigError(
      std::string("tiled run, stage ") + stage + ": the tiles' halo (" + format_number(halo_m * 1e3) + " mm, " +
      std::to_string(tiles.halo) + " cells) is narrower than the point test's and spike searches' reach (" +
      format_number(reach_m * 1e3) + " mm: cross_check.isolation_radius_spacings " + format_number(options.isolation_radius_spacings) +
      " x the scan's spacing " + format_number(spacing_m * 1e3) + " mm (" + spacing_what +
      "), plus the largest of the tolerance, the spike height and the confirmation footprint), so points near a "
      "tile's edge would be judged without all their neighbours: " +
      (needed > 0 ? "raise scale.filter_halo_cells (now " + filter_halo_now(config, tiles) + ") to at least " +
                        std::to_string(needed)
                  : "no scale.filter_halo_cells up to 4096 is enough: use a coarser grid (grid.n), grid.upsample, or a "
                    "smaller cross_check.isolation_radius_spacings") +
      "; with tile jobs, make a new plan with it and run its jobs again");
}

// The gzipped LAS, LAZ and E57 files of `input`, which have no stream of their own under gzip
// (their readers seek: the header's VLRs and EVLRs, LAZ's chunk table, E57's XML section at the
// end), each inflated once into `dir` (the run's scratch folder, removed with it at the end or
// on failure; plan_passes removes it after its last pass) and listed in load.inflated, so that
// every pass streams it from the copy (open_point_stream) instead of reading the whole file at
// every pass; a note names each.
// Returns the copies' size [MB]. @throws hc::InputError naming the file for bad gzip data (as
// the whole read would), hc::ResourceError naming the folder when a copy cannot be written.
double inflate_seeking_inputs(const std::vector<fs::path>& input, const fs::path& dir, LoadOptions& load, std::vector<std::string>& notes) {
  double bytes = 0.0;
  for (std::size_t i = 0; i < input.size(); ++i) {
    const fs::path& f = input[i];
    std::string ext;
    if (!detail::gz_name(f, ext) || !detail::reader_seeks(ext)) continue;
    std::error_code ec;
    if (!fs::is_regular_file(f, ec)) continue;  // the whole read says what is wrong
    const fs::path copy = dir / ("input_" + std::to_string(i) + ext);
    const auto src = detail::ByteSource::open(f, detail::quoted(f), true);
    std::unique_ptr<std::FILE, int (*)(std::FILE*)> out(std::fopen(copy.c_str(), "wb"), &std::fclose);
    if (!out) throw ResourceError("tiled run: cannot create " + copy.string() + " to inflate " + detail::quoted(f) + ": " + std::strerror(errno));
    std::vector<char> block(std::size_t{4} << 20);
    std::uint64_t written = 0;
    for (std::size_t got; (got = src->read(block.data(), block.size())) > 0;) {
      if (std::fwrite(block.data(), 1, got, out.get()) != got) {
        throw ResourceError("tiled run: cannot write " + copy.string() + " (inflating " + detail::quoted(f) + "; scale.scratch full?): " +
                            std::strerror(errno));
      }
      written += got;
    }
    if (std::fflush(out.get()) != 0) throw ResourceError("tiled run: cannot write " + copy.string() + ": " + std::strerror(errno));
    load.inflated.emplace_back(f, copy);
    bytes += static_cast<double>(written);
    notes.push_back("input: " + f.filename().string() + " inflated once into the scratch folder (" + format_number(std::round(static_cast<double>(written) / 1e6)) +
                    " MB) and streamed from there");
  }
  return bytes / 1e6;
}

// Passes 1, 2 and 2b (the file comment of tiling.hpp): the plan, the spill into `dir`
// (tile_<t>.bin) and the robust test's scale. Stage reports go to plan.reports.
Plan plan_passes(const RunConfig& config, const fs::path& dir, const ProgressFn& progress) {
  check_supported(config);
  Plan plan;
  auto& reports = plan.reports;
  const std::vector<fs::path>& input = config.input.files;
  const std::string input_name = detail::inputs_label(input);
  LoadOptions load{config.input.las_drop_classes, config.input.as_points};
  const std::size_t chunk_points = config.scale.chunk_points;
  const double unit_m = metres_per_unit(config.input.units);

  // The grid's geometry for the box of the points measured, or, in the tiled run's second
  // attempt (ScaleConfig::grid_box), for the box of the points the first one's filters kept.
  const auto grid_geometry_of = [&](double x0, double x1, double y0, double y1, std::size_t n, const ReprojectOptions& o) {
    if (const auto& b = config.scale.grid_box) {
      return tiled_grid_geometry(b->x_min_m, b->x_max_m, b->y_min_m, b->y_max_m, static_cast<std::size_t>(b->points), o);
    }
    return tiled_grid_geometry(x0, x1, y0, y1, n, o);
  };

  // 1. Plan: the file box (recentring), then the grid box and coverage in the grid frame.
  FileBox box;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  Tiles tiles;
  ReprojectOptions ro = config.grid.reproject;
  std::vector<std::string> read_notes;
  std::string crs;
  std::uint64_t grid_points = 0;  // points after non-finite and crop: the in-core outlier stage's input
  // The grid's geometry, upsample factor and tiles from the points in the grid frame (passes 2
  // and 2b), leaving out those `far` holds (far clusters, when found: the grid is then made
  // again without them, as the in-core run grids after removing them).
  double z_min = std::numeric_limits<double>::infinity(), z_max = -z_min;
  bool grid_box_from_file = false;  // the last lay_out took the grid's box from the file box
  const bool robust = config.filters.outliers.enabled && config.filters.outliers.method == OutlierMethod::kRobust;
  // Whether stage tile_scale will give the robust sample's scale, for `points` after
  // non-finite and crop (the in-core filter's indices are 32-bit: above 2^32 − 2 points each
  // tile keeps its own scale).
  const auto sample_to_come = [robust](std::uint64_t points) { return robust && points < std::numeric_limits<std::uint32_t>::max() - 1; };
  // scale.filter_halo_cells: auto: the spacing it takes, the estimate at tile_plan, then the
  // robust sample's from stage tile_scale on (0: not known).
  double spacing_estimate_m = 0.0, sample_spacing_m = 0.0;
  int coverage_passes = 0;  // over the input, for the upsample factor (lay_out)
  // scale.tile_max_points (lay_out): the side scale.tile_cells gave (a multiple of the upsample
  // factor), whether a pass of its own counted the points per block, and the most points a
  // window of the chosen side can hold by those counts (0: not counted: the scan holds at most
  // scale.tile_max_points points, or the bound is off).
  int configured_side = 0;
  bool count_pass = false;
  std::uint64_t window_points_bound = 0;
  // The points per block of the last layout (lay_out), kept until tile_scale: a halo widened
  // there chooses the tile side again with them (choose_side). At most 2049² counts, 33 MB.
  std::optional<BlockCounts> counts;
  auto choose_side = [&](StageReport& rep) {
    const int k = tiles.k;
    const int floor_side = std::min(configured_side, (std::max(16, tiles.halo) + k - 1) / k * k);
    const auto [side, most] = choose_tile_side(*counts, tiles.g, configured_side, k, tiles.halo, floor_side, config.scale.tile_max_points);
    tiles.cut(side);
    window_points_bound = most;
    if (side < configured_side) {
      rep.notes.push_back("tiles of " + std::to_string(side) + " cells, not scale.tile_cells' " + std::to_string(configured_side) +
                          ", so that no window (tile and halo) holds more than scale.tile_max_points = " +
                          std::to_string(config.scale.tile_max_points) + " points (at most " + std::to_string(most) + " by the plan's count)");
    }
    if (most > config.scale.tile_max_points) {
      rep.notes.push_back("the densest window holds up to " + std::to_string(most) + " points even in tiles of " + std::to_string(side) +
                          " cells (no smaller than the halo, " + std::to_string(tiles.halo) +
                          " cells), more than scale.tile_max_points: the tile loop's memory follows that window");
    }
  };
  // The x-y area of the grid's box [m²] (the last lay_out's), for the spacing estimate.
  double grid_area_m2 = 0.0;
  // With the upsample factor left to the spill (lay_out): the coverage of factors 1 and 2 that
  // spill_pass takes of every point it writes; empty otherwise.
  std::optional<UpsampleCoverage> spill_coverage;
  // Whether tile_plan leaves the upsample factor to the spill, the tiles cut for factor 1: when
  // that factor is likely, from the points per node of the grid (tiles.g, grid_points): at least kSpillDecidesPointsPerNode
  // on average (uniform points at that density miss about 2 % of the nodes, and factor 1 needs
  // kAutoUpsampleCoverage, 90 %, of the hit nodes with their 4 neighbours hit), and with
  // scale.tile_max_points, a window of the configured side (clipped to the grid) holding fewer
  // points than it at that mean (else smaller tiles are likely, which the spill could only find
  // after writing).
  const auto spill_may_decide = [&] {
    const double nodes = static_cast<double>(tiles.g.rows) * static_cast<double>(tiles.g.cols);
    const double per_node = nodes > 0.0 ? static_cast<double>(grid_points) / nodes : 0.0;
    if (!(per_node >= kSpillDecidesPointsPerNode)) return false;
    if (!counts) return true;
    const int side = tiles.size + 2 * tiles.halo;
    const double window = static_cast<double>(std::min(side, tiles.g.rows)) * static_cast<double>(std::min(side, tiles.g.cols));
    return per_node * window <= static_cast<double>(config.scale.tile_max_points);
  };
  // Points per block for the tile side (choose_side): with scale.tile_max_points below the
  // scan's points; `counted` once a pass over every point has filled them.
  bool counted = false;
  double coverage = 0.0;  // the upsample coverage at the factor chosen
  // grid.upsample: auto: factor j's coverage counts (UpsampleCoverage::counts) at index j − 1,
  // for j = 1 to the factor chosen, over the factor_points points it was chosen from (Plan).
  std::vector<std::array<std::uint64_t, 2>> factor_counts;
  std::uint64_t factor_points = 0;
  const auto take_counts = [&](const UpsampleCoverage& cov, int k_first, int k_to) {
    for (int j = k_first; j <= k_to; ++j) {
      const auto c = cov.counts(j);
      if (!c || factor_counts.size() != static_cast<std::size_t>(j - 1)) {  // not tracked: none known
        factor_counts.clear();
        factor_points = 0;
        return;
      }
      factor_counts.push_back(*c);
    }
    factor_points = cov.points();
  };
  // The factor an earlier attempt found on the kept points (ScaleConfig::GridBox::upsample_factor).
  const int carried_k = config.scale.grid_box ? config.scale.grid_box->upsample_factor : 0;
  // The upsample coverage of factors k_first to k_last over the input (without the points `far`
  // holds), in a pass of its own that fills `counts` too when they are wanted and not counted;
  // returns UpsampleCoverage::factor.
  const auto coverage_pass = [&](const FarCells* far, int k_first, int k_last, const char* stage_name, const char* what) {
    UpsampleCoverage cov(tiles.g, k_first, k_last);
    const bool count = counts && !counted;
    for_each_grid_chunk(load, config, centre, unit_m, box.points, progress, stage_name, what, [&](const Cloud& g) {
      // Far points counted too: the spill keeps them (marked) in the windows of their clamped nodes.
      if (count) counts->add(g.xyz.data(), g.size());
      if (!far) {
        cov.add(g.xyz.data(), g.size());
        return;
      }
      for (Eigen::Index i = 0; i < g.xyz.cols(); ++i) {
        if (!far->holds(g.xyz.data() + 3 * i)) cov.add(g.xyz.data() + 3 * i, 1);
      }
    });
    counted = counted || count;
    const int k = cov.factor(&coverage);
    take_counts(cov, k_first, k > 0 ? k : k_last);
    return k;
  };
  // The tiles for the factor tiles.k on the grid tiles.g (the last lay_out's): their side
  // (scale.tile_cells, a multiple of the factor), the filter halo and the halo; with
  // scale.tile_max_points, the side from the points per block (`counts`, counted here in a pass of
  // their own unless a pass counted them already), or, when `counts_now` is false, the
  // configured side until the spill has counted them (settle_layout).
  const auto cut_tiles = [&](StageReport& rep, const char* stage_name, bool counts_now) {
    ro = config.grid.reproject;
    ro.upsample_factor = tiles.k;
    const int k = tiles.k;
    tiles.size = (config.scale.tile_cells + k - 1) / k * k;
    tiles.despike = tiles.isolated = 0;  // with a fixed value (or no filter share)
    const auto take_shares = [&](const FilterShares& s) {
      tiles.filter = s.filter;
      tiles.despike = s.despike;
      tiles.isolated = s.isolated;
    };
    if (!filter_halo_added(config)) {
      tiles.filter = 0;  // no filter share in the halo (tile_halo), whatever the key says
    } else if (config.scale.filter_halo_cells != ScaleConfig::kAutoFilterHalo) {
      tiles.filter = config.scale.filter_halo_cells;
    } else if (sample_spacing_m > 0.0) {
      // auto, the robust sample's spacing known (a layout after tile_far_clusters)
      take_shares(auto_filter_shares(config, k, tiles.g.cell_size_m, sample_spacing_m));
    } else {
      // auto at tile_plan: from an estimate of the scan's spacing, the x-y box's area per point
      // (a surface that fills its box; slopes, back sides and holes make the true spacing
      // larger or smaller), half as large again; stage tile_scale widens the halo, and spills
      // the points again, when the robust sample's spacing needs more. Without a robust sample
      // (no robust filter, or more than 2^32 − 2 points: each tile its own scale) nothing
      // corrects it before the tile loop, so the halo keeps the former fixed default, 32, at
      // least.
      const std::uint64_t kept = grid_points;
      spacing_estimate_m = kept > 0 && grid_area_m2 > 0.0 ? std::sqrt(grid_area_m2 / static_cast<double>(kept)) : 0.0;
      take_shares(auto_filter_shares(config, k, tiles.g.cell_size_m, 1.5 * spacing_estimate_m));
      if (tiles.filter < 0) throw no_filter_halo_error(stage_name, "estimated", spacing_estimate_m, tiles.g.cell_size_m);
      if (!sample_to_come(kept)) tiles.filter = std::max(tiles.filter, 32);
    }
    if (tiles.filter < 0) throw no_filter_halo_error(stage_name, "the robust sample's", sample_spacing_m, tiles.g.cell_size_m);
    tiles.halo = tile_halo(config, k, tiles.filter, tiles.despike, tiles.isolated);
    // scale.tile_max_points: tiles small enough that no window holds more points than that
    // (each tile's memory is its window's points), down to the halo's side.
    configured_side = tiles.size;
    window_points_bound = 0;
    if (counts && !counts_now) {
      tiles.cut(tiles.size);  // the side waits for the counts the spill takes (settle_layout)
    } else if (counts) {
      if (!counted) {
        count_pass = true;
        for_each_grid_chunk(load, config, centre, unit_m, box.points, progress, stage_name,
                            "pass 2d of 3: the points per block, for the tile size", [&](const Cloud& g) {
                              // Far points too, as the coverage pass counts them.
                              counts->add(g.xyz.data(), g.size());
                            });
        counted = true;
      }
      counts->finish();
      choose_side(rep);
    } else {
      tiles.cut(tiles.size);
    }
  };
  // tile_plan's figures of the tiles in use (set, or appended the first time).
  const auto set_tile_figures = [&](StageReport& rep) {
    detail::set_figure(rep, "upsample_factor", tiles.k);
    detail::set_figure(rep, "tiles", static_cast<double>(tiles.count()));
    detail::set_figure(rep, "tile_cells", tiles.size);
    if (window_points_bound > 0) detail::set_figure(rep, "window_points_bound", static_cast<double>(window_points_bound));
    detail::set_figure(rep, "halo_cells", tiles.halo);
    detail::set_figure(rep, "filter_halo_cells", tiles.filter);
    detail::set_figure(rep, "despike_halo_cells", tiles.despike);
    detail::set_figure(rep, "isolated_halo_cells", tiles.isolated);
    // 1: the grid share holds the despike's island groups (scale.island_halo on, or auto's
    // second attempt); 0: a window that cannot decide one stops (off) or starts again (auto).
    detail::set_figure(rep, "island_halo", config.scale.island_halo == ScaleConfig::Tiled::kOn ? 1.0 : 0.0);
  };
  // The grid (tiles.g) from the points in the grid frame without those `far` holds, then the
  // upsample factor and the tiles (cut_tiles). With grid.upsample auto the factor needs a pass
  // over the points (their coverage of the grid). At tile_plan, on a scan dense enough for its
  // grid that factor 1 is likely (spill_may_decide), that pass is left to the spill: the tiles
  // are cut for factor 1 and spill_pass takes the coverage (and the points per block) as it
  // writes; settle_layout then checks the guess, and only a wrong one costs a spill again.
  auto lay_out = [&](const FarCells* far, StageReport& rep) {
    const char* stage_name = far ? "tile_far_clusters" : "tile_plan";
    ro = config.grid.reproject;
    // The grid frame's x-y box, as reproject's pass over the points takes it.
    double x_min = std::numeric_limits<double>::infinity(), x_max = -x_min, y_min = x_min, y_max = -x_min;
    std::size_t kept = 0;
    // With the identity view transform (ViewTransform::is_identity, which apply_view_transform
    // skips) and no crop, the grid frame is the file's, recentred and scaled per axis:
    // (v − centre)·unit rounds monotonically, so the box of the points in the grid frame is the
    // file box's corners taken through the same arithmetic as to_grid_frame, bit for bit, and
    // the pass over the input is not needed. The file box holds the finite points, the ones
    // remove_non_finite keeps: with a finite centre, input.max_extent_m (at most 1e9 m) keeps
    // every such point finite in the grid frame. (An infinite centre, from coordinates near the
    // double range, takes the pass, which finds no finite point and says so.)
    const bool file_frame = !far && !config.filters.crop_m && centre.allFinite() && config.view.is_identity();
    if (file_frame) {
      const auto to_grid = [&](double v, int a) {
        double w = v - centre[a];
        if (unit_m != 1.0) w *= unit_m;
        return w;
      };
      x_min = to_grid(box.lo.x(), 0);
      x_max = to_grid(box.hi.x(), 0);
      y_min = to_grid(box.lo.y(), 1);
      y_max = to_grid(box.hi.y(), 1);
      z_min = std::min(z_min, to_grid(box.lo.z(), 2));
      z_max = std::max(z_max, to_grid(box.hi.z(), 2));
      kept = box.finite;
    }
    grid_box_from_file = file_frame && !config.scale.grid_box;  // a later attempt's box is the kept points'
    if (!file_frame) {
      for_each_grid_chunk(load, config, centre, unit_m, box.points, progress, stage_name,
                          "pass 2 of 3: the grid's box", [&](const Cloud& g) {
                            for (Eigen::Index i = 0; i < g.xyz.cols(); ++i) {
                              if (far && far->holds(g.xyz.data() + 3 * i)) continue;
                              x_min = std::min(x_min, g.xyz(0, i));
                              x_max = std::max(x_max, g.xyz(0, i));
                              y_min = std::min(y_min, g.xyz(1, i));
                              y_max = std::max(y_max, g.xyz(1, i));
                              z_min = std::min(z_min, g.xyz(2, i));
                              z_max = std::max(z_max, g.xyz(2, i));
                              ++kept;
                            }
                          });
    }
    grid_points = kept;
    if (kept == 0 && config.filters.crop_m && box.finite > 0) {
      // As the in-core crop stage stops (crop_box), not later at an empty grid.
      throw_nothing_inside_box(box.finite, config.filters.crop_m->first, config.filters.crop_m->second, "; tiled run");
    }
    tiles.g = grid_geometry_of(x_min, x_max, y_min, y_max, kept, ro);
    grid_area_m2 = std::max(0.0, x_max - x_min) * std::max(0.0, y_max - y_min);
    counts.reset();
    if (config.scale.tile_max_points > 0 && box.points > config.scale.tile_max_points) counts.emplace(tiles.g);
    counted = false;
    coverage_passes = 0;
    count_pass = false;
    spill_coverage.reset();
    factor_counts.clear();
    factor_points = 0;
    if (config.grid.reproject.upsample_factor == 0 && carried_k == 0) {
      bool guess = !far;
      if (guess) {
        tiles.k = 1;
        try {
          cut_tiles(rep, "tile_plan", false);
        } catch (const ConfigError&) {
          guess = false;  // no filter halo for factor 1: the coverage pass first, as without a guess
        }
      }
      if (guess && spill_may_decide()) {
        spill_coverage.emplace(tiles.g, 1, 2);
        return;
      }
      // Factors 1 and 2 first (a scan as dense as its grid stops there); the rest, 3 to
      // kMaxUpsampleFactor, in one more pass only when both fail. Each factor's coverage is its
      // own grid's, so the factor is the one a single pass over all factors gives.
      tiles.k = coverage_pass(far, 1, 2, stage_name, "pass 2b of 3: the upsample coverage");
      coverage_passes = 1;
      if (tiles.k == 0) {
        tiles.k = coverage_pass(far, 3, kMaxUpsampleFactor, stage_name, "pass 2c of 3: the upsample coverage, factors 3 and more");
        coverage_passes = 2;
      }
      rep.figure("upsample_coverage", coverage);
    } else {
      tiles.k = carried_k > 0 ? carried_k : ro.upsample_factor;
      if (carried_k > 0) {
        rep.notes.push_back("upsample factor " + std::to_string(carried_k) + ": the factor grid.upsample: auto gives the points an earlier "
                            "attempt's filters kept on this grid, as the in-core run chooses it");
      }
    }
    cut_tiles(rep, stage_name, true);
  };
  (void)stage("tile_plan", reports, progress, [&] {
    StageResult<int> r;
    const double inflated_mb = inflate_seeking_inputs(input, dir, load, r.report.notes);
    if (!load.inflated.empty()) r.report.figure("inflated_input_mb", inflated_mb);
    {
      auto s = open_input(config, load);
      crs = s->crs();
      Cloud c;
      bool first = true;
      detail::PassProgress tick(progress, "tile_plan", "pass 1 of 3: the file's box", config.scale.progress_interval_s);
      const double total = static_cast<double>(std::max<std::uint64_t>(1, s->total_points()));
      while (s->next(c, chunk_points)) {
        tick(static_cast<double>(box.points + c.size()) / total);
        if (first) {
          box.layout = {c.has_rgb(), c.has_intensity(), std::nullopt};
          box.float32 = c.float32_xyz;
          first = false;
        }
        box.points += c.size();
        for (Eigen::Index i = 0; i < c.xyz.cols(); ++i) {
          const auto p = c.xyz.col(i);
          if (!p.allFinite()) continue;
          box.lo = box.lo.cwiseMin(p);
          box.hi = box.hi.cwiseMax(p);
          ++box.finite;
          if (box.float32) {
            for (int a = 0; a < 3; ++a) {
              box.max_abs[a] = std::max(box.max_abs[a], std::abs(p[a]));
              auto& seen = box.distinct[static_cast<std::size_t>(a)];
              if (static_cast<int>(seen.size()) < detail::kDistinctCap && std::find(seen.begin(), seen.end(), p[a]) == seen.end()) {
                seen.push_back(p[a]);
              }
            }
          }
        }
      }
      read_notes = s->notes();  // after the pass: a stream may add notes as it reads (LAS: colour, dropped)
    }
    if (box.points == 0) throw InputError("tiled run: " + input_name + " holds no point");
    if (box.finite == 0) throw InputError("to_metres_and_recentre: none of the " + std::to_string(box.points) + " points has finite coordinates");
    const Eigen::Vector3d box_m = (box.hi - box.lo) * unit_m;
    for (int a = 0; a < 3; ++a) {
      if (!(box_m[a] <= config.input.max_extent_m)) {
        throw InputError("the points span " + std::to_string(box_m[a]) + " m along " + std::string(1, static_cast<char>('x' + a)) +
                         ": more than input.max_extent_m = " + std::to_string(config.input.max_extent_m) +
                         " m (far outliers or wrong input.units? crop them with filters.crop or raise input.max_extent_m)");
      }
    }
    centre = 0.5 * (box.lo + box.hi);
    // The spill keeps a float file's own x y z: half the bytes (FileFloats).
    if (box.float32) box.layout.floats = FileFloats::of(centre, unit_m, config.view);
    lay_out(nullptr, r.report);
    r.report.count_in = box.points;
    r.report.count_out = grid_points;
    r.report.figure("rows", tiles.g.rows);
    r.report.figure("cols", tiles.g.cols);
    set_tile_figures(r.report);
    if (spacing_estimate_m > 0.0) r.report.figure("spacing_estimate_mm", spacing_estimate_m * 1e3);
    r.report.notes.insert(r.report.notes.begin(), read_notes.begin(), read_notes.end());
    if (spill_coverage) {
      // The factor, the tiles and the halo above are factor 1's until the spill has the
      // coverage (settle_layout sets them).
      r.report.notes.push_back(std::string("passes over the input: the file box, ") + (grid_box_from_file ? "" : "the grid box, ") +
                               "then the spill, which took the upsample coverage" +
                               (counts ? " and the points per block for the tile size" : "") + " (" +
                               format_number(static_cast<double>(grid_points) / (static_cast<double>(tiles.g.rows) * tiles.g.cols)) +
                               " points per grid node: factor 1 likely)" +
                               (grid_box_from_file ? " (the grid's box is the file box's, recentred: identity view, no crop)" : ""));
      return r;
    }
    r.report.notes.push_back(std::string("passes over the input: the file box, ") +
                             (grid_box_from_file ? "" : "the grid box, ") +
                             (coverage_passes == 2   ? "the upsample coverage for factors 1 and 2, again for 3 and more, "
                              : coverage_passes == 1 ? "the upsample coverage, "
                                                     : "") +
                             (count_pass ? "the points per block for the tile size, " : "") + "then the spill" +
                             (grid_box_from_file ? " (the grid's box is the file box's, recentred: identity view, no crop)" : ""));
    return r;
  });

  detail::StoredPrecision precision;
  precision.float32 = box.float32;
  precision.file = input_name;
  precision.crs = crs;
  for (int a = 0; a < 3; ++a) {
    precision.max_abs_m[a] = box.max_abs[a] * unit_m;
    precision.distinct[a] = static_cast<int>(box.distinct[static_cast<std::size_t>(a)].size());
  }
  const Eigen::Vector3d offset_m = centre * unit_m;
  for (const fs::path& f : input) plan.inputs.push_back({f.string(), sha256_file(f)});
  if (config.input.conf) plan.inputs.push_back({config.input.conf->string(), sha256_file(*config.input.conf)});

  // 2. Spill every point to the tiles whose window holds its node. The robust test's sample
  // (the points the in-core run samples, by their order after non-finite and crop) is marked
  // (flag bit kSampleFlag) in the tile whose interior holds it.
  const bool shared_scale = sample_to_come(grid_points);
  const std::vector<std::uint32_t> robust_sample =
      shared_scale ? robust_sample_indices(static_cast<std::size_t>(grid_points), RobustOutlierOptions{}.sample)
                   : std::vector<std::uint32_t>();
  // The spill pass: every point (but those `far` holds) to the tiles whose window holds its node;
  // the robust sample marked only in the first spill (its scale is computed once, on every point,
  // as in core).
  std::optional<Spill> spill;
  std::size_t spill_tiles = 0;
  std::uint64_t far_points = 0;  // spilled with kFarFlag
  auto spill_pass = [&](const FarCells* far, StageReport& rep, const char* stage_name) {
    std::uint64_t spilled = 0, copies = 0;
    for (;;) {
      if (spill) {  // a pass again (far clusters marked, or in doubles after a float pass stopped): the earlier files go first
        for (std::size_t t = 0; t < spill_tiles; ++t) {
          std::error_code ec;
          fs::remove(spill->file(t), ec);
          if (ec) throw InputError("tiled run: cannot remove the spill file " + spill->file(t).string() + ": " + ec.message());
        }
      }
      far_points = 0;
      // The upsample factor left to this pass (lay_out): the coverage and the points per block
      // of every point it writes, taken again if the pass starts again.
      if (spill_coverage) {
        spill_coverage.emplace(tiles.g, 1, 2);
        if (counts) counts.emplace(tiles.g);
      }
      spill.emplace(dir, "tile_", tiles.count(), box.layout);
      spill_tiles = tiles.count();
      spilled = copies = 0;
      std::size_t next_sample = 0;
      const NodeBinner node(tiles.g);
      // Per row and per column of nodes: the first and last tile whose window holds it
      // (tiles_of) and the tile that owns it, looked up rather than divided per point.
      const auto spans = [&](int nodes, bool rows) {
        std::vector<std::array<int, 3>> v(static_cast<std::size_t>(nodes));
        for (int i = 0; i < nodes; ++i) {
          const auto tt = rows ? tiles_of(tiles, i, 0) : tiles_of(tiles, 0, i);
          v[static_cast<std::size_t>(i)] = rows ? std::array<int, 3>{tt[0], tt[1], i / tiles.size} : std::array<int, 3>{tt[2], tt[3], i / tiles.size};
        }
        return v;
      };
      const std::vector<std::array<int, 3>> row_tiles = spans(tiles.g.rows, true), col_tiles = spans(tiles.g.cols, false);
      std::uint64_t seen = 0;
      try {
      for_each_grid_chunk(load, config, centre, unit_m, box.points, progress, stage_name,
                          spill_coverage ? "pass 3 of 3: the spill, with the upsample coverage" : "pass 3 of 3: the spill",
                          [&](const Cloud& g) {
        if (spill_coverage) {
          spill_coverage->add(g.xyz.data(), g.size());
          if (counts) counts->add(g.xyz.data(), g.size());
        }
        for (Eigen::Index i = 0; i < g.xyz.cols(); ++i, ++seen) {
          const double* p = g.xyz.data() + 3 * i;
          const bool far_point = far && far->holds(p);
          far_points += far_point ? 1U : 0U;
          spilled += far_point ? 0U : 1U;
          const auto [tr0, tr1, own_r] = row_tiles[static_cast<std::size_t>(node.row(p))];
          const auto [tc0, tc1, own_c] = col_tiles[static_cast<std::size_t>(node.col(p))];
          const std::uint8_t* rgb = g.has_rgb() ? g.rgb.data() + 3 * i : nullptr;
          const float inten = g.has_intensity() ? g.intensity[static_cast<std::size_t>(i)] : 0.0f;
          while (!far && next_sample < robust_sample.size() && robust_sample[next_sample] < seen) ++next_sample;
          const bool sampled = !far && next_sample < robust_sample.size() && robust_sample[next_sample] == seen;
          for (int tr = tr0; tr <= tr1; ++tr) {
            for (int tc = tc0; tc <= tc1; ++tc) {
              const std::uint8_t flag = far_point ? kFarFlag : sampled && tr == own_r && tc == own_c ? kSampleFlag : std::uint8_t{0};
              spill->add(static_cast<std::size_t>(tr) * static_cast<std::size_t>(tiles.tiles_c) + static_cast<std::size_t>(tc), flag, p,
                        rgb, inten);
              ++copies;
            }
          }
        }
      });
      } catch (const Spill::NotFloats& e) {
        // A point whose file floats do not give its grid coordinates back (FileFloats): the
        // pass again, in doubles (the files written so far go first).
        rep.notes.push_back("the spill holds x y z as doubles: point " + std::to_string(seen) +
                            " (counting from 0 after non-finite points and the crop), at (" + format_number(e.xyz_m[0]) + ", " +
                            format_number(e.xyz_m[1]) + ", " + format_number(e.xyz_m[2]) +
                            ") m in the grid frame, does not come back from the file's floats bit for bit");
        box.layout.floats.reset();
        continue;
      }
      spill->flush_all();
      break;
    }
    rep.count_in = box.points;
    rep.figure("spill_xyz_floats", box.layout.floats ? 1.0 : 0.0);
    rep.count_out = spilled;
    if (far) rep.figure("far_points_spilled_marked", static_cast<double>(far_points));
    rep.figure("points_spilled", static_cast<double>(copies));
    rep.figure("halo_copies_per_point", spilled ? static_cast<double>(copies) / static_cast<double>(spilled) : 0.0);
    rep.figure("spill_bytes_peak_mb", static_cast<double>(spill->bytes()) / 1e6);
    // The largest window's points as spilled (halo copies and far points included): what a
    // tile holds (scale.tile_max_points bounds it through the plan's count).
    std::size_t most_records = 0;
    for (std::size_t t = 0; t < spill_tiles; ++t) most_records = std::max(most_records, spill->records(t));
    rep.figure("window_points_max", static_cast<double>(most_records));
    rep.notes.push_back("spill folder " + dir.string());
    return spilled;
  };
  // After a spill that took the upsample coverage (lay_out left the factor to it): the factor
  // from that coverage (factors 3 and more in a pass of their own when 1 and 2 both fail, as
  // lay_out would), the tiles cut for it with the points per block the spill counted, and
  // tile_plan's figures set to them. Returns whether those are the tiles spilled; when not
  // (another factor, or smaller tiles for scale.tile_max_points), the points must be spilled
  // again.
  const auto settle_layout = [&]() -> bool {
    StageReport* plan_rep = nullptr;
    for (StageReport& rp : reports) plan_rep = rp.stage == "tile_plan" ? &rp : plan_rep;
    if (plan_rep == nullptr) throw std::logic_error("tiled run: settle_layout before stage tile_plan");
    counted = counts.has_value();
    int k = spill_coverage->factor(&coverage);
    take_counts(*spill_coverage, 1, k > 0 ? k : 2);
    spill_coverage.reset();
    if (k == 0) {
      k = coverage_pass(nullptr, 3, kMaxUpsampleFactor, "tile_spill", "the upsample coverage, factors 3 and more");
      coverage_passes = 1;
    }
    const Tiles spilled = tiles;
    tiles.k = k;
    cut_tiles(*plan_rep, "tile_plan", true);
    detail::set_figure(*plan_rep, "upsample_coverage", coverage);
    set_tile_figures(*plan_rep);
    const bool same = tiles.k == spilled.k && tiles.size == spilled.size && tiles.halo == spilled.halo && tiles.filter == spilled.filter &&
                      tiles.despike == spilled.despike && tiles.isolated == spilled.isolated && tiles.tiles_r == spilled.tiles_r && tiles.tiles_c == spilled.tiles_c;
    if (!same) {
      plan_rep->notes.push_back("upsample factor " + std::to_string(tiles.k) + ", tiles of " + std::to_string(tiles.size) + " cells, halo " +
                                std::to_string(tiles.halo) + " cells: found by the spill, which had guessed factor 1 and " +
                                std::to_string(spilled.size) + "-cell tiles; the points were spilled again" +
                                (coverage_passes == 1 ? " after a pass for the coverage of factors 3 and more" : ""));
    }
    return same;
  };
  (void)stage("tile_spill", reports, progress, [&] {
    StageResult<int> r;
    (void)spill_pass(nullptr, r.report, "tile_spill");
    if (spill_coverage && !settle_layout()) {
      r.report = StageReport{};
      (void)spill_pass(nullptr, r.report, "tile_spill");
      r.report.notes.push_back("spilled twice: the first spill's guess of the upsample factor or the tile side was not the one its "
                               "coverage and counts gave (see tile_plan)");
    }
    return r;
  });

  // 2b. The robust test's scale over the whole scan: each tile gives the mean k-NN distance of
  // the sampled points it owns (over its points and halo, as the in-core run's over all points),
  // then the median and MAD of their logarithms (robust_scale_of), as in core.
  std::optional<RobustScale> robust_scale;
  if (robust && !robust_sample.empty()) {
    (void)stage("tile_scale", reports, progress, [&] {
      StageResult<int> r;
      const int k = config.filters.outliers.k;
      std::size_t found = 0, in_small_tiles = 0;
      // The sampled points whose search reached past their window, and by how much at most [m];
      // the bounds of every sampled point's ln d and ln nearest (robust_scale_fixed).
      std::size_t past_window = 0;
      double past_window_m = 0.0;
      std::vector<std::array<double, 2>> log_bounds, nearest_bounds;
      // How the sampled points' searches went (detail::NearSearch, summed over the windows).
      detail::NearSearch searched;
      // The scale from the sampled points' k-NN distances over their tiles' windows (the spill
      // as it is). A point's search over its window gives its true k + 1 nearest when the
      // (k + 1)-th lies closer than any point outside the window: closer than its xy clearance b
      // to the window's box (points outside it lie beyond, less a rounding step: NodeBinner).
      // Otherwise each true j-th distance D_j lies in [min(d_j, b), d_j] (d_j: the window's;
      // a point past b can only stand in for a farther one), so d (their mean) and the nearest
      // distance are known to within bounds; robust_scale_fixed tells whether the scale can
      // depend on where in them the in-core run's values lie.
      const auto scale_from_spill = [&] {
        std::vector<double> logs, nearest_logs, nearest;
        logs.reserve(robust_sample.size());
        nearest_logs.reserve(robust_sample.size());
        log_bounds.clear();
        nearest_bounds.clear();
        std::vector<float> xyz, top_d2;  // reused: a window's points as floats (read_window_floats)
        std::vector<std::uint32_t> mine;
        std::vector<std::array<double, 3>> sampled_m;  // every sampled point, once (its owner's window)
        sampled_m.reserve(robust_sample.size());
        found = in_small_tiles = past_window = 0;
        past_window_m = 0.0;
        searched = detail::NearSearch{};
        const auto k1 = static_cast<std::size_t>(k) + 1;
        const double inf = std::numeric_limits<double>::infinity();
        // A thousandth of a cell off the clearance: NodeBinner's rounding step (a millionth of a
        // cell, Tiles::reading_box_m) and the floats' (under a micrometre about the centre).
        const double slack_m = 1e-3 * tiles.g.cell_size_m;
        detail::PassProgress tick(progress, "tile_scale", "the robust test's sample, tile by tile", config.scale.progress_interval_s);
        for (std::size_t t = 0; t < tiles.count(); ++t) {
          tick(static_cast<double>(t) / static_cast<double>(tiles.count()));
          const auto wc = read_window_floats(*spill, tiles, t, xyz, mine, &sampled_m);
          found += mine.size();
          if (mine.empty()) continue;
          if (xyz.size() / 3 < k1 + 1) {
            in_small_tiles += mine.size();  // fewer than k + 2 points in the window: no k-NN distance here
            for (std::size_t i = 0; i < mine.size(); ++i) {
              log_bounds.push_back({-inf, inf});  // unknown, in core even whether d > 0
              nearest_bounds.push_back({-inf, inf});
            }
            continue;
          }
          const auto wb = tiles.box_m(tiles.window(t));
          detail::NearSearch how;
          const auto d = detail::mean_knn_distances_of(xyz, mine, k, &nearest, true, &how, &top_d2);
          searched.blocks += how.blocks;
          searched.wide_blocks += how.wide_blocks;
          searched.balls += how.balls;
          searched.subset_points += how.subset_points;
          for (std::size_t i = 0; i < mine.size(); ++i) {
            const double x = wc[0] + static_cast<double>(xyz[3 * mine[i]]), y = wc[1] + static_cast<double>(xyz[3 * mine[i] + 1]);
            const double b = std::max(0.0, std::min({x - wb[0], wb[1] - x, y - wb[2], wb[3] - y}) - slack_m);
            const float* d2 = top_d2.data() + i * k1;
            double sum = 0.0, reach = 0.0;
            for (std::size_t j = 0; j < k1; ++j) {
              const auto dj = static_cast<double>(std::sqrt(d2[j]));
              sum += std::min(dj, b);
              reach = std::max(reach, dj);
            }
            // An exact copy of the point (d = 0, nearest = 0) has its copies in its window too:
            // no value, here as in core.
            const bool complete = reach < b;
            if (!complete) {
              ++past_window;
              past_window_m = std::max(past_window_m, reach - b);
            }
            if (d[i] > 0.0) {
              logs.push_back(std::log(d[i]));
              log_bounds.push_back({complete ? logs.back() : std::log(std::min(d[i], sum / static_cast<double>(k))), logs.back()});
            }
            if (nearest[i] > 0.0) {
              nearest_logs.push_back(std::log(nearest[i]));
              nearest_bounds.push_back({std::log(std::min(nearest[i], b)), nearest_logs.back()});
            }
          }
        }
        auto scale = robust_scale_of(std::move(logs), found - in_small_tiles, std::move(nearest_logs));
        // The in-core run's float frame: the same sampled points' median (every one is marked
        // once, in the tile that owns it).
        if (sampled_m.size() != robust_sample.size()) {
          throw std::logic_error("tiled run, stage tile_scale: " + std::to_string(sampled_m.size()) + " sampled points found in the spill, " +
                                 std::to_string(robust_sample.size()) + " marked");
        }
        if (scale) scale->centre_m = robust_sample_centre(sampled_m);
        return scale;
      };
      // The least filter halo [cells] whose windows hold the farthest sampled search seen (the
      // halo grows by its excess, one node to spare; tile_halo rounds to the upsample factor);
      // -1 when none up to 4096 does, 0 when every search stayed inside.
      // fixed_value: the value to name to the user, which replaces auto's shares (tile_halo).
      const auto filter_for_searches = [&](bool fixed_value) {
        if (past_window == 0) return 0;
        const double want = tiles.halo + std::ceil(past_window_m / tiles.g.cell_size_m) + 1.0;
        if (fixed_value) return least_fixed_filter_cells(config, tiles.k, [want](int halo) { return halo >= want; });
        for (int f = tiles.filter + 1; f <= 4096; ++f) {
          if (tile_halo(config, tiles.k, f, tiles.despike, tiles.isolated) >= want) return f;
        }
        return -1;
      };
      // Throws when the windows leave the scale open (see scale_from_spill).
      const auto check_fixed = [&] {
        if (robust_scale_fixed(log_bounds, nearest_bounds)) return;
        const int needed = filter_for_searches(true);
        std::string what = "tiled run, stage tile_scale: the robust test's scale (median and MAD of ln d, and the spacing) could "
                           "differ from the in-core run's: of its " + std::to_string(found) + " sampled points, ";
        if (past_window > 0) {
          what += std::to_string(past_window) + " have k-NN searches that reach past their tile's window (by up to " +
                  format_number(past_window_m * 1e3) + " mm), where their distances are only bounded";
        }
        if (in_small_tiles > 0) {
          what += std::string(past_window > 0 ? ", and " : "") + std::to_string(in_small_tiles) +
                  " lie in windows of fewer than k + 2 points, where they have no distance";
        }
        what += ": set scale.filter_halo_cells (now " + filter_halo_now(config, tiles) + ")" +
                (needed > 0 ? " to at least " + std::to_string(needed) : std::string(" higher")) +
                ", or use larger tiles (scale.tile_cells)";
        throw ConfigError(what);
      };
      robust_scale = scale_from_spill();
      // scale.filter_halo_cells: auto: the halo the sample's spacing needs (without one, the
      // former fixed default, 32, at least); where tile_plan's estimate gave less, the points
      // are spilled again with it and the scale taken again over the new windows (a wider halo
      // is kept).
      if (config.scale.filter_halo_cells == ScaleConfig::kAutoFilterHalo && filter_halo_added(config)) {
        const auto holds = [&](const FilterShares& n) {
          return n.filter <= tiles.filter && n.despike <= tiles.despike && n.isolated <= tiles.isolated;
        };
        for (int pass = 0;; ++pass) {
          sample_spacing_m = robust_scale ? robust_scale->spacing_m : 0.0;
          const FilterShares for_spacing = sample_spacing_m > 0.0 ? auto_filter_shares(config, tiles.k, tiles.g.cell_size_m, sample_spacing_m)
                                                                  : FilterShares{std::max(tiles.filter, 32), tiles.despike, tiles.isolated};
          if (for_spacing.filter < 0) throw no_filter_halo_error("tile_scale", "the robust sample's", sample_spacing_m, tiles.g.cell_size_m);
          FilterShares need = for_spacing;
          // The sampled points' own searches, where they leave the scale open (check_fixed
          // names the key when no halo up to 4096 holds them, or after the last pass).
          if (!robust_scale_fixed(log_bounds, nearest_bounds)) need.filter = std::max(need.filter, filter_for_searches(false));
          const int needed = need.filter;
          r.report.figure("filter_halo_cells_needed", needed);
          r.report.figure("despike_halo_cells_needed", need.despike);
          r.report.figure("isolated_halo_cells_needed", need.isolated);
          if (holds(need)) break;
          if (pass == 3) {
            // Three spills, and the sample's spacing still asks for more than the last one held
            // (each wider halo moved it). The searches' share is check_fixed's to name.
            if (holds(for_spacing)) break;
            const int want = tile_halo(config, tiles.k, std::max(tiles.filter, for_spacing.filter), std::max(tiles.despike, for_spacing.despike),
                                       std::max(tiles.isolated, for_spacing.isolated));
            const int fixed = least_fixed_filter_cells(config, tiles.k, [want](int halo) { return halo >= want; });
            throw ConfigError("tiled run, stage tile_scale: scale.filter_halo_cells auto: after three spills the robust sample's spacing (" +
                              format_number(sample_spacing_m * 1e3) + " mm) still needs a wider halo than the last spill's (" +
                              std::to_string(tiles.halo) + " cells, " + std::to_string(want) + " needed): set scale.filter_halo_cells to " +
                              (fixed >= 0 ? "at least " + std::to_string(fixed) : std::string("a value")) +
                              ", or use larger tiles (scale.tile_cells)");
          }
          const int planned = tiles.filter, planned_despike = tiles.despike, planned_isolated = tiles.isolated;
          // Each share as wide as the sample needs, or as planned where that is wider.
          tiles.filter = std::max(tiles.filter, need.filter);
          tiles.despike = std::max(tiles.despike, need.despike);
          tiles.isolated = std::max(tiles.isolated, need.isolated);
          tiles.halo = tile_halo(config, tiles.k, tiles.filter, tiles.despike, tiles.isolated);
          // scale.tile_max_points: the wider halo widens every window; the side is chosen
          // again from the plan's counts (smaller tiles, or the same).
          const int side_before = tiles.size;
          if (counts) choose_side(r.report);
          StageReport again;
          (void)spill_pass(nullptr, again, "tile_scale");
          r.report.figure("second_spill", 1.0);
          r.report.notes.push_back("scale.filter_halo_cells auto: the sample's spacing or k-NN searches need a filter share of " +
                                   std::to_string(needed) + " cells (the despike's and the isolated filter's radii: " +
                                   std::to_string(need.despike) + " and " + std::to_string(need.isolated) + " cells), " +
                                   (pass == 0 ? "tile_plan's estimate gave " : "the halo had ") + std::to_string(planned) + " (" +
                                   std::to_string(planned_despike) + ", " + std::to_string(planned_isolated) +
                                   "): the points were spilled again with the wider halo and the scale taken again");
          // The plan's and the spill's figures describe the halo in use.
          for (StageReport& rp : reports) {
            if (rp.stage == "tile_plan") {
              detail::set_figure(rp, "halo_cells", tiles.halo);
              detail::set_figure(rp, "filter_halo_cells", tiles.filter);
              detail::set_figure(rp, "despike_halo_cells", tiles.despike);
              detail::set_figure(rp, "isolated_halo_cells", tiles.isolated);
              if (pass == 0) {
                rp.notes.push_back("halo_cells, filter_halo_cells, despike_halo_cells, isolated_halo_cells: widened at tile_scale for the "
                                   "robust sample's spacing");
              }
              if (tiles.size != side_before) {
                detail::set_figure(rp, "tile_cells", tiles.size);
                detail::set_figure(rp, "tiles", static_cast<double>(tiles.count()));
                rp.notes.push_back("tile_cells, tiles: chosen again at tile_scale for the wider halo (scale.tile_max_points)");
              }
              if (counts) detail::set_figure(rp, "window_points_bound", static_cast<double>(window_points_bound));
            }
            if (rp.stage == "tile_spill") {
              for (const char* f : {"points_spilled", "halo_copies_per_point", "spill_bytes_peak_mb", "window_points_max"})
                detail::set_figure(rp, f, detail::figure_of(again, f, 0.0));
              if (pass == 0) rp.notes.push_back("points_spilled, halo_copies_per_point, spill_bytes_peak_mb: of the spill again at tile_scale");
            }
          }
          robust_scale = scale_from_spill();
        }
        r.report.figure("filter_halo_cells", tiles.filter);
        r.report.figure("despike_halo_cells", tiles.despike);
        r.report.figure("isolated_halo_cells", tiles.isolated);
        r.report.figure("halo_cells", tiles.halo);
      }
      check_fixed();
      r.report.figure("sampled_past_window", static_cast<double>(past_window));
      r.report.figure("sampled_past_window_max_mm", past_window_m * 1e3);
      r.report.count_in = robust_sample.size();
      r.report.count_out = found;
      r.report.figure("sampled_in_sparse_tiles", static_cast<double>(in_small_tiles));
      // Each window's sampled points searched among the points near them (near_knn.hpp): by
      // their 3 × 3 × 3 block of cells, their 9 × 9 × 9 one, or a ball; the subsets' points.
      r.report.figure("sampled_by_block", static_cast<double>(searched.blocks));
      r.report.figure("sampled_by_wider_block", static_cast<double>(searched.wide_blocks));
      r.report.figure("sampled_by_ball", static_cast<double>(searched.balls));
      r.report.figure("sample_search_points", static_cast<double>(searched.subset_points));
      if (robust_scale) {
        r.report.figure("median_knn_distance_mm", std::exp(robust_scale->median_log) * 1e3);
        r.report.figure("mad_log_knn_distance", robust_scale->mad_log);
        r.report.figure("sample", static_cast<double>(robust_scale->sample));
        if (robust_scale->spacing_m > 0.0) r.report.figure("sample_spacing_mm", robust_scale->spacing_m * 1e3);
      }
      r.report.notes.push_back(robust_scale ? "the robust outlier test's scale over the whole scan, from the points the in-core run samples"
                                            : "no sampled point with a k-NN distance above 0: each tile takes its own scale");
      return r;
    });
  }

  // 2c. Far clusters over the whole scan (the in-core run removes them after the robust test,
  // before gridding; a tile alone cannot tell a passer-by 20 m away from the main body). Single
  // linkage on coarse cells of edge E = max(link, far / (2√3)) over every spilled point: two
  // points closer than the link always share a component, and points in cells that are not
  // neighbours are more than E apart; a component whose box lies more than `far` from the main
  // body's box (points up to 2√3·E = far apart may share a component: coarser than in core,
  // never finer, so a cluster kept in core is kept here) and that is small is removed: the grid
  // is laid out and the points spilled again without it. The scale stays the one of every point.
  const FarClusterOptions& fco = config.filters.outliers.far_clusters;
  if (robust && fco.enabled && robust_scale && grid_points > 0) {
    (void)stage("tile_far_clusters", reports, progress, [&] {
      StageResult<int> r;
      const OutlierConfig& oc = config.filters.outliers;
      // The in-core run's link (far_link_m, the robust test's own threshold).
      RobustOutlierOptions threshold_options;
      threshold_options.local_ratio = oc.local_ratio;
      threshold_options.mad_multiplier = oc.mad_multiplier;
      const double link = far_link_m(fco, robust_global_threshold_m(*robust_scale, threshold_options));
      const double far_d = fco.far_distance_m > 0.0 ? fco.far_distance_m : 10.0 * link;
      const Eigen::Vector3d lo(tiles.g.x0_m - tiles.g.cell_size_m, tiles.g.y0_m - tiles.g.cell_size_m, z_min);
      const double extent = std::max({tiles.g.cell_size_m * (tiles.g.cols + 2), tiles.g.cell_size_m * (tiles.g.rows + 2), z_max - z_min});
      // E ≥ 2·link: the in-core cells (edge link) link points up to 2·link apart per axis, so its
      // components nest in these.
      const std::size_t small = std::max<std::size_t>(fco.max_points, static_cast<std::size_t>(fco.max_fraction * static_cast<double>(grid_points)));
      FarCells cells(lo, std::max({2.0 * link, far_d / (2.0 * std::sqrt(3.0)), extent / 2097150.0}), small);
      // Every point once: the copy in the tile that owns its node; tiles row by row, as
      // FarCells joins them, each streamed from its spill in batches of 2^16 points (far_cells.hpp:
      // a tile's cells, then the frontier, are held, not a tile's points).
      detail::PassProgress tick(progress, "tile_far_clusters", "coarse cells of every point, tile by tile", config.scale.progress_interval_s);
      const NodeBinner owner(tiles.g);
      constexpr std::size_t kBatch = std::size_t{1} << 16;
      std::vector<double> batch;
      batch.reserve(3 * kBatch);
      for (std::size_t t = 0; t < tiles.count(); ++t) {
        tick(static_cast<double>(t) / static_cast<double>(tiles.count()));
        const auto in = tiles.interior(t);
        cells.begin_tile(static_cast<int>(t / static_cast<std::size_t>(tiles.tiles_c)));
        spill->scan(t, [&](std::uint8_t, const double* p, const std::uint8_t*, float) {
          if (!owner.inside(p, in)) return;  // a halo copy: its own tile takes it
          batch.insert(batch.end(), p, p + 3);
          if (batch.size() == 3 * kBatch) {
            cells.add_points(batch.data(), kBatch);
            batch.clear();
          }
        });
        cells.add_points(batch.data(), batch.size() / 3);
        batch.clear();
        cells.end_tile();
      }
      const FarCells::Result fc = cells.components(far_d);
      r.report.count_in = grid_points;
      r.report.figure("link_mm", link * 1e3);
      r.report.figure("far_distance_mm", far_d * 1e3);
      r.report.figure("cell_mm", cells.edge() * 1e3);
      r.report.figure("cells", static_cast<double>(fc.cells));
      r.report.figure("frontier_cells_peak", static_cast<double>(fc.frontier_cells_peak));
      r.report.figure("tile_components", static_cast<double>(fc.tile_components));
      r.report.figure("listed_cells_peak", static_cast<double>(fc.listed_cells_peak));
      r.report.figure("clusters", static_cast<double>(fc.clusters));
      r.report.figure("far_clusters", static_cast<double>(fc.removed_clusters));
      r.report.figure("removed_far_clusters", static_cast<double>(fc.removed_points));
      r.report.figure("kept_far_clusters", static_cast<double>(fc.kept_far_clusters));
      for (const std::string& n : fc.notes) r.report.notes.push_back(n);
      plan.far_size_points = grid_points;  // before the far clusters go: as in core (remove_far_clusters_after)
      plan.far_extent_m = extent;
      if (fc.clusters > 0) {
        // A millionth of the extent wider than the main body's points' box (kept as float
        // offsets from the origin until the sixty-sixth session, which this slack covered): a
        // wider box only spares clusters, never removes one the in-core run keeps.
        const Eigen::Vector3d slack = Eigen::Vector3d::Constant(1e-6 * extent);
        plan.far_main_box_m = std::array<Eigen::Vector3d, 2>{fc.main_lo - slack, fc.main_hi + slack};
      }
      if (fc.removed_points > 0) {
        const std::uint64_t before = grid_points;
        // Most far clusters (stray returns in front of or behind the surface) leave the grid's
        // x-y box, and so the layout, as it was. Then a second spill would write the same
        // records in the same order (the same tiles of the same points), only with other
        // flags: kFarFlag on far points, 0 on the rest (the sample marks served tile_scale).
        // So the records are re-marked in place, and the box and upsample coverage without the
        // far points are taken from each point's copy in its own tile; only when the layout
        // changes are the points spilled again from the input (3 passes over it).
        const GridGeometry old_g = tiles.g;
        const int old_k = tiles.k;
        double x_min = std::numeric_limits<double>::infinity(), x_max = -x_min, y_min = x_min, y_max = -x_min;
        std::uint64_t kept = 0, far_owned = 0, copies = 0;
        std::optional<UpsampleCoverage> cov;
        // Auto upsampling: the layout stays only if the factor stays old_k, the first factor
        // whose coverage reaches kAutoUpsampleCoverage; that needs the coverages of factors 1 to
        // old_k, not of larger ones (factor() returns another value exactly when the full
        // range's search would). Coverage is not monotone in the points (an isolated hit lowers
        // it), so the smaller factors are tracked again.
        if (config.grid.reproject.upsample_factor == 0 && carried_k == 0) cov.emplace(old_g, 1, old_k);
        std::vector<double> own_kept;  // a tile's kept points, for the coverage in one batch
        const NodeBinner node(old_g);
        detail::PassProgress tick2(progress, "tile_far_clusters", "far points re-marked in the spill, tile by tile", config.scale.progress_interval_s);
        for (std::size_t t = 0; t < tiles.count(); ++t) {
          tick2(static_cast<double>(t) / static_cast<double>(tiles.count()));
          const auto in = tiles.interior(t);
          own_kept.clear();
          spill->remark(t, [&](const double* p) {
            ++copies;
            const bool far_point = cells.holds(p);
            if (node.inside(p, in)) {  // the point's own copy
              if (far_point) {
                ++far_owned;
              } else {
                ++kept;
                x_min = std::min(x_min, p[0]);
                x_max = std::max(x_max, p[0]);
                y_min = std::min(y_min, p[1]);
                y_max = std::max(y_max, p[1]);
                if (cov) {
                  own_kept.insert(own_kept.end(), p, p + 3);
                  if (own_kept.size() >= (std::size_t{3} << 20)) {  // bounded: at most 2^20 points held
                    cov->add(own_kept.data(), own_kept.size() / 3);
                    own_kept.clear();
                  }
                }
              }
            }
            return far_point ? kFarFlag : std::uint8_t{0};
          });
          if (cov) cov->add(own_kept.data(), own_kept.size() / 3);
        }
        bool same_layout = kept > 0;
        if (same_layout) {
          ro = config.grid.reproject;
          const GridGeometry new_g = grid_geometry_of(x_min, x_max, y_min, y_max, kept, ro);
          same_layout = new_g.rows == old_g.rows && new_g.cols == old_g.cols && new_g.x0_m == old_g.x0_m &&
                        new_g.y0_m == old_g.y0_m && new_g.cell_size_m == old_g.cell_size_m;
          if (same_layout && cov) {
            double without_far = 0.0;
            same_layout = cov->factor(&without_far) == old_k;
            if (same_layout) {
              r.report.figure("upsample_coverage", without_far);  // else lay_out reports it
              factor_counts.clear();
              take_counts(*cov, 1, old_k);
            }
          }
          ro.upsample_factor = old_k;
        }
        std::uint64_t spilled = kept;
        if (same_layout) {
          grid_points = kept;
          far_points = far_owned;
          r.report.count_in = box.points;  // as spill_pass reports it
          r.report.figure("second_spill", 0.0);
          r.report.figure("far_points_spilled_marked", static_cast<double>(far_points));
          r.report.figure("points_spilled", static_cast<double>(copies));
          r.report.figure("halo_copies_per_point", kept ? static_cast<double>(copies) / static_cast<double>(kept) : 0.0);
          r.report.figure("spill_bytes_peak_mb", static_cast<double>(spill->bytes()) / 1e6);
          r.report.notes.push_back("spill folder " + dir.string());
          r.report.notes.push_back("the grid's layout is unchanged without the far clusters: their points were re-marked in the spill files, not spilled again");
        } else {
          r.report.figure("second_spill", 1.0);
          lay_out(&cells, r.report);
          spilled = spill_pass(&cells, r.report, "tile_far_clusters");
        }
        // The plan's and the spill's figures describe the new layout.
        for (StageReport& rp : reports) {
          for (auto& [name, v] : rp.figures) {
            if (rp.stage == "tile_plan" && name == "rows") v = tiles.g.rows;
            if (rp.stage == "tile_plan" && name == "cols") v = tiles.g.cols;
            if (rp.stage == "tile_plan" && name == "tiles") v = static_cast<double>(tiles.count());
            if (rp.stage == "tile_plan" && name == "upsample_factor") v = tiles.k;
            if (rp.stage == "tile_plan" && name == "halo_cells") v = tiles.halo;
            if (rp.stage == "tile_plan" && name == "filter_halo_cells") v = tiles.filter;
            if (rp.stage == "tile_plan" && name == "despike_halo_cells") v = tiles.despike;
            if (rp.stage == "tile_plan" && name == "isolated_halo_cells") v = tiles.isolated;
            if (rp.stage == "tile_plan" && name == "tile_cells") v = tiles.size;
            if (rp.stage == "tile_plan" && name == "window_points_bound") v = static_cast<double>(window_points_bound);
          }
          if (rp.stage == "tile_plan") {
            rp.count_out = grid_points;
            if (!same_layout) rp.notes.push_back("rows, cols, tiles: after tile_far_clusters removed far clusters and laid the grid out again");
          }
        }
        if (!same_layout) {
          r.report.notes.push_back("grid laid out and points spilled again without the far clusters: " + std::to_string(tiles.g.rows) +
                                   " x " + std::to_string(tiles.g.cols) + " cells, " + std::to_string(tiles.count()) + " tiles");
        }
        r.report.count_out = spilled;
        plan.far_points = far_points;
        if (before - spilled != fc.removed_points || far_points != fc.removed_points) {
          throw std::logic_error("tiled run: far clusters held " + std::to_string(fc.removed_points) + " points, the spill left out " +
                                 std::to_string(before - spilled));
        }
      } else {
        r.report.count_out = grid_points;
        r.report.notes.push_back("no far cluster to remove");
      }
      return r;
    });
  }

  // The honest check's halo, before the tile loop: with the robust filter on, the check's
  // spacing is the robust test's sample's (stage tile_scale), known now, so a halo short of its
  // reach is refused here rather than after the whole tile loop (or, with tile jobs, at the
  // merge). Without it, the check after the loop decides on the tiles' median.
  if (const double s = robust_scale ? robust_scale->spacing_m : 0.0; config.cross_check.enabled && s > 0.0) {
    const HonestCheckOptions options = detail::honest_options_for(config, false, static_cast<double>(tiles.k), tiles.g.cell_size_m);
    check_honest_halo(config, tiles, options, s, "tile_scale", "the robust test's sample's; checked before the tile loop");
  }

  plan.tiles = tiles;
  plan.factor_counts = std::move(factor_counts);
  plan.factor_points = factor_points;
  plan.layout = box.layout;
  plan.robust_scale = robust_scale;
  plan.input_points = box.points;
  plan.grid_points = grid_points;
  plan.precision = precision;
  plan.offset_m = offset_m;
  plan.crs = crs;
  // The passes over the input are done: the inflated copies go now (a tile job's plan folder
  // keeps no copy of the input; the scratch folder would take them at the end anyway).
  for (const auto& [original, copy] : load.inflated) {
    std::error_code ec;
    fs::remove(copy, ec);
  }
  return plan;
}


// The heap a tile loop may keep past what it holds between tiles: the largest window's points
// (the spill's records) at detail::TileHeapBudget::kBytesPerWindowPoint.
std::size_t window_heap_budget(const Spill& spill, std::size_t tile_count) {
  std::size_t most = 0;
  for (std::size_t t = 0; t < tile_count; ++t) most = std::max(most, spill.records(t));
  return most * detail::TileHeapBudget::kBytesPerWindowPoint;
}

// Whether grid.upsample: auto could give another factor than the plan's (plan.tiles.k) to
// `kept_points` of the plan.factor_points it chose from (a subset: the filters only remove).
// Removing a point un-hits at most one node of a factor's grid, which takes one node out of
// the hit ones (O) and at most five out of those with their 4 neighbours hit (I, itself and its
// neighbours): with m removed, a factor's coverage I / O stays within [(I − 5m) / (O − m),
// I / (O − m)]. It may change when a factor below the plan's could reach
// kAutoUpsampleCoverage or the plan's fall below it. True when the plan's counts are not known
// (a factor carried over, a plan.json of an older build): then the kept points are read.
bool factor_may_change(const Plan& plan, std::uint64_t kept_points) {
  const std::size_t k = static_cast<std::size_t>(plan.tiles.k);
  if (plan.factor_counts.size() != k || kept_points > plan.factor_points) return true;
  const double m = static_cast<double>(plan.factor_points - kept_points);
  for (std::size_t j = 0; j < k; ++j) {
    const double o = static_cast<double>(plan.factor_counts[j][0]), i = static_cast<double>(plan.factor_counts[j][1]);
    if (!(o - m > 0.0)) return true;
    if (j + 1 < k && i / (o - m) >= kAutoUpsampleCoverage) return true;  // a smaller factor could pass
    if (j + 1 == k && (i - 5.0 * m) / (o - m) < kAutoUpsampleCoverage) return true;  // the plan's could fail
  }
  return false;
}

// The factor grid.upsample: auto gives on grid g (UpsampleCoverage over every factor) the
// interior points the tiles kept (KeptMask, read through the spill) and, with `despiked`, the
// points their despike removed (TileMerge::despiked_m): those the in-core run's filters keep
// before its despike; without, those it leaves. One read of the kept points, counted in
// merged.factor_reads (figure upsample_factor_reads of stage tiles).
int kept_points_factor(TileMerge& merged, const Plan& plan, const KeptMask& kept, const GridGeometry& g,
                       const std::vector<std::array<double, 3>>* despiked) {
  ++merged.factor_reads;
  UpsampleCoverage cov(g, 1, kMaxUpsampleFactor);
  std::vector<std::uint8_t> flag;
  std::vector<double> own;
  for (std::size_t t = 0; t < plan.tiles.count(); ++t) {
    const Cloud pts = kept.read(t, flag);
    own.clear();
    for (std::size_t i = 0; i < pts.size(); ++i) {
      if (flag[i] == 1) own.insert(own.end(), pts.xyz.data() + 3 * i, pts.xyz.data() + 3 * i + 3);
    }
    cov.add(own.data(), own.size() / 3);
  }
  if (despiked != nullptr) {
    for (const auto& p : *despiked) cov.add(p.data(), 1);
  }
  double coverage = 0.0;
  return cov.factor(&coverage);
}

// ---------------------------------------------------------------------------------------------
// Steps 4 to 6 on the gathered tiles: the whole grid, the merged cross-check, the surface layers.
// `built.summary.stages` holds the plan's and the tile loop's reports.
BuiltScene finish_tiled(const RunConfig& config, const Plan& plan, TileMerge& merged, const Spill& spill, const KeptMask& kept,
                        BuiltScene built, const ProgressFn& progress, detail::Clock::time_point t_start) {
  RunSummary& summary = built.summary;
  auto& reports = summary.stages;
  Scene& scene = built.scene;
  const Tiles& tiles = plan.tiles;
  DepthGrid& grid = merged.grid;
  const Eigen::Vector3d& offset_m = plan.offset_m;
  scene.provenance.crs = plan.crs;
  scene.provenance.inputs.insert(scene.provenance.inputs.end(), plan.inputs.begin(), plan.inputs.end());
  // The levels table's sample: every stride-th interior kept point in tile order, taken in the
  // cross-check's first pass over the kept points (or a pass of its own without it).
  // Also with the cross-check on (whose first pass takes it at no extra read): a tiled scene
  // stores it for `hapticloud levels` (points_sample.bin, lod_report.hpp); at most
  // lod.report_sample_points points (200 000: 4.8 MB).
  const bool keep_sample = keeps_sample(config) || config.cross_check.enabled;
  const std::size_t stride = sample_stride_of(config, plan.input_points);
  std::vector<double> sample_xyz;
  std::size_t interior_seen = 0;
  bool sampled = false;
  auto sample_point = [&](const double* p) {
    if (interior_seen++ % stride == 0) sample_xyz.insert(sample_xyz.end(), p, p + 3);
  };

  // The windows' despike took every group of at most island_max_cells cells as an island
  // (HonestCheckOptions::spare_largest_group off), as the in-core run does where the whole grid's
  // largest group is larger: shown where some window's cells that are the whole grid's hold such
  // a group. Otherwise (a grid of specks only) the in-core run spares its largest speck, which no
  // window can name: a warning, the scenes may differ about that speck.
  for (StageReport& rep : reports) {
    if (rep.stage != "tiles" || detail::figure_of(rep, "sum_tiles_with_a_group_past_island_max_cells", 1.0) != 0.0) continue;
    rep.notes.push_back("warning: no tile's window held a group of more than cross_check.island_max_cells = " +
                        std::to_string(config.cross_check.honest.island_max_cells) +
                        " valid cells (a grid of specks only): the tiles' despike took every group as an island, where an "
                        "in-core run spares the whole grid's largest group, so the scenes may differ about that group "
                        "(scale.tiled: off gives the in-core one)");
    summary.warnings.push_back(rep.notes.back().substr(9));
  }

  // 4. The whole grid, as in core; its surface layers after the checks (step 6), which do not
  // read them, so that their 16 bytes a sample are not held beside the checks' windows.
  const std::size_t grid_report = reports.size() - 1;
  const Eigen::Affine3d model_to_grid =
      detail::scene_from_grid(grid, config, reports, progress, plan.precision, offset_m, grid_report, built);
  // Level 0's file-backed layers (scale.level0_file): their pages given back to the kernel after
  // each sweep and each tile below, so that the page cache, not the run, holds them.
  // (The depth is still `grid`'s; scene_from_grid moved the other layers into the scene.)
  auto release_level0 = [&] {
    grid.release_resident();
    scene.layers.release_resident();
  };
  release_level0();

  // 5. The cross-check, per tile, merged.
  if (config.cross_check.enabled) {
    summary.cross_check = stage("cross_check", reports, progress, [&] {
      StageResult<CrossCheck> r;
      CrossCheck& cc = r.value;
      cc.tolerance_m = config.cross_check.tolerance_m;
      cc.hidden_band_m = config.cross_check.hidden_band_m;
      cc.cell_error_m = level0_layer(config, tiles.g, kept.dir(), "the cross-check's error map");
      cc.cell_error_m.model_to_grid = model_to_grid;
      auto release_maps = [&] {
        release_level0();
        cc.cell_error_m.values().release_resident();
      };
      const BilinearSurface surface(HeightFieldView::of(grid.depth));
      RadixPercentiles vertical, normal;
      std::vector<std::uint8_t> flag;
      // The in-core search's float frame (cross_check_frame_centre of the whole grid): every
      // tile's search and the search again below take it, so that the error map is the in-core
      // one bit for bit (since 2026-11-30; before, each tile's own frame, to float rounding).
      const Eigen::Vector3d frame_centre = detail::cross_check_frame_centre(grid.depth);
      release_level0();
      // Samples whose nearest point may lie beyond their tile's halo (judged on the tile's
      // distance): found again over the interior points of every tile their search disc
      // reaches (brute force: few samples on a grid made from the points), with the in-core
      // search's float arithmetic (squared distances in float in its frame).
      struct Far {
        int r, c;
        double best_m;  ///< the tile's recorded distance (infinity: none), then the least found [m]
        float best_sq = std::numeric_limits<float>::infinity();  ///< the search again's least squared distance
      };
      std::vector<Far> unverified;
      std::size_t researched = 0, improved = 0;
      // Freed heap back past a window's worth before a tile's points are read (TileHeapBudget).
      detail::TileHeapBudget heap(window_heap_budget(spill, tiles.count()));
      auto research = [&](std::vector<Far>& far) {
        if (far.empty()) return;
        researched = far.size();
        const double cell = tiles.g.cell_size_m;
        std::vector<std::uint8_t> fl;
        for (std::size_t t = 0; t < tiles.count(); ++t) {
          const auto in = tiles.interior(t);
          const double x_lo = tiles.g.x_of_col(in[2]) - 0.5 * cell, x_hi = tiles.g.x_of_col(in[3] - 1) + 0.5 * cell;
          const double y_lo = tiles.g.y_of_row(in[0]) - 0.5 * cell, y_hi = tiles.g.y_of_row(in[1] - 1) + 0.5 * cell;
          std::vector<std::size_t> mine;
          for (std::size_t f = 0; f < far.size(); ++f) {
            const double qx = tiles.g.x_of_col(far[f].c), qy = tiles.g.y_of_row(far[f].r);
            const double dx = std::max({x_lo - qx, 0.0, qx - x_hi}), dy = std::max({y_lo - qy, 0.0, qy - y_hi});
            const double reach_m = far[f].best_m * (1.0 + 1e-6);  // the float distances' rounding
            if (dx * dx + dy * dy <= reach_m * reach_m) mine.push_back(f);
          }
          if (mine.empty()) continue;
          (void)heap.before_tile();
          const Cloud pts = kept.read(t, fl);
          for (const std::size_t f : mine) {
            const float q[3] = {static_cast<float>(tiles.g.x_of_col(far[f].c) - frame_centre.x()),
                                static_cast<float>(tiles.g.y_of_row(far[f].r) - frame_centre.y()),
                                static_cast<float>(static_cast<double>(grid.depth.at(far[f].r, far[f].c)) - frame_centre.z())};
            float best_sq = far[f].best_sq;
            for (std::size_t i = 0; i < pts.size(); ++i) {
              if (fl[i] == 0) continue;
              const double* p = pts.xyz.data() + 3 * i;
              const float dx = static_cast<float>(p[0] - frame_centre.x()) - q[0];
              const float dy = static_cast<float>(p[1] - frame_centre.y()) - q[1];
              const float dz = static_cast<float>(p[2] - frame_centre.z()) - q[2];
              best_sq = std::min(best_sq, dx * dx + dy * dy + dz * dz);
            }
            far[f].best_sq = best_sq;
          }
        }
        // The least of the tile's and the search again's: recording (√, to float) is monotone,
        // so this is the record of the least squared distance, as the in-core search's.
        for (Far& f : far) {
          if (!std::isfinite(f.best_sq)) continue;
          const float again = detail::cross_check_recorded_distance(f.best_sq);
          if (!(static_cast<double>(again) < f.best_m)) continue;
          f.best_m = static_cast<double>(again);
          cc.cell_error_m.at(f.r, f.c) = again;
          ++improved;
        }
      };
      detail::PassProgress tick(progress, "cross_check", "the tiles' kept points, then their residuals again", config.scale.progress_interval_s);
      ResidualFile residuals(kept.dir() / "cross_check_residuals.bin");
      // The first pass over the kept points.
      for (std::size_t t = 0; t < tiles.count(); ++t) {
        tick(0.9 * static_cast<double>(t) / static_cast<double>(tiles.count()));
        (void)heap.before_tile();
        release_maps();
        const Cloud pts = kept.read(t, flag);
        // The points come in spill order, at random cells of the whole grid (32 MB at N = 4096):
        // each one's two grid rows fetched kAhead points before it is evaluated.
        constexpr std::size_t kAhead = 8;
        for (std::size_t i = 0; i < pts.size(); ++i) {
          if (i + kAhead < pts.size()) {
            const double* ahead = pts.xyz.data() + 3 * (i + kAhead);
            surface.prefetch(ahead[0], ahead[1]);
          }
          if (flag[i] == 0) continue;  // a halo copy: its own tile counts it
          const double* p = pts.xyz.data() + 3 * i;
          if (keep_sample) sample_point(p);
          const PointResidual pr = point_residual(surface, tiles.g, p[0], p[1], p[2], cc.hidden_band_m);
          switch (pr.kind) {
            case PointResidual::kOutside: ++cc.points_outside; break;
            case PointResidual::kOffSurface: ++cc.points_off_surface; break;
            case PointResidual::kHidden: ++cc.points_hidden; break;
            case PointResidual::kOnSurface:
              ++cc.points_on_surface;
              vertical.pass1(pr.vertical_m);
              normal.pass1(pr.normal_m);
              residuals.put(pr.vertical_m, pr.normal_m);
              break;
          }
        }
        if (pts.size() == 0) {
          // No kept point here (a tile of hole-filled cells): its valid cells are searched
          // over the other tiles.
          const auto in = tiles.interior(t);
          for (int rr = in[0]; rr < in[1]; ++rr)
            for (int c = in[2]; c < in[3]; ++c)
              if (!std::isnan(grid.depth.at(rr, c))) unverified.push_back({rr, c, std::numeric_limits<double>::infinity()});
        }
        if (pts.size() > 0) {
          // (b): the window's valid samples against the tile's kept points (halo included).
          const GridWindow w = tiles.window(t);
          const auto in = tiles.interior(t);
          const GridGeometry wg = tiles.part(w.row0, w.col0, w.rows, w.cols);
          HeightField crop(wg);
          std::size_t valid = 0;
          for (int rr = 0; rr < w.rows; ++rr)
            for (int c = 0; c < w.cols; ++c) {
              crop.at(rr, c) = grid.depth.at(w.row0 + rr, w.col0 + c);
              valid += std::isnan(crop.at(rr, c)) ? 0U : 1U;
            }
          if (valid == 0 || w.rows < 2 || w.cols < 2) continue;
          // Only the interior's samples are searched (the window's halo samples are other tiles'
          // interiors); the halo's points and heights still set the search and its frame.
          // In the whole grid's float frame and at its sample positions, as the in-core search.
          const detail::CellErrorFrame frame{tiles.g, w.row0, w.col0, frame_centre};
          const CrossCheck part = detail::cross_check_cell_errors(pts, crop, cc.tolerance_m, cc.hidden_band_m,
                                                                  {in[0] - w.row0, in[1] - w.row0, in[2] - w.col0, in[3] - w.col0}, &frame)
                                      .value;
          // A point outside the window has its node outside it: at least (index distance −
          // 1/2) cells from the query in x-y. A distance beyond that margin is re-searched
          // over every tile's points below.
          const double cell = tiles.g.cell_size_m;
          for (int rr = in[0]; rr < in[1]; ++rr) {
            for (int c = in[2]; c < in[3]; ++c) {
              const float d = part.cell_error_m.at(rr - w.row0, c - w.col0);
              cc.cell_error_m.at(rr, c) = d;
              if (std::isnan(d)) continue;
              int edge = std::numeric_limits<int>::max();
              if (w.row0 > 0) edge = std::min(edge, rr - w.row0 + 1);
              if (w.col0 > 0) edge = std::min(edge, c - w.col0 + 1);
              if (w.row0 + w.rows < tiles.g.rows) edge = std::min(edge, w.row0 + w.rows - rr);
              if (w.col0 + w.cols < tiles.g.cols) edge = std::min(edge, w.col0 + w.cols - c);
              if (edge != std::numeric_limits<int>::max() && static_cast<double>(d) > (edge - 0.5) * cell) {
                unverified.push_back({rr, c, static_cast<double>(d)});
              }
            }
          }
        }
      }
      sampled = keep_sample;
      vertical.prepare();
      normal.prepare();
      research(unverified);
      tick(0.9);
      // The second pass of the exact percentiles, over the first pass's residuals.
      residuals.each([&](float v, float nrm) {
        vertical.pass2(v);
        normal.pass2(nrm);
      });
      cc.point_vertical = vertical.stats();
      cc.point_normal = normal.stats();
      // The supported cells' errors: exact percentiles by two passes over the error map
      // (RadixPercentiles, the nearest ranks error_stats_mm takes; the squares summed in the
      // same row-major order), so no copy of 4 bytes a cell (fifty-sixth session).
      RadixPercentiles cell_errors;
      std::size_t supported = 0, valid = 0;
      const float* depth = grid.depth.data();
      const float* error = cc.cell_error_m.data();
      for (std::size_t i = 0; i < tiles.g.cell_count(); ++i) {
        if (i % kReleaseEveryCells == kReleaseEveryCells - 1) release_maps();
        if (std::isnan(depth[i])) continue;
        ++valid;
        const float d = error[i];
        if (std::isnan(d)) continue;  // a valid cell no tile's points could reach: not supported
        cell_errors.pass1(d);
        supported += d <= cc.tolerance_m ? 1U : 0U;
      }
      if (valid == 0) throw InputError("cross_check: the grid has no valid cell (tiled run)");
      cell_errors.prepare();
      for (std::size_t i = 0; i < tiles.g.cell_count(); ++i) {
        if (i % kReleaseEveryCells == kReleaseEveryCells - 1) release_maps();
        if (!std::isnan(depth[i]) && !std::isnan(error[i])) cell_errors.pass2(error[i]);
      }
      cc.cell_to_point = cell_errors.stats();
      release_maps();
      cc.supported_fraction = valid ? static_cast<double>(supported) / static_cast<double>(valid) : 0.0;
      r.report.count_in = cc.points_on_surface + cc.points_off_surface + cc.points_hidden + cc.points_outside;
      r.report.count_out = valid;
      add_error_stats_figures(r.report, "point_vertical", cc.point_vertical);
      add_error_stats_figures(r.report, "point_normal", cc.point_normal);
      add_error_stats_figures(r.report, "cell_to_point", cc.cell_to_point);
      r.report.figure("points_on_surface", static_cast<double>(cc.points_on_surface));
      r.report.figure("points_off_surface", static_cast<double>(cc.points_off_surface));
      r.report.figure("points_hidden", static_cast<double>(cc.points_hidden));
      r.report.figure("points_outside", static_cast<double>(cc.points_outside));
      r.report.figure("tolerance_mm", cc.tolerance_m * 1e3);
      r.report.figure("supported_fraction", cc.supported_fraction);
      r.report.figure("samples_researched_across_tiles", static_cast<double>(researched));
      r.report.figure("samples_nearer_in_another_tile", static_cast<double>(improved));
      // Where the filters removed a point that set the box, the in-core run's grid differs from
      // this one: said, not silent (docs/scale.md, "What equals the in-core run"). The kept
      // points' box is the tiles' (TileMerge::after_box: the points each owns after its filters
      // and despike, those the kept masks hold), which the in-core run lays its grid on.
      if (const XyBox& kb = merged.after_box; kb.points > 0) {
        const GridGeometry g_core = grid_for_box(config, tiles, kb);
        if (!(g_core == tiles.g)) {
          r.report.notes.push_back(
              "warning: the kept points span x " + format_number(kb.x_lo) + " to " + format_number(kb.x_hi) + " m, y " +
              format_number(kb.y_lo) + " to " + format_number(kb.y_hi) + " m; the grid was laid on the points before the outlier "
              "filters (" + grid_words(tiles.g) + "); an in-core run lays it on the kept points (" + grid_words(g_core) +
              "), so its scene differs from this one; " +
              (config.scale.grid_on_kept_points
                   ? std::string()
                   : std::string("scale.grid_on_kept_points: true (the default) lays it on the kept points by starting again; ")) +
              "scale.tiled: off gives the in-core grid");
          summary.warnings.push_back(r.report.notes.back().substr(9));
        } else if (const ScaleConfig::GridBox* gb = config.scale.grid_box ? &*config.scale.grid_box : nullptr;
                   config.grid.reproject.upsample_factor == 0 && (!config.scale.grid_on_kept_points || (gb != nullptr && gb->last)) &&
                   factor_may_change(plan, kb.points)) {
          // grid.upsample: auto where no later attempt checks the factor (scale.grid_on_kept_points
          // false, or the last attempt): the kept points' own, said where it differs, not silent.
          if (const int k_core = kept_points_factor(merged, plan, kept, tiles.g, nullptr); k_core != tiles.k) {
            r.report.notes.push_back("warning: grid.upsample: auto gives the kept points factor " + std::to_string(k_core) + ", not " +
                                     std::to_string(tiles.k) + " as chosen before the outlier filters; an in-core run upsamples them by " +
                                     std::to_string(k_core) + ", so its scene differs from this one; " +
                                     (config.scale.grid_on_kept_points
                                          ? std::string()
                                          : std::string("scale.grid_on_kept_points: true (the default) takes their factor by starting again; ")) +
                                     "scale.tiled: off gives the in-core grid");
            summary.warnings.push_back(r.report.notes.back().substr(9));
          }
        }
      }
      r.report.notes.push_back("merged over " + std::to_string(tiles.count()) +
                               " tiles: (a) per interior point on the whole grid (exact percentiles by radix selection), "
                               "(b) per interior cell against its tile's kept points, halo included");
      return r;
    });

    // 5b. The honest cross-check (honest_check.hpp), tile by tile: each tile's input points as
    // spilled (those it removed flagged from its kept-point mask) against the whole grid's cells
    // over its window, counting what the tile owns (InputCheckScope); the grid's own spike, pit
    // and island test on the whole grid; then the verdict, as in core.
    struct Honest {
      InputCheck input;
      GridSpikes spikes;
    };
    Honest honest = stage("honest_check", reports, progress, [&] {
      StageResult<Honest> r;
      const HonestCheckOptions options =
          detail::honest_options_for(config, false, static_cast<double>(tiles.k), tiles.g.cell_size_m);
      InputCheck& in = r.value.input;
      // The whole run's spacing: the robust test's sample's, as in core; without the robust
      // filter, the tiles' spacings, their median weighted by points.
      double spacing_m = plan.robust_scale ? plan.robust_scale->spacing_m : 0.0;
      const bool from_sample = spacing_m > 0.0;
      if (!from_sample) {
        std::vector<std::pair<double, std::uint64_t>> sp = merged.spacings;
        std::sort(sp.begin(), sp.end());
        std::uint64_t total = 0, acc = 0;
        for (const auto& e : sp) total += e.second;
        for (const auto& e : sp) {
          acc += e.second;
          if (2 * acc >= total) {
            spacing_m = e.first;
            break;
          }
        }
      }
      if (!(spacing_m > 0.0)) spacing_m = tiles.g.cell_size_m;  // no tile had two points: the cell
      // The point test and the spike searches see a tile's points within their reach only when
      // the halo holds it: a search that would leave it is an error (issue 14), not an edge where
      // points count as isolated. With the robust filter on, plan_passes checked this already
      // (the spacing is the robust sample's); without it, the spacing is known only once every
      // tile has run, so it comes here (or, with tile jobs, at the merge).
      const double reach_m = honest_reach_m(options, spacing_m);
      r.report.figure("halo_mm", tiles.halo * tiles.g.cell_size_m * 1e3);
      r.report.figure("reach_mm", reach_m * 1e3);
      check_honest_halo(config, tiles, options, spacing_m, "honest_check",
                        from_sample ? "the robust test's sample's"
                                    : "the tiles' median, measured on their windows, which a wider halo changes a little");
      r.value.spikes = find_grid_spikes(grid.depth, options);
      release_level0();
      GridSpikes& spikes = r.value.spikes;
      spikes.confirmed = 0;
      // The box of the whole grid's valid samples (far points).
      InputCheckScope scope;
      scope.spacing_m = spacing_m;
      scope.whole = &grid.depth;  // the points' classes on the whole grid, as in core
      {
        int r_lo = tiles.g.rows, r_hi = -1, c_lo = tiles.g.cols, c_hi = -1;
        float z_lo = std::numeric_limits<float>::infinity(), z_hi = -z_lo;
        for (int rr = 0; rr < tiles.g.rows; ++rr) {
          if (rr % 256 == 255) release_level0();
          for (int c = 0; c < tiles.g.cols; ++c) {
            const float z = grid.depth.at(rr, c);
            if (std::isnan(z)) continue;
            r_lo = std::min(r_lo, rr), r_hi = std::max(r_hi, rr), c_lo = std::min(c_lo, c), c_hi = std::max(c_hi, c);
            z_lo = std::min(z_lo, z), z_hi = std::max(z_hi, z);
          }
        }
        if (r_hi < 0) throw InputError("honest check: the grid has no valid cell (tiled run)");
        scope.valid_lo = Eigen::Vector3d(tiles.g.x_of_col(c_lo), tiles.g.y_of_row(r_lo), z_lo);
        scope.valid_hi = Eigen::Vector3d(tiles.g.x_of_col(c_hi), tiles.g.y_of_row(r_hi), z_hi);
      }
      release_level0();
      // The flagged spike and pit cells by tile.
      std::vector<std::vector<std::array<int, 2>>> flagged_in(tiles.count());
      for (const auto& rc : spikes.flagged) {
        flagged_in[static_cast<std::size_t>(rc[0] / tiles.size) * static_cast<std::size_t>(tiles.tiles_c) +
                   static_cast<std::size_t>(rc[1] / tiles.size)]
            .push_back(rc);
      }
      const CellBuffer<std::uint8_t>& flags = scene.layers.flags;
      std::vector<std::uint8_t> fl_in, removed, near, owned;
      detail::PassProgress tick(progress, "honest_check", "the input as spilled against the grid, tile by tile",
                        config.scale.progress_interval_s);
      detail::TileHeapBudget heap(window_heap_budget(spill, tiles.count()));  // as the tile loop
      for (std::size_t t = 0; t < tiles.count(); ++t) {
        tick(static_cast<double>(t) / static_cast<double>(tiles.count()));
        (void)heap.before_tile();
        release_level0();
        const Cloud input = spill.read(t, fl_in);
        if (input.size() == 0) continue;
        kept.removed(t, removed, near);  // the mask, instead of a copy of the kept points matched back
        const GridWindow w = tiles.window(t);
        const auto inner = tiles.interior(t);
        owned_by(tiles, t, input, owned);
        const GridGeometry wg = tiles.part(w.row0, w.col0, w.rows, w.cols);
        HeightField crop(wg);
        CellBuffer<std::uint8_t> crop_flags(wg.cell_count(), 0);
        for (int rr = 0; rr < w.rows; ++rr)
          for (int c = 0; c < w.cols; ++c) {
            crop.at(rr, c) = grid.depth.at(w.row0 + rr, w.col0 + c);
            crop_flags[static_cast<std::size_t>(rr) * static_cast<std::size_t>(w.cols) + static_cast<std::size_t>(c)] =
                flags[static_cast<std::size_t>(w.row0 + rr) * static_cast<std::size_t>(tiles.g.cols) + static_cast<std::size_t>(w.col0 + c)];
          }
        GridSpikes local;
        for (const auto& rc : flagged_in[t]) local.flagged.push_back({rc[0] - w.row0, rc[1] - w.col0});
        scope.owned = &owned;
        scope.removed = &removed;
        scope.near = &near;
        scope.cells = {inner[0] - w.row0, inner[1] - w.row0, inner[2] - w.col0, inner[3] - w.col0};
        const InputCheck part = check_input(input.xyz, Cloud{}, crop, options, 0.0, &local, &crop_flags, &scope);
        in.add_classes(part);
        in.isolated += part.isolated;
        in.isolation_tested += part.isolation_tested;
        in.isolation_hashed += part.isolation_hashed;
        in.spikes_kept += part.spikes_kept;
        for (const auto& rc : part.spikes_kept_cells) {
          if (in.spikes_kept_cells.size() < 100) in.spikes_kept_cells.push_back({rc[0] + w.row0, rc[1] + w.col0});
        }
        spikes.confirmed += local.confirmed;
        in.spacing_m = part.spacing_m;
        in.isolation_radius_m = part.isolation_radius_m;
      }
      // The points the plan's passes dropped (non-finite, outside filters.crop) were removed
      // before the spill: counted as removed, not classified.
      const std::uint64_t dropped = plan.input_points - plan.grid_points - plan.far_points;
      in.points += dropped;
      in.removed += dropped;
      if (in.spacing_m == 0.0) in.spacing_m = spacing_m;
      detail::add_honest_figures(in, spikes, r.report);
      r.report.figure("tiles", static_cast<double>(tiles.count()));
      r.report.figure("isolation_points_tested", static_cast<double>(in.isolation_tested));
      r.report.figure("isolation_points_hashed", static_cast<double>(in.isolation_hashed));
      r.report.notes.push_back("tiled run: each tile's input points (as spilled: after units, recentring, view, non-finite and "
                               "crop) and kept points against the whole grid over its window; the spacing is the tiles' "
                               "median weighted by points; " + std::to_string(dropped) +
                               " points dropped before the spill (non-finite, crop) count as removed");
      return r;
    });
    const double supported = summary.cross_check->supported_fraction;
    summary.verdict = decide_verdict(honest.input, honest.spikes, supported, reports, config.cross_check.honest);
    summary.input_check = std::move(honest.input);
    summary.grid_spikes = std::move(honest.spikes);
  }
  // The scratch disk level 0's file-backed layers take while the scene holds them
  // (scale.level0_file), beside the spill's spill_bytes_peak_mb.
  double level0_file_bytes = 0.0;
  auto count_file = [&level0_file_bytes](const auto& cells) {
    if (cells.file_backed()) level0_file_bytes += static_cast<double>(cells.size() * sizeof(cells[0]));
  };
  count_file(grid.depth.values());
  count_file(scene.layers.flags);
  count_file(scene.layers.colour_rgb8);
  count_file(scene.layers.intensity.values());
  if (summary.cross_check) count_file(summary.cross_check->cell_error_m.values());
  // And how often the kept points were read for grid.upsample: auto's factor (kept_points_factor:
  // the attempts' check, and the cross-check stage's warning; 0 where the plan's counts showed
  // the removals cannot move it).
  for (StageReport& rep : reports) {
    if (rep.stage != "tiles") continue;
    detail::set_figure(rep, "upsample_factor_reads", static_cast<double>(merged.factor_reads));
    detail::set_figure(rep, "level0_file_mb", level0_file_bytes / 1e6);
  }
  // 6. The surface layers of the whole grid (or, for a tiled scene, left to its level builder);
  // then the cross-check's error map into the scene.
  detail::scene_surface_layers(grid.depth, config, reports, progress, built);
  // Moved, not copied (4 bytes a cell; a copy made the write stage hold two): the summary's
  // map is the scene's layer (RunSummary::cross_check).
  if (summary.cross_check) {
    scene.layers.cell_error = std::move(summary.cross_check->cell_error_m);
    summary.cross_check->cell_error_m = HeightField();
  }
  release_level0();
  if (keep_sample && !sampled) {
    std::vector<std::uint8_t> flag;
    for (std::size_t t = 0; t < tiles.count(); ++t) {
      const Cloud pts = kept.read(t, flag);
      for (std::size_t i = 0; i < pts.size(); ++i)
        if (flag[i] != 0) sample_point(pts.xyz.data() + 3 * i);
    }
  }
  if (keep_sample && !sample_xyz.empty()) {
    Cloud sample;
    sample.xyz = Eigen::Map<const Eigen::Matrix3Xd>(sample_xyz.data(), 3, static_cast<Eigen::Index>(sample_xyz.size() / 3));
    built.point_sample = std::move(sample);
    built.point_sample_of = interior_seen;
  }
  scene.layers.depth = std::move(grid.depth);

  scene.layer_options = config.layers.options;
  scene.lod = config.lod;
  SceneProvenance& prov = scene.provenance;
  prov.tool = std::string("hapticloud ") + HC_VERSION;
  prov.config_file = config.source.string();
  prov.units = config.input.units;
  prov.recentre_offset_m = offset_m;
  prov.resolved_config_yaml = config.resolved_yaml;
  summary.total_seconds = detail::seconds_since(t_start);
  return built;
}

// ---------------------------------------------------------------------------------------------
// Tile jobs in other processes: plan.json, part_<t>.bin, kept_<t>.bin.

// 4: layout.xyz_floats, and spill records of the file's floats when it is set (FileFloats);
// 5: the input files as a list (inputs); 6: the halo's shares under auto (tiles'
// despike_halo_cells, isolated_halo_cells; 2026-11-29);
// 7: the grid's box from an earlier plan's kept points (grid_box; 2026-11-30);
// 8: the whole scan's extent for the far clusters' check (far_extent_m; 2026-11-30).
constexpr const char* kPlanFormat = "hapticloud tile plan 8";
// 2: kept_<t>.bin is a mask over the spill (KeptMask), not the kept points.
// 3: the kept points' boxes (scale.grid_on_kept_points); 4: the despike's removed points;
// 5: the far clusters' link cells (TileOutput::link_cells; 2026-11-30).
constexpr char kPartMagic[12] = {'H', 'C', 'T', 'I', 'L', 'E', 'P', 'A', 'R', 'T', '6', '\n'};
constexpr char kPartEnd[4] = {'E', 'N', 'D', '\n'};

// Doubles as C99 hexadecimal floats ("%a"), so every value reads back to the same bits.
std::string hex(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%a", v);
  return buf;
}

double unhex(const nlohmann::json& j, const fs::path& file, const char* key) {
  if (!j.is_string()) throw InputError(file.string() + ": " + key + " is not a hexadecimal float string (as hapticloud writes it)");
  const std::string s = j.get<std::string>();
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (end == s.c_str() || *end != '\0') throw InputError(file.string() + ": " + key + " = \"" + s + "\" is not a number");
  return v;
}

// Probe points for a float spill's frame (plan.json layout.xyz_floats.check): 16 float x y z
// [file units] about the frame's centre, spread over ±2^10 units with every fraction bit of the
// float used (SplitMix64, fixed seeds), so that an arithmetic that rounds otherwise (an FMA, a
// compiler or Eigen that sums the view in another order) gives another double for some of them.
std::vector<std::array<float, 3>> xyz_floats_probes(const FileFloats& ff) {
  std::vector<std::array<float, 3>> out(16);
  for (std::size_t i = 0; i < out.size(); ++i) {
    for (std::size_t a = 0; a < 3; ++a) {
      const std::uint64_t h = detail::splitmix64(0x5EEDu + 3 * i + a);
      const double offset = (static_cast<double>(h >> 11) * 0x1p-53 - 0.5) * 2048.0;  // [-1024, 1024)
      out[i][a] = static_cast<float>(ff.centre[static_cast<Eigen::Index>(a)] + offset);
    }
  }
  return out;
}

std::string random_id();

// This host's name with every character but letters and digits made '_' (empty when unknown).
std::string host_tag() {
  char host[256] = {0};
  if (::gethostname(host, sizeof host - 1) != 0) host[0] = '\0';
  std::string h;
  for (const char* c = host; *c; ++c) h.push_back(std::isalnum(static_cast<unsigned char>(*c)) ? *c : '_');
  return h;
}

// A name no other attempt uses, even on another host sharing the folder (host, process, random).
std::string attempt_tag() { return host_tag() + "-" + std::to_string(::getpid()) + "-" + random_id(); }

}  // namespace

void detail::write_atomically(const fs::path& target, const std::string& bytes) {
  const fs::path tmp = target.parent_path() / ("." + target.filename().string() + std::string(kTmpInfix) + attempt_tag());
  // Removed however this ends (after the rename, nothing is left to remove); SIGINT/SIGTERM
  // (hapticloud's signal watcher) removes it while it is written.
  const LiveScratchFile temp(tmp);
  std::FILE* f = open_live_scratch_file(tmp, "wb");
  const bool ok = f && std::fwrite(bytes.data(), 1, bytes.size(), f) == bytes.size() && std::fflush(f) == 0 &&
                  ::fsync(::fileno(f)) == 0;
  const int err = errno;
  const bool closed = f && std::fclose(f) == 0;
  if (!ok || !closed) {
    throw InputError("cannot write " + target.string() + ": " + std::strerror(ok ? errno : err) + " (is the disk full?)");
  }
  std::error_code ec;
  rename_live_scratch(tmp, target, ec);
  if (ec) throw InputError("cannot write " + target.string() + ": " + ec.message());
}

namespace {

std::string read_file_bytes(const fs::path& file, const char* what) {
  std::FILE* f = std::fopen(file.c_str(), "rb");
  if (!f) throw InputError(std::string(what) + " " + file.string() + " cannot be opened: " + std::strerror(errno));
  std::string s;
  char buf[1 << 16];
  std::size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) s.append(buf, n);
  const bool err = std::ferror(f) != 0;
  std::fclose(f);
  if (err) throw InputError(std::string(what) + " " + file.string() + " cannot be read");
  return s;
}

// What plan.json holds besides the Plan.
struct PlanFile {
  Plan plan;
  fs::path dir;
  std::string id;  // random, 16 hex digits: a part file of another plan is refused
  fs::path config_file;
  std::vector<std::string> overrides;
  std::string resolved_yaml;
  std::vector<std::uintmax_t> spill_bytes;  // tile_<t>.bin sizes as written
  // The box a tile-merge of an earlier plan found the grid is to be laid on
  // (scale.grid_on_kept_points; tile-plan --grid-box), set as the config's scale.grid_box; and
  // the lines saying why, one per earlier plan (its tile_plan notes).
  std::optional<ScaleConfig::GridBox> grid_box;
  std::vector<std::string> grid_why;
};

// A string that must read back byte for byte: as is when it is UTF-8, else {"hex": its bytes}.
nlohmann::json text(const std::string& s) {
  try {
    (void)nlohmann::json(s).dump();
    return s;
  } catch (const nlohmann::json::type_error&) {
    std::string h;
    char b[3];
    for (const unsigned char c : s) {
      std::snprintf(b, sizeof b, "%02x", c);
      h += b;
    }
    return nlohmann::json{{"hex", h}};
  }
}

std::string untext(const nlohmann::json& j) {
  if (j.is_string()) return j.get<std::string>();
  const std::string h = j.at("hex").get<std::string>();
  if (h.size() % 2 != 0) throw nlohmann::json::other_error::create(501, "odd hex string", &j);
  std::string s;
  for (std::size_t i = 0; i < h.size(); i += 2) s.push_back(static_cast<char>(std::stoi(h.substr(i, 2), nullptr, 16)));
  return s;
}

nlohmann::json report_json(const StageReport& r) {
  nlohmann::json figures = nlohmann::json::array();
  for (const auto& [name, v] : r.figures) figures.push_back({name, hex(v)});
  return {{"stage", r.stage},     {"count_in", r.count_in}, {"count_out", r.count_out}, {"seconds", hex(r.seconds)},
          {"peak_rss_bytes", r.peak_rss_bytes}, {"figures", figures},   {"notes", r.notes}};
}

// A ScaleConfig::GridBox as plan.json and grid_box.json hold it: its bounds [m] as hexadecimal
// floats, its point count, `last`, the upsample factor (0: the plan's choice), the despike's removed points [m] (sorted, as
// grid_on_kept_points leaves them; null: none taken over) and the despike's figures.
nlohmann::json grid_box_json(const ScaleConfig::GridBox& b) {
  nlohmann::json j{{"x_min_m", hex(b.x_min_m)}, {"x_max_m", hex(b.x_max_m)}, {"y_min_m", hex(b.y_min_m)},
                   {"y_max_m", hex(b.y_max_m)}, {"points", b.points},          {"last", b.last},
                   {"upsample_factor", b.upsample_factor}};
  j["despiked_m"] = nullptr;
  if (b.despiked_m) {
    j["despiked_m"] = nlohmann::json::array();
    for (const auto& p : *b.despiked_m) j["despiked_m"].push_back({hex(p[0]), hex(p[1]), hex(p[2])});
  }
  j["despike_sums"] = nlohmann::json::object();
  for (const auto& [name, v] : b.despike_sums) j["despike_sums"][name] = hex(v);
  return j;
}

// grid_box_json's object `j`, found at `key` of `file`.
// @throws InputError naming file and key for a missing or mistyped member, a coordinate that is
//         not finite, a minimum above its maximum, no points, or removed points out of order.
ScaleConfig::GridBox grid_box_of(const nlohmann::json& j, const fs::path& file, const std::string& key) {
  const auto finite = [&](const nlohmann::json& v, const std::string& k) {
    const double d = unhex(v, file, k.c_str());
    if (!std::isfinite(d)) throw InputError(file.string() + ": " + k + " is " + format_number(d) + ", expected a finite coordinate [m]");
    return d;
  };
  ScaleConfig::GridBox b;
  b.x_min_m = finite(j.at("x_min_m"), key + ".x_min_m");
  b.x_max_m = finite(j.at("x_max_m"), key + ".x_max_m");
  b.y_min_m = finite(j.at("y_min_m"), key + ".y_min_m");
  b.y_max_m = finite(j.at("y_max_m"), key + ".y_max_m");
  if (!(b.x_min_m <= b.x_max_m && b.y_min_m <= b.y_max_m)) {
    throw InputError(file.string() + ": " + key + " has a minimum above its maximum (expected x_min_m <= x_max_m and y_min_m <= y_max_m)");
  }
  if (!j.at("points").is_number_unsigned() || j.at("points").get<std::uint64_t>() == 0) {
    throw InputError(file.string() + ": " + key + ".points is " + j.at("points").dump() +
                     ", expected the count of the points the box holds (a whole number >= 1)");
  }
  b.points = j.at("points").get<std::uint64_t>();
  b.last = j.at("last").get<bool>();
  if (j.contains("upsample_factor")) {  // absent in the files of builds before 2026-11-30: 0
    const auto& k = j.at("upsample_factor");
    if (!k.is_number_integer() || k.get<int>() < 0 || k.get<int>() > kMaxUpsampleFactor) {
      throw InputError(file.string() + ": " + key + ".upsample_factor is " + k.dump() + ", expected 0 (the plan chooses) or a factor 1 to " +
                       std::to_string(kMaxUpsampleFactor));
    }
    b.upsample_factor = k.get<int>();
  }
  if (const auto& d = j.at("despiked_m"); !d.is_null()) {
    if (!d.is_array()) throw InputError(file.string() + ": " + key + ".despiked_m is not a list of points (x y z [m]) or null");
    auto v = std::make_shared<std::vector<std::array<double, 3>>>();
    v->reserve(d.size());
    for (std::size_t i = 0; i < d.size(); ++i) {
      const std::string k = key + ".despiked_m[" + std::to_string(i) + "]";
      if (!d[i].is_array() || d[i].size() != 3) throw InputError(file.string() + ": " + k + " is not 3 numbers (x y z [m])");
      v->push_back({finite(d[i][0], k), finite(d[i][1], k), finite(d[i][2], k)});
    }
    if (!std::is_sorted(v->begin(), v->end())) {
      throw InputError(file.string() + ": " + key + ".despiked_m is not in increasing order of x, y, z (as tile-merge writes it)");
    }
    b.despiked_m = std::move(v);
  }
  if (!j.at("despike_sums").is_object()) {
    throw InputError(file.string() + ": " + key + ".despike_sums is " + j.at("despike_sums").dump() +
                     ", expected an object of the despike's figures (name: hexadecimal float)");
  }
  if (b.despiked_m && j.at("despike_sums").empty()) {
    throw InputError(file.string() + ": " + key + ".despike_sums is empty where despiked_m lists the despike's removed points "
                     "(expected its figures beside them, as tile-merge writes them)");
  }
  for (const auto& [name, v] : j.at("despike_sums").items()) {
    b.despike_sums[name] = unhex(v, file, (key + ".despike_sums." + name).c_str());
  }
  return b;
}

void write_plan_file(const PlanFile& pf) {
  const Plan& p = pf.plan;
  const Tiles& t = p.tiles;
  nlohmann::json j;
  j["format"] = kPlanFormat;
  j["id"] = pf.id;
  j["config_file"] = text(pf.config_file.string());
  j["overrides"] = nlohmann::json::array();
  for (const auto& o : pf.overrides) j["overrides"].push_back(text(o));
  j["resolved_yaml"] = text(pf.resolved_yaml);
  j["tiles"] = {{"count", t.count()},         {"rows", t.g.rows},           {"cols", t.g.cols},
                {"x0_m", hex(t.g.x0_m)},       {"y0_m", hex(t.g.y0_m)},       {"cell_size_m", hex(t.g.cell_size_m)},
                {"upsample_factor", t.k},     {"tile_cells", t.size},       {"halo_cells", t.halo},
                {"filter_halo_cells", t.filter}, {"despike_halo_cells", t.despike}, {"isolated_halo_cells", t.isolated},
                {"tiles_r", t.tiles_r},    {"tiles_c", t.tiles_c}};
  j["spill_bytes"] = pf.spill_bytes;
  j["layout"] = {{"rgb", p.layout.rgb}, {"intensity", p.layout.intensity}, {"xyz_floats", nullptr}};
  if (const auto& ff = p.layout.floats) {
    auto& x = j["layout"]["xyz_floats"];
    x["centre"] = {hex(ff->centre.x()), hex(ff->centre.y()), hex(ff->centre.z())};
    x["unit_m"] = hex(ff->unit_m);
    x["turned"] = ff->turned;
    x["linear"] = nlohmann::json::array();
    for (int i = 0; i < 9; ++i) x["linear"].push_back(hex(ff->linear(i / 3, i % 3)));
    x["translation_m"] = {hex(ff->translation_m.x()), hex(ff->translation_m.y()), hex(ff->translation_m.z())};
    // The plan's own arithmetic on probe points: a job or merge of another build that takes the
    // spill's floats to other doubles refuses the plan (read_plan_file).
    x["check"] = nlohmann::json::array();
    for (const auto& f : xyz_floats_probes(*ff)) {
      double g[3];
      ff->to_grid(f.data(), g);
      x["check"].push_back({hex(f[0]), hex(f[1]), hex(f[2]), hex(g[0]), hex(g[1]), hex(g[2])});
    }
  }
  j["robust_scale"] = p.robust_scale ? nlohmann::json{{"median_log", hex(p.robust_scale->median_log)},
                                                      {"mad_log", hex(p.robust_scale->mad_log)},
                                                      {"sample", p.robust_scale->sample},
                                                      {"spacing_m", hex(p.robust_scale->spacing_m)}}
                                     : nlohmann::json();
  if (p.robust_scale && p.robust_scale->centre_m) {
    const auto& c = *p.robust_scale->centre_m;
    j["robust_scale"]["centre_m"] = {hex(c[0]), hex(c[1]), hex(c[2])};
  }
  j["input_points"] = p.input_points;
  j["grid_points"] = p.grid_points;
  j["far_points"] = p.far_points;
  j["far_main_box_m"] = p.far_main_box_m ? nlohmann::json{hex((*p.far_main_box_m)[0].x()), hex((*p.far_main_box_m)[0].y()),
                                                           hex((*p.far_main_box_m)[0].z()), hex((*p.far_main_box_m)[1].x()),
                                                           hex((*p.far_main_box_m)[1].y()), hex((*p.far_main_box_m)[1].z())}
                                         : nlohmann::json();
  j["far_size_points"] = p.far_size_points;
  j["far_extent_m"] = hex(p.far_extent_m);
  j["factor_counts"] = nlohmann::json::array();  // grid.upsample auto: {O, I} of factors 1 to k (factor_may_change)
  for (const auto& c : p.factor_counts) j["factor_counts"].push_back({c[0], c[1]});
  j["factor_points"] = p.factor_points;
  j["precision"] = {{"float32", p.precision.float32},
                    {"file", text(p.precision.file)},
                    {"crs", text(p.precision.crs)},
                    {"max_abs_m", {hex(p.precision.max_abs_m.x()), hex(p.precision.max_abs_m.y()), hex(p.precision.max_abs_m.z())}},
                    {"distinct", {p.precision.distinct.x(), p.precision.distinct.y(), p.precision.distinct.z()}}};
  j["offset_m"] = {hex(p.offset_m.x()), hex(p.offset_m.y()), hex(p.offset_m.z())};
  j["crs"] = text(p.crs);
  j["inputs"] = nlohmann::json::array();
  for (const SceneInput& in : p.inputs) j["inputs"].push_back({{"file", text(in.file)}, {"sha256", in.sha256}});
  nlohmann::json reports = nlohmann::json::array();
  for (const auto& r : p.reports) reports.push_back(report_json(r));
  j["reports"] = reports;
  j["grid_box"] = nullptr;
  if (pf.grid_box) {
    j["grid_box"] = grid_box_json(*pf.grid_box);
    j["grid_box"]["why"] = nlohmann::json::array();
    for (const std::string& w : pf.grid_why) j["grid_box"]["why"].push_back(text(w));
  }
  // Notes and figure names are for reading only: a byte that is not UTF-8 becomes U+FFFD.
  detail::write_atomically(pf.dir / "plan.json", j.dump(1, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
}

PlanFile read_plan_file(const fs::path& plan_file) {
  const std::string bytes = read_file_bytes(plan_file, "the tile plan");
  std::string where;
  PlanFile pf;
  pf.dir = plan_file.parent_path().empty() ? fs::path(".") : plan_file.parent_path();
  try {
    where = "the JSON text";
    const nlohmann::json j = nlohmann::json::parse(bytes);
    where = "format, id";
    if (j.value("format", std::string()) != kPlanFormat) {
      throw InputError(plan_file.string() + ": not a plan of this version (format is not \"" + kPlanFormat +
                       "\"; write it with hapticloud tile-plan)");
    }
    pf.id = j.at("id").get<std::string>();
    where = "config_file, overrides, resolved_yaml";
    pf.config_file = untext(j.at("config_file"));
    for (const auto& o : j.at("overrides")) pf.overrides.push_back(untext(o));
    pf.resolved_yaml = untext(j.at("resolved_yaml"));
    Plan& p = pf.plan;
    where = "tiles";
    const auto& t = j.at("tiles");
    p.tiles.g.rows = t.at("rows").get<int>();
    p.tiles.g.cols = t.at("cols").get<int>();
    p.tiles.g.x0_m = unhex(t.at("x0_m"), plan_file, "tiles.x0_m");
    p.tiles.g.y0_m = unhex(t.at("y0_m"), plan_file, "tiles.y0_m");
    p.tiles.g.cell_size_m = unhex(t.at("cell_size_m"), plan_file, "tiles.cell_size_m");
    p.tiles.k = t.at("upsample_factor").get<int>();
    p.tiles.size = t.at("tile_cells").get<int>();
    p.tiles.halo = t.at("halo_cells").get<int>();
    p.tiles.filter = t.at("filter_halo_cells").get<int>();
    p.tiles.despike = t.at("despike_halo_cells").get<int>();
    p.tiles.isolated = t.at("isolated_halo_cells").get<int>();
    p.tiles.tiles_r = t.at("tiles_r").get<int>();
    p.tiles.tiles_c = t.at("tiles_c").get<int>();
    if (p.tiles.g.rows < 1 || p.tiles.g.cols < 1 || p.tiles.size < 1 || p.tiles.k < 1 || p.tiles.halo < 0 ||
        p.tiles.filter < 0 || p.tiles.filter > p.tiles.halo || p.tiles.despike < 0 || p.tiles.isolated < 0 ||
        p.tiles.isolated + p.tiles.filter > p.tiles.halo || p.tiles.despike > p.tiles.halo ||
        p.tiles.tiles_r != (p.tiles.g.rows + p.tiles.size - 1) / p.tiles.size ||
        p.tiles.tiles_c != (p.tiles.g.cols + p.tiles.size - 1) / p.tiles.size || !(p.tiles.g.cell_size_m > 0.0)) {
      throw InputError(plan_file.string() + ": tiles does not describe a tiling of the grid (rows, cols, tile_cells, tiles_r, tiles_c, halo_cells, filter_halo_cells: at least 0 and at most halo_cells; despike_halo_cells and isolated_halo_cells: at least 0, despike_halo_cells and isolated_halo_cells + filter_halo_cells at most halo_cells)");
    }
    where = "spill_bytes";
    pf.spill_bytes = j.at("spill_bytes").get<std::vector<std::uintmax_t>>();
    if (pf.spill_bytes.size() != p.tiles.count()) {
      throw InputError(plan_file.string() + ": spill_bytes has " + std::to_string(pf.spill_bytes.size()) + " entries, expected " +
                       std::to_string(p.tiles.count()) + " (one per tile)");
    }
    where = "layout, robust_scale, input_points, grid_points, far_points, far_main_box_m, far_size_points, far_extent_m, precision, offset_m, crs, inputs";
    p.layout.rgb = j.at("layout").at("rgb").get<bool>();
    p.layout.intensity = j.at("layout").at("intensity").get<bool>();
    if (const auto& x = j.at("layout").at("xyz_floats"); !x.is_null()) {
      const std::string was = where;
      where = "layout.xyz_floats (centre, unit_m, turned, linear, translation_m, check)";
      FileFloats ff;
      const auto number = [&](const nlohmann::json& v, const std::string& key) {
        const double d = unhex(v, plan_file, key.c_str());
        if (!std::isfinite(d)) throw InputError(plan_file.string() + ": " + key + " is " + format_number(d) + ", expected a finite number");
        return d;
      };
      for (int a = 0; a < 3; ++a) {
        const auto i = static_cast<std::size_t>(a);
        ff.centre[a] = number(x.at("centre").at(i), "layout.xyz_floats.centre[" + std::to_string(a) + "]");
        ff.translation_m[a] = number(x.at("translation_m").at(i), "layout.xyz_floats.translation_m[" + std::to_string(a) + "]");
      }
      ff.unit_m = number(x.at("unit_m"), "layout.xyz_floats.unit_m");
      if (!(ff.unit_m > 0.0)) throw InputError(plan_file.string() + ": layout.xyz_floats.unit_m is " + format_number(ff.unit_m) + ", expected > 0 [m per file unit]");
      ff.turned = x.at("turned").get<bool>();
      if (!x.at("linear").is_array() || x.at("linear").size() != 9) {
        throw InputError(plan_file.string() + ": layout.xyz_floats.linear is not 9 numbers (the view's linear part, row by row)");
      }
      for (int i = 0; i < 9; ++i) {
        ff.linear(i / 3, i % 3) = number(x.at("linear").at(static_cast<std::size_t>(i)), "layout.xyz_floats.linear[" + std::to_string(i) + "]");
      }
      ff.inverse = ff.linear.inverse();
      // This build must take the spill's floats to the grid frame as the plan's build did, bit
      // for bit (the spill was checked against the plan's in-core arithmetic, not this one's).
      const std::vector<std::array<float, 3>> probes = xyz_floats_probes(ff);
      const auto& check = x.at("check");
      if (!check.is_array() || check.size() != probes.size()) {
        throw InputError(plan_file.string() + ": layout.xyz_floats.check is not " + std::to_string(probes.size()) +
                         " probe points (a plan written by another hapticloud version? write it again with tile-plan)");
      }
      for (std::size_t i = 0; i < probes.size(); ++i) {
        const std::string key = "layout.xyz_floats.check[" + std::to_string(i) + "]";
        if (!check[i].is_array() || check[i].size() != 6) throw InputError(plan_file.string() + ": " + key + " is not 6 numbers (x y z, then the grid frame's)");
        double want[6];
        for (std::size_t c = 0; c < 6; ++c) want[c] = unhex(check[i][c], plan_file, key.c_str());
        double got[3];
        ff.to_grid(probes[i].data(), got);
        const bool same_probe = want[0] == static_cast<double>(probes[i][0]) && want[1] == static_cast<double>(probes[i][1]) &&
                                want[2] == static_cast<double>(probes[i][2]);
        const bool same_frame = std::bit_cast<std::uint64_t>(got[0]) == std::bit_cast<std::uint64_t>(want[3]) &&
                                std::bit_cast<std::uint64_t>(got[1]) == std::bit_cast<std::uint64_t>(want[4]) &&
                                std::bit_cast<std::uint64_t>(got[2]) == std::bit_cast<std::uint64_t>(want[5]);
        const std::string fix = ": the spill would read back as other points; run tile-job and tile-merge with the build that "
                                "wrote the plan (this is hapticloud " + std::string(HC_VERSION) + "), or write the plan again with this one";
        if (!same_probe) {
          throw InputError(plan_file.string() + ": " + key + " probes the float point (" + hex(want[0]) + ", " + hex(want[1]) + ", " +
                           hex(want[2]) + "), where this build makes (" + hex(probes[i][0]) + ", " + hex(probes[i][1]) + ", " +
                           hex(probes[i][2]) + ")" + fix);
        }
        if (!same_frame) {
          throw InputError(plan_file.string() + ": " + key + ": this build takes the float point (" + hex(want[0]) + ", " + hex(want[1]) +
                           ", " + hex(want[2]) + ") to (" + hex(got[0]) + ", " + hex(got[1]) + ", " + hex(got[2]) +
                           ") m in the grid frame, where the plan's build took it to (" + hex(want[3]) + ", " + hex(want[4]) + ", " +
                           hex(want[5]) + ")" + fix);
        }
      }
      p.layout.floats = ff;
      where = was;
    }
    if (!j.at("robust_scale").is_null()) {
      const auto& rs = j.at("robust_scale");
      p.robust_scale = RobustScale{unhex(rs.at("median_log"), plan_file, "robust_scale.median_log"),
                                   unhex(rs.at("mad_log"), plan_file, "robust_scale.mad_log"), rs.at("sample").get<std::size_t>(),
                                   unhex(rs.at("spacing_m"), plan_file, "robust_scale.spacing_m")};
      if (rs.contains("centre_m")) {  // written since 2026-11-28 (fifty-first session)
        const auto& c = rs.at("centre_m");
        if (!c.is_array() || c.size() != 3) {
          throw InputError(plan_file.string() + ": robust_scale.centre_m is " + c.dump() + ", expected 3 numbers (x y z [m])");
        }
        std::array<double, 3> v{};
        for (std::size_t a = 0; a < 3; ++a) {
          v[a] = unhex(c.at(a), plan_file, "robust_scale.centre_m");
          if (!std::isfinite(v[a])) {
            throw InputError(plan_file.string() + ": robust_scale.centre_m holds " + format_number(v[a]) + ", expected finite coordinates [m]");
          }
        }
        p.robust_scale->centre_m = v;
      }
      if (!std::isfinite(p.robust_scale->spacing_m) || p.robust_scale->spacing_m < 0.0) {
        throw InputError(plan_file.string() + ": robust_scale.spacing_m is " + format_number(p.robust_scale->spacing_m) +
                         ", expected a finite spacing >= 0 [m] (0: unknown)");
      }
    }
    p.input_points = j.at("input_points").get<std::uint64_t>();
    p.grid_points = j.at("grid_points").get<std::uint64_t>();
    p.far_points = j.at("far_points").get<std::uint64_t>();
    if (!j.at("far_main_box_m").is_null()) {
      const auto& b = j.at("far_main_box_m");
      if (!b.is_array() || b.size() != 6) throw InputError(plan_file.string() + ": far_main_box_m is not 6 numbers (x, y, z min, then max)");
      std::array<Eigen::Vector3d, 2> box;
      for (std::size_t i = 0; i < 6; ++i) {
        const std::string key = "far_main_box_m[" + std::to_string(i) + "]";
        const double v = unhex(b.at(i), plan_file, key.c_str());
        if (!std::isfinite(v)) throw InputError(plan_file.string() + ": " + key + " is " + format_number(v) + ", expected a finite coordinate [m]");
        box[i / 3][static_cast<Eigen::Index>(i % 3)] = v;
      }
      if (!(box[0].array() <= box[1].array()).all()) {
        throw InputError(plan_file.string() + ": far_main_box_m has a minimum above its maximum (expected x, y, z min, then max)");
      }
      p.far_main_box_m = box;
    }
    p.far_size_points = j.at("far_size_points").get<std::uint64_t>();
    p.far_extent_m = unhex(j.at("far_extent_m"), plan_file, "far_extent_m");
    if (j.contains("factor_counts")) {  // absent in plans of builds before 2026-11-30: none known (the merge reads the kept points)
      where = "factor_counts, factor_points";
      for (const auto& c : j.at("factor_counts")) p.factor_counts.push_back({c.at(0).get<std::uint64_t>(), c.at(1).get<std::uint64_t>()});
      p.factor_points = j.at("factor_points").get<std::uint64_t>();
      if (!p.factor_counts.empty() && p.factor_counts.size() != static_cast<std::size_t>(p.tiles.k)) {
        throw InputError(plan_file.string() + ": factor_counts holds " + std::to_string(p.factor_counts.size()) +
                         " factors' counts, expected none or one per factor up to upsample_factor " + std::to_string(p.tiles.k));
      }
    }
    const auto& pr = j.at("precision");
    p.precision.float32 = pr.at("float32").get<bool>();
    p.precision.file = untext(pr.at("file"));
    p.precision.crs = untext(pr.at("crs"));
    for (int a = 0; a < 3; ++a) {
      p.precision.max_abs_m[a] = unhex(pr.at("max_abs_m").at(static_cast<std::size_t>(a)), plan_file, "precision.max_abs_m");
      p.precision.distinct[a] = pr.at("distinct").at(static_cast<std::size_t>(a)).get<int>();
      p.offset_m[a] = unhex(j.at("offset_m").at(static_cast<std::size_t>(a)), plan_file, "offset_m");
    }
    p.crs = untext(j.at("crs"));
    for (const auto& in : j.at("inputs")) p.inputs.push_back({untext(in.at("file")), in.at("sha256").get<std::string>()});
    where = "reports";
    for (const auto& rj : j.at("reports")) {
      StageReport r;
      r.stage = rj.at("stage").get<std::string>();
      r.count_in = rj.at("count_in").get<std::size_t>();
      r.count_out = rj.at("count_out").get<std::size_t>();
      r.seconds = unhex(rj.at("seconds"), plan_file, "reports[].seconds");
      r.peak_rss_bytes = rj.at("peak_rss_bytes").get<std::size_t>();
      for (const auto& fj : rj.at("figures")) r.figure(fj.at(0).get<std::string>(), unhex(fj.at(1), plan_file, "reports[].figures"));
      r.notes = rj.at("notes").get<std::vector<std::string>>();
      p.reports.push_back(std::move(r));
    }
    where = "grid_box";
    if (const auto& gb = j.at("grid_box"); !gb.is_null()) {
      pf.grid_box = grid_box_of(gb, plan_file, "grid_box");
      for (const auto& w : gb.at("why")) pf.grid_why.push_back(untext(w));
    }
  } catch (const nlohmann::json::exception& e) {
    throw InputError(plan_file.string() + ": " + where + ": not as hapticloud tile-plan writes it (" + e.what() + ")");
  } catch (const std::logic_error& e) {  // std::stoi of a hex text
    throw InputError(plan_file.string() + ": " + where + ": not as hapticloud tile-plan writes it (" + e.what() + ")");
  }
  return pf;
}

// The run config the plan was made with; refused if its file or the overrides now resolve to
// other values (the tiles would not fit together).
RunConfig config_of(const PlanFile& pf, const fs::path& plan_file) {
  RunConfig config = load_run_config(pf.config_file, pf.overrides);
  if (config.resolved_yaml != pf.resolved_yaml) {
    throw ConfigError(plan_file.string() + ": the config " + pf.config_file.string() +
                      " (with the plan's --set overrides) resolves to other values than when the plan was made; make a new plan "
                      "(hapticloud tile-plan)");
  }
  config.scale.grid_box = pf.grid_box;  // not a key: tile-plan --grid-box
  return config;
}

fs::path part_file(const fs::path& dir, std::size_t t) { return dir / ("part_" + std::to_string(t) + ".bin"); }

template <class T>
void put(std::string& s, const T& v) {
  s.append(reinterpret_cast<const char*>(&v), sizeof v);
}

std::string encode_part(const std::string& plan_id, const TileOutput& o) {
  std::string s(kPartMagic, sizeof kPartMagic);
  s += plan_id;
  put(s, static_cast<std::uint64_t>(o.tile));
  put(s, o.in);
  put(s, o.out);
  put(s, o.unjudged);
  put(s, static_cast<std::uint64_t>(o.kept_bytes));
  put(s, o.seconds);
  put(s, static_cast<std::uint64_t>(o.sums.size()));
  for (const auto& [name, v] : o.sums) {
    put(s, static_cast<std::uint32_t>(name.size()));
    s += name;
    put(s, v);
  }
  put(s, o.spacing_m);
  put(s, o.spacing_points);
  for (const XyBox* b : {&o.kept_box, &o.after_box}) {
    put(s, b->x_lo);
    put(s, b->x_hi);
    put(s, b->y_lo);
    put(s, b->y_hi);
    put(s, b->points);
  }
  put(s, static_cast<std::uint64_t>(o.despiked_m.size()));
  for (const auto& p : o.despiked_m) s.append(reinterpret_cast<const char*>(p.data()), sizeof p);
  put(s, o.link_m);
  put(s, static_cast<std::uint8_t>(o.link_cells_partial));
  put(s, static_cast<std::uint64_t>(o.link_cells.size()));
  for (const TileOutput::LinkCell& c : o.link_cells) {
    put(s, c.key);
    put(s, c.count);
    for (const double v : c.lo) put(s, v);
    for (const double v : c.hi) put(s, v);
  }
  put(s, static_cast<std::uint64_t>(o.far_clusters_hit.size()));
  for (const std::uint32_t c : o.far_clusters_hit) put(s, c);
  const DepthGrid& g = o.interior;
  const std::int32_t rows = g.depth.rows(), cols = g.depth.cols();
  put(s, rows);
  put(s, cols);
  put(s, static_cast<std::uint8_t>(g.has_colour()));
  put(s, static_cast<std::uint8_t>(g.has_intensity()));
  if (rows > 0) {
    const GridGeometry& geo = g.depth.geometry();
    put(s, geo.x0_m);
    put(s, geo.y0_m);
    put(s, geo.cell_size_m);
    s.append(reinterpret_cast<const char*>(g.depth.data()), g.depth.values().size() * sizeof(float));
    s.append(reinterpret_cast<const char*>(g.flags.data()), g.flags.size());
    if (g.has_colour()) s.append(reinterpret_cast<const char*>(g.colour_rgb8.data()), g.colour_rgb8.size());
    if (g.has_intensity()) s.append(reinterpret_cast<const char*>(g.intensity.data()), g.intensity.values().size() * sizeof(float));
  }
  s.append(kPartEnd, sizeof kPartEnd);
  return s;
}

class PartReader {
 public:
  PartReader(std::string bytes, fs::path file) : b_(std::move(bytes)), file_(std::move(file)) {}
  void take(void* out, std::size_t n) {
    if (n > b_.size() - at_) bad("truncated");
    std::memcpy(out, b_.data() + at_, n);
    at_ += n;
  }
  template <class T>
  T get() {
    T v;
    take(&v, sizeof v);
    return v;
  }
  std::string str(std::size_t n) {
    if (n > b_.size() - at_) bad("truncated");
    std::string s = b_.substr(at_, n);
    at_ += n;
    return s;
  }
  bool at_end() const { return at_ == b_.size(); }
  std::size_t left() const { return b_.size() - at_; }
  [[noreturn]] void bad(const std::string& why) const {
    throw InputError(file_.string() + ": " + why + " (not a complete tile result of this plan; run its tile-job again)");
  }

 private:
  std::string b_;
  fs::path file_;
  std::size_t at_ = 0;
};

TileOutput decode_part(const fs::path& file, const std::string& plan_id, std::size_t t, const Tiles& tiles) {
  PartReader r(read_file_bytes(file, "the tile result"), file);
  const std::string magic = r.str(sizeof kPartMagic);
  if (magic != std::string(kPartMagic, sizeof kPartMagic)) {
    r.bad(magic.rfind("HCTILEPART", 0) == 0 ? "a tile result of another hapticloud version (" + magic.substr(0, sizeof kPartMagic - 1) +
                                                  ", expected " + std::string(kPartMagic, sizeof kPartMagic - 1) + ")"
                                            : std::string("not a tile result"));
  }
  if (r.str(plan_id.size()) != plan_id) r.bad("written for another plan");
  TileOutput o;
  o.tile = static_cast<std::size_t>(r.get<std::uint64_t>());
  if (o.tile != t) r.bad("holds tile " + std::to_string(o.tile) + ", expected " + std::to_string(t));
  o.in = r.get<std::uint64_t>();
  o.out = r.get<std::uint64_t>();
  o.unjudged = r.get<std::uint64_t>();
  o.kept_bytes = static_cast<std::uintmax_t>(r.get<std::uint64_t>());
  o.seconds = r.get<double>();
  const auto n_sums = r.get<std::uint64_t>();
  for (std::uint64_t i = 0; i < n_sums; ++i) {
    const auto len = r.get<std::uint32_t>();
    std::string name = r.str(len);
    o.sums[name] = r.get<double>();
  }
  o.spacing_m = r.get<double>();
  o.spacing_points = r.get<std::uint64_t>();
  for (XyBox* b : {&o.kept_box, &o.after_box}) {
    b->x_lo = r.get<double>();
    b->x_hi = r.get<double>();
    b->y_lo = r.get<double>();
    b->y_hi = r.get<double>();
    b->points = r.get<std::uint64_t>();
  }
  const auto n_despiked = r.get<std::uint64_t>();
  if (n_despiked > o.in || n_despiked > r.left() / (3 * sizeof(double))) {
    r.bad("lists " + std::to_string(n_despiked) + " despiked points of " + std::to_string(o.in) + " input points in " +
          std::to_string(r.left()) + " bytes left");
  }
  o.despiked_m.resize(static_cast<std::size_t>(n_despiked));
  for (auto& p : o.despiked_m) r.take(p.data(), sizeof p);
  o.link_m = r.get<double>();
  o.link_cells_partial = r.get<std::uint8_t>() != 0;
  const auto n_cells = r.get<std::uint64_t>();
  if (n_cells > 0 && !(std::isfinite(o.link_m) && o.link_m > 0.0)) r.bad("its far-cluster link cells have a link of " + format_number(o.link_m) + " m");
  constexpr std::size_t kCellBytes = 2 * sizeof(std::uint64_t) + 6 * sizeof(double);
  if (n_cells > o.in || n_cells > r.left() / kCellBytes) {
    r.bad("lists " + std::to_string(n_cells) + " far-cluster link cells of " + std::to_string(o.in) + " input points in " +
          std::to_string(r.left()) + " bytes left");
  }
  o.link_cells.resize(static_cast<std::size_t>(n_cells));
  for (TileOutput::LinkCell& c : o.link_cells) {
    c.key = r.get<std::uint64_t>();
    c.count = r.get<std::uint64_t>();
    if (c.key == FarCells::kNoKey || c.count == 0 || c.count > o.in) r.bad("holds a far-cluster link cell without a key or points");
    for (double& v : c.lo) v = r.get<double>();
    for (double& v : c.hi) v = r.get<double>();
  }
  const auto n_hit = r.get<std::uint64_t>();
  if (n_hit > o.in || n_hit > r.left() / sizeof(std::uint32_t)) {
    r.bad("lists " + std::to_string(n_hit) + " far clusters hit of " + std::to_string(o.in) + " input points in " + std::to_string(r.left()) +
          " bytes left");
  }
  o.far_clusters_hit.resize(static_cast<std::size_t>(n_hit));
  for (std::uint32_t& c : o.far_clusters_hit) c = r.get<std::uint32_t>();
  const auto rows = r.get<std::int32_t>(), cols = r.get<std::int32_t>();
  const bool colour = r.get<std::uint8_t>() != 0, intensity = r.get<std::uint8_t>() != 0;
  if (rows > 0) {
    const auto in = tiles.interior(t);
    if (rows != in[1] - in[0] || cols != in[3] - in[2]) r.bad("its grid is " + std::to_string(rows) + " x " + std::to_string(cols) + " cells, not the tile's interior");
    GridGeometry g = tiles.g;
    g.rows = rows;
    g.cols = cols;
    g.x0_m = r.get<double>();
    g.y0_m = r.get<double>();
    g.cell_size_m = r.get<double>();
    DepthGrid& d = o.interior;
    d.depth = HeightField(g);
    r.take(d.depth.data(), g.cell_count() * sizeof(float));
    d.flags.assign(g.cell_count(), 0);
    r.take(d.flags.data(), d.flags.size());
    if (colour) {
      d.colour_rgb8.assign(3 * g.cell_count(), 0);
      r.take(d.colour_rgb8.data(), d.colour_rgb8.size());
    }
    if (intensity) {
      d.intensity = HeightField(g);
      r.take(d.intensity.data(), g.cell_count() * sizeof(float));
    }
  }
  if (r.str(sizeof kPartEnd) != std::string(kPartEnd, sizeof kPartEnd) || !r.at_end()) r.bad("its end marker is missing");
  return o;
}

// Removes, on failure, what a tile plan created (the folder when it made it, else the files).
class PlanCleanup {
 public:
  // SIGINT/SIGTERM (hapticloud's signal watcher) removes the same: the folder when this made it,
  // else the entries the plan writes (tile_<t>.bin, plan.json and its temporary).
  PlanCleanup(fs::path dir, bool made_dir) : dir_(std::move(dir)), made_(made_dir) {
    if (made_) {
      register_live_scratch_dir(dir_);
    } else {
      register_live_scratch_entries(dir_, {"tile_", "plan.json", ".plan.json"});
    }
  }
  ~PlanCleanup() {
    unregister();
    if (done_) return;
    std::error_code ec;
    if (made_) {
      fs::remove_all(dir_, ec);
      return;
    }
    std::vector<fs::path> ours;
    for (fs::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec)) {
      const std::string n = it->path().filename().string();
      if (n.rfind("tile_", 0) == 0 || n == "plan.json") ours.push_back(it->path());
    }
    for (const auto& f : ours) fs::remove(f, ec);
  }
  PlanCleanup(const PlanCleanup&) = delete;
  PlanCleanup& operator=(const PlanCleanup&) = delete;
  void keep() {
    unregister();
    done_ = true;
  }

 private:
  void unregister() noexcept {
    if (made_) {
      unregister_live_scratch_dir(dir_);
    } else {
      unregister_live_scratch_entries(dir_);
    }
  }

  fs::path dir_;
  bool made_;
  bool done_ = false;
};

std::string random_id() {
  std::random_device rd;
  const std::uint64_t v = (static_cast<std::uint64_t>(rd()) << 32) ^ rd() ^
                          static_cast<std::uint64_t>(std::chrono::steady_clock::now().time_since_epoch().count());
  char buf[17];
  std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(v));
  return buf;
}

}  // namespace

namespace {
BuiltScene build_scene_tiled_once(const RunConfig& config, const ProgressFn& progress, SurfaceLayersAt layers,
                                  detail::Clock::time_point t_start);

// Thrown by build_scene_tiled_once after its tile loop (scale.grid_on_kept_points, no
// ScaleConfig::grid_box yet) when the outlier filters removed a point that set the x-y box the
// grid was laid on: the in-core run lays it on `box`, the kept points' box, as `kept`.
struct GridOnKeptPoints : std::runtime_error {
  GridOnKeptPoints(ScaleConfig::GridBox b, const GridGeometry& f, const GridGeometry& k, bool d, int k_first = 0)
      : std::runtime_error("tiled run: the grid is to be laid on the kept points (caught by build_scene_tiled)"),
        box(std::move(b)), first(f), kept(k), after_despike(d), first_factor(k_first) {}
  ScaleConfig::GridBox box;
  GridGeometry first, kept;
  bool after_despike = false;  // the box left after the despike (its removals taken over)
  int first_factor = 0;        // the attempt's upsample factor, where box.upsample_factor differs from it
  // Only the factor moved: the grid is the attempt's.
  bool factor_only() const { return first_factor > 0 && first == kept; }
  std::string island_halo_widened;  // the warning, when the attempt ran with the wider grid share
};

// Where exact_far_clusters found that the in-core run's far clusters (`far`) hold points the
// tiles kept and every spill is still there (in process; at tile-merge always): the tiles whose
// windows hold a point in their cells (tiles_holding) are processed again by `again`, given the
// config with ScaleConfig::far_cells set and the tiles' list, which feeds each new output to
// `merged` (TileMerge::add replaces a tile's output; its third argument takes the share of their
// sweeps done, for `progress`); the totals are then made again. Those tiles
// remove the kept points in the clusters' cells, so the scene is the in-core run's (docs/scale.md,
// "Far clusters exact"). Figures far_tiles_again, far_tiles_again_s and far_tiles_again_cpu_s
// (the wall and process CPU seconds of `again`) and notes on `r` (stage tiles).
// @throws std::logic_error when the owners did not remove exactly the clusters' points (a bug).
void far_tiles_again(const RunConfig& config, const Tiles& tiles, std::shared_ptr<const ScaleConfig::FarCellKeys> far, TileMerge& merged,
                     StageReport& r, const ProgressFn& progress,
                     const std::function<void(const RunConfig&, const std::vector<std::size_t>&, const std::function<void(double)>&)>& again) {
  const std::vector<std::size_t> list = tiles_holding(tiles, *far);
  RunConfig fix = config;
  fix.scale.far_cells = far;
  detail::PassProgress tick(progress, "tiles", "the tiles holding far clusters the tiles kept, processed again", config.scale.progress_interval_s);
  const auto t_again = detail::Clock::now();
  const double cpu_again = detail::process_cpu_seconds();
  again(fix, list, [&](double f) { tick(f); });
  r.figure("far_tiles_again_s", detail::seconds_since(t_again));
  r.figure("far_tiles_again_cpu_s", detail::process_cpu_seconds() - cpu_again);
  merged.finish();
  const auto it = merged.sums.find("far_points_owned");
  const double removed = it != merged.sums.end() ? it->second : 0.0;
  if (removed != static_cast<double>(far->points)) {
    throw std::logic_error("tiled run: the " + std::to_string(list.size()) + " tiles processed again removed " + format_number(removed) +
                           " owned points in the far clusters' cells, which hold " + std::to_string(far->points));
  }
  r.figure("far_tiles_again", static_cast<double>(list.size()));
  r.notes.push_back("far clusters: the whole scan's, joined from the tiles' kept points, hold " + std::to_string(far->points) +
                    " points in " + std::to_string(far->clusters) + " clusters, more than the tiles removed (they judge far "
                    "clusters only where a window holds them whole): the " + std::to_string(list.size()) +
                    " tiles whose windows hold them were processed again, removing the kept points in their " +
                    std::to_string(far->keys.size()) + " cells");
  for (const std::string& n : far->notes) r.notes.push_back(n);
}

// Thrown by build_scene_tiled_once after its tile loop when the in-core run's far clusters
// hold points the tiles kept (exact_far_clusters) and the spills are gone (no tile can be
// processed again): build_scene_tiled starts again carrying their
// cells (ScaleConfig::far_cells).
struct FarCellsAgain : std::runtime_error {
  explicit FarCellsAgain(std::shared_ptr<const ScaleConfig::FarCellKeys> c)
      : std::runtime_error("tiled run: far clusters to be removed by their cells (caught by build_scene_tiled)"), cells(std::move(c)) {}
  std::shared_ptr<const ScaleConfig::FarCellKeys> cells;
  std::string island_halo_widened;  // as GridOnKeptPoints'
};

// scale.grid_on_kept_points after a tile loop (in process or merged from tile jobs): where the
// points the tiles' filters kept (TileMerge::kept_box), or those their despike left
// (after_box), give another grid than the plan's, the box the next attempt lays its grid on.
// First the filters' box (the despike must judge on its grid), then the despike's (its removals
// taken over: GridBox::despiked_m, despike_sums). None when the key is false, the plan's box is
// already the despike's or the last one (GridBox::last), or the grids agree.
std::optional<GridOnKeptPoints> grid_on_kept_points(const RunConfig& config, const Plan& plan, TileMerge& merged, const KeptMask& kept) {
  const ScaleConfig::GridBox* now_box = config.scale.grid_box ? &*config.scale.grid_box : nullptr;
  const bool checks = config.scale.grid_on_kept_points && !(now_box != nullptr && (now_box->despiked_m || now_box->last));
  if (!checks || merged.kept_box.points == 0) return std::nullopt;
  const auto geometry = [&](const XyBox& b) { return grid_for_box(config, plan.tiles, b); };
  const auto box_of = [](const XyBox& b) {
    ScaleConfig::GridBox g;
    g.x_min_m = b.x_lo, g.x_max_m = b.x_hi, g.y_min_m = b.y_lo, g.y_max_m = b.y_hi, g.points = b.points;
    return g;
  };
  // grid.upsample: auto: the in-core run chooses the factor on the points its filters keep, and
  // again on those its despike leaves (reproject_after_removal).
  const bool auto_k = config.grid.reproject.upsample_factor == 0;
  const bool k_carried = now_box != nullptr && now_box->upsample_factor > 0;  // found on these very points
  if (const GridGeometry g = geometry(merged.kept_box); !(g == plan.tiles.g)) {
    ScaleConfig::GridBox b = box_of(merged.kept_box);
    if (auto_k) b.upsample_factor = kept_points_factor(merged, plan, kept, g, &merged.despiked_m);
    return GridOnKeptPoints(std::move(b), plan.tiles.g, g, false);
  }
  if (auto_k && !k_carried && factor_may_change(plan, merged.kept_box.points)) {
    if (const int k = kept_points_factor(merged, plan, kept, plan.tiles.g, &merged.despiked_m); k != plan.tiles.k) {
      ScaleConfig::GridBox b = box_of(merged.kept_box);
      b.upsample_factor = k;
      return GridOnKeptPoints(std::move(b), plan.tiles.g, plan.tiles.g, false, plan.tiles.k);
    }
  }
  if (merged.after_box.points > 0 && !merged.despiked_m.empty()) {
    const GridGeometry a = geometry(merged.after_box);
    int k_after = plan.tiles.k;
    if (auto_k && (!(a == plan.tiles.g) || factor_may_change(plan, merged.after_box.points))) {
      k_after = kept_points_factor(merged, plan, kept, a, nullptr);
    }
    if (!(a == plan.tiles.g) || k_after != plan.tiles.k) {
      ScaleConfig::GridBox b = box_of(merged.after_box);
      if (auto_k) b.upsample_factor = k_after;
      std::sort(merged.despiked_m.begin(), merged.despiked_m.end());
      b.despiked_m = std::make_shared<const std::vector<std::array<double, 3>>>(std::move(merged.despiked_m));
      merged.despiked_m.clear();
      // The despike's figures, which the attempt that takes its removals over cannot count.
      for (const char* name : kDespikeSums) {
        if (const auto it = merged.sums.find(name); it != merged.sums.end()) b.despike_sums[name] = it->second;
      }
      return GridOnKeptPoints(std::move(b), plan.tiles.g, a, true, k_after != plan.tiles.k ? plan.tiles.k : 0);
    }
  }
  return std::nullopt;
}

// Where the plan's box took the despike's removals over, its figures are those of the attempt
// that judged them (on the grid the in-core despike reads).
void take_over_despike_sums(const RunConfig& config, TileMerge& merged) {
  if (!config.scale.grid_box || !config.scale.grid_box->despiked_m) return;
  for (const char* name : kDespikeSums) merged.sums.erase(name);
  for (const auto& [name, v] : config.scale.grid_box->despike_sums) merged.sums[name] = v;
}

// The line a later attempt's tile_plan notes for an attempt that stopped for `e`, ending with
// `then` (what happened next: "the run started again after 12 s").
std::string grid_relaid_why(const GridOnKeptPoints& e, const std::string& then) {
  if (e.factor_only()) {
    return std::string(e.after_despike ? "the despike" : "the outlier filters") + " moved the upsample coverage (grid.upsample: auto): " +
           "the in-core run takes factor " + std::to_string(e.box.upsample_factor) + " on the points " +
           (e.after_despike ? "the despike leaves (its removals taken over)" : "the filters keep") + ", not " + std::to_string(e.first_factor) +
           " as on every point, so " + then + " with factor " + std::to_string(e.box.upsample_factor);
  }
  return std::string(e.after_despike ? "the despike" : "the outlier filters") + " removed a point that set the x-y box of the grid " +
         grid_words(e.first) + ", so " + then + " with the grid laid on the points " +
         (e.after_despike ? "the despike left (its removals taken over)" : "the filters keep") + ", as the in-core run lays it: " +
         grid_words(e.kept);
}

BuiltScene build_scene_tiled_on_its_grid(const RunConfig& config, const ProgressFn& progress, SurfaceLayersAt layers,
                                         detail::Clock::time_point t_start);

// grid_box.json, which tile-merge writes for the next plan (GridBoxError, tile-plan --grid-box).
constexpr const char* kGridBoxFormat = "hapticloud grid box 1";

struct GridBoxFile {
  ScaleConfig::GridBox box;
  std::vector<std::string> why;  // one line per plan before the next
  std::string plan_id;           // the plan whose merge wrote it
  std::string resolved_yaml;     // its config's
  Eigen::Vector3d offset_m = Eigen::Vector3d::Zero();  // its recentring (Plan::offset_m)
  std::vector<SceneInput> inputs;                      // its input files and their SHA-256
};

void write_grid_box_file(const fs::path& file, const GridBoxFile& g) {
  nlohmann::json j;
  j["format"] = kGridBoxFormat;
  j["plan"] = g.plan_id;
  j["resolved_yaml"] = text(g.resolved_yaml);
  j["offset_m"] = {hex(g.offset_m.x()), hex(g.offset_m.y()), hex(g.offset_m.z())};
  j["inputs"] = nlohmann::json::array();
  for (const SceneInput& in : g.inputs) j["inputs"].push_back({{"file", text(in.file)}, {"sha256", in.sha256}});
  j["box"] = grid_box_json(g.box);
  j["why"] = nlohmann::json::array();
  for (const std::string& w : g.why) j["why"].push_back(text(w));
  detail::write_atomically(file, j.dump(1, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
}

GridBoxFile read_grid_box_file(const fs::path& file) {
  const std::string bytes = read_file_bytes(file, "the grid box (tile-plan --grid-box)");
  GridBoxFile g;
  std::string where = "the JSON text";
  try {
    const nlohmann::json j = nlohmann::json::parse(bytes);
    where = "format";
    if (!j.is_object() || j.value("format", std::string()) != kGridBoxFormat) {
      throw InputError(file.string() + ": not a grid box of this version (format is not \"" + kGridBoxFormat +
                       "\"; hapticloud tile-merge writes it as WORK/grid_box.json)");
    }
    where = "plan, resolved_yaml, offset_m, inputs";
    g.plan_id = j.at("plan").get<std::string>();
    g.resolved_yaml = untext(j.at("resolved_yaml"));
    for (int a = 0; a < 3; ++a) g.offset_m[a] = unhex(j.at("offset_m").at(static_cast<std::size_t>(a)), file, "offset_m");
    for (const auto& in : j.at("inputs")) g.inputs.push_back({untext(in.at("file")), in.at("sha256").get<std::string>()});
    where = "box";
    g.box = grid_box_of(j.at("box"), file, "box");
    where = "why";
    if (!j.at("why").is_array() || j.at("why").empty()) {
      throw InputError(file.string() + ": why is " + j.at("why").dump() + ", expected a list of lines, one per plan before the next");
    }
    for (const auto& w : j.at("why")) g.why.push_back(untext(w));
  } catch (const nlohmann::json::exception& e) {
    throw InputError(file.string() + ": " + where + ": not as hapticloud tile-merge writes a grid box (" + e.what() + ")");
  }
  return g;
}

// The resolved YAML `yaml` without its `scale` section (tiling, scratch and halo keys, which do
// not change the scene), as yaml-cpp emits it.
// @throws InputError naming `file` and `key` for text that is not YAML.
std::string yaml_but_scale(const std::string& yaml, const fs::path& file, const char* key) {
  YAML::Node n;
  try {
    n = YAML::Load(yaml);
  } catch (const YAML::Exception& e) {
    throw InputError(file.string() + ": " + key + " is not YAML text (" + e.what() + "; expected a resolved run config)");
  }
  if (n.IsMap() && n["scale"]) n.remove("scale");
  YAML::Emitter e;
  e << n;
  return e.c_str();
}
}  // namespace

// The tiled run. Its plan lays the grid on the points before the outlier filters; where those
// remove a point that set the box (a stray at the scan's edge), the in-core run's grid is
// another one, so the run starts again from the plan with the kept points' box (the first
// attempt stops after its tile loop, which gave the box; the verdicts are the whole scan's, so
// the second attempt keeps the same points and its grid is the in-core one).
BuiltScene build_scene_tiled(const RunConfig& config, const ProgressFn& progress, SurfaceLayersAt layers) {
  const auto t_start = detail::Clock::now();
  RunConfig now = config;
  std::vector<std::string> why;  // one line per attempt started again
  // At most three attempts: the box before the filters, the box they keep (on whose grid the
  // despike judges), the box the despike leaves (its removals taken over). The verdicts are the
  // whole scan's and so the same on any grid, save where the tiles decide them (a far cluster
  // removed only where one window's decided region holds it whole, a window too sparse to
  // judge): the third attempt checks no more, and finish_tiled warns if its grid still differs.
  // One more attempt, counted apart, where the in-core run's far clusters hold points the tiles
  // kept (FarCellsAgain: their cells carried; once at most, since an attempt that carries them
  // does not look again).
  int attempt = 0;  // of the grid's attempts
  for (;;) {
    ++attempt;
    if (attempt == 3) now.scale.grid_box->last = true;  // checks no more (finish_tiled warns)
    try {
      BuiltScene built = build_scene_tiled_on_its_grid(now, progress, layers, t_start);
      if (!why.empty()) {
        const double lost_s = detail::seconds_since(t_start);
        for (const std::string& w : why) {
          if (w.rfind("warning: ", 0) == 0) built.summary.warnings.push_back(w.substr(9));
        }
        for (StageReport& rep : built.summary.stages) {
          if (rep.stage != "tile_plan") continue;
          rep.figure("grid_relaid", static_cast<double>(attempt - 1));
          rep.figure("far_cells_carried", now.scale.far_cells ? 1.0 : 0.0);
          for (const std::string& w : why) rep.notes.push_back(w);
          rep.notes.push_back("(" + format_number(lost_s) + " s in all" +
                              (attempt > 1 ? "; scale.grid_on_kept_points: false keeps the first grid and skips the grid's later attempts)" : ")"));
        }
      }
      return built;
    } catch (const GridOnKeptPoints& e) {  // the attempt's scratch folder is gone with it
      if (!e.island_halo_widened.empty()) {  // the later attempts start with the wider share
        now.scale.island_halo = ScaleConfig::Tiled::kOn;
        why.push_back("warning: " + e.island_halo_widened);
      }
      why.push_back(grid_relaid_why(e, "the run started again after " + format_number(detail::seconds_since(t_start)) + " s"));
      now.scale.grid_box = e.box;
    } catch (const FarCellsAgain& e) {
      if (!e.island_halo_widened.empty()) {
        now.scale.island_halo = ScaleConfig::Tiled::kOn;
        why.push_back("warning: " + e.island_halo_widened);
      }
      if (now.scale.far_cells && now.scale.far_cells->last) throw std::logic_error("build_scene_tiled: far-cluster cells carried after the last");
      const bool again = now.scale.far_cells != nullptr;  // the carried cells were another grid's: once more, the last
      why.push_back((again ? std::string("the far clusters of the kept points moved with the grid (the whole-scan pass's coarse cells lie on it): ")
                           : std::string("the whole scan's far clusters, joined from the tiles' kept points, hold more points than the tiles "
                                         "removed (they judge far clusters only where a window holds them whole): ")) +
                    std::to_string(e.cells->points) + " points in " + std::to_string(e.cells->clusters) + " clusters; the run started again after " +
                    format_number(detail::seconds_since(t_start)) + " s, its tiles removing the kept points in those clusters' " +
                    std::to_string(e.cells->keys.size()) + " cells");
      auto cells = std::make_shared<ScaleConfig::FarCellKeys>(*e.cells);
      cells->last = again;
      now.scale.far_cells = std::move(cells);
      --attempt;  // not one of the grid's attempts
    }
  }
}

namespace {
BuiltScene build_scene_tiled_on_its_grid(const RunConfig& config, const ProgressFn& progress, SurfaceLayersAt layers,
                                         detail::Clock::time_point t_start) {
  if (config.scale.island_halo != ScaleConfig::Tiled::kAuto) return build_scene_tiled_once(config, progress, layers, t_start);
  std::string why;
  std::size_t tile = 0;
  int now = 0, then = 0;
  try {
    return build_scene_tiled_once(config, progress, layers, t_start);  // the narrower share
  } catch (const UndecidedIslandsError& e) {  // the first attempt's scratch folder is gone with it
    why = e.what();
    why = why.substr(0, std::min(why.size(), why.find(": set scale.island_halo")));  // its advice does not apply now
    tile = e.tile;
    now = e.halo_now;
    then = e.halo_then;
  }
  const double lost_s = detail::seconds_since(t_start);
  RunConfig wide = config;
  wide.scale.island_halo = ScaleConfig::Tiled::kOn;
  const std::string warning =
      "scale.island_halo: auto: tile " + std::to_string(tile) + "'s window could not decide whether a group of at most " +
      "cross_check.island_max_cells = " + std::to_string(config.cross_check.honest.island_max_cells) +
      " valid cells is an island, so the run started again from the plan with the wider grid share (a halo of " +
      std::to_string(then) + " nodes instead of " + std::to_string(now) + ") after " + format_number(lost_s) +
      " s; set scale.island_halo: true to skip the first attempt with this scan and config. The first attempt stopped with: " + why;
  BuiltScene built;
  try {
    built = build_scene_tiled_once(wide, progress, layers, t_start);
  } catch (GridOnKeptPoints& e) {  // build_scene_tiled starts again, with the wider share
    e.island_halo_widened = warning;
    throw;
  } catch (FarCellsAgain& e) {  // likewise
    e.island_halo_widened = warning;
    throw;
  }
  for (StageReport& rep : built.summary.stages) {
    if (rep.stage != "tile_plan") continue;
    rep.figure("island_halo_restarted_after_s", lost_s);
    rep.notes.push_back("warning: " + warning);
  }
  built.summary.warnings.push_back(warning);
  return built;
}

BuiltScene build_scene_tiled_once(const RunConfig& config, const ProgressFn& progress, SurfaceLayersAt layers,
                                  detail::Clock::time_point t_start) {
  const detail::StageHeapRelease heap_release;  // each stage's freed heap back when it ends
  ScratchDir scratch(config.scale.scratch);
  Plan plan = plan_passes(config, scratch.path(), progress);
  Spill spill(scratch.path(), "tile_", plan.tiles.count(), plan.layout);
  spill.adopt_existing();
  KeptMask kept(scratch.path(), "kept_", spill, plan.tiles.count());
  BuiltScene built;
  built.surface_layers_at = layers;  // asked for; scene_surface_layers says what it did
  built.from_tiled_run = true;
  built.summary.stages = std::move(plan.reports);
  TileMerge merged(config, plan, scratch.path());
  std::shared_ptr<const ScaleConfig::FarCellKeys> far_again;  // exact_far_clusters
  // 3. The tile jobs, in process and in order (tile-job runs the same run_tiles elsewhere).
  (void)stage("tiles", built.summary.stages, progress, [&] {
    StageResult<int> r;
    detail::PassProgress tick(progress, "tiles", "the tile loop", config.scale.progress_interval_s);
    // When nothing reads the kept points after the loop (no cross-check, no levels sample), a
    // tile's spill goes once the last band (the strays judged) has processed it.
    const Tiles& tiles = plan.tiles;
    // grid.upsample: auto under scale.grid_on_kept_points reads the kept points after the loop
    // too (kept_points_factor; until the sixty-sixth session the spills were dropped under it,
    // and that read failed on a missing spill file).
    const bool factor_reads = config.grid.reproject.upsample_factor == 0 && config.scale.grid_on_kept_points;
    const bool drop = !config.cross_check.enabled && !keeps_sample(config) && !factor_reads;
    // Freed heap back when the tiles before left more than a window's worth (TileHeapBudget).
    detail::TileHeapBudget heap(window_heap_budget(spill, tiles.count()));
    std::vector<std::size_t> all(tiles.count());
    std::iota(all.begin(), all.end(), std::size_t{0});
    std::vector<std::size_t> left;  // processed, its spill kept for a later band
    StrayVerdicts verdicts;  // the strays' verdicts, for the tiles the fix-up below processes again
    // Their first looks too, up to KeptLooks::kBudgetBytes (figures far_tiles_again_looks_kept
    // and looks_kept_mb where the fix-up ran).
    KeptLooks looks_kept;
    const bool mapped = run_tiles(
        config, plan, spill, kept, all, heap, [&](double f) { tick(f); },
        [&](TileOutput&& o, bool last) {
          const std::size_t t = o.tile;
          merged.add(tiles, std::move(o));
          if (!drop) return;
          if (!last) {
            left.push_back(t);
            return;
          }
          for (const std::size_t u : left) spill.remove(u);
          left.clear();
          spill.remove(t);
        },
        drop ? nullptr : &verdicts, drop ? nullptr : &looks_kept);  // kept only where the spills stay for a fix-up
    merged.finish();
    far_again = exact_far_clusters(config, plan, merged, r.report);
    if (far_again && !drop && config.scale.far_cells == nullptr) {
      // Their spills are all still there: the tiles holding them are processed again, their
      // strays' verdicts the loop's (no gathering where it kept them all).
      verdicts.seal();
      r.report.figure("strays_verdicts_kept", static_cast<double>(verdicts.size()));
      far_tiles_again(config, tiles, std::move(far_again), merged, r.report, progress,
                      [&](const RunConfig& fix, const std::vector<std::size_t>& again, const std::function<void(double)>& again_tick) {
                        (void)run_tiles(fix, plan, spill, kept, again, heap, again_tick, [&](TileOutput&& o, bool) { merged.add(tiles, std::move(o)); },
                                        &verdicts, &looks_kept);
                      });
      r.report.figure("far_tiles_again_looks_kept", static_cast<double>(looks_kept.taken()));
      r.report.figure("looks_kept_mb", static_cast<double>(looks_kept.bytes()) / 1e6);
      far_again = nullptr;
    }
    looks_kept = KeptLooks{};  // their memory back
    take_over_despike_sums(config, merged);
    merged.report(config, r.report);
    r.report.figure("heap_releases", static_cast<double>(heap.releases()));
    r.report.figure("large_blocks_mapped", mapped ? 1.0 : 0.0);
    return r;
  });
  // The in-core run's far clusters hold points the tiles kept, and the spills are gone (else the
  // tiles were processed again above): build_scene_tiled starts again
  // carrying their cells (before the grid's box is looked at: their points may set it).
  if (far_again) throw FarCellsAgain(std::move(far_again));
  // The in-core run lays its grid on the points the filters keep: where that is another grid,
  // build_scene_tiled starts again with their box (scale.grid_on_kept_points).
  if (std::optional<GridOnKeptPoints> again = grid_on_kept_points(config, plan, merged, kept)) throw std::move(*again);
  return finish_tiled(config, plan, merged, spill, kept, std::move(built), progress, t_start);
}
}  // namespace

TilePlanInfo write_tile_plan(const fs::path& config_file, const std::vector<std::string>& overrides, const fs::path& work_dir,
                             const ProgressFn& progress, const fs::path& grid_box_file) {
  const fs::path config_abs = fs::absolute(config_file);
  RunConfig config = load_run_config(config_abs, overrides);
  check_supported(config);
  std::optional<GridBoxFile> box;
  if (!grid_box_file.empty()) {
    box = read_grid_box_file(grid_box_file);
    if (yaml_but_scale(box->resolved_yaml, grid_box_file, "resolved_yaml") !=
        yaml_but_scale(config.resolved_yaml, config_abs, "the config")) {
      throw ConfigError("tile-plan --grid-box " + grid_box_file.string() + ": the box was found with a config that resolves to other " +
                        "values outside scale than " + config_abs.string() + " with these --set overrides (the kept points, and so " +
                        "their box, depend on them): plan with that config, or without --grid-box");
    }
    config.scale.grid_box = box->box;
  }
  std::error_code ec;
  bool made = false;
  if (fs::exists(work_dir, ec)) {
    if (!fs::is_directory(work_dir, ec) || !fs::is_empty(work_dir, ec)) {
      throw InputError("tile plan: " + work_dir.string() + " exists and is not an empty folder (expected a new or empty folder for the plan and its tiles)");
    }
  } else {
    // Registered before it exists: SIGINT/SIGTERM while it is made removes it too.
    register_live_scratch_dir(work_dir);
    fs::create_directories(work_dir, ec);
    if (ec || !fs::is_directory(work_dir)) {
      unregister_live_scratch_dir(work_dir);
      throw InputError("tile plan: cannot create the folder " + work_dir.string() + (ec ? ": " + ec.message() : std::string()));
    }
    made = true;
  }
  PlanCleanup cleanup(work_dir, made);
  PlanFile pf;
  pf.dir = work_dir;
  pf.plan = plan_passes(config, work_dir, progress);
  pf.id = random_id();
  pf.config_file = config_abs;
  pf.overrides = overrides;
  pf.resolved_yaml = config.resolved_yaml;
  if (box) {
    // The box is in the grid frame of the scan it came from: the same files, recentred alike.
    bool same_inputs = box->inputs.size() == pf.plan.inputs.size();
    for (std::size_t i = 0; same_inputs && i < box->inputs.size(); ++i) {
      same_inputs = box->inputs[i].file == pf.plan.inputs[i].file && box->inputs[i].sha256 == pf.plan.inputs[i].sha256;
    }
    if (!same_inputs || box->offset_m != pf.plan.offset_m) {
      const auto words = [](const Eigen::Vector3d& v) { return "(" + hex(v.x()) + ", " + hex(v.y()) + ", " + hex(v.z()) + ") m"; };
      throw InputError("tile-plan --grid-box " + grid_box_file.string() + ": the box was found on " +
                       (same_inputs ? "the same input files recentred otherwise (offset_m " + words(box->offset_m) + ", this plan's " +
                                          words(pf.plan.offset_m) + ")"
                                    : std::string("other input files (or files that changed since)")) +
                       " than this plan reads: plan again without --grid-box");
    }
    pf.grid_box = box->box;
    pf.grid_why = box->why;
    for (StageReport& rep : pf.plan.reports) {
      if (rep.stage != "tile_plan") continue;
      rep.figure("grid_relaid", static_cast<double>(box->why.size()));
      for (const std::string& w : box->why) rep.notes.push_back(w);
      rep.notes.push_back("(the box from " + grid_box_file.string() + ", which tile-merge of plan " + box->plan_id +
                          " wrote; a plan with scale.grid_on_kept_points: false keeps the first grid)");
    }
  }
  Spill spill(work_dir, "tile_", pf.plan.tiles.count(), pf.plan.layout);
  spill.adopt_existing();
  TilePlanInfo info;
  for (std::size_t t = 0; t < pf.plan.tiles.count(); ++t) {
    pf.spill_bytes.push_back(spill.bytes(t));
    info.spill_bytes += spill.bytes(t);
  }
  write_plan_file(pf);
  cleanup.keep();
  info.plan_file = work_dir / "plan.json";
  info.tiles = pf.plan.tiles.count();
  return info;
}

std::size_t tile_plan_tiles(const fs::path& plan_file) { return read_plan_file(plan_file).plan.tiles.count(); }

namespace {

// Processes `tiles` (each once, in order, all in the plan) of plan file `plan_file` (read into
// `pf`) under `config` as tile jobs do: their kept masks written under a temporary name and
// moved to kept_<t>.bin once whole and flushed, then their results written atomically to their
// part files (so a merge never pairs a new result with an old mask); `then` gets each result
// after its files are written; `progress` the share of the tiles' two sweeps done. Used by
// run_tile_jobs and by tile-merge's far-cluster fix-up.
// @throws InputError naming a spill file that is missing or changed, or a file that cannot be
// written or moved.
void run_jobs(const PlanFile& pf, const RunConfig& config, const std::vector<std::size_t>& tiles, const std::function<void(TileOutput&&)>& then,
              const std::function<void(double)>& progress = [](double) {}) {
  const Plan& plan = pf.plan;
  Spill spill(pf.dir, "tile_", plan.tiles.count(), plan.layout);
  spill.adopt_existing();
  const std::string tmp_prefix = std::string(kKeptJobPrefix) + attempt_tag() + "-";
  KeptMask kept(pf.dir, tmp_prefix, spill, plan.tiles.count());
  // Every spill file, not only the jobs' own: a tile's robust test may read its neighbours'.
  for (std::size_t t = 0; t < plan.tiles.count(); ++t) {
    if (spill.bytes(t) != pf.spill_bytes[t]) {
      throw InputError(spill.file(t).string() + " holds " + std::to_string(spill.bytes(t)) + " bytes, the plan wrote " +
                       std::to_string(pf.spill_bytes[t]) + " (a missing or changed spill file: make a new plan)");
    }
  }
  detail::TileHeapBudget heap(window_heap_budget(spill, plan.tiles.count()));
  // Each attempt's temporary kept file goes however the job ends (renamed below on success),
  // and on SIGINT/SIGTERM (hapticloud's signal watcher).
  std::list<LiveScratchFile> temps;
  for (const std::size_t t : tiles) temps.emplace_back(kept.file(t));
  // The tiles in bands as in the tile loop of build_scene_tiled (run_tiles): the strays of a
  // band judged over the whole scan, read from every spill their balls meet.
  (void)run_tiles(config, plan, spill, kept, tiles, heap, progress, [&](TileOutput&& o, bool) {
    const std::size_t t = o.tile;
    std::error_code ec;
    if (o.kept_bytes > 0) {
      // The file must be there, whole: a merge that found this tile done may have removed it as a
      // killed attempt's (another host's). Such an attempt's file is not moved over the tile's.
      const std::uintmax_t on_disk = fs::file_size(kept.file(t), ec);
      if (ec || on_disk != o.kept_bytes) {
        throw InputError("tile-job: " + kept.file(t).string() + " holds " + (ec ? std::string("nothing") : std::to_string(on_disk) + " bytes") +
                         ", the tile's mask has " + std::to_string(o.kept_bytes) +
                         " (removed or changed by another process, such as a tile-merge that found tile " + std::to_string(t) +
                         " done): not moved to kept_" + std::to_string(t) + ".bin");
      }
      const int fd = ::open(kept.file(t).c_str(), O_RDONLY);
      const bool synced = fd >= 0 && ::fsync(fd) == 0;
      if (fd >= 0) ::close(fd);
      if (!synced) throw InputError("tile-job: cannot flush " + kept.file(t).string() + " to disk: " + std::strerror(errno));
    }
    const fs::path kept_final = pf.dir / ("kept_" + std::to_string(t) + ".bin");
    if (o.kept_bytes == 0) {
      fs::remove(kept_final, ec);  // no kept point: no file (merge reads 0 bytes)
    } else {
      rename_live_scratch(kept.file(t), kept_final, ec);
      if (ec) throw InputError("tile-job: cannot move " + kept.file(t).string() + " to " + kept_final.string() + ": " + ec.message());
    }
    detail::write_atomically(part_file(pf.dir, t), encode_part(pf.id, o));
    then(std::move(o));
  });
}

}  // namespace

void run_tile_jobs(const fs::path& plan_file, const std::vector<std::size_t>& tiles_asked) {
  const detail::StageHeapRelease heap_release;  // each tile's freed heap back, as in the tile loop
  std::vector<std::size_t> tiles = tiles_asked;  // each tile once
  std::sort(tiles.begin(), tiles.end());
  tiles.erase(std::unique(tiles.begin(), tiles.end()), tiles.end());
  const PlanFile pf = read_plan_file(plan_file);
  const RunConfig config = config_of(pf, plan_file);
  for (const std::size_t t : tiles) {
    if (t >= pf.plan.tiles.count()) {
      throw InputError(plan_file.string() + ": no tile " + std::to_string(t) + " (the plan has tiles 0 to " +
                       std::to_string(pf.plan.tiles.count() - 1) + ")");
    }
  }
  run_jobs(pf, config, tiles, [](TileOutput&&) {});
}

namespace {

// The host and process of an attempt_tag() at the start of `s` ("<host>-<pid>-<16 hex digits>",
// the host with every character but letters and digits made '_'); `rest` gets what follows it.
// false when `s` does not start with such a tag.
bool parse_attempt_tag(const std::string& s, std::string& host, long& pid, std::string& rest) {
  const std::size_t d1 = s.find('-');
  if (d1 == std::string::npos) return false;
  const std::size_t d2 = s.find('-', d1 + 1);
  if (d2 == std::string::npos || d2 == d1 + 1 || d2 - d1 - 1 > 10 || s.size() < d2 + 17) return false;
  host = s.substr(0, d1);
  for (const char c : host)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '_') return false;
  for (std::size_t i = d1 + 1; i < d2; ++i)
    if (!std::isdigit(static_cast<unsigned char>(s[i]))) return false;
  for (std::size_t i = d2 + 1; i < d2 + 17; ++i)
    if (!std::isxdigit(static_cast<unsigned char>(s[i]))) return false;
  pid = std::stol(s.substr(d1 + 1, d2 - d1 - 1));
  rest = s.substr(d2 + 17);
  return true;
}

bool all_digits(const std::string& s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)) != 0; });
}

// What tile jobs killed outright (SIGKILL, a lost node, the OOM killer) leave in the plan's
// folder, removed by a merge that found every tile's result: their block copies
// (`.blocks-<tag>/` folders), temporary kept files (`.kept-job-<tag>-<t>.bin`) and temporary
// results (`.part_<t>.bin.tmp-<tag>`, `.plan.json.tmp-<tag>`), <tag> an attempt_tag(). Only
// entries of exactly these names (and kinds: no symbolic link) go; the plan's folder holds only
// what hapticloud wrote (tile-plan takes a new or empty folder). An entry whose tag names this
// host and a process that is alive is left (a duplicate attempt still running). One of another
// host's is removed: its attempt is a duplicate of a tile that has a result, and it fails
// without harm (tile-job checks its kept file's size before moving it). Figures into `report`
// (only when something was removed): stale_scratch_removed (entries), stale_scratch_mb (their
// bytes / 10^6); a note names up to five of them, and one names what could not go. Returns
// the entries left as a running attempt's.
std::size_t remove_stale_scratch(const fs::path& dir, StageReport& report) {
  const std::string me = host_tag();
  std::vector<fs::path> stale;
  std::size_t running = 0;
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    std::error_code kind;
    const fs::file_status st = it->symlink_status(kind);
    if (kind) continue;
    const bool is_dir = fs::is_directory(st), is_file = fs::is_regular_file(st);
    std::string host, rest;
    long pid = 0;
    bool ours = false;
    const auto tag_after = [&](std::string_view head) {
      return name.rfind(head, 0) == 0 && parse_attempt_tag(name.substr(head.size()), host, pid, rest);
    };
    const std::string plan_tmp = ".plan.json" + std::string(kTmpInfix);
    const std::size_t part_tmp = name.find(".bin" + std::string(kTmpInfix));  // .part_<t>.bin.tmp-<tag>
    if (is_dir) {
      ours = tag_after(kBlocksPrefix) && rest.empty();
    } else if (is_file && tag_after(kKeptJobPrefix)) {  // -<t>.bin after the tag
      ours = rest.size() > 5 && rest[0] == '-' && rest.compare(rest.size() - 4, 4, ".bin") == 0 &&
             all_digits(rest.substr(1, rest.size() - 5));
    } else if (is_file && tag_after(plan_tmp)) {
      ours = rest.empty();
    } else if (is_file && name.rfind(".part_", 0) == 0 && part_tmp != std::string::npos &&
               all_digits(name.substr(6, part_tmp - 6))) {
      ours = parse_attempt_tag(name.substr(part_tmp + 4 + kTmpInfix.size()), host, pid, rest) && rest.empty();
    }
    if (!ours) continue;
    if (host == me && pid > 0 && !detail::process_gone(pid)) {
      ++running;  // a running attempt's (or a reused process number's): left
      continue;
    }
    stale.push_back(it->path());
  }
  if (ec) report.notes.push_back("could not list " + dir.string() + " for scratch killed tile jobs left: " + ec.message());
  if (running > 0) {
    report.notes.push_back(std::to_string(running) + " scratch entries of processes still running on this host left in " +
                           dir.string());
  }
  if (stale.empty()) return running;
  std::sort(stale.begin(), stale.end());
  std::uintmax_t bytes = 0;
  std::size_t removed = 0;
  std::string names;
  for (const fs::path& p : stale) {
    std::uintmax_t b = 0;
    std::error_code size_ec;
    if (fs::is_directory(p, size_ec)) {
      for (fs::recursive_directory_iterator it(p, size_ec), end; !size_ec && it != end; it.increment(size_ec)) {
        std::error_code file_ec;
        if (it->is_regular_file(file_ec)) {
          const std::uintmax_t f = it->file_size(file_ec);
          if (!file_ec) b += f;
        }
      }
    } else {
      b = fs::file_size(p, size_ec);
      if (size_ec) b = 0;
    }
    ec.clear();
    const std::uintmax_t gone = fs::remove_all(p, ec);
    if (ec || gone == static_cast<std::uintmax_t>(-1)) {
      report.notes.push_back("could not remove " + p.string() + ", left by a killed tile job: " + ec.message());
      continue;
    }
    if (gone == 0) continue;  // gone meanwhile (its attempt moved or removed it)
    bytes += b;
    if (removed++ < 5) names += (names.empty() ? "" : ", ") + p.filename().string();
  }
  if (removed == 0) return running;
  report.figure("stale_scratch_removed", static_cast<double>(removed));
  report.figure("stale_scratch_mb", static_cast<double>(bytes) / 1e6);
  report.notes.push_back("removed " + std::to_string(removed) + " entries (" + format_number(static_cast<double>(bytes) / 1e6) +
                         " MB) that killed tile jobs left in " + dir.string() + ": " + names + (removed > 5 ? ", ..." : ""));
  return running;
}

}  // namespace

namespace {

// far_fixup.json (tile-merge's far clusters' fix-up under way): the plan's id and the cells
// (ScaleConfig::FarCellKeys; the link as a hexadecimal float), written atomically.
void write_far_fixup_file(const fs::path& file, const std::string& plan_id, const ScaleConfig::FarCellKeys& k) {
  nlohmann::json j;
  j["plan_id"] = plan_id;
  j["link_m"] = hex(k.link_m);
  j["keys"] = k.keys;
  j["cluster"] = k.cluster;
  j["points"] = k.points;
  j["clusters"] = k.clusters;
  j["notes"] = k.notes;
  detail::write_atomically(file, j.dump() + "\n");
}

// The cells of far_fixup.json. @throws InputError naming the file and the key when it is not
// as write_far_fixup_file writes it, or belongs to another plan.
std::shared_ptr<const ScaleConfig::FarCellKeys> read_far_fixup_file(const fs::path& file, const std::string& plan_id) {
  const std::string text = read_file_bytes(file, "far-cluster fix-up");
  const nlohmann::json j = nlohmann::json::parse(text, nullptr, false);
  const auto bad = [&](const std::string& what) -> InputError {
    return InputError(file.string() + ": " + what + " (tile-merge writes this file while it processes tiles again for far clusters; "
                      "remove it only together with the plan's part files)");
  };
  if (j.is_discarded() || !j.is_object()) throw bad("not a JSON object");
  if (!j.contains("plan_id") || j["plan_id"] != plan_id) throw bad("plan_id is not this plan's (" + plan_id + ")");
  auto k = std::make_shared<ScaleConfig::FarCellKeys>();
  try {
    k->link_m = unhex(j.at("link_m"), file, "link_m");
    k->keys = j.at("keys").get<std::vector<std::uint64_t>>();
    k->cluster = j.at("cluster").get<std::vector<std::uint32_t>>();
    k->points = j.at("points").get<std::uint64_t>();
    k->clusters = j.at("clusters").get<std::uint64_t>();
    k->notes = j.at("notes").get<std::vector<std::string>>();
  } catch (const nlohmann::json::exception& e) {
    throw bad(std::string("a key is missing or of another type: ") + e.what());
  }
  if (!(std::isfinite(k->link_m) && k->link_m > 0.0)) throw bad("link_m is not a positive length");
  if (k->keys.empty() || k->cluster.size() != k->keys.size() || !std::is_sorted(k->keys.begin(), k->keys.end())) {
    throw bad("keys must be sorted and as many as cluster's entries, at least one");
  }
  return k;
}

}  // namespace

MergedTileRun merge_tile_jobs(const fs::path& plan_file, const ProgressFn& progress, SurfaceLayersAt layers) {
  const auto t_start = detail::Clock::now();
  const detail::StageHeapRelease heap_release;  // as build_scene_tiled
  PlanFile pf = read_plan_file(plan_file);
  MergedTileRun m{config_of(pf, plan_file), {}};
  const RunConfig& config = m.config;
  Plan& plan = pf.plan;
  std::vector<std::size_t> missing;
  for (std::size_t t = 0; t < plan.tiles.count(); ++t) {
    std::error_code ec;
    if (!fs::is_regular_file(part_file(pf.dir, t), ec)) missing.push_back(t);
  }
  if (!missing.empty()) {
    std::string list;
    for (std::size_t i = 0; i < missing.size() && i < 20; ++i) {
      if (i) list += ",";
      list += std::to_string(missing[i]);
    }
    const std::string what = missing.size() > 20 ? list + " and " + std::to_string(missing.size() - 20) + " more" : list;
    const std::string todo = missing.size() > 20 ? "their tile jobs" : "hapticloud tile-job " + plan_file.string() + " --tiles " + list;
    throw InputError("tile-merge: " + plan_file.string() + ": " + std::to_string(missing.size()) + " of " +
                     std::to_string(plan.tiles.count()) + " tiles have no result (" + what + "): run " + todo +
                     " first; no scene is made from a partial set");
  }
  Spill spill(pf.dir, "tile_", plan.tiles.count(), plan.layout);
  spill.adopt_existing();
  KeptMask kept(pf.dir, "kept_", spill, plan.tiles.count());
  kept.adopt_existing();
  BuiltScene built;
  built.surface_layers_at = layers;  // asked for; scene_surface_layers says what it did
  built.from_tiled_run = true;
  built.summary.stages = std::move(plan.reports);
  TileMerge merged(config, plan, pf.dir);
  (void)stage("tiles", built.summary.stages, progress, [&] {
    StageResult<int> r;
    for (std::size_t t = 0; t < plan.tiles.count(); ++t) {
      TileOutput o = decode_part(part_file(pf.dir, t), pf.id, t, plan.tiles);
      if (o.kept_bytes != kept.bytes(t)) {
        throw InputError(kept.file(t).string() + " holds " + std::to_string(kept.bytes(t)) + " bytes, its tile result says " +
                         std::to_string(o.kept_bytes) + " (run tile-job " + std::to_string(t) + " again)");
      }
      merged.add(plan.tiles, std::move(o));
    }
    merged.finish();
    // Every tile has its result: the scratch of attempts that were killed is of no use to anyone,
    // and another host's duplicate attempt, its kept file gone, then fails without moving it over
    // a tile the fix-up below replaces. One still running on this host could: the fix-up waits.
    const std::size_t running = remove_stale_scratch(pf.dir, r.report);
    // Where the in-core run's far clusters hold points the tiles kept, the tiles holding them are
    // processed again here, as the in-process run does, and their results and masks replaced (a
    // merge run again then finds nothing short). Their cells are written first to
    // far_fixup.json, which goes once every such tile is replaced and checked: a merge that finds
    // it (the one before stopped half way) processes the same tiles again with those cells, since
    // the parts already replaced no longer show them short.
    const fs::path fixup_file = pf.dir / "far_fixup.json";
    std::error_code fixup_ec;
    const bool resuming = fs::exists(fixup_file, fixup_ec);
    std::shared_ptr<const ScaleConfig::FarCellKeys> far_short = exact_far_clusters(config, plan, merged, r.report);
    if (running > 0 && (far_short || resuming)) {
      throw InputError("tile-merge: " + plan_file.string() + ": the tiles missed far clusters, and the merge processes the tiles holding them "
                       "again, replacing their results; " + std::to_string(running) + " scratch entries of tile-job attempts still running "
                       "on this host are in " + pf.dir.string() + ": run tile-merge again once they have ended (no scene was written)");
    }
    if (resuming) {
      far_short = read_far_fixup_file(fixup_file, pf.id);
      r.report.notes.push_back("far clusters: " + fixup_file.string() + " (a merge stopped while processing tiles again) gives the cells");
    } else if (far_short) {
      write_far_fixup_file(fixup_file, pf.id, *far_short);
    }
    if (far_short) {
      far_tiles_again(config, plan.tiles, std::move(far_short), merged, r.report, progress,
                      [&](const RunConfig& fix, const std::vector<std::size_t>& again, const std::function<void(double)>& tick) {
                        run_jobs(pf, fix, again, [&](TileOutput&& o) { merged.add(plan.tiles, std::move(o)); }, tick);
                      });
      kept.adopt_existing();
      std::error_code ec;
      fs::remove(fixup_file, ec);
      if (ec) throw InputError("tile-merge: cannot remove " + fixup_file.string() + ": " + ec.message());
    }
    take_over_despike_sums(config, merged);  // after the fix-up: its finish() makes the totals again
    merged.report(config, r.report);
    r.report.figure("tile_job_seconds", merged.job_seconds);
    r.report.notes.push_back("merged from the results of " + std::to_string(plan.tiles.count()) + " tile jobs (hapticloud tile-job) in " +
                             pf.dir.string());
    return r;
  });
  for (std::size_t t = 0; t < plan.tiles.count(); ++t) {
    if (spill.bytes(t) != pf.spill_bytes[t]) {
      throw InputError(spill.file(t).string() + " holds " + std::to_string(spill.bytes(t)) + " bytes, the plan wrote " +
                       std::to_string(pf.spill_bytes[t]) + " (the kept points and the honest check read it; a missing or changed spill file: make a new plan)");
    }
  }
  // The in-core run lays its grid on the points the filters keep: where that is another grid, the
  // box for a new plan, as build_scene_tiled starts again in process (scale.grid_on_kept_points).
  if (std::optional<GridOnKeptPoints> again = grid_on_kept_points(config, plan, merged, kept)) {
    GridBoxFile g;
    g.box = std::move(again->box);
    g.box.last = config.scale.grid_box.has_value();  // the third plan checks no more, as the third attempt
    g.why = pf.grid_why;
    g.why.push_back(grid_relaid_why(*again, "tile-merge of plan " + pf.id + " stopped and a new plan was made"));
    g.plan_id = pf.id;
    g.resolved_yaml = pf.resolved_yaml;
    g.offset_m = plan.offset_m;
    g.inputs = plan.inputs;
    const fs::path box_file = pf.dir / "grid_box.json";
    write_grid_box_file(box_file, g);
    std::string sets;
    for (const std::string& o : pf.overrides) {
      std::string quoted;  // for a POSIX shell: ' closes, \' is the quote, ' opens again
      for (const char ch : o) quoted += ch == '\'' ? std::string("'\\''") : std::string(1, ch);
      sets += " --set '" + quoted + "'";
    }
    throw GridBoxError("tile-merge: " + plan_file.string() + ": " +
                       (again->factor_only() ? grid_relaid_why(*again, "the plan is to be made again") + ". Their box and factor are in "
                                    : std::string(again->after_despike ? "the despike" : "the outlier filters") +
                                          " removed a point that set the x-y box of the plan's grid " + grid_words(again->first) +
                                          "; the in-core run lays its grid on the points " +
                                          (again->after_despike ? "the despike left" : "they keep") + " (" + grid_words(again->kept) +
                                          "). Their box is in ") +
                       box_file.string() + ": plan again with hapticloud tile-plan " +
                       pf.config_file.string() + sets + " --grid-box " + box_file.string() +
                       " --work NEW_FOLDER, run its tile jobs and merge it (tools/dask/hapticloud-dask does so); a plan made "
                       "with --set scale.grid_on_kept_points=false keeps the first grid instead, with a warning. No scene was written.",
                       box_file);
  }
  m.built = finish_tiled(config, plan, merged, spill, kept, std::move(built), progress, t_start);
  return m;
}

}  // namespace hc::pipeline
