// Reading a scan in chunks (point_stream.hpp): binary PLY natively, anything else read whole by
// load_cloud and handed out in slices.

#include "hc/pipeline/point_stream.hpp"

#include "readers/byte_source.hpp"
#include "readers/readers.hpp"
#include "readers/text_parse.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <array>
#include <map>
#include <optional>
#include <sys/mman.h>
#include <sys/stat.h>
#include <tuple>
#include <mutex>
#include <cctype>
#include <utility>

namespace hc::pipeline {
namespace {

// A cloud read whole, given out in slices.
class WholeStream final : public PointStream {
 public:
  explicit WholeStream(StageResult<Cloud> read)
      : cloud_(std::move(read.value)), total_(cloud_.size()), crs_(cloud_.crs) {
    notes_ = std::move(read.report.notes);
    notes_.push_back("read whole (this format or layout is not streamed), then handed out in chunks");
  }
  std::uint64_t total_points() const override { return total_; }
  const std::vector<std::string>& notes() const override { return notes_; }
  bool streamed() const override { return false; }
  std::string crs() const override { return crs_; }
  bool next(Cloud& chunk, std::size_t max_points) override {
    chunk = Cloud();
    const std::size_t n = std::min(std::max<std::size_t>(max_points, 1), total_ - done_);
    if (n == 0) return false;
    const auto first = static_cast<Eigen::Index>(done_), count = static_cast<Eigen::Index>(n);
    chunk.xyz = cloud_.xyz.middleCols(first, count);
    if (cloud_.has_rgb()) chunk.rgb.assign(cloud_.rgb.begin() + 3 * first, cloud_.rgb.begin() + 3 * (first + count));
    if (cloud_.has_intensity()) {
      chunk.intensity.assign(cloud_.intensity.begin() + first, cloud_.intensity.begin() + first + count);
    }
    chunk.float32_xyz = cloud_.float32_xyz;
    done_ += n;
    if (done_ == total_) cloud_ = Cloud();  // free it as soon as the last chunk is out
    return true;
  }

