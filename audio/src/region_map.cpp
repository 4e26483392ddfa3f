#include "hc/audio/region_map.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <string>

namespace hc::audio {
namespace {

constexpr std::size_t kMaxCells = std::size_t{64} << 20;

/// Even-odd rule point-in-polygon test.
bool inside_polygon(const std::vector<std::array<double, 2>>& poly, double x, double y) {
  bool in = false;
  const std::size_t n = poly.size();
  for (std::size_t i = 0, j = n - 1; i < n; j = i++) {
    const double xi = poly[i][0], yi = poly[i][1], xj = poly[j][0], yj = poly[j][1];
    if ((yi > y) != (yj > y)) {
      const double xc = xi + (y - yi) * (xj - xi) / (yj - yi);
      if (x < xc) in = !in;
    }
  }
  return in;
}

void bounds_of(const RegionShape& s, double& x0, double& y0, double& x1, double& y1) {
  if (s.kind == ShapeKind::kBox) {
    x0 = s.x_min_m, y0 = s.y_min_m, x1 = s.x_max_m, y1 = s.y_max_m;
    return;
  }
  x0 = y0 = std::numeric_limits<double>::infinity();
  x1 = y1 = -std::numeric_limits<double>::infinity();
  for (const auto& v : s.polygon_m) {
    x0 = std::min(x0, v[0]), x1 = std::max(x1, v[0]);
    y0 = std::min(y0, v[1]), y1 = std::max(y1, v[1]);
  }
}

std::string pgm_token(std::istream& in, const std::filesystem::path& path) {
  std::string tok;
  while (in) {
    const int c = in.get();
    if (c == '#') {
      std::string line;
      std::getline(in, line);
      continue;
    }
    if (c == EOF) break;
    if (std::isspace(c)) {
      if (!tok.empty()) return tok;
      continue;
    }
    tok.push_back(static_cast<char>(c));
  }
  if (tok.empty()) throw InputError("audio: label image '" + path.string() + "' has a truncated PGM header");
  return tok;
}

}  // namespace

LabelImage read_label_pgm(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError("audio: label image '" + path.string() + "' cannot be opened (does it exist?)");
  if (pgm_token(in, path) != "P5") {
    throw InputError("audio: label image '" + path.string() + "' is not a binary PGM (expected the magic 'P5')");
  }
  int w = 0, h = 0, maxval = 0;
  try {
    w = std::stoi(pgm_token(in, path));
    h = std::stoi(pgm_token(in, path));
    maxval = std::stoi(pgm_token(in, path));
  } catch (const std::logic_error&) {
    throw InputError("audio: label image '" + path.string() + "' has a malformed PGM header (width, height, maxval)");
  }
  if (w < 1 || h < 1 || maxval < 1 || maxval > 65535 ||
      static_cast<std::size_t>(w) * static_cast<std::size_t>(h) > kMaxCells) {
    throw InputError("audio: label image '" + path.string() + "' has an invalid size " + std::to_string(w) + "x" +
                     std::to_string(h) + " or maxval " + std::to_string(maxval));
  }
  LabelImage img;
  img.rows = h;
  img.cols = w;
  const std::size_t n = static_cast<std::size_t>(w) * static_cast<std::size_t>(h);
  const std::size_t bytes = maxval > 255 ? 2 : 1;
  std::vector<unsigned char> raw(n * bytes);
  in.read(reinterpret_cast<char*>(raw.data()), static_cast<std::streamsize>(raw.size()));
  if (static_cast<std::size_t>(in.gcount()) != raw.size()) {
    throw InputError("audio: label image '" + path.string() + "' is truncated: " + std::to_string(in.gcount()) +
                     " of " + std::to_string(raw.size()) + " pixel bytes");
  }
  img.labels.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    img.labels[i] = bytes == 2 ? (raw[2 * i] << 8 | raw[2 * i + 1]) : raw[i];
  }
  return img;
}

