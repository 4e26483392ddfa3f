#pragma once
/// @file las_records.hpp
/// What the LAS reader (read_las.cpp) shares with the LAZ reader (read_laz.cpp): the public
/// header and (E)VLR parsing, and the decoding of uncompressed point records into a Cloud.
/// A LAZ file is a LAS file whose point records are compressed (LASzip specification: the
/// LAS header and VLRs are stored as in LAS, the format byte carries the compression bit): the
/// LAZ reader parses the header here, decompresses the records into LAS record layout, and
/// hands them to decode_las_records, so both formats keep exactly the same fields.
/// Private to the pipeline (not installed).

#include "readers.hpp"

#include "hc/pipeline/point_stream.hpp"

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace hc::pipeline::detail {

/// One (E)VLR found in the file; `data` points into ScanSource::bytes.
struct Vlr {
  std::string user_id;
  std::uint16_t record_id = 0;
  const char* data = nullptr;
  std::size_t length = 0;
};

/// The validated LAS public header (ASPRS LAS 1.4 R15 §2.4) of a LAS or LAZ file.
struct LasHeader {
  std::string version;            ///< "1.2" etc.
  std::string system_id;          ///< system identifier (header bytes 26–57), trailing NULs cut
  std::string software;           ///< generating software (header bytes 58–89)
  int minor = 0;                  ///< version minor (major is 1)
  std::size_t header_size = 0;    ///< bytes
  std::size_t offset = 0;         ///< byte offset of the point data
  int format = 0;                 ///< point data format 0..10 (compression bits cleared)
  std::size_t record_length = 0;  ///< bytes per point record (base + extra bytes)
  std::size_t base_length = 0;    ///< bytes of the format's standard fields
  std::uint64_t count = 0;        ///< number of point records (> 0)
  double scale[3] = {1, 1, 1};    ///< x y z scale factors (file units per count)
  double shift[3] = {0, 0, 0};    ///< x y z offsets (file units)
  std::vector<Vlr> vlrs;          ///< VLRs then EVLRs, in file order
  std::vector<std::string> notes; ///< header notes for the stage report
};

/// Parses and checks the header and (E)VLRs of source.bytes. `compressed` = false (LAS): the
/// compression bits of the format byte are refused and the records must fit the file;
/// true (LAZ): the format byte's bits 6–7 are cleared and the record room is not checked
/// (the LAZ reader checks its chunks against the file size). Throws hc::InputError naming the
/// file and the offending field.
LasHeader parse_las_header(const ScanSource& source, bool compressed);
/// The point count of a LAS public header at `b` (at least 227 bytes, 375 for LAS 1.4; the
/// caller checked the signature and the size): the legacy uint32 count at byte 107, from version
/// 1.4 the uint64 count at byte 247 unless that is 0 and the legacy one is not (ASPRS LAS 1.4 R15,
/// Table 3). parse_las_header's rule, without its checks of the rest of the file.
std::uint64_t las_header_point_count(const char* b);
/// The same on the file's bytes `bytes` (a whole file in memory or mapped), `name` quoted for
/// messages. The VLRs' `data` point into `bytes`.
LasHeader parse_las_header(std::string_view bytes, const std::string& name, bool compressed);

/// Decodes uncompressed point records (LAS 1.4 R15 tables 7–17) block by block: x y z =
/// X·scale + offset in double (file units), intensity raw 0..65535, RGB u16 → 8 bit (the high
/// byte, or the low byte when every kept value fits 8 bits: rgb_max decides over the whole
/// file), the classes of LoadOptions::las_drop_classes dropped and counted. Shared by the whole
/// read (decode_las_records) and the streamed one (open_las_stream), so both give the same points.
class LasRecordDecoder {
 public:
  LasRecordDecoder(const LasHeader& header, const LoadOptions* options);
  bool has_rgb() const { return rgb_at_ != 0; }
  /// The largest R, G or B value of the kept records among the n at p (0 without colour).
  std::uint16_t rgb_max(const char* p, std::size_t n) const;
  /// Decodes the n records at p; writes the kept ones at xyz (3 per point), intensity and rgb
  /// (3 per point, when has_rgb) from index 0. @return the number kept.
  std::size_t decode(const char* p, std::size_t n, bool rgb_low_bytes, double* xyz, float* intensity, std::uint8_t* rgb);
  /// The same into `chunk` (replaced): xyz, intensity and rgb of the kept records. @return the
  /// number kept (chunk.size()). Used by the streams (open_las_stream, open_laz_stream).
  std::size_t decode_chunk(const char* p, std::size_t n, bool rgb_low_bytes, Cloud& chunk);
  std::uint64_t kept() const { return kept_; }
  /// The classes dropped (LoadOptions::las_drop_classes as given).
  const std::vector<int>& drop_classes() const { return drop_classes_; }
  /// "dropped N points by classification (...)" over every decode call so far.
  std::string dropped_note() const;
  /// The error text (after "load_cloud: <file> ") when no record is kept.
  static std::string nothing_kept_message(std::uint64_t count);

 private:
  std::size_t record_length_, class_at_;
  unsigned class_mask_;
  std::size_t rgb_at_;
  double scale_[3] = {1, 1, 1}, shift_[3] = {0, 0, 0};
  std::vector<int> drop_classes_;
  std::array<bool, 256> drop_{};
  std::array<std::uint64_t, 256> dropped_{};
  std::uint64_t kept_ = 0;
};

/// The point-record streams of LAS and LAZ (open_las_stream, open_laz_stream): the decoding,
/// the notes in decode_las_records' order, the 8- or 16-bit colour decision (one pass over every
/// record before the first chunk, as the whole read decides it) and the sticky failure are
/// shared; a subclass hands out the records.
class LasRecordStream : public PointStream {
 public:
  /// `format_notes`: the header's notes and las_format_notes; `crs_notes`, `crs`: las_crs's.
  /// `key`: the file's large_file_key, under which the colour pass's result is kept for later
  /// streams of the same unchanged file.
  LasRecordStream(std::string name, const LasHeader& header, const LoadOptions* options,
                  std::vector<std::string> format_notes, std::vector<std::string> crs_notes, std::string crs,
                  std::optional<FileKey> key);
  std::uint64_t total_points() const override { return total_; }
  const std::vector<std::string>& notes() const override { return notes_; }
  bool streamed() const override { return true; }
  std::string crs() const override { return crs_; }
  bool next(Cloud& chunk, std::size_t max_points) final;

 protected:
  /// Points `records` at the next up to `max` (≥ 1, at most the records left) records and
  /// returns how many (≥ 1). @throws hc::InputError when they cannot be read.
  virtual std::size_t next_records(std::size_t max, const char*& records) = 0;
  /// Calls f(records, n) on every record once, from the first, in blocks; then the next
  /// next_records starts again at the first record. @throws hc::InputError.
  virtual void each_record_block(const std::function<void(const char*, std::size_t)>& f) = 0;

  std::string name_;
  std::size_t record_length_;
  std::uint64_t total_;

 private:
  void decide_colour();
  void assemble_notes();

  LasRecordDecoder decoder_;
  std::optional<FileKey> key_;
  std::uint64_t done_ = 0;
  bool colour_decided_ = false, rgb_low_bytes_ = false;
  StickyFailure sticky_;
  std::vector<std::string> format_notes_, crs_notes_, notes_;
  std::string crs_;
};

/// The stage report's notes on a LAS header: version, format, record count, system and software;
/// scale and offset; extra bytes.
std::vector<std::string> las_format_notes(const LasHeader& header);
/// The note on how RGB was taken (see LasRecordDecoder).
std::string las_rgb_note(bool rgb_low_bytes);
/// The CRS the header's VLRs declare (WKT 2112, or a summary of the GeoTIFF keys 34735–34737),
/// or ""; appends notes on it and on other VLRs. Needs the bytes the VLRs point into.
std::string las_crs(const LasHeader& header, std::vector<std::string>& notes);

/// Decodes `header.count` uncompressed records of `header.record_length` bytes starting at
/// `records` (LAS 1.4 R15 tables 7–17 layout) into a Cloud in file units: x y z = X·scale +
/// offset in double, intensity raw 0..65535, RGB 16 → 8 bit, classes of
/// LoadOptions::las_drop_classes dropped; notes on format, CRS and dropped points.
/// Throws hc::InputError if every point is dropped.
ReadResult decode_las_records(const ScanSource& source, LasHeader&& header, const char* records);

/// read_laz.cpp: decompresses the LAZ point data of source (whose header was parsed with
/// `compressed` = true) into header.count LAS records of header.record_length bytes, in file
/// order, and appends a note on the compressor to header.notes. Throws hc::InputError naming
/// the file and the offending VLR field, item, chunk or offset. The buffer is allocated without
/// zero-filling (every byte is written by the decoder).
std::unique_ptr<char[]> decompress_laz(const ScanSource& source, LasHeader& header);

}  // namespace hc::pipeline::detail
