// Colour and intensity from the scan to the scene's layers (issue 12, "Colour and intensity,
// scan to screen"): reprojection against a brute-force front-most oracle, splats, hole filling,
// the filters keeping attributes aligned, and a coloured sample through the whole run.

#include "hc/pipeline/filters.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/reproject.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <gtest/gtest.h>

#include "test_paths.hpp"

#include <cmath>
#include <fstream>
#include <random>
#include <sstream>

namespace {

namespace fs = std::filesystem;
using namespace hc::pipeline;

/// Two layers over the same x-y cells: a back layer (z in [0, 0.1)) and a front layer
/// (z in [0.5, 0.6)), each point with its own random colour and intensity; z values are floats
/// (so the front-most point of a node is unique as a float too).
Cloud two_layer_cloud(std::size_t n_per_layer, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> xy(0.0f, 1.0f), dz(0.0f, 0.1f), unit(0.0f, 1.0f);
  std::uniform_int_distribution<int> byte(0, 255);
  Cloud c;
  c.xyz.resize(3, static_cast<Eigen::Index>(2 * n_per_layer));
  for (std::size_t i = 0; i < n_per_layer; ++i) {
    const float x = xy(rng), y = xy(rng);
    for (std::size_t layer = 0; layer < 2; ++layer) {
      const auto k = static_cast<Eigen::Index>(2 * i + layer);
      c.xyz.col(k) = Eigen::Vector3d(x, y, static_cast<float>(layer == 0 ? dz(rng) : 0.5f + dz(rng)));
      for (int ch = 0; ch < 3; ++ch) c.rgb.push_back(static_cast<std::uint8_t>(byte(rng)));
      c.intensity.push_back(unit(rng));
    }
  }
  return c;
}

/// Brute-force oracle: for each node of g, the index of the point with the largest z among the
/// points whose nearest node it is (−1 if none). Written from the spec, not from reproject.cpp.
std::vector<long> oracle_front_most(const Cloud& c, const hc::GridGeometry& g) {
  std::vector<long> best(g.cell_count(), -1);
  for (std::size_t i = 0; i < c.size(); ++i) {
    const double x = c.xyz(0, static_cast<Eigen::Index>(i)), y = c.xyz(1, static_cast<Eigen::Index>(i));
    const int col = std::clamp(static_cast<int>(std::floor((x - g.x0_m) / g.cell_size_m + 0.5)), 0, g.cols - 1);
    const int row = std::clamp(static_cast<int>(std::floor((y - g.y0_m) / g.cell_size_m + 0.5)), 0, g.rows - 1);
    const std::size_t k = static_cast<std::size_t>(row) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(col);
    if (best[k] < 0 || c.xyz(2, static_cast<Eigen::Index>(i)) > c.xyz(2, best[k])) best[k] = static_cast<long>(i);
  }
  return best;
}

void expect_cell_is_point(const DepthGrid& d, const Cloud& c, std::size_t cell, long point) {
  for (std::size_t ch = 0; ch < 3; ++ch) {
    ASSERT_EQ(d.colour_rgb8[3 * cell + ch], c.rgb[3 * static_cast<std::size_t>(point) + ch]) << "cell " << cell;
  }
  ASSERT_EQ(d.intensity.data()[cell], c.intensity[static_cast<std::size_t>(point)]) << "cell " << cell;
}

TEST(ColourLayers, EachMeasuredCellTakesTheFrontMostPointsColourAndIntensity) {
  const Cloud cloud = two_layer_cloud(3000, 7);
  ReprojectOptions o;
  o.grid.n_long_side = 40;  // about 2 points per node and layer
  const DepthGrid d = reproject(cloud, o).value;
  ASSERT_TRUE(d.has_colour());
  ASSERT_TRUE(d.has_intensity());
  const hc::GridGeometry& g = d.depth.geometry();
  ASSERT_EQ(d.colour_rgb8.size(), 3 * g.cell_count());
  ASSERT_EQ(d.intensity.values().size(), g.cell_count());
  const std::vector<long> oracle = oracle_front_most(cloud, g);
  std::size_t measured = 0;
  for (std::size_t k = 0; k < g.cell_count(); ++k) {
    if (oracle[k] < 0) {
      EXPECT_EQ(d.flags[k], kCellEmpty);
      EXPECT_TRUE(std::isnan(d.intensity.data()[k]));
      EXPECT_EQ(d.colour_rgb8[3 * k] | d.colour_rgb8[3 * k + 1] | d.colour_rgb8[3 * k + 2], 0);
      continue;
    }
    ++measured;
    ASSERT_EQ(d.flags[k], kCellMeasured);
    ASSERT_EQ(d.depth.data()[k], static_cast<float>(cloud.xyz(2, oracle[k])));
    ASSERT_GE(d.depth.data()[k], 0.5f);  // the front layer wins
    expect_cell_is_point(d, cloud, k, oracle[k]);
  }
  EXPECT_GT(measured, g.cell_count() * 3 / 4);
}

TEST(ColourLayers, DepthAndFlagsDoNotChangeWhenTheCloudCarriesColour) {
  const Cloud coloured = two_layer_cloud(2000, 11);
  Cloud plain;
  plain.xyz = coloured.xyz;
  for (int mode = 0; mode < 3; ++mode) {
    ReprojectOptions o;
    o.grid.n_long_side = 60;
    o.see_through_depth_m = 0.2;
    if (mode == 0) o.splat_radius_cells = 2.0;
    if (mode == 1) {
      o.splat_radius_cells = 2.5;
      o.splat_mode = SplatMode::kInterpolate;
    }
    if (mode == 2) o.upsample_factor = 2;
    DepthGrid a = reproject(coloured, o).value;
    DepthGrid b = reproject(plain, o).value;
    a = fill_holes(std::move(a), 20).value;
    b = fill_holes(std::move(b), 20).value;
    EXPECT_FALSE(b.has_colour());
    EXPECT_FALSE(b.has_intensity());
    ASSERT_EQ(a.flags, b.flags) << "mode " << mode;
    ASSERT_EQ(a.depth.values().size(), b.depth.values().size());
    for (std::size_t k = 0; k < a.depth.values().size(); ++k) {
      const float za = a.depth.data()[k], zb = b.depth.data()[k];
      ASSERT_TRUE((std::isnan(za) && std::isnan(zb)) || za == zb) << "mode " << mode << " cell " << k;
      // Colour and intensity exist exactly where depth does.
      EXPECT_EQ(std::isnan(a.intensity.data()[k]), std::isnan(za)) << "mode " << mode << " cell " << k;
    }
  }
}

TEST(ColourLayers, DiscSplatsCarryTheColourOfTheMeasuredCellWhoseDepthTheyTook) {
  // Sparse points: many cells are filled by a neighbour's disc.
  const Cloud cloud = two_layer_cloud(150, 3);
  ReprojectOptions o;
  o.grid.n_long_side = 50;
  o.splat_radius_cells = 2.0;
  const DepthGrid d = reproject(cloud, o).value;
  const hc::GridGeometry& g = d.depth.geometry();
  const std::vector<long> oracle = oracle_front_most(cloud, g);
  std::size_t splatted = 0;
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      const std::size_t k = static_cast<std::size_t>(r) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(c);
      if (d.flags[k] == kCellMeasured) {
        expect_cell_is_point(d, cloud, k, oracle[k]);
        continue;
      }
      // Oracle for a splatted / empty cell: the front-most measured node within the disc.
      long best = -1;
      for (int rr = 0; rr < g.rows; ++rr) {
        for (int cc = 0; cc < g.cols; ++cc) {
          if ((rr - r) * (rr - r) + (cc - c) * (cc - c) > 4) continue;
          const long p = oracle[static_cast<std::size_t>(rr) * static_cast<std::size_t>(g.cols) + static_cast<std::size_t>(cc)];
          if (p >= 0 && (best < 0 || cloud.xyz(2, p) > cloud.xyz(2, best))) best = p;
        }
      }
      if (best < 0) {
        ASSERT_EQ(d.flags[k], kCellEmpty);
        continue;
      }
      ASSERT_EQ(d.flags[k], kCellSplatted);
      ++splatted;
      ASSERT_EQ(d.depth.data()[k], static_cast<float>(cloud.xyz(2, best)));
      expect_cell_is_point(d, cloud, k, best);
    }
  }
  EXPECT_GT(splatted, 100u);
}

