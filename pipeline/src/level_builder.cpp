#include "hc/pipeline/level_builder.hpp"

#include "image_io.hpp"
#include "posix_io.hpp"
#include "stage_util.hpp"
#include "tiled_layers.hpp"

#include "hc/common/error.hpp"
#include "hc/common/format.hpp"
#include "hc/pipeline/exact_sum.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/pipeline/surface_layers.hpp"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>

namespace hc::pipeline {

namespace {

namespace fs = std::filesystem;
using detail::Clock;
using detail::seconds_since;
using detail::TiledTiffReader;
using detail::TiledTiffWriter;
using detail::TileSamples;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

void check(const std::string& why, const fs::path& file, const char* what) {
  if (!why.empty()) throw InputError(file.string() + ": " + what + ": " + why);
}

/// A stored layer opened for reading.
struct LayerIn {
  fs::path file;
  TiledTiffReader reader;
  TileSamples samples = TileSamples::kFloat32;
  void open(const fs::path& f, TileSamples s, const GridGeometry& g) {
    file = f;
    samples = s;
    check(reader.open(f, s), f, "cannot read the tiled layer");
    if (reader.width() != g.cols || reader.height() != g.rows) {
      throw InputError(f.string() + ": the tiled layer holds " + std::to_string(reader.height()) + " x " +
                       std::to_string(reader.width()) + " samples: expected " + std::to_string(g.rows) + " x " +
                       std::to_string(g.cols) + " (the level's grid)");
    }
  }
  void read(const SampleWindow& w, void* out) const {
    check(reader.read_region(w.row0, w.col0, w.rows, w.cols, out), file, "cannot read the tiled layer");
  }
};

/// A layer of the level being built, written tile by tile.
struct LayerOut {
  fs::path file;
  TiledTiffWriter writer;
  void open(const fs::path& f, const GridGeometry& g, int tile, TileSamples s) {
    file = f;
    check(writer.open(f, g.cols, g.rows, tile, s), f, "cannot create the tiled layer");
  }
  void write(int tr, int tc, const void* data) { check(writer.write_tile(tr, tc, data), file, "cannot write a tile"); }
  std::uint64_t finish() {
    check(writer.finish(), file, "cannot finish the tiled layer");
    return writer.bytes_written();
  }
};

/// The scratch file of a level's s values: one tile² block of doubles per tile, tile order.
/// Registered for the signal clean-up while it lives and removed when it goes (LiveScratchFile).
class ScratchFile {
 public:
  ScratchFile(const fs::path& dir, int level)
      : live_(dir / ("hapticloud-levels-s-" + std::to_string(::getpid()) + "-L" + std::to_string(level) + ".bin")) {
    std::error_code ec;
    fs::create_directories(dir, ec);
    file_ = open_live_scratch_file(live_.path(), "w+b");
    if (file_ == nullptr) {
      throw InputError(live_.path().string() + ": cannot create the level builder's scratch file (scale.scratch): " +
                       std::strerror(errno));
    }
  }
  ~ScratchFile() { std::fclose(file_); }  // before live_ removes the file
  ScratchFile(const ScratchFile&) = delete;
  ScratchFile& operator=(const ScratchFile&) = delete;
  void write(std::uint64_t offset, const void* data, std::size_t bytes) {
    if (!detail::pwrite_full(::fileno(file_), data, bytes, offset)) {
      throw InputError(live_.path().string() + ": cannot write the scratch file: " + std::strerror(errno));
    }
  }
  void read(std::uint64_t offset, void* data, std::size_t bytes) const {
    if (!detail::pread_full(::fileno(file_), data, bytes, offset)) {
      throw InputError(live_.path().string() + ": cannot read the scratch file back: " + std::strerror(errno));
    }
  }

