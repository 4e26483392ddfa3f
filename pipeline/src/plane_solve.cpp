// The despike's 3 × 3 plane solve (plane_solve.hpp). Compiled without ASan and UBSan in every
// build (pipeline/CMakeLists.txt) and kept out of the unity batches: its whole call tree is
// Eigen's fixed-size LDLT on values on this function's stack, where instrumentation has
// nothing to find, and under ASan at -O1 that instrumented template code took 60 % of the
// despike-heavy tests' time (TileJobs.AMergeOnAGrid..., perf, 2026-12-02; docs/ci.md).
#include "plane_solve.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Core>

namespace hc::pipeline::detail {

bool solve_plane_ldlt(const double* a, const double* b, double min_rcond, double* x) noexcept {
  Eigen::Matrix3d m;
  m << a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8];
  const Eigen::LDLT<Eigen::Matrix3d> ldlt(m);
  if (ldlt.info() != Eigen::Success || ldlt.rcond() < min_rcond) return false;
  const Eigen::Vector3d coef = ldlt.solve(Eigen::Vector3d(b[0], b[1], b[2]));
  if (!coef.allFinite()) return false;
  x[0] = coef(0);
  x[1] = coef(1);
  x[2] = coef(2);
  return true;
}

}  // namespace hc::pipeline::detail
