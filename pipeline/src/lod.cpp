#include "stage_util.hpp"
#include "tiled_layers.hpp"
#include "hc/pipeline/lod.hpp"

#include "hc/common/error.hpp"
#include "hc/common/format.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <list>
#include <map>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace hc::pipeline {
namespace {

using detail::Clock;
using detail::seconds_since;

std::size_t field_bytes(const HeightField& f) { return f.values().size() * sizeof(float); }

void validate_options(const LodOptions& o) {
  const auto fail = [](const std::string& key, double value, const std::string& expected) {
    throw ConfigError("lod: " + key + " = " + format_number(value) + ": expected " + expected);
  };
  if (o.min_cells < 2 || o.min_cells > 65536) fail("lod.min_cells", o.min_cells, "an integer in [2, 65536]");
  if (!(o.valid_fraction > 0.0 && o.valid_fraction <= 1.0)) fail("lod.valid_fraction", o.valid_fraction, "a number in (0, 1]");
  if (!(o.antialias_sigma_cells >= 0.5 && o.antialias_sigma_cells <= 4.0)) {
    fail("lod.antialias_sigma_cells", o.antialias_sigma_cells, "a number in [0.5, 4]");
  }
  if (!(o.memory_budget_mb > 0.0 && o.memory_budget_mb <= 1e6)) fail("lod.memory_budget_mb", o.memory_budget_mb, "a number in (0, 1e6]");
  if (o.window_cells < 2 || o.window_cells > 4096) fail("lod.window_cells", o.window_cells, "an integer in [2, 4096]");
}

/// Colour of the next level: each channel by downsample_2x over the samples whose depth is
/// valid (so the same mask, the same weights and the same validity as the depth), rounded.
std::vector<std::uint8_t> downsample_colour_2x(const HeightField& fine_depth, std::span<const std::uint8_t> fine_rgb,
                                               double sigma_cells, double valid_fraction) {
  const std::size_t n = fine_depth.values().size();
  std::vector<std::uint8_t> out;
  for (std::size_t ch = 0; ch < 3; ++ch) {
    HeightField channel(fine_depth.geometry());
    for (std::size_t i = 0; i < n; ++i) {
      if (!std::isnan(fine_depth.data()[i])) channel.data()[i] = fine_rgb[3 * i + ch];
    }
    const HeightField coarse = downsample_2x(channel, sigma_cells, valid_fraction);
    if (out.empty()) out.assign(3 * coarse.values().size(), 0);
    for (std::size_t i = 0; i < coarse.values().size(); ++i) {
      const float v = coarse.data()[i];
      if (!std::isnan(v)) out[3 * i + ch] = static_cast<std::uint8_t>(std::clamp(std::lround(v), 0L, 255L));
    }
  }
  return out;
}

}  // namespace

std::size_t LodLevel::bytes() const {
  return field_bytes(depth_m) + field_bytes(envelope_m) + field_bytes(texture_m) + field_bytes(mu_d) +
         field_bytes(mu_s) + colour_rgb8.size() + field_bytes(cell_error_m);
}

std::size_t LodWindowLayers::bytes() const {
  return field_bytes(depth_m) + field_bytes(envelope_m) + field_bytes(texture_m) + field_bytes(mu_d) +
         field_bytes(mu_s) + colour_rgb8.size() + field_bytes(cell_error_m);
}

int lod_level_count(const GridGeometry& finest, int min_cells) {
  if (min_cells < 2) throw ConfigError("lod: lod.min_cells = " + std::to_string(min_cells) + ": expected an integer >= 2");
  int count = 1;
  for (GridGeometry g = finest;;) {
    g.rows = (g.rows + 1) / 2;
    g.cols = (g.cols + 1) / 2;
    if (std::max(g.rows, g.cols) < min_cells || std::min(g.rows, g.cols) < 2) break;
    ++count;
    if (g.rows <= 2 && g.cols <= 2) break;
  }
  return count;
}

GridGeometry lod_level_geometry(const GridGeometry& finest, int level) {
  if (level < 0 || level > 30) throw ConfigError("lod: level " + std::to_string(level) + " is out of range: expected 0..30");
  GridGeometry g = finest;
  for (int l = 0; l < level; ++l) {
    g.rows = (g.rows + 1) / 2;
    g.cols = (g.cols + 1) / 2;
    g.cell_size_m *= 2.0;
  }
  return g;
}

namespace {

void check_downsample_options(double sigma_cells, double valid_fraction) {
  if (!(sigma_cells >= 0.5 && sigma_cells <= 4.0)) {
    throw ConfigError("lod: lod.antialias_sigma_cells = " + format_number(sigma_cells) + ": expected a number in [0.5, 4]");
  }
  if (!(valid_fraction > 0.0 && valid_fraction <= 1.0)) {
    throw ConfigError("lod: lod.valid_fraction = " + format_number(valid_fraction) + ": expected a number in (0, 1]");
  }
}

}  // namespace

int downsample_2x_radius_cells(double sigma_cells) { return static_cast<int>(std::ceil(3.0 * sigma_cells)); }

