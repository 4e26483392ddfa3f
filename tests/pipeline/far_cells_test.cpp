// detail::FarCells (far_cells.hpp), the tiled run's far clusters found tile by tile, against a
// flood fill over every occupied cell of the whole scan at once (written here from the rule:
// floor((p − origin)/E) per axis clamped to [0, 2^21 − 1], 26-neighbour linkage, the main body
// the component of most points, far when its box is more than far_m from the main body's box,
// removed when also at most `small` points; boxes of the points in doubles). Its link-cell mode
// (link_key, add_cell: the tiled run's merge) against the in-core remove_far_clusters itself.
//
// The scene (grid frame, metres): a carved wall 2 m × 1 m in 8 × 4 tiles of 0.25 m, and about
// it the cases the joining along tile edges must get right: a small far cluster on a corner
// where four tiles meet; a U whose two arms lie in different tile columns and meet only in the
// last row of tiles (one cluster, known only after the last row); a large far cluster (kept,
// noted); a small cluster near the wall (not far); isolated far points; points clamped to the
// first cell index; pairs of points across a tile edge that cuts a cell. Each tile's points
// come shuffled, in three batches. Run with cells much smaller than a tile and with cells larger
// than a tile (a cell's neighbours then lie two tiles away, which the frontier's eviction must
// allow for). Each bound of the frontier and of the look-up, narrowed by one index, fails a
// test here (checked by hand, 2026-11-26).

#include "far_cells.hpp"

#include "hc/common/format.hpp"
#include "hc/pipeline/robust_outliers.hpp"
#include "stage_util.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <map>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

using hc::format_number;
using hc::pipeline::detail::FarCells;
using Key = std::array<std::int64_t, 3>;

constexpr double kTile = 0.25;
constexpr int kTilesC = 8, kTilesR = 4;
// The cells' origin: off the tiles' lattice, so that tile edges cut cells.
const Eigen::Vector3d kOrigin(-0.0037, -0.0041, -1.0);

struct Scene {
  std::vector<Eigen::Vector3d> points;
};

Scene carved_wall_with_clusters() {
  Scene s;
  std::mt19937_64 rng(20261126);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.0005);
  auto add = [&](double x, double y, double z) { s.points.emplace_back(x, y, z); };
  // The wall: 80 000 points, carved relief up to 1 cm.
  for (int i = 0; i < 80000; ++i) {
    const double x = 2.0 * u(rng), y = u(rng);
    add(x, y, 0.01 * std::sin(9.0 * x) * std::cos(7.0 * y) + noise(rng));
  }
  // A: 50 points 0.5 m in front of the wall about (0.5, 0.5), where four tiles meet.
  for (int i = 0; i < 50; ++i) add(0.5 + 0.02 * (u(rng) - 0.5), 0.5 + 0.02 * (u(rng) - 0.5), 0.5 + 0.005 * u(rng));
  // U: arms at x = 1.55 and 1.95 (tile columns 6 and 7) from y = 0.05 to 0.9, joined at y = 0.9
  // (tile row 3), 0.3 m in front of the wall, a point every 3 mm.
  for (double y = 0.05; y <= 0.9; y += 0.003) {
    add(1.55, y, 0.3);
    add(1.95, y, 0.3);
  }
  for (double x = 1.55; x <= 1.95; x += 0.003) add(x, 0.9, 0.3);
  // B: 5 000 points 0.6 m behind the wall about (1.25, 0.25): far, too large to remove.
  for (int i = 0; i < 5000; ++i) add(1.25 + 0.1 * (u(rng) - 0.5), 0.25 + 0.1 * (u(rng) - 0.5), -0.6 + 0.01 * u(rng));
  // C: 30 points 4 cm in front of the wall: not far.
  for (int i = 0; i < 30; ++i) add(0.9 + 0.01 * u(rng), 0.7 + 0.01 * u(rng), 0.04 + 0.002 * u(rng));
  // Isolated points 2 m in front, anywhere over the wall.
  for (int i = 0; i < 12; ++i) add(2.0 * u(rng), u(rng), 2.0 + 0.5 * u(rng));
  // Pairs of points 0.6-0.75 m in front, about 1 cm apart across a tile edge (x = 0.5, or
  // y = 0.5) that cuts cell 50 (kOrigin is not on the tiles' lattice). In the first of each
  // kind, one point lies in cell 49 and the other in cell 50's part past the edge: one cluster
  // only if the frontier keeps the cells one index before a tile's last. In the second, one
  // lies in cell 50's part before the edge and the other in cell 51: one cluster only if a
  // tile looks up its cells one index past its first.
  add(0.492, 0.6, 0.6);
  add(0.503, 0.6, 0.6);
  add(1.1, 0.492, 0.7);
  add(1.1, 0.503, 0.7);
  add(0.498, 0.6, 0.65);
  add(0.5075, 0.6, 0.65);
  add(1.3, 0.498, 0.75);
  add(1.3, 0.5075, 0.75);
  // Points left of and below the cells' origin: clamped to index 0.
  add(-0.4, 0.1, 0.8);
  add(-0.3, 0.1, 0.8);
  add(0.1, -0.2, 0.8);
  return s;
}

