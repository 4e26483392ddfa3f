// GeoTIFF export through GDAL (raster_export.hpp). GDAL lives in a module loaded on the first
// export (pipeline/gdal/geotiff_gdal.cpp, interface geotiff_module.h): every other command starts
// without it.

#include "hc/pipeline/raster_export.hpp"

#include "hc/common/file_output.hpp"

#include "hc/common/error.hpp"

#include "geotiff_module.h"
#include "modules.hpp"

#include <dlfcn.h>

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <system_error>

namespace hc::pipeline {

namespace {

// The module's file name; where it is looked for: detail::load_module ($HC_GDAL_MODULE first).
constexpr const char* kModuleName = "hc_geotiff_gdal.so";

struct Module {
  HcGeoTiffWriteFn write = nullptr;
  std::string path;   // the file loaded
  std::string tried;  // where it was looked for, for the error
};

const Module& geotiff_module() {
  static Module module;
  static std::once_flag once;
  std::call_once(once, [] {
    const detail::LoadedModule m = detail::load_module(kModuleName, "HC_GDAL_MODULE", {HC_GEOTIFF_WRITE_SYMBOL});
    module.tried = m.tried;
    if (!m.handle) return;
    module.write = reinterpret_cast<HcGeoTiffWriteFn>(dlsym(m.handle, HC_GEOTIFF_WRITE_SYMBOL));
    module.path = m.path;
  });
  return module;
}

}  // namespace

GeoTiffLayout geotiff_layout(const GridGeometry& g, const Eigen::Affine3d& model_to_grid, bool is_height) {
  GeoTiffLayout out;
  const Eigen::Matrix3d l = model_to_grid.linear();
  const double s = l.col(0).norm();
  out.file_frame = s > 0.0 && std::isfinite(s) && (l - s * Eigen::Matrix3d::Identity()).norm() <= 1e-9 * s;
  const double top_y = g.y_of_row(g.rows - 1);
  if (out.file_frame) {
    // grid = s·file + t, so file = (grid − t) / s.
    const Eigen::Vector3d t = model_to_grid.translation();
    const double cell = g.cell_size_m / s;
    out.geotransform = {(g.x0_m - t.x()) / s - 0.5 * cell, cell, 0.0, (top_y - t.y()) / s + 0.5 * cell, 0.0, -cell};
    if (is_height) {
      out.z_scale = 1.0 / s;
      out.z_offset = -t.z() / s;
    }
  } else {
    const double cell = g.cell_size_m;
    out.geotransform = {g.x0_m - 0.5 * cell, cell, 0.0, top_y + 0.5 * cell, 0.0, -cell};
  }
  return out;
}

std::string geotiff_module_path() {
  try {
    return geotiff_module().path;
  } catch (...) {
    return {};
  }
}

std::vector<std::string> write_geotiff(const HeightField& layer, const GeoTiffLayout& layout, const std::string& crs,
                                       const std::filesystem::path& file, const std::vector<std::string>& metadata) {
  namespace fs = std::filesystem;
  if (layer.rows() < 1 || layer.cols() < 1) throw std::invalid_argument("write_geotiff: the layer is empty");
  std::error_code ec;
  const fs::path target = file.has_parent_path() ? file : fs::path(".") / file;
  if (!fs::is_directory(target.parent_path(), ec)) {
    throw InputError("export: folder " + target.parent_path().string() + " of " + file.string() + " does not exist");
  }
  if (fs::exists(fs::symlink_status(target, ec))) {
    throw InputError("export: " + target.string() + " exists already (not overwritten; choose another --out)");
  }
  for (const std::string& item : metadata) {
    const std::size_t eq = item.find('=');
    if (eq == std::string::npos || eq == 0) throw std::invalid_argument("write_geotiff: metadata item '" + item + "' is not KEY=VALUE");
  }
  const Module& module = geotiff_module();
  if (!module.write) {
    throw InputError("export: cannot write " + target.string() + ": the GeoTIFF writer module " + kModuleName +
                     " (GDAL) was not found or not loaded; looked at " + module.tried +
                     " (set HC_GDAL_MODULE to its path)");
  }
  const fs::path tmp = create_temporary_beside(target);
  // Removes the temporary on every way out but the successful link (exceptions included).
  struct RemoveTemporary {
    const fs::path& path;
    bool keep = false;
    ~RemoveTemporary() {
      std::error_code e;
      if (!keep) fs::remove(path, e);
    }
  } cleanup{tmp};
  // Image row j = grid row rows − 1 − j (upright), values mapped to the file frame.
  std::vector<float> pixels(static_cast<std::size_t>(layer.rows()) * static_cast<std::size_t>(layer.cols()));
  for (int j = 0; j < layer.rows(); ++j) {
    const int r = layer.rows() - 1 - j;
    for (int c = 0; c < layer.cols(); ++c) {
      const float v = layer.at(r, c);
      pixels[static_cast<std::size_t>(j) * static_cast<std::size_t>(layer.cols()) + static_cast<std::size_t>(c)] =
          std::isnan(v) ? v : static_cast<float>(layout.z_scale * static_cast<double>(v) + layout.z_offset);
    }
  }
  std::vector<const char*> items;
  for (const std::string& item : metadata) items.push_back(item.c_str());
  const std::string tmp_path = tmp.string();
  HcGeoTiffJob job{};
  job.abi = HC_GEOTIFF_ABI;
  job.path = tmp_path.c_str();
  job.cols = layer.cols();
  job.rows = layer.rows();
  job.pixels = pixels.data();
  job.geotransform = layout.geotransform.data();
  job.crs = crs.c_str();
  job.crs_in_file_frame = layout.file_frame ? 1 : 0;
  job.metadata = items.data();
  job.n_metadata = items.size();
  HcGeoTiffResult result{};
  if (module.write(&job, &result) != 0) {
    throw InputError("export: " + std::string(result.what) + " " + target.string() + ": " + result.detail);
  }
  std::vector<std::string> notes;
  std::istringstream lines(result.notes);
  for (std::string line; std::getline(lines, line);)
    if (!line.empty()) notes.push_back(line);
  if (!link_into_place(tmp, target)) {
    const std::string why = errno == EEXIST ? "it exists already (not overwritten)" : std::strerror(errno);
    throw InputError("export: cannot put " + target.string() + " in place: " + why);
  }
  cleanup.keep = true;
  return notes;
}

}  // namespace hc::pipeline