void downsample_2x_block(const float* fine, const SampleWindow& fine_window, int fine_rows, int fine_cols, double ref,
                         double sigma_cells, double valid_fraction, const SampleWindow& out_block, float* out) {
  check_downsample_options(sigma_cells, valid_fraction);
  const int radius = downsample_2x_radius_cells(sigma_cells);
  const int crows = (fine_rows + 1) / 2, ccols = (fine_cols + 1) / 2;
  // The fine samples the block's kernels reach, clipped to the grid, must lie in the window.
  const int need_r0 = std::max(0, 2 * out_block.row0 - radius);
  const int need_r1 = std::min(fine_rows - 1, 2 * (out_block.row0 + out_block.rows - 1) + radius);
  const int need_c0 = std::max(0, 2 * out_block.col0 - radius);
  const int need_c1 = std::min(fine_cols - 1, 2 * (out_block.col0 + out_block.cols - 1) + radius);
  if (out_block.rows < 1 || out_block.cols < 1 || out_block.row0 < 0 || out_block.col0 < 0 ||
      out_block.row0 + out_block.rows > crows || out_block.col0 + out_block.cols > ccols ||
      fine_window.row0 > need_r0 || fine_window.col0 > need_c0 || fine_window.row0 + fine_window.rows - 1 < need_r1 ||
      fine_window.col0 + fine_window.cols - 1 < need_c1) {
    throw std::invalid_argument("downsample_2x_block: the window does not hold the block's kernels, or the block leaves the level");
  }
  std::vector<double> w(static_cast<std::size_t>(2 * radius + 1));
  for (int k = -radius; k <= radius; ++k) {
    w[static_cast<std::size_t>(k + radius)] = std::exp(-0.5 * k * k / (sigma_cells * sigma_cells));
  }
  // Weight of the in-grid fine samples of each coarse column / row (the certainty of a full grid).
  const auto inside_weight = [&](int centre, int n) {
    double s = 0.0;
    for (int k = -radius; k <= radius; ++k) {
      const int i = centre + k;
      if (i >= 0 && i < n) s += w[static_cast<std::size_t>(k + radius)];
    }
    return s;
  };
  const int bc = out_block.cols, br = out_block.rows;
  std::vector<double> inside_col(static_cast<std::size_t>(bc)), inside_row(static_cast<std::size_t>(br));
  for (int c = 0; c < bc; ++c) inside_col[static_cast<std::size_t>(c)] = inside_weight(2 * (out_block.col0 + c), fine_cols);
  for (int r = 0; r < br; ++r) inside_row[static_cast<std::size_t>(r)] = inside_weight(2 * (out_block.row0 + r), fine_rows);

  // Horizontal pass at the block's coarse columns, every fine row it needs: S = Σ w·m·(z − ref),
  // W = Σ w·m (rounded to float, as every block and the whole grid do).
  const int hrows = need_r1 - need_r0 + 1;
  const std::size_t hn = static_cast<std::size_t>(hrows) * static_cast<std::size_t>(bc);
  std::vector<float> hs(hn), hw(hn);
  for (int r = need_r0; r <= need_r1; ++r) {
    const float* row = fine + static_cast<std::ptrdiff_t>(r - fine_window.row0) * fine_window.cols - fine_window.col0;
    float* os = hs.data() + static_cast<std::ptrdiff_t>(r - need_r0) * bc;
    float* ow = hw.data() + static_cast<std::ptrdiff_t>(r - need_r0) * bc;
    for (int c = 0; c < bc; ++c) {
      const int cc = 2 * (out_block.col0 + c);
      const int lo = std::max(0, cc - radius), hi = std::min(fine_cols - 1, cc + radius);
      double s = 0.0, sw = 0.0;
      for (int i = lo; i <= hi; ++i) {
        const float v = row[i];
        if (std::isnan(v)) continue;
        const double wk = w[static_cast<std::size_t>(i - cc + radius)];
        s += wk * (static_cast<double>(v) - ref);
        sw += wk;
      }
      os[c] = static_cast<float>(s);
      ow[c] = static_cast<float>(sw);
    }
  }
  // Vertical pass at the block's coarse rows.
  for (int r = 0; r < br; ++r) {
    const int rr = 2 * (out_block.row0 + r);
    const int lo = std::max(0, rr - radius), hi = std::min(fine_rows - 1, rr + radius);
    float* o = out + static_cast<std::ptrdiff_t>(r) * bc;
    for (int c = 0; c < bc; ++c) {
      double s = 0.0, sw = 0.0;
      for (int i = lo; i <= hi; ++i) {
        const double wk = w[static_cast<std::size_t>(i - rr + radius)];
        const std::size_t k = static_cast<std::size_t>(i - need_r0) * static_cast<std::size_t>(bc) + static_cast<std::size_t>(c);
        s += wk * hs[k];
        sw += wk * hw[k];
      }
      const double full = inside_row[static_cast<std::size_t>(r)] * inside_col[static_cast<std::size_t>(c)];
      o[c] = sw > 0.0 && sw >= valid_fraction * full * (1.0 - 1e-6) ? static_cast<float>(ref + s / sw) : kNoData;
    }
  }
}

void add_finite_values(const float* values, std::size_t count, ExactFloatSum& sum, std::size_t& finite) {
  for (std::size_t i = 0; i < count; ++i) {
    if (std::isfinite(values[i])) {
      sum.add(values[i]);
      ++finite;
    }
  }
}

