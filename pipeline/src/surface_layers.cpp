#include "hc/common/format.hpp"
#include "stage_util.hpp"
#include "hc/pipeline/surface_layers.hpp"
#include "hc/pipeline/exact_sum.hpp"

#include "hc/common/error.hpp"

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace hc::pipeline {

namespace {

using detail::Clock;
using detail::seconds_since;

using hc::format_number;

[[noreturn]] void option_error(const std::string& field, const std::string& key, double value,
                               const std::string& expected) {
  throw ConfigError("surface layers: option " + field + " (config key " + key + ") = " + format_number(value) +
                    ": expected " + expected);
}

/// Checks lo < v ≤ hi (open_low) or lo ≤ v ≤ hi, rejecting NaN.
void check_range(const std::string& field, const std::string& key, double v, double lo, double hi,
                 bool open_low) {
  const bool ok = std::isfinite(v) && (open_low ? v > lo : v >= lo) && v <= hi;
  if (!ok) {
    option_error(field, key, v,
                 "a number in " + std::string(open_low ? "(" : "[") + format_number(lo) + ", " + format_number(hi) + "]");
  }
}

void validate(const SurfaceLayerOptions& o) {
  check_range("sigma_space_cells", "layers.texture.sigma_space_cells", o.sigma_space_cells, 0.0, 100.0, true);
  check_range("sigma_range_m", "layers.texture.sigma_range_m", o.sigma_range_m, 0.0, 10.0, true);
  check_range("mu_min", "layers.friction.mu_min", o.mu_min, 0.0, 10.0, false);
  check_range("mu_max", "layers.friction.mu_max", o.mu_max, 0.0, 10.0, false);
  if (o.mu_max < o.mu_min) {
    option_error("mu_max", "layers.friction.mu_max", o.mu_max,
                 "a number in [mu_min, 10] = [" + format_number(o.mu_min) + ", 10]");
  }
  check_range("workspace_radius_m", "layers.friction.workspace_radius_m", o.workspace_radius_m, 0.0, 10.0, true);
  check_range("curvature_gain_m", "layers.friction.curvature_gain_m", o.curvature_gain_m, 0.0, 100.0, false);
  check_range("mu_s", "layers.friction.mu_s", o.mu_s, 0.0, 10.0, false);
  for (std::size_t i = 0; i < o.mu_s_regions.size(); ++i) {
    const StaticFrictionRegion& g = o.mu_s_regions[i];
    const std::string field = "mu_s_regions[" + std::to_string(i) + "]";
    const std::string key = "layers.friction." + field;
    for (double v : {g.x_min_m, g.y_min_m, g.x_max_m, g.y_max_m}) {
      if (!std::isfinite(v)) option_error(field + ".bounds", key, v, "finite bounds in metres");
    }
    if (!(g.x_max_m > g.x_min_m)) {
      option_error(field + ".x_max_m", key + ".x_max_m", g.x_max_m, "a number > x_min_m = " + format_number(g.x_min_m));
    }
    if (!(g.y_max_m > g.y_min_m)) {
      option_error(field + ".y_max_m", key + ".y_max_m", g.y_max_m, "a number > y_min_m = " + format_number(g.y_min_m));
    }
    check_range(field + ".mu_s", key + ".mu_s", g.mu_s, 0.0, 10.0, false);
  }
}

/// Window radius [cells] of the bilateral filter and of the hole fill: ⌈2σ_s⌉, at least 1.
int window_radius_cells(double sigma_space_cells) {
  return std::max(1, static_cast<int>(std::ceil(2.0 * sigma_space_cells)));
}

/// minmod of two slopes: the smaller magnitude when they agree in sign, else 0. Keeps a cliff
/// between two valid cells from dominating the extrapolated gradient.
float minmod(float a, float b) {
  if (a * b <= 0.0f) return 0.0f;
  return std::abs(a) < std::abs(b) ? a : b;
}

struct EnvelopeResult {
  cv::Mat envelope;  ///< rows × cols CV_32F, f_b − ref at valid cells (other cells undefined)
  double fill_seconds = 0.0;
  double filter_seconds = 0.0;
  std::size_t filled_cells = 0;  ///< no-data cells (padding included) given an extrapolated value
  double lut_bin_m = 0.0;        ///< OpenCV's range-kernel table step over the filter input [m]
  int diameter_cells = 0;
};

/// The bilateral filter's padded input (fill_for_envelope).
struct FillResult {
  cv::Mat value;                 ///< (rows + 2r) × (cols + 2r) CV_32F
  std::size_t filled_cells = 0;  ///< no-data cells within reach of data given an extrapolation
  double seconds = 0.0;
  int radius_cells = 0;          ///< r
};

/// Largest |value| the fill clamps to: far inside float's range, so differences stay finite.
constexpr double kFloatRangeLimit = 1e30;
/// Largest depth range [m] handed to cv::bilateralFilter (a whole site is ≤ 10 km, see
/// input.max_extent_m); its range table is built in float from max − min.
constexpr double kMaxEnvelopeRangeM = 1e6;

/// The bilateral filter's input: (f − ref) padded by the window radius r on every side, where
/// every no-data cell (padding included) holds an extrapolated value. See compute_surface_layers'
/// comment. `band`, when given, is the level-wide {min, max} of the valid values (a block of a
/// larger grid, surface_layers_block) instead of the block's own: the extrapolations are
/// clamped to the band around them, so a block computes what the whole grid computes.
FillResult fill_for_envelope(const cv::Mat& f, const cv::Mat& valid, const SurfaceLayerOptions& o,
                             const float* band) {
  FillResult out;
  const auto t0 = Clock::now();
  const int r = window_radius_cells(o.sigma_space_cells);
  out.radius_cells = r;
  const int rows = f.rows + 2 * r;
  const int cols = f.cols + 2 * r;

  // Padded value, mask and minmod gradient (metres per cell) images; zero where no data.
  cv::Mat value(rows, cols, CV_32F, cv::Scalar(0));
  cv::Mat mask(rows, cols, CV_32F, cv::Scalar(0));
  cv::Mat gx(rows, cols, CV_32F, cv::Scalar(0));
  cv::Mat gy(rows, cols, CV_32F, cv::Scalar(0));
  float vmin = std::numeric_limits<float>::max();
  float vmax = std::numeric_limits<float>::lowest();
  std::size_t valid_cells = 0;
  // Slope along one axis at a valid cell from its two neighbours (nullptr = none or no data).
  auto slope = [](float v, const float* fwd, const float* bwd) {
    if (fwd && bwd) return minmod(*fwd - v, v - *bwd);
    if (fwd) return *fwd - v;
    if (bwd) return v - *bwd;
    return 0.0f;
  };
  for (int rr = 0; rr < f.rows; ++rr) {
    const float* fr = f.ptr<float>(rr);
    const std::uint8_t* ok = valid.ptr<std::uint8_t>(rr);
    const float* fu = rr + 1 < f.rows ? f.ptr<float>(rr + 1) : nullptr;
    const std::uint8_t* oku = rr + 1 < f.rows ? valid.ptr<std::uint8_t>(rr + 1) : nullptr;
    const float* fd = rr > 0 ? f.ptr<float>(rr - 1) : nullptr;
    const std::uint8_t* okd = rr > 0 ? valid.ptr<std::uint8_t>(rr - 1) : nullptr;
    float* vrow = value.ptr<float>(rr + r) + r;
    float* mrow = mask.ptr<float>(rr + r) + r;
    float* gxrow = gx.ptr<float>(rr + r) + r;
    float* gyrow = gy.ptr<float>(rr + r) + r;
    for (int cc = 0; cc < f.cols; ++cc) {
      if (!ok[cc]) continue;
      const float v = fr[cc];
      ++valid_cells;
      vmin = std::min(vmin, v);
      vmax = std::max(vmax, v);
      vrow[cc] = v;
      mrow[cc] = 1.0f;
      gxrow[cc] = slope(v, cc + 1 < f.cols && ok[cc + 1] ? fr + cc + 1 : nullptr,
                        cc > 0 && ok[cc - 1] ? fr + cc - 1 : nullptr);
      gyrow[cc] = slope(v, fu && oku[cc] ? fu + cc : nullptr, fd && okd[cc] ? fd + cc : nullptr);
    }
  }
  if (band) {
    vmin = band[0];
    vmax = band[1];
  }

  // Smooth the gradient a little over valid cells only (normalised 5-tap Gaussian, σ = 1 cell):
  // exact gradients of a plane stay exact, single-cell noise is damped before it is extrapolated.
  cv::Mat w(1, 5, CV_32F);
  for (int k = -2; k <= 2; ++k) w.at<float>(0, k + 2) = static_cast<float>(std::exp(-0.5 * k * k));
  cv::Mat bm, bgx, bgy;
  const cv::Point anchor(-1, -1);
  cv::sepFilter2D(mask, bm, CV_32F, w, w, anchor, 0.0, cv::BORDER_CONSTANT);
  cv::sepFilter2D(gx, bgx, CV_32F, w, w, anchor, 0.0, cv::BORDER_CONSTANT);
  cv::sepFilter2D(gy, bgy, CV_32F, w, w, anchor, 0.0, cv::BORDER_CONSTANT);

  // Every no-data cell q takes the first-order extrapolation from its nearest valid cell p:
  //   fill(q) = f(p) + ∇f(p)·(q − p),
  // exact on planes; taking one nearest cell (not an average) keeps the fill from blending the
  // two sides of a depth step. Nearest cells from OpenCV's labelled distance transform.
  const cv::Rect inner(r, r, f.cols, f.rows);
  cv::Mat features(rows, cols, CV_8U, cv::Scalar(255));
  features(inner).setTo(cv::Scalar(0), valid);
  cv::Mat dist, labels;
  cv::distanceTransform(features, dist, labels, cv::DIST_L2, cv::DIST_MASK_5, cv::DIST_LABEL_PIXEL);
  // Label of a valid cell → its linear index in the padded image (labels count the valid cells).
  std::vector<int> label_cell(valid_cells + 1, 0);
  for (int rr = 0; rr < rows; ++rr) {
    const float* m = mask.ptr<float>(rr);
    const int* lab = labels.ptr<int>(rr);
    for (int cc = 0; cc < cols; ++cc) {
      if (m[cc] == 0.0f) continue;
      const auto l = static_cast<std::size_t>(lab[cc]);
      if (l >= label_cell.size()) label_cell.resize(std::max(l + 1, 2 * label_cell.size()), 0);
      label_cell[l] = rr * cols + cc;
    }
  }
  // Keep extrapolations within a band around the data so OpenCV's range table stays fine.
  // In double: vmax − vmin overflows float for finite depths near ±3.4e38.
  const double span = std::max(static_cast<double>(vmax) - vmin, o.sigma_range_m);
  const float lo = static_cast<float>(std::max(static_cast<double>(vmin) - span, -kFloatRangeLimit));
  const float hi = static_cast<float>(std::min(static_cast<double>(vmax) + span, kFloatRangeLimit));
  const float reach = static_cast<float>(r) * 1.5f + 1.0f;  // beyond this no window sees the cell
  float* const val = value.ptr<float>();
  const float* const sm = bm.ptr<float>();
  const float* const sgx = bgx.ptr<float>();
  const float* const sgy = bgy.ptr<float>();
  for (int rr = 0; rr < rows; ++rr) {
    const float* m = mask.ptr<float>(rr);
    const int* lab = labels.ptr<int>(rr);
    const float* d = dist.ptr<float>(rr);
    for (int cc = 0; cc < cols; ++cc) {
      if (m[cc] != 0.0f) continue;
      const int p = label_cell[static_cast<std::size_t>(lab[cc])];
      float v = val[p];
      if (d[cc] <= reach) {
        const int pr = p / cols, pc = p % cols;
        v += (sgx[p] * static_cast<float>(cc - pc) + sgy[p] * static_cast<float>(rr - pr)) / sm[p];
        v = std::clamp(v, lo, hi);
        ++out.filled_cells;
      }
      val[rr * cols + cc] = v;
    }
  }
  out.value = std::move(value);
  out.seconds = seconds_since(t0);
  return out;
}

/// Bilateral envelope of the filled input `fill` (fill_for_envelope) over its inner rows × cols
/// (f − ref; f_b − ref at valid cells, other cells undefined). `range`, when given, is the
/// level-wide {min, max} of the whole grid's filled input: the block's values are clamped to it
/// and the two are put in a row beyond every inner window's reach, so OpenCV's range table (built
/// from the image's min and max) is the whole grid's.
EnvelopeResult filter_envelope(FillResult&& fill, int inner_rows, int inner_cols, const SurfaceLayerOptions& o,
                               const float* range) {
  EnvelopeResult out;
  const int r = fill.radius_cells;
  out.diameter_cells = 2 * r + 1;
  out.filled_cells = fill.filled_cells;
  out.fill_seconds = fill.seconds;
  cv::Mat value = std::move(fill.value);
  if (range) {
    cv::Mat grown(value.rows + 1, value.cols, CV_32F);
    cv::Mat body = grown.rowRange(0, value.rows);
    cv::min(cv::max(value, range[0]), range[1], body);
    float* extra = grown.ptr<float>(value.rows);
    std::fill(extra, extra + value.cols, range[0]);
    extra[value.cols - 1] = range[1];
    value = grown;
  }
  double dmin = 0.0, dmax = 0.0;
  cv::minMaxLoc(value, &dmin, &dmax);
  const float fmin = static_cast<float>(dmin), fmax = static_cast<float>(dmax);
  // OpenCV's bilateral filter builds its range table from (max − min) in float; a range that
  // overflows it, or leaves too little precision for sigma_range, makes it read out of bounds.
  const double value_range = static_cast<double>(fmax) - fmin;
  if (!(value_range <= kMaxEnvelopeRangeM)) {
    std::ostringstream msg;
    msg << "surface layers: the depth values span " << value_range << " m (from " << fmin << " to " << fmax
        << " m), more than the " << kMaxEnvelopeRangeM
        << " m the bilateral envelope can filter; expected a scan of bounded depth (far outliers? enable "
           "filters.outliers or crop with filters.crop)";
    throw InputError(msg.str());
  }
  const auto t1 = Clock::now();
  cv::Mat filtered;
  cv::bilateralFilter(value, filtered, out.diameter_cells, o.sigma_range_m, o.sigma_space_cells,
                      cv::BORDER_REPLICATE);
  out.envelope = filtered(cv::Rect(r, r, inner_cols, inner_rows)).clone();
  out.filter_seconds = seconds_since(t1);
  out.lut_bin_m = static_cast<double>(fmax - fmin) / 4096.0;
  return out;
}

/// Bilateral envelope of (f − ref) where `valid` marks data. See compute_surface_layers' comment.
EnvelopeResult bilateral_envelope(const cv::Mat& f, const cv::Mat& valid, const SurfaceLayerOptions& o) {
  return filter_envelope(fill_for_envelope(f, valid, o, nullptr), f.rows, f.cols, o, nullptr);
}

/// First (and second) derivative along one axis at index i of n, step `stride` in `v`, spacing
/// 1/inv_d: central if both neighbours are valid, else second-order one-sided over 3 cells.
/// Returns false when no stencil exists.
template <class T>
bool axis_derivative(const T* v, int i, int n, std::ptrdiff_t stride, double inv_d, double& d1,
                     double* d2) {
  auto at = [&](int k) -> double { return static_cast<double>(v[k * stride]); };
  auto good = [&](int k) { return i + k >= 0 && i + k < n && !std::isnan(at(k)); };
  const double h0 = at(0);
  if (good(-1) && good(1)) {
    d1 = 0.5 * (at(1) - at(-1)) * inv_d;
    if (d2) *d2 = (at(1) - 2.0 * h0 + at(-1)) * inv_d * inv_d;
    return true;
  }
  for (int s : {1, -1}) {
    if (good(s) && good(2 * s)) {
      d1 = s * (-3.0 * h0 + 4.0 * at(s) - at(2 * s)) * 0.5 * inv_d;
      if (d2) *d2 = (h0 - 2.0 * at(s) + at(2 * s)) * inv_d * inv_d;
      return true;
    }
  }
  return false;
}

}  // namespace

FrictionModel friction_model_from_string(const std::string& name) {
  if (name == "paper") return FrictionModel::kPaper;
  if (name == "curvature") return FrictionModel::kCurvature;
  throw ConfigError("layers.friction.model = '" + name + "': expected one of paper, curvature");
}

std::string to_string(FrictionModel model) {
  return model == FrictionModel::kPaper ? "paper" : "curvature";
}

FrictionScale friction_scale_from_string(const std::string& name) {
  if (name == "scene") return FrictionScale::kScene;
  if (name == "device") return FrictionScale::kDevice;
  if (name == "level_median") return FrictionScale::kLevelMedian;
  throw ConfigError("layers.friction.scale = '" + name + "': expected one of scene, device, level_median");
}

std::string to_string(FrictionScale scale) {
  switch (scale) {
    case FrictionScale::kScene: return "scene";
    case FrictionScale::kDevice: return "device";
    case FrictionScale::kLevelMedian: break;
  }
  return "level_median";
}

double device_scale(double workspace_radius_m, int window_cells, double cell_size_m) {
  if (window_cells < 2) {
    throw ConfigError("friction: lod.window_cells = " + std::to_string(window_cells) +
                      ": expected at least 2 samples to map a haptic window into the workspace");
  }
  if (!(workspace_radius_m > 0.0) || !std::isfinite(workspace_radius_m)) {
    throw ConfigError("friction: layers.friction.workspace_radius_m = " + format_number(workspace_radius_m) +
                      ": expected a radius > 0 m");
  }
  if (!(cell_size_m > 0.0) || !std::isfinite(cell_size_m)) {
    throw ConfigError("friction: cell size " + format_number(cell_size_m) + " m: expected a cell size > 0 m");
  }
  return 2.0 * workspace_radius_m / (static_cast<double>(window_cells - 1) * cell_size_m);
}

FrictionHistogram friction_histogram(const HeightField& mu_d, double mu_min, double mu_max, int bins) {
  if (bins < 1) throw ConfigError("friction histogram: " + std::to_string(bins) + " bins: expected at least 1");
  if (!(mu_max >= mu_min)) {
    throw ConfigError("friction histogram: mu_max = " + format_number(mu_max) + " < mu_min = " + format_number(mu_min));
  }
  FrictionHistogram h;
  h.bins.assign(static_cast<std::size_t>(bins), 0);
  const float lo = static_cast<float>(mu_min), hi = static_cast<float>(mu_max);
  for (float v : mu_d.values()) {
    if (std::isnan(v)) continue;
    ++h.valid;
    if (v <= lo) {
      ++h.at_min;
    } else if (v >= hi) {
      ++h.at_max;
    } else {
      const double t = (static_cast<double>(v) - mu_min) / (mu_max - mu_min);
      const auto k = static_cast<std::size_t>(std::clamp(static_cast<int>(std::ceil(t * bins)) - 1, 0, bins - 1));
      ++h.bins[k];
    }
  }
  return h;
}

double friction_s(float mean_per_m, float gaussian_per_m2, double sigma) {
  const double H = mean_per_m / sigma;
  const double K = gaussian_per_m2 / (sigma * sigma);
  // H [1/m] and K [1/m²] are added as numbers in SI (scene or device metres), as the paper prints it.
  return std::sqrt(H * H + K * K);
}

double friction_mu_d(double s, double s_ref, const SurfaceLayerOptions& options) {
  const double mu_min = options.mu_min;
  const double mu_max = options.mu_max;
  const double R = options.workspace_radius_m;
  double mu;
  if (options.friction_scale == FrictionScale::kLevelMedian) {
    const double sh = s_ref > 0.0 ? s / s_ref : 0.0;  // ŝ, dimensionless
    if (options.friction_model == FrictionModel::kPaper) {
      // μ = √(μ_min μ_max)/ŝ ≥ μ_max ⇔ ŝ·μ_max ≤ √(μ_min μ_max) (covers ŝ = 0 without dividing).
      const double mu_mid = std::sqrt(mu_min * mu_max);
      mu = (sh * mu_max <= mu_mid) ? mu_max : std::max(mu_min, mu_mid / sh);
    } else {
      mu = std::min(mu_max, mu_min + 0.5 * (mu_max - mu_min) * sh);
    }
  } else if (options.friction_model == FrictionModel::kPaper) {
    // 1/(R·s) ≥ μ_max ⇔ R·s·μ_max ≤ 1 (also covers s = 0 without dividing by zero).
    mu = (R * s * mu_max <= 1.0) ? mu_max : std::max(mu_min, 1.0 / (R * s));
  } else {
    mu = std::min(mu_max, mu_min + options.curvature_gain_m * s);
  }
  if (!std::isfinite(mu)) mu = options.friction_model == FrictionModel::kPaper ? mu_min : mu_max;
  return mu;
}

double friction_mu_s(double x_m, double y_m, const SurfaceLayerOptions& options) {
  double mu = options.mu_s;
  for (const StaticFrictionRegion& reg : options.mu_s_regions) {
    if (x_m >= reg.x_min_m && x_m <= reg.x_max_m && y_m >= reg.y_min_m && y_m <= reg.y_max_m) mu = reg.mu_s;
  }
  return mu;
}

double friction_sigma(const SurfaceLayerOptions& options, int window_cells, double cell_size_m) {
  return options.friction_scale == FrictionScale::kScene
             ? 1.0
             : device_scale(options.workspace_radius_m, window_cells, cell_size_m);
}

double friction_s_floor(const SurfaceLayerOptions& options) {
  return options.mu_max > 0.0 ? 1.0 / (options.workspace_radius_m * options.mu_max) : 0.0;
}

int surface_layers_radius_cells(const SurfaceLayerOptions& options) {
  return window_radius_cells(options.sigma_space_cells);
}

int surface_layers_halo_cells(const SurfaceLayerOptions& options) {
  validate(options);
  const int r = window_radius_cells(options.sigma_space_cells);
  // Curvature stencils (4) + the bilateral window (r) + the reach of a fill whose nearest valid
  // cell is found by the 5 × 5 chamfer transform (within 1.5 r + 1, chamfer ≤ 1.1 × Euclidean)
  // + the smoothed gradient at that cell (3) + the chamfer mask (2) + one for rounding.
  return 4 + r + static_cast<int>(std::ceil(1.1 * (1.5 * r + 1.0))) + 6;
}

SurfaceLayerBlock surface_layers_block(const float* depth_m, const SampleWindow& window, const GridGeometry& level,
                                       const SampleWindow& inner, const SurfaceLayerLevelValues& values, bool fill_only,
                                       const SurfaceLayerOptions& options, int window_cells) {
  validate(options);
  const int wr = window.rows, wc = window.cols;
  if (wr < 1 || wc < 1 || window.row0 < 0 || window.col0 < 0 || window.row0 + wr > level.rows ||
      window.col0 + wc > level.cols || inner.row0 < window.row0 || inner.col0 < window.col0 || inner.rows < 1 ||
      inner.cols < 1 || inner.row0 + inner.rows > window.row0 + wr || inner.col0 + inner.cols > window.col0 + wc) {
    throw std::invalid_argument("surface_layers_block: the inner block must lie in the window and the window in the level");
  }
  const double ref = values.ref_m;
  cv::Mat fm(wr, wc, CV_32F);
  cv::Mat valid(wr, wc, CV_8U);
  for (int r = 0; r < wr; ++r) {
    for (int c = 0; c < wc; ++c) {
      const float v = depth_m[static_cast<std::size_t>(r) * static_cast<std::size_t>(wc) + static_cast<std::size_t>(c)];
      const bool ok = !std::isnan(v);
      valid.at<std::uint8_t>(r, c) = ok ? 1 : 0;
      fm.at<float>(r, c) = ok ? static_cast<float>(static_cast<double>(v) - ref) : 0.0f;
    }
  }
  SurfaceLayerBlock out;
  out.rows = inner.rows;
  out.cols = inner.cols;
  FillResult fill = fill_for_envelope(fm, valid, options, values.band_m);
  const int rad = fill.radius_cells;
  if (fill_only) {
    // The cells this block owns in the whole grid's padded input: its inner cells, and the
    // padding beside them where they touch the level's edge.
    int p_r0 = inner.row0 - window.row0 + rad, p_c0 = inner.col0 - window.col0 + rad;
    int p_r1 = p_r0 + inner.rows, p_c1 = p_c0 + inner.cols;
    if (inner.row0 == 0) p_r0 -= rad;
    if (inner.col0 == 0) p_c0 -= rad;
    if (inner.row0 + inner.rows == level.rows) p_r1 += rad;
    if (inner.col0 + inner.cols == level.cols) p_c1 += rad;
    double lo = values.band_m[0], hi = values.band_m[1];
    cv::minMaxLoc(fill.value(cv::Range(p_r0, p_r1), cv::Range(p_c0, p_c1)), &lo, &hi);
    out.fill_min_m = std::min(static_cast<float>(lo), values.band_m[0]);
    out.fill_max_m = std::max(static_cast<float>(hi), values.band_m[1]);
    return out;
  }
  const EnvelopeResult env = filter_envelope(std::move(fill), wr, wc, options, values.fill_range_m);
  GridGeometry wg = level;
  wg.rows = wr;
  wg.cols = wc;
  HeightField texture(wg);
  for (int r = 0; r < wr; ++r) {
    for (int c = 0; c < wc; ++c) {
      if (valid.at<std::uint8_t>(r, c) == 0) continue;
      texture.at(r, c) = fm.at<float>(r, c) - env.envelope.at<float>(r, c);
    }
  }
  const Curvature curv = compute_curvature(texture);
  const double sigma = friction_sigma(options, window_cells, level.cell_size_m);
  const std::size_t n = static_cast<std::size_t>(inner.rows) * static_cast<std::size_t>(inner.cols);
  out.envelope_m.assign(n, kNoData);
  out.texture_m.assign(n, kNoData);
  out.s.assign(n, -1.0);
  const int dr = inner.row0 - window.row0, dc = inner.col0 - window.col0;
  for (int r = 0; r < inner.rows; ++r) {
    for (int c = 0; c < inner.cols; ++c) {
      if (valid.at<std::uint8_t>(r + dr, c + dc) == 0) continue;
      const std::size_t i = static_cast<std::size_t>(r) * static_cast<std::size_t>(inner.cols) + static_cast<std::size_t>(c);
      const float fb = env.envelope.at<float>(r + dr, c + dc);
      out.envelope_m[i] = static_cast<float>(static_cast<double>(fb) + ref);
      out.texture_m[i] = texture.at(r + dr, c + dc);
      out.s[i] = friction_s(curv.mean_per_m.at(r + dr, c + dc), curv.gaussian_per_m2.at(r + dr, c + dc), sigma);
    }
  }
  return out;
}

Curvature compute_curvature(const HeightField& surface_m) {
  const GridGeometry& g = surface_m.geometry();
  const int rows = g.rows;
  const int cols = g.cols;
  const double inv_d = 1.0 / g.cell_size_m;
  const std::size_t n = g.cell_count();
  const float nan = kNoData;
  std::vector<float> hx(n, nan), hy(n, nan), hxx(n, nan), hyy(n, nan);
  const float* h = surface_m.data();
  auto idx = [cols](int r, int c) { return static_cast<std::size_t>(r) * static_cast<std::size_t>(cols) +
                                           static_cast<std::size_t>(c); };
  // Rows are independent within each pass: OpenCV's thread pool (default thread count).
  cv::parallel_for_(cv::Range(0, rows), [&](const cv::Range& range) {
    for (int r = range.start; r < range.end; ++r) {
      for (int c = 0; c < cols; ++c) {
        const std::size_t i = idx(r, c);
        if (std::isnan(h[i])) continue;
        double d1 = 0, d2 = 0;
        if (axis_derivative(h + i, c, cols, 1, inv_d, d1, &d2)) {
          hx[i] = static_cast<float>(d1);
          hxx[i] = static_cast<float>(d2);
        }
        if (axis_derivative(h + i, r, rows, cols, inv_d, d1, &d2)) {
          hy[i] = static_cast<float>(d1);
          hyy[i] = static_cast<float>(d2);
        }
      }
    }
  });
  Curvature out{HeightField(g), HeightField(g), 0};
  out.mean_per_m.model_to_grid = surface_m.model_to_grid;
  out.gaussian_per_m2.model_to_grid = surface_m.model_to_grid;
  float* H = out.mean_per_m.data();
  float* K = out.gaussian_per_m2.data();
  std::atomic<std::size_t> zero_fallback{0};
  cv::parallel_for_(cv::Range(0, rows), [&](const cv::Range& range) {
    std::size_t zeros = 0;
    for (int r = range.start; r < range.end; ++r) {
      for (int c = 0; c < cols; ++c) {
        const std::size_t i = idx(r, c);
        if (std::isnan(h[i])) continue;
        H[i] = 0.0f;
        K[i] = 0.0f;
        if (std::isnan(hx[i]) || std::isnan(hy[i])) {
          ++zeros;
          continue;
        }
        double xy_a = 0, xy_b = 0;
        const bool a = axis_derivative(hx.data() + i, r, rows, cols, inv_d, xy_a, nullptr);
        const bool b = axis_derivative(hy.data() + i, c, cols, 1, inv_d, xy_b, nullptr);
        if (!a && !b) {
          ++zeros;
          continue;
        }
        const double hxy = a && b ? 0.5 * (xy_a + xy_b) : (a ? xy_a : xy_b);
        const double px = hx[i], py = hy[i], pxx = hxx[i], pyy = hyy[i];
        const double q = 1.0 + px * px + py * py;
        const double mean = (pxx * (1.0 + py * py) + pyy * (1.0 + px * px) - 2.0 * hxy * px * py) /
                            (2.0 * q * std::sqrt(q));
        const double gauss = (pxx * pyy - hxy * hxy) / (q * q);
        H[i] = static_cast<float>(mean);
        K[i] = static_cast<float>(gauss);
      }
    }
    zero_fallback += zeros;
  });
  out.zero_fallback_cells = zero_fallback.load();
  return out;
}

StageResult<SurfaceLayers> compute_surface_layers(const HeightField& depth_m,
                                                  const SurfaceLayerOptions& options, int window_cells) {
  const auto t_start = Clock::now();
  validate(options);
  const GridGeometry& g = depth_m.geometry();
  if (g.rows < 1 || g.cols < 1 || !(g.cell_size_m > 0.0) || depth_m.values().size() != g.cell_count()) {
    throw InputError("surface layers: depth grid is empty or malformed (" + std::to_string(g.rows) + " × " +
                     std::to_string(g.cols) + " cells, cell size " + format_number(g.cell_size_m) +
                     " m): expected ≥ 1 × 1 cells and a cell size > 0");
  }
  const std::size_t n = g.cell_count();
  const float* f = depth_m.data();
  std::size_t valid_cells = 0;
  ExactFloatSum sum;  // exact: a level's blocks (surface_layers_block) get the same mean
  for (std::size_t i = 0; i < n; ++i) {
    if (std::isnan(f[i])) continue;
    if (std::isinf(f[i])) {
      throw InputError("surface layers: depth grid cell (" + std::to_string(i / static_cast<std::size_t>(g.cols)) +
                       ", " + std::to_string(i % static_cast<std::size_t>(g.cols)) +
                       ") is infinite: expected a finite height in metres or NaN (no data)");
    }
    ++valid_cells;
    sum.add(f[i]);
  }
  if (valid_cells == 0) {
    throw InputError("surface layers: the depth grid (" + std::to_string(g.rows) + " × " + std::to_string(g.cols) +
                     " cells) has no valid cell: expected at least one finite height");
  }
  // Work relative to the mean height so float keeps sub-micrometre resolution.
  const double ref = sum.value() / static_cast<double>(valid_cells);
  cv::Mat fm(g.rows, g.cols, CV_32F);
  cv::Mat valid(g.rows, g.cols, CV_8U);
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      const float v = depth_m.at(r, c);
      const bool ok = !std::isnan(v);
      valid.at<std::uint8_t>(r, c) = ok ? 1 : 0;
      fm.at<float>(r, c) = ok ? static_cast<float>(static_cast<double>(v) - ref) : 0.0f;
    }
  }

  EnvelopeResult env = bilateral_envelope(fm, valid, options);

  // Each working array goes as soon as it is used up, and the friction maps come after the
  // curvature: a whole grid's layers peaked at about 53 bytes a sample with every array alive to
  // the end (446 MB at 4096 × 2049, 2026-11-26), about 36 now; the values are the same.
  StageResult<SurfaceLayers> result;
  SurfaceLayers& L = result.value;
  L.friction_model = options.friction_model;
  L.envelope_m = HeightField(g);
  L.texture_m = HeightField(g);
  for (HeightField* layer : {&L.envelope_m, &L.texture_m}) layer->model_to_grid = depth_m.model_to_grid;
  double sum_h2 = 0.0, max_abs_h = 0.0;
  for (int r = 0; r < g.rows; ++r) {
    for (int c = 0; c < g.cols; ++c) {
      if (valid.at<std::uint8_t>(r, c) == 0) continue;
      const float fb = env.envelope.at<float>(r, c);
      const float h = fm.at<float>(r, c) - fb;
      L.envelope_m.at(r, c) = static_cast<float>(static_cast<double>(fb) + ref);
      L.texture_m.at(r, c) = h;
      sum_h2 += static_cast<double>(h) * h;
      max_abs_h = std::max(max_abs_h, std::abs(static_cast<double>(h)));
    }
  }
  fm.release();
  valid.release();
  env.envelope.release();

  const auto t_curv = Clock::now();
  Curvature curv = compute_curvature(L.texture_m);
  L.mean_curvature_per_m = std::move(curv.mean_per_m);
  L.gaussian_curvature_per_m2 = std::move(curv.gaussian_per_m2);
  const double curvature_seconds = seconds_since(t_curv);

  // Friction maps. s = √(H² + K²) in the units of options.friction_scale (docs/friction.md).
  const auto t_fric = Clock::now();
  const double mu_min = options.mu_min;
  const double mu_max = options.mu_max;
  const double R = options.workspace_radius_m;
  const FrictionScale fscale = options.friction_scale;
  // σ: device metres per grid metre (1 for `scene`): H_dev = H/σ [1/m], K_dev = K/σ² [1/m²].
  const double sigma = friction_sigma(options, window_cells, g.cell_size_m);
  // s of cell i (computed again where needed instead of kept: 8 bytes a sample).
  const auto s_of = [&](std::size_t i) {
    return friction_s(L.mean_curvature_per_m.data()[i], L.gaussian_curvature_per_m2.data()[i], sigma);
  };
  std::vector<double> s_positive;
  if (fscale == FrictionScale::kLevelMedian) {
    s_positive.reserve(valid_cells);
    for (std::size_t i = 0; i < n; ++i) {
      if (std::isnan(f[i])) continue;
      const double s = s_of(i);
      if (s > 0.0 && std::isfinite(s)) s_positive.push_back(s);
    }
  }
  // Reference for `level_median`: the median of s over the cells with s > 0, but never below
  // the flatness floor 1/(R·μ_max) [device units]: the curvature that the paper's own formula
  // maps to μ_max. A texture whose median is below it is flat to the hand (float rounding on a
  // plane, say) and is not stretched over the whole friction range.
  double s_ref = 0.0, s_median = 0.0;
  const double s_floor = friction_s_floor(options);
  if (!s_positive.empty()) {
    const auto mid_s = s_positive.begin() + static_cast<std::ptrdiff_t>(s_positive.size() / 2);
    std::nth_element(s_positive.begin(), mid_s, s_positive.end());
    s_median = *mid_s;
  }
  if (fscale == FrictionScale::kLevelMedian) s_ref = std::max(s_median, s_floor);
  std::vector<double>().swap(s_positive);
  L.mu_d = HeightField(g);
  L.mu_s = HeightField(g);
  for (HeightField* layer : {&L.mu_d, &L.mu_s}) layer->model_to_grid = depth_m.model_to_grid;
  std::size_t at_min = 0, at_max = 0;
  std::vector<float> mu_values;
  mu_values.reserve(valid_cells);
  for (std::size_t i = 0; i < n; ++i) {
    if (std::isnan(f[i])) continue;
    const double mu = friction_mu_d(s_of(i), s_ref, options);
    at_min += mu <= mu_min ? 1U : 0U;
    at_max += mu >= mu_max ? 1U : 0U;
    L.mu_d.data()[i] = static_cast<float>(mu);
    mu_values.push_back(static_cast<float>(mu));
  }
  for (int r = 0; r < g.rows; ++r) {
    const double y = g.y_of_row(r);
    for (int c = 0; c < g.cols; ++c) {
      if (std::isnan(depth_m.at(r, c))) continue;
      L.mu_s.at(r, c) = static_cast<float>(friction_mu_s(g.x_of_col(c), y, options));
    }
  }
  const double friction_seconds = seconds_since(t_fric);

  StageReport& rep = result.report;
  rep.stage = "surface_layers";
  rep.count_in = valid_cells;
  rep.count_out = valid_cells;
  const double nv = static_cast<double>(valid_cells);
  rep.figure("grid_cells", static_cast<double>(n));
  rep.figure("bilateral_diameter_cells", env.diameter_cells);
  rep.figure("hole_fill_cells", static_cast<double>(env.filled_cells));
  rep.figure("hole_fill_seconds", env.fill_seconds);
  rep.figure("bilateral_seconds", env.filter_seconds);
  rep.figure("curvature_seconds", curvature_seconds);
  rep.figure("friction_seconds", friction_seconds);
  rep.figure("texture_rms_mm", 1e3 * std::sqrt(sum_h2 / nv));
  rep.figure("texture_max_abs_mm", 1e3 * max_abs_h);
  rep.figure("curvature_zero_fallback_cells", static_cast<double>(curv.zero_fallback_cells));
  const auto mid = mu_values.begin() + static_cast<std::ptrdiff_t>(mu_values.size() / 2);
  std::nth_element(mu_values.begin(), mid, mu_values.end());
  rep.figure("mu_d_median", *mid);
  rep.figure("mu_d_min", *std::min_element(mu_values.begin(), mu_values.end()));
  rep.figure("mu_d_max", *std::max_element(mu_values.begin(), mu_values.end()));
  rep.figure("mu_d_at_min_fraction", static_cast<double>(at_min) / nv);
  rep.figure("mu_d_at_max_fraction", static_cast<double>(at_max) / nv);
  rep.figure("friction_device_scale", sigma);
  if (fscale == FrictionScale::kLevelMedian) {
    rep.figure("friction_s_median", s_median);
    rep.figure("friction_s_reference", s_ref);
  }
  {
    const FrictionHistogram hist = friction_histogram(L.mu_d, mu_min, mu_max);
    for (std::size_t k = 0; k < hist.bins.size(); ++k) {
      rep.figure("mu_d_bin_" + std::to_string(k) + "_fraction", static_cast<double>(hist.bins[k]) / nv);
    }
  }
  if (fscale == FrictionScale::kScene) {
    rep.notes.push_back("friction.scale = scene: H [1/m] and K [1/m^2] in scene metres");
  } else {
    rep.notes.push_back("friction.scale = " + to_string(fscale) + ": H and K in device metres, sigma = 2R/((" +
                        std::to_string(window_cells) + " - 1) * cell) = " + format_number(sigma) +
                        " device m per scene m" +
                        (fscale == FrictionScale::kLevelMedian
                             ? "; s divided by max(its median over cells with s > 0, 1/(R*mu_max)) = " +
                                   format_number(s_ref) + ", c unused, mid-range constants"
                             : std::string()));
  }
  if (options.friction_model == FrictionModel::kPaper) {
    rep.notes.push_back("friction.model = paper: mu_d = 1/(R*sqrt(H^2+K^2)) with R = " + format_number(R) +
                        " m, clamped to [" + format_number(mu_min) + ", " + format_number(mu_max) +
                        "]; friction falls as curvature grows (flat texture -> mu_max)");
  } else {
    rep.notes.push_back("friction.model = curvature: mu_d = mu_min + c*sqrt(H^2+K^2) with c = " +
                        format_number(options.curvature_gain_m) + " m, clamped to [" + format_number(mu_min) + ", " + format_number(mu_max) +
                        "]; friction grows with curvature (flat texture -> mu_min)");
  }
  rep.notes.push_back("envelope: cv::bilateralFilter, sigma_s = " + format_number(options.sigma_space_cells) +
                      " cells, sigma_r = " + format_number(options.sigma_range_m) + " m, window " +
                      std::to_string(env.diameter_cells) + " cells; no-data cells and the border filled by "
                      "first-order normalised convolution for the filter input only");
  if (env.lut_bin_m > 0.25 * options.sigma_range_m) {
    rep.notes.push_back("warning: the filter input spans " + format_number(env.lut_bin_m * 4096.0) +
                        " m, so OpenCV's 4096-entry range table steps by " + format_number(env.lut_bin_m) +
                        " m, more than sigma_r/4: the range kernel is coarsely quantised");
  }
  rep.seconds = seconds_since(t_start);
  return result;
}

}  // namespace hc::pipeline