 private:
  LiveScratchFile live_;
  std::FILE* file_ = nullptr;
};

/// Tiles of a level: the inner block of tile (tr, tc).
struct TileGrid {
  int tile = 0, rows = 0, cols = 0, tile_rows = 0, tile_cols = 0;
  TileGrid(const GridGeometry& g, int t) : tile(t), rows(g.rows), cols(g.cols) {
    tile_rows = (g.rows + t - 1) / t;
    tile_cols = (g.cols + t - 1) / t;
  }
  SampleWindow block(int tr, int tc) const {
    const int r0 = tr * tile, c0 = tc * tile;
    return {r0, c0, std::min(tile, rows - r0), std::min(tile, cols - c0)};
  }
};

/// Copies a block (rows × cols, row-major) into a tile² buffer (rest `fill`).
template <class T>
void to_tile(const T* block, int rows, int cols, int tile, int channels, T fill, std::vector<T>& buf) {
  buf.assign(static_cast<std::size_t>(tile) * static_cast<std::size_t>(tile) * static_cast<std::size_t>(channels), fill);
  for (int r = 0; r < rows; ++r) {
    std::copy_n(block + static_cast<std::ptrdiff_t>(r) * cols * channels, static_cast<std::size_t>(cols) * static_cast<std::size_t>(channels),
                buf.data() + static_cast<std::ptrdiff_t>(r) * tile * channels);
  }
}

/// The exact element of rank `rank` (0-based) among the positive finite s values of the scratch
/// file (radix selection on the bit patterns, which order like the values for positive doubles).
/// `blocks`: the byte offsets of the blocks of `block_values` doubles that hold data.
double select_positive_s(const ScratchFile& file, const std::vector<std::uint64_t>& blocks, std::size_t block_values,
                         std::uint64_t rank, std::size_t* peak) {
  constexpr std::uint64_t kCollect = std::uint64_t{1} << 22;
  std::vector<double> buf(block_values);
  const auto scan = [&](auto&& visit) {
    for (const std::uint64_t at : blocks) {
      const std::size_t n = block_values;
      file.read(at, buf.data(), n * sizeof(double));
      for (std::size_t i = 0; i < n; ++i) {
        const double s = buf[i];
        if (!(s > 0.0) || !std::isfinite(s)) continue;
        std::uint64_t key;
        std::memcpy(&key, &s, sizeof key);
        visit(key);
      }
    }
  };
  std::uint64_t prefix = 0, in_bucket = std::numeric_limits<std::uint64_t>::max();
  int known = 0;  // leading bits fixed
  const auto matches = [&](std::uint64_t key) { return known == 0 || (key >> (64 - known)) == prefix; };
  while (true) {
    if (in_bucket <= kCollect || known == 64) {
      std::vector<std::uint64_t> keys;
      scan([&](std::uint64_t key) {
        if (matches(key)) keys.push_back(key);
      });
      *peak = std::max(*peak, buf.size() * sizeof(double) + keys.size() * sizeof(std::uint64_t));
      const auto mid = keys.begin() + static_cast<std::ptrdiff_t>(rank);
      std::nth_element(keys.begin(), mid, keys.end());
      double s;
      std::memcpy(&s, &*mid, sizeof s);
      return s;
    }
    std::vector<std::uint64_t> hist(std::size_t{1} << 16, 0);
    const int shift = 64 - known - 16;
    scan([&](std::uint64_t key) {
      if (matches(key)) ++hist[static_cast<std::size_t>((key >> shift) & 0xFFFFu)];
    });
    std::uint64_t below = 0;
    std::size_t b = 0;
    while (below + hist[b] <= rank) below += hist[b++];
    rank -= below;
    in_bucket = hist[b];
    prefix = (prefix << 16) | b;
    known += 16;
  }
}

/// A level's level-wide values, summed exactly (ExactFloatSum) so that its tiles give them in any
/// order: the mean heights downsample_2x takes as references (depth; each colour channel over
/// the samples with depth, as downsample_colour_2x sums them; the cell error) and the band of
/// valid depths compute_surface_layers takes.
struct LevelStats {
  ExactFloatSum depth_sum, error_sum;
  std::size_t depth_n = 0, error_n = 0, rgb_n = 0;
  std::array<double, 3> rgb_sum{0.0, 0.0, 0.0};  // integers below 2^53: exact in any order
  float vmin = std::numeric_limits<float>::max(), vmax = std::numeric_limits<float>::lowest();

