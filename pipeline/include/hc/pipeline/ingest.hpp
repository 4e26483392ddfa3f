#pragma once
/// @file ingest.hpp
/// Stage 1: reading scans (PLY ASCII/binary incl. Stanford range-grid PLYs and .ply.gz, PCD,
/// OBJ vertices, XYZ text) and merging several views through a scanalyze .conf.

#include "hc/pipeline/cloud.hpp"

#include <Eigen/Geometry>

#include <filesystem>
#include <string>
#include <vector>

namespace hc::pipeline {

/// Reads every vertex of one scan file, in the file's own units and frame.
/// Format by extension: .ply, .pcd, .obj (vertex lines only), .xyz/.txt (whitespace-separated
/// x y z per line, extra columns ignored, '#' comments); a trailing .gz on any of them is
/// decompressed in memory first. Double-typed properties stay double (no float rounding).
/// Stanford range-grid PLYs: `obj_info` lines and stray header lines (for example `bye`) are
/// skipped; the `range_grid` element (and any element after `vertex`, such as faces) is ignored.
/// PLY is read by the project's own parser (binary records, ASCII lines), list properties
/// included in any position of any element up to `vertex` (skipped); PCD by PCL after a
/// header and data check. NaN values are kept (see remove_non_finite). scan_id is left empty.
/// @return N > 0 points.
/// @throws hc::InputError naming the file when it is missing, unreadable, empty, truncated,
///         declares more points than it holds, holds a non-numeric value (the message names the
///         line), has a PLY list that cannot be placed (negative or fractional count, float count
///         type; the message names the property), is not valid gzip, or has an unknown extension.
/// Real-time: no. Thread-safe: yes. Source: PLY format (Turk, 1994); PCD v0.5/v0.7 (PCL).
StageResult<Cloud> load_cloud(const std::filesystem::path& path);

/// One `bmesh` line of a scanalyze .conf: file name, translation t and unit quaternion q.
struct ScanPose {
  std::string file;
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();

  /// The scan-to-world transform. scanalyze convention, verified on the Buddha and bunny
  /// alignments (data/README.md): p_world = R(q)ᵀ · p_scan + t.
  Eigen::Affine3d scan_to_world() const;
};

/// Parses the `bmesh FILE tx ty tz qx qy qz qw` lines of a scanalyze .conf; `camera` and
/// `mesh` lines are ignored.
/// @throws hc::InputError naming the file and line for a malformed bmesh line or a file with none.
std::vector<ScanPose> read_scanalyze_conf(const std::filesystem::path& conf_path);

/// Loads each scan, moves it into the common frame with its pose from `conf_path` (matched by
/// file name, ignoring a trailing .gz) and concatenates them; scan_id is the index in `scans`.
/// @throws hc::InputError if a scan has no pose in the .conf (names both files).
StageResult<Cloud> load_and_merge_scans(const std::vector<std::filesystem::path>& scans,
                                        const std::filesystem::path& conf_path);

}  // namespace hc::pipeline
