// Hole filling of a depth grid by normalised convolution.
//
// A hole is a 4-connected component of no-data cells (empty or see-through). Components that
// touch the grid border are background; components larger than max_hole_cells stay no data, and
// so (with max_rim_step_m) do those whose rim spreads about its fitted plane as a depth step
// does (occlusion gaps between a near and a far surface). Every other hole is filled from its rim inwards: in each sweep, a hole cell whose Gaussian-
// weighted support of known cells (valid or already filled) reaches kMinSupport of the full
// kernel weight gets the normalised convolution value Σ w·z / Σ w over the known cells in its
// window (a masked Gaussian blur divided by the blurred mask, evaluated only at hole cells).
// Cells filled in one sweep become known for the next (updates are committed after each sweep,
// so the result does not depend on scan order). A hole cell 4-adjacent to a known cell always
// has enough support, so each sweep fills at least the hole's outer ring and the loop ends.
// The cost is proportional to the hole area times the kernel size, not to the grid size.
// Colour and intensity, when the grid has them, are filled by the same weights over the same
// known cells as the depth (so a filled cell's colour is the blur of its rim's colours).

#include "hc/pipeline/reproject.hpp"

#include "hc/common/error.hpp"

#include <Eigen/Core>
#include <Eigen/Cholesky>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <limits>
#include <sstream>
#include <utility>
#include <vector>

namespace hc::pipeline {

namespace {

constexpr double kSigmaCells = 1.0;  ///< Gaussian σ of the fill kernel [cells]
constexpr int kRadiusCells = 3;      ///< kernel half-width, 3σ [cells]
constexpr double kMinSupport = 0.05; ///< minimum known-cell weight fraction to fill a cell [-]

/// True when the rim of a hole (its valid 8-neighbours; the hole does not touch the border, so
/// every neighbour exists) spreads about the least-squares plane z = a + b·col + c·row through
/// it by more than max_step_m [m]: the spread is max − min of the rim's residuals. A slope fits
/// the plane (spread 0); a depth step of height H across the hole tilts the plane and leaves a
/// spread of about 0.6–0.9·H (a 2 × 2 hole centred on the step: 0.63·H). A rim of fewer than 3
/// cells, or one on a line, is judged by its depth span. `rim` is scratch space.
bool rim_departs(const float* z, std::size_t cols, const std::vector<std::size_t>& hole, std::vector<std::size_t>& rim,
                 double max_step_m) {
  rim.clear();
  for (const std::size_t i : hole) {
    for (const std::ptrdiff_t dr : {-1, 0, 1})
      for (const std::ptrdiff_t dc : {-1, 0, 1}) {
        const auto j = static_cast<std::size_t>(static_cast<std::ptrdiff_t>(i) + dr * static_cast<std::ptrdiff_t>(cols) + dc);
        if (!std::isnan(z[j])) rim.push_back(j);
      }
  }
  std::sort(rim.begin(), rim.end());
  rim.erase(std::unique(rim.begin(), rim.end()), rim.end());
  if (rim.empty()) return false;
  // Centred coordinates (cells) and depth, for a well-conditioned 3 × 3 normal system.
  double mc = 0.0, mr = 0.0, mz = 0.0;
  for (const std::size_t j : rim) {
    mc += static_cast<double>(j % cols);
    mr += static_cast<double>(j / cols);
    mz += static_cast<double>(z[j]);
  }
  const auto n = static_cast<double>(rim.size());
  mc /= n;
  mr /= n;
  mz /= n;
  Eigen::Matrix2d a = Eigen::Matrix2d::Zero();
  Eigen::Vector2d rhs = Eigen::Vector2d::Zero();
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const std::size_t j : rim) {
    const Eigen::Vector2d u(static_cast<double>(j % cols) - mc, static_cast<double>(j / cols) - mr);
    const double dz = static_cast<double>(z[j]) - mz;
    a += u * u.transpose();
    rhs += u * dz;
    lo = std::min(lo, dz);
    hi = std::max(hi, dz);
  }
  // Fewer than 3 cells or all on a line: no plane; the span decides.
  if (rim.size() < 3 || std::abs(a.determinant()) < 1e-9 * (1.0 + a.squaredNorm())) return hi - lo > max_step_m;
  const Eigen::Vector2d slope = a.ldlt().solve(rhs);
  double res_lo = std::numeric_limits<double>::infinity(), res_hi = -res_lo;
  for (const std::size_t j : rim) {
    const Eigen::Vector2d u(static_cast<double>(j % cols) - mc, static_cast<double>(j / cols) - mr);
    const double res = static_cast<double>(z[j]) - mz - slope.dot(u);
    res_lo = std::min(res_lo, res);
    res_hi = std::max(res_hi, res);
  }
  return res_hi - res_lo > max_step_m;
}

}  // namespace

