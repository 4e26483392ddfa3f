#pragma once
/// @file readers.hpp
/// The per-format scan readers behind hc::pipeline::load_cloud (private to the pipeline; not
/// installed, not public API). One file per format under pipeline/src/readers/:
///   read_ply.cpp  PLY ascii / binary_little_endian / binary_big_endian (own parser, lists too)
///   read_pcd.cpp  PCD v0.5/v0.7 (header and data checked and every body read here, whole
///                 or in chunks: binary, binary_compressed and ascii; PCL's reader the tests' oracle)
///   read_obj.cpp  OBJ `v x y z` lines
///   read_xyz.cpp  XYZ / TXT text, x y z per line
///   read_conf.cpp scanalyze .conf poses (read_scanalyze_conf of the public header)
///   read_las.cpp  LAS 1.0–1.4, point data formats 0–10 (uncompressed)
///   read_laz.cpp  LAZ (LASzip point-wise and layered chunked compressors; COPC read as LAZ)
///   read_ptx.cpp  Leica PTX text, one or several scans, each moved by its 4×4 transform
///   read_pts.cpp  Leica PTS text, point count line(s) then X Y Z [I] [R G B]
/// load_cloud (ingest.cpp) reads the file once, inflates a trailing .gz once, and dispatches on
/// the extension through its table kFormats: a new format is a new read_<format>.cpp defining
/// a ReaderFn plus one line in that table.
///
/// Interface contract of a reader:
///   - input: the whole file, already decompressed, in memory (ScanSource);
///   - output: every point in the file's own units and frame, in double, NaN kept, scan_id
///     empty, plus human-readable notes for the stage report;
///   - errors: hc::InputError whose message starts "load_cloud: " + display_name and says what
///     was found and what was expected (line or record number where there is one); never a
///     warning plus an empty or partial cloud.
///
/// Options: a reader that has settings (LAS: the classes to drop) reads them from
/// ScanSource::options, which load_cloud fills from its LoadOptions argument (run.cpp passes
/// config.input's values); nullptr means LoadOptions' defaults.
///
/// Later readers (E57, LAZ). PTX and PTS are text and fit this interface as is.
/// E57 and LAZ files can be larger than memory should hold twice; such a reader will be added
/// with a second entry point that opens ScanSource::path itself and delivers the points in
/// chunks, e.g. `using ChunkReaderFn = void (*)(const ScanSource&, const ChunkSink&)` with
/// `ChunkSink = std::function<void(const Eigen::Matrix3Xd& chunk)>`, and a flag in the
/// dispatch table so load_cloud skips the whole-file read (and any .gz inflation, which such
/// formats do not use) for it. Nothing in the existing readers needs to change for that.

#include "hc/common/error.hpp"
#include "hc/pipeline/cloud.hpp"
#include "hc/pipeline/ingest.hpp"
#include "hc/pipeline/point_stream.hpp"

#include <filesystem>
#include <memory>
#include <string_view>
#include <cstdint>
#include <optional>
#include <array>
#include <string>
#include <vector>