HeightField downsample_2x(const HeightField& fine, double sigma_cells, double valid_fraction) {
  check_downsample_options(sigma_cells, valid_fraction);
  const GridGeometry& fg = fine.geometry();
  if (fg.rows < 1 || fg.cols < 1 || fine.values().size() != fg.cell_count()) {
    throw InputError("lod: cannot decimate an empty grid (" + std::to_string(fg.rows) + " x " +
                     std::to_string(fg.cols) + " samples)");
  }
  const GridGeometry cg = lod_level_geometry(fg, 1);
  HeightField coarse(cg);
  coarse.model_to_grid = fine.model_to_grid;

  // Reference height: sums relative to it keep float resolution far below a micrometre. The
  // mean is exact (ExactFloatSum), so a level built tile by tile gets the same bits.
  ExactFloatSum sum;
  std::size_t n_valid = 0;
  add_finite_values(fine.data(), fine.values().size(), sum, n_valid);
  if (n_valid == 0) return coarse;  // all no data
  const double ref = sum.value() / static_cast<double>(n_valid);

  const SampleWindow whole{0, 0, fg.rows, fg.cols};
  const int mid = cg.rows / 2;
  const auto half = [&](int r0, int r1) {
    if (r1 <= r0) return;
    downsample_2x_block(fine.data(), whole, fg.rows, fg.cols, ref, sigma_cells, valid_fraction,
                        SampleWindow{r0, 0, r1 - r0, cg.cols}, coarse.data() + static_cast<std::ptrdiff_t>(r0) * cg.cols);
  };
  if (fine.values().size() >= (std::size_t{1} << 18)) {
    detail::run_two([&] { half(0, mid); }, [&] { half(mid, cg.rows); });
  } else {
    half(0, cg.rows);
  }
  return coarse;
}

// ---------------------------------------------------------------- pyramid and cache

struct LodPyramid::Entry {
  bool is_window = false;
  int level = 0;
  int row0 = 0, col0 = 0, rows = 0, cols = 0;  // windows
  std::shared_ptr<const LodLevel> lvl;         // levels
  std::shared_ptr<const LodWindowLayers> win;  // windows
  std::size_t bytes = 0;
  std::uint64_t last_use = 0;
};

LodPyramid::LodPyramid(LodLevel finest, const SurfaceLayerOptions& layer_options, const LodOptions& options)
    : options_(options), layer_options_(layer_options) {
  validate_options(options_);
  const GridGeometry& g = finest.depth_m.geometry();
  if (g.rows < 2 || g.cols < 2 || !(g.cell_size_m > 0.0) || finest.depth_m.values().size() != g.cell_count()) {
    throw InputError("lod: the finest depth grid has " + std::to_string(g.rows) + " x " + std::to_string(g.cols) +
                     " samples of " + format_number(g.cell_size_m) + " m: expected at least 2 x 2 and a cell size > 0");
  }
  if (finest.depth_m.valid_count() == 0) throw InputError("lod: the finest depth grid has no valid sample");
  if (!finest.colour_rgb8.empty() && finest.colour_rgb8.size() != 3 * g.cell_count()) {
    throw InputError("lod: level 0 colour holds " + std::to_string(finest.colour_rgb8.size()) + " bytes, expected " +
                     std::to_string(3 * g.cell_count()) + " (3 per sample of the depth's " + std::to_string(g.rows) +
                     " x " + std::to_string(g.cols) + ")");
  }
  if (finest.cell_error_m.rows() > 0 && !(finest.cell_error_m.geometry() == g)) {
    throw InputError("lod: level 0 layer 'cell_error' has " + std::to_string(finest.cell_error_m.rows()) + " x " +
                     std::to_string(finest.cell_error_m.cols()) + " samples, expected the depth's " +
                     std::to_string(g.rows) + " x " + std::to_string(g.cols));
  }
  if (finest.has_layers) {
    const std::pair<const char*, const HeightField*> layers[] = {
        {"envelope", &finest.envelope_m}, {"texture", &finest.texture_m}, {"mu_d", &finest.mu_d}, {"mu_s", &finest.mu_s}};
    for (const auto& [name, f] : layers) {
      if (!(f->geometry() == g)) {
        throw InputError(std::string("lod: level 0 layer '") + name + "' has " + std::to_string(f->rows()) + " x " +
                         std::to_string(f->cols()) + " samples, expected the depth's " + std::to_string(g.rows) +
                         " x " + std::to_string(g.cols));
      }
    }
  }
  finest.level = 0;
  level_count_ = lod_level_count(g, options_.min_cells);
  for (int l = 0; l < level_count_; ++l) geometries_.push_back(lod_level_geometry(g, l));
  finest_ = std::make_shared<LodLevel>(std::move(finest));
}

// The files of a tiled scene (open_stored). Readers are opened on first use; each serialises
// its own reads, so windows of different layers or levels read in parallel.
struct LodPyramid::Stored {
  enum Kind { kDepth, kEnvelope, kTexture, kMuD, kMuS, kCellError, kColour, kKinds };
  static constexpr std::array<const char*, kKinds> kNames = {"depth", "envelope", "texture", "mu_d",
                                                            "mu_s",  "cell_error", "colour"};
  std::filesystem::path dir;
  Eigen::Affine3d model_to_grid = Eigen::Affine3d::Identity();
  bool has_layers = false, has_cell_error = false, has_colour = false;
  std::vector<GridGeometry> geometries;
  std::mutex mutex;  // readers
  std::vector<std::array<std::unique_ptr<detail::TiledTiffReader>, kKinds>> readers;

