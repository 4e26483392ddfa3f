#pragma once
/// @file ingest.hpp
/// Stage 1: reading scans (PLY ASCII/binary incl. Stanford range-grid PLYs and .ply.gz, PCD,
/// OBJ vertices, XYZ text, LAS, PTX, PTS) and merging several views through a scanalyze .conf.

#include "hc/pipeline/cloud.hpp"

#include <Eigen/Geometry>

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

namespace hc::pipeline {

/// Format-specific reading options (config keys input.las.*, docs/config.md).
struct LoadOptions {
  /// LAS classification codes whose points are dropped on reading (ASPRS: 7 low noise,
  /// 18 high noise); the count per class goes into the stage report. Values 0..255.
  std::vector<int> las_drop_classes{7, 18};
  /// `input.as_points`: read a mesh's vertices only. The faces a PLY or OBJ file holds are
  /// dropped (the load report's notes say how many) and an OBJ's texture is not read.
  bool as_points = false;
  /// Gzipped LAS, LAZ and E57 files and a plain copy of each ({original, copy}): open_point_stream
  /// streams such a file from its copy natively (their readers seek, so they have no stream under
  /// gzip), naming the original in every message; load_cloud does not use it. The tiled run
  /// fills it with copies inflated once into its scratch folder (tiled_run.cpp).
  std::vector<std::pair<std::filesystem::path, std::filesystem::path>> inflated{};
};

/// Reads every vertex of one scan file, in the file's own units and frame.
/// Format by extension: .ply, .pcd, .obj, .xyz/.txt (whitespace-separated
/// x y z per line, extra columns ignored, '#' comments); a trailing .gz on any of them is
/// decompressed in memory first. Double-typed properties stay double (no float rounding).
/// Stanford range-grid PLYs: `obj_info` lines and stray header lines (for example `bye`) are
/// skipped; the `range_grid` element gives each vertex its scanner row/col (Cloud::row, col).
/// Meshes: PLY `face` and OBJ `f` elements become Cloud::mesh (polygons fan-split into
/// triangles; OBJ texture coordinates and the MTL `map_Kd` image read with OpenCV; PLY and
/// OBJ vertex colours become Cloud::rgb). A face element that cannot be used (truncated,
/// indices out of range) is dropped with a note in the report, never silently.
/// PLY is read by the project's own parser (binary records, ASCII lines), list properties
/// included in any position of any element up to `vertex` (skipped); PCD (ascii, binary and
/// binary_compressed bodies) by the project's own reader after a header check, its x y z, packed
/// colour and intensity the values PCL's reader gives where both accept a file. NaN values are kept (see remove_non_finite). scan_id is left empty.
/// @return N > 0 points.
/// @throws hc::InputError naming the file when it is missing, unreadable, empty, truncated,
///         declares more points than it holds, holds a non-numeric value (the message names the
///         line), has a PLY list that cannot be placed (negative or fractional count, float count
///         type; the message names the property), is not valid gzip, or has an unknown extension.
/// Real-time: no. Thread-safe: yes. Source: PLY format (Turk, 1994); PCD v0.5/v0.7 (PCL).
StageResult<Cloud> load_cloud(const std::filesystem::path& path);

/// As above, with format options. Also reads .las (LAS 1.0–1.4, point data formats 0–10:
/// scaled X Y Z in double, intensity, RGB as 8 bit, classes in options.las_drop_classes
/// dropped, CRS in the notes), .laz (LASzip-compressed LAS: point-wise compressor for formats
/// 0–5 with POINT10/GPSTIME11/RGB12/BYTE v2, layered chunked compressor for formats 6–10 with
/// POINT14/RGB14/RGBNIR14/BYTE14 v3; COPC files read as plain LAZ; the same fields as .las),
/// .ptx (Leica PTX: every scan moved into the common frame by its
/// 4×4 transform, no-return points 0 0 0 skipped, intensity, RGB, row/column kept, and with
/// several scans each point's scan index as scan_id, since rows and columns are per scan) and .pts
/// (Leica PTS: count line, X Y Z [intensity] [R G B]).
/// @throws hc::InputError as above, and for a LAS header whose counts exceed the file, an
///         unknown point format or a record shorter than its format; a LAZ file without a
///         LASzip VLR, with another compressor, coder, item type or item version, or with a
///         chunk table or chunk that lies outside the file or ends early (offset named); a PTX scan whose lines do
///         not match its rows × columns; a PTS count line that disagrees with the points.
/// Sources: ASPRS LAS 1.4 R15; LASzip specification ("LASzip for LAS 1.4", Isenburg 2013); COPC 1.0; Leica PTX/PTS conventions (Cyclone export formats).
StageResult<Cloud> load_cloud(const std::filesystem::path& path, const LoadOptions& options);

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

/// Each scan's scan-to-world transform (ScanPose::scan_to_world) from the scanalyze .conf at
/// `conf_path`, in the order of `scans`: the bmesh line whose file name equals the scan's, a
/// trailing .gz ignored on both sides (the first such line). All are resolved before any scan
/// is read, so a missing pose fails at once. Shared by load_and_merge_scans and the tiled run's
/// streams (open_posed_point_streams), so both place a scan by the same line.
/// @throws hc::InputError for no scans, more than 65 535, a malformed .conf
///         (read_scanalyze_conf), or a scan without a bmesh line (names the scan and the .conf).
/// Thread-safe: yes. Source: scanalyze's .conf convention (data/README.md).
std::vector<Eigen::Affine3d> scan_poses(const std::vector<std::filesystem::path>& scans, const std::filesystem::path& conf_path);

/// Moves `xyz` (3 × n, a scan's own frame and units) into the common frame:
/// p ← L·p + t with L = scan_to_world.linear(), t = its translation, each coordinate summed as
/// ((L(i,0)·x + L(i,1)·y) + L(i,2)·z) + t(i) in double. One function for the in-core merge and
/// the tiled run's chunks, so both give the same doubles bit for bit whatever the chunk size
/// (an Eigen product picks its kernel by size, which may round a sum of zeros to +0 or −0).
/// Real-time: no. Thread-safe: yes (on distinct arrays). Source: this project.
void move_to_world(const Eigen::Affine3d& scan_to_world, Eigen::Matrix3Xd& xyz);

/// Loads each scan, moves it into the common frame with its pose from `conf_path` (matched by
/// file name, ignoring a trailing .gz) and concatenates them; scan_id is the index in `scans`.
/// Scanner row/column, colour and intensity are kept when every scan has them (a note names the
/// first scan without colour or intensity when another has it); faces are renumbered; other
/// attributes are not merged.
/// @throws hc::InputError if a scan has no pose in the .conf (names both files).
StageResult<Cloud> load_and_merge_scans(const std::vector<std::filesystem::path>& scans,
                                        const std::filesystem::path& conf_path,
                                        const LoadOptions& options = {});

/// input.shared_frame: loads each file (load_cloud) and takes their points in the listed order,
/// in the files' own frame and units, as if one file held them all: the parts of one scan (the
/// tiles of a survey in one CRS, a scan cut in pieces). An attribute (colour, intensity,
/// normals with their curvature, scanner row/column) that some file lacks is dropped, with a
/// note naming the first file without it; scan_id is each file's own scan index (0 without one)
/// plus the scans of the files before it, so scanner rows and columns stay per scan (more than
/// 65 536 scans: scan ids and rows/columns dropped, with a note); faces are renumbered; a
/// texture is kept only when every mesh shares one image (Cloud::append's rule). float32_xyz:
/// set when any file stores floats. The points are copied once into the whole (the parts are
/// held until then: memory about twice the points). Notes: each file's points and its own notes
/// (prefixed with its name), then the dropped attributes. Figure `files`. The tiled run reads
/// the same points in the same order (open_point_streams, point_stream.hpp) under the same
/// rules for colour, intensity, float32 and CRS.
/// @throws hc::InputError as load_cloud for each file (the message names it), when `files` is
///         empty, when two files declare different coordinate reference systems (both named
///         with their CRS), or when meshes hold more points than 32-bit face indices reach.
/// Real-time: no. Thread-safe: yes. Source: this project (issue 14: whole sites in several files).
StageResult<Cloud> load_files_in_one_frame(const std::vector<std::filesystem::path>& files, const LoadOptions& options = {});

/// The CRS check of load_files_in_one_frame and open_point_streams: `crs` is the CRS seen so far
/// (empty: none yet) with the file that declared it; a file declaring another one is an error.
/// Updates the pair when `file_crs` is the first one declared; an empty `file_crs` (a file that
/// declares none) is taken as agreeing.
/// @throws hc::InputError naming both files and both CRS.
/// Thread-safe: yes (no shared state). Source: this project (issue 14).
void check_same_crs(std::pair<std::string, std::string>& crs, const std::string& file_crs, const std::filesystem::path& file);

}  // namespace hc::pipeline
