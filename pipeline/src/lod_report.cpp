#include "stage_util.hpp"
#include "hc/pipeline/lod_report.hpp"

#include "hc/common/bilinear_surface.hpp"
#include "hc/common/error.hpp"
#include "hc/common/format.hpp"
#include "hc/common/units.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/filters.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/preview.hpp"
#include "hc/pipeline/synthetic.hpp"
#include "hc/pipeline/transform.hpp"


#include <algorithm>
#include <string>
#include <optional>
#include <filesystem>
#include <cstring>
#include <cstdio>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <iomanip>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace hc::pipeline {
namespace {


std::string fixed(double v, int precision) { return format_number(v, precision, NumberStyle::kFixed); }

/// One line per distinct sampling of the rows' cross-check (a), or "" when none was sampled.
std::string level_sampling_note(const std::vector<LevelRow>& rows) {
  std::ostringstream note;
  for (const LevelRow& r : rows) {
    if (!r.point_vertical || r.points_checked >= r.points_total) continue;
    note << "\nLevel " << r.level << ": RMS and p95 from " << r.points_checked << " of " << r.points_total
         << " points (evenly strided)" << (r.support_measured ? "; support over every point." : "; support not measured (it needs every point).");
  }
  return note.str().empty() ? std::string() : note.str() + "\n";
}

// A level of a stored pyramid larger than options.stored_window_samples² samples, read a window
// at a time (issue 14: a level of a 65 536 × 32 768 scene is never read whole). Windows of
// side × side samples own their samples; each is read with one more row and column (the far
// corners of its last cells), so that every point whose bilinear cell lies in a window's own part
// is evaluated there with point_residual_of_part, bit for bit as on the whole level. Fills the
// row's valid cells, μ_d histogram (merged counts) and, with `points`, (a) on every stride-th
// point, its residuals kept in the points' order (so error_stats_mm sums as the whole level's
// path does). The support is not measured (it needs every point against the whole level).
void stored_level_row(LodPyramid& pyramid, int level, const Cloud* points, std::size_t stride, std::size_t total,
                      const LevelTableOptions& options, int side, LevelRow& row) {
  const GridGeometry& g = pyramid.geometry(level);
  const int wr = (g.rows + side - 1) / side, wc = (g.cols + side - 1) / side;
  const std::size_t n = points != nullptr ? points->size() : 0;
  const std::size_t checked = n == 0 ? 0 : (n + stride - 1) / stride;
  // The checked points by the window owning their cell (index into `checked` order).
  std::vector<std::vector<std::size_t>> mine(static_cast<std::size_t>(wr) * static_cast<std::size_t>(wc));
  if (points != nullptr) {
    const double* p = points->xyz.data();
    for (std::size_t i = 0, k = 0; i < n; i += stride, ++k) {
      const double* q = p + 3 * i;
      if (!std::isfinite(q[0]) || !std::isfinite(q[1]) || !std::isfinite(q[2])) continue;
      if (q[0] < g.x0_m || q[0] > g.x_of_col(g.cols - 1) || q[1] < g.y0_m || q[1] > g.y_of_row(g.rows - 1)) continue;  // outside
      const BilinearCell cell = bilinear_cell(g, q[0], q[1]);  // the cell BilinearSurface::sample reads
      mine[static_cast<std::size_t>(cell.j / side) * static_cast<std::size_t>(wc) + static_cast<std::size_t>(cell.i / side)]
          .push_back(k);
    }
  }
  std::vector<float> vertical(checked, std::numeric_limits<float>::quiet_NaN());
  const double mu_min = pyramid.layer_options().mu_min, mu_max = pyramid.layer_options().mu_max;
  FrictionHistogram mu;
  bool has_mu = false;
  std::size_t valid = 0;
  for (int a = 0; a < wr; ++a) {
    for (int b = 0; b < wc; ++b) {
      const int r0 = a * side, c0 = b * side;
      const int r1 = std::min(g.rows, r0 + side), c1 = std::min(g.cols, c0 + side);  // own part [r0, r1) × [c0, c1)
      const int rs = std::min(r0, g.rows - 2), cs = std::min(c0, g.cols - 2);       // read from here (at least 2 × 2)
      const int re = std::min(g.rows, r1 + 1), ce = std::min(g.cols, c1 + 1);
      const auto w = pyramid.window(level, rs, cs, re - rs, ce - cs, false);  // each read once: not cached
      if (w->row0 != rs || w->col0 != cs || w->depth_m.rows() != re - rs || w->depth_m.cols() != ce - cs) {
        throw std::logic_error("level_table: level " + std::to_string(level) + "'s window at (" + std::to_string(rs) + ", " +
                               std::to_string(cs) + ") came back moved or cut");
      }
      const HeightField& d = w->depth_m;
      for (int r = r0; r < r1; ++r)
        for (int c = c0; c < c1; ++c) valid += std::isnan(d.at(r - rs, c - cs)) ? 0U : 1U;
      if (w->mu_d.rows() > 0) {
        HeightField own(GridGeometry{r1 - r0, c1 - c0, g.x_of_col(c0), g.y_of_row(r0), g.cell_size_m});
        for (int r = r0; r < r1; ++r)
          for (int c = c0; c < c1; ++c) own.at(r - r0, c - c0) = w->mu_d.at(r - rs, c - cs);
        const FrictionHistogram h = friction_histogram(own, mu_min, mu_max);
        if (!has_mu) {
          mu = h;
          has_mu = true;
        } else {
          mu.valid += h.valid;
          mu.at_min += h.at_min;
          mu.at_max += h.at_max;
          for (std::size_t k = 0; k < mu.bins.size(); ++k) mu.bins[k] += h.bins[k];
        }
      }
      for (const std::size_t k : mine[static_cast<std::size_t>(a) * static_cast<std::size_t>(wc) + static_cast<std::size_t>(b)]) {
        const double* q = points->xyz.data() + 3 * (k * stride);
        const PointResidual pr = point_residual_of_part(d.data(), d.cols(), rs, cs, g, q[0], q[1], q[2], options.hidden_band_m);
        if (pr.kind == PointResidual::kOnSurface) vertical[k] = pr.vertical_m;
      }
    }
  }
  row.valid_cells = valid;
  if (has_mu) row.mu_d = mu;
  if (points == nullptr || valid == 0) return;
  std::vector<double> vertical_m;
  vertical_m.reserve(checked);
  for (const float v : vertical)
    if (!std::isnan(v)) vertical_m.push_back(static_cast<double>(v));
  if (vertical_m.empty()) return;
  row.point_vertical = error_stats_mm(std::move(vertical_m));
  row.points_checked = checked;
  row.points_total = total;
}

}  // namespace