  /// Adds a block of n samples: depth (with colour when given) and error, each when not nullptr.
  void add(const float* depth, const std::uint8_t* rgb, const float* error, std::size_t n) {
    for (std::size_t i = 0; depth != nullptr && i < n; ++i) {
      const float v = depth[i];
      if (std::isnan(v)) continue;
      depth_sum.add(v);
      ++depth_n;
      vmin = std::min(vmin, v);
      vmax = std::max(vmax, v);
      if (rgb != nullptr) {
        for (std::size_t c = 0; c < 3; ++c) rgb_sum[c] += static_cast<float>(rgb[3 * i + c]);
        ++rgb_n;
      }
    }
    if (error != nullptr) add_finite_values(error, n, error_sum, error_n);
  }
  /// Adds another part's values (exact: as if its samples had been added here).
  void merge(const LevelStats& o) {
    depth_sum.merge(o.depth_sum);
    error_sum.merge(o.error_sum);
    depth_n += o.depth_n;
    error_n += o.error_n;
    rgb_n += o.rgb_n;
    for (std::size_t c = 0; c < 3; ++c) rgb_sum[c] += o.rgb_sum[c];
    vmin = std::min(vmin, o.vmin);
    vmax = std::max(vmax, o.vmax);
  }
  double depth_ref() const { return depth_n > 0 ? depth_sum.value() / static_cast<double>(depth_n) : 0.0; }
  double error_ref() const { return error_n > 0 ? error_sum.value() / static_cast<double>(error_n) : 0.0; }
  double rgb_ref(std::size_t c) const { return rgb_n > 0 ? rgb_sum[c] / static_cast<double>(rgb_n) : 0.0; }
};

/// Runs work(0, i) and work(1, i + 1) for i = 0, 2, 4, … < count on two threads (each worker
/// keeps its own readers and buffers), then emit(i) and emit(i + 1) in order on this thread, so
/// that tiles are written in order and at most two are held.
template <class Work, class Emit>
void pairs_on_two(int count, Work&& work, Emit&& emit) {
  for (int i = 0; i < count; i += 2) {
    if (i + 1 < count) {
      detail::run_two([&] { work(1, i + 1); }, [&] { work(0, i); });
      emit(i);
      emit(i + 1);
    } else {
      work(0, i);
      emit(i);
    }
  }
}

class Builder {
 public:
  Builder(const fs::path& scene_dir, const fs::path& scratch, const LevelProgress& progress, Level0Layers level0)
      : dir_(scene_dir), scratch_(scratch), progress_(progress), level0_(level0) {
    scene_ = load_scene(scene_dir, false);
    if (!scene_.storage.stores_levels()) {
      throw InputError(scene_dir.string() + ": not a tiled scene that stores its levels (format 3 with storage "
                       "tile_cells and stored_levels; write it with scale.scene_tiles on)");
    }
    tile_ = scene_.storage.tile_cells;
    levels_ = scene_.storage.stored_levels;
    has_layers_ = fs::exists(dir_ / "envelope.tiff") && fs::exists(dir_ / "texture.tiff") &&
                  fs::exists(dir_ / "mu_d.tiff") && fs::exists(dir_ / "mu_s.tiff");
    has_colour_ = fs::exists(dir_ / "colour.tiff");
    has_error_ = fs::exists(dir_ / "cell_error.tiff");
    for (int l = 0; l < levels_; ++l) geometry_.push_back(lod_level_geometry(scene_.geometry, l));
  }

  StoredLevelsReport run() {
    const auto t0 = Clock::now();
    const fs::path root = dir_ / kSceneLevelsFolder;
    if (fs::exists(root)) {
      throw InputError(root.string() + ": the levels folder already exists: expected a scene whose levels are not built yet");
    }
    std::error_code ec;
    fs::create_directory(root, ec);
    if (ec) throw InputError(root.string() + ": cannot create the levels folder: " + ec.message());
    // Removed on an error: the levels folder, and level 0's layer files written into the scene
    // folder (Level0Layers::kSceneFolder).
    struct Remove {
      std::vector<fs::path> made;
      bool keep = false;
      ~Remove() {
        std::error_code e;
        if (!keep)
          for (const fs::path& p : made) fs::remove_all(p, e);
      }
    } guard{{root}};
    // Level 0's level-wide values, in one pass over its tiles; each coarser level's come from the
    // pass that writes it.
    LevelStats stats = level0_stats();
    if (!has_layers_) {
      if (level0_ == Level0Layers::kLevelsFolder) {
        make_dir(0);
      } else {
        for (const char* name : {"envelope", "texture", "mu_d", "mu_s"}) {
          const fs::path f = file(0, name);
          if (fs::exists(f)) throw InputError(f.string() + ": exists, but level 0's other surface layers do not: expected all four or none");
          guard.made.push_back(f);
        }
      }
      report_.level0_layers = true;
      report_.depth_seconds.push_back(0.0);
      const auto tl = Clock::now();
      build_layers(0, stats);
      report_.layers_seconds.push_back(seconds_since(tl));
    }
    for (int k = 1; k < levels_; ++k) {
      make_dir(k);
      const auto td = Clock::now();
      stats = build_depth(k, stats);
      report_.depth_seconds.push_back(seconds_since(td));
      const auto tl = Clock::now();
      build_layers(k, stats);
      report_.layers_seconds.push_back(seconds_since(tl));
      ++report_.levels_built;
    }
    if (report_.level0_layers && level0_ == Level0Layers::kSceneFolder) add_level0_surface_layers(dir_);
    guard.keep = true;
    report_.seconds = seconds_since(t0);
    return report_;
  }

