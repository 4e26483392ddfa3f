#pragma once
// The 3 × 3 solve of the despike's least-squares planes (honest_check.cpp, PlaneSums), in a
// translation unit of its own that the sanitizer builds compile uninstrumented
// (pipeline/CMakeLists.txt; docs/ci.md, "The plane solve outside the sanitizers").

namespace hc::pipeline::detail {

/// Solves the symmetric normal equations A·x = b of a plane fit with Eigen's LDLT (Eigen 3.4,
/// `Eigen::LDLT<Matrix3d>`: robust pivoting Cholesky; reciprocal condition from its L1-norm
/// estimate).
///
/// a: A's 9 entries, row-major (A is symmetric: a[1] == a[3], a[2] == a[6], a[5] == a[7]),
///    in the units of the caller's sums (cell counts and cell offsets: PlaneSums).
/// b: the right-hand side, 3 entries [m, m·cell, m·cell]. x: the solution, written only when
///    the solve succeeds [m, m/cell, m/cell].
/// Returns false, x untouched, when the LDLT fails, its reciprocal condition is under
/// min_rcond, or x is not finite. No error is thrown; every pointer must hold its entries.
/// The values are those of the same Eigen calls made inline (IEEE double, no contraction:
/// the release and sanitizer builds give the same bits).
bool solve_plane_ldlt(const double* a, const double* b, double min_rcond, double* x) noexcept;

}  // namespace hc::pipeline::detail