std::vector<LevelRow> level_table(const std::shared_ptr<LodPyramid>& pyramid, const Cloud* points,
                                  const LevelTableOptions& options) {
  if (options.cross_check && points != nullptr &&
      (!(options.hidden_band_m > 0.0) || !std::isfinite(options.hidden_band_m))) {
    std::ostringstream msg;
    msg << "level_table: hidden_band_m = " << options.hidden_band_m << " (expected a finite distance > 0)";
    throw ConfigError(msg.str());
  }
  const std::size_t n = points != nullptr ? points->size() : 0;
  const bool whole_set = options.points_represent <= n;  // 0, or a sample of every point
  const std::size_t total = whole_set ? n : options.points_represent;
  const std::size_t stride = !whole_set || options.sample_points == 0 || n <= options.sample_points
                                 ? 1
                                 : (n + options.sample_points - 1) / options.sample_points;
  if (options.stored_window_samples < 2) {
    throw ConfigError("level_table: stored_window_samples = " + std::to_string(options.stored_window_samples) +
                      " (expected at least 2)");
  }
  std::vector<LevelRow> rows;
  for (int level = 0; level < pyramid->level_count(); ++level) {
    LevelRow row;
    row.level = level;
    if (pyramid->stored()) {
      const GridGeometry& g = pyramid->geometry(level);
      // The window's side: options.stored_window_samples, less where a window of every layer
      // would hold more than half of what the pyramid lets windows and levels hold
      // (LodPyramid::window refuses more); a level read whole is at most that too.
      const double per_sample = static_cast<double>(std::max<std::size_t>(1, pyramid->stored_bytes_per_sample()));
      const double half_budget = 0.5 * static_cast<double>(pyramid->entry_budget_bytes());
      const int budget_side = static_cast<int>(std::floor(std::sqrt(half_budget / per_sample))) - 1;
      const int side_i = std::max(2, std::min(options.stored_window_samples, budget_side));
      const auto side = static_cast<std::size_t>(side_i);
      if (g.rows >= 2 && g.cols >= 2 && g.cell_count() > side * side) {
        row.rows = g.rows;
        row.cols = g.cols;
        row.cell_size_m = g.cell_size_m;
        row.stored = true;
        const auto t_check = detail::Clock::now();
        stored_level_row(*pyramid, level, options.cross_check ? points : nullptr, stride, total, options, side_i, row);
        row.cross_check_seconds = options.cross_check && points != nullptr ? detail::seconds_since(t_check) : 0.0;
        if (options.cross_check && level == 0 && options.level0_cross_check) {  // as the whole level's path
          row.point_vertical = options.level0_cross_check->point_vertical;
          row.supported_fraction = options.level0_cross_check->supported_fraction;
          row.support_measured = true;
          row.points_checked = row.points_total = total;
          row.cross_check_seconds = 0.0;
        }
        rows.push_back(row);
        continue;
      }
    }
    const auto lvl = pyramid->level(level);
    row.stored = pyramid->stored();
    const GridGeometry& g = lvl->depth_m.geometry();
    row.rows = g.rows;
    row.cols = g.cols;
    row.cell_size_m = g.cell_size_m;
    row.valid_cells = lvl->depth_m.valid_count();
    row.build_seconds = row.stored ? 0.0 : lvl->depth_seconds + lvl->layers_seconds;  // a stored level is read, not built
    if (lvl->has_layers && lvl->mu_d.rows() > 0) {
      row.mu_d = friction_histogram(lvl->mu_d, pyramid->layer_options().mu_min, pyramid->layer_options().mu_max);
    }
    if (options.cross_check && level == 0 && options.level0_cross_check) {
      row.point_vertical = options.level0_cross_check->point_vertical;
      row.supported_fraction = options.level0_cross_check->supported_fraction;
      row.support_measured = true;
      row.points_checked = row.points_total = total;
    } else if (options.cross_check && points != nullptr && row.valid_cells > 0 && g.rows >= 2 && g.cols >= 2) {
      // (a) on every stride-th point, exactly as cross_check evaluates each one.
      const auto t_check = detail::Clock::now();
      const BilinearSurface surface(HeightFieldView::of(lvl->depth_m));
      std::vector<double> vertical_m;
      vertical_m.reserve(n / stride + 1);
      const double* p = points->xyz.data();
      std::size_t checked = 0;
      for (std::size_t i = 0; i < n; i += stride, ++checked) {
        const double* q = p + 3 * i;
        if (!std::isfinite(q[0]) || !std::isfinite(q[1]) || !std::isfinite(q[2])) continue;
        const PointResidual r = point_residual(surface, g, q[0], q[1], q[2], options.hidden_band_m);
        if (r.kind == PointResidual::kOnSurface) vertical_m.push_back(static_cast<double>(r.vertical_m));
      }
      // No evaluated point on the level's surface (no finite point at all, say): no figures, the
      // columns show "–" (cross_check would refuse such a cloud).
      if (!vertical_m.empty()) {
        row.point_vertical = error_stats_mm(std::move(vertical_m));
        row.points_checked = checked;
        row.points_total = total;
        if (whole_set) {
          row.supported_fraction = supported_fraction(*points, lvl->depth_m, options.tolerance_m);
          row.support_measured = true;
        }
      }
      row.cross_check_seconds = detail::seconds_since(t_check);
    }

    rows.push_back(row);
  }
  return rows;
}