  std::filesystem::path file(int level, int kind) const {
    const std::string name = kNames[static_cast<std::size_t>(kind)];
    // Level 0's surface layers computed by the pyramid for a scene that has none (layers off in
    // the run) are stored in levels/L0/ (build_stored_levels), so that every level has them.
    if (level == 0 && kind >= kEnvelope && kind <= kMuS && !std::filesystem::exists(dir / (name + ".tiff"))) {
      return dir / kSceneLevelsFolder / "L0" / (name + ".tiff");
    }
    return detail::stored_layer_file(dir, level, name);
  }
  /// Bytes per sample of a level with every layer the store holds (and the surface layers, which
  /// a level without them would compute).
  std::size_t bytes_per_sample() const {
    return sizeof(float) * (5 + (has_cell_error ? 1 : 0)) + (has_colour ? 3 : 0);
  }
  const detail::TiledTiffReader& reader(int level, int kind) {
    std::lock_guard<std::mutex> lock(mutex);
    auto& slot = readers[static_cast<std::size_t>(level)][static_cast<std::size_t>(kind)];
    if (!slot) {
      const std::filesystem::path f = file(level, kind);
      const GridGeometry& g = geometries[static_cast<std::size_t>(level)];
      auto r = std::make_unique<detail::TiledTiffReader>();
      std::string why = r->open(f, kind == kColour ? detail::TileSamples::kRgb8 : detail::TileSamples::kFloat32);
      if (why.empty() && (r->width() != g.cols || r->height() != g.rows)) {
        why = std::to_string(r->width()) + "x" + std::to_string(r->height()) + " samples, expected level " +
              std::to_string(level) + "'s " + std::to_string(g.cols) + "x" + std::to_string(g.rows);
      }
      if (!why.empty()) throw InputError(f.string() + ": stored level " + std::to_string(level) + " layer '" +
                                         kNames[static_cast<std::size_t>(kind)] + "': " + why);
      slot = std::move(r);
    }
    return *slot;
  }
  // A window through the tile cache (`cached`), or a whole level straight from the files, so that
  // reading the navigation view's level does not flush the tiles the windows use.
  void read_into(int level, int kind, int row0, int col0, int rows, int cols, void* out, bool cached) {
    if (cached) {
      region(level, kind, row0, col0, rows, cols, out);
      return;
    }
    const std::string why = reader(level, kind).read_region(row0, col0, rows, cols, out);
    if (!why.empty()) throw InputError(file(level, kind).string() + ": " + why);
  }
  HeightField field(int level, int kind, int row0, int col0, int rows, int cols, bool cached) {
    const GridGeometry& g = geometries[static_cast<std::size_t>(level)];
    HeightField out(GridGeometry{rows, cols, g.x_of_col(col0), g.y_of_row(row0), g.cell_size_m});
    out.model_to_grid = model_to_grid;
    read_into(level, kind, row0, col0, rows, cols, out.data(), cached);
    return out;
  }
  std::vector<std::uint8_t> colour(int level, int row0, int col0, int rows, int cols, bool cached) {
    std::vector<std::uint8_t> out(3 * static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols));
    read_into(level, kColour, row0, col0, rows, cols, out.data(), cached);
    return out;
  }

  // The tile cache (issue 14: "the LoD cache holds tiles under its memory budget"): decoded tiles
  // by (level, layer, tile row, tile col), least recently used evicted beyond tile_budget bytes,
  // so windows that share tiles (a pan, a zoom back) decode each tile once. A null tile is a
  // tile without bytes (no data).
  using TileData = std::shared_ptr<const std::vector<std::uint8_t>>;
  using TileKey = std::array<int, 4>;
  std::size_t tile_budget = 0;
  std::mutex tile_mutex;
  std::list<std::pair<TileKey, TileData>> tile_lru;  // most recently used first
  std::map<TileKey, std::list<std::pair<TileKey, TileData>>::iterator> tiles;
  std::size_t tile_bytes = 0;
  std::uint64_t tile_hits = 0;

  // Only tiles with data are cached (a tile without bytes is told by one byte-count lookup);
  // O(log n) per lookup and insert, O(1) per eviction.
  TileData tile(int level, int kind, int tr, int tc) {
    const TileKey key{level, kind, tr, tc};
    {
      std::lock_guard<std::mutex> lock(tile_mutex);
      if (auto it = tiles.find(key); it != tiles.end()) {
        tile_lru.splice(tile_lru.begin(), tile_lru, it->second);
        ++tile_hits;
        return it->second->second;
      }
    }
    const detail::TiledTiffReader& r = reader(level, kind);
    auto data = std::make_shared<std::vector<std::uint8_t>>(static_cast<std::size_t>(r.tile()) *
                                                            static_cast<std::size_t>(r.tile()) *
                                                            (kind == kColour ? 3u : sizeof(float)));
    bool sparse = false;
    const std::string why = r.read_tile(tr, tc, data->data(), &sparse);
    if (!why.empty()) throw InputError(file(level, kind).string() + ": " + why);
    if (sparse) return nullptr;
    TileData out(std::move(data));
    std::lock_guard<std::mutex> lock(tile_mutex);
    if (auto it = tiles.find(key); it != tiles.end()) return it->second->second;  // read by another thread meanwhile
    tile_lru.emplace_front(key, out);
    tiles.emplace(key, tile_lru.begin());
    tile_bytes += out->size();
    while (tile_bytes > tile_budget && tile_lru.size() > 1) {  // never the tile just read
      tile_bytes -= tile_lru.back().second->size();
      tiles.erase(tile_lru.back().first);
      tile_lru.pop_back();
    }
    return out;
  }

  // rows × cols samples of a level's layer from (row0, col0) into `out` (row-major; × 3 bytes for
  // colour), from the cached tiles: NaN (float) or 0 (colour) where a tile has no bytes.
  void region(int level, int kind, int row0, int col0, int rows, int cols, void* out) {
    const detail::TiledTiffReader& r = reader(level, kind);
    if (rows < 1 || cols < 1 || row0 < 0 || col0 < 0 || row0 + rows > r.height() || col0 + cols > r.width()) {
      throw std::logic_error("lod: stored region outside level " + std::to_string(level));
    }
    const int t = r.tile();
    const auto samples = kind == kColour ? detail::TileSamples::kRgb8 : detail::TileSamples::kFloat32;
    for (int tr = row0 / t; tr * t < row0 + rows; ++tr) {
      for (int tc = col0 / t; tc * t < col0 + cols; ++tc) {
        const TileData data = tile(level, kind, tr, tc);
        detail::copy_tile_part(data ? data->data() : nullptr, tr, tc, t, samples, row0, col0, rows, cols, out);
      }
    }
  }
  std::uint64_t tiles_read() {
    std::lock_guard<std::mutex> lock(mutex);
    std::uint64_t n = 0;
    for (const auto& level : readers)
      for (const auto& r : level) n += r ? r->tiles_read() : 0;
    return n;
  }
};

