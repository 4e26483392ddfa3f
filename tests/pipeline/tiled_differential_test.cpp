// The tiled run against the in-core run on random scans and random configs (issue 14: "the
// result equals the in-core run"). Each seed draws a generated relief scan (hc::tools::relief:
// size, shape, relief, noise, back face, outliers, colour, order; PLY, LAS or E57) and a config
// (grid size, splat mode and radius, see-through, hole filling, upsample, the robust filter and
// its despike and far clusters, the honest check's spike limits, texture), then runs it in core
// and in tiles of a random side. The oracle is the in-core run: every layer bit for bit, the
// cross-check's figures and the honest check's counts and verdict (tiled_oracle.hpp). Where the
// in-core run stops, the tiled run stops with the same kind of error. A tiled run may instead
// stop where its halo is too narrow, with an error naming the scale key to raise (as issue 14
// asks: "a search that would leave the halo is an error naming the stage, not a silent edge");
// that is counted and printed. So is a documented difference: where the in-core run removed far
// clusters and the tiled run's whole-scan pass removed far points before the robust test, the
// tiled run's far clusters may be a subset of core's (docs/scale.md), so it may keep more points;
// then only that is checked. Together they may take at most a quarter of the seeds. Seeds with
// a known, open divergence (kKnownDivergences) are listed and not run.
//
// Seeds: HC_TILED_DIFF_SEEDS="first:count" (default 1:6, about 8 s on the 2-core VM, so that
// scripts/test keeps within its 15 minutes; .ci/run runs 7:194 after scripts/test); a failing seed prints its YAML and keeps its folder, so that
// it can be run alone.

#include "hc/common/error.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/honest_check.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/tiling.hpp"
#include "hc/tools/relief.hpp"

#include "stage_figure.hpp"
#include "test_paths.hpp"
#include "tiled_oracle.hpp"

#include <gtest/gtest.h>

#include <bit>
#include <cctype>
#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>
#include <typeinfo>
#include <numeric>
#include <vector>

#include <unistd.h>

