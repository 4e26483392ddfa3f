#pragma once
// The pipeline's dlopen modules (hc_geotiff_gdal.so: GDAL; hc_pcl.so: PCL), loaded on first use
// so that commands that never need them start without their libraries (bench/README.md,
// "Start-up"). Private to hc::pipeline.

#include "pcl_module.h"

#include <initializer_list>
#include <string>

namespace hc::pipeline::detail {

/// A module file found and loaded (kept loaded for the rest of the process), or not.
struct LoadedModule {
  void* handle = nullptr;  ///< dlopen's handle, null when not found or not loadable
  std::string path;        ///< the file loaded
  std::string tried;       ///< where it was looked for (and why each failed), for the error
};

/// Looks for the module file `file_name` and loads it (RTLD_NOW | RTLD_LOCAL), accepting the
/// first candidate that exports every one of `symbols` (a stale or foreign file is passed over). Candidates, in order: $`env_var` (a file); beside the
/// binary that holds this code (dladdr, else /proc/self/exe), then that binary's folder +
/// HC_MODULE_DIR_FROM_BINDIR (the installed tree: bin/ → lib/hapticloud/); the installed
/// module folder; the build tree's. Never throws; thread-safe when each caller serialises its
/// own first call (std::call_once).
LoadedModule load_module(const char* file_name, const char* env_var, std::initializer_list<const char*> symbols);

/// The PCL module's entry points (pcl_module.h), loaded on the first call.
struct PclModule {
  HcPclFilterFn filter = nullptr;
  HcPclFreeFn free = nullptr;
  std::string path;
};
/// Releases a filter result's buffers (HcPclFilterResult::kept, ::xyz) when it goes out of
/// scope, on every way out.
struct PclFilterResultGuard {
  const PclModule& module;
  HcPclFilterResult& result;
  ~PclFilterResultGuard() {
    module.free(result.kept);
    module.free(result.xyz);
  }
};

/// The PCL module, loaded once per process.
/// @throws hc::InputError when it cannot be found or loaded, naming `who` (the stage or file
///         that needs PCL), where it looked and the variable HC_PCL_MODULE that names it.
const PclModule& pcl_module(const std::string& who);

}  // namespace hc::pipeline::detail