 private:
  void make_dir(int level) {
    const fs::path d = level == 0 ? dir_ / kSceneLevelsFolder / "L0" : detail::stored_layer_file(dir_, level, "depth").parent_path();
    std::error_code ec;
    fs::create_directory(d, ec);
    if (ec) throw InputError(d.string() + ": cannot create the folder of level " + std::to_string(level) + ": " + ec.message());
  }
  /// A layer file of a level; level 0's computed layers go to levels/L0/ (where LodPyramid::open_stored reads them)
  /// or, with Level0Layers::kSceneFolder, beside depth.tiff.
  fs::path file(int level, const std::string& name) const {
    if (level == 0 && !has_layers_ && level0_ == Level0Layers::kLevelsFolder &&
        (name == "envelope" || name == "texture" || name == "mu_d" || name == "mu_s")) {
      return dir_ / kSceneLevelsFolder / "L0" / (name + ".tiff");
    }
    return detail::stored_layer_file(dir_, level, name);
  }
  void note_buffer(std::size_t bytes) { report_.peak_buffer_bytes = std::max(report_.peak_buffer_bytes, bytes); }
  void tell(const std::string& what, double fraction) const {
    if (progress_) progress_(what, fraction);
  }

  /// Level 0's level-wide values, tile by tile (pairs on two threads, merged exactly).
  /// @throws hc::InputError for an infinite depth, naming the file and the sample.
  LevelStats level0_stats() {
    const GridGeometry& g = geometry_[0];
    struct Worker {
      LayerIn depth_in, colour_in, error_in;
      std::vector<float> d, e;
      std::vector<std::uint8_t> rgb;
      LevelStats part;
    };
    std::array<Worker, 2> workers;
    for (Worker& w : workers) {
      w.depth_in.open(file(0, "depth"), TileSamples::kFloat32, g);
      if (has_colour_) w.colour_in.open(file(0, "colour"), TileSamples::kRgb8, g);
      if (has_error_) w.error_in.open(file(0, "cell_error"), TileSamples::kFloat32, g);
    }
    LevelStats stats;
    const TileGrid tiles(g, tile_);
    for (int tr = 0; tr < tiles.tile_rows; ++tr) {
      pairs_on_two(
          tiles.tile_cols,
          [&](int wi, int tc) {
            Worker& w = workers[static_cast<std::size_t>(wi)];
            const SampleWindow b = tiles.block(tr, tc);
            const std::size_t n = static_cast<std::size_t>(b.rows) * static_cast<std::size_t>(b.cols);
            w.d.resize(n);
            w.depth_in.read(b, w.d.data());
            for (std::size_t i = 0; i < n; ++i) {
              if (std::isinf(w.d[i])) {
                throw InputError(w.depth_in.file.string() + ": sample (" +
                                 std::to_string(b.row0 + static_cast<int>(i / static_cast<std::size_t>(b.cols))) + ", " +
                                 std::to_string(b.col0 + static_cast<int>(i % static_cast<std::size_t>(b.cols))) +
                                 ") is infinite: expected a finite height in metres or NaN (no data)");
              }
            }
            if (has_colour_) {
              w.rgb.resize(3 * n);
              w.colour_in.read(b, w.rgb.data());
            }
            if (has_error_) {
              w.e.resize(n);
              w.error_in.read(b, w.e.data());
            }
            w.part = LevelStats{};
            w.part.add(w.d.data(), has_colour_ ? w.rgb.data() : nullptr, has_error_ ? w.e.data() : nullptr, n);
          },
          [&](int tc) { stats.merge(workers[static_cast<std::size_t>(tc % 2)].part); });
      tell("level 0 mean heights", static_cast<double>(tr + 1) / tiles.tile_rows);
    }
    note_buffer(2 * static_cast<std::size_t>(tile_) * static_cast<std::size_t>(tile_) * (2 * sizeof(float) + 3));
    return stats;
  }

