// Far clusters found tile by tile (far_cells.hpp).

#include "far_cells.hpp"

#include "hc/common/format.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>

namespace hc::pipeline::detail {

namespace {

std::uint64_t pack(std::int64_t x, std::int64_t y, std::int64_t z) {
  return (static_cast<std::uint64_t>(x) << 42) | (static_cast<std::uint64_t>(y) << 21) | static_cast<std::uint64_t>(z);
}
constexpr std::int64_t kMax = (std::int64_t{1} << 21) - 1;
std::int64_t x_of(std::uint64_t k) { return static_cast<std::int64_t>(k >> 42); }
std::int64_t y_of(std::uint64_t k) { return static_cast<std::int64_t>((k >> 21) & static_cast<std::uint64_t>(kMax)); }
std::int64_t z_of(std::uint64_t k) { return static_cast<std::int64_t>(k & static_cast<std::uint64_t>(kMax)); }

}  // namespace

FarCells::FarCells(const Eigen::Vector3d& origin_m, double edge_m, std::uint64_t small_points)
    : origin_(origin_m), edge_(edge_m), inv_(1.0 / edge_m), small_(small_points),
      far_filter_(std::size_t{1} << (kFilterBits - 6), 0) {
  if (!(std::isfinite(edge_m) && edge_m > 0.0)) {
    throw std::invalid_argument("FarCells: the cells' edge must be finite and positive, got " + format_number(edge_m) + " m");
  }
}

std::uint64_t FarCells::key(const double* p) const {
  std::int64_t c[3];
  for (int a = 0; a < 3; ++a) {
    // ⌊f⌋ clamped to [0, kMax], without std::floor (a library call on the baseline x86-64
    // target, three a point here): below 0 (or NaN) 0, from kMax on kMax, else the truncation,
    // which is the floor of a value ≥ 0.
    const double f = (p[a] - origin_[a]) * inv_;
    c[a] = !(f >= 0.0) ? 0 : f >= static_cast<double>(kMax) ? kMax : static_cast<std::int64_t>(f);
  }
  return pack(c[0], c[1], c[2]);
}

std::uint32_t FarCells::find(std::uint32_t a) {
  while (parent_[a] != a) a = parent_[a] = parent_[parent_[a]];
  return a;
}

void FarCells::join(std::uint32_t a, std::uint32_t b) {
  std::uint32_t ra = find(a), rb = find(b);
  if (ra == rb) return;
  // The root keeps the longer list, so a key is copied O(log) times at most.
  if (listed_cells_[ra].size() < listed_cells_[rb].size()) std::swap(ra, rb);
  parent_[rb] = ra;
  Comp& x = comps_[ra];
  const Comp& y = comps_[rb];
  x.count += y.count;
  x.least_key = std::min(x.least_key, y.least_key);
  for (int i = 0; i < 3; ++i) {
    x.lo[i] = std::min(x.lo[i], y.lo[i]);
    x.hi[i] = std::max(x.hi[i], y.hi[i]);
  }
  std::vector<std::uint64_t>& keep = listed_cells_[ra];
  std::vector<std::uint64_t>& gone = listed_cells_[rb];
  if (x.count <= small_) {
    keep.insert(keep.end(), gone.begin(), gone.end());
  } else {  // too large to be removed: neither list is needed
    listed_ -= keep.size() + gone.size();
    std::vector<std::uint64_t>().swap(keep);
  }
  std::vector<std::uint64_t>().swap(gone);
}

void FarCells::evict_before_row() {
  // Every cell of a later row has a y index >= y_seen_max_ (the class comment): a frontier cell
  // below y_seen_max_ - 1 can neighbour none of them.
  if (y_seen_max_ < 2) return;
  const std::uint64_t least = y_seen_max_ - 1;
  for (auto it = frontier_.begin(); it != frontier_.end();) {
    if (static_cast<std::uint64_t>(y_of(it->first)) < least) {
      it = frontier_.erase(it);
    } else {
      ++it;
    }
  }
}

void FarCells::begin_tile(int tile_row) {
  if (done_) throw std::logic_error("FarCells::begin_tile after components()");
  if (in_tile_) throw std::logic_error("FarCells::begin_tile: the tile before was not ended");
  if (tile_row < row_) {
    throw std::logic_error("FarCells::begin_tile: tile row " + std::to_string(tile_row) + " after row " + std::to_string(row_) +
                           " (tiles must come row by row)");
  }
  if (tile_row > row_) {
    evict_before_row();
    row_ = tile_row;
  }
  std::fill(tile_slots_.begin(), tile_slots_.end(), Slot{0, kFree});
  tile_cells_.clear();
  tile_keys_.clear();
  in_tile_ = true;
}

std::uint32_t FarCells::tile_find(std::uint64_t key) const {
  const std::size_t mask = tile_slots_.size() - 1;
  for (std::size_t i = tile_home(key);; i = (i + 1) & mask) {
    const Slot& s = tile_slots_[i];
    if (s.index == kFree || s.key == key) return s.index;
  }
}

void FarCells::tile_grow() {
  ++tile_bits_;
  tile_slots_.assign(std::size_t{1} << tile_bits_, Slot{0, kFree});
  const std::size_t mask = tile_slots_.size() - 1;
  for (std::uint32_t c = 0; c < tile_keys_.size(); ++c) {
    std::size_t i = tile_home(tile_keys_[c]);
    while (tile_slots_[i].index != kFree) i = (i + 1) & mask;
    tile_slots_[i] = Slot{tile_keys_[c], c};
  }
}

std::uint32_t FarCells::tile_cell(std::uint64_t key) {
  const std::size_t mask = tile_slots_.size() - 1;
  for (std::size_t i = tile_home(key);; i = (i + 1) & mask) {
    Slot& s = tile_slots_[i];
    if (s.key == key && s.index != kFree) return s.index;
    if (s.index != kFree) continue;
    const auto c = static_cast<std::uint32_t>(tile_cells_.size());
    s = Slot{key, c};
    tile_cells_.emplace_back();
    tile_keys_.push_back(key);
    if (2 * tile_keys_.size() > tile_slots_.size()) tile_grow();
    return c;
  }
}

void FarCells::add_points(const double* xyz, std::size_t n) {
  if (!in_tile_) throw std::logic_error("FarCells::add_points outside a tile");
  if (cells_fed_) throw std::logic_error("FarCells::add_points after add_cell (one way of feeding per FarCells)");
  points_fed_ = points_fed_ || n > 0;
  for (std::size_t j = 0; j < n; ++j) {
    const double* p = xyz + 3 * j;
    Cell& c = tile_cells_[tile_cell(key(p))];
    ++c.count;
    for (int a = 0; a < 3; ++a) {
      c.lo[a] = std::min(c.lo[a], p[a]);
      c.hi[a] = std::max(c.hi[a], p[a]);
    }
  }
}

void FarCells::add_cell(std::uint64_t key, std::uint32_t count, const double* lo, const double* hi) {
  if (!in_tile_) throw std::logic_error("FarCells::add_cell outside a tile");
  if (points_fed_) throw std::logic_error("FarCells::add_cell after add_points (one way of feeding per FarCells)");
  cells_fed_ = true;
  if (key == kNoKey) throw std::logic_error("FarCells::add_cell: a cell without a key (kNoKey)");
  Cell& c = tile_cells_[tile_cell(key)];
  c.count += count;
  for (int a = 0; a < 3; ++a) {
    c.lo[a] = std::min(c.lo[a], lo[a]);
    c.hi[a] = std::max(c.hi[a], hi[a]);
  }
}

std::uint64_t FarCells::link_key(const double* p, double inv_edge) {
  constexpr double kHalf = static_cast<double>(std::int64_t{1} << 20);
  std::int64_t c[3];
  for (int a = 0; a < 3; ++a) {
    // ⌊f⌋ without std::floor (a library call on the baseline x86-64 target): the truncation,
    // one less where it rounded a negative value up; exact within the range checked.
    const double f = p[a] * inv_edge;
    if (!(f >= -kHalf && f < kHalf)) return kNoKey;  // NaN too
    auto t = static_cast<std::int64_t>(f);
    t -= static_cast<double>(t) > f ? 1 : 0;
    c[a] = t + (std::int64_t{1} << 20);
  }
  return pack(c[0], c[1], c[2]);
}

FarCells::FarCellList FarCells::far_cells() const {
  std::vector<std::pair<std::uint64_t, std::uint32_t>> all(far_.begin(), far_.end());
  std::sort(all.begin(), all.end());
  FarCellList l;
  l.keys.reserve(all.size());
  l.cluster.reserve(all.size());
  for (const auto& [k, c] : all) {
    l.keys.push_back(k);
    l.cluster.push_back(c);
  }
  return l;
}

void FarCells::end_tile() {
  if (!in_tile_) throw std::logic_error("FarCells::end_tile outside a tile");
  in_tile_ = false;
  if (tile_keys_.empty()) return;

  // The tile's components: its cells in key order, linked to their 13 neighbours of larger key
  // (a pair of neighbours is one link, seen from its smaller key).
  std::vector<std::uint64_t> keys = tile_keys_;
  std::sort(keys.begin(), keys.end());
  const auto index_of = [&keys](std::uint64_t k) -> std::int64_t {
    const auto it = std::lower_bound(keys.begin(), keys.end(), k);
    return it != keys.end() && *it == k ? it - keys.begin() : -1;
  };
  std::vector<std::uint32_t> lp(keys.size());
  std::iota(lp.begin(), lp.end(), 0U);
  const auto lfind = [&lp](std::uint32_t i) {
    while (lp[i] != i) i = lp[i] = lp[lp[i]];
    return i;
  };
  std::int64_t x_lo = kMax, x_hi = 0, y_lo = kMax, y_hi = 0;
  for (std::uint32_t i = 0; i < keys.size(); ++i) {
    const std::int64_t x = x_of(keys[i]), y = y_of(keys[i]), z = z_of(keys[i]);
    x_lo = std::min(x_lo, x);
    x_hi = std::max(x_hi, x);
    y_lo = std::min(y_lo, y);
    y_hi = std::max(y_hi, y);
    for (int dx = 0; dx <= 1; ++dx)
      for (int dy = dx ? -1 : 0; dy <= 1; ++dy)
        for (int dz = (dx || dy) ? -1 : 1; dz <= 1; ++dz) {
          const std::int64_t nx = x + dx, ny = y + dy, nz = z + dz;
          if (nx > kMax || ny < 0 || ny > kMax || nz < 0 || nz > kMax) continue;
          const std::int64_t j = index_of(pack(nx, ny, nz));
          if (j < 0) continue;
          const std::uint32_t a = lfind(i), b = lfind(static_cast<std::uint32_t>(j));
          if (a != b) lp[std::max(a, b)] = std::min(a, b);  // the root is the least index: the least key
        }
  }
  // One component number per tile component, numbered at its root (its least key, met first).
  std::vector<std::uint32_t> label(keys.size());
  for (std::uint32_t i = 0; i < keys.size(); ++i) {
    const std::uint32_t root = lfind(i);
    if (root == i) {
      label[i] = static_cast<std::uint32_t>(parent_.size());
      parent_.push_back(label[i]);
      comps_.emplace_back();
      listed_cells_.emplace_back();
      comps_.back().least_key = keys[i];
    } else {
      label[i] = label[root];
    }
    const Cell& c = tile_cells_[tile_find(keys[i])];
    Comp& q = comps_[label[i]];
    q.count += c.count;
    for (int a = 0; a < 3; ++a) {
      q.lo[a] = std::min(q.lo[a], c.lo[a]);
      q.hi[a] = std::max(q.hi[a], c.hi[a]);
      stats_.box_lo[a] = std::min(stats_.box_lo[a], c.lo[a]);
      stats_.box_hi[a] = std::max(stats_.box_hi[a], c.hi[a]);
    }
  }
  for (std::uint32_t i = 0; i < keys.size(); ++i) {
    if (comps_[label[i]].count <= small_) {
      listed_cells_[label[i]].push_back(keys[i]);
      ++listed_;
    }
  }

  // Links to earlier tiles: only a cell within one index of the tile's least x or y index can
  // neighbour one (the class comment); the same key is the same cell, cut by a tile's edge.
  std::size_t repeats = 0;
  for (std::uint32_t i = 0; i < keys.size(); ++i) {
    const std::int64_t x = x_of(keys[i]), y = y_of(keys[i]), z = z_of(keys[i]);
    if (x > x_lo + 1 && y > y_lo + 1) continue;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          const std::int64_t nx = x + dx, ny = y + dy, nz = z + dz;
          if (nx < 0 || ny < 0 || nz < 0 || nx > kMax || ny > kMax || nz > kMax) continue;
          const auto it = frontier_.find(pack(nx, ny, nz));
          if (it == frontier_.end()) continue;
          if (dx == 0 && dy == 0 && dz == 0) ++repeats;
          join(label[i], it->second);
        }
  }
  cells_ += keys.size() - repeats;

