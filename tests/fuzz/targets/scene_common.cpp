#include "scene_common.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <algorithm>
#include <fstream>
#include <functional>
#include <stdexcept>

namespace hc::fuzz {
namespace {

namespace fs = std::filesystem;

/// A copy of a base scene folder in the scratch folder, and the image files it holds (paths
/// relative to it, sorted: an input byte maps to one file).
struct SceneCopy {
  fs::path base, dir;
  std::vector<std::string> images;
  std::string replaced;

  SceneCopy(const fs::path& base_dir, const std::string& name) : base(base_dir), dir(scratch_dir() / name) {
    fs::create_directories(dir);
    fs::copy(base, dir, fs::copy_options::recursive | fs::copy_options::overwrite_existing);
    for (const auto& e : fs::recursive_directory_iterator(base)) {
      const auto ext = e.path().extension();
      if (ext == ".tif" || ext == ".tiff" || ext == ".png") images.push_back(fs::relative(e.path(), base).string());
    }
    std::sort(images.begin(), images.end());
    if (images.empty()) throw std::runtime_error("hc fuzz: no image file in " + base.string());
  }

  /// Writes `data` over `file` (restoring the file the previous call replaced), then runs `use`.
  void with(const std::string& file, const std::uint8_t* data, std::size_t size, const std::function<void()>& use) {
    if (!replaced.empty()) fs::copy_file(base / replaced, dir / replaced, fs::copy_options::overwrite_existing);
    replaced = file;
    {
      std::ofstream out(dir / file, std::ios::binary | std::ios::trunc);
      out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
      if (!out) throw std::runtime_error("hc fuzz: cannot write " + (dir / file).string());
    }
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
  });
}

}  // namespace hc::fuzz
