// The tiled scene on disk (issue 14): layer TIFFs in square tiles with sparse no-data tiles
// (scene format 3), every level of detail stored beside level 0, and LodPyramid::open_stored,
// which reads only the tiles a window overlaps.
// Oracles: libtiff read directly (not through the project's readers) for the files; the
// in-memory pyramid of the same level 0 (lod_test.cpp checks its levels against brute force)
// for the stored levels and windows; tile counts from the window's geometry.

#include "height_field_bits.hpp"
#include "file_bytes.hpp"
#include "test_paths.hpp"
#include "tiled_scene_fixture.hpp"

#include "hc/common/bilinear_surface.hpp"
#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/level_builder.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/lod_report.hpp"
#include "hc/pipeline/preview.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <tiffio.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <set>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

namespace {

namespace fs = std::filesystem;
using hc::GridGeometry;
using hc::HeightField;
using hc::Scene;
using hc::SceneStorage;
using hc::pipeline::LodLevel;
using hc::pipeline::LodOptions;
using hc::pipeline::LodPyramid;
using hc::pipeline::SurfaceLayerOptions;
using hc::test::differing_bits;
using hc::test::wavy_scene;
using hc::test::write_tiled;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

std::shared_ptr<LodPyramid> memory_pyramid(const Scene& s) {
  LodLevel l0;
  l0.depth_m = s.layers.depth;
  l0.envelope_m = s.layers.envelope;
  l0.texture_m = s.layers.texture;
  l0.mu_d = s.layers.mu_d;
  l0.mu_s = s.layers.mu_s;
  l0.has_layers = true;
  l0.cell_error_m = s.layers.cell_error;
  l0.colour_rgb8 = s.layers.colour_rgb8;
  return std::make_shared<LodPyramid>(std::move(l0), s.layer_options, s.lod);
}

/// A tiled float TIFF read with libtiff directly: values (NaN for a tile without bytes) and
/// the indices of the tiles without bytes.
struct RawTiled {
  int width = 0, height = 0, tile = 0;
  std::vector<float> v;
  std::vector<int> sparse;
};
RawTiled read_raw_tiled(const fs::path& file) {
  RawTiled out;
  TIFF* t = TIFFOpen(file.c_str(), "r");
  EXPECT_NE(t, nullptr) << file;
  if (t == nullptr) return out;
  EXPECT_TRUE(TIFFIsTiled(t)) << file;
  std::uint32_t w = 0, h = 0, tw = 0, th = 0;
  TIFFGetField(t, TIFFTAG_IMAGEWIDTH, &w);
  TIFFGetField(t, TIFFTAG_IMAGELENGTH, &h);
  TIFFGetField(t, TIFFTAG_TILEWIDTH, &tw);
  TIFFGetField(t, TIFFTAG_TILELENGTH, &th);
  out.width = static_cast<int>(w);
  out.height = static_cast<int>(h);
  out.tile = static_cast<int>(tw);
  EXPECT_EQ(tw, th);
  out.v.assign(static_cast<std::size_t>(w) * h, 0.0f);
  std::vector<float> buf(static_cast<std::size_t>(tw) * th);
  for (std::uint32_t y = 0; y < h; y += th) {
    for (std::uint32_t x = 0; x < w; x += tw) {
      const auto idx = TIFFComputeTile(t, x, y, 0, 0);
      const bool none = TIFFGetStrileByteCount(t, idx) == 0;
      if (none) {
        out.sparse.push_back(static_cast<int>(idx));
        std::fill(buf.begin(), buf.end(), kNaN);
      } else {
        EXPECT_GE(TIFFReadTile(t, buf.data(), x, y, 0, 0), 0) << file;
      }
      for (std::uint32_t r = 0; r < th && y + r < h; ++r)
        for (std::uint32_t c = 0; c < tw && x + c < w; ++c) out.v[(y + r) * w + x + c] = buf[r * tw + c];
    }
  }
  TIFFClose(t);
  return out;
}

/// Indices of the tiles without bytes of any TIFF (libtiff directly), row-major tile order.
std::set<int> tiles_without_bytes(const fs::path& file) {
  std::set<int> out;
  TIFF* t = TIFFOpen(file.c_str(), "r");
  EXPECT_NE(t, nullptr) << file;
  if (t == nullptr) return out;
  for (ttile_t i = 0; i < TIFFNumberOfTiles(t); ++i) {
    if (TIFFGetStrileByteCount(t, i) == 0) out.insert(static_cast<int>(i));
  }
  TIFFClose(t);
  return out;
}

std::size_t differing_from(const HeightField& f, const std::vector<float>& v) {
  return differing_bits(f, [&] {
    HeightField g(f.geometry());
    std::copy(v.begin(), v.end(), g.data());
    return g;
  }());
}

TEST(TiledScene, LayersAreTiledTiffsWithNoDataTilesStoredWithoutBytesAndLoadAsTheWholeScene) {
  // 150 × 97 with tiles of 32: partial edge tiles in both directions; the hole covers the whole
  // tile (row 2, col 1) = samples [64, 96) × [32, 64), so that tile holds no data.
  const Scene s = wavy_scene(150, 97, 64, 32, 32);
  const fs::path dir = hc::test::temp_dir("scene");
  const fs::path tiled = write_tiled(s, dir, 32);
  hc::pipeline::write_scene(s, dir / "whole");

  const RawTiled depth = read_raw_tiled(tiled / "depth.tiff");
  ASSERT_EQ(depth.width, 97);
  ASSERT_EQ(depth.height, 150);
  EXPECT_EQ(depth.tile, 32);
  EXPECT_EQ(differing_from(s.layers.depth, depth.v), 0u);
  // Tiles are numbered row by row: 4 across (97 / 32), so tile (2, 1) is number 9; the tiles of the
  // last column (x from 96) hold only the NaN last column and are sparse too.
  std::vector<int> expected_sparse = {3, 7, 9, 11, 15, 19};
  EXPECT_EQ(depth.sparse, expected_sparse);
  for (const char* name : {"envelope", "texture", "mu_d", "mu_s", "cell_error"}) {
    EXPECT_EQ(read_raw_tiled(tiled / (std::string(name) + ".tiff")).sparse, expected_sparse) << name;
  }

  const Scene a = hc::pipeline::load_scene(tiled);
  const Scene b = hc::pipeline::load_scene(dir / "whole");
  EXPECT_EQ(a.format_version, hc::pipeline::kTiledSceneFormatVersion);
  EXPECT_EQ(b.format_version, hc::pipeline::kSceneFormatVersion);
  EXPECT_EQ(a.storage, (SceneStorage{32, memory_pyramid(s)->level_count()}));
  EXPECT_EQ(b.storage, SceneStorage{});
  EXPECT_EQ(differing_bits(a.layers.depth, b.layers.depth), 0u);
  EXPECT_EQ(differing_bits(a.layers.envelope, b.layers.envelope), 0u);
  EXPECT_EQ(differing_bits(a.layers.texture, b.layers.texture), 0u);
  EXPECT_EQ(differing_bits(a.layers.mu_d, b.layers.mu_d), 0u);
  EXPECT_EQ(differing_bits(a.layers.mu_s, b.layers.mu_s), 0u);
  EXPECT_EQ(differing_bits(a.layers.cell_error, b.layers.cell_error), 0u);
  EXPECT_EQ(a.layers.colour_rgb8, s.layers.colour_rgb8);
  EXPECT_EQ(a.geometry, s.geometry);

  // (GDAL reads the same file in TiledScene.GdalReadsATileWithoutBytesAsNoDataAndTheTileBesideItAsTheLayer,
  // tiled_scene_gdal_test.cpp, in the executable that links GDAL.)

  // Metadata only: no layer, the storage record.
  const Scene h = hc::pipeline::load_scene(tiled, false);
  EXPECT_EQ(h.layers.depth.rows(), 0);
  EXPECT_EQ(h.geometry, s.geometry);
  EXPECT_EQ(h.storage, a.storage);
}

// The levels table of a stored pyramid (hapticloud levels on a tiled scene, issue 14): a level
// of more than stored_window_samples² samples is read a window at a time, never whole, and its row
// equals the in-memory pyramid's (the oracle: level_table on memory_pyramid, whose levels the
// stored ones equal bit for bit): valid cells, the μ_d histogram, and (a) on every s-th point
// bit for bit; its support is not measured. Points: random over the grid's extent and past it,
// some non-finite, some hidden below the surface, on the no-data hole, and on the grid's last
// row and column (the clamped cells). Window sides 30 (level 0's 300 rows end in a band of
// exactly one window, 211 columns in one of a single column: read from one column before) and 37
// (partial windows). Mutations, run: the windows read without the extra row and column (a
// point's far corners outside: the check throws or reads past), and the residuals kept in window
// order (the RMS's last bits differ).
TEST(TiledScene, TheLevelsTableOfAStoredPyramidReadsWindowsAndEqualsTheInMemoryTable) {
  const Scene s = wavy_scene(300, 211, 96, 48, 100);
  const fs::path dir = hc::test::temp_dir("levels_table");
  const fs::path scene_dir = write_tiled(s, dir, 48);
  const GridGeometry& g = s.geometry;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> ux(g.x0_m - 0.01, g.x_of_col(g.cols - 1) + 0.01);
  std::uniform_real_distribution<double> uy(g.y0_m - 0.01, g.y_of_row(g.rows - 1) + 0.01);
  std::normal_distribution<double> dz(0.0, 0.001);
  std::vector<std::array<double, 3>> p;
  const hc::BilinearSurface f(hc::HeightFieldView::of(s.layers.depth));
  for (int i = 0; i < 40000; ++i) {
    const double x = ux(rng), y = uy(rng);
    const double z = f.height(std::clamp(x, g.x0_m, g.x_of_col(g.cols - 1)), std::clamp(y, g.y0_m, g.y_of_row(g.rows - 1)));
    p.push_back({x, y, (std::isnan(z) ? 0.0 : z) + dz(rng) - (i % 50 == 0 ? 0.01 : 0.0)});
  }
  for (int c = 0; c < g.cols; ++c) p.push_back({g.x_of_col(c), g.y_of_row(g.rows - 1), 0.0});  // the last row
  for (int r = 0; r < g.rows; ++r) p.push_back({g.x_of_col(g.cols - 2), g.y_of_row(r), 0.0});   // next to the last column
  p.push_back({std::numeric_limits<double>::quiet_NaN(), 0.0, 0.0});
  p.push_back({0.0, std::numeric_limits<double>::infinity(), 0.0});
  hc::pipeline::Cloud points;
  points.xyz.resize(3, static_cast<Eigen::Index>(p.size()));
  for (std::size_t i = 0; i < p.size(); ++i)
    for (int a = 0; a < 3; ++a) points.xyz(a, static_cast<Eigen::Index>(i)) = p[i][static_cast<std::size_t>(a)];
  hc::pipeline::LevelTableOptions to;
  to.sample_points = 15000;  // every 3rd point
  const auto mem = hc::pipeline::level_table(memory_pyramid(s), &points, to);
  for (const int side : {30, 37}) {
    SCOPED_TRACE("window side " + std::to_string(side));
    auto stored = LodPyramid::open_stored(scene_dir, s.lod);
    to.stored_window_samples = side;
    const auto rows = hc::pipeline::level_table(stored, &points, to);
    ASSERT_EQ(rows.size(), mem.size());
    int windowed = 0;
    for (std::size_t l = 0; l < rows.size(); ++l) {
      SCOPED_TRACE("level " + std::to_string(l));
      const auto& a = rows[l];
      const auto& b = mem[l];
      const bool in_windows = static_cast<std::size_t>(a.rows) * static_cast<std::size_t>(a.cols) >
                              static_cast<std::size_t>(side) * static_cast<std::size_t>(side);
      windowed += in_windows ? 1 : 0;
      EXPECT_TRUE(a.stored);
      EXPECT_EQ(stored->is_cached(static_cast<int>(l), false), !in_windows) << "a windowed level is never read whole";
      EXPECT_EQ(a.rows, b.rows);
      EXPECT_EQ(a.cols, b.cols);
      EXPECT_EQ(a.cell_size_m, b.cell_size_m);
      EXPECT_EQ(a.valid_cells, b.valid_cells);
      ASSERT_TRUE(a.mu_d && b.mu_d);
      EXPECT_EQ(a.mu_d->valid, b.mu_d->valid);
      EXPECT_EQ(a.mu_d->at_min, b.mu_d->at_min);
      EXPECT_EQ(a.mu_d->at_max, b.mu_d->at_max);
      EXPECT_EQ(a.mu_d->bins, b.mu_d->bins);
      ASSERT_TRUE(a.point_vertical && b.point_vertical);
      EXPECT_EQ(a.point_vertical->count, b.point_vertical->count);
      EXPECT_EQ(a.point_vertical->rms_mm, b.point_vertical->rms_mm);
      EXPECT_EQ(a.point_vertical->p95_mm, b.point_vertical->p95_mm);
      EXPECT_EQ(a.point_vertical->max_mm, b.point_vertical->max_mm);
      EXPECT_EQ(a.points_checked, b.points_checked);
      EXPECT_EQ(a.points_total, b.points_total);
      EXPECT_EQ(a.support_measured, !in_windows);
      if (!in_windows) {
        EXPECT_EQ(a.supported_fraction, b.supported_fraction);
      }
      EXPECT_GT(b.point_vertical->count, 100U) << "the comparison saw points";
    }
    EXPECT_GE(windowed, 3) << "levels 0 to 2 at least go by windows";
    EXPECT_NE(hc::pipeline::level_table_text(rows).find("stored"), std::string::npos);
    // The sweep's windows are read once and not cached (window(..., keep = false)): the cache
    // holds no window after it, and its misses count every window read.
    const auto cs = stored->cache_stats();
    EXPECT_EQ(cs.windows_cached, 0);
    EXPECT_EQ(cs.hits, 0U);
    EXPECT_GE(cs.misses, 3U * 3U) << "level 0 alone is read in at least 3 x 3 windows";
  }
  {
    // window(keep = false) itself: read and not cached; a kept window is then taken from the cache.
    auto stored = LodPyramid::open_stored(scene_dir, s.lod);
    const auto once = stored->window(0, 10, 20, 40, 50, false);
    EXPECT_EQ(stored->cache_stats().windows_cached, 0);
    const auto kept = stored->window(0, 10, 20, 40, 50);
    EXPECT_EQ(stored->cache_stats().windows_cached, 1);
    const auto again = stored->window(0, 10, 20, 40, 50, false);
    EXPECT_EQ(again.get(), kept.get()) << "a cached window is taken, not read again";
    EXPECT_NE(once.get(), kept.get());
    ASSERT_EQ(once->depth_m.values().size(), kept->depth_m.values().size());
    EXPECT_EQ(std::memcmp(once->depth_m.data(), kept->depth_m.data(), once->depth_m.values().size() * sizeof(float)), 0);
    const auto c = stored->cache_stats();
    EXPECT_EQ(c.misses, 2U);
    EXPECT_EQ(c.hits, 1U);
  }
  // The points as a sample of ten times as many (a stored points_sample.bin): (a) from every one,
  // no support, the same figures as the in-memory table given the same.
  to.stored_window_samples = 30;
  to.points_represent = 10 * points.size();
  const auto mem_sampled = hc::pipeline::level_table(memory_pyramid(s), &points, to);
  const auto stored_sampled = hc::pipeline::level_table(LodPyramid::open_stored(scene_dir, s.lod), &points, to);
  ASSERT_EQ(stored_sampled.size(), mem_sampled.size());
  for (std::size_t l = 0; l < mem_sampled.size(); ++l) {
    const auto& a = stored_sampled[l];
    const auto& b = mem_sampled[l];
    ASSERT_TRUE(a.point_vertical && b.point_vertical) << l;
    EXPECT_EQ(a.point_vertical->rms_mm, b.point_vertical->rms_mm) << l;
    EXPECT_EQ(a.points_checked, points.size()) << l;
    EXPECT_EQ(a.points_total, 10 * points.size()) << l;
    EXPECT_FALSE(a.support_measured) << l;
  }
  to.points_represent = 0;
  to.stored_window_samples = 1;
  EXPECT_THROW((void)hc::pipeline::level_table(LodPyramid::open_stored(scene_dir, s.lod), &points, to), hc::ConfigError);
  // A small lod.memory_budget_mb narrows the windows below stored_window_samples (a window of
  // every layer must fit): the table still reads, and equals the in-memory one.
  LodOptions small = s.lod;
  small.memory_budget_mb = 0.5;  // about 7 000 samples a window: sides of 79 instead of 1024
  to.stored_window_samples = 1024;
  const auto narrowed = hc::pipeline::level_table(LodPyramid::open_stored(scene_dir, small), &points, to);
  ASSERT_EQ(narrowed.size(), mem.size());
  for (std::size_t l = 0; l < mem.size(); ++l) {
    ASSERT_TRUE(narrowed[l].point_vertical) << l;
    EXPECT_EQ(narrowed[l].point_vertical->rms_mm, mem[l].point_vertical->rms_mm) << l;
    EXPECT_EQ(narrowed[l].valid_cells, mem[l].valid_cells) << l;
  }
}

// points_sample.bin (lod_report.hpp): every stride-th point and the count it stands for read
// back bit for bit; an absent file is no sample; a file cut short, with another header, a count
// above what it stands for, or a NaN is an error naming the file. Oracle: the points written.
TEST(TiledScene, TheLevelsPointSampleReadsBackAndRefusesAMalformedFile) {
  const fs::path dir = hc::test::temp_dir("point_sample");
  EXPECT_FALSE(hc::pipeline::read_level_point_sample(dir).has_value());
  hc::pipeline::Cloud pts;
  pts.xyz.resize(3, 10);
  for (int i = 0; i < 10; ++i) pts.xyz.col(i) = Eigen::Vector3d(0.1 * i + 1e-17, -0.3 * i, std::ldexp(1.0, -i) / 3.0);
  hc::pipeline::write_level_point_sample(dir, hc::pipeline::every_nth_point(pts, 3), 1000);
  const auto back = hc::pipeline::read_level_point_sample(dir);
  ASSERT_TRUE(back.has_value());
  EXPECT_EQ(back->represents, 1000U);
  ASSERT_EQ(back->points.size(), 4U);  // points 0, 3, 6, 9
  for (int k = 0; k < 4; ++k) EXPECT_EQ(back->points.xyz.col(k), pts.xyz.col(3 * k)) << k;
  hc::pipeline::write_level_point_sample(dir, pts);
  EXPECT_EQ(hc::pipeline::read_level_point_sample(dir)->represents, 10U) << "0: the points' count";
  const fs::path file = dir / "points_sample.bin";
  const std::string good = hc::test::read_bytes(file);
  const auto refused = [&](std::string bytes, const std::string& why) {
    std::ofstream(file, std::ios::binary | std::ios::trunc) << bytes;
    try {
      (void)hc::pipeline::read_level_point_sample(dir);
      ADD_FAILURE() << why << ": no error";
    } catch (const hc::InputError& e) {
      EXPECT_NE(std::string(e.what()).find(file.string()), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(why), std::string::npos) << e.what();
    }
  };
  refused(good.substr(0, good.size() - 1), "bytes for 10 points");
  refused("HCPSMP2\n" + good.substr(8), "no HCPSMP1 header");
  refused(good.substr(0, 10), "no HCPSMP1 header");
  std::string fewer = good;
  fewer[16] = 9;  // represents 9 < count 10
  refused(fewer, "fewer than its 10");
  std::string nan = good;
  const double q = std::numeric_limits<double>::quiet_NaN();
  std::memcpy(nan.data() + 24 + 8, &q, 8);
  refused(nan, "not finite");
}

TEST(TiledScene, StoredWindowsAndLevelsEqualTheInMemoryPyramidAndReadOnlyTheirTiles) {
  const Scene s = wavy_scene(300, 211, 96, 48, 100);
  const fs::path dir = hc::test::temp_dir("scene");
  constexpr int kTile = 48;
  const fs::path scene_dir = write_tiled(s, dir, kTile);
  auto mem = memory_pyramid(s);
  auto stored = LodPyramid::open_stored(scene_dir, s.lod);
  ASSERT_TRUE(stored->stored());
  ASSERT_EQ(stored->level_count(), mem->level_count());
  ASSERT_GE(stored->level_count(), 4);
  // The hole [96, 196) × [48, 148) covers level 0's tiles (2, 1), (2, 2), (3, 1) and (3, 2) whole:
  // they are stored without bytes and read back as no data.
  EXPECT_EQ(read_raw_tiled(scene_dir / "depth.tiff").sparse.size(), 4u);
  EXPECT_EQ(stored->tiles_read(), 0u) << "opening reads directories, not tiles";

  std::mt19937 rng(11);
  // Per level: the tiles without bytes of each of its 7 layer files, and the tiles decoded so far
  // (the tile cache holds them all: this scene is far below a quarter of the 512 MB budget).
  const char* files[] = {"depth", "envelope", "texture", "mu_d", "mu_s", "cell_error", "colour"};
  std::vector<std::vector<std::set<int>>> sparse(static_cast<std::size_t>(stored->level_count()));
  std::vector<std::set<int>> decoded(static_cast<std::size_t>(stored->level_count()));
  for (int level = 0; level < stored->level_count(); ++level) {
    for (const char* f : files) {
      const fs::path file = level == 0 ? scene_dir / (std::string(f) + ".tiff")
                                       : scene_dir / "levels" / ("L" + std::to_string(level)) / (std::string(f) + ".tiff");
      sparse[static_cast<std::size_t>(level)].push_back(tiles_without_bytes(file));
    }
  }
  int windows = 0;
  std::set<std::array<int, 5>> asked;
  for (int level = 0; level < stored->level_count(); ++level) {
    const GridGeometry& g = stored->geometry(level);
    ASSERT_EQ(g, mem->geometry(level)) << "level " << level;
    for (int k = 0; k < 12; ++k) {
      const int rows = std::min(g.rows, 2 + static_cast<int>(rng() % 60));
      const int cols = std::min(g.cols, 2 + static_cast<int>(rng() % 60));
      const int row0 = static_cast<int>(rng() % static_cast<unsigned>(g.rows - rows + 1));
      const int col0 = static_cast<int>(rng() % static_cast<unsigned>(g.cols - cols + 1));
      const std::uint64_t before = stored->tiles_read();
      const auto w = stored->window(level, row0, col0, rows, cols);
      const std::uint64_t read = stored->tiles_read() - before;
      const auto m = mem->window(level, row0, col0, rows, cols);
      SCOPED_TRACE("level " + std::to_string(level) + " window " + std::to_string(rows) + "x" + std::to_string(cols) +
                   " at " + std::to_string(row0) + "," + std::to_string(col0));
      EXPECT_EQ(differing_bits(w->depth_m, m->depth_m), 0u);
      EXPECT_EQ(differing_bits(w->envelope_m, m->envelope_m), 0u);
      EXPECT_EQ(differing_bits(w->texture_m, m->texture_m), 0u);
      EXPECT_EQ(differing_bits(w->mu_d, m->mu_d), 0u);
      EXPECT_EQ(differing_bits(w->mu_s, m->mu_s), 0u);
      EXPECT_EQ(differing_bits(w->cell_error_m, m->cell_error_m), 0u);
      EXPECT_EQ(w->colour_rgb8, m->colour_rgb8);
      // Exactly the tiles it overlaps that no earlier window of this level decoded, in each layer
      // file where they have bytes (a repeated window comes from the window cache: none).
      const int across = (g.cols + kTile - 1) / kTile;
      std::uint64_t expected = 0;
      const bool repeat = !asked.insert({level, row0, col0, rows, cols}).second;
      for (int tr = row0 / kTile; tr <= (row0 + rows - 1) / kTile; ++tr) {
        for (int tc = col0 / kTile; tc <= (col0 + cols - 1) / kTile; ++tc) {
          const int index = tr * across + tc;
          if (repeat || !decoded[static_cast<std::size_t>(level)].insert(index).second) continue;
          for (const auto& none : sparse[static_cast<std::size_t>(level)]) expected += none.count(index) ? 0u : 1u;
        }
      }
      EXPECT_EQ(read, expected);
      ++windows;
    }
    // The whole level, from its tiles.
    const auto a = stored->level(level);
    const auto b = mem->level(level);
    EXPECT_EQ(differing_bits(a->depth_m, b->depth_m), 0u) << "level " << level;
    EXPECT_EQ(differing_bits(a->mu_d, b->mu_d), 0u) << "level " << level;
    EXPECT_EQ(a->colour_rgb8, b->colour_rgb8) << "level " << level;
  }
  EXPECT_EQ(windows, 12 * stored->level_count());
  const auto stats = stored->cache_stats();
  EXPECT_GT(stats.tile_hits, 0u) << "overlapping windows share decoded tiles";
  EXPECT_GT(stats.tiles_cached, 0);
  EXPECT_LE(stats.bytes + stats.tile_bytes, stats.budget_bytes);
}

TEST(TiledScene, ALevelLargerThanTheBudgetIsRefusedWholeButItsWindowsAreRead) {
  const Scene s = wavy_scene(300, 211, 96, 48, 100);
  const fs::path scene_dir = write_tiled(s, hc::test::temp_dir("scene"), 64);
  LodOptions small = s.lod;
  small.memory_budget_mb = 0.5;  // level 0 with its layers and colour is 300·211·27 B = 1.6 MB
  auto stored = LodPyramid::open_stored(scene_dir, small);
  try {
    (void)stored->level(0);
    FAIL() << "level 0 is larger than the budget";
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("lod.memory_budget_mb"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("300 x 211"), std::string::npos) << e.what();
  }
  const auto w = stored->window(0, 10, 10, 40, 40);
  EXPECT_EQ(w->depth_m.rows(), 40);
  // A window larger than the budget is refused too (it would read the whole level).
  EXPECT_THROW((void)stored->window(0, 0, 0, 300, 211), hc::InputError);
  EXPECT_LE(stored->cache_stats().bytes, stored->cache_stats().budget_bytes);
}

TEST(TiledScene, AMissingOrForeignLevelFileAndAnUntiledSceneAreNamedErrors) {
  const Scene s = wavy_scene(120, 90, 0, 0, 0);
  const fs::path dir = hc::test::temp_dir("scene");
  const fs::path scene_dir = write_tiled(s, dir, 32);
  fs::remove(scene_dir / "levels" / "L2" / "depth.tiff");
  try {
    (void)LodPyramid::open_stored(scene_dir, s.lod);
    FAIL() << "a missing level file must be refused at open";
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("L2/depth.tiff"), std::string::npos) << e.what();
  }
  // Level 1's depth in the place of level 2's: its size is named.
  fs::copy_file(scene_dir / "levels" / "L1" / "depth.tiff", scene_dir / "levels" / "L2" / "depth.tiff");
  try {
    (void)LodPyramid::open_stored(scene_dir, s.lod);
    FAIL() << "a level file of the wrong size must be refused";
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("expected level 2"), std::string::npos) << e.what();
  }
  hc::pipeline::write_scene(s, dir / "whole");
  try {
    (void)LodPyramid::open_stored(dir / "whole", s.lod);
    FAIL() << "a format-2 scene stores no levels";
  } catch (const hc::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("scale.scene_tiles"), std::string::npos) << e.what();
  }
}