LodPyramid::LodPyramid(std::shared_ptr<Stored> stored, const SurfaceLayerOptions& layer_options, const LodOptions& options,
                       int level_count, const GridGeometry& finest)
    : options_(options), layer_options_(layer_options), level_count_(level_count), stored_(std::move(stored)) {
  validate_options(options_);
  for (int l = 0; l < level_count_; ++l) geometries_.push_back(lod_level_geometry(finest, l));
}

std::shared_ptr<LodPyramid> LodPyramid::open_stored(const std::filesystem::path& scene_dir, const LodOptions& options) {
  const Scene header = load_scene(scene_dir, false);
  if (!header.storage.stores_levels()) {
    throw InputError(scene_dir.string() + ": the scene stores no levels of detail in tiles (format_version " +
                     std::to_string(header.format_version) +
                     "); write it with scale.scene_tiles: on, or load it whole (load_scene)");
  }
  const GridGeometry& g = header.geometry;
  if (g.rows < 2 || g.cols < 2) {
    throw InputError(scene_dir.string() + ": the scene's grid has " + std::to_string(g.rows) + " x " +
                     std::to_string(g.cols) + " samples: expected at least 2 x 2");
  }
  auto stored = std::make_shared<Stored>();
  stored->dir = scene_dir;
  // A quarter of the budget for decoded tiles, the rest for windows and whole levels.
  stored->tile_budget = static_cast<std::size_t>(options.memory_budget_mb * 1024.0 * 1024.0 / 4.0);
  stored->model_to_grid = header.model_to_grid;
  const auto exists = [&](int kind) { return std::filesystem::exists(stored->file(0, kind)); };
  stored->has_layers = exists(Stored::kEnvelope) && exists(Stored::kTexture) && exists(Stored::kMuD) && exists(Stored::kMuS);
  stored->has_cell_error = exists(Stored::kCellError);
  stored->has_colour = exists(Stored::kColour);
  const int levels = std::min(header.storage.stored_levels, lod_level_count(g, 2));
  for (int l = 0; l < levels; ++l) stored->geometries.push_back(lod_level_geometry(g, l));
  stored->readers.resize(static_cast<std::size_t>(levels));
  std::shared_ptr<LodPyramid> p(new LodPyramid(stored, header.layer_options, options, levels, g));
  // Every layer level 0 has is required at every level, and every file is opened now (its
  // directory only): a missing, foreign or mis-sized file is refused at open, naming it.
  for (int l = 0; l < levels; ++l) {
    for (int kind = 0; kind < Stored::kKinds; ++kind) {
      const bool present = kind == Stored::kDepth || (kind <= Stored::kMuS && stored->has_layers) ||
                           (kind == Stored::kCellError && stored->has_cell_error) ||
                           (kind == Stored::kColour && stored->has_colour);
      if (present) (void)stored->reader(l, kind);
    }
  }
  return p;
}

std::uint64_t LodPyramid::tiles_read() const { return stored_ ? stored_->tiles_read() : 0; }

std::filesystem::path LodPyramid::stored_dir() const { return stored_ ? stored_->dir : std::filesystem::path(); }

std::size_t LodPyramid::stored_bytes_per_sample() const noexcept { return stored_ ? stored_->bytes_per_sample() : 0; }

std::size_t LodPyramid::entry_budget_bytes() const noexcept {
  return static_cast<std::size_t>(entry_budget_mb() * 1024.0 * 1024.0);
}

std::shared_ptr<LodWindowLayers> LodPyramid::read_stored_window(int level, int row0, int col0, int rows, int cols,
                                                                bool cached) const {
  Stored& st = *stored_;
  auto win = std::make_shared<LodWindowLayers>();
  win->level = level;
  win->row0 = row0;
  win->col0 = col0;
  win->depth_m = st.field(level, Stored::kDepth, row0, col0, rows, cols, cached);
  if (st.has_layers) {
    win->envelope_m = st.field(level, Stored::kEnvelope, row0, col0, rows, cols, cached);
    win->texture_m = st.field(level, Stored::kTexture, row0, col0, rows, cols, cached);
    win->mu_d = st.field(level, Stored::kMuD, row0, col0, rows, cols, cached);
    win->mu_s = st.field(level, Stored::kMuS, row0, col0, rows, cols, cached);
  }
  if (st.has_cell_error) win->cell_error_m = st.field(level, Stored::kCellError, row0, col0, rows, cols, cached);
  if (st.has_colour) win->colour_rgb8 = st.colour(level, row0, col0, rows, cols, cached);
  return win;
}

