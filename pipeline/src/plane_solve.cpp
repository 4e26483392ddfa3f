// The despike's 3 × 3 plane solve (plane_solve.hpp). Compiled without ASan and UBSan in every
// build (pipeline/CMakeLists.txt) and kept out of the unity batches: its whole call tree is
// Eigen's fixed-size LDLT on values on this function's stack, where instrumentation has
// nothing to find, and under ASan at -O1 that instrumented template code took 60 % of the
// despike-heavy tests' time (TileJobs.AMergeOnAGrid..., perf, 2026-12-02; docs/ci.md).
#include "plane_solve.hpp"

#include <Eigen/Cholesky>

namespace hc::pipeline::detail {

std::optional<Eigen::Vector3d> solve_plane_ldlt(const Eigen::Matrix3d& a, const Eigen::Vector3d& b,
                                                double min_rcond) noexcept {
  const Eigen::LDLT<Eigen::Matrix3d> ldlt(a);
  if (ldlt.info() != Eigen::Success || ldlt.rcond() < min_rcond) return std::nullopt;
  const Eigen::Vector3d x = ldlt.solve(b);
  if (!x.allFinite()) return std::nullopt;
  return x;
}

}  // namespace hc::pipeline::detail