TEST(TiledScene, TheRunWritesATiledSceneAboveTheThresholdThatLoadsAsTheWholeOne) {
  hc::test::scan_path("happy_buddha/happy_stand_merged_1099005pts.ply.gz");
  const std::string cfg = std::string(HC_SOURCE_DIR) + "/configs/happy_buddha.yaml";
  const hc::pipeline::RunConfig whole_cfg = hc::pipeline::load_run_config(cfg, {"grid.n=400", "lod.report=false"});
  const hc::pipeline::RunConfig tiled_cfg =
      hc::pipeline::load_run_config(cfg, {"grid.n=400", "lod.report=false", "scale.scene_tiles_above_cells=1000",
                                          "scale.scene_tile_cells=64"});
  EXPECT_FALSE(hc::pipeline::writes_tiled_scene(whole_cfg.scale, GridGeometry{400, 400, 0, 0, 1}));
  EXPECT_TRUE(hc::pipeline::writes_tiled_scene(tiled_cfg.scale, GridGeometry{400, 400, 0, 0, 1}));
  const hc::pipeline::BuiltScene built = hc::pipeline::build_scene(whole_cfg);
  const fs::path dir = hc::test::temp_dir("runs");
  hc::pipeline::write_run(built, whole_cfg, dir / "whole");
  hc::pipeline::write_run(built, tiled_cfg, dir / "tiled");
  const Scene a = hc::pipeline::load_scene(dir / "tiled" / "scene");
  const Scene b = hc::pipeline::load_scene(dir / "whole" / "scene");
  ASSERT_EQ(a.format_version, hc::pipeline::kTiledSceneFormatVersion);
  ASSERT_EQ(b.format_version, hc::pipeline::kSceneFormatVersion);
  for (const auto& [x, y] : {std::pair{&a.layers.depth, &b.layers.depth}, {&a.layers.texture, &b.layers.texture},
                             {&a.layers.mu_d, &b.layers.mu_d}, {&a.layers.cell_error, &b.layers.cell_error}}) {
    EXPECT_EQ(differing_bits(*x, *y), 0u);
  }
  // The stored levels are the levels of the whole scene's pyramid.
  auto stored = LodPyramid::open_stored(dir / "tiled" / "scene", a.lod);
  auto mem = LodPyramid::from_scene(Scene(b), b.layer_options, b.lod);
  ASSERT_EQ(stored->level_count(), mem->level_count());
  EXPECT_EQ(a.storage.stored_levels, mem->level_count());
  for (int level = 0; level < stored->level_count(); ++level) {
    const GridGeometry& g = stored->geometry(level);
    const auto w = stored->window(level, g.rows / 3, g.cols / 4, 200, 200);
    const auto m = mem->window(level, g.rows / 3, g.cols / 4, 200, 200);
    EXPECT_EQ(differing_bits(w->depth_m, m->depth_m), 0u) << "level " << level;
    EXPECT_EQ(differing_bits(w->texture_m, m->texture_m), 0u) << "level " << level;
    EXPECT_EQ(differing_bits(w->mu_d, m->mu_d), 0u) << "level " << level;
    EXPECT_EQ(differing_bits(w->cell_error_m, m->cell_error_m), 0u) << "level " << level;
  }
}