std::shared_ptr<LodPyramid> LodPyramid::from_scene(hc::Scene&& scene, const SurfaceLayerOptions& layer_options,
                                                   const LodOptions& options) {
  if (scene.layers.depth.rows() == 0) throw InputError("lod: the scene has no depth layer");
  LodLevel l0;
  l0.depth_m = std::move(scene.layers.depth);
  l0.colour_rgb8 = std::move(scene.layers.colour_rgb8);
  l0.cell_error_m = std::move(scene.layers.cell_error);
  if (scene.layers.has_surface_layers()) {
    l0.envelope_m = std::move(scene.layers.envelope);
    l0.texture_m = std::move(scene.layers.texture);
    l0.mu_d = std::move(scene.layers.mu_d);
    l0.mu_s = std::move(scene.layers.mu_s);
    l0.has_layers = true;
  }
  return std::make_shared<LodPyramid>(std::move(l0), layer_options, options);
}

const GridGeometry& LodPyramid::geometry(int level) const {
  if (level < 0 || level >= level_count_) {
    throw InputError("lod: level " + std::to_string(level) + " does not exist: expected 0.." +
                     std::to_string(level_count_ - 1));
  }
  return geometries_[static_cast<std::size_t>(level)];
}

void LodPyramid::touch_locked(Entry& e) { e.last_use = ++clock_; }

double LodPyramid::entry_budget_mb() const noexcept {
  // A stored pyramid gives a quarter of the budget to its decoded tiles (Stored::tile_budget).
  return stored_ ? 0.75 * options_.memory_budget_mb : options_.memory_budget_mb;
}

void LodPyramid::evict_locked() {
  const std::size_t budget = entry_budget_bytes();
  while (bytes_ > budget && entries_.size() > 1) {
    // Least recently used, but never the entry touched last (the one just built or returned).
    auto victim = entries_.end();
    for (auto it = entries_.begin(); it != entries_.end(); ++it) {
      if ((*it)->last_use == clock_) continue;
      if (victim == entries_.end() || (*it)->last_use < (*victim)->last_use) victim = it;
    }
    if (victim == entries_.end()) break;
    bytes_ -= (*victim)->bytes;
    entries_.erase(victim);
    ++evictions_;
  }
}

std::shared_ptr<const LodLevel> LodPyramid::cached_locked(int level, bool with_layers,
                                                          std::shared_ptr<const LodLevel>* depth_only) {
  if (level == 0 && finest_) {
    if (!with_layers || finest_->has_layers) return finest_;
    if (depth_only != nullptr) *depth_only = finest_;
    return nullptr;
  }
  for (const auto& e : entries_) {
    if (e->is_window || e->level != level) continue;
    if (e->lvl->has_layers || !with_layers) {
      ++hits_;
      touch_locked(*e);
      return e->lvl;
    }
    if (depth_only != nullptr) *depth_only = e->lvl;
  }
  return nullptr;
}

std::shared_ptr<const LodLevel> LodPyramid::get_level(int level, bool with_layers) {
  (void)geometry(level);  // range check
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (auto hit = cached_locked(level, with_layers, nullptr)) return hit;
  }
  // Builds are serialised by build_mutex_ (recursive: a level builds the depth above it first)
  // and run without mutex_, so lookups and windows of cached levels never wait for a build.
  std::lock_guard<std::recursive_mutex> build(build_mutex_);
  std::shared_ptr<const LodLevel> depth_only;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (auto hit = cached_locked(level, with_layers, &depth_only)) return hit;  // built meanwhile
    ++misses_;
  }
  auto built = std::make_shared<LodLevel>();
  built->level = level;
  if (depth_only) {
    built->depth_m = depth_only->depth_m;
    built->colour_rgb8 = depth_only->colour_rgb8;
    built->cell_error_m = depth_only->cell_error_m;
    built->depth_seconds = depth_only->depth_seconds;
  } else if (stored_) {
    const GridGeometry& g = geometries_[static_cast<std::size_t>(level)];
    const double mb = static_cast<double>(g.cell_count() * stored_->bytes_per_sample()) / (1024.0 * 1024.0);
    if (mb > entry_budget_mb()) {
      throw InputError("lod: level " + std::to_string(level) + " of the stored scene " + stored_->dir.string() + " is " +
                       std::to_string(g.rows) + " x " + std::to_string(g.cols) + " samples (" + format_number(mb) +
                       " MB with its layers), more than 3/4 of lod.memory_budget_mb = " +
                       format_number(options_.memory_budget_mb) +
                       " (the rest holds decoded tiles): only its windows are read; choose a coarser level or raise the budget");
    }
    const auto t0 = Clock::now();
    // Straight from the files: a whole level read through the tile cache would flush the tiles
    // the windows use.
    std::shared_ptr<LodWindowLayers> whole = read_stored_window(level, 0, 0, g.rows, g.cols, false);
    built->depth_m = std::move(whole->depth_m);
    built->colour_rgb8 = std::move(whole->colour_rgb8);
    built->cell_error_m = std::move(whole->cell_error_m);
    if (stored_->has_layers) {
      built->envelope_m = std::move(whole->envelope_m);
      built->texture_m = std::move(whole->texture_m);
      built->mu_d = std::move(whole->mu_d);
      built->mu_s = std::move(whole->mu_s);
      built->has_layers = true;
    }
    built->depth_seconds = seconds_since(t0);
  } else {
    const std::shared_ptr<const LodLevel> above = get_level(level - 1, false);
    const auto t0 = Clock::now();
    built->depth_m = downsample_2x(above->depth_m, options_.antialias_sigma_cells, options_.valid_fraction);
    if (!above->colour_rgb8.empty()) {
      built->colour_rgb8 = downsample_colour_2x(above->depth_m, above->colour_rgb8, options_.antialias_sigma_cells,
                                                options_.valid_fraction);
    }
    if (above->cell_error_m.rows() > 0) {
      built->cell_error_m = downsample_2x(above->cell_error_m, options_.antialias_sigma_cells, options_.valid_fraction);
    }
    built->depth_seconds = seconds_since(t0);
  }
  if (with_layers && !built->has_layers) {
    const auto t0 = Clock::now();
    if (built->depth_m.valid_count() > 0) {
      SurfaceLayers layers = compute_surface_layers(built->depth_m, layer_options_, options_.window_cells).value;
      built->envelope_m = std::move(layers.envelope_m);
      built->texture_m = std::move(layers.texture_m);
      built->mu_d = std::move(layers.mu_d);
      built->mu_s = std::move(layers.mu_s);
    } else {
      // No valid sample (every coarse sample below valid_fraction): all layers are no data.
      built->envelope_m = built->texture_m = built->mu_d = built->mu_s = HeightField(built->depth_m.geometry());
    }
    for (HeightField* f : {&built->envelope_m, &built->texture_m, &built->mu_d, &built->mu_s}) {
      f->model_to_grid = built->depth_m.model_to_grid;
    }
    built->has_layers = true;
    built->layers_seconds = seconds_since(t0);
  }
  // The level is published only once complete: a throw leaves no trace.
  std::lock_guard<std::mutex> lock(mutex_);
  if (level == 0 && !stored_) {
    finest_ = built;
    return built;
  }
  std::shared_ptr<Entry> entry;
  for (const auto& e : entries_) {
    if (!e->is_window && e->level == level) entry = e;
  }
  if (!entry) {
    entry = std::make_shared<Entry>();
    entry->level = level;
    entries_.push_back(entry);
  }
  bytes_ -= entry->bytes;
  entry->lvl = built;
  entry->bytes = built->bytes();
  bytes_ += entry->bytes;
  touch_locked(*entry);
  evict_locked();
  return built;
}