namespace hc::pipeline::detail {

/// One scan file as a reader sees it.
struct ScanSource {
  const std::string& bytes;            ///< the whole file, inflated if it was .gz; never empty
  const std::filesystem::path& path;   ///< the file on disk (for readers that reopen it)
  bool inflated = false;               ///< true if `bytes` came from a .gz (not the file on disk)
  const std::string& display_name;     ///< the path, quoted, for messages
  /// Format options from the config (input.las.*); nullptr = the defaults of LoadOptions.
  const LoadOptions* options = nullptr;
};

/// What a reader returns: the points and notes for the load stage's report.
struct ReadResult {
  Cloud cloud;
  std::vector<std::string> notes;
};

using ReaderFn = ReadResult (*)(const ScanSource&);

ReadResult read_ply(const ScanSource& source);  ///< read_ply.cpp
ReadResult read_pcd(const ScanSource& source);  ///< read_pcd.cpp
ReadResult read_obj(const ScanSource& source);  ///< read_obj.cpp
ReadResult read_xyz(const ScanSource& source);  ///< read_xyz.cpp
ReadResult read_e57(const ScanSource& source);  ///< read_e57.cpp: ASTM E2807 E57, every data3D scan posed into the file frame and merged (metres; scan_id when > 1 scan; intensity [0,1], rgb 8 bit, row/col; intensity by intensityLimits, else the prototype's bounds, else the least and greatest non-NaN value of the scan's records); InputError on bad CRC-32C page (its offset), truncation, bad XML, zero scans
ReadResult read_las(const ScanSource& source);  ///< read_las.cpp (LAS 1.0–1.4, formats 0–10)
ReadResult read_laz(const ScanSource& source);  ///< read_laz.cpp (LAZ: LASzip compressors 1–3, formats 0–3 and 6–8; COPC as plain LAZ)
ReadResult read_ptx(const ScanSource& source);  ///< read_ptx.cpp (Leica PTX, one or more scans)
ReadResult read_pts(const ScanSource& source);  ///< read_pts.cpp (Leica PTS)

/// read_ply.cpp: a binary PLY whose elements up to `vertex` have no lists, or an ASCII PLY (lines
/// read in blocks, AsciiVertexParser: the same vertices, colour and errors as read_ply), streamed
/// in chunks (point_stream.hpp); nullptr when the file is not such a PLY (binary with lists, no end_header:
/// the caller reads it whole, and load_cloud's errors name the problem), or when it holds a
/// `face` element and !points_only (a mesh keeps its faces). `name` is the quoted path for
/// messages. @throws hc::InputError for a bad header or a binary file shorter than its header's
/// vertex data; an ASCII file's bad line or early end comes from next(), as read_ply's error
/// (sticky).
std::unique_ptr<PointStream> open_ply_stream(const std::filesystem::path& path, const std::string& name,
                                             bool points_only, bool gz = false);

/// read_pcd.cpp: a PCD streamed in chunks (point_stream.hpp), DATA binary (records),
/// binary_compressed (an LZF decoder per column read) or ascii (blocks of lines): the same
/// points (x y z, any declared type widened as read_pcd widens it), colours, intensities, notes
/// and errors as read_pcd, in file order; nullptr when the file has no DATA line in its first
/// 16 MB (the whole read says what is wrong). Under gzip, opening it inflates the file once to
/// learn its size (kept for later streams of a large file, first_look). `name` is the quoted
/// path for messages. @throws hc::InputError, in read_pcd's words, for a bad header, a body
/// shorter than the header declares, and bad gzip data; a bad data line's error comes from
/// next() (sticky).
std::unique_ptr<PointStream> open_pcd_stream(const std::filesystem::path& path, const std::string& name, bool gz = false);

/// A read-only mapping of a whole open file (mmap, MAP_PRIVATE), released on destruction; for
/// the streams that read a header, (E)VLRs or a table through it and the bulk of the file by
/// read calls (read_las.cpp, read_laz.cpp).
struct FileMapping {
  const char* data = nullptr;
  std::size_t size = 0;
  /// Maps the whole of `fd` (not closed here). @return false for an empty file, or when fstat
  /// or mmap fail (the caller then falls back to the whole read, which says why).
  bool map(int fd);
  std::string_view bytes() const { return {data, size}; }
  FileMapping() = default;
  FileMapping(const FileMapping&) = delete;
  FileMapping& operator=(const FileMapping&) = delete;
  ~FileMapping();
};

/// A file's identity as fstat sees it: device, inode, size and modification time.
struct FileKey {
  std::uint64_t dev = 0, ino = 0, size = 0;
  std::int64_t mtime_s = 0, mtime_ns = 0;
  bool operator==(const FileKey&) const = default;
};
/// The key of the open file `fd` when it is 64 MiB or more, else nullopt: a small file is cheap
/// to read again, and a file rewritten in place within one tick of the file system's coarse
/// clock keeps its size and time (point_stream.cpp).
std::optional<FileKey> large_file_key(int fd);
/// What a stream's first pass over a large file found (`what` names the pass: "ptx_look",
/// "las_rgb"; two numbers), kept for later streams of the same unchanged file: a tiled run opens
/// its input once per pass. Process-wide, the last 16 entries, thread-safe (point_stream.cpp).
bool recall_first_pass(const FileKey& key, const std::string& what, std::array<std::uint64_t, 2>& values);
void remember_first_pass(const FileKey& key, const std::string& what, const std::array<std::uint64_t, 2>& values);

/// The sticky failure of a stream (point_stream.hpp): once next() has thrown, the reader's
/// position no longer agrees with its counts, so every later call fails too, naming the first
/// error. The LAS/LAZ, E57 and text streams (line_stream.hpp) run their next() through it.
class StickyFailure {
 public:
  /// Clears `chunk` and returns body()'s result. @throws hc::InputError naming `name` and the
  /// first failure when an earlier call failed; whatever body() throws (remembered, `chunk`
  /// cleared).
  template <class Body>
  bool run(const std::string& name, Cloud& chunk, Body&& body) {
    chunk = Cloud();
    if (failed_) throw InputError("load_cloud: " + name + ": the stream failed earlier: " + failure_);
    try {
      return body();
    } catch (const std::exception& e) {
      failed_ = true;
      failure_ = e.what();
      chunk = Cloud();
      throw;
    }
  }

