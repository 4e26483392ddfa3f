#include "hc/haptics/haptic_surface.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <new>
#include <sstream>
#include <string>
#include <vector>

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace hc::haptics {
namespace {

std::string geometry_text(const GridGeometry& g) {
  std::ostringstream s;
  s << g.rows << "x" << g.cols << " cells of " << g.cell_size_m << " m at (" << g.x0_m << ", "
    << g.y0_m << ")";
  return s.str();
}

void check_layer(const HeightField* layer, const char* name, const GridGeometry& depth) {
  if (layer == nullptr) return;
  if (!(layer->geometry() == depth)) {
    throw InputError(std::string("haptic surface: layer '") + name + "' has geometry " +
                     geometry_text(layer->geometry()) + ", expected the depth layer's " +
                     geometry_text(depth));
  }
}

void check_option(double value, const char* name) {
  if (!std::isfinite(value) || value < 0.0) {
    std::ostringstream s;
    s << "haptic surface: option " << name << " = " << value << ", expected a finite value >= 0";
    throw ConfigError(s.str());
  }
}

}  // namespace

HapticSurface::HapticSurface(const SurfaceLayers& layers, const SurfaceOptions& options)
    : options_(options) {
  if (layers.depth == nullptr) throw InputError("haptic surface: the depth layer is required");
  const GridGeometry& g = layers.depth->geometry();
  if (g.rows < 1 || g.cols < 1 || !(g.cell_size_m > 0.0) || !std::isfinite(g.cell_size_m)) {
    throw InputError("haptic surface: depth layer has invalid geometry " + geometry_text(g) +
                     " (expected rows, cols >= 1 and cell_size_m > 0)");
  }
  check_layer(layers.envelope, "envelope", g);
  check_layer(layers.texture, "texture", g);
  check_layer(layers.mu_d, "mu_d", g);
  check_layer(layers.mu_s, "mu_s", g);
  check_layer(layers.region_id, "region_id", g);
  check_option(options.texture_gain, "texture_gain");
  check_option(options.default_mu_d, "default_mu_d");
  check_option(options.default_mu_s, "default_mu_s");
  check_option(options.floor_margin_m, "floor_margin_m");
  source_geometry_ = g;

  // Rendered height of every input sample (double for the sum, stored as float).
  const std::size_t n = g.cell_count();
  std::vector<float> rendered(n);
  double lo = std::numeric_limits<double>::infinity();
  double hi = -lo;
  const float* d = layers.depth->data();
  const float* e = layers.envelope ? layers.envelope->data() : nullptr;
  const float* t = layers.texture ? layers.texture->data() : nullptr;
  const double gain = options.texture_gain;
  for (std::size_t k = 0; k < n; ++k) {
    double env = 0.0;
    double tex = 0.0;
    if (e != nullptr && t != nullptr) {
      env = e[k];
      tex = t[k];
    } else if (e != nullptr) {
      env = e[k];
      tex = static_cast<double>(d[k]) - e[k];
    } else if (t != nullptr) {
      env = static_cast<double>(d[k]) - t[k];
      tex = t[k];
    } else {
      env = d[k];
      tex = 0.0;
    }
    const double z = env + gain * tex;
    if (std::isfinite(z) && std::isfinite(static_cast<double>(d[k]))) {
      rendered[k] = static_cast<float>(z);
      lo = std::min(lo, static_cast<double>(rendered[k]));
      hi = std::max(hi, static_cast<double>(rendered[k]));
    } else {
      rendered[k] = kNoData;
      ++no_data_count_;
    }
  }
  if (!(lo <= hi)) {
    throw DegenerateInputError("haptic surface: no sample of the depth layer (" + geometry_text(g) +
                               ") has a finite rendered height");
  }
  min_height_m_ = lo;
  max_height_m_ = hi;
  floor_m_ = static_cast<double>(static_cast<float>(lo - options.floor_margin_m));
  const float floor_f = static_cast<float>(floor_m_);

  // Padded copy: one ring of floor samples around the input grid.
  GridGeometry pg = g;
  pg.rows = g.rows + 2;
  pg.cols = g.cols + 2;
  pg.x0_m = g.x0_m - g.cell_size_m;
  pg.y0_m = g.y0_m - g.cell_size_m;
  padded_geometry_ = pg;
  const std::size_t pcols = static_cast<std::size_t>(pg.cols);
  const auto padded_index = [pcols](int r, int c) {
    return static_cast<std::size_t>(r + 1) * pcols + static_cast<std::size_t>(c + 1);
  };
  nodes_ = allocate_nodes(pg.cell_count(), floor_f);
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      const float z = rendered[static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) +
                               static_cast<std::size_t>(c)];
      nodes_[padded_index(r, c)] = std::isnan(z) ? floor_f : z;
    }
  }
  surface_ = BilinearSurface(HeightFieldView{nodes_.get(), pg, pg.cols});
  data_ = nodes_.get();
  stride_ = pg.cols;
  x0_m_ = pg.x0_m;
  y0_m_ = pg.y0_m;
  inv_cell_ = 1.0 / pg.cell_size_m;
  max_u_ = static_cast<double>(pg.cols - 1);
  max_v_ = static_cast<double>(pg.rows - 1);
  last_i_ = pg.cols - 2;
  last_j_ = pg.rows - 2;

  const auto pad_layer = [&](const HeightField* layer, double fallback) -> NodeBuffer {
    if (layer == nullptr) return nullptr;
    NodeBuffer out = allocate_nodes(pg.cell_count(), static_cast<float>(fallback));
    for (int r = 0; r < g.rows; ++r) {
      for (int c = 0; c < g.cols; ++c) {
        const float v = layer->at(r, c);
        out[padded_index(r, c)] = std::isfinite(v) && v >= 0.0F ? v : static_cast<float>(fallback);
      }
    }
    return out;
  };
  mu_d_ = pad_layer(layers.mu_d, options.default_mu_d);
  mu_s_ = pad_layer(layers.mu_s, options.default_mu_s);
  if (layers.region_id != nullptr) {
    region_ = std::make_unique<std::int32_t[]>(pg.cell_count());
    std::fill_n(region_.get(), pg.cell_count(), -1);
    for (int r = 0; r < g.rows; ++r) {
      for (int c = 0; c < g.cols; ++c) {
        const float v = layers.region_id->at(r, c);
        region_[padded_index(r, c)] =
            std::isfinite(v) && std::fabs(v) < 2.0e9F ? static_cast<std::int32_t>(std::lround(v))
                                                       : -1;
      }
    }
  }
}