std::shared_ptr<const LodLevel> LodPyramid::level(int level) { return get_level(level, true); }

std::shared_ptr<const LodLevel> LodPyramid::depth_level(int level) { return get_level(level, false); }

bool LodPyramid::is_cached(int level, bool with_layers) const {
  std::lock_guard<std::mutex> lock(mutex_);
  if (level == 0 && finest_) return !with_layers || finest_->has_layers;
  for (const auto& e : entries_) {
    if (!e->is_window && e->level == level) return !with_layers || e->lvl->has_layers;
  }
  return false;
}

std::shared_ptr<const LodWindowLayers> LodPyramid::window(int level, int row0, int col0, int rows, int cols, bool keep) {
  const GridGeometry& g = geometry(level);
  if (rows < 2 || cols < 2) {
    throw InputError("lod: window of " + std::to_string(rows) + " x " + std::to_string(cols) +
                     " samples: expected at least 2 x 2");
  }
  rows = std::min(rows, g.rows);
  cols = std::min(cols, g.cols);
  row0 = std::clamp(row0, 0, g.rows - rows);
  col0 = std::clamp(col0, 0, g.cols - cols);
  const auto cached_window = [&]() -> std::shared_ptr<const LodWindowLayers> {
    for (const auto& e : entries_) {
      if (e->is_window && e->level == level && e->row0 == row0 && e->col0 == col0 && e->rows == rows &&
          e->cols == cols) {
        ++hits_;
        touch_locked(*e);
        return e->win;
      }
    }
    return nullptr;
  };
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (auto hit = cached_window()) return hit;
  }
  std::shared_ptr<LodWindowLayers> win;
  std::shared_ptr<const LodLevel> lvl;
  if (stored_) {
    const double mb = static_cast<double>(static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols) *
                                          stored_->bytes_per_sample()) / (1024.0 * 1024.0);
    if (mb > entry_budget_mb()) {
      throw InputError("lod: a window of " + std::to_string(rows) + " x " + std::to_string(cols) + " samples (" +
                       format_number(mb) + " MB with its layers) is larger than 3/4 of lod.memory_budget_mb = " +
                       format_number(options_.memory_budget_mb) + " (the rest holds decoded tiles)");
    }
    win = read_stored_window(level, row0, col0, rows, cols, true);  // its tiles, cached (without mutex_)
  } else {
    lvl = get_level(level, true);  // may build (without mutex_)
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (auto hit = cached_window()) return hit;  // cropped by another thread meanwhile
  ++misses_;
  if (!win) win = crop_window_locked(*lvl, level, row0, col0, rows, cols);
  if (!keep) return win;  // read once: not cached
  auto entry = std::make_shared<Entry>();
  entry->is_window = true;
  entry->level = level;
  entry->row0 = row0;
  entry->col0 = col0;
  entry->rows = rows;
  entry->cols = cols;
  entry->win = win;
  entry->bytes = win->bytes();
  bytes_ += entry->bytes;
  entries_.push_back(entry);
  touch_locked(*entry);
  evict_locked();
  return win;
}