namespace tiled_differential {
namespace {

namespace fs = std::filesystem;
using hc::pipeline::BuiltScene;
using hc::pipeline::RunConfig;

// A small deterministic generator (SplitMix64), so that a seed draws the same case on every
// machine and library version (std::uniform_*_distribution is not specified bit for bit).
class Draw {
 public:
  // The seed mixed first: consecutive seeds must not give shifted copies of one sequence.
  explicit Draw(std::uint64_t seed) : s_(seed) { s_ = bits(); }
  std::uint64_t bits() {
    std::uint64_t z = (s_ += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
  }
  double uniform(double lo, double hi) { return lo + (hi - lo) * static_cast<double>(bits() >> 11) * 0x1.0p-53; }
  int integer(int lo, int hi) { return lo + static_cast<int>(bits() % static_cast<std::uint64_t>(hi - lo + 1)); }
  bool coin(double p = 0.5) { return uniform(0.0, 1.0) < p; }

 private:
  std::uint64_t s_;
};

struct Case {
  hc::tools::ReliefSpec spec;
  std::string file;
  std::string yaml;
  std::vector<std::string> sets;  ///< dotted key=value overrides (hapticloud run --set)
  int tile_cells = 0;
};

std::string number(double v) {
  std::ostringstream o;
  o.precision(17);
  o << v;
  return o.str();
}

Case draw_case(std::uint64_t seed) {
  Draw d(seed);
  Case c;
  hc::tools::ReliefSpec& s = c.spec;
  s.seed = seed;
  s.points = static_cast<std::uint64_t>(d.integer(15'000, 90'000));
  s.width_m = d.uniform(0.3, 2.0);
  s.height_m = d.uniform(0.2, 1.2);
  s.relief_depth_m = d.coin(0.8) ? d.uniform(0.0, 0.05) : 0.0;
  s.course_m = d.uniform(0.08, 0.3);
  s.block_m = d.uniform(0.1, 0.5);
  s.chisel_amplitude_m = d.uniform(0.0, 0.001);
  s.noise_sigma_m = d.coin(0.8) ? d.uniform(0.0, 0.002) : 0.0;
  s.thickness_m = d.uniform(0.05, 0.4);
  s.back_fraction = d.coin(0.7) ? d.uniform(0.0, 0.2) : 0.0;
  s.outlier_fraction = d.coin(0.7) ? d.uniform(0.0, 0.02) : 0.0;
  s.outlier_reach_m = d.uniform(0.0, 0.5);
  s.rgb = d.coin();
  s.scan_order = d.coin(0.3);
  const int format = d.integer(0, 2);
  c.file = format == 0 ? "scan.ply" : format == 1 ? "scan.las" : "scan.e57";

  const int n = d.integer(60, 360);
  std::ostringstream y;
  y << "input: {files: [" << c.file << "], units: m}\n";
  if (d.coin(0.25)) {
    // A view tilted about x and y: the back face and the relief's flanks move in depth.
    y << "view: {rotation: {euler_deg: [" << number(d.uniform(-25, 25)) << ", " << number(d.uniform(-25, 25)) << ", "
      << number(d.uniform(-180, 180)) << "], order: xyz}}\n";
  }
  const char* modes[] = {"disc", "interpolate", "plane"};
  y << "grid: {n: " << n << ", splat_mode: " << modes[d.integer(0, 2)] << ", splat_radius_cells: " << number(d.uniform(0.6, 2.5))
    << ", see_through_depth_m: " << (d.coin(0.7) ? number(d.uniform(0.003, 0.05)) : "0")
    << ", hole_fill_max_cells: " << (d.coin(0.6) ? d.integer(1, 64) : 0);
  const int up = d.integer(0, 3);
  y << ", upsample: " << (up == 0 ? "off" : up == 1 ? "auto" : std::to_string(up)) << "}\n";
  const bool filter = d.coin(0.75);
  y << "filters: {outliers: {enabled: " << (filter ? "true" : "false");
  if (filter) {
    y << ", k: " << d.integer(6, 24) << ", local_ratio: " << number(d.uniform(2.0, 5.0))
      << ", mad_multiplier: " << number(d.uniform(2.0, 6.0)) << ", despike: " << (d.coin(0.7) ? "true" : "false")
      << ", far_clusters: {enabled: " << (d.coin(0.7) ? "true" : "false") << "}";
  }
  y << "}}\n";
  y << "cross_check: {tolerance_m: " << number(d.uniform(0.0005, 0.004)) << ", spike_min_height_m: " << number(d.uniform(0.002, 0.02))
    << ", island_max_cells: " << d.integer(1, 12) << "}\n";
  y << "layers: {texture: {sigma_space_cells: " << number(d.uniform(1.0, 4.0)) << ", sigma_range_m: " << number(d.uniform(0.001, 0.01))
    << "}}\n";
  y << "scale: {chunk_points: " << d.integer(1024, 20'000) << "}\n";
  c.tile_cells = d.integer(std::max(16, n / 10), std::max(16, n / 3));  // 9 to 100 tiles or so
  // Drawn after the above, so that adding them left the earlier draws of every seed as they
  // were; given as --set overrides (c.sets).
  auto set = [&](const std::string& key, const std::string& value) { c.sets.push_back(key + "=" + value); };
  if (d.coin(0.2)) {
    // A crop box (grid frame) cutting into the wall's sides and, at times, its back face.
    const double x0 = -0.5 * s.width_m * d.uniform(0.5, 1.2), y0 = -0.5 * s.height_m * d.uniform(0.5, 1.2);
    const double z0 = -s.thickness_m * d.uniform(0.1, 1.5);
    const double x1 = 0.5 * s.width_m * d.uniform(0.5, 1.2), y1 = 0.5 * s.height_m * d.uniform(0.5, 1.2);
    set("filters.crop.min_m", "[" + number(x0) + ", " + number(y0) + ", " + number(z0) + "]");
    set("filters.crop.max_m", "[" + number(x1) + ", " + number(y1) + ", 1]");
  }
  if (filter && d.coin(0.3)) set("filters.outliers.off_surface_ratio", d.coin(0.3) ? "0" : number(d.uniform(1.5, 4.0)));
  if (d.coin(0.3)) {
    set("cross_check.isolation_min_neighbours", std::to_string(d.integer(1, 6)));
    set("cross_check.isolation_radius_spacings", number(d.uniform(3.0, 20.0)));
  }
  if (d.coin(0.3)) set("grid.hole_fill_max_step_m", number(d.uniform(0.002, 0.05)));
  // Several bands of tiles (their strays gathered band by band), smaller tiles by the point
  // bound, a fixed filter halo (too narrow at times: then an error naming the key).
  if (d.coin(0.3)) set("scale.band_mb", number(d.uniform(0.02, 1.0)));
  if (d.coin(0.2)) set("scale.tile_max_points", std::to_string(d.integer(1000, 20'000)));
  if (d.coin(0.15)) set("scale.filter_halo_cells", std::to_string(d.integer(0, 40)));
  c.yaml = y.str();
  return c;
}

// The points a run kept after every filter: its cross-check's input (stage cross_check's
// count in, in core and tiled).
double kept_points(const BuiltScene& b) {
  for (const auto& r : b.summary.stages) {
    if (r.stage == "cross_check") return static_cast<double>(r.count_in);
  }
  ADD_FAILURE() << "no stage cross_check";
  return -1.0;
}

// The points a tiled run removed in far clusters, each once: the whole-scan pass's (stage
// tile_far_clusters) and the tiles' own, each point summed by the tile that owns it.
double tiled_far_points(const BuiltScene& b) {
  const auto or0 = [](double v) { return v > 0.0 ? v : 0.0; };  // stage_figure: -1 when absent
  return or0(hc::test::stage_figure(b, "tile_far_clusters", "removed_far_clusters")) +
         or0(hc::test::stage_figure(b, "tiles", "sum_far_points_owned"));
}

// The overrides as `--set` options, one line.
std::string sets_text(const std::vector<std::string>& sets) {
  std::string t;
  for (const std::string& v : sets) t += "--set '" + v + "' ";
  return t.empty() ? t : t + "\n";
}

// The kind of a thrown exception, for comparing the two runs' stops.
struct Stop {
  std::string type;
  std::string message;
};

// The first `most` cells where two height fields' bits differ, as "(row, col) in-core tiled"
// lines with the cell's place in its tile, for a diverging seed's report.
std::string first_differences(const hc::HeightField& a, const hc::HeightField& b, int tile_cells, std::size_t most = 12) {
  std::ostringstream o;
  if (a.values().size() != b.values().size()) return "the layers differ in size\n";
  std::size_t shown = 0, all = 0;
  for (std::size_t i = 0; i < a.values().size(); ++i) {
    if (std::bit_cast<std::uint32_t>(a.values()[i]) == std::bit_cast<std::uint32_t>(b.values()[i])) continue;
    ++all;
    if (shown++ >= most) continue;
    const std::size_t r = i / static_cast<std::size_t>(a.cols()), col = i % static_cast<std::size_t>(a.cols());
    o << "  (" << r << ", " << col << ") " << number(a.values()[i]) << " " << number(b.values()[i]) << "  tile row+"
      << r % static_cast<std::size_t>(tile_cells) << " col+" << col % static_cast<std::size_t>(tile_cells) << "\n";
  }
  o << "  " << all << " cells differ of " << a.values().size() << " (" << a.rows() << " x " << a.cols() << ")\n";
  return o.str();
}

template <class F>
std::optional<Stop> stop_of(F&& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return Stop{typeid(e).name(), e.what()};
  }
  return std::nullopt;
}

// A tiled run's refusal of a halo too narrow for a search, naming the key to raise.
bool names_a_halo_key(const std::string& message) {
  for (const char* key : {"scale.filter_halo_cells", "scale.max_gatherings", "scale.island_halo"}) {
    if (message.find(key) != std::string::npos) return true;
  }
  return false;
}

// Seeds whose tiled run is known to differ from the in-core one, each with its open finding
// (docs/scale.md, "Random scans and configs against the in-core run"): printed, not run. Remove
// a seed with the fix of its finding; a new divergent seed is a finding to fix or list here.
struct KnownDivergence {
  std::uint64_t seed;
  const char* why;
};
// None open since the sixty-fourth session (2026-11-30): seeds 121, 198, 308 and 331 were
// fixed, and 649 in the sixty-fifth (a tiled run's verdict left out the far clusters its tiles
// removed); TheSeedsThatFoundADivergenceGiveTheInCoreScene runs them in the suite.
constexpr std::array<KnownDivergence, 0> kKnownDivergences{};

const KnownDivergence* known_divergence(std::uint64_t seed) {
  for (const KnownDivergence& k : kKnownDivergences) {
    if (k.seed == seed) return &k;
  }
  return nullptr;
}

std::pair<std::uint64_t, std::uint64_t> seeds_asked() {
  std::uint64_t first = 1, count = 6;
  if (const char* e = std::getenv("HC_TILED_DIFF_SEEDS")) {
    const std::string s = e;
    const auto colon = s.find(':');
    if (colon == std::string::npos) {
      ADD_FAILURE() << "HC_TILED_DIFF_SEEDS=" << s << ": expected first:count, e.g. 1:6";
      return {1, 0};
    }
    first = std::stoull(s.substr(0, colon));
    count = std::stoull(s.substr(colon + 1));
  }
  return {first, count};
}

// What check_seeds met: scenes compared equal, stops alike, halo refusals, far-cluster subsets,
// known divergences not run.
struct Tally {
  std::size_t compared = 0, stopped_alike = 0, halo_refusals = 0, far_subset = 0, known = 0;
  std::size_t far_cells_carried = 0;  // compared scenes whose tiled run processed tiles again (or started again) for far clusters' cells
  std::size_t verdicts_kept = 0;  // of those, runs whose tiles processed again took strays' verdicts kept from the loop (no gathering)
};

// Each seed's case in core and tiled (the file's header), counted in `tally`; returns at the
// first divergent seed. (void: the gtest ASSERTs return.) `band_mb`, when given, replaces the
// tiled run's scale.band_mb (0: one tile a band, so no tile shares its points' judging).
void check_seeds(const std::vector<std::uint64_t>& seeds, Tally& tally, std::optional<double> band_mb = std::nullopt) {
  auto& [compared, stopped_alike, halo_refusals, far_subset, known, far_cells_carried, verdicts_kept] = tally;
  for (const std::uint64_t seed : seeds) {
    if (const KnownDivergence* k = known_divergence(seed)) {
      std::cout << "[ known    ] seed " << seed << " not run: " << k->why << "\n";
      ++known;
      continue;
    }
    const Case c = draw_case(seed);
    SCOPED_TRACE("seed " + std::to_string(seed) + " (HC_TILED_DIFF_SEEDS=" + std::to_string(seed) + ":1), tile_cells " +
                 std::to_string(c.tile_cells) + ", " + std::to_string(c.spec.points) + " points\n" + c.yaml + sets_text(c.sets));
    const fs::path dir = hc::test::temp_dir("tiled_diff_" + std::to_string(seed));
    (void)hc::tools::write_relief(c.spec, dir / c.file, 8192, 1);
    fs::create_directory(dir / "scratch");
    RunConfig config = hc::pipeline::parse_run_config(c.yaml, dir / "run.yaml", c.sets);
    config.scale.tiled = hc::pipeline::ScaleConfig::Tiled::kOff;
    BuiltScene in, tiled;
    const auto in_stop = stop_of([&] { in = hc::pipeline::build_scene(config); });
    config.scale.tiled = hc::pipeline::ScaleConfig::Tiled::kOn;
    config.scale.tile_cells = c.tile_cells;
    if (band_mb) config.scale.band_mb = *band_mb;
    config.scale.scratch = dir / "scratch";
    const auto tiled_stop = stop_of([&] { tiled = hc::pipeline::build_scene(config); });
    EXPECT_TRUE(fs::is_empty(dir / "scratch")) << "the spill is removed, also after a stop";
    if (in_stop) {
      ASSERT_TRUE(tiled_stop) << "the in-core run stopped (" << in_stop->message << "), the tiled run did not";
      EXPECT_EQ(in_stop->type, tiled_stop->type) << "in core: " << in_stop->message << "\ntiled: " << tiled_stop->message;
      ++stopped_alike;
    } else if (tiled_stop) {
      EXPECT_TRUE(names_a_halo_key(tiled_stop->message)) << "the tiled run stopped where the in-core run did not: " << tiled_stop->message;
      std::cout << "[ halo     ] seed " << seed << ": " << tiled_stop->message << "\n";
      ++halo_refusals;
    } else if (const double far = hc::test::stage_figure(in, "outliers", "removed_far_clusters");
               far > 0.0 && hc::test::stage_figure(tiled, "tile_far_clusters", "removed_far_clusters") > 0.0 &&
               (kept_points(tiled) > kept_points(in) || tiled_far_points(tiled) < far)) {
      // Documented (docs/scale.md, "Far clusters exact"): since the sixty-sixth session the
      // tiles' far clusters are the in-core run's among the points the tiles' robust test keeps
      // (the run starts again carrying their cells where the tiles fell short). Where the
      // whole-scan pass removed far points before any robust test, the in-core run's robust test
      // may have taken some of them first, or their absence moved a neighbour's verdict: then
      // the tiled run may keep points core removes or count fewer as far. Only then is this a
      // subset; without that pass's removals the scene and the far_points reason must be equal.
      std::cout << "[ far      ] seed " << seed << ": in core " << far << " points removed in far clusters; the tiled run kept "
                << kept_points(tiled) - kept_points(in) << " more points and removed " << tiled_far_points(tiled)
                << " as far (a subset of the far clusters)\n";
      ++far_subset;
    } else {
      ASSERT_GT(hc::test::stage_figure(tiled, "tile_plan", "tiles"), 1.0) << "the grid was cut into several tiles";
      hc::test::expect_tiled_scene_equals_in_core(in, tiled, dir / "scratch");
      if (::testing::Test::HasFailure()) {
        std::cout << "depth:\n" << first_differences(in.scene.layers.depth, tiled.scene.layers.depth, c.tile_cells);
      }
      ASSERT_TRUE(in.summary.verdict && tiled.summary.verdict && in.summary.input_check && tiled.summary.input_check);
      // Every reason alike, code and level, but far_points: the in-core run counts the far
      // clusters among the points its robust test keeps; a tiled run removes most far clusters
      // before its tiles, on every point (stage tile_far_clusters: the grid is laid out without
      // them), where core's robust test may take them first, and its tiles remove the rest (each
      // point and cluster counted by its owner). So where core warns, the tiled run warns with
      // the same counts, word for word, unless its whole-scan pass removed points too; it may
      // warn alone only when that pass removed points.
      const auto reasons = [](const hc::pipeline::Verdict& v) {
        std::vector<std::string> r;
        for (const auto& x : v.reasons) {
          if (x.code != "far_points") r.push_back(x.code + " " + x.level);
        }
        return r;
      };
      const auto far_reason = [](const hc::pipeline::Verdict& v) {
        for (const auto& x : v.reasons) {
          if (x.code == "far_points") return x.message;
        }
        return std::string();
      };
      const hc::pipeline::Verdict& vi = *in.summary.verdict;
      const hc::pipeline::Verdict& vt = *tiled.summary.verdict;
      EXPECT_EQ(reasons(vi), reasons(vt));
      const bool pass_removed = hc::test::stage_figure(tiled, "tile_far_clusters", "removed_far_clusters") > 0.0;
      if (vi.has("far_points")) {
        EXPECT_TRUE(vt.has("far_points")) << far_reason(vi);
        if (!pass_removed) {
          EXPECT_EQ(far_reason(vi), far_reason(vt));
        }
      } else if (vt.has("far_points")) {
        EXPECT_TRUE(pass_removed) << "the tiled run warns of far points the in-core run did not find: " << far_reason(vt);
      }
      if (vi.has("far_points") == vt.has("far_points")) {
        EXPECT_EQ(vi.status, vt.status);
      }
      const auto& a = *in.summary.input_check;
      const auto& b = *tiled.summary.input_check;
      hc::test::expect_same_point_classes(a, b);
      // The isolated-point test's radius comes from the scan's spacing: the robust filter's
      // sample's in both runs; without the filter, the in-core run's strided sample and the
      // tiles' median weighted by points (honest_check.hpp, median_point_spacing), which differ.
      if (config.filters.outliers.enabled) {
        EXPECT_EQ(a.spacing_m, b.spacing_m);
        EXPECT_EQ(a.isolated, b.isolated);
      }
      ++compared;
      if (hc::test::stage_figure(tiled, "tiles", "far_tiles_again") > 0.0 || hc::test::stage_figure(tiled, "tile_plan", "far_cells_carried") == 1.0) {
        ++far_cells_carried;
      }
      if (hc::test::stage_figure(tiled, "tiles", "sum_robust_strays_verdicts_kept") > 0.0) ++verdicts_kept;
    }
    if (!tiled_stop) {
      std::cout << "[ seed     ] " << seed << ": " << c.spec.points << " points, " << hc::test::stage_figure(tiled, "tile_plan", "tiles")
                << " tiles of " << c.tile_cells << " cells; " << sets_text(c.sets) << "\n";
    }
    if (::testing::Test::HasFailure()) {
      std::cout << "[ diverged ] seed " << seed << "; the scan and config are in " << dir << "\n";
      return;  // the first divergent seed is the one to look at; its folder is kept
    }
    fs::remove_all(dir);
  }
  std::cout << "[ tiled    ] " << compared << " scenes compared, " << stopped_alike << " stopped in both, " << halo_refusals
            << " tiled runs stopped naming a halo key, " << far_subset << " kept points of far clusters core removed, " << known
            << " known divergences not run; " << far_cells_carried << " of the compared processed tiles again for far clusters' cells (" << verdicts_kept
            << " taking the loop's stray verdicts)\n";
}

TEST(TiledDifferential, RandomScansAndConfigsGiveTheInCoreScene) {
  const auto [first, count] = seeds_asked();
  std::vector<std::uint64_t> seeds(count);
  std::iota(seeds.begin(), seeds.end(), first);
  Tally t;
  check_seeds(seeds, t);
  EXPECT_LE(4 * (t.halo_refusals + t.far_subset), count - t.known) << "too many of the random cases were not compared";
}

// The seeds that found the divergences fixed in the sixty-fourth session (2026-11-30), each a
// scene compared equal: 121 and 198, grid.upsample: auto whose factor the filters move (3
// against 4, 1 against 2: the tiled run now starts again with the factor of the kept points);
// 308, a stray on a node boundary that a tile's despike binned otherwise; 331, far clusters
// linked on cells from each cloud's own box.
TEST(TiledDifferential, TheSeedsThatFoundADivergenceGiveTheInCoreScene) {
  Tally t;
  check_seeds({121, 198, 308, 331, 649}, t);
  EXPECT_EQ(t.compared, 5U) << "each a scene compared (not a stop, a halo refusal or a far-cluster subset)";
}

// Seeds whose tiles removed fewer far-cluster points than the in-core run until the sixty-sixth
// session (2026-11-30): 5 (3 points core removed as far, none by the tiles; the scene alike, the
// isolated filter took them), 59 (25 points; the tiled scene kept 21 of them) and 220 (a lone
// stray in a window too sparse to judge). The merge now joins the tiles' kept points' link
// cells into the in-core far clusters, and the tiles whose windows hold their points are
// processed again, removing them: each scene and far_points reason compared equal, each run
// fixed up so. Seed 323 (found by the census as an error of an earlier form of this): after the
// fix-up the grid is laid again on the kept points, and the whole-scan pass on that grid
// removes the far point itself.
TEST(TiledDifferential, WhereTheTilesMissFarClustersTheTilesHoldingThemAreProcessedAgain) {
  Tally t;
  check_seeds({5, 59, 220}, t);
  EXPECT_EQ(t.compared, 3U) << "each a scene compared (not a far-cluster subset)";
  EXPECT_EQ(t.far_cells_carried, 3U) << "each found short at the merge and fixed up";
  Tally relaid;  // the scene's own attempt needs no fix-up: its whole-scan pass took the point
  check_seeds({323}, relaid);
  EXPECT_EQ(relaid.compared, 1U);
}

// The tiles processed again for far clusters' cells take their strays' whole-scan verdicts from
// the tile loop before (StrayVerdicts) instead of gathering them again, and their first looks
// (KeptLooks, seventy-second session) instead of running the robust test again. With scale.band_mb 0
// (one tile a band) no tile shares its judging, so the strays a tile processed again finds are
// the loop's. The oracle is the same plan through tile jobs, whose merge processes those tiles
// again gathering the strays' verdicts anew: the tiles' robust figures (each window's removals by
// reason, its strays' verdicts among them), the far points and the layers must be the same, and
// the layers the in-core run's. (Where tiles share a band, a tile processed alone judges points
// its band left to their owners, and gathers for those.)
TEST(TiledDifferential, TheTilesProcessedAgainTakeTheLoopsStrayVerdicts) {
  for (const std::uint64_t seed : {5U, 59U}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    const Case c = draw_case(seed);
    const fs::path dir = hc::test::temp_dir("tiled_diff_verdicts_" + std::to_string(seed));
    (void)hc::tools::write_relief(c.spec, dir / c.file, 8192, 1);
    std::ofstream(dir / "run.yaml") << c.yaml;
    std::vector<std::string> sets = c.sets;
    sets.push_back("scale.tiled=on");
    sets.push_back("scale.tile_cells=" + std::to_string(c.tile_cells));
    sets.push_back("scale.band_mb=0");
    RunConfig config = hc::pipeline::parse_run_config(c.yaml, dir / "run.yaml", sets);
    const BuiltScene tiled = hc::pipeline::build_scene(config);
    EXPECT_GT(hc::test::stage_figure(tiled, "tiles", "far_tiles_again"), 0.0) << "tiles processed again";
    EXPECT_GT(hc::test::stage_figure(tiled, "tiles", "sum_robust_strays_verdicts_kept"), 0.0) << "taking the loop's verdicts";
    // One tile a band: no look shares, so every tile processed again takes its first look
    // (KeptLooks) instead of running the robust test again; the oracles below ran it anew.
    EXPECT_EQ(hc::test::stage_figure(tiled, "tiles", "far_tiles_again_looks_kept"), hc::test::stage_figure(tiled, "tiles", "far_tiles_again"))
        << "every tile processed again took its kept look";
    fs::path box;
    std::optional<hc::pipeline::MergedTileRun> merged;
    for (int plans = 1; !merged && plans <= 3; ++plans) {
      const auto info = hc::pipeline::write_tile_plan(dir / "run.yaml", sets, dir / ("plan" + std::to_string(plans)), {}, box);
      for (std::size_t t = 0; t < info.tiles; ++t) hc::pipeline::run_tile_jobs(info.plan_file, {t});
      try {
        merged = hc::pipeline::merge_tile_jobs(info.plan_file);
      } catch (const hc::pipeline::GridBoxError& e) {
        box = e.box_file;
      }
    }
    ASSERT_TRUE(merged.has_value());
    const BuiltScene& jobs = merged->built;
    EXPECT_GT(hc::test::stage_figure(jobs, "tiles", "far_tiles_again"), 0.0);
    EXPECT_EQ(hc::test::stage_figure(jobs, "tiles", "sum_robust_strays_verdicts_kept"), -1.0) << "the merge gathers";
    for (const char* f : {"sum_removed_global", "sum_removed_local", "sum_removed_off_surface", "sum_removed_robust", "sum_far_points_owned",
                          "sum_removed_isolated", "far_tiles_again"}) {
      EXPECT_EQ(hc::test::stage_figure(tiled, "tiles", f), hc::test::stage_figure(jobs, "tiles", f)) << f;
    }
    hc::test::expect_same_layers(jobs.scene.layers, tiled.scene.layers);
    config.scale.tiled = hc::pipeline::ScaleConfig::Tiled::kOff;
    const BuiltScene in = hc::pipeline::build_scene(config);
    hc::test::expect_same_layers(in.scene.layers, tiled.scene.layers);
    fs::remove_all(dir);
  }
}

// Seed 59 with the cross-check and the levels table off. With grid.upsample 2 nothing reads the
// spills after the loop, so the loop drops each one once read: no tile can be processed again,
// and the run starts again carrying the far clusters' cells instead. With the case's own
// upsample: auto the kept points' factor reads them after the loop (scale.grid_on_kept_points),
// so they are kept (until the sixty-sixth session they were dropped, and that read stopped the
// run on a missing spill file) and the tiles are processed again. The oracle is the in-core run
// of the same config: the same layers, and the same far points counted.
TEST(TiledDifferential, WithoutTheCrossCheckFarClustersTheTilesMissedAreRemovedToo) {
  const Case c = draw_case(59);
  for (const char* upsample : {"2", "auto"}) {
    SCOPED_TRACE(std::string("grid.upsample ") + upsample);
    const fs::path dir = hc::test::temp_dir(std::string("tiled_diff_far_no_check_") + upsample);
    (void)hc::tools::write_relief(c.spec, dir / c.file, 8192, 1);
    std::vector<std::string> sets = c.sets;
    sets.push_back("cross_check.enabled=false");
    sets.push_back("lod.report=false");
    sets.push_back(std::string("grid.upsample=") + upsample);
    RunConfig config = hc::pipeline::parse_run_config(c.yaml, dir / "run.yaml", sets);
    config.scale.tiled = hc::pipeline::ScaleConfig::Tiled::kOff;
    const BuiltScene in = hc::pipeline::build_scene(config);
    config.scale.tiled = hc::pipeline::ScaleConfig::Tiled::kOn;
    config.scale.tile_cells = c.tile_cells;
    const BuiltScene tiled = hc::pipeline::build_scene(config);
    const bool restarted = hc::test::stage_figure(tiled, "tile_plan", "far_cells_carried") == 1.0;
    const bool fixed_up = hc::test::stage_figure(tiled, "tiles", "far_tiles_again") > 0.0;
    EXPECT_EQ(restarted, std::string(upsample) == "2");
    EXPECT_EQ(fixed_up, std::string(upsample) == "auto");
    const double far = hc::test::stage_figure(in, "outliers", "removed_far_clusters");
    ASSERT_GT(far, 0.0);
    EXPECT_EQ(tiled_far_points(tiled), far);
    hc::test::expect_same_layers(in.scene.layers, tiled.scene.layers);
    fs::remove_all(dir);
  }
}

// Seed 59 through tile jobs (write_tile_plan, run_tile_jobs, merge_tile_jobs): the tiles miss
// far clusters, and tile-merge processes the tiles holding them again itself, replacing their
// results and kept masks, so the merged scene is the in-core run's (the oracle: the in-core run's
// layers and far count). A second merge of the same plan finds nothing short and gives the same
// scene without processing a tile (the replaced parts and masks agree).
TEST(TiledDifferential, ThroughTileJobsFarClustersTheTilesMissedAreRemovedByTheMerge) {
  const std::uint64_t seed = 59;
  const Case c = draw_case(seed);
  const fs::path dir = hc::test::temp_dir("tiled_diff_jobs_far");
  (void)hc::tools::write_relief(c.spec, dir / c.file, 8192, 1);
  std::ofstream(dir / "run.yaml") << c.yaml;
  RunConfig config = hc::pipeline::parse_run_config(c.yaml, dir / "run.yaml", c.sets);
  config.scale.tiled = hc::pipeline::ScaleConfig::Tiled::kOff;
  const BuiltScene in = hc::pipeline::build_scene(config);
  const double far = hc::test::stage_figure(in, "outliers", "removed_far_clusters");
  ASSERT_GT(far, 0.0);
  std::vector<std::string> sets = c.sets;
  sets.push_back("scale.tiled=on");
  sets.push_back("scale.tile_cells=" + std::to_string(c.tile_cells));
  fs::path box;
  std::optional<hc::pipeline::MergedTileRun> merged;
  fs::path plan_file;
  std::size_t tiles = 0;
  for (int plans = 1; !merged && plans <= 3; ++plans) {
    const auto info = hc::pipeline::write_tile_plan(dir / "run.yaml", sets, dir / ("plan" + std::to_string(plans)), {}, box);
    for (std::size_t t = 0; t < info.tiles; ++t) hc::pipeline::run_tile_jobs(info.plan_file, {t});
    try {
      merged = hc::pipeline::merge_tile_jobs(info.plan_file);
      plan_file = info.plan_file;
      tiles = info.tiles;
    } catch (const hc::pipeline::GridBoxError& e) {
      box = e.box_file;
    }
  }
  ASSERT_TRUE(merged.has_value());
  // The far-points reason (its counts of points and clusters) and the honest check's point
  // classes, which read the kept masks the merge replaced.
  const auto far_reason = [](const BuiltScene& b) {
    for (const auto& x : b.summary.verdict->reasons) {
      if (x.code == "far_points") return x.message;
    }
    return std::string();
  };
  const auto same_as_in_core = [&](const BuiltScene& b) {
    EXPECT_EQ(tiled_far_points(b), far);
    hc::test::expect_same_layers(in.scene.layers, b.scene.layers);
    ASSERT_TRUE(in.summary.input_check && b.summary.input_check && in.summary.verdict && b.summary.verdict);
    hc::test::expect_same_point_classes(*in.summary.input_check, *b.summary.input_check);
    EXPECT_EQ(far_reason(in), far_reason(b));
  };
  EXPECT_GT(hc::test::stage_figure(merged->built, "tiles", "far_tiles_again"), 0.0) << "the merge processed tiles again";
  EXPECT_EQ(hc::test::stage_figure(merged->built, "tiles", "exact_far_points"), far);
  same_as_in_core(merged->built);
  const fs::path work = plan_file.parent_path();
  EXPECT_FALSE(fs::exists(work / "far_fixup.json"));
  {
    // A tile job's attempt still running on this host (its temporary kept file, named with this
    // host and this live process): a merge that would process tiles again waits, naming it.
    for (std::size_t t = 0; t < tiles; ++t) hc::pipeline::run_tile_jobs(plan_file, {t});  // the first results back
    char host[256] = {0};
    ASSERT_EQ(::gethostname(host, sizeof host - 1), 0);
    std::string h;
    for (const char* ch = host; *ch; ++ch) h.push_back(std::isalnum(static_cast<unsigned char>(*ch)) ? *ch : '_');
    const fs::path live = work / (".kept-job-" + h + "-" + std::to_string(::getpid()) + "-0123456789abcdef-0.bin");
    std::ofstream(live) << "x";
    try {
      (void)hc::pipeline::merge_tile_jobs(plan_file);
      ADD_FAILURE() << "the merge went on beside a running attempt";
    } catch (const hc::InputError& e) {
      EXPECT_NE(std::string(e.what()).find("still running"), std::string::npos) << e.what();
    }
    EXPECT_TRUE(fs::exists(live)) << "a running attempt's file is left";
    EXPECT_FALSE(fs::exists(work / "far_fixup.json")) << "nothing replaced, no fix-up under way";
    fs::remove(live);
    const hc::pipeline::MergedTileRun fixed = hc::pipeline::merge_tile_jobs(plan_file);
    EXPECT_GT(hc::test::stage_figure(fixed.built, "tiles", "far_tiles_again"), 0.0);
    same_as_in_core(fixed.built);
  }
  {
    SCOPED_TRACE("a second merge");
    const hc::pipeline::MergedTileRun again = hc::pipeline::merge_tile_jobs(plan_file);
    EXPECT_EQ(hc::test::stage_figure(again.built, "tiles", "far_tiles_again"), -1.0) << "nothing left short (no such figure)";
    same_as_in_core(again.built);
  }
  // A merge stopped while processing tiles again (here: a spill file missing when the fix-up
  // reads the spills, after the tile jobs were run again and gave their first results back)
  // leaves far_fixup.json; the next merge takes the cells from it.
  for (std::size_t t = 0; t < tiles; ++t) hc::pipeline::run_tile_jobs(plan_file, {t});
  fs::rename(work / "tile_0.bin", work / "tile_0.bin.away");
  EXPECT_THROW((void)hc::pipeline::merge_tile_jobs(plan_file), hc::InputError);
  EXPECT_TRUE(fs::exists(work / "far_fixup.json"));
  fs::rename(work / "tile_0.bin.away", work / "tile_0.bin");
  {
    SCOPED_TRACE("the merge after one stopped");
    const hc::pipeline::MergedTileRun resumed = hc::pipeline::merge_tile_jobs(plan_file);
    const auto& notes = resumed.built.summary.stages;
    EXPECT_TRUE(std::any_of(notes.begin(), notes.end(), [](const hc::pipeline::StageReport& r) {
      return std::any_of(r.notes.begin(), r.notes.end(), [](const std::string& n) { return n.find("far_fixup.json") != std::string::npos; });
    }));
    EXPECT_GT(hc::test::stage_figure(resumed.built, "tiles", "far_tiles_again"), 0.0);
    same_as_in_core(resumed.built);
  }
  EXPECT_FALSE(fs::exists(work / "far_fixup.json"));
  fs::remove_all(dir);
}

// Seed 121 with scale.grid_on_kept_points: false: no attempt starts again, so the tiled scene
// keeps the factor chosen from every point, and the run says that the in-core run (the oracle:
// its reproject's factor) takes another one, instead of differing silently.
TEST(TiledDifferential, WithTheKeptPointsCheckOffAFactorTheFiltersMoveIsAWarning) {
  const Case c = draw_case(121);
  const fs::path dir = hc::test::temp_dir("tiled_diff_factor_warning");
  (void)hc::tools::write_relief(c.spec, dir / c.file, 8192, 1);
  RunConfig config = hc::pipeline::parse_run_config(c.yaml, dir / "run.yaml", c.sets);
  config.scale.tiled = hc::pipeline::ScaleConfig::Tiled::kOff;
  const BuiltScene in = hc::pipeline::build_scene(config);
  config.scale.tiled = hc::pipeline::ScaleConfig::Tiled::kOn;
  config.scale.tile_cells = c.tile_cells;
  config.scale.grid_on_kept_points = false;
  const BuiltScene tiled = hc::pipeline::build_scene(config);
  const double k_core = hc::test::stage_figure(in, "reproject", "upsample_factor");
  const double k_tiled = hc::test::stage_figure(tiled, "tile_plan", "upsample_factor");
  ASSERT_NE(k_core, k_tiled) << "the case moves the factor";
  const std::string want = "grid.upsample: auto gives the kept points factor " + std::to_string(static_cast<int>(k_core)) + ", not " +
                           std::to_string(static_cast<int>(k_tiled));
  EXPECT_EQ(std::count_if(tiled.summary.warnings.begin(), tiled.summary.warnings.end(),
                          [&](const std::string& w) { return w.find(want) != std::string::npos; }),
            1)
      << want;
  EXPECT_EQ(hc::test::stage_figure(tiled, "tiles", "upsample_factor_reads"), 1.0) << "one read, the warning's: no attempt checks with the key false";
  fs::remove_all(dir);
}

// The same two upsample cases through tile jobs (write_tile_plan, run_tile_jobs, merge_tile_jobs):
// the first plan's merge finds that the kept points take another factor and writes a grid box
// with it (GridBoxError); a plan on that box (--grid-box) merges to the in-core scene.
TEST(TiledDifferential, ThroughTileJobsAFactorTheFiltersMoveIsFoundAndAPlanWithItGivesTheInCoreScene) {
  for (const std::uint64_t seed : {121U, 198U}) {
    const Case c = draw_case(seed);
    SCOPED_TRACE("seed " + std::to_string(seed));
    const fs::path dir = hc::test::temp_dir("tiled_diff_jobs_" + std::to_string(seed));
    (void)hc::tools::write_relief(c.spec, dir / c.file, 8192, 1);
    std::ofstream(dir / "run.yaml") << c.yaml;
    RunConfig config = hc::pipeline::parse_run_config(c.yaml, dir / "run.yaml", c.sets);
    config.scale.tiled = hc::pipeline::ScaleConfig::Tiled::kOff;
    const BuiltScene in = hc::pipeline::build_scene(config);
    std::vector<std::string> sets = c.sets;
    sets.push_back("scale.tiled=on");
    sets.push_back("scale.tile_cells=" + std::to_string(c.tile_cells));
    fs::path box;
    std::optional<hc::pipeline::MergedTileRun> merged;
    int plans = 0;
    while (!merged && plans < 3) {
      ++plans;
      const auto info = hc::pipeline::write_tile_plan(dir / "run.yaml", sets, dir / ("plan" + std::to_string(plans)), {}, box);
      for (std::size_t t = 0; t < info.tiles; ++t) hc::pipeline::run_tile_jobs(info.plan_file, {t});
      try {
        merged = hc::pipeline::merge_tile_jobs(info.plan_file);
      } catch (const hc::pipeline::GridBoxError& e) {
        const std::string what = e.what();
        EXPECT_NE(what.find("moved the upsample coverage"), std::string::npos) << what;
        box = e.box_file;
      }
    }
    ASSERT_TRUE(merged.has_value());
    EXPECT_EQ(plans, 2) << "one plan on every point's factor, one on the kept points'";
    EXPECT_EQ(hc::test::stage_figure(merged->built, "tile_plan", "upsample_factor"), hc::test::stage_figure(in, "reproject", "upsample_factor"));
    hc::test::expect_same_layers(in.scene.layers, merged->built.scene.layers);
    fs::remove_all(dir);
  }
}

}  // namespace
}  // namespace tiled_differential