 private:
  Cloud cloud_;
  std::size_t total_ = 0, done_ = 0;
  std::string crs_;
  std::vector<std::string> notes_;
};

// What opening a file of several in one frame learns (FilesStream): the point count, CRS and
// attributes of its stream's first chunk.
struct FileProbe {
  std::uint64_t total = 0;
  std::string crs;
  bool streamed = false, rgb = false, intensity = false, float32 = false;
};

// Probes kept for the process, by the file's identity (device, inode, size, modification time)
// and the load options it was opened with (input.las.drop_classes and input.as_points change
// what a file gives: a LAS file read whole counts the points left after the dropped classes, a
// mesh read as points streams): every pass of a tiled run opens the files again, and a probe can
// cost a pass of its own (a LAS file's colour depth, a text file's line count).
using ProbeKey = std::pair<std::array<std::int64_t, 5>, std::string>;
struct ProbeCache {
  std::mutex mutex;
  std::map<ProbeKey, FileProbe> probes;
};
ProbeCache& probe_cache() {
  static ProbeCache cache;
  return cache;
}
// The probe kept for f opened with `options`, if any; `key` gets f's identity and the options
// (an empty identity when f cannot be stat'ed: then nothing is kept for it).
std::optional<FileProbe> recall_probe(const std::filesystem::path& f, const LoadOptions& options, ProbeKey& key) {
  struct stat st {};
  if (::stat(f.c_str(), &st) != 0) return std::nullopt;
  key.first = {static_cast<std::int64_t>(st.st_dev), static_cast<std::int64_t>(st.st_ino), static_cast<std::int64_t>(st.st_size),
               static_cast<std::int64_t>(st.st_mtim.tv_sec), static_cast<std::int64_t>(st.st_mtim.tv_nsec)};
  key.second = options.as_points ? "points;" : "as read;";
  for (const int c : options.las_drop_classes) key.second += std::to_string(c) + ",";
  ProbeCache& c = probe_cache();
  const std::lock_guard<std::mutex> lock(c.mutex);
  const auto it = c.probes.find(key);
  return it == c.probes.end() ? std::nullopt : std::optional<FileProbe>(it->second);
}
void remember_probe(const ProbeKey& key, const FileProbe& p) {
  if (key.first == std::array<std::int64_t, 5>{}) return;
  ProbeCache& c = probe_cache();
  const std::lock_guard<std::mutex> lock(c.mutex);
  if (c.probes.size() >= 4096) c.probes.clear();  // bounded: a few hundred bytes an entry
  c.probes[key] = p;
}

// Several files in one frame (open_point_streams), or scans placed by their poses
// (open_posed_point_streams): each file's stream in turn.
class FilesStream final : public PointStream {
 public:
  // `poses`: empty (input.shared_frame), or one scan-to-world transform per file (input.conf).
  FilesStream(std::vector<std::filesystem::path> files, const LoadOptions& options, std::vector<Eigen::Affine3d> poses = {})
      : files_(std::move(files)), options_(options), poses_(std::move(poses)) {
    const bool posed = !poses_.empty();
    const char* key = posed ? "input.conf" : "input.shared_frame";
    std::pair<std::string, std::string> crs;
    bool any_rgb = false, any_intensity = false;
    std::string no_rgb, no_intensity;  // the first file without each
    for (const auto& f : files_) {
      ProbeKey probe_key{};
      std::optional<FileProbe> p = recall_probe(f, options_, probe_key);
      if (!p) {
        const auto s = open_point_stream(f, options_);
        Cloud c;
        const bool any = s->next(c, 1);
        // A scan without points merges as none (load_and_merge_scans: no colour, no intensity).
        if (!any && !posed) throw InputError("input.shared_frame: " + detail::quoted(f) + " holds no points");
        p = FileProbe{s->total_points(), s->crs(), s->streamed(), c.has_rgb(), c.has_intensity(), c.float32_xyz};
        remember_probe(probe_key, *p);
      }
      total_ += p->total;
      if (!posed) check_same_crs(crs, p->crs, f);  // poses place the scans: the merge declares no CRS
      streamed_ = streamed_ && p->streamed;
      float32_ = float32_ || p->float32;
      any_rgb = any_rgb || p->rgb;
      any_intensity = any_intensity || p->intensity;
      if (!p->rgb && no_rgb.empty()) no_rgb = f.filename().string();
      if (!p->intensity && no_intensity.empty()) no_intensity = f.filename().string();
    }
    crs_ = crs.first;
    float32_ = float32_ && !posed;  // posed coordinates are no file's floats: spilled as doubles
    keep_rgb_ = no_rgb.empty();
    keep_intensity_ = no_intensity.empty();
    if (any_rgb && !keep_rgb_) notes_.push_back(std::string(key) + ": rgb dropped: " + no_rgb + " has none");
    if (any_intensity && !keep_intensity_) notes_.push_back(std::string(key) + ": intensity dropped: " + no_intensity + " has none");
  }
  std::uint64_t total_points() const override { return total_; }
  const std::vector<std::string>& notes() const override { return notes_; }
  bool streamed() const override { return streamed_; }
  std::string crs() const override { return crs_; }
  bool next(Cloud& chunk, std::size_t max_points) override {
    while (at_ < files_.size()) {
      if (!now_) now_ = open_point_stream(files_[at_], options_);
      if (now_->next(chunk, max_points)) {
        given_ += chunk.size();
        if (!keep_rgb_) chunk.rgb.clear();
        if (!keep_intensity_) chunk.intensity.clear();
        if (!poses_.empty()) move_to_world(poses_[at_], chunk.xyz);
        chunk.float32_xyz = float32_;
        return true;
      }
      const std::string name = files_[at_].filename().string();
      notes_.push_back(name + ": " + std::to_string(given_) + " points");
      for (const auto& n : now_->notes()) notes_.push_back(name + ": " + n);
      now_.reset();
      given_ = 0;
      ++at_;
    }
    chunk = Cloud();
    return false;
  }

