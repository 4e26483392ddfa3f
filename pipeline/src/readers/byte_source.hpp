#pragma once
/// @file byte_source.hpp
/// The bytes of a scan file read front to back for the streams of point_stream.hpp: a plain
/// file (stdio), or a gzip file decompressed as it is read (zlib's inflate; the members of a
/// concatenated file in turn, as load_cloud's whole read inflates them, with its errors). Private
/// to the pipeline.

#include "readers.hpp"

#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

namespace hc::pipeline::detail {

class ByteSource {
 public:
  /// Opens `path` (`name`: the quoted path for messages); gz: its data are gzip-compressed
  /// (or zlib: the header is detected, as load_cloud's whole read detects it).
  /// @throws hc::InputError naming the file when it cannot be opened or is empty, in
  ///         load_cloud's words.
  static std::unique_ptr<ByteSource> open(const std::filesystem::path& path, const std::string& name, bool gz);
  virtual ~ByteSource() = default;
  ByteSource(const ByteSource&) = delete;
  ByteSource& operator=(const ByteSource&) = delete;

  /// Up to n bytes of the (decompressed) data into out; fewer only at its end.
  /// @throws hc::InputError naming the file on a read error, or on gzip data that are corrupt,
  ///         truncated, followed by bytes that are no member, or decompress to nothing, in
  ///         load_cloud's words.
  virtual std::size_t read(char* out, std::size_t n) = 0;
  /// Moves to byte `offset` of the (decompressed) data: for gzip, decompressed again from the
  /// start when going back. @throws hc::InputError naming the file when it cannot.
  virtual void seek(std::uint64_t offset) = 0;
  /// For gzip, reads the rest of the data so that bad data after the last byte a stream needs
  /// (after a PLY's vertices) fail as the whole read, which inflates the whole file, fails on
  /// them. @throws as read.
  virtual void drain() {}
  /// The file on disk's key when it is large (large_file_key), for a first look kept across
  /// streams.
  std::optional<FileKey> key() const { return key_; }
  const std::string& name() const { return name_; }

 protected:
  ByteSource(std::string name, std::optional<FileKey> key) : name_(std::move(name)), key_(key) {}
  std::string name_;
  std::optional<FileKey> key_;
};

/// A stream's first look over `src`: `look()` (reading src from its start) gives two numbers,
/// kept under `what` for later streams of the same unchanged large file (recall_first_pass);
/// src is then back at its start. @throws what look throws, and hc::InputError naming the
/// file when it cannot go back.
template <class Look>
std::array<std::uint64_t, 2> first_look(ByteSource& src, const std::string& what, Look&& look) {
  std::array<std::uint64_t, 2> v{};
  const std::optional<FileKey> key = src.key();
  if (key && recall_first_pass(*key, what, v)) return v;
  v = look();
  if (key) remember_first_pass(*key, what, v);
  src.seek(0);
  return v;
}

/// A text header read from src's current position up to the end of its first line whose first
/// word (the characters after any std::isspace ones, up to the next one) is `word`: the PLY
/// header's end_header line, the PCD header's DATA line. The bytes read (in blocks of 64 KiB,
/// at most max_bytes and one block more) go to `head`, which may hold bytes past that line.
/// unterminated_last: a last line without a newline at the data's end counts too.
/// @return the offset in head just past that line's newline (head.size() for an unterminated
///         last line), or std::string::npos when no such line was found.
/// @throws what src.read throws.
std::size_t read_header_until_word(ByteSource& src, std::string_view word, std::string& head, bool unterminated_last,
                                   std::size_t max_bytes = std::size_t{16} << 20);

/// Whether `path` ends in ".gz" (any case), and its extension before that, lower case (".ply"
/// for "Scan.PLY.gz").
bool gz_name(const std::filesystem::path& path, std::string& inner_ext);
/// Whether the reader of the format with extension `ext` (as gz_name gives it) seeks through the
/// file (LAS: its VLRs and EVLRs; LAZ: its chunk table; E57: its XML section at the end), so
/// that it has no stream under gzip: a gzipped such file streams from a plain copy
/// (LoadOptions::inflated).
inline bool reader_seeks(const std::string& ext) { return ext == ".las" || ext == ".laz" || ext == ".e57"; }

}  // namespace hc::pipeline::detail
