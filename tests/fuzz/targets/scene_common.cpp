#include "scene_common.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <algorithm>
#include <fstream>
#include <stdexcept>

namespace hc::fuzz {
namespace {

namespace fs = std::filesystem;

const fs::path& base_dir() {
  static const fs::path dir = HC_FUZZ_SCENE_BASE;  // tests/fuzz/scene_base (set by CMake)
  return dir;
}

fs::path scene_dir() {
  static const fs::path dir = [] {
    const fs::path d = scratch_dir() / "scene";
    fs::create_directories(d);
    for (const auto& e : fs::directory_iterator(base_dir())) fs::copy_file(e.path(), d / e.path().filename());
    return d;
  }();
  return dir;
}

}  // namespace

const std::vector<std::string>& scene_base_layers() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> n;
    for (const auto& e : fs::directory_iterator(base_dir())) {
      const auto ext = e.path().extension();
      if (ext == ".tif" || ext == ".tiff" || ext == ".png") n.push_back(e.path().filename().string());
    }
    std::sort(n.begin(), n.end());
    if (n.empty()) throw std::runtime_error("hc fuzz: no TIFF layer in " + base_dir().string());
    return n;
  }();
  return names;
}

void load_scene_with(const std::string& file, const std::uint8_t* data, std::size_t size) {
  static std::string replaced;
  const fs::path dir = scene_dir();
  if (!replaced.empty()) fs::copy_file(base_dir() / replaced, dir / replaced, fs::copy_options::overwrite_existing);
  replaced = file;
  {
    std::ofstream out(dir / file, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
    if (!out) throw std::runtime_error("hc fuzz: cannot write " + (dir / file).string());
  }
  try {
    (void)pipeline::load_scene(dir);
  } catch (const hc::Error&) {
  }
}

}  // namespace hc::fuzz