 private:
  bool failed_ = false;
  std::string failure_;
};

/// load_cloud's words (ingest.cpp) for a scan file of 0 bytes, `name` the quoted path; the
/// streams (byte_source.cpp) say the same.
InputError empty_file_error(const std::string& name);
/// load_cloud's words for gzip (or zlib) data that zlib's inflate refuses: `truncated` (the data
/// end inside a member, after `compressed_bytes` bytes of file) or not valid (`zlib_msg`, zlib's
/// z_stream::msg, or nullptr); shared by the whole read's inflate (ingest.cpp) and the streams'
/// (byte_source.cpp, GzSource). Source: RFC 1950/1952 as zlib reads them.
InputError gzip_data_error(const std::string& name, bool truncated, const char* zlib_msg, std::uint64_t compressed_bytes);
/// load_cloud's words for gzip data that decompress to nothing.
InputError gzip_empty_error(const std::string& name);

/// An uncompressed LAS file (read_las.cpp) streamed in chunks of records: the same points,
/// colour, intensity and CRS as read_las, in file order. The header and (E)VLRs are read through
/// a read-only mapping that is released before the first chunk; with colour, one pass over the
/// records decides 16- or 8-bit RGB (as read_las does) before the first chunk, and is kept for
/// later streams of the same unchanged file of 64 MiB or more (recall_first_pass). nullptr when the
/// file cannot be opened or mapped (load_cloud's whole read then says why). `name` is the quoted
/// path for messages. @throws hc::InputError as read_las for a bad header or a file shorter
/// than its records, and from next() when no record is kept or the file shrinks.
std::unique_ptr<PointStream> open_las_stream(const std::filesystem::path& path, const std::string& name,
                                             const LoadOptions* options);

/// An E57 file (read_e57.cpp) read scan by scan: its pages read with pread and each checked
/// (CRC-32C), each data3D scan decoded max_points records at a time as its packets are read
/// (memory: a chunk and the packet buffers ahead of it, not the scan; with several scans, each
/// scan's invalid-state bytestream is read at open up to its first valid record, for the merge); the same points, intensity, colour, CRS and notes as read_e57 (no scan_id or
/// row/column). The attributes kept are decided from the scans' prototypes as read_e57's merge
/// decides them. nullptr when the file cannot be opened or is shorter than its header.
/// @throws hc::InputError as read_e57: a bad header or XML section when opened; a bad page,
/// packet or bytestream from next() (sticky).
std::unique_ptr<PointStream> open_e57_stream(const std::filesystem::path& path, const std::string& name);

class ByteSource;
/// The points open_e57_stream's stream of the same file counts (total_points: each data3D scan's
/// recordCount, at most 2^32 − 1 each), from the file's bytes read front to back through `src`
/// (read_e57.cpp), for a gzipped E57, which has no stream (its reader seeks): the XML section
/// (ASTM E2807 § 7.2: the header's xmlPhysicalOffset and xmlLogicalLength) lies near the end, so
/// src is read up to it; the pages before it are dropped as they come, the XML's pages kept
/// (a few KiB to MiB) and checked (CRC-32C, § 7.3). `name` is the quoted path for messages.
/// @throws hc::InputError as open_e57_stream for a bad header, page or XML section, or when src
///         ends before the XML section does; what src.read throws.
std::uint64_t e57_record_count(ByteSource& src, const std::string& name);

/// A PTX file (read_ptx.cpp) read in blocks of lines: the same points, intensity, colour and
/// notes as read_ptx (no row/column), in file order. Opening it reads every scan header and
/// each scan's first point line, skipping the other lines unparsed, for the points the file
/// holds (rows × columns summed, no-returns included) and whether every scan has colour (RGB is
/// kept only then, as read_ptx decides); a later stream of the same unchanged file (device,
/// inode, size, modification time) reuses that look. @throws hc::InputError as read_ptx: a bad header or a
/// file that ends inside a scan when opened, a bad point line from next() (sticky).
std::unique_ptr<PointStream> open_ptx_stream(const std::filesystem::path& path, const std::string& name, bool gz = false);

/// A PTS file (read_pts.cpp) read in blocks of lines: the same points, intensity, colour, notes
/// and errors as read_pts, in file order. Opening it takes a first look at its count lines,
/// skipping the point lines unparsed, for the points it holds (total_points: the counts' sum up
/// to the first line where a count should be and is not, whose problem next() then reports); a
/// later stream of the same unchanged file of 64 MiB or more reuses it (recall_first_pass).
/// @throws hc::InputError when the file cannot be opened, and from next() as read_pts (sticky).
std::unique_ptr<PointStream> open_pts_stream(const std::filesystem::path& path, const std::string& name, bool gz = false);

/// An XYZ / TXT file (read_xyz.cpp) read in blocks of lines: the same points and errors as
/// read_xyz, in file order. Opening it counts its point lines (neither blank nor comment-only)
/// without parsing them, kept as open_pts_stream keeps its look. @throws hc::InputError when the
/// file cannot be opened, and from next() as read_xyz (sticky).
std::unique_ptr<PointStream> open_xyz_stream(const std::filesystem::path& path, const std::string& name, bool gz = false);

/// An OBJ file's vertices (read_obj.cpp) read in blocks of lines: the same points, vertex colour
/// and errors as read_obj, in file order (its `vt` and `f` lines parsed for their errors, not
/// kept). Opening it takes a first look (the `v` lines, whether all hold r g b, whether there is
/// an `f` line), kept as open_pts_stream keeps its look. nullptr when the file has faces and
/// as_points is false (a mesh, rasterised in core). @throws hc::InputError when the file cannot
/// be opened, and from next() as read_obj (sticky).
std::unique_ptr<PointStream> open_obj_stream(const std::filesystem::path& path, const std::string& name, bool as_points,
                                             bool gz = false);

/// A LAZ file (read_laz.cpp) decompressed and streamed chunk by chunk: the same points,
/// colour, intensity and CRS as read_laz, in file order, with one LASzip chunk's compressed
/// bytes and records in memory at a time (read with pread). The header, the (E)VLRs and the
/// chunk table are read through a read-only mapping released before the stream is returned;
/// with colour, one pass decompressing every chunk decides 16- or 8-bit RGB before the first
/// chunk (kept for later streams of the same unchanged file of 64 MiB or more). nullptr when the file cannot be opened or mapped. @throws hc::InputError as read_laz
/// for a bad header, LASzip VLR or chunk table when opened, and from next() for a corrupt or
/// truncated chunk or when no record is kept (the failure is sticky).
std::unique_ptr<PointStream> open_laz_stream(const std::filesystem::path& path, const std::string& name,
                                             const LoadOptions* options);

}  // namespace hc::pipeline::detail
