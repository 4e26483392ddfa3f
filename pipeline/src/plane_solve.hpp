#pragma once
// The 3 × 3 solve of the despike's least-squares planes (honest_check.cpp, PlaneSums), in a
// translation unit of its own that the sanitizer builds compile uninstrumented
// (pipeline/CMakeLists.txt; docs/ci.md, "2026-12-02 (seventy-third session)").

#include <Eigen/Core>

#include <optional>

namespace hc::pipeline::detail {

/// Solves the symmetric 3 × 3 normal equations a·x = b of a least-squares plane fit with
/// Eigen's LDLT (Eigen 3.4, `Eigen::LDLT<Matrix3d>`: Cholesky with symmetric pivoting; the
/// reciprocal condition number is its L1-norm estimate, `LDLT::rcond`).
///
/// a: the normal matrix (symmetric), b: the right-hand side, both in the units of the caller's
/// sums (PlaneSums: cell counts and offsets [cells], heights [m]). Returns x ([m, m/cell,
/// m/cell] for PlaneSums), or nullopt when the LDLT fails, its reciprocal condition is under
/// min_rcond, or x is not finite; nothing is thrown. The values are those of the same Eigen
/// calls made inline (IEEE double, no contraction): release and sanitizer builds agree bit for bit.
std::optional<Eigen::Vector3d> solve_plane_ldlt(const Eigen::Matrix3d& a, const Eigen::Vector3d& b,
                                                double min_rcond) noexcept;

}  // namespace hc::pipeline::detail