int tile_col(const Eigen::Vector3d& p) { return std::clamp(static_cast<int>(std::floor(p.x() / kTile)), 0, kTilesC - 1); }
int tile_row(const Eigen::Vector3d& p) { return std::clamp(static_cast<int>(std::floor(p.y() / kTile)), 0, kTilesR - 1); }

// ---- The oracle: every occupied cell at once, flood fill. ----

struct OracleCell {
  std::uint64_t count = 0;
  std::array<double, 3> lo{INFINITY, INFINITY, INFINITY}, hi{-INFINITY, -INFINITY, -INFINITY};
};

struct Oracle {
  std::size_t cells = 0, clusters = 0, removed_clusters = 0, kept_far_clusters = 0;
  std::uint64_t removed_points = 0;
  Eigen::Vector3d main_lo, main_hi;
  std::vector<std::string> notes;
  std::set<Key> removed_cells;
};

Key cell_of(const Eigen::Vector3d& p, const Eigen::Vector3d& origin, double edge) {
  Key k;
  for (int a = 0; a < 3; ++a) {
    const double i = std::floor((p[a] - origin[a]) / edge);
    k[static_cast<std::size_t>(a)] = static_cast<std::int64_t>(std::clamp(i, 0.0, double((1 << 21) - 1)));
  }
  return k;
}

Oracle flood_fill(const Scene& s, const Eigen::Vector3d& origin, double edge, std::uint64_t small, double far_m) {
  std::map<Key, OracleCell> cells;
  for (const Eigen::Vector3d& p : s.points) {
    OracleCell& c = cells[cell_of(p, origin, edge)];
    ++c.count;
    for (std::size_t a = 0; a < 3; ++a) {
      const double v = p[static_cast<int>(a)];
      c.lo[a] = std::min(c.lo[a], v);
      c.hi[a] = std::max(c.hi[a], v);
    }
  }
  struct Comp {
    std::uint64_t count = 0;
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(INFINITY), hi = Eigen::Vector3d::Constant(-INFINITY);
    std::vector<Key> members;
  };
  std::vector<Comp> comps;  // in order of their least cell (the map's order is the key order)
  std::set<Key> seen;
  for (const auto& [start, unused] : cells) {
    if (seen.count(start)) continue;
    Comp c;
    std::vector<Key> todo{start};
    seen.insert(start);
    while (!todo.empty()) {
      const Key k = todo.back();
      todo.pop_back();
      c.members.push_back(k);
      const OracleCell& oc = cells.at(k);
      c.count += oc.count;
      for (int a = 0; a < 3; ++a) {
        c.lo[a] = std::min(c.lo[a], oc.lo[static_cast<std::size_t>(a)]);
        c.hi[a] = std::max(c.hi[a], oc.hi[static_cast<std::size_t>(a)]);
      }
      for (int dx = -1; dx <= 1; ++dx)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dz = -1; dz <= 1; ++dz) {
            const Key n{k[0] + dx, k[1] + dy, k[2] + dz};
            if (cells.count(n) && !seen.count(n)) {
              seen.insert(n);
              todo.push_back(n);
            }
          }
    }
    comps.push_back(std::move(c));
  }
  Oracle o;
  o.cells = cells.size();
  o.clusters = comps.size();
  std::size_t main = 0;
  for (std::size_t q = 1; q < comps.size(); ++q)
    if (comps[q].count > comps[main].count) main = q;
  o.main_lo = comps[main].lo;
  o.main_hi = comps[main].hi;
  for (std::size_t q = 0; q < comps.size(); ++q) {
    if (q == main) continue;
    const Comp& c = comps[q];
    double sq = 0.0;
    for (int a = 0; a < 3; ++a) {
      const double d = std::max({c.lo[a] - o.main_hi[a], o.main_lo[a] - c.hi[a], 0.0});
      sq += d * d;
    }
    const double gap = std::sqrt(sq);
    if (!(gap > far_m)) continue;
    const bool remove = c.count <= small;
    (remove ? o.removed_clusters : o.kept_far_clusters) += 1;
    if (remove) {
      o.removed_points += c.count;
      o.removed_cells.insert(c.members.begin(), c.members.end());
    }
    if (o.notes.size() < 20) {
      const Eigen::Vector3d m = 0.5 * (c.lo + c.hi);
      o.notes.push_back(std::string(remove ? "removed far cluster: " : "kept far cluster (too large to remove): ") +
                        std::to_string(c.count) + " points in a box centred at (" + format_number(m.x()) + ", " +
                        format_number(m.y()) + ", " + format_number(m.z()) + ") m (grid frame), " + format_number(gap) +
                        " m from the main body's box");
    }
  }
  return o;
}