std::string level_table_markdown(const std::vector<LevelRow>& rows) {
  std::ostringstream md;
  md << "| level | cell (mm) | size (samples) | valid | build (ms) | RMS (mm) | p95 (mm) | supported | tick p50 / p99 (ns) "
        "| switch (ms) | μ_d at min / max | μ_d histogram (10 bins, %) |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const LevelRow& r : rows) {
    md << "| " << r.level << " | " << fixed(r.cell_size_m * 1000.0, 4) << " | " << r.cols << " × " << r.rows << " | "
       << r.valid_cells << " | " << (r.stored ? std::string("stored") : fixed(r.build_seconds * 1000.0, 1)) << " | ";
    if (r.point_vertical) {
      md << fixed(r.point_vertical->rms_mm, 3) << " | " << fixed(r.point_vertical->p95_mm, 3) << " | "
         << (r.support_measured ? fixed(100.0 * r.supported_fraction, 1) + " %" : std::string("–")) << " | ";
    } else {
      md << "– | – | – | ";
    }
    if (r.timed) {
      md << fixed(r.tick_p50_ns, 0) << " / " << fixed(r.tick_p99_ns, 0) << " | " << fixed(r.switch_ms, 3) << " | ";
    } else {
      md << "– | – | ";
    }
    if (r.mu_d && r.mu_d->valid > 0) {
      const double nv = static_cast<double>(r.mu_d->valid);
      md << fixed(100.0 * r.mu_d->at_min_fraction(), 1) << " % / " << fixed(100.0 * r.mu_d->at_max_fraction(), 1)
         << " % | ";
      for (std::size_t k = 0; k < r.mu_d->bins.size(); ++k) {
        md << (k ? " " : "") << fixed(100.0 * static_cast<double>(r.mu_d->bins[k]) / nv, 0);
      }
      md << " |\n";
    } else {
      md << "– | – |\n";
    }
  }
  md << level_sampling_note(rows);
  return md.str();
}