TEST(TiledScene, ASceneWrittenTileByTileReadsAsTheSceneWrittenWhole) {
  const Scene s = wavy_scene(200, 150, 60, 20, 50);
  constexpr int kTile = 32;
  const fs::path dir = hc::test::temp_dir("scene");
  const fs::path whole = write_tiled(s, dir, kTile);
  auto mem = memory_pyramid(s);
  const fs::path streamed = dir / "streamed";
  hc::pipeline::TiledSceneWriter::Contents contents;
  contents.cell_error = true;
  contents.colour = true;
  hc::pipeline::TiledSceneWriter w(streamed, s, SceneStorage{kTile, mem->level_count()}, contents);
  // Levels coarsest first and tiles in reverse order: any order is allowed.
  for (int level = mem->level_count() - 1; level >= 0; --level) {
    const auto lvl = mem->level(level);
    const GridGeometry& g = w.level_geometry(level);
    ASSERT_EQ(g, lvl->depth_m.geometry());
    for (int tr = (g.rows - 1) / kTile; tr >= 0; --tr) {
      for (int tc = (g.cols - 1) / kTile; tc >= 0; --tc) {
        std::vector<float> tile(kTile * kTile, kNaN);
        std::vector<std::uint8_t> rgb(3 * kTile * kTile, 0);
        const auto put = [&](const char* name, const HeightField& f) {
          std::fill(tile.begin(), tile.end(), kNaN);
          for (int r = 0; r < kTile && tr * kTile + r < g.rows; ++r)
            for (int c = 0; c < kTile && tc * kTile + c < g.cols; ++c) tile[r * kTile + c] = f.at(tr * kTile + r, tc * kTile + c);
          w.write_tile(level, name, tr, tc, tile.data());
        };
        put("depth", lvl->depth_m);
        put("envelope", lvl->envelope_m);
        put("texture", lvl->texture_m);
        put("mu_d", lvl->mu_d);
        put("mu_s", lvl->mu_s);
        put("cell_error", lvl->cell_error_m);
        for (int r = 0; r < kTile && tr * kTile + r < g.rows; ++r)
          for (int c = 0; c < kTile && tc * kTile + c < g.cols; ++c)
            for (int k = 0; k < 3; ++k)
              rgb[3 * (r * kTile + c) + k] =
                  lvl->colour_rgb8[3 * (static_cast<std::size_t>(tr * kTile + r) * g.cols + tc * kTile + c) + k];
        w.write_tile(level, "colour", tr, tc, rgb.data());
      }
    }
  }
  EXPECT_THROW(w.write_tile(0, "intensity", 0, 0, nullptr), std::invalid_argument);
  EXPECT_THROW(w.write_tile(0, "depth", 7, 0, nullptr), std::invalid_argument);  // rows 224.. are outside
  EXPECT_GT(w.finish(), 0u);

  const Scene a = hc::pipeline::load_scene(streamed);
  const Scene b = hc::pipeline::load_scene(whole);
  EXPECT_EQ(a.storage, b.storage);
  EXPECT_EQ(differing_bits(a.layers.depth, b.layers.depth), 0u);
  EXPECT_EQ(differing_bits(a.layers.mu_d, b.layers.mu_d), 0u);
  EXPECT_EQ(a.layers.colour_rgb8, b.layers.colour_rgb8);
  auto x = LodPyramid::open_stored(streamed, s.lod);
  auto y = LodPyramid::open_stored(whole, s.lod);
  ASSERT_EQ(x->level_count(), y->level_count());
  for (int level = 0; level < x->level_count(); ++level) {
    const auto p = x->level(level);
    const auto q = y->level(level);
    EXPECT_EQ(differing_bits(p->depth_m, q->depth_m), 0u) << level;
    EXPECT_EQ(differing_bits(p->texture_m, q->texture_m), 0u) << level;
    EXPECT_EQ(differing_bits(p->cell_error_m, q->cell_error_m), 0u) << level;
    EXPECT_EQ(p->colour_rgb8, q->colour_rgb8) << level;
  }
}

