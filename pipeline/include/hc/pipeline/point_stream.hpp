#pragma once
/// @file point_stream.hpp
/// Reading a scan in chunks (issue 14): the passes of the tiled pipeline read the input several
/// times and must never hold it whole.
///
/// Streamed natively (memory: one chunk): binary PLY (little or big endian; fixed-stride vertex
/// records, or records with list properties walked one by one from blocks of 1 MiB or more,
/// since 2026-11-27; elements with lists before the vertices walked over when opened);
/// uncompressed LAS 1.0–1.4
/// (`.las`: the same points, colour, intensity, dropped classes and CRS as load_cloud; with
/// colour, one extra pass over the records before the first chunk decides 8- or 16-bit RGB, as
/// load_cloud does); LAZ (`.laz`, one LASzip chunk decompressed at a time, the same points as
/// load_cloud, and the same extra pass with colour); PTX (`.ptx`, lines read in blocks, the same
/// points and notes as load_cloud without row/column; a first look at open time reads every scan
/// header and counts the point lines); E57 (`.e57`, scan by scan, each decoded a chunk of records at
/// a time as its packets are read, pages read and checked from the file; the same points, intensity, colour, CRS and notes
/// as load_cloud); PTS (`.pts`, lines read in blocks, the same points, intensity, colour, notes
/// and errors as load_cloud; a first look at open time reads the count lines and skips the point
/// lines unparsed); XYZ (`.xyz`, `.txt`: the same, the first look counting the point lines);
/// ASCII PLY (lines read in blocks from the one after the header; list properties parsed and
/// skipped; the count from the header); PCD (`.pcd`: DATA binary in fixed-size records, binary_compressed
/// through an LZF decoder per column, ascii in blocks of lines; the same points, colours,
/// intensities and errors as load_cloud); OBJ vertices
/// (`.obj` without faces, or with `input.as_points`). A gzipped LAS, LAZ or E57 file streams from
/// its plain copy when LoadOptions::inflated lists one (the tiled run's). PLY, PCD, OBJ, PTX, PTS and XYZ stream under
/// gzip too (`.ply.gz`
/// and so on: decompressed as they are read with zlib's inflate, with load_cloud's errors; every
/// pass decompresses again, and a first look decompresses the whole file once: a PCD's to learn
/// its size, which load_cloud checks the header against). The stream's
/// points, colour, intensity and errors are load_cloud's; a PLY header is read up to its
/// `end_header` line, and one whose element sizes overflow is left to the whole read. The other formats are read whole. Elements after the vertex
/// element (faces, range grids) are not read: a mesh is rasterised in core (mesh_raster.hpp),
/// never tiled. Every other file is read whole by load_cloud once and handed out in chunks (the
/// stream's notes say so), so any format load_cloud reads can be streamed, with its memory.

#include "hc/pipeline/cloud.hpp"
#include "hc/pipeline/ingest.hpp"

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace hc::pipeline {

/// A scan file read front to back in chunks. Not thread-safe; one reader per stream.
class PointStream {
 public:
  virtual ~PointStream() = default;
  /// Points the file holds (its header's count; for a file read whole, the points read).
  virtual std::uint64_t total_points() const = 0;
  /// Replaces `chunk` with the next up to max_points (≥ 1) points: xyz in the file's units and
  /// frame (double, as load_cloud gives them: float32 properties widened exactly), rgb when the
  /// file has colour, intensity when a file read whole has it; other attributes empty. @return false when every point has been given (chunk
  /// then empty). @throws hc::InputError naming the file if it cannot be read or ends early.
  virtual bool next(Cloud& chunk, std::size_t max_points) = 0;
  /// How the file is read, for the stage report (format, streamed or read whole).
  virtual const std::vector<std::string>& notes() const = 0;
  /// True when the file is read in chunks; false when it was read whole.
  virtual bool streamed() const = 0;
  /// The coordinate reference system the file declares (Cloud::crs), or empty.
  virtual std::string crs() const { return {}; }
};

/// Opens `path` for reading in chunks; see the file comment for which files stream natively.
/// @throws hc::InputError as load_cloud does (missing file, bad header, truncated data: a
///         streamed binary PLY's size is checked against its header when it is opened).
std::unique_ptr<PointStream> open_point_stream(const std::filesystem::path& path, const LoadOptions& options = {});

/// input.shared_frame: the files' points in the listed order as one stream, with
/// load_files_in_one_frame's rules (ingest.hpp): colour or intensity only when every file has
/// it (a note names the first file without it), one CRS, and float32_xyz on every chunk when
/// any file stores floats (a tiled run's spill then tries the file floats and, at the first
/// point of a double file, spills again in doubles: one pass more for a mix). One file:
/// open_point_stream(files[0]). The first open in the process probes each file (opens it and
/// reads its first point: its count, CRS and attributes), kept for the process by the file's
/// device, inode, size and modification time, so later passes open each file once; then one
/// file is open at a time, and a chunk never spans two files. total_points() is the sum;
/// notes() holds, after each file, its points handed out ("<name>: N points") and its notes
/// prefixed with its name; streamed() is true when every file streams.
/// @throws hc::InputError as open_point_stream for each file, for an empty list, a file without
///         points, or two files declaring different CRS (check_same_crs).
std::unique_ptr<PointStream> open_point_streams(const std::vector<std::filesystem::path>& files, const LoadOptions& options = {});

/// input.conf: the scans in the listed order, each moved into the common frame by its pose
/// from the scanalyze .conf at `conf_path` (scan_poses, move_to_world: the doubles
/// load_and_merge_scans computes, bit for bit), as one stream of the points the in-core merge
/// holds, in its order. Colour or intensity only when every scan has it (a note "input.conf:
/// rgb dropped: <scan> has none"); no CRS (the poses place the scans); float32_xyz never set
/// (posed coordinates are no file's floats); a scan without points gives none. One file is
/// open at a time and a chunk never spans two scans; total_points(), notes() and streamed() as
/// open_point_streams. A scan with faces streams only with LoadOptions::as_points (else the
/// error of open_point_stream: a mesh is rasterised in core).
/// @throws hc::InputError as scan_poses (a scan without a pose names both files) before any
///         scan is opened, then as open_point_stream for each scan.
/// Real-time: no. Thread-safe: one reader per stream. Source: this project (issue 14: a
/// survey's stations placed by their registration).
std::unique_ptr<PointStream> open_posed_point_streams(const std::vector<std::filesystem::path>& scans,
                                                      const std::filesystem::path& conf_path, const LoadOptions& options = {});

}  // namespace hc::pipeline