TEST(ColourLayers, HoleFillingGivesFilledCellsTheColourOfAUniformRim) {
  // A dense plane with one colour and intensity, with a small square hole in the middle.
  Cloud c;
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i <= 40; ++i) {
    for (int j = 0; j <= 40; ++j) {
      if (i >= 18 && i <= 21 && j >= 18 && j <= 21) continue;
      pts.emplace_back(i * 0.01, j * 0.01, 0.002 * i);
    }
  }
  c.xyz.resize(3, static_cast<Eigen::Index>(pts.size()));
  for (std::size_t k = 0; k < pts.size(); ++k) {
    c.xyz.col(static_cast<Eigen::Index>(k)) = pts[k];
    c.rgb.insert(c.rgb.end(), {12, 200, 99});
    c.intensity.push_back(0.625f);
  }
  ReprojectOptions o;
  o.grid.n_long_side = 41;
  DepthGrid d = fill_holes(reproject(c, o).value, 30).value;
  std::size_t filled = 0;
  for (std::size_t k = 0; k < d.flags.size(); ++k) {
    if (d.flags[k] != kCellFilled) continue;
    ++filled;
    EXPECT_EQ(d.colour_rgb8[3 * k], 12);
    EXPECT_EQ(d.colour_rgb8[3 * k + 1], 200);
    EXPECT_EQ(d.colour_rgb8[3 * k + 2], 99);
    EXPECT_NEAR(d.intensity.data()[k], 0.625f, 1e-6f);
  }
  EXPECT_EQ(filled, 16u);
}