TEST(TiledScene, ASceneWithoutSurfaceLayersStoresTheLayersThePyramidComputesForEveryLevel) {
  // layers.enabled: false. The in-memory pyramid computes the surface layers of every level its
  // windows come from, level 0 included; the stored scene must give the same windows.
  const std::string cfg = std::string(HC_SOURCE_DIR) + "/configs/sinusoid.yaml";
  const fs::path dir = hc::test::temp_dir("run");
  hc::pipeline::run_pipeline(hc::pipeline::load_run_config(cfg, {"layers.enabled=false", "lod.report=false",
                                                                 "scale.scene_tiles=on", "scale.scene_tile_cells=32",
                                                                 "lod.min_cells=20"}),
                             dir / "out");
  const Scene whole = hc::pipeline::load_scene(dir / "out" / "scene");
  ASSERT_FALSE(whole.layers.has_surface_layers());
  EXPECT_TRUE(fs::exists(dir / "out" / "scene" / "levels" / "L0" / "mu_d.tiff"));
  auto stored = LodPyramid::open_stored(dir / "out" / "scene", whole.lod);
  auto mem = LodPyramid::from_scene(Scene(whole), whole.layer_options, whole.lod);
  ASSERT_EQ(stored->level_count(), mem->level_count());
  for (int level = 0; level < stored->level_count(); ++level) {
    const auto w = stored->window(level, 3, 5, 30, 30);
    const auto m = mem->window(level, 3, 5, 30, 30);
    ASSERT_GT(m->texture_m.rows(), 0) << level;
    EXPECT_EQ(differing_bits(w->depth_m, m->depth_m), 0u) << level;
    EXPECT_EQ(differing_bits(w->texture_m, m->texture_m), 0u) << level;
    EXPECT_EQ(differing_bits(w->mu_d, m->mu_d), 0u) << level;
    EXPECT_EQ(differing_bits(w->mu_s, m->mu_s), 0u) << level;
  }
}

