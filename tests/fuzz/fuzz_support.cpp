#include "fuzz_support.hpp"

#include <cstdlib>
#include <fstream>
#include <stdexcept>
#include <system_error>
#include <unistd.h>

namespace hc::fuzz {

namespace {

struct Scratch {
  std::filesystem::path dir;
  Scratch() {
    std::string tmpl = (std::filesystem::temp_directory_path() / "hc-fuzz-XXXXXX").string();
    if (::mkdtemp(tmpl.data()) == nullptr) throw std::runtime_error("hc fuzz: cannot create " + tmpl);
    dir = tmpl;
  }
  ~Scratch() {
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
  }
};

}  // namespace

const std::filesystem::path& scratch_dir() {
  static const Scratch scratch;
  return scratch.dir;
}

std::filesystem::path write_scratch(const std::string& name, const std::uint8_t* data, std::size_t size) {
  const std::filesystem::path p = scratch_dir() / name;
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  if (!out) throw std::runtime_error("hc fuzz: cannot write " + p.string());
  return p;
}

const std::vector<Target>& all_targets() {
  static const std::vector<Target> targets = {
      {"ply", &ply},           {"pcd", &pcd},
      {"obj", &obj},           {"xyz", &xyz},
      {"scanalyze_conf", &scanalyze_conf}, {"run_config", &run_config},
      {"scene_yaml", &scene_yaml},         {"scene_tiff", &scene_tiff},
      {"falcon_frames", &falcon_frames},
      {"e57", &e57},           {"las", &las},
      {"ptx", &ptx},           {"pts", &pts},
      {"laz", &laz},           {"scene_tiled", &scene_tiled},
  };
  return targets;
}

}  // namespace hc::fuzz