TEST(ColourLayers, OutlierRemovalKeepsEachSurvivingPointsOwnColourAndIntensity) {
  // A plane plus far outliers; colour and intensity encode the point's index.
  Cloud c;
  std::vector<Eigen::Vector3d> pts;
  for (int i = 0; i < 30; ++i) {
    for (int j = 0; j < 30; ++j) pts.emplace_back(i * 0.01, j * 0.01, 0.0);
  }
  for (int k = 0; k < 12; ++k) pts.emplace_back(0.05 * k, 0.1, 5.0 + k);
  c.xyz.resize(3, static_cast<Eigen::Index>(pts.size()));
  for (std::size_t k = 0; k < pts.size(); ++k) {
    c.xyz.col(static_cast<Eigen::Index>(k)) = pts[k];
    c.rgb.insert(c.rgb.end(), {static_cast<std::uint8_t>(k & 255), static_cast<std::uint8_t>(k >> 8), 7});
    c.intensity.push_back(static_cast<float>(k));
  }
  const Cloud kept = remove_statistical_outliers(c, 8, 1.0).value;
  ASSERT_LT(kept.size(), c.size());
  ASSERT_EQ(kept.rgb.size(), 3 * kept.size());
  ASSERT_EQ(kept.intensity.size(), kept.size());
  for (std::size_t i = 0; i < kept.size(); ++i) {
    const Eigen::Vector3d p = kept.xyz.col(static_cast<Eigen::Index>(i));
    // The original index of this point, found by its coordinates (all distinct).
    std::size_t src = pts.size();
    for (std::size_t k = 0; k < pts.size(); ++k) {
      if (pts[k] == p) src = k;
    }
    ASSERT_LT(src, pts.size());
    EXPECT_LT(p.z(), 1.0) << "an outlier survived";
    EXPECT_EQ(kept.intensity[i], static_cast<float>(src));
    EXPECT_EQ(kept.rgb[3 * i], src & 255);
    EXPECT_EQ(kept.rgb[3 * i + 1], src >> 8);
    EXPECT_EQ(kept.rgb[3 * i + 2], 7);
  }
}

TEST(ColourLayers, VoxelFilterAveragesColourAndIntensityPerVoxel) {
  const Cloud c = two_layer_cloud(500, 5);
  const double leaf = 0.05;
  const StageResult<Cloud> v = voxel_downsample(c, leaf);
  ASSERT_TRUE(v.value.has_rgb());
  ASSERT_TRUE(v.value.has_intensity());
  ASSERT_EQ(v.value.rgb.size(), 3 * v.value.size());
  ASSERT_EQ(v.value.intensity.size(), v.value.size());
  // Oracle: group the input points by the voxel (floor(p / leaf) per axis) that contains each
  // output centroid, in double; compare the mean colour and intensity. Points within 1e-6 of a
  // voxel face are avoided (float rounding may put them on either side).
  std::size_t checked = 0;
  for (std::size_t o = 0; o < v.value.size(); ++o) {
    const Eigen::Vector3d centroid = v.value.xyz.col(static_cast<Eigen::Index>(o));
    const Eigen::Vector3d key = (centroid / leaf).array().floor();
    double sum[4] = {0, 0, 0, 0};
    std::size_t n = 0;
    bool near_face = false;
    for (std::size_t i = 0; i < c.size(); ++i) {
      const Eigen::Vector3d q = c.xyz.col(static_cast<Eigen::Index>(i)) / leaf;
      const Eigen::Vector3d frac = q - q.array().floor().matrix();
      if (((q.array().floor() - key.array()).abs() > 0.5).any()) continue;
      if ((frac.array() < 1e-4).any() || (frac.array() > 1 - 1e-4).any()) near_face = true;
      for (std::size_t ch = 0; ch < 3; ++ch) sum[ch] += c.rgb[3 * i + ch];
      sum[3] += c.intensity[i];
      ++n;
    }
    if (near_face) continue;
    ASSERT_GT(n, 0u);
    ++checked;
    for (std::size_t ch = 0; ch < 3; ++ch) {
      EXPECT_EQ(v.value.rgb[3 * o + ch], std::lround(sum[ch] / static_cast<double>(n))) << "voxel " << o;
    }
    EXPECT_NEAR(v.value.intensity[o], sum[3] / static_cast<double>(n), 1e-6) << "voxel " << o;
  }
  EXPECT_GT(checked, v.value.size() * 9 / 10);
}