std::string level_table_text(const std::vector<LevelRow>& rows) {
  std::ostringstream t;
  t << std::left << std::setw(6) << "level" << std::setw(11) << "cell_mm" << std::setw(14) << "cols x rows"
    << std::setw(10) << "build_ms" << std::setw(10) << "rms_mm" << std::setw(10) << "p95_mm" << std::setw(11)
    << "supported" << std::setw(13) << "tick_p50_ns" << std::setw(12) << "tick_p99_ns" << "switch_ms\n";
  for (const LevelRow& r : rows) {
    t << std::setw(6) << r.level << std::setw(11) << fixed(r.cell_size_m * 1000.0, 4) << std::setw(14)
      << (std::to_string(r.cols) + " x " + std::to_string(r.rows)) << std::setw(10)
      << (r.stored ? std::string("stored") : fixed(r.build_seconds * 1000.0, 1));
    if (r.point_vertical) {
      t << std::setw(10) << fixed(r.point_vertical->rms_mm, 3) << std::setw(10) << fixed(r.point_vertical->p95_mm, 3)
        << std::setw(11) << (r.support_measured ? fixed(100.0 * r.supported_fraction, 1) + "%" : std::string("-"));
    } else {
      t << std::setw(10) << "-" << std::setw(10) << "-" << std::setw(11) << "-";
    }
    if (r.timed) {
      t << std::setw(13) << fixed(r.tick_p50_ns, 0) << std::setw(12) << fixed(r.tick_p99_ns, 0) << fixed(r.switch_ms, 3)
        << "\n";
    } else {
      t << std::setw(13) << "-" << std::setw(12) << "-" << "-\n";
    }
  }
  t << level_sampling_note(rows);
  return t.str();
}

std::size_t level_sample_stride(std::uint64_t n, std::size_t sample_points) {
  const std::uint64_t per = sample_points > 0 ? sample_points : LodOptions{}.report_sample_points;
  return static_cast<std::size_t>(std::max<std::uint64_t>(1, (n + per - 1) / per));
}

Cloud every_nth_point(const Cloud& points, std::size_t stride) {
  stride = std::max<std::size_t>(stride, 1);
  const std::size_t n = points.size();
  Cloud out;
  out.xyz.resize(3, static_cast<Eigen::Index>(n == 0 ? 0 : (n + stride - 1) / stride));
  for (std::size_t i = 0, k = 0; i < n; i += stride, ++k) {
    out.xyz.col(static_cast<Eigen::Index>(k)) = points.xyz.col(static_cast<Eigen::Index>(i));
  }
  return out;
}

namespace {
constexpr char kSampleMagic[8] = {'H', 'C', 'P', 'S', 'M', 'P', '1', '\n'};
constexpr std::size_t kSampleHeader = 24;  // magic, count, represents
}  // namespace