StageResult<DepthGrid> fill_holes(DepthGrid grid, int max_hole_cells, double max_rim_step_m) {
  const auto t0 = std::chrono::steady_clock::now();
  if (max_hole_cells < 0) {
    std::ostringstream msg;
    msg << "fill_holes: max_hole_cells = " << max_hole_cells << " (expected >= 0; 0 disables)";
    throw ConfigError(msg.str());
  }
  if (!(max_rim_step_m >= 0.0) || !std::isfinite(max_rim_step_m)) {
    std::ostringstream msg;
    msg << "fill_holes: grid.hole_fill_max_step_m = " << max_rim_step_m << " (expected a depth >= 0 [m]; 0 = no limit)";
    throw ConfigError(msg.str());
  }
  const int rows = grid.depth.rows(), cols = grid.depth.cols();
  const std::size_t cells = grid.depth.geometry().cell_count();
  if (grid.flags.size() != cells) {
    std::ostringstream msg;
    msg << "fill_holes: the flag mask has " << grid.flags.size() << " entries for a " << cols
        << " x " << rows << " grid (expected " << cells << ")";
    throw InputError(msg.str());
  }
  if ((grid.has_colour() && grid.colour_rgb8.size() != 3 * cells) ||
      (grid.has_intensity() && grid.intensity.values().size() != cells)) {
    std::ostringstream msg;
    msg << "fill_holes: colour (" << grid.colour_rgb8.size() << " bytes) or intensity ("
        << grid.intensity.values().size() << " cells) does not match a " << cols << " x " << rows
        << " grid (expected " << 3 * cells << " bytes and " << cells << " cells)";
    throw InputError(msg.str());
  }
  const bool rgb = grid.has_colour(), inten = grid.has_intensity();

  StageResult<DepthGrid> result;
  StageReport& rep = result.report;
  rep.stage = "fill_holes";
  rep.count_in = grid.depth.valid_count();

  std::size_t holes_total = 0, holes_filled = 0, cells_filled = 0, largest_filled = 0, holes_at_steps = 0;
  int sweeps = 0;
  if (max_hole_cells > 0) {
    float* z = grid.depth.data();
    const auto ucols = static_cast<std::size_t>(cols);
    // Label the no-data components (4-connectivity) with an explicit stack; keep the cells of
    // the fillable ones.
    // A bit a cell (an eighth of a byte: the grid may be a file-backed level 0 larger than memory).
    std::vector<bool> seen(cells, false);
    std::vector<std::size_t> stack, component, fillable, rim;
    for (std::size_t start = 0; start < cells; ++start) {
      // A file-backed level 0's pages given back as the sweep passes (cell_buffer.hpp).
      if (start % kReleaseEveryCells == 0) grid.depth.values().release_resident();
      if (seen[start] || !std::isnan(z[start])) continue;
      ++holes_total;
      component.clear();
      bool border = false;
      stack.push_back(start);
      seen[start] = true;
      std::size_t size = 0;
      while (!stack.empty()) {
        const std::size_t i = stack.back();
        stack.pop_back();
        // Cells recorded only while the hole may still be filled: a larger one (the background
        // around a scan, which may be most of a fine grid) is counted, not listed.
        if (++size <= static_cast<std::size_t>(max_hole_cells)) component.push_back(i);
        const std::size_t r = i / ucols, c = i % ucols;
        if (r == 0 || c == 0 || r + 1 == static_cast<std::size_t>(rows) || c + 1 == ucols) border = true;
        auto visit = [&](std::size_t j) {
          if (!seen[j] && std::isnan(z[j])) {
            seen[j] = true;
            stack.push_back(j);
          }
        };
        if (c > 0) visit(i - 1);
        if (c + 1 < ucols) visit(i + 1);
        if (r > 0) visit(i - ucols);
        if (r + 1 < static_cast<std::size_t>(rows)) visit(i + ucols);
      }
      if (border || size > static_cast<std::size_t>(max_hole_cells)) continue;
      if (max_rim_step_m > 0.0 && rim_departs(z, ucols, component, rim, max_rim_step_m)) {
        ++holes_at_steps;
        continue;
      }
      ++holes_filled;
      largest_filled = std::max(largest_filled, component.size());
      fillable.insert(fillable.end(), component.begin(), component.end());
    }

    // Gaussian kernel table.
    constexpr int kSide = 2 * kRadiusCells + 1;
    double kernel[kSide][kSide];
    double kernel_sum = 0.0;
    for (int dr = -kRadiusCells; dr <= kRadiusCells; ++dr) {
      for (int dc = -kRadiusCells; dc <= kRadiusCells; ++dc) {
        const double w = std::exp(-(dr * dr + dc * dc) / (2.0 * kSigmaCells * kSigmaCells));
        kernel[dr + kRadiusCells][dc + kRadiusCells] = w;
        kernel_sum += w;
      }
    }
    const double min_weight = kMinSupport * kernel_sum;

    std::vector<std::size_t> pending = std::move(fillable), next;
    std::vector<std::pair<std::size_t, float>> staged;
    // Colour (3) and intensity (1) of each staged cell, same weights as its depth.
    std::vector<std::array<double, 4>> staged_attr;
    std::uint8_t* colour = grid.colour_rgb8.data();
    float* intensity = grid.intensity.data();
    while (!pending.empty()) {
      ++sweeps;
      staged.clear();
      staged_attr.clear();
      next.clear();
      for (const std::size_t i : pending) {
        const int r = static_cast<int>(i / ucols), c = static_cast<int>(i % ucols);
        double wsum = 0.0, zsum = 0.0;
        std::array<double, 4> asum = {0.0, 0.0, 0.0, 0.0};
        const int r_lo = std::max(0, r - kRadiusCells), r_hi = std::min(rows - 1, r + kRadiusCells);
        const int c_lo = std::max(0, c - kRadiusCells), c_hi = std::min(cols - 1, c + kRadiusCells);
        for (int rr = r_lo; rr <= r_hi; ++rr) {
          const float* row = z + static_cast<std::size_t>(rr) * ucols;
          const double* krow = kernel[rr - r + kRadiusCells];
          for (int cc = c_lo; cc <= c_hi; ++cc) {
            const float v = row[cc];
            if (std::isnan(v)) continue;
            const double w = krow[cc - c + kRadiusCells];
            wsum += w;
            zsum += w * v;
            if (rgb || inten) {
              const std::size_t j = static_cast<std::size_t>(rr) * ucols + static_cast<std::size_t>(cc);
              if (rgb) {
                for (std::size_t k = 0; k < 3; ++k) asum[k] += w * colour[3 * j + k];
              }
              if (inten) asum[3] += w * static_cast<double>(intensity[j]);
            }
          }
        }
        if (wsum >= min_weight) {
          staged.emplace_back(i, static_cast<float>(zsum / wsum));
          if (rgb || inten) staged_attr.push_back({asum[0] / wsum, asum[1] / wsum, asum[2] / wsum, asum[3] / wsum});
        } else {
          next.push_back(i);
        }
      }
      if (staged.empty()) {
        // Cannot happen for a hole enclosed by data (its rim always has support); guard anyway.
        std::ostringstream msg;
        msg << "fill_holes: " << next.size() << " hole cells have no data within "
            << kRadiusCells << " cells after " << sweeps << " sweeps";
        throw DegenerateInputError(msg.str());
      }
      for (const auto& [i, v] : staged) {
        z[i] = v;
        grid.flags[i] = kCellFilled;
      }
      for (std::size_t s = 0; s < staged_attr.size(); ++s) {
        const std::size_t i = staged[s].first;
        if (rgb) {
          for (std::size_t k = 0; k < 3; ++k) {
            colour[3 * i + k] = static_cast<std::uint8_t>(std::clamp(std::lround(staged_attr[s][k]), 0L, 255L));
          }
        }
        if (inten) intensity[i] = static_cast<float>(staged_attr[s][3]);
      }
      cells_filled += staged.size();
      pending.swap(next);
    }
  }

  grid.release_resident();
  rep.count_out = rep.count_in + cells_filled;
  rep.figure("max_hole_cells", max_hole_cells);
  rep.figure("no_data_regions", static_cast<double>(holes_total));
  rep.figure("holes_filled", static_cast<double>(holes_filled));
  rep.figure("cells_filled", static_cast<double>(cells_filled));
  rep.figure("largest_filled_hole_cells", static_cast<double>(largest_filled));
  if (max_rim_step_m > 0.0) {
    rep.figure("max_rim_step_m", max_rim_step_m);
    rep.figure("holes_at_depth_steps", static_cast<double>(holes_at_steps));
  }
  rep.figure("sweeps", sweeps);
  if (max_hole_cells == 0) rep.notes.emplace_back("hole filling disabled (max_hole_cells = 0)");
  result.value = std::move(grid);
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

}  // namespace hc::pipeline