TEST(ColourLayers, ColouredLasRunWritesColourLayerAndPreviewsAndReadsThemBack) {
  const fs::path dir = hc::test::temp_dir("las");
  const fs::path las = hc::test::scan_path("scanner_samples/las/pdal-simple.las");
  const RunConfig config = parse_run_config("input: {files: [" + las.string() + "]}\n"
                                            "grid: {n: 80, hole_fill_max_cells: 8}\nlod: {report: true}\n",
                                            dir / "run.yaml");
  const BuiltScene built = build_scene(config, false);
  ASSERT_FALSE(built.scene.layers.colour_rgb8.empty());
  ASSERT_FALSE(built.scene.layers.intensity.values().empty());
  // Measured cells against the oracle on the same prepared points.
  const Cloud points = prepare_points(config);
  ASSERT_TRUE(points.has_rgb());
  const hc::GridGeometry& g = built.scene.geometry;
  const std::vector<long> oracle = oracle_front_most(points, g);
  std::size_t measured = 0;
  for (std::size_t k = 0; k < g.cell_count(); ++k) {
    if (built.scene.layers.flags[k] != kCellMeasured) continue;
    ++measured;
    ASSERT_GE(oracle[k], 0);
    for (std::size_t ch = 0; ch < 3; ++ch) {
      ASSERT_EQ(built.scene.layers.colour_rgb8[3 * k + ch], points.rgb[3 * static_cast<std::size_t>(oracle[k]) + ch]);
    }
    ASSERT_EQ(built.scene.layers.intensity.data()[k], points.intensity[static_cast<std::size_t>(oracle[k])]);
  }
  EXPECT_GT(measured, 300u);

  write_run(built, config, dir / "out");
  for (const char* f : {"scene/colour.png", "previews/colour.png", "previews/colour_hillshade.png", "previews/intensity.png"}) {
    EXPECT_TRUE(fs::exists(dir / "out" / f)) << f;
  }
  const Scene loaded = load_scene(dir / "out" / "scene");
  EXPECT_EQ(loaded.layers.colour_rgb8, built.scene.layers.colour_rgb8);
  ASSERT_EQ(loaded.layers.intensity.values().size(), built.scene.layers.intensity.values().size());
  for (std::size_t k = 0; k < g.cell_count(); ++k) {
    const float a = loaded.layers.intensity.data()[k], b = built.scene.layers.intensity.data()[k];
    ASSERT_TRUE((std::isnan(a) && std::isnan(b)) || a == b) << k;
  }
  std::ifstream md(dir / "out" / "report.md");
  std::stringstream text;
  text << md.rdbuf();
  EXPECT_NE(text.str().find("previews/colour.png"), std::string::npos);
  EXPECT_NE(text.str().find("previews/colour_hillshade.png"), std::string::npos);
  EXPECT_NE(text.str().find("previews/intensity.png"), std::string::npos);
  EXPECT_NE(text.str().find("per-point attributes found: colour (rgb), intensity"), std::string::npos);

  // The move overload (run_pipeline's), which hands level 0's layers to the levels pyramid
  // instead of copying them: the same scene files, the same levels table rows and the same
  // previews named in report.md.
  ASSERT_TRUE(config.lod.report);
  BuiltScene moved = built;
  write_run(std::move(moved), config, dir / "out_moved");
  for (const auto& e : fs::directory_iterator(dir / "out" / "scene")) {
    std::ifstream a(e.path(), std::ios::binary), b(dir / "out_moved" / "scene" / e.path().filename(), std::ios::binary);
    std::stringstream sa, sb;
    sa << a.rdbuf();
    sb << b.rdbuf();
    EXPECT_TRUE(sa.str() == sb.str()) << e.path().filename();
  }
  const auto picture_and_table_lines = [](const fs::path& report) {
    std::ifstream in(report);
    std::vector<std::string> lines;
    for (std::string line; std::getline(in, line);) {
      if (line.rfind("![", 0) == 0) lines.push_back(line);
      if (line.rfind("| ", 0) == 0) lines.push_back(line.substr(0, line.find('|', 2)));  // a table row's first cell
    }
    return lines;
  };
  const std::vector<std::string> want = picture_and_table_lines(dir / "out" / "report.md");
  EXPECT_EQ(picture_and_table_lines(dir / "out_moved" / "report.md"), want);
  EXPECT_NE(std::find(want.begin(), want.end(), "![colour (front-most point per cell)](previews/colour.png)"), want.end());
}