TEST(TiledScene, PreviewsOfALevelZeroWiderThanTheCapAreTheStoredLevelsThatFits) {
  // scale.preview_max_side = 64 on the 200-sample sinusoid: levels 200, 100, 50, 25; the
  // previews must be those of level 2 (the finest within 64), drawn from the in-memory pyramid
  // of the same scene (LodPyramid::from_scene, which lod_test checks against brute force).
  const std::string cfg = std::string(HC_SOURCE_DIR) + "/configs/sinusoid.yaml";
  const fs::path dir = hc::test::temp_dir("capped");
  hc::pipeline::run_pipeline(hc::pipeline::load_run_config(cfg, {"lod.report=false", "scale.scene_tiles=on",
                                                                 "scale.scene_tile_cells=32", "lod.min_cells=20",
                                                                 "scale.preview_max_side=64"}),
                             dir / "out");
  const Scene whole = hc::pipeline::load_scene(dir / "out" / "scene");
  ASSERT_EQ(whole.geometry.cols, 200);
  int expected = 0;
  while (std::max(hc::pipeline::lod_level_geometry(whole.geometry, expected).rows,
                  hc::pipeline::lod_level_geometry(whole.geometry, expected).cols) > 64) {
    ++expected;
  }
  ASSERT_EQ(expected, 2);
  auto mem = LodPyramid::from_scene(Scene(whole), whole.layer_options, whole.lod);
  const auto level = mem->level(expected);
  ASSERT_EQ(level->depth_m.cols(), 50);
  const fs::path oracle = dir / "oracle";
  fs::create_directory(oracle);
  const std::string sfx = " (level 2, 1 sample : 4 cells)";
  hc::pipeline::write_colour_preview(level->depth_m, oracle / "depth.png", "depth z" + sfx, "mm", 1000.0);
  hc::pipeline::write_colour_preview(level->texture_m, oracle / "texture.png", "texture h = f - f_b" + sfx, "mm", 1000.0);
  hc::pipeline::write_colour_preview(level->mu_s, oracle / "mu_s.png", "static friction mu_s" + sfx, "-", 1.0);
  hc::pipeline::write_colour_preview(level->cell_error_m, oracle / "cross_check_error.png",
                                     "cross-check: grid sample to nearest point, level 0's averaged" + sfx, "mm", 1000.0);
  hc::pipeline::write_hillshade_preview(level->depth_m, oracle / "hillshade.png", "hillshade" + sfx);
  for (const char* png : {"depth.png", "texture.png", "mu_s.png", "cross_check_error.png", "hillshade.png"}) {
    ASSERT_TRUE(fs::exists(dir / "out" / "previews" / png)) << png;
    EXPECT_EQ(hc::test::read_bytes(dir / "out" / "previews" / png), hc::test::read_bytes(oracle / png)) << png;
  }
  // Level 0's own preview differs (the check above can fail).
  hc::pipeline::write_colour_preview(whole.layers.depth, oracle / "depth0.png", "depth z", "mm", 1000.0);
  EXPECT_NE(hc::test::read_bytes(dir / "out" / "previews" / "depth.png"), hc::test::read_bytes(oracle / "depth0.png"));
  // The report names the level.
  std::ifstream report_in(dir / "out" / "report.json");
  const auto report = nlohmann::json::parse(report_in);
  bool named = false;
  for (const auto& st : report["stages"]) {
    if (st["stage"] != "scene_levels") continue;
    EXPECT_EQ(st["figures"]["previews_level"].get<double>(), 2.0);
    for (const auto& n : st["notes"]) named = named || n.get<std::string>().find("stored level 2 (50 x 50)") != std::string::npos;
  }
  EXPECT_TRUE(named) << report.dump();
}