std::shared_ptr<LodWindowLayers> LodPyramid::crop_window_locked(const LodLevel& lvl, int level, int row0, int col0,
                                                                int rows, int cols) {
  auto win = std::make_shared<LodWindowLayers>();
  win->level = level;
  win->row0 = row0;
  win->col0 = col0;
  win->depth_m = crop_height_field(lvl.depth_m, row0, col0, rows, cols);
  if (!lvl.colour_rgb8.empty()) win->colour_rgb8 = crop_colour(lvl.colour_rgb8, lvl.depth_m.geometry(), row0, col0, rows, cols);
  if (lvl.cell_error_m.rows() > 0) win->cell_error_m = crop_height_field(lvl.cell_error_m, row0, col0, rows, cols);
  if (lvl.has_layers) {
    win->envelope_m = crop_height_field(lvl.envelope_m, row0, col0, rows, cols);
    win->texture_m = crop_height_field(lvl.texture_m, row0, col0, rows, cols);
    win->mu_d = crop_height_field(lvl.mu_d, row0, col0, rows, cols);
    win->mu_s = crop_height_field(lvl.mu_s, row0, col0, rows, cols);
  }
  return win;
}

LodPyramid::CacheStats LodPyramid::cache_stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  CacheStats s;
  s.bytes = bytes_;
  s.budget_bytes = static_cast<std::size_t>(options_.memory_budget_mb * 1024.0 * 1024.0);
  s.finest_bytes = finest_ ? finest_->bytes() : 0;
  s.hits = hits_;
  s.misses = misses_;
  s.evictions = evictions_;
  for (const auto& e : entries_) (e->is_window ? s.windows_cached : s.levels_cached) += 1;
  if (stored_) {
    std::lock_guard<std::mutex> tiles_lock(stored_->tile_mutex);
    s.tile_bytes = stored_->tile_bytes;
    s.tiles_cached = static_cast<int>(stored_->tiles.size());
    s.tile_hits = stored_->tile_hits;
  }
  return s;
}

HeightField crop_height_field(const HeightField& src, int row0, int col0, int rows, int cols) {
  const GridGeometry& g = src.geometry();
  if (rows < 1 || cols < 1 || row0 < 0 || col0 < 0 || row0 + rows > g.rows || col0 + cols > g.cols) {
    throw std::invalid_argument("crop_height_field: window " + std::to_string(rows) + " x " + std::to_string(cols) + " at (" +
                                std::to_string(row0) + ", " + std::to_string(col0) + ") outside a " + std::to_string(g.rows) +
                                " x " + std::to_string(g.cols) + " field");
  }
  GridGeometry w{rows, cols, g.x_of_col(col0), g.y_of_row(row0), g.cell_size_m};
  HeightField out(w);
  out.model_to_grid = src.model_to_grid;
  for (int r = 0; r < rows; ++r) {
    const float* from = src.data() + static_cast<std::ptrdiff_t>(row0 + r) * g.cols + col0;
    std::copy(from, from + cols, out.data() + static_cast<std::ptrdiff_t>(r) * cols);
  }
  return out;
}

std::vector<std::uint8_t> crop_colour(std::span<const std::uint8_t> src, const GridGeometry& g, int row0, int col0,
                                      int rows, int cols) {
  std::vector<std::uint8_t> out(3 * static_cast<std::size_t>(rows) * static_cast<std::size_t>(cols));
  for (int r = 0; r < rows; ++r) {
    const std::uint8_t* from = src.data() + 3 * (static_cast<std::ptrdiff_t>(row0 + r) * g.cols + col0);
    std::copy(from, from + 3 * cols, out.data() + 3 * static_cast<std::ptrdiff_t>(r) * cols);
  }
  return out;
}


SampleWindow window_of_extent(const GridGeometry& g, double x0_m, double y0_m, double x1_m, double y1_m) {
  if (!(x0_m < x1_m) || !(y0_m < y1_m) || !std::isfinite(x0_m) || !std::isfinite(x1_m) || !std::isfinite(y0_m) ||
      !std::isfinite(y1_m)) {
    throw ConfigError("window x " + format_number(x0_m) + " .. " + format_number(x1_m) + ", y " + format_number(y0_m) +
                      " .. " + format_number(y1_m) + " m: expected finite X0 < X1 and Y0 < Y1");
  }
  // Nodes with x0 <= x <= x1 (a relative slack of 1e-9 cell for corners given exactly).
  const double eps = 1e-9;
  const int c0 = std::max(0, static_cast<int>(std::ceil(g.col_of_x(x0_m) - eps)));
  const int c1 = std::min(g.cols - 1, static_cast<int>(std::floor(g.col_of_x(x1_m) + eps)));
  const int r0 = std::max(0, static_cast<int>(std::ceil(g.row_of_y(y0_m) - eps)));
  const int r1 = std::min(g.rows - 1, static_cast<int>(std::floor(g.row_of_y(y1_m) + eps)));
  if (c1 - c0 < 1 || r1 - r0 < 1) {
    throw ConfigError("window x " + format_number(x0_m) + " .. " + format_number(x1_m) + ", y " + format_number(y0_m) +
                      " .. " + format_number(y1_m) + " m holds fewer than 2 x 2 nodes of the grid, which spans x " +
                      format_number(g.x_of_col(0)) + " .. " + format_number(g.x_of_col(g.cols - 1)) + ", y " +
                      format_number(g.y_of_row(0)) + " .. " + format_number(g.y_of_row(g.rows - 1)) + " m (grid frame)");
  }
  return {r0, c0, r1 - r0 + 1, c1 - c0 + 1};
}

}  // namespace hc::pipeline
