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
#include <cmath>
#include <iomanip>
#include <sstream>

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
  const bool whole_set = options.points_represent == 0;
  const std::size_t total = whole_set ? n : options.points_represent;
  const std::size_t stride = !whole_set || options.sample_points == 0 || n <= options.sample_points
                                 ? 1
                                 : (n + options.sample_points - 1) / options.sample_points;
  std::vector<LevelRow> rows;
  for (int level = 0; level < pyramid->level_count(); ++level) {
    LevelRow row;
    row.level = level;
    const auto lvl = pyramid->level(level);
    const GridGeometry& g = lvl->depth_m.geometry();
    row.rows = g.rows;
    row.cols = g.cols;
    row.cell_size_m = g.cell_size_m;
    row.valid_cells = lvl->depth_m.valid_count();
    row.build_seconds = lvl->depth_seconds + lvl->layers_seconds;
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
       << r.valid_cells << " | " << fixed(r.build_seconds * 1000.0, 1) << " | ";
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
      << (std::to_string(r.cols) + " x " + std::to_string(r.rows)) << std::setw(10) << fixed(r.build_seconds * 1000.0, 1);
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