TEST(TiledScene, StageSceneLevelsReportsEveryPassOfTheLevelBuilderWithItsFraction) {
  // run_pipeline's progress callback during stage scene_levels (scale.progress_interval_s = 0:
  // every row of tiles): every pass the builder makes (level 0's means; per level k ≥ 1 its
  // depth and its layers' fill range, envelope and friction) is named with ", this pass", its
  // fractions rise to 1, and all of them come before the stage's end.
  const std::string cfg = std::string(HC_SOURCE_DIR) + "/configs/sinusoid.yaml";
  const fs::path dir = hc::test::temp_dir("progress");
  struct Call {
    std::string note;
    double fraction = 0.0;
    bool done = false;
  };
  std::vector<Call> calls;
  hc::pipeline::run_pipeline(
      hc::pipeline::load_run_config(cfg, {"lod.report=false", "scale.scene_tiles=on", "scale.scene_tile_cells=32",
                                          "lod.min_cells=20", "scale.progress_interval_s=0"}),
      dir / "out", [&](const hc::pipeline::StageReport& r, bool done) {
        if (r.stage != "scene_levels") return;
        Call c;
        c.done = done;
        if (!done && !r.notes.empty()) {
          c.note = r.notes.front();
          for (const auto& [name, value] : r.figures)
            if (name == "progress_fraction") c.fraction = value;
        }
        calls.push_back(c);
      });
  ASSERT_FALSE(calls.empty());
  EXPECT_TRUE(calls.back().done);
  const Scene whole = hc::pipeline::load_scene(dir / "out" / "scene");
  const int levels = whole.storage.stored_levels;
  ASSERT_EQ(levels, 4);  // 200, 100, 50, 25 samples
  std::vector<std::string> passes = {"level 0 mean heights"};
  for (int k = 1; k < levels; ++k) {
    for (const char* p : {" depth", " layers (fill range)", " layers (envelope)", " layers (friction)"}) {
      passes.push_back("level " + std::to_string(k) + p);
    }
  }
  for (const std::string& pass : passes) {
    const std::string note = pass + ", this pass";
    double last = 0.0;
    std::size_t seen = 0;
    for (std::size_t i = 0; i + 1 < calls.size(); ++i) {
      if (calls[i].note != note) continue;
      EXPECT_FALSE(calls[i].done);
      EXPECT_GE(calls[i].fraction, last) << note;
      last = calls[i].fraction;
      ++seen;
    }
    EXPECT_GT(seen, 0U) << note << " was not reported";
    EXPECT_DOUBLE_EQ(last, 1.0) << note;
  }
}