// ---- The tile-by-tile run, as the tiled run feeds it. ----

// Tiles row by row, as the tiled run feeds them: each tile's own points, shuffled, in three
// batches of add_points.
void feed_tiles(const Scene& s, FarCells& cells) {
  std::mt19937_64 rng(7);
  for (int r = 0; r < kTilesR; ++r) {
    for (int c = 0; c < kTilesC; ++c) {
      std::vector<Eigen::Vector3d> own;
      for (const Eigen::Vector3d& p : s.points)
        if (tile_row(p) == r && tile_col(p) == c) own.push_back(p);
      std::shuffle(own.begin(), own.end(), rng);
      std::vector<double> xyz;
      for (const Eigen::Vector3d& p : own) xyz.insert(xyz.end(), {p.x(), p.y(), p.z()});
      cells.begin_tile(r);
      const std::size_t n = own.size(), cut1 = n / 3, cut2 = 2 * n / 3;
      cells.add_points(xyz.data(), cut1);
      cells.add_points(xyz.data() + 3 * cut1, cut2 - cut1);
      cells.add_points(xyz.data() + 3 * cut2, n - cut2);
      cells.end_tile();
    }
  }
}

void expect_same_as_flood_fill(double edge, double far_m, std::uint64_t small) {
  const Scene s = carved_wall_with_clusters();
  const Eigen::Vector3d origin = kOrigin;
  const Oracle o = flood_fill(s, origin, edge, small, far_m);

  FarCells cells(origin, edge, small);
  feed_tiles(s, cells);
  const FarCells::Result fc = cells.components(far_m);

  SCOPED_TRACE("edge " + format_number(edge) + " m");
  EXPECT_EQ(fc.cells, o.cells);
  EXPECT_EQ(fc.clusters, o.clusters);
  EXPECT_EQ(fc.removed_clusters, o.removed_clusters);
  EXPECT_EQ(fc.kept_far_clusters, o.kept_far_clusters);
  EXPECT_EQ(fc.removed_points, o.removed_points);
  EXPECT_EQ(fc.main_lo, o.main_lo);
  EXPECT_EQ(fc.main_hi, o.main_hi);
  EXPECT_EQ(fc.notes, o.notes);
  std::size_t held = 0, wrong = 0;
  for (const Eigen::Vector3d& p : s.points) {
    const bool far = o.removed_cells.count(cell_of(p, origin, edge)) > 0;
    held += far ? 1 : 0;
    wrong += cells.holds(p.data()) != far ? 1 : 0;
  }
  EXPECT_EQ(wrong, 0U);
  EXPECT_EQ(held, o.removed_points);
}

TEST(FarCells, TileByTileFindsTheWholeScansComponentsWithCellsSmallerThanATile) {
  // E = 1 cm: 25 × 25 cells a tile.
  expect_same_as_flood_fill(0.01, 0.1, 1000);
  // The cases the scene was built for, counted by hand: removed are A, the U (one cluster,
  // though its arms meet only in the last row of tiles), the 12 isolated points (in cells
  // apart), the four pairs across tile edges and the 3 clamped points (two share a cell: 2
  // clusters); B is far and kept.
  const Scene s = carved_wall_with_clusters();
  FarCells cells(kOrigin, 0.01, 1000);
  feed_tiles(s, cells);
  const FarCells::Result fc = cells.components(0.1);
  EXPECT_EQ(fc.kept_far_clusters, 1U);
  EXPECT_EQ(fc.removed_clusters, 1U + 1U + 12U + 4U + 2U);
  // Bounded by a tile, not by the scan: the frontier held a fraction of the cells.
  EXPECT_LT(fc.frontier_cells_peak, fc.cells / 4);
}