  /// Level k's depth, colour and cell error from level k − 1's stored tiles, whose level-wide
  /// values are `fine`. @return level k's level-wide values (of the samples written).
  LevelStats build_depth(int k, const LevelStats& fine) {
    const GridGeometry& fg = geometry_[static_cast<std::size_t>(k - 1)];
    const GridGeometry& cg = geometry_[static_cast<std::size_t>(k)];
    const LodOptions& lod = scene_.lod;
    const double depth_ref = fine.depth_ref(), error_ref = fine.error_ref();
    const std::array<double, 3> rgb_ref{fine.rgb_ref(0), fine.rgb_ref(1), fine.rgb_ref(2)};
    const bool colour = has_colour_ && fine.rgb_n > 0, error = has_error_ && fine.error_n > 0;

    // Each worker: its own readers of level k − 1 and its buffers; the block it made last.
    struct Worker {
      LayerIn depth_in, colour_in, error_in;
      std::vector<float> fine, fine_e, chan, block, block_c, block_e;
      std::vector<std::uint8_t> fine_rgb, block_rgb;
      bool no_depth = true;
      SampleWindow b{};
    };
    std::array<Worker, 2> workers;
    for (Worker& w : workers) {
      w.depth_in.open(file(k - 1, "depth"), TileSamples::kFloat32, fg);
      if (has_colour_) w.colour_in.open(file(k - 1, "colour"), TileSamples::kRgb8, fg);
      if (has_error_) w.error_in.open(file(k - 1, "cell_error"), TileSamples::kFloat32, fg);
    }
    LayerOut depth_out, colour_out, error_out;
    depth_out.open(file(k, "depth"), cg, tile_, TileSamples::kFloat32);
    if (has_colour_) colour_out.open(file(k, "colour"), cg, tile_, TileSamples::kRgb8);
    if (has_error_) error_out.open(file(k, "cell_error"), cg, tile_, TileSamples::kFloat32);
    const double sigma = lod.antialias_sigma_cells, vf = lod.valid_fraction;
    const int rad = downsample_2x_radius_cells(sigma);
    const TileGrid tiles(cg, tile_);
    LevelStats coarse;
    if (fine.depth_n > 0) {
      std::vector<float> tile_f;
      std::vector<std::uint8_t> tile_rgb;
      for (int tr = 0; tr < tiles.tile_rows; ++tr) {
        const auto work = [&](int wi, int tc) {
          Worker& w = workers[static_cast<std::size_t>(wi)];
          const SampleWindow b = tiles.block(tr, tc);
          w.b = b;
          const int r0 = std::max(0, 2 * b.row0 - rad), r1 = std::min(fg.rows - 1, 2 * (b.row0 + b.rows - 1) + rad);
          const int c0 = std::max(0, 2 * b.col0 - rad), c1 = std::min(fg.cols - 1, 2 * (b.col0 + b.cols - 1) + rad);
          const SampleWindow win{r0, c0, r1 - r0 + 1, c1 - c0 + 1};
          const std::size_t n = static_cast<std::size_t>(win.rows) * static_cast<std::size_t>(win.cols);
          const std::size_t bn = static_cast<std::size_t>(b.rows) * static_cast<std::size_t>(b.cols);
          w.fine.resize(n);
          w.depth_in.read(win, w.fine.data());
          // A window without depth leaves the depth and colour tiles sparse (no data, colour 0).
          w.no_depth = std::all_of(w.fine.begin(), w.fine.end(), [](float v) { return std::isnan(v); });
          if (error) {  // the error layer is decimated on its own, as downsample_2x does it
            w.fine_e.resize(n);
            w.error_in.read(win, w.fine_e.data());
            w.block_e.resize(bn);
            downsample_2x_block(w.fine_e.data(), win, fg.rows, fg.cols, error_ref, sigma, vf, b, w.block_e.data());
          }
          if (w.no_depth) return;
          w.block.resize(bn);
          downsample_2x_block(w.fine.data(), win, fg.rows, fg.cols, depth_ref, sigma, vf, b, w.block.data());
          if (has_colour_) {
            w.block_rgb.assign(3 * bn, 0);
            if (colour) {
              w.fine_rgb.resize(3 * n);
              w.colour_in.read(win, w.fine_rgb.data());
              w.chan.resize(n);
              w.block_c.resize(bn);
              for (std::size_t c = 0; c < 3; ++c) {
                for (std::size_t i = 0; i < n; ++i) w.chan[i] = std::isnan(w.fine[i]) ? kNaN : static_cast<float>(w.fine_rgb[3 * i + c]);
                downsample_2x_block(w.chan.data(), win, fg.rows, fg.cols, rgb_ref[c], sigma, vf, b, w.block_c.data());
                for (std::size_t i = 0; i < bn; ++i) {
                  const float v = w.block_c[i];
                  if (!std::isnan(v)) w.block_rgb[3 * i + c] = static_cast<std::uint8_t>(std::clamp(std::lround(v), 0L, 255L));
                }
              }
            }
          }
        };
        const auto emit = [&](int tc) {
          const Worker& w = workers[static_cast<std::size_t>(tc % 2)];
          const SampleWindow& b = w.b;
          const std::size_t bn = static_cast<std::size_t>(b.rows) * static_cast<std::size_t>(b.cols);
          if (error) {
            to_tile(w.block_e.data(), b.rows, b.cols, tile_, 1, kNaN, tile_f);
            error_out.write(tr, tc, tile_f.data());
            coarse.add(nullptr, nullptr, w.block_e.data(), bn);
          }
          if (w.no_depth) return;  // the depth and colour tiles stay sparse
          to_tile(w.block.data(), b.rows, b.cols, tile_, 1, kNaN, tile_f);
          depth_out.write(tr, tc, tile_f.data());
          if (has_colour_) {
            to_tile(w.block_rgb.data(), b.rows, b.cols, tile_, 3, std::uint8_t{0}, tile_rgb);
            colour_out.write(tr, tc, tile_rgb.data());
          }
          coarse.add(w.block.data(), has_colour_ ? w.block_rgb.data() : nullptr, nullptr, bn);
        };
        pairs_on_two(tiles.tile_cols, work, emit);
        const SampleWindow b = tiles.block(tr, 0);
        const std::size_t n = static_cast<std::size_t>(2 * b.rows + 2 * rad + 1) * static_cast<std::size_t>(2 * tile_ + 2 * rad + 1);
        note_buffer(2 * (n * (3 * sizeof(float) + 3) + static_cast<std::size_t>(tile_) * static_cast<std::size_t>(tile_) * (3 * sizeof(float) + 3)));
        tell("level " + std::to_string(k) + " depth", static_cast<double>(tr + 1) / tiles.tile_rows);
      }
    }
    report_.bytes += depth_out.finish();
    if (has_colour_) report_.bytes += colour_out.finish();
    if (has_error_) report_.bytes += error_out.finish();
    return coarse;
  }