 private:
  std::vector<std::filesystem::path> files_;
  LoadOptions options_;
  std::vector<Eigen::Affine3d> poses_;  // per file, or empty
  std::unique_ptr<PointStream> now_;  // files_[at_]'s stream, once opened
  std::size_t at_ = 0;
  std::uint64_t total_ = 0, given_ = 0;  // given_: files_[at_]'s points handed out
  bool streamed_ = true, float32_ = false, keep_rgb_ = true, keep_intensity_ = true;
  std::string crs_;
  std::vector<std::string> notes_;
};

}  // namespace

namespace detail {

bool FileMapping::map(int fd) {
  struct stat st {};
  if (::fstat(fd, &st) != 0 || st.st_size <= 0) return false;
  void* p = ::mmap(nullptr, static_cast<std::size_t>(st.st_size), PROT_READ, MAP_PRIVATE, fd, 0);
  if (p == MAP_FAILED) return false;
  data = static_cast<const char*>(p);
  size = static_cast<std::size_t>(st.st_size);
  return true;
}

FileMapping::~FileMapping() {
  if (data != nullptr) ::munmap(const_cast<char*>(data), size);
}

std::optional<FileKey> large_file_key(int fd) {
  struct stat st {};
  if (::fstat(fd, &st) != 0 || st.st_size < (off_t{64} << 20)) return std::nullopt;
  return FileKey{static_cast<std::uint64_t>(st.st_dev), static_cast<std::uint64_t>(st.st_ino),
                 static_cast<std::uint64_t>(st.st_size), static_cast<std::int64_t>(st.st_mtim.tv_sec),
                 static_cast<std::int64_t>(st.st_mtim.tv_nsec)};
}

namespace {
struct FirstPassCache {
  std::mutex mutex;
  std::vector<std::tuple<FileKey, std::string, std::array<std::uint64_t, 2>>> entries;  // newest last
};
FirstPassCache& first_pass_cache() {
  static FirstPassCache cache;
  return cache;
}
}  // namespace

bool recall_first_pass(const FileKey& key, const std::string& what, std::array<std::uint64_t, 2>& values) {
  FirstPassCache& c = first_pass_cache();
  const std::lock_guard<std::mutex> lock(c.mutex);
  for (const auto& [k, w, v] : c.entries) {
    if (k == key && w == what) {
      values = v;
      return true;
    }
  }
  return false;
}

void remember_first_pass(const FileKey& key, const std::string& what, const std::array<std::uint64_t, 2>& values) {
  FirstPassCache& c = first_pass_cache();
  const std::lock_guard<std::mutex> lock(c.mutex);
  if (c.entries.size() == 16) c.entries.erase(c.entries.begin());
  c.entries.emplace_back(key, what, values);
}

}  // namespace detail

std::unique_ptr<PointStream> open_point_stream(const std::filesystem::path& path, const LoadOptions& options) {
  std::string ext;
  const bool gz = detail::gz_name(path, ext);
  std::error_code ec;
  if (std::filesystem::is_regular_file(path, ec)) {
    // Natively streamed; under gzip the text formats and PLY (decompressed as they are read).
    if (ext == ".ply") {
      if (auto s = detail::open_ply_stream(path, detail::quoted(path), options.as_points, gz)) return s;
    }
    if (ext == ".ptx") return detail::open_ptx_stream(path, detail::quoted(path), gz);
    if (ext == ".pts") return detail::open_pts_stream(path, detail::quoted(path), gz);
    if (ext == ".xyz" || ext == ".txt") return detail::open_xyz_stream(path, detail::quoted(path), gz);
    if (ext == ".obj") {
      if (auto s = detail::open_obj_stream(path, detail::quoted(path), options.as_points, gz)) return s;
    }
    if (ext == ".pcd") {
      if (auto s = detail::open_pcd_stream(path, detail::quoted(path), gz)) return s;
    }
    // A gzipped LAS, LAZ or E57 file with a plain copy (LoadOptions::inflated): the copy, named
    // as the original.
    if (gz && detail::reader_seeks(ext)) {
      for (const auto& [original, copy] : options.inflated) {
        if (original != path) continue;
        std::unique_ptr<PointStream> s = ext == ".las"   ? detail::open_las_stream(copy, detail::quoted(path), &options)
                                         : ext == ".laz" ? detail::open_laz_stream(copy, detail::quoted(path), &options)
                                                         : detail::open_e57_stream(copy, detail::quoted(path));
        if (s) return s;
        break;  // the whole read (of the original) says what is wrong
      }
    }
    if (!gz && ext == ".las") {
      if (auto s = detail::open_las_stream(path, detail::quoted(path), &options)) return s;
    }
    if (!gz && ext == ".e57") {
      if (auto s = detail::open_e57_stream(path, detail::quoted(path))) return s;
    }
    if (!gz && ext == ".laz") {
      if (auto s = detail::open_laz_stream(path, detail::quoted(path), &options)) return s;
    }
  }
  StageResult<Cloud> read = load_cloud(path, options);
  if (read.value.has_mesh()) {
    throw InputError("load_cloud: " + detail::quoted(path) + " is a mesh (" + std::to_string(read.value.mesh.triangles.size()) +
                     " triangles): it is rasterised in core, not streamed (input.as_points: true takes its vertices)");
  }
  return std::make_unique<WholeStream>(std::move(read));
}

std::unique_ptr<PointStream> open_point_streams(const std::vector<std::filesystem::path>& files, const LoadOptions& options) {
  if (files.empty()) throw InputError("open_point_streams: no files given (input.files is empty)");
  if (files.size() == 1) return open_point_stream(files.front(), options);
  return std::make_unique<FilesStream>(files, options);
}

std::unique_ptr<PointStream> open_posed_point_streams(const std::vector<std::filesystem::path>& scans,
                                                      const std::filesystem::path& conf_path, const LoadOptions& options) {
  return std::make_unique<FilesStream>(scans, options, scan_poses(scans, conf_path));
}

}  // namespace hc::pipeline