TEST(FarCells, TileByTileFindsTheWholeScansComponentsWithCellsLargerThanATile) {
  // E = 30 cm > a tile's 25 cm: a cell's neighbours reach two tiles away.
  expect_same_as_flood_fill(0.3, 0.35, 1000);
  // E = 60 cm, the small limit above the U's and A's points.
  expect_same_as_flood_fill(0.6, 0.7, 6000);
}

// The merge's use (tiled_run.cpp, exact_far_clusters): each tile's own points reduced to its
// link cells (link_key at the link, count, box), fed whole in row order. The oracle is the
// in-core step, remove_far_clusters on the whole cloud at the same link: the points in the far
// keys' cells are exactly the ones it removes, and the counts agree. The scene lies partly at
// negative coordinates (the clamped points), which link_key's shift must carry. A tile's cells
// are fed in shuffled order, one key twice (two half cells), as add_cell allows.
TEST(FarCells, LinkCellsFedWholeGiveTheInCoreFarClusters) {
  const Scene s = carved_wall_with_clusters();
  for (const double link : {0.01, 0.004}) {
    SCOPED_TRACE("link " + format_number(link) + " m");
    hc::pipeline::Cloud cloud;
    cloud.xyz.resize(3, static_cast<Eigen::Index>(s.points.size()));
    for (std::size_t i = 0; i < s.points.size(); ++i) cloud.xyz.col(static_cast<Eigen::Index>(i)) = s.points[i];
    hc::pipeline::FarClusterOptions o;
    o.max_points = 1000;
    o.max_fraction = 0.0;
    o.far_distance_m = 0.1;
    hc::pipeline::RemovedPoints removed;
    const auto in_core = hc::pipeline::remove_far_clusters(cloud, link, o, nullptr, 0, &removed);
    ASSERT_GT(removed.size(), 100U) << "the scene's far clusters";

    FarCells cells(Eigen::Vector3d::Zero(), link, 1000);
    std::mt19937_64 rng(11);
    for (int r = 0; r < kTilesR; ++r) {
      for (int c = 0; c < kTilesC; ++c) {
        struct Cell {
          std::uint64_t count = 0;
          double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        };
        std::map<std::uint64_t, Cell> own;
        for (const Eigen::Vector3d& p : s.points) {
          if (tile_row(p) != r || tile_col(p) != c) continue;
          const std::uint64_t k = FarCells::link_key(p.data(), 1.0 / link);
          ASSERT_NE(k, FarCells::kNoKey);
          Cell& q = own[k];
          ++q.count;
          for (int a = 0; a < 3; ++a) {
            q.lo[a] = std::min(q.lo[a], p[a]);
            q.hi[a] = std::max(q.hi[a], p[a]);
          }
        }
        std::vector<std::pair<std::uint64_t, Cell>> list(own.begin(), own.end());
        std::shuffle(list.begin(), list.end(), rng);
        cells.begin_tile(r);
        for (std::size_t i = 0; i < list.size(); ++i) {
          const auto& [k, q] = list[i];
          if (i == 0 && q.count >= 2) {  // one cell in two halves: the same box, the count split
            cells.add_cell(k, 1, q.lo, q.hi);
            cells.add_cell(k, static_cast<std::uint32_t>(q.count - 1), q.lo, q.hi);
          } else {
            cells.add_cell(k, static_cast<std::uint32_t>(q.count), q.lo, q.hi);
          }
        }
        cells.end_tile();
      }
    }
    const FarCells::Result fc = cells.components(0.1);
    EXPECT_EQ(fc.removed_points, removed.size());
    EXPECT_EQ(static_cast<double>(fc.removed_clusters), hc::pipeline::detail::figure_of(in_core.report, "far_clusters", -1.0));
    const FarCells::FarCellList list = cells.far_cells();
    const std::vector<std::uint64_t>& far = list.keys;
    EXPECT_TRUE(std::is_sorted(far.begin(), far.end()));
    ASSERT_EQ(list.cluster.size(), far.size());
    // The clusters: the in-core run's numbers (in the order of their first points) map one to
    // one onto these (in the order of their least cells).
    std::map<std::uint32_t, std::uint32_t> ours_of_core;
    std::set<std::uint32_t> ours;
    for (std::size_t j = 0; j < removed.size(); ++j) {
      const auto at = std::lower_bound(far.begin(), far.end(), FarCells::link_key(s.points[removed.at[j]].data(), 1.0 / link));
      ASSERT_TRUE(at != far.end());
      const std::uint32_t c = list.cluster[static_cast<std::size_t>(at - far.begin())];
      EXPECT_EQ(ours_of_core.emplace(removed.cluster[j], c).first->second, c) << "one in-core cluster, one of ours";
      ours.insert(c);
    }
    EXPECT_EQ(ours.size(), ours_of_core.size()) << "and one of ours, one in-core cluster";
    EXPECT_EQ(ours.size(), fc.removed_clusters);
    std::set<std::size_t> gone(removed.at.begin(), removed.at.end());
    std::size_t wrong = 0;
    for (std::size_t i = 0; i < s.points.size(); ++i) {
      const bool in_far = std::binary_search(far.begin(), far.end(), FarCells::link_key(s.points[i].data(), 1.0 / link));
      wrong += in_far != (gone.count(i) > 0) ? 1U : 0U;
    }
    EXPECT_EQ(wrong, 0U);
    EXPECT_EQ(fc.box_lo, Eigen::Vector3d(-0.4, -0.2, cloud.xyz.row(2).minCoeff()));
  }
  // Beyond the shifted 21 bits, and not finite: no key.
  const double big[3] = {0.0, 2.0e6, 0.0}, nan[3] = {std::nan(""), 0.0, 0.0};
  EXPECT_EQ(FarCells::link_key(big, 1.0), FarCells::kNoKey);
  EXPECT_EQ(FarCells::link_key(nan, 1.0), FarCells::kNoKey);
  const double edge[3] = {-1048576.0, 1048575.5, 0.0};
  EXPECT_NE(FarCells::link_key(edge, 1.0), FarCells::kNoKey);
  // floor, not truncation, below 0: -0.5 and -1 share cell -1, 0 is the next.
  const double a[3] = {-0.5, 0.0, 0.0}, b[3] = {-1.0, 0.0, 0.0}, c[3] = {0.0, 0.0, 0.0};
  EXPECT_EQ(FarCells::link_key(a, 1.0), FarCells::link_key(b, 1.0));
  EXPECT_EQ(FarCells::link_key(c, 1.0), FarCells::link_key(a, 1.0) + (std::uint64_t{1} << 42));
  // One way of feeding per FarCells; holds() only for points fed.
  FarCells fed(Eigen::Vector3d::Zero(), 0.01, 10);
  fed.begin_tile(0);
  const double lo[3] = {0, 0, 0};
  fed.add_cell(FarCells::link_key(lo, 100.0), 1, lo, lo);
  EXPECT_THROW(fed.add_points(lo, 1), std::logic_error);
  fed.end_tile();
  (void)fed.components(1.0);
  EXPECT_THROW((void)fed.holds(lo), std::logic_error);
}

TEST(FarCells, RefusesTilesOutOfRowOrderAndABadEdge) {
  FarCells cells(Eigen::Vector3d::Zero(), 0.01, 10);
  const double p[3] = {0.0, 0.0, 0.0};
  EXPECT_THROW(cells.add_points(p, 1), std::logic_error) << "points outside a tile";
  EXPECT_THROW(cells.end_tile(), std::logic_error) << "no tile begun";
  cells.begin_tile(1);
  EXPECT_THROW(cells.begin_tile(1), std::logic_error) << "the tile before not ended";
  cells.add_points(p, 1);
  EXPECT_THROW((void)cells.components(1.0), std::logic_error) << "the last tile not ended";
  cells.end_tile();
  EXPECT_THROW(cells.begin_tile(0), std::logic_error) << "a row before the last";
  (void)cells.components(1.0);
  EXPECT_THROW(cells.begin_tile(1), std::logic_error) << "after components()";
  EXPECT_THROW(FarCells(Eigen::Vector3d::Zero(), 0.0, 10), std::invalid_argument);
  EXPECT_THROW(FarCells(Eigen::Vector3d::Zero(), std::nan(""), 10), std::invalid_argument);
}

}  // namespace