TEST(ColourLayers, LevelsOfDetailSmoothColourLikeDepthAndCropItIntoWindows) {
  // Level 0: 64 x 64 plane with a hole; red is a ramp along columns (R = col), so normalised
  // smoothing reproduces it at the interior coarse samples: R = 2^L · col_L.
  const hc::GridGeometry g{64, 64, 0.0, 0.0, 0.001};
  LodLevel l0;
  l0.depth_m = hc::HeightField(g, 0.0f);
  l0.colour_rgb8.assign(3 * g.cell_count(), 0);
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      const std::size_t k = static_cast<std::size_t>(r) * 64 + static_cast<std::size_t>(c);
      if (r >= 20 && r < 40 && c >= 20 && c < 40) {
        l0.depth_m.data()[k] = hc::kNoData;
        continue;
      }
      l0.colour_rgb8[3 * k] = static_cast<std::uint8_t>(c);
      l0.colour_rgb8[3 * k + 1] = 50;
      l0.colour_rgb8[3 * k + 2] = 200;
    }
  }
  hc::LodOptions lo;
  lo.min_cells = 8;
  LodPyramid pyramid(std::move(l0), hc::SurfaceLayerOptions{}, lo);
  ASSERT_GE(pyramid.level_count(), 3);
  for (int level = 1; level < 3; ++level) {
    const auto lvl = pyramid.depth_level(level);
    const hc::GridGeometry& lg = lvl->depth_m.geometry();
    ASSERT_EQ(lvl->colour_rgb8.size(), 3 * lg.cell_count()) << "level " << level;
    const int step = 1 << level;
    std::size_t checked = 0;
    for (int r = 0; r < lg.rows; ++r) {
      for (int c = 0; c < lg.cols; ++c) {
        const std::size_t k = static_cast<std::size_t>(r) * static_cast<std::size_t>(lg.cols) + static_cast<std::size_t>(c);
        const std::uint8_t* rgb = lvl->colour_rgb8.data() + 3 * k;
        if (std::isnan(lvl->depth_m.data()[k])) {
          EXPECT_EQ(rgb[0] | rgb[1] | rgb[2], 0);
          continue;
        }
        EXPECT_EQ(rgb[1], 50);
        EXPECT_EQ(rgb[2], 200);
        // Away from the border and the hole by the reach of the kernels of every level so far
        // (⌈3σ⌉ samples of each finer level), the ramp is exact.
        const int reach = static_cast<int>(std::ceil(3.0 * lo.antialias_sigma_cells));
        const int fr = r * step, fc = c * step, margin = (step - 1) * reach + 1;
        const bool clear = fr >= margin && fc >= margin && fr < 64 - margin && fc < 64 - margin &&
                           (fr < 20 - margin || fr >= 40 + margin || fc < 20 - margin || fc >= 40 + margin);
        if (!clear) continue;
        ++checked;
        EXPECT_NEAR(rgb[0], fc, 1) << "level " << level << " (" << r << ", " << c << ")";
      }
    }
    EXPECT_GT(checked, 0u) << "level " << level;
  }
  const auto win = pyramid.window(1, 3, 5, 8, 9);
  const auto lvl1 = pyramid.depth_level(1);
  ASSERT_EQ(win->colour_rgb8.size(), 3u * 8u * 9u);
  for (int r = 0; r < 8; ++r) {
    for (int c = 0; c < 9; ++c) {
      for (int ch = 0; ch < 3; ++ch) {
        EXPECT_EQ(win->colour_rgb8[static_cast<std::size_t>(3 * (r * 9 + c) + ch)],
                  lvl1->colour_rgb8[static_cast<std::size_t>(3 * ((win->row0 + r) * lvl1->depth_m.cols() + win->col0 + c) + ch)]);
      }
    }
  }
}

}  // namespace