  // The frontier: the cells within one index of the tile's largest x or y index.
  for (std::uint32_t i = 0; i < keys.size(); ++i) {
    if (x_of(keys[i]) < x_hi - 1 && y_of(keys[i]) < y_hi - 1) continue;
    const auto [it, added] = frontier_.emplace(keys[i], label[i]);
    if (!added) join(it->second, label[i]);
  }
  y_seen_max_ = std::max<std::uint64_t>(y_seen_max_, static_cast<std::uint64_t>(y_hi));
  stats_.frontier_cells_peak = std::max(stats_.frontier_cells_peak, frontier_.size());
  stats_.tile_components = parent_.size();
  stats_.listed_cells_peak = std::max(stats_.listed_cells_peak, listed_);
}

FarCells::Result FarCells::components(double far_m) {
  if (done_) throw std::logic_error("FarCells::components called twice");
  if (in_tile_) throw std::logic_error("FarCells::components: the last tile was not ended");
  done_ = true;
  std::vector<Slot>().swap(tile_slots_);
  std::vector<Cell>().swap(tile_cells_);
  std::vector<std::uint64_t>().swap(tile_keys_);
  std::unordered_map<std::uint64_t, std::uint32_t>().swap(frontier_);
  Result r = stats_;
  r.cells = cells_;
  std::vector<std::uint32_t> roots;
  for (std::uint32_t l = 0; l < parent_.size(); ++l)
    if (find(l) == l) roots.push_back(l);
  std::sort(roots.begin(), roots.end(), [this](std::uint32_t a, std::uint32_t b) { return comps_[a].least_key < comps_[b].least_key; });
  r.clusters = roots.size();
  if (!roots.empty()) {
    const auto box = [this](std::uint32_t q, bool hi) {
      const double* v = hi ? comps_[q].hi : comps_[q].lo;
      return Eigen::Vector3d(v[0], v[1], v[2]);
    };
    std::uint32_t main = roots[0];
    for (const std::uint32_t q : roots)
      if (comps_[q].count > comps_[main].count) main = q;
    r.main_lo = box(main, false);
    r.main_hi = box(main, true);
    for (const std::uint32_t q : roots) {
      if (q == main) continue;
      const Eigen::Vector3d lo = box(q, false), hi = box(q, true);
      const Eigen::Vector3d d = (lo - r.main_hi).cwiseMax(r.main_lo - hi).cwiseMax(0.0);
      const double gap = d.norm();
      if (!(gap > far_m)) continue;
      const std::uint64_t count = comps_[q].count;
      const bool remove = count <= small_;
      (remove ? r.removed_clusters : r.kept_far_clusters) += 1;
      if (remove) {
        r.removed_points += count;
        for (const std::uint64_t k : listed_cells_[q]) {
          far_.emplace(k, static_cast<std::uint32_t>(r.removed_clusters - 1));
          const std::uint64_t b = filter_bit(k);
          far_filter_[b >> 6] |= std::uint64_t{1} << (b & 63);
        }
      }
      if (r.notes.size() < 20) {
        const Eigen::Vector3d m = 0.5 * (lo + hi);
        r.notes.push_back(std::string(remove ? "removed far cluster: " : "kept far cluster (too large to remove): ") +
                          std::to_string(count) + " points in a box centred at (" + format_number(m.x()) + ", " +
                          format_number(m.y()) + ", " + format_number(m.z()) + ") m (grid frame), " + format_number(gap) +
                          " m from the main body's box");
      }
    }
  }
  std::vector<std::uint32_t>().swap(parent_);
  std::vector<Comp>().swap(comps_);
  std::vector<std::vector<std::uint64_t>>().swap(listed_cells_);
  return r;
}

}  // namespace hc::pipeline::detail