  /// The window a layer block reads: the block plus the halo, clipped to the level, its first
  /// column a multiple of 64 and its padded width a multiple of 64 unless it ends at the level's
  /// right edge (surface_layers_block's conditions).
  SampleWindow layer_window(const SampleWindow& b, const GridGeometry& g, int halo, int rad) const {
    const int r0 = std::max(0, b.row0 - halo), r1 = std::min(g.rows, b.row0 + b.rows + halo);
    int c0 = std::max(0, b.col0 - halo);
    c0 -= c0 % 64;
    int c1 = b.col0 + b.cols + halo;
    if (c1 >= g.cols) {
      c1 = g.cols;
    } else {
      const int padded = ((c1 - c0 + 2 * rad + 63) / 64) * 64;
      c1 = std::min(g.cols, c0 + padded - 2 * rad);
    }
    return {r0, c0, r1 - r0, c1 - c0};
  }

  /// The surface layers of level k from its stored depth, whose level-wide values are `stats`
  /// (compute_surface_layers, tile by tile).
  void build_layers(int k, const LevelStats& stats) {
    const GridGeometry& g = geometry_[static_cast<std::size_t>(k)];
    const SurfaceLayerOptions& opt = scene_.layer_options;
    const int window_cells = scene_.lod.window_cells;
    const std::string name = "level " + std::to_string(k);
    LayerOut env_out, tex_out, mud_out, mus_out;
    env_out.open(file(k, "envelope"), g, tile_, TileSamples::kFloat32);
    tex_out.open(file(k, "texture"), g, tile_, TileSamples::kFloat32);
    mud_out.open(file(k, "mu_d"), g, tile_, TileSamples::kFloat32);
    mus_out.open(file(k, "mu_s"), g, tile_, TileSamples::kFloat32);
    const auto finish = [&] {
      for (LayerOut* o : {&env_out, &tex_out, &mud_out, &mus_out}) report_.bytes += o->finish();
    };
    if (stats.depth_n == 0) {  // as the pyramid: every layer no data
      finish();
      return;
    }
    SurfaceLayerLevelValues values;
    values.ref_m = stats.depth_ref();
    values.band_m[0] = static_cast<float>(static_cast<double>(stats.vmin) - values.ref_m);
    values.band_m[1] = static_cast<float>(static_cast<double>(stats.vmax) - values.ref_m);
    const int halo = surface_layers_halo_cells(opt);
    const int rad = surface_layers_radius_cells(opt);
    const TileGrid tiles(g, tile_);

    // Each worker: its own reader of level k's depth, its window and the block it made last.
    struct Worker {
      LayerIn depth_in;
      std::vector<float> win;
      bool empty = true;  // the window holds no valid sample
      SampleWindow b{};
      SurfaceLayerBlock out;
    };
    std::array<Worker, 2> workers;
    for (Worker& w : workers) w.depth_in.open(file(k, "depth"), TileSamples::kFloat32, g);
    const auto read_window = [&](Worker& w, int tr, int tc) {
      w.b = tiles.block(tr, tc);
      const SampleWindow win = layer_window(w.b, g, halo, rad);
      w.win.resize(static_cast<std::size_t>(win.rows) * static_cast<std::size_t>(win.cols));
      w.depth_in.read(win, w.win.data());
      w.empty = std::all_of(w.win.begin(), w.win.end(), [](float v) { return std::isnan(v); });
      return win;
    };
    // Two windows and about 14 working images of their padded size (fill, filter, curvature).
    note_buffer(2 * static_cast<std::size_t>(std::min(g.rows, tile_ + 2 * halo) + 2 * rad + 1) *
                static_cast<std::size_t>(std::min(g.cols, tile_ + 2 * halo + 64) + 2 * rad) * 14 * 4);
    // One pass of surface_layers_block over the level's tiles, pairs on two threads, then
    // emit(tile row, tile column, worker) in order for the tiles whose window holds data (an empty
    // window's cells are beyond the fill's reach and have no layers: its tiles stay sparse).
    const auto block_pass = [&](bool fill_only, const std::string& what, auto&& emit) {
      for (int tr = 0; tr < tiles.tile_rows; ++tr) {
        pairs_on_two(
            tiles.tile_cols,
            [&](int wi, int tc) {
              Worker& w = workers[static_cast<std::size_t>(wi)];
              const SampleWindow win = read_window(w, tr, tc);
              if (!w.empty) w.out = surface_layers_block(w.win.data(), win, g, w.b, values, fill_only, opt, window_cells);
            },
            [&](int tc) {
              const Worker& w = workers[static_cast<std::size_t>(tc % 2)];
              if (!w.empty) emit(tr, tc, w);
            });
        tell(name + " layers (" + what + ")", static_cast<double>(tr + 1) / tiles.tile_rows);
      }
    };

    // Pass 1: the range of the bilateral filter's whole filled input.
    float fmin = values.band_m[0], fmax = values.band_m[1];
    block_pass(true, "fill range", [&](int, int, const Worker& w) {
      fmin = std::min(fmin, w.out.fill_min_m);
      fmax = std::max(fmax, w.out.fill_max_m);
    });
    values.fill_range_m[0] = fmin;
    values.fill_range_m[1] = fmax;

    // Pass 2: envelope and texture written; s to the scratch file.
    ScratchFile scratch(scratch_, k);
    const std::size_t tile_n = static_cast<std::size_t>(tile_) * static_cast<std::size_t>(tile_);
    std::uint64_t positive = 0;
    std::vector<std::uint64_t> with_data;  // tiles written to the scratch file, in tile order
    std::vector<float> tile_f;
    std::vector<double> tile_s;
    block_pass(false, "envelope", [&](int tr, int tc, const Worker& w) {
      const SampleWindow& b = w.b;
      const std::uint64_t index = static_cast<std::uint64_t>(tr) * static_cast<std::uint64_t>(tiles.tile_cols) +
                                  static_cast<std::uint64_t>(tc);
      to_tile(w.out.envelope_m.data(), b.rows, b.cols, tile_, 1, kNaN, tile_f);
      env_out.write(tr, tc, tile_f.data());
      to_tile(w.out.texture_m.data(), b.rows, b.cols, tile_, 1, kNaN, tile_f);
      tex_out.write(tr, tc, tile_f.data());
      to_tile(w.out.s.data(), b.rows, b.cols, tile_, 1, -1.0, tile_s);
      for (double s : w.out.s) positive += s > 0.0 && std::isfinite(s) ? 1U : 0U;
      scratch.write(index * tile_n * sizeof(double), tile_s.data(), tile_n * sizeof(double));
      with_data.push_back(index);
    });
    report_.scratch_bytes = std::max<std::uint64_t>(report_.scratch_bytes, with_data.size() * tile_n * sizeof(double));

    // The reference of `level_median`: the exact median of s over the cells with s > 0.
    double s_ref = 0.0;
    if (opt.friction_scale == FrictionScale::kLevelMedian) {
      double s_median = 0.0;
      if (positive > 0) {
        std::size_t peak = 0;
        std::vector<std::uint64_t> offsets(with_data.size());
        for (std::size_t i = 0; i < with_data.size(); ++i) offsets[i] = with_data[i] * tile_n * sizeof(double);
        s_median = select_positive_s(scratch, offsets, tile_n, positive / 2, &peak);
        note_buffer(peak);
      }
      s_ref = std::max(s_median, friction_s_floor(opt));
    }

    // Pass 3: μ_d and μ_s.
    std::vector<float> mu_d(tile_n), mu_s(tile_n);
    std::size_t next = 0;
    for (int tr = 0; tr < tiles.tile_rows; ++tr) {
      for (int tc = 0; tc < tiles.tile_cols; ++tc) {
        const SampleWindow b = tiles.block(tr, tc);
        const std::uint64_t index = static_cast<std::uint64_t>(tr) * static_cast<std::uint64_t>(tiles.tile_cols) +
                                    static_cast<std::uint64_t>(tc);
        if (next == with_data.size() || with_data[next] != index) continue;  // no data: sparse
        ++next;
        tile_s.resize(tile_n);
        scratch.read(index * tile_n * sizeof(double), tile_s.data(), tile_n * sizeof(double));
        std::fill(mu_d.begin(), mu_d.end(), kNaN);
        std::fill(mu_s.begin(), mu_s.end(), kNaN);
        for (int r = 0; r < b.rows; ++r) {
          const double y = g.y_of_row(b.row0 + r);
          for (int c = 0; c < b.cols; ++c) {
            const std::size_t i = static_cast<std::size_t>(r) * static_cast<std::size_t>(tile_) + static_cast<std::size_t>(c);
            if (tile_s[i] == -1.0) continue;  // no data
            mu_d[i] = static_cast<float>(friction_mu_d(tile_s[i], s_ref, opt));
            mu_s[i] = static_cast<float>(friction_mu_s(g.x_of_col(b.col0 + c), y, opt));
          }
        }
        mud_out.write(tr, tc, mu_d.data());
        mus_out.write(tr, tc, mu_s.data());
      }
      tell(name + " layers (friction)", static_cast<double>(tr + 1) / tiles.tile_rows);
    }
    finish();
  }

  fs::path dir_, scratch_;
  LevelProgress progress_;
  Level0Layers level0_;
  Scene scene_;
  int tile_ = 0, levels_ = 0;
  bool has_layers_ = false, has_colour_ = false, has_error_ = false;
  std::vector<GridGeometry> geometry_;
  StoredLevelsReport report_;
};

}  // namespace

StoredLevelsReport build_stored_levels(const fs::path& scene_dir, const fs::path& scratch_dir,
                                       const LevelProgress& progress, Level0Layers level0) {
  Builder b(scene_dir, scratch_dir, progress, level0);
  return b.run();
}

}  // namespace hc::pipeline
