// XYZ / TXT text reader: x y z per line, extra columns ignored, '#' comments and blank lines
// skipped, blanks or commas as separators. Values are parsed in double (std::from_chars). Read
// whole (read_xyz) or in chunks (open_xyz_stream, issue 14), by one parser over either kind of
// line source (text_lines.hpp): the same points and errors.

#include "readers.hpp"
#include "byte_source.hpp"
#include "line_stream.hpp"
#include "text_lines.hpp"
#include "text_parse.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/point_stream.hpp"

#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>

namespace hc::pipeline::detail {

namespace {

/// [b, e) without a '#' comment and the separators before it and at its start: empty for a
/// comment-only line.
void strip_comment(const char*& b, const char*& e) {
  if (const void* hash = std::memchr(b, '#', static_cast<std::size_t>(e - b))) e = static_cast<const char*>(hash);
  while (b < e && is_space(*b)) ++b;
}

/// The XYZ parser over a line source (TextLines or FileLines).
template <class LineSource>
class XyzParser {
 public:
  XyzParser(LineSource& lines, const std::string& name) : lines_(lines), name_(name) {}

  /// Appends up to `max` (≥ 1) points' x y z to xyz. @return false once the file is done (the
  /// last points may have come with this call); a file without a point is then an error.
  /// @throws hc::InputError naming the file and line for a line whose first three tokens are
  /// not numbers.
  bool read(std::size_t max, std::vector<double>& xyz) {
    if (done_) return false;
    std::size_t taken = 0;
    const char* b = nullptr;
    const char* e = nullptr;
    while (taken < max) {
      if (!lines_.next(b, e)) {
        done_ = true;
        if (points_ == 0) throw InputError("load_cloud: " + name_ + " holds no points (no 'x y z' line)");
        return false;
      }
      strip_comment(b, e);
      if (b == e) continue;  // comment-only line
      const char* p = b;
      for (int a = 0; a < 3; ++a) {
        double v = 0.0;
        if (!parse_double(p, e, v)) {
          const std::string_view tok = first_token(p, e);
          throw InputError("load_cloud: " + name_ + " line " + std::to_string(lines_.line_no()) + ": " +
                           (tok.empty() ? std::string("expected 3 numbers (x y z), found only ") + std::to_string(a)
                                        : "'" + std::string(tok.substr(0, 40)) + "' is not a number (expected x y z)"));
        }
        xyz.push_back(v);
      }
      ++points_;
      ++taken;
    }
    return true;
  }

  /// The point lines (neither blank nor comment-only), counted without parsing them.
  std::uint64_t look() {
    std::uint64_t n = 0;
    const char* b = nullptr;
    const char* e = nullptr;
    while (lines_.next(b, e)) {
      strip_comment(b, e);
      n += b < e ? 1U : 0U;
    }
    return n;
  }

 private:
  LineSource& lines_;
  const std::string& name_;
  std::uint64_t points_ = 0;
  bool done_ = false;
};

// An XYZ file read in blocks of lines (point_stream.hpp). Opening it counts its point lines
// (XyzParser::look), kept for later streams of the same unchanged large file
// (recall_first_pass); then the points come a chunk at a time.
class XyzStream final : public LineStream {
 public:
  XyzStream(const std::filesystem::path& path, const std::string& name, bool gz) : LineStream(ByteSource::open(path, name, gz)) {
    total_ = points_by_look<XyzParser>("xyz_look");
    start_lines();
    parser_ = std::make_unique<XyzParser<FileLines>>(*lines_, name_);
    notes_ = {"XYZ text", "lines streamed in chunks"};
  }

 private:
  void fill(std::size_t max) override { (void)parser_->read(max, xyz_); }

  std::unique_ptr<XyzParser<FileLines>> parser_;
};

}  // namespace

ReadResult read_xyz(const ScanSource& source) {
  TextLines lines(source.bytes, source.display_name);
  XyzParser<TextLines> parser(lines, source.display_name);
  std::vector<double> xyz;
  xyz.reserve(source.bytes.size() / 16);
  (void)parser.read(std::numeric_limits<std::size_t>::max(), xyz);
  return {cloud_from(xyz), {"XYZ text"}};
}

std::unique_ptr<PointStream> open_xyz_stream(const std::filesystem::path& path, const std::string& name, bool gz) {
  return std::make_unique<XyzStream>(path, name, gz);
}

}  // namespace hc::pipeline::detail