// Suite LodPyramid, so that CI's ThreadSanitizer stage (.ci/run) runs it: two threads read windows
// of one stored pyramid at once, with budgets small enough that tiles and windows are evicted
// while the other thread uses them; every window equals the in-memory pyramid's.
TEST(LodPyramid, StoredWindowsReadFromTwoThreadsUnderEvictionEqualTheInMemoryOnes) {
  const Scene s = wavy_scene(300, 211, 96, 48, 100);
  const fs::path scene_dir = write_tiled(s, hc::test::temp_dir("scene"), 48);
  LodOptions small = s.lod;
  small.memory_budget_mb = 1.5;  // tiles 0.375 MB (about 40 float tiles), windows 1.125 MB
  auto stored = LodPyramid::open_stored(scene_dir, small);
  struct Request {
    int level, row0, col0, rows, cols;
    std::shared_ptr<const hc::pipeline::LodWindowLayers> got;
  };
  const auto requests = [&](unsigned seed) {
    std::mt19937 rng(seed);
    std::vector<Request> out;
    for (int i = 0; i < 150; ++i) {
      const int level = static_cast<int>(rng() % static_cast<unsigned>(stored->level_count()));
      const GridGeometry& g = stored->geometry(level);
      const int rows = std::min(g.rows, 2 + static_cast<int>(rng() % 50));
      const int cols = std::min(g.cols, 2 + static_cast<int>(rng() % 50));
      out.push_back({level, static_cast<int>(rng() % static_cast<unsigned>(g.rows - rows + 1)),
                     static_cast<int>(rng() % static_cast<unsigned>(g.cols - cols + 1)), rows, cols, nullptr});
    }
    return out;
  };
  std::vector<Request> a = requests(21), b = requests(22);
  const auto run = [&](std::vector<Request>& list) {
    for (Request& r : list) r.got = stored->window(r.level, r.row0, r.col0, r.rows, r.cols);
  };
  std::thread other([&] { run(b); });
  run(a);
  other.join();
  auto mem = memory_pyramid(s);
  for (const auto* list : {&a, &b}) {
    for (const Request& r : *list) {
      const auto m = mem->window(r.level, r.row0, r.col0, r.rows, r.cols);
      ASSERT_EQ(differing_bits(r.got->depth_m, m->depth_m), 0u) << r.level << " " << r.row0 << "," << r.col0;
      ASSERT_EQ(differing_bits(r.got->texture_m, m->texture_m), 0u);
      ASSERT_EQ(r.got->colour_rgb8, m->colour_rgb8);
    }
  }
  const auto stats = stored->cache_stats();
  EXPECT_GT(stats.evictions, 0u) << "the window budget must have been exceeded for the test to mean anything";
  EXPECT_LE(stats.tile_bytes, static_cast<std::size_t>(0.375 * 1024 * 1024) + 48 * 48 * 4);
}

TEST(TiledScene, TileSidesThatAreNotMultiplesOfSixteenAreRefused) {
  const std::string cfg = std::string(HC_SOURCE_DIR) + "/configs/sinusoid.yaml";
  try {
    (void)hc::pipeline::load_run_config(cfg, {"scale.scene_tile_cells=100"});
    FAIL() << "100 is not a multiple of 16";
  } catch (const hc::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("scale.scene_tile_cells"), std::string::npos) << e.what();
  }
  const Scene s = wavy_scene(40, 40, 0, 0, 0);
  EXPECT_THROW(hc::pipeline::write_scene(s, hc::test::temp_dir("x") / "scene", SceneStorage{40, 1}), std::invalid_argument);
}

}  // namespace
