// PTS reader (Leica Cyclone's unordered ASCII export), written from the format's published
// description: a line holding the point count, then that many lines `X Y Z [intensity] [R G B]`
// (3, 4, 6 or 7 numbers, the same on every line). Several such blocks may follow each other
// (several scans exported to one file); they are all read, in the file's single frame (PTS has
// no transform). Leica writes intensity as an integer in −2048..2047; it is kept as stored.
// Read whole (read_pts) or in chunks (open_pts_stream, issue 14), by one parser over either
// kind of line source (text_lines.hpp): the same points, attributes, notes and errors.

#include "readers.hpp"
#include "byte_source.hpp"
#include "line_stream.hpp"
#include "text_lines.hpp"
#include "text_parse.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/point_stream.hpp"

#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>

namespace hc::pipeline::detail {

namespace {

/// Parses up to 7 numbers of [b, e) into v; returns how many, 8 if there are more, SIZE_MAX if a
/// token is not a number (then *bad, when given, points at it).
std::size_t parse_up_to_7(const char* b, const char* e, double* v, const char** bad = nullptr) {
  const char* p = b;
  std::size_t n = 0;
  for (;;) {
    while (p < e && is_space(*p)) ++p;
    if (p >= e) return n;
    if (n == 7) return 8;
    if (bad != nullptr) *bad = p;
    if (!parse_double(p, e, v[n])) return std::numeric_limits<std::size_t>::max();
    ++n;
  }
}

constexpr std::size_t kNotNumber = std::numeric_limits<std::size_t>::max();

/// The PTS parser over a line source (TextLines or FileLines): count lines and point lines in
/// file order, handing out points a chunk at a time. Every error names the file and the line.
template <class LineSource>
class PtsParser {
 public:
  /// reserve_cap > 0 (a whole read): a count line reserves room in xyz for that many points
  /// more, at most reserve_cap.
  PtsParser(LineSource& lines, const std::string& name, std::size_t reserve_cap = 0)
      : lines_(lines), name_(name), reserve_cap_(reserve_cap) {}

  /// Appends up to `max` (≥ 1) points: x y z to xyz, intensity (4 or 7 numbers a line) and
  /// r g b (6 or 7) to theirs. @return false once the file is done (the last points may have
  /// come with this call); then the end is checked: the last block's count, at least one count
  /// line and one point. @throws hc::InputError naming the file and line for a line that is not
  /// a count or a point of the first point line's width, a count that its point lines do not
  /// match, a colour outside 0..255.
  bool read(std::size_t max, std::vector<double>& xyz, std::vector<float>& intensity, std::vector<std::uint8_t>& rgb) {
    if (done_) return false;
    std::size_t taken = 0;
    const char* b = nullptr;
    const char* e = nullptr;
    while (taken < max) {
      if (!lines_.next(b, e)) {
        finish();
        return false;
      }
      const std::size_t line_no = lines_.line_no();
      double v[7];
      const char* bad = b;
      const std::size_t got = parse_up_to_7(b, e, v, &bad);
      if (got == kNotNumber) {
        throw InputError("load_cloud: " + name_ + " line " + std::to_string(line_no) + ": '" +
                         std::string(first_token(bad, e).substr(0, 40)) +
                         "' is not a number (expected a point count or X Y Z [intensity] [R G B])");
      }
      if (got == 1) {  // a count line opens a block
        if (!(v[0] >= 0) || v[0] != std::floor(v[0]) || v[0] > 1e12) {
          throw InputError("load_cloud: " + name_ + " line " + std::to_string(line_no) + ": point count " +
                           std::string(first_token(b, e).substr(0, 40)) + ": expected a non-negative integer");
        }
        close_block(line_no - 1);
        stated_ = static_cast<std::size_t>(v[0]);
        if (reserve_cap_ > 0) xyz.reserve(xyz.size() + 3 * std::min(stated_, reserve_cap_));
        in_block_ = 0;
        count_line_ = line_no;
        ++blocks_;
        continue;
      }
      if (blocks_ == 0) {
        throw InputError("load_cloud: " + name_ + " line " + std::to_string(line_no) +
                         ": expected the point count line first, found a line of " + std::to_string(got) + " numbers");
      }
      if (width_ == 0) {
        if (got != 3 && got != 4 && got != 6 && got != 7) {
          throw InputError("load_cloud: " + name_ + " line " + std::to_string(line_no) + ": " + std::to_string(got) +
                           " numbers: expected X Y Z [intensity] [R G B] (3, 4, 6 or 7 numbers)");
        }
        width_ = got;
      }
      if (got != width_) {
        throw InputError("load_cloud: " + name_ + " line " + std::to_string(line_no) + ": " + std::to_string(got) +
                         " numbers where the first point line has " + std::to_string(width_));
      }
      ++in_block_;
      xyz.insert(xyz.end(), {v[0], v[1], v[2]});
      if (width_ == 4 || width_ == 7) {
        const auto in = static_cast<float>(v[3]);
        intensity.push_back(in);
        i_min_ = std::min(i_min_, in);
        i_max_ = std::max(i_max_, in);
        integral_intensity_ = integral_intensity_ && v[3] == std::floor(v[3]);
      }
      if (width_ >= 6) {
        for (std::size_t c = width_ - 3; c < width_; ++c) {
          if (!(v[c] >= 0.0 && v[c] <= 255.0)) {
            throw InputError("load_cloud: " + name_ + " line " + std::to_string(line_no) + ": colour value " + std::to_string(v[c]) +
                             ": expected 0 to 255");
          }
          rgb.push_back(static_cast<std::uint8_t>(std::lround(v[c])));
        }
      }
      ++points_;
      ++taken;
    }
    return true;
  }

