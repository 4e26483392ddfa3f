#pragma once
/// @file text_lines.hpp
/// The non-blank lines of a text scan, from a buffer held whole (TextLines, the whole readers)
/// or from a file read in blocks of 4 MiB (FileLines, the streams of point_stream.hpp), with the
/// same line numbers (counted from 1, blank lines included) and the same lines: a line is [b, e)
/// without its '\n'; a line of separators only (text_parse.hpp's is_space) is blank; a line longer
/// than kMaxTextLineBytes is an InputError naming the file and the line in both (no scan's line
/// is near that long; until 2026-11-28 only the streams refused one, at a length that depended on
/// where their 4 MiB blocks fell). Shared by the PTX, PTS, XYZ, OBJ, ascii PCD and ASCII PLY
/// readers (private to the pipeline).

#include "byte_source.hpp"
#include "text_parse.hpp"

#include "hc/common/error.hpp"

#include <cstdio>
#include <cstring>
#include <string>
#include <utility>

namespace hc::pipeline::detail {

/// The longest text line the readers take [bytes, without its '\n']: 64 MiB.
inline constexpr std::size_t kMaxTextLineBytes = std::size_t{64} << 20;

/// The error for line `line_no` (from 1) of the file `name` (as the readers name it) when it is
/// longer than kMaxTextLineBytes.
[[noreturn]] inline void throw_text_line_too_long(const std::string& name, std::size_t line_no) {
  throw InputError("load_cloud: " + name + " line " + std::to_string(line_no) + " is longer than 64 MiB (" +
                   std::to_string(kMaxTextLineBytes) + " bytes; a text scan's line holds one point)");
}

/// Walks the lines of a text buffer from byte `from`, skipping blank ones (every line when
/// !skip_blank: a PLY body, where a blank line is an error), counting line numbers from 1.
/// `name` names the file in the error for a line longer than kMaxTextLineBytes (InputError);
/// `lines_before`: the file's lines before `from` (as FileLines), so that line numbers are the file's.
class TextLines {
 public:
  TextLines(const std::string& text, std::string name, std::size_t from = 0, bool skip_blank = true, std::size_t lines_before = 0)
      : begin_(text.data()), p_(text.data() + std::min(from, text.size())), end_(text.data() + text.size()),
        skip_blank_(skip_blank), name_(std::move(name)), line_no_(lines_before) {}

  /// The next non-blank line (or the next line) in [b, e); false at the end of the text.
  bool next(const char*& b, const char*& e) {
    while (p_ < end_) {
      const void* nl = std::memchr(p_, '\n', static_cast<std::size_t>(end_ - p_));
      const char* line_end = nl ? static_cast<const char*>(nl) : end_;
      b = p_;
      e = line_end;
      p_ = nl ? line_end + 1 : end_;
      ++line_no_;
      if (static_cast<std::size_t>(e - b) > kMaxTextLineBytes) throw_text_line_too_long(name_, line_no_);
      if (!skip_blank_) return true;
      const char* q = b;
      while (q < e && is_space(*q)) ++q;
      if (q < e) return true;
    }
    return false;
  }
  std::size_t line_no() const { return line_no_; }
  /// Bytes of the text before the next line.
  std::size_t offset() const { return static_cast<std::size_t>(p_ - begin_); }

 private:
  const char* begin_;
  const char* p_;
  const char* end_;
  bool skip_blank_;
  std::string name_;
  std::size_t line_no_;
};

/// The same over a file read in blocks (for the streams; plain or gzip, ByteSource), with the
/// same limit (kMaxTextLineBytes; a longer line is the same InputError), as is a read error.
/// `src` is not owned and must outlive this.
class FileLines {
 public:
  /// From the file's current position; skip_blank as TextLines; `lines_before`: the lines of the
  /// file before that position (a header read on its own), so that line numbers are the file's.
  FileLines(ByteSource& src, bool skip_blank = true, std::size_t lines_before = 0)
      : src_(src), name_(src.name()), skip_blank_(skip_blank), line_no_(lines_before) {}

  bool next(const char*& b, const char*& e) {
    for (;;) {
      const char* nl = pos_ < buf_.size()
                           ? static_cast<const char*>(std::memchr(buf_.data() + pos_, '\n', buf_.size() - pos_))
                           : nullptr;
      if (nl == nullptr && !eof_) {
        refill();
        continue;
      }
      if (pos_ >= buf_.size()) return false;  // end of the file
      b = buf_.data() + pos_;
      e = nl ? nl : buf_.data() + buf_.size();
      pos_ = static_cast<std::size_t>(e - buf_.data()) + (nl ? 1 : 0);
      ++line_no_;
      if (static_cast<std::size_t>(e - b) > kMaxTextLineBytes) throw_text_line_too_long(name_, line_no_);
      if (!skip_blank_) return true;
      const char* q = b;
      while (q < e && is_space(*q)) ++q;
      if (q < e) return true;
    }
  }
  std::size_t line_no() const { return line_no_; }

 private:
  void refill() {
    buf_.erase(0, pos_);  // keep the partial line
    pos_ = 0;
    if (buf_.size() > kMaxTextLineBytes) throw_text_line_too_long(name_, line_no_ + 1);  // a partial line already longer
    const std::size_t old = buf_.size();
    buf_.resize(old + kBlock);
    const std::size_t got = src_.read(buf_.data() + old, kBlock);
    buf_.resize(old + got);
    if (got < kBlock) eof_ = true;
  }
  static constexpr std::size_t kBlock = std::size_t{4} << 20;
  ByteSource& src_;
  const std::string& name_;
  bool skip_blank_;
  std::size_t line_no_;
  std::string buf_;
  std::size_t pos_ = 0;
  bool eof_ = false;
};

}  // namespace hc::pipeline::detail
