#pragma once
/// @file relief.hpp
/// Generated large relief scans for the scaling work of issue 14: a carved stone wall (courses
/// of blocks with mortar joints, a rosette medallion on every block, a fine chisel texture),
/// sampled as a terrestrial survey would see it (noise on z, points on the wall's back face,
/// a few outliers), written as binary PLY or LAS in chunks so that 10⁹ points need no more
/// memory than one chunk (ReliefSpec::sorted, a permutation at write time, also holds 12 bytes a
/// point while sorting).
///
/// Every point is a pure function of (seed, index): a counter-based generator (SplitMix64 of the
/// seed and the index) draws its class, position and noise. So a file does not depend on the
/// chunk size or the thread count, any point can be recomputed from its index (the tests'
/// oracle), and two runs with the same spec write the same bytes.
///
/// Frame: x to the right along the wall, y up, z towards the viewer, metres; the front face's
/// flat ashlar lies at z = 0, the back face at z = −thickness_m. Viewed along −z (the project's
/// default view) the front face is the Monge surface z = relief_height_m(x, y).

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>

namespace hc::tools {

/// What one generated scan holds. Defaults: the 2 m × 1 m wall of the issue-14 measurements.
struct ReliefSpec {
  double width_m = 2.0;            ///< along x, > 0
  double height_m = 1.0;           ///< along y, > 0
  std::uint64_t points = 1'000'000;  ///< total points, ≥ 1 (LAS 1.2: ≤ 2³² − 1)
  double relief_depth_m = 0.03;    ///< how far a medallion stands out of the ashlar, ≥ 0
  double course_m = 0.25;          ///< block height (horizontal joints every course_m), > 0
  double block_m = 0.5;            ///< block length (vertical joints, staggered per course), > 0
  double joint_depth_m = 0.006;    ///< mortar joint depth (Gaussian groove), ≥ 0
  double joint_half_width_m = 0.004;  ///< the groove's 1/e half-width, > 0
  double chisel_amplitude_m = 0.0003;  ///< fine tooling marks, ≥ 0
  double chisel_wavelength_m = 0.004;  ///< their wavelength, > 0
  double noise_sigma_m = 0.0005;   ///< Gaussian range noise on z, ≥ 0
  double thickness_m = 0.3;        ///< wall thickness (back face at −thickness_m), > 0
  double back_fraction = 0.05;     ///< share of points on the back face, in [0, 1]
  double outlier_fraction = 0.001;  ///< share of outliers, in [0, 1]; back + outliers ≤ 1
  /// Outliers are uniform in the box of the wall's x-y extent and z in
  /// [−thickness_m, outlier_reach_m] (a passer-by, a bird, a mixed pixel), ≥ 0.
  double outlier_reach_m = 0.3;
  std::uint64_t seed = 1;
  bool rgb = false;  ///< write a stone colour per point (PLY uchar r g b; LAS point format 2)
  /// The points' order. false (the default): every point's x and y are drawn uniformly over the
  /// wall, so consecutive points lie anywhere on it (the worst case for any per-point access to
  /// a grid). true: the order a terrestrial scanner in front of the wall records them, vertical
  /// profiles from left to right, each from the bottom up: point i lies in cell (column
  /// i / R, row i mod R) of a raster of R = max(1, round(√(points · height_m / width_m))) rows
  /// and C = ⌈points / R⌉ columns over the wall, uniformly within its cell (the last column
  /// holds the remainder, from the bottom). Back-face points and outliers are drawn as in the
  /// default order, at their raster cell's x and y.
  bool scan_order = false;
  /// Written by write_relief only: the default order's points (scan_order false), written in a
  /// scanner's order: by the column of the scan raster their x falls in (scan_raster's C
  /// columns over the wall), then up by y, then by index. The same points as the default file
  /// in another order, so that a run's speed on the two differs by the order alone
  /// (bench/scale.py --order sorted). The permutation is held while writing: 12 bytes a point
  /// while sorting (1.2 GB at 10⁸), 4 after; points < 2³² − 1. relief_point(spec, i) is still
  /// the default order's point i.
  bool sorted = false;
};

/// The class of a generated point.
enum class ReliefPointKind : std::uint8_t { kFront = 0, kBack = 1, kOutlier = 2 };

/// One generated point: position [m] in the wall frame (see the file comment), class and colour.
struct ReliefPoint {
  double x_m = 0.0, y_m = 0.0, z_m = 0.0;
  ReliefPointKind kind = ReliefPointKind::kFront;
  std::uint8_t r = 0, g = 0, b = 0;
};

/// Checks every field of `spec`. @throws hc::ConfigError naming the field, its value and the
/// allowed range.
void validate(const ReliefSpec& spec);

/// The raster of ReliefSpec::scan_order: rows (points per vertical profile) and columns.
struct ScanRaster {
  std::uint64_t rows = 1, cols = 1;
};
/// R = max(1, round(√(points · height_m / width_m))), at most points, and C = ⌈points / R⌉
/// (ReliefSpec::scan_order). Does not validate `spec`.
ScanRaster scan_raster(const ReliefSpec& spec);

/// The front face without noise: z [m] at (x, y) [m], for any x, y (the pattern repeats past
/// the wall's edges). The sum of
///   - the joints: −joint_depth_m · exp(−(d / joint_half_width_m)²), d the distance to the
///     nearest joint line (horizontal every course_m from the bottom edge y = −height_m/2;
///     vertical every block_m from the left edge x = −width_m/2, shifted by block_m/2 on odd
///     courses);
///   - a rosette on every block: with (ρ, θ) the polar offset from the block's centre and
///     R(θ) = 0.35 · min(block_m, course_m) · (1 + 0.15 cos 6θ), relief_depth_m · cos²(π ρ / 2R)
///     for ρ < R, else 0;
///   - the chisel marks: chisel_amplitude_m · sin(2π (x + y/2) / chisel_wavelength_m).
/// Smooth (C¹) except at a rosette's rim, where the height is continuous with zero slope.
double relief_height_m(const ReliefSpec& spec, double x_m, double y_m);

/// Point `index` (0 ≤ index < spec.points) of the scan; the same for any chunking.
/// Classes: the first uniform draw u picks outlier (u < outlier_fraction), back face
/// (u < outlier_fraction + back_fraction) or front face; x, y uniform over the wall (with
/// spec.scan_order: uniform over the point's raster cell); z the face
/// plus N(0, noise_sigma_m²) (Box–Muller), or uniform in the outlier box. Colour (if spec.rgb):
/// a sandstone tone shaded by the height over the ashlar. Does not validate `spec`.
ReliefPoint relief_point(const ReliefSpec& spec, std::uint64_t index);

/// Output format, chosen by the file's extension.
enum class ReliefFormat {
  kPly,  ///< .ply: binary_little_endian 1.0, vertex x y z float [m] (+ red green blue uchar)
  kLas,  ///< .las: LAS 1.2, point data format 0 (2 with rgb), scale 0.1 mm, offset 0, class 1
  /// .e57: ASTM E2807-11, one data3D scan without a pose: cartesianX/Y/Z Float single [m]
  /// (+ colorRed/Green/Blue Integer 0..255), data packets of 4096 records, pages of 1024 bytes
  /// with their CRC-32C (§ 7.3), the XML section after the points.
  kE57,
};

/// What write_relief wrote.
struct ReliefWriteStats {
  std::uint64_t points = 0, front = 0, back = 0, outliers = 0;
  std::uint64_t bytes = 0;
  double seconds = 0.0;
  std::size_t buffer_bytes = 0;  ///< the one chunk buffer (the writer's working memory, besides sorted's permutation)
};

/// Progress: points written so far and the total.
using ReliefProgressFn = std::function<void(std::uint64_t done, std::uint64_t total)>;
/// Told the exclusive temporary's path once it exists, and an empty path once it is gone (put
/// in place, or removed after a failure): a caller's signal clean-up removes what it was told
/// last (hc-gen-relief on SIGINT, SIGTERM or SIGHUP). Called on the writing thread.
using ReliefTemporaryFn = std::function<void(const std::filesystem::path& temporary)>;

/// Writes the scan to `out` (.ply, .las or .e57, by extension) in chunks of chunk_points points,
/// generated on up to `threads` threads (0 = the hardware's count). The file is written into an
/// exclusive temporary beside `out` and put in place only when complete (hc/common/
/// file_output.hpp): an existing file is never replaced, and a failure leaves nothing behind.
/// LAS: the header's bounds are those of the stored (quantised) coordinates; coordinates are
/// X = round(x / 0.0001 m); every point is a single return of class 1 (unclassified).
/// Memory: one chunk (chunk_points × the record size), and with spec.sorted the permutation (12
/// bytes a point while sorting, 4 after). Bytes out: PLY 12 (15 with rgb) per point
/// plus the header; LAS 20 (26) plus 227; E57 the same records as PLY in packets (18 bytes a
/// packet of 4096 records), 4 bytes of CRC a 1020-byte page, and the XML section.
/// @throws hc::ConfigError for an invalid spec (validate), chunk_points 0, an extension other
///         than .ply / .las / .e57, a LAS or E57 file of 2³² points or more, or coordinates outside LAS's
///         32-bit range at 0.1 mm (±214 km); hc::InputError naming `out` if it exists, cannot be
///         written or the disk fills.
/// `temporary`, when given, is told the temporary's path (ReliefTemporaryFn).
ReliefWriteStats write_relief(const ReliefSpec& spec, const std::filesystem::path& out, std::size_t chunk_points = 1u << 20,
                              unsigned threads = 0, const ReliefProgressFn& progress = {},
                              const ReliefTemporaryFn& temporary = {});

}  // namespace hc::tools
