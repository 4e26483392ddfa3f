#pragma once
/// @file lzf_reader.hpp
/// LZF data decompressed as they are read, in memory bounded by LZF's reach (8 KiB), not by the
/// data: the body of a DATA binary_compressed PCD streamed (read_pcd.cpp). Private to the
/// pipeline.
///
/// The format (Marc Lehmann's liblzf, lzf_d.c, which PCL's pcl/common/src/lzf.cpp follows for
/// its binary_compressed bodies): a sequence of instructions, each starting with a control byte
/// c.
///   - c < 32: a literal run, the next c + 1 bytes copied to the output.
///   - c ≥ 32: a back reference of length L = c >> 5 (7: plus the next byte), then a low offset
///     byte b; the L + 2 bytes starting ((c & 31) << 8) + b + 1 bytes before the output's end are
///     copied to it, one at a time (a reference may overlap what it writes).
/// The data end after the last instruction; nothing marks the end. A reference reaches at most
/// 8192 bytes back, so only that much of the output is kept.
///
/// liblzf's decoder (and so PCL's) fails where an instruction needs bytes past the compressed
/// data's end, a reference points before the output's start, or the output would pass the size
/// the caller allows; PCL then compares the size produced with the size its header stored.
/// LzfReader fails in the same cases (hc::InputError), naming where.

#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace hc::pipeline::detail {

class LzfReader {
 public:
  /// Fills `out` with up to `n` bytes of the compressed data, fewer only at its end (0: no
  /// more); may throw (a ByteSource's errors pass through).
  using Fill = std::function<std::size_t(char* out, std::size_t n)>;

  /// compressed_bytes: the compressed data's size (no more than that is asked of `fill`);
  /// decompressed_bytes: the size they must give exactly. `what` starts every error message
  /// ("load_cloud: 'scan.pcd': the compressed block" for example).
  LzfReader(std::uint64_t compressed_bytes, std::uint64_t decompressed_bytes, Fill fill, std::string what);

  /// The next n decompressed bytes into out (nullptr: decoded and dropped, to reach a later
  /// column).
  /// @throws hc::InputError (`what` first) when the data are corrupt (a reference before the
  ///         output's start), end before n more bytes, or give more than decompressed_bytes;
  ///         what `fill` throws.
  void read(char* out, std::size_t n);

  /// Decodes the rest and checks that the compressed data gave exactly decompressed_bytes.
  /// @throws as read, and hc::InputError when they give fewer.
  void finish();

  /// Decompressed bytes handed out or dropped so far.
  std::uint64_t position() const { return taken_; }

 private:
  // One instruction decoded to the window's end. false at the compressed data's end.
  bool step();
  // The next compressed byte. @throws when there is none (`need`: what it was for).
  unsigned char byte(const char* need);
  [[noreturn]] void fail(const std::string& why) const;

  static constexpr std::size_t kReach = 8192;    // LZF's farthest reference [bytes]
  static constexpr std::size_t kSpan = 1 << 16;  // decoded ahead of the reader at most [bytes]
  static constexpr std::size_t kLongest = 264;   // the longest instruction's output (7 + 255 + 2)

  std::uint64_t compressed_, decompressed_;
  Fill fill_;
  std::string what_;
  std::vector<char> in_;           // compressed bytes read, in_[in_at_, in_end_) not yet used
  std::size_t in_at_ = 0, in_end_ = 0;
  std::uint64_t in_read_ = 0;      // compressed bytes read from fill_
  std::vector<char> win_;          // the output's last bytes: win_[0, end_), of which [at_, end_) not yet taken
  std::size_t at_ = 0, end_ = 0;
  std::uint64_t produced_ = 0;     // decompressed bytes decoded
  std::uint64_t taken_ = 0;        // handed out or dropped
};

}  // namespace hc::pipeline::detail