void HapticSurface::FreeDeleter::operator()(float* p) const noexcept { std::free(p); }

HapticSurface::NodeBuffer HapticSurface::allocate_nodes(std::size_t count, float fill) {
  constexpr std::size_t kHugePage = std::size_t{2} << 20;
  const std::size_t bytes = count * sizeof(float);
  const std::size_t align = bytes >= kHugePage ? kHugePage : 64;
  const std::size_t rounded = (bytes + align - 1) / align * align;
  void* p = std::aligned_alloc(align, rounded);
  if (p == nullptr) throw std::bad_alloc();
#if defined(__linux__)
  // Best effort: without transparent huge pages this is a no-op and only costs TLB misses.
  if (align == kHugePage) (void)madvise(p, rounded, MADV_HUGEPAGE);
#endif
  NodeBuffer buffer(static_cast<float*>(p));
  std::fill_n(buffer.get(), count, fill);
  return buffer;
}

FrictionSample HapticSurface::friction_from_maps(double x_m, double y_m) const noexcept {
  // The cell as sample() finds it, once for both layers.
  const CellAt c = locate(x_m, y_m);
  const double u = c.u, v = c.v;
  const auto at = [&](const float* layer) {
    const float* r0 = layer + c.offset;
    return (1 - u) * (1 - v) * r0[0] + u * (1 - v) * r0[1] + (1 - u) * v * r0[stride_] + u * v * r0[stride_ + 1];
  };
  FrictionSample f{options_.default_mu_d, options_.default_mu_s};
  if (mu_d_) f.mu_d = at(mu_d_.get());
  if (mu_s_) f.mu_s = at(mu_s_.get());
  return f;
}

std::int32_t HapticSurface::region_id(double x_m, double y_m) const noexcept {
  if (!region_) return -1;
  const GridGeometry& g = padded_geometry_;
  const double cu = std::round((x_m - g.x0_m) / g.cell_size_m);
  const double cv = std::round((y_m - g.y0_m) / g.cell_size_m);
  if (!(cu >= 0.0 && cu <= g.cols - 1) || !(cv >= 0.0 && cv <= g.rows - 1)) return -1;
  return region_[static_cast<std::size_t>(cv) * static_cast<std::size_t>(g.cols) +
                 static_cast<std::size_t>(cu)];
}

}  // namespace hc::haptics