  /// The points a first look at the file finds without parsing point lines: the count lines'
  /// sum, reading a count line, skipping that many non-blank lines unparsed, and so on. It stops
  /// at the first line where a count line should be and is not (a count its point lines do not
  /// match, or no count line first): read() then reports that line's problem.
  std::uint64_t look() {
    std::uint64_t total = 0;
    const char* b = nullptr;
    const char* e = nullptr;
    while (lines_.next(b, e)) {
      double v[7];
      if (parse_up_to_7(b, e, v) != 1 || !(v[0] >= 0) || v[0] != std::floor(v[0]) || v[0] > 1e12) break;
      const auto n = static_cast<std::uint64_t>(v[0]);
      std::uint64_t skipped = 0;
      while (skipped < n && lines_.next(b, e)) ++skipped;
      total += skipped;
      if (skipped < n) break;
    }
    return total;
  }

  /// The notes of the whole read: the blocks, points and fields, the intensity's range, colour.
  std::vector<std::string> notes() const {
    std::vector<std::string> notes;
    notes.push_back("PTS, " + std::to_string(blocks_) + " block(s), " + std::to_string(points_) + " points, " +
                    (width_ == 3   ? "X Y Z"
                     : width_ == 4 ? "X Y Z intensity"
                     : width_ == 6 ? "X Y Z R G B"
                                   : "X Y Z intensity R G B"));
    if (width_ == 4 || width_ == 7) {
      const bool leica = integral_intensity_ && i_min_ >= -2048.0f && i_max_ <= 2047.0f && i_min_ < 0.0f;
      notes.push_back("intensity kept as stored, range " + std::to_string(static_cast<double>(i_min_)) + " to " +
                      std::to_string(static_cast<double>(i_max_)) + (leica ? " (Leica's integer range -2048..2047)" : ""));
    }
    if (width_ >= 6) notes.push_back("RGB kept");
    return notes;
  }

 private:
  void close_block(std::size_t where) const {
    if (blocks_ > 0 && in_block_ != stated_) {
      throw InputError("load_cloud: " + name_ + " line " + std::to_string(count_line_) + ": the count line says " +
                       std::to_string(stated_) + " points but " + std::to_string(in_block_) + " point lines follow it (up to line " +
                       std::to_string(where) + "): expected the count to match the points");
    }
  }
  // At the end of the file: the last block's count, and something read.
  void finish() {
    done_ = true;
    close_block(lines_.line_no());
    if (blocks_ == 0) throw InputError("load_cloud: " + name_ + " holds no PTS point count line");
    if (points_ == 0) throw InputError("load_cloud: " + name_ + " holds no points (its count lines say 0)");
  }

  LineSource& lines_;
  const std::string& name_;
  std::size_t reserve_cap_;
  std::size_t width_ = 0;       // numbers per point line, fixed by the first one
  std::size_t stated_ = 0;      // the current block's count line
  std::size_t in_block_ = 0;    // point lines seen in the current block
  std::size_t count_line_ = 0;  // line number of the current block's count line
  std::size_t blocks_ = 0;
  std::uint64_t points_ = 0;
  bool done_ = false;
  float i_min_ = std::numeric_limits<float>::infinity(), i_max_ = -std::numeric_limits<float>::infinity();
  bool integral_intensity_ = true;
};

// A PTS file read in blocks of lines (point_stream.hpp). Opening it takes a first look
// (PtsParser::look: count lines only) for the points it holds, kept for later streams of the
// same unchanged large file (recall_first_pass); then the points come a chunk at a time.
class PtsStream final : public LineStream {
 public:
  PtsStream(const std::filesystem::path& path, const std::string& name, bool gz) : LineStream(ByteSource::open(path, name, gz)) {
    total_ = points_by_look<PtsParser>("pts_look");
    start_lines();
    parser_ = std::make_unique<PtsParser<FileLines>>(*lines_, name_);
    notes_ = {"PTS, point lines streamed in chunks"};
  }

 private:
  void fill(std::size_t max) override {
    if (parser_->read(max, xyz_, intensity_, rgb_)) return;
    notes_ = parser_->notes();
    notes_.push_back("point lines streamed in chunks");
  }

  std::unique_ptr<PtsParser<FileLines>> parser_;
};

}  // namespace

ReadResult read_pts(const ScanSource& source) {
  TextLines lines(source.bytes, source.display_name);
  PtsParser<TextLines> parser(lines, source.display_name, source.bytes.size() / 8);
  std::vector<double> xyz;
  std::vector<float> intensity;
  std::vector<std::uint8_t> rgb;
  (void)parser.read(std::numeric_limits<std::size_t>::max(), xyz, intensity, rgb);
  Cloud cloud = cloud_from(xyz);
  if (!intensity.empty()) cloud.intensity = std::move(intensity);
  if (!rgb.empty()) cloud.rgb = std::move(rgb);
  return {std::move(cloud), parser.notes()};
}

std::unique_ptr<PointStream> open_pts_stream(const std::filesystem::path& path, const std::string& name, bool gz) {
  return std::make_unique<PtsStream>(path, name, gz);
}

}  // namespace hc::pipeline::detail