void write_level_point_sample(const std::filesystem::path& scene_dir, const Cloud& points, std::uint64_t represents) {
  const std::filesystem::path file = scene_dir / kLevelPointSampleFile;
  const std::uint64_t count = points.size();
  if (represents == 0) represents = count;
  char head[kSampleHeader];
  std::memcpy(head, kSampleMagic, 8);
  std::memcpy(head + 8, &count, 8);  // little-endian hosts only (as every binary file here)
  std::memcpy(head + 16, &represents, 8);
  std::FILE* f = std::fopen(file.c_str(), "wb");
  const bool ok = f && std::fwrite(head, 1, kSampleHeader, f) == kSampleHeader &&
                  (count == 0 || std::fwrite(points.xyz.data(), 24, count, f) == count);
  const int err = errno;
  const bool closed = f && std::fclose(f) == 0;
  if (!ok || !closed) throw InputError("cannot write " + file.string() + ": " + std::strerror(ok ? errno : err));
}

std::optional<LevelPointSample> read_level_point_sample(const std::filesystem::path& scene_dir) {
  const std::filesystem::path file = scene_dir / kLevelPointSampleFile;
  std::error_code ec;
  if (!std::filesystem::exists(file, ec)) return std::nullopt;
  const auto bad = [&](const std::string& why) {
    return InputError(file.string() + ": " + why + " (expected the levels table's point sample that a tiled scene, or a "
                      "scene of a tiled run, stores; read the scan instead with a run config (hapticloud levels --config, "
                      "Python levels(config=...)), or skip the cross-check)");
  };
  const std::uintmax_t size = std::filesystem::file_size(file, ec);
  if (ec) throw InputError(file.string() + " cannot be read: " + ec.message());
  std::FILE* f = std::fopen(file.c_str(), "rb");
  if (!f) throw InputError(file.string() + " cannot be opened: " + std::strerror(errno));
  // The header, then the points straight into the matrix (no second copy).
  char head[kSampleHeader] = {};
  const bool got_head = size >= kSampleHeader && std::fread(head, 1, kSampleHeader, f) == kSampleHeader;
  std::uint64_t count = 0, represents = 0;
  std::memcpy(&count, head + 8, 8);
  std::memcpy(&represents, head + 16, 8);
  const auto fail = [&](const InputError& e) {
    std::fclose(f);
    throw e;
  };
  if (!got_head || std::memcmp(head, kSampleMagic, 8) != 0) fail(bad("no HCPSMP1 header"));
  if (count > (size - kSampleHeader) / 24 || size != kSampleHeader + count * 24) {
    fail(bad(std::to_string(size) + " bytes for " + std::to_string(count) + " points (24 bytes each after a " +
             std::to_string(kSampleHeader) + "-byte header)"));
  }
  if (represents < count) fail(bad("it stands for " + std::to_string(represents) + " points, fewer than its " + std::to_string(count)));
  LevelPointSample s;
  s.represents = represents;
  s.points.xyz.resize(3, static_cast<Eigen::Index>(count));
  const bool got = count == 0 || std::fread(s.points.xyz.data(), 24, count, f) == count;
  std::fclose(f);
  if (!got) throw InputError(file.string() + " cannot be read (cut short while it was read?)");
  if (!s.points.xyz.allFinite()) throw bad("a coordinate is not finite");
  return s;
}

std::vector<std::string> write_level_previews(LodPyramid& pyramid, const std::filesystem::path& dir) {
  std::vector<std::string> names, titles;
  std::vector<std::shared_ptr<const LodLevel>> levels;
  for (int level = 0; level < pyramid.level_count(); ++level) {
    const std::string name = "lod_level_" + std::to_string(level) + ".png";
    levels.push_back(pyramid.depth_level(level));
    const HeightField& depth = levels.back()->depth_m;
    std::ostringstream title;
    title << "level " << level << ": " << depth.rows() << " x " << depth.cols() << " cells of "
          << format_number(depth.cell_size_m() * 1e3, 3) << " mm";
    titles.push_back(title.str());
    write_hillshade_preview(depth, dir / name, title.str());
    names.push_back(name);
  }
  // Side by side at one height (level 0's, at most 600 px); coarse levels keep their cells.
  std::vector<const HeightField*> fields;
  for (const auto& l : levels) fields.push_back(&l->depth_m);
  write_hillshades_side_by_side(fields, titles, dir / "lod_levels.png", 600);
  names.push_back("lod_levels.png");
  return names;
}

}  // namespace hc::pipeline
