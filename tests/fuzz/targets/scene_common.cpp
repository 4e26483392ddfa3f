#include "scene_common.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/lod_report.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <algorithm>
#include <fstream>
#include <functional>
#include <map>
#include <sstream>
#include <stdexcept>

namespace hc::fuzz {
namespace {

namespace fs = std::filesystem;

/// The bytes of `file`, read through a stream (libstdc++'s file streams retry a read a signal
/// interrupts).
std::string read_bytes(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw std::runtime_error("hc fuzz: cannot open " + file.string());
  std::ostringstream bytes;
  bytes << in.rdbuf();
  if (in.bad() || !bytes) throw std::runtime_error("hc fuzz: cannot read " + file.string());
  return bytes.str();
}

/// Writes `size` bytes to `file`, replacing it, through a stream (libstdc++'s file streams
/// retry a write a signal interrupts).
void write_bytes(const fs::path& file, const char* data, std::size_t size) {
  std::ofstream out(file, std::ios::binary | std::ios::trunc);
  out.write(data, static_cast<std::streamsize>(size));
  out.close();
  if (!out) throw std::runtime_error("hc fuzz: cannot write " + file.string());
}

/// A copy of a base scene folder in the scratch folder, and the image files it holds (paths
/// relative to it, sorted: an input byte maps to one file).
///
/// Files are copied through streams from bytes held in memory, not with std::filesystem::copy:
/// libFuzzer's timer signal (SIGALRM, installed without SA_RESTART) interrupts the kernel copy
/// that libstdc++ uses, and copy_file then throws "Interrupted system call" instead of retrying.
/// Every file's bytes are kept: any of them (an image, scene.yaml) may be the one replaced.
struct SceneCopy {
  fs::path base, dir;
  std::vector<std::string> images;  ///< the image files, then the binary ones (.bin)
  std::vector<std::string> binaries;
  std::map<std::string, std::string> base_bytes;  ///< the base's bytes of each file (relative path)
  std::string replaced;

  SceneCopy(const fs::path& base_dir, const std::string& name) : base(base_dir), dir(scratch_dir() / name) {
    fs::create_directories(dir);
    for (const auto& e : fs::recursive_directory_iterator(base)) {
      const fs::path rel = fs::relative(e.path(), base);
      if (e.is_directory()) {
        fs::create_directories(dir / rel);
        continue;
      }
      std::string bytes = read_bytes(e.path());
      write_bytes(dir / rel, bytes.data(), bytes.size());
      const auto ext = e.path().extension();
      if (ext == ".tif" || ext == ".tiff" || ext == ".png") images.push_back(rel.string());
      if (ext == ".bin") binaries.push_back(rel.string());
      base_bytes.emplace(rel.string(), std::move(bytes));
    }
    std::sort(images.begin(), images.end());
    if (images.empty()) throw std::runtime_error("hc fuzz: no image file in " + base.string());
    // Binary files after the images, so that a corpus input's first byte keeps naming the image
    // it named before they were added (scene_tiled: points_sample.bin, 2026-11-29).
    std::sort(binaries.begin(), binaries.end());
    images.insert(images.end(), binaries.begin(), binaries.end());
  }

  /// Writes `data` over `file` (restoring the file the previous call replaced), then runs `use`.
  void with(const std::string& file, const std::uint8_t* data, std::size_t size, const std::function<void()>& use) {
    if (base_bytes.count(file) == 0) throw std::logic_error("hc fuzz: " + file + " is not a file of " + base.string());
    if (!replaced.empty()) {
      const std::string& original = base_bytes.at(replaced);
      write_bytes(dir / replaced, original.data(), original.size());
    }
    replaced = file;
    write_bytes(dir / file, reinterpret_cast<const char*>(data), size);
    try {
      use();
    } catch (const hc::Error&) {
    }
  }
};

SceneCopy& flat_scene() {
  static SceneCopy copy(HC_FUZZ_SCENE_BASE, "scene");  // tests/fuzz/scene_base (set by CMake)
  return copy;
}

SceneCopy& tiled_scene() {
  static SceneCopy copy(HC_FUZZ_SCENE_TILED_BASE, "scene_tiled");  // tests/fuzz/scene_tiled_base
  return copy;
}

}  // namespace

const std::vector<std::string>& scene_base_layers() { return flat_scene().images; }

void load_scene_with(const std::string& file, const std::uint8_t* data, std::size_t size) {
  SceneCopy& s = flat_scene();
  s.with(file, data, size, [&] { (void)pipeline::load_scene(s.dir); });
}

const std::vector<std::string>& tiled_scene_files() { return tiled_scene().images; }

void open_tiled_scene_with(const std::string& file, const std::uint8_t* data, std::size_t size) {
  SceneCopy& s = tiled_scene();
  s.with(file, data, size, [&] {
    try {
      (void)pipeline::load_scene(s.dir);
    } catch (const hc::Error&) {
    }
    const Scene header = pipeline::load_scene(s.dir, false);
    auto levels = pipeline::LodPyramid::open_stored(s.dir, header.lod);
    for (int l = 0; l < levels->level_count(); ++l) {
      const GridGeometry& g = levels->geometry(l);
      try {
        (void)levels->window(l, 0, 0, 24, 24);
        (void)levels->window(l, g.rows / 2, g.cols / 3, 7, 19);
      } catch (const hc::Error&) {
      }
    }
    (void)levels->level(levels->level_count() - 1);
    try {
      (void)pipeline::read_level_point_sample(s.dir);
    } catch (const hc::Error&) {
    }
  });
}

}  // namespace hc::fuzz
