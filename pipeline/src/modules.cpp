// The pipeline's dlopen modules (modules.hpp).

#include "modules.hpp"

#include "hc/common/error.hpp"

#include <dlfcn.h>

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <vector>

namespace hc::pipeline::detail {

LoadedModule load_module(const char* file_name, const char* env_var, std::initializer_list<const char*> symbols) {
  LoadedModule module;
  std::vector<std::string> candidates;
  if (const char* env = std::getenv(env_var); env && *env) candidates.emplace_back(env);
  // The binary holding this code: dladdr names a shared object by its path, but the main
  // program by argv[0] (a bare "hapticloud" when started from $PATH, which must not be
  // resolved against the working folder): then /proc/self/exe.
  std::vector<std::filesystem::path> binaries;
  Dl_info info{};
  if (dladdr(reinterpret_cast<void*>(&load_module), &info) != 0 && info.dli_fname &&
      std::strchr(info.dli_fname, '/') != nullptr && info.dli_fname[0] == '/') {
    binaries.emplace_back(info.dli_fname);
  }
  binaries.emplace_back("/proc/self/exe");
  for (const std::filesystem::path& b : binaries) {
    std::error_code ec;
    const std::filesystem::path self = std::filesystem::canonical(b, ec);
    if (ec) continue;
    candidates.push_back((self.parent_path() / file_name).string());
    candidates.push_back((self.parent_path() / HC_MODULE_DIR_FROM_BINDIR / file_name).lexically_normal().string());
  }
  // The installed tree's own folder (a program or Python module elsewhere linking the
  // installed library), then the build tree's.
  candidates.push_back((std::filesystem::path(HC_INSTALL_MODULE_DIR) / file_name).string());
  candidates.push_back((std::filesystem::path(HC_BUILD_MODULE_DIR) / file_name).string());
  for (const std::string& c : candidates) {
    module.tried += (module.tried.empty() ? "" : ", ") + c;
    std::error_code ec;
    if (!std::filesystem::is_regular_file(c, ec)) continue;
    void* handle = dlopen(c.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (!handle) {
      const char* why = dlerror();
      module.tried += std::string(" (") + (why ? why : "dlopen failed") + ")";
      continue;
    }
    const char* missing = nullptr;
    for (const char* symbol : symbols)
      if (missing == nullptr && dlsym(handle, symbol) == nullptr) missing = symbol;
    if (missing == nullptr) {
      module.handle = handle;
      module.path = c;
      return module;  // kept loaded for the rest of the process
    }
    module.tried += " (no symbol " + std::string(missing) + ")";
    dlclose(handle);
  }
  return module;
}

const PclModule& pcl_module(const std::string& who) {
  static PclModule module;
  static std::string tried;
  static std::once_flag once;
  std::call_once(once, [] {
    const LoadedModule m =
        load_module("hc_pcl.so", "HC_PCL_MODULE", {HC_PCL_FILTER_SYMBOL, HC_PCL_FREE_SYMBOL});
    tried = m.tried;
    if (!m.handle) return;
    module.filter = reinterpret_cast<HcPclFilterFn>(dlsym(m.handle, HC_PCL_FILTER_SYMBOL));
    module.free = reinterpret_cast<HcPclFreeFn>(dlsym(m.handle, HC_PCL_FREE_SYMBOL));
    module.path = m.path;
  });
  if (!module.filter) {
    throw InputError(who + " needs PCL, but the PCL module hc_pcl.so was not found or not loaded; looked at " + tried +
                     " (set HC_PCL_MODULE to its path)");
  }
  return module;
}

}  // namespace hc::pipeline::detail
