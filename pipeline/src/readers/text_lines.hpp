#pragma once
/// @file text_lines.hpp
/// The non-blank lines of a text scan, from a buffer held whole (TextLines, the whole readers)
/// or from a file read in blocks of 4 MiB (FileLines, the streams of point_stream.hpp), with the
/// same line numbers (counted from 1, blank lines included) and the same lines: a line is [b, e)
/// without its '\n'; a line of separators only (text_parse.hpp's is_space) is blank. Shared by
/// the PTX, PTS and XYZ readers (private to the pipeline).

#include "byte_source.hpp"
#include "text_parse.hpp"

#include "hc/common/error.hpp"

#include <cstdio>
#include <cstring>
#include <string>

namespace hc::pipeline::detail {

/// Walks the lines of a text buffer from byte `from`, skipping blank ones (every line when
/// !skip_blank: a PLY body, where a blank line is an error), counting line numbers from 1.
class TextLines {
 public:
  explicit TextLines(const std::string& text, std::size_t from = 0, bool skip_blank = true)
      : begin_(text.data()), p_(text.data() + std::min(from, text.size())), end_(text.data() + text.size()), skip_blank_(skip_blank) {}

  /// The next non-blank line (or the next line) in [b, e); false at the end of the text.
  bool next(const char*& b, const char*& e) {
    while (p_ < end_) {
      const void* nl = std::memchr(p_, '\n', static_cast<std::size_t>(end_ - p_));
      const char* line_end = nl ? static_cast<const char*>(nl) : end_;
      b = p_;
      e = line_end;
      p_ = nl ? line_end + 1 : end_;
      ++line_no_;
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
  std::size_t line_no_ = 0;
};

/// The same over a file read in blocks (for the streams; plain or gzip, ByteSource): lines up to
/// 64 MiB long; a longer one is an InputError naming the file and the line (no scan's line is
/// near that), as is a read error. `src` is not owned and must outlive this.
class FileLines {
 public:
  /// From the file's current position; skip_blank as TextLines.
  FileLines(ByteSource& src, bool skip_blank = true) : src_(src), name_(src.name()), skip_blank_(skip_blank) {}

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
    if (buf_.size() > (std::size_t{64} << 20)) {
      throw InputError("load_cloud: " + name_ + " line " + std::to_string(line_no_ + 1) + " is longer than 64 MiB");
    }
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
  std::string buf_;
  std::size_t pos_ = 0, line_no_ = 0;
  bool eof_ = false;
};

}  // namespace hc::pipeline::detail
