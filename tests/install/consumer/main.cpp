// A consumer of an installed hapticloud (tests/install/consumer_test.cmake): builds the scene of
// the installed configs/sinusoid.yaml in memory and checks its depth grid against the analytic
// surface z = A·sin(2πx/λ)·sin(2πy/λ) it was sampled from (paper Sec. 5.1), and a bilinear
// sample between nodes against the same formula. Exit 0 when both agree within the bounds below.
//
//   consumer SINUSOID_CONFIG.yaml

#include <hc/common/bilinear_surface.hpp>
#include <hc/pipeline/config.hpp>
#include <hc/pipeline/run.hpp>
#include <hc/pipeline/synthetic.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s SINUSOID_CONFIG.yaml\n", argv[0]);
    return 2;
  }
  try {
    // 100 × 100 cells of 1 mm over the 10 cm square; the levels table is not needed here.
    const hc::pipeline::RunConfig cfg = hc::pipeline::load_run_config(argv[1], {"grid.n=100", "lod.report=false"});
    if (!cfg.input.synthetic) {
      std::fprintf(stderr, "%s: expected a synthetic input\n", argv[1]);
      return 1;
    }
    const hc::pipeline::BuiltScene built = hc::pipeline::build_scene(cfg);
    const hc::Scene& scene = built.scene;
    const hc::GridGeometry& g = scene.geometry;
    // Grid frame → the surface's own frame (the run recentres, the view is the identity).
    const Eigen::Affine3d grid_to_model = scene.model_to_grid.inverse();
    double sum2 = 0.0, max_abs = 0.0;
    long valid = 0;
    for (int r = 0; r < g.rows; ++r) {
      for (int c = 0; c < g.cols; ++c) {
        if (!scene.layers.depth.valid(r, c)) continue;
        const Eigen::Vector3d m = grid_to_model * Eigen::Vector3d(g.x_of_col(c), g.y_of_row(r), scene.layers.depth.at(r, c));
        const double e = m.z() - hc::pipeline::synthetic_height(*cfg.input.synthetic, m.x(), m.y());
        sum2 += e * e;
        max_abs = std::max(max_abs, std::abs(e));
        ++valid;
      }
    }
    const double rms_mm = valid > 0 ? 1e3 * std::sqrt(sum2 / static_cast<double>(valid)) : 0.0;
    std::printf("consumer: %d x %d grid, %ld valid nodes, against the analytic surface RMS %.4f mm, max %.4f mm\n",
                g.rows, g.cols, valid, rms_mm, 1e3 * max_abs);
    // Bound: a node takes the front-most sample of its 1 mm cell (disc splats), which lies within
    // the half-diagonal 0.71 mm of the node; the steepest slope is 2πA/λ ≈ 0.79 (A = 5 mm,
    // λ = 40 mm), so |error| ≤ 0.79 · 0.71 mm + 5σ of the 0.02 mm noise ≈ 0.66 mm.
    const hc::pipeline::SyntheticSpec& spec = *cfg.input.synthetic;
    const double bound_mm =
        2.0 * M_PI * spec.amplitude_m / spec.wavelength_m * (std::sqrt(0.5) * 1e3 * g.cell_size_m) + 5e3 * spec.noise_sigma_m;
    if (valid < g.rows * g.cols * 9 / 10 || !(1e3 * max_abs <= bound_mm)) {
      std::fprintf(stderr, "consumer: the grid does not match the analytic surface\n");
      return 1;
    }
    // hapticloud::common's bilinear interpolant between nodes, at a cell centre near the middle:
    // within the same bound plus the interpolant's own error (curvature·cell²/8 < 0.05 mm).
    const hc::BilinearSurface surface(hc::HeightFieldView::of(scene.layers.depth));
    const double x = g.x_of_col(g.cols / 2) + 0.5 * g.cell_size_m, y = g.y_of_row(g.rows / 2) + 0.5 * g.cell_size_m;
    const hc::SurfaceSample s = surface.sample(x, y);
    const Eigen::Vector3d m = grid_to_model * Eigen::Vector3d(x, y, s.z_m);
    const double e_mm = 1e3 * (m.z() - hc::pipeline::synthetic_height(*cfg.input.synthetic, m.x(), m.y()));
    std::printf("consumer: bilinear sample at a cell centre off the analytic surface by %.4f mm\n", e_mm);
    if (!s.valid || !(std::abs(e_mm) <= bound_mm + 0.05)) {
      std::fprintf(stderr, "consumer: the bilinear sample does not match the analytic surface\n");
      return 1;
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "consumer: %s\n", e.what());
    return 1;
  }
}