RegionMap::RegionMap(const std::vector<RegionConfig>& regions, const GridGeometry* grid, double cell_m,
                     const LabelImage* labels) {
  if (regions.empty()) return;
  bool any_label = false;
  for (const auto& r : regions) any_label = any_label || r.shape.kind == ShapeKind::kLabel;
  if (any_label && (labels == nullptr || grid == nullptr)) {
    throw ConfigError("audio: label regions need both audio.label_image and the scene's grid");
  }
  if (grid != nullptr) {
    if (grid->rows < 1 || grid->cols < 1 || !(grid->cell_size_m > 0.0)) {
      throw ConfigError("audio: the region raster's grid is empty or has a non-positive cell size");
    }
    geometry_ = *grid;
  } else {
    if (!(cell_m > 0.0) || !std::isfinite(cell_m)) {
      throw ConfigError("audio: region_cell_m = " + std::to_string(cell_m) + ": expected a number > 0");
    }
    double x0 = std::numeric_limits<double>::infinity(), y0 = x0, x1 = -x0, y1 = -x0;
    for (const auto& r : regions) {
      double a, b, c, d;
      bounds_of(r.shape, a, b, c, d);
      x0 = std::min(x0, a), y0 = std::min(y0, b), x1 = std::max(x1, c), y1 = std::max(y1, d);
    }
    const double cols = std::ceil((x1 - x0) / cell_m) + 1;
    const double rows = std::ceil((y1 - y0) / cell_m) + 1;
    if (!(cols * rows <= static_cast<double>(kMaxCells))) {
      throw ResourceError("audio: the region raster would need " + std::to_string(cols * rows) +
                          " cells at region_cell_m = " + std::to_string(cell_m) + "; at most " +
                          std::to_string(kMaxCells) + " (increase audio.region_cell_m)");
    }
    geometry_ = GridGeometry{static_cast<int>(rows), static_cast<int>(cols), x0, y0, cell_m};
  }
  if (geometry_.cell_count() > kMaxCells) {
    throw ResourceError("audio: the region raster would need " + std::to_string(geometry_.cell_count()) +
                        " cells; at most " + std::to_string(kMaxCells));
  }
  if (labels != nullptr && any_label && (labels->rows != geometry_.rows || labels->cols != geometry_.cols)) {
    throw ConfigError("audio: the label image is " + std::to_string(labels->cols) + "x" + std::to_string(labels->rows) +
                      " (cols x rows) but the grid is " + std::to_string(geometry_.cols) + "x" +
                      std::to_string(geometry_.rows) + ": expected the same size");
  }
  inv_cell_ = 1.0 / geometry_.cell_size_m;
  ids_.assign(geometry_.cell_count(), -1);
  const GridGeometry& g = geometry_;
  for (std::size_t id = 0; id < regions.size(); ++id) {
    const RegionShape& s = regions[id].shape;
    const auto rid = static_cast<std::int32_t>(id);
    if (s.kind == ShapeKind::kLabel) {
      for (std::size_t i = 0; i < ids_.size(); ++i) {
        if (labels->labels[i] == s.label) ids_[i] = rid;
      }
      continue;
    }
    double x0, y0, x1, y1;
    bounds_of(s, x0, y0, x1, y1);
    const int c0 = std::max(0, static_cast<int>(std::floor(g.col_of_x(x0))));
    const int c1 = std::min(g.cols - 1, static_cast<int>(std::ceil(g.col_of_x(x1))));
    const int r0 = std::max(0, static_cast<int>(std::floor(g.row_of_y(y0))));
    const int r1 = std::min(g.rows - 1, static_cast<int>(std::ceil(g.row_of_y(y1))));
    for (int r = r0; r <= r1; ++r) {
      const double y = g.y_of_row(r);
      for (int c = c0; c <= c1; ++c) {
        const double x = g.x_of_col(c);
        const bool in = s.kind == ShapeKind::kBox ? (x >= x0 && x <= x1 && y >= y0 && y <= y1)
                                                  : inside_polygon(s.polygon_m, x, y);
        if (in) ids_[static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(c)] = rid;
      }
    }
  }
}

HeightField RegionMap::to_layer(const GridGeometry& grid) const {
  HeightField out(grid);
  for (int r = 0; r < grid.rows; ++r) {
    for (int c = 0; c < grid.cols; ++c) {
      const std::int32_t id = lookup(grid.x_of_col(c), grid.y_of_row(r));
      out.at(r, c) = id >= 0 ? static_cast<float>(id) : kNoData;
    }
  }
  return out;
}

std::vector<std::size_t> RegionMap::counts(std::size_t region_count) const {
  std::vector<std::size_t> n(region_count, 0);
  for (std::int32_t id : ids_) {
    if (id >= 0 && static_cast<std::size_t>(id) < region_count) ++n[static_cast<std::size_t>(id)];
  }
  return n;
}

}  // namespace hc::audio
