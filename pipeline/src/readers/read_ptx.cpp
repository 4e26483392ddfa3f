// PTX reader (Leica Cyclone's ASCII export of organised scans), written from the format's
// published description. A file holds one or more scans, each:
//   columns                       (one integer)
//   rows                          (one integer)
//   scanner position x y z        (registered frame)
//   scanner axis X, Y, Z          (three lines of 3 numbers: the scanner's axes in that frame)
//   4 × 4 transform               (four lines of 4 numbers, row-vector convention: the 3 × 3
//                                  block's rows are the axes, the last row is the translation,
//                                  the last column is 0 0 0 1)
//   columns × rows point lines    x y z intensity [r g b], in the scanner's own frame, column by
//                                 column (all rows of column 0, then column 1, ...); 0 0 0 is a
//                                 direction without a return.
// Every point is moved into the common frame as p_world = [x y z 1] · M, i.e.
// p_world = x·M.row(0) + y·M.row(1) + z·M.row(2) + M.row(3) (first three entries of each row).
// Checked on the shared sample complex-transform.ptx: its transform's last row equals its
// scanner position line and its 3 × 3 rows equal its axis lines, while its last column is
// 0 0 0 1 — a column-vector reading would give that scan no translation at all.

#include "readers.hpp"
#include "byte_source.hpp"
#include "line_stream.hpp"
#include "text_lines.hpp"
#include "text_parse.hpp"

#include "hc/common/error.hpp"

#include <Eigen/Core>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>

namespace hc::pipeline::detail {

namespace {

/// Parses up to `max` numbers of [b, e) into v; returns how many, or max + 1 if there are more
/// or -1 (as SIZE_MAX) if a token is not a number.
std::size_t parse_numbers(const char* b, const char* e, double* v, std::size_t max) {
  const char* p = b;
  std::size_t n = 0;
  for (;;) {
    while (p < e && is_space(*p)) ++p;
    if (p >= e) return n;
    if (n == max) return max + 1;
    if (!parse_double(p, e, v[n])) return std::numeric_limits<std::size_t>::max();
    ++n;
  }
}

std::string excerpt(const char* b, const char* e) {
  std::string s(b, static_cast<std::size_t>(std::min<std::ptrdiff_t>(e - b, 60)));
  while (!s.empty() && (s.back() == '\r' || s.back() == ' ')) s.pop_back();
  return s;
}


/// The PTX parser over a line source (TextLines or FileLines): scan headers and point lines, in
/// file order, handing out measured points a block at a time. Every error names the file and the
/// line, as in the format's description above.
template <class LineSource>
class PtxParser {
 public:
  PtxParser(LineSource& lines, const std::string& name) : lines_(lines), name_(name) {}

  /// Appends up to `max` measured points (common frame) to xyz (3 per point), intensity and rgb
  /// (3 per point when the scan has colour), and their grid row and column when rows/cols are
  /// given, and their scan's index in the file (0 for the first) when scan_out is given.
  /// @return false once the file is done (after the last scan).
  bool read(std::size_t max, std::vector<double>& xyz, std::vector<float>& intensity, std::vector<std::uint8_t>& rgb,
            std::vector<std::int32_t>* rows_out, std::vector<std::int32_t>* cols_out,
            std::vector<std::size_t>* scan_out = nullptr) {
    std::size_t given = 0;
    while (given < max) {
      if (i_ == n_) {
        if (in_scan_) end_scan();
        if (!start_scan()) return false;
        continue;
      }
      const char* b = nullptr;
      const char* e = nullptr;
      if (!lines_.next(b, e)) ends_inside_scan();
      const std::size_t got = parse_numbers(b, e, v_, 7);
      if (width_ == 0 && (got == 4 || got == 7)) width_ = got;
      if (got != width_) {
        fail_at("scan " + std::to_string(scans_) + " point " + std::to_string(i_ + 1) + " of " + std::to_string(n_) +
                ": expected " + (width_ ? std::to_string(width_) : std::string("4 or 7")) +
                " numbers (x y z intensity [r g b]), found '" + excerpt(b, e) + "'");
      }
      const std::size_t i = i_++;
      if (v_[0] == 0.0 && v_[1] == 0.0 && v_[2] == 0.0) {
        ++no_return_;
        continue;
      }
      Eigen::Vector3d p(v_[0], v_[1], v_[2]);
      if (!identity_) p = rot_t_ * p + t_;
      xyz.insert(xyz.end(), {p.x(), p.y(), p.z()});
      const float in = static_cast<float>(v_[3]);
      intensity.push_back(in);
      i_min_ = std::min(i_min_, in);
      i_max_ = std::max(i_max_, in);
      if (width_ == 7) {
        for (int c = 4; c < 7; ++c) {
          if (!(v_[c] >= 0.0 && v_[c] <= 255.0)) {
            fail_at("scan " + std::to_string(scans_) + ": colour value " + std::to_string(v_[c]) + ": expected 0 to 255");
          }
          rgb.push_back(static_cast<std::uint8_t>(std::lround(v_[c])));
        }
      }
      if (rows_out) rows_out->push_back(static_cast<std::int32_t>(i % rows_));
      if (cols_out) cols_out->push_back(static_cast<std::int32_t>(i / rows_));
      if (scan_out) scan_out->push_back(scans_ - 1);
      ++given;
    }
    return true;
  }

  /// Reads the next scan's header (the next non-blank line starts it); false at the end of the
  /// file. Then skip_points() or read() its points.
  bool start_scan() {
    const char* b = nullptr;
    const char* e = nullptr;
    if (!lines_.next(b, e)) {
      done_ = true;
      return false;
    }
    const std::size_t scan = ++scans_;
    std::size_t dims[2] = {0, 0};
    for (int d = 0; d < 2; ++d) {
      if (d == 1) header_line(scan, 1, "the row count", b, e);
      const std::size_t got = parse_numbers(b, e, v_, 1);
      if (got != 1 || !(v_[0] >= 1) || v_[0] != std::floor(v_[0]) || v_[0] > 1e9) {
        fail_at(std::string("scan ") + std::to_string(scan) + ": expected the " + (d == 0 ? "column" : "row") +
                " count (one integer ≥ 1) of a PTX scan header, found '" + excerpt(b, e) + "'" +
                (scan > 1 && d == 0 ? " (more point lines than scan " + std::to_string(scan - 1) +
                                          "'s rows × columns?)"
                                    : ""));
      }
      dims[d] = static_cast<std::size_t>(v_[0]);
    }
    columns_ = dims[0];
    rows_ = dims[1];
    header_line_no_ = lines_.line_no() - 1;
    header_line(scan, 3, "the scanner position x y z", b, e);
    header_line(scan, 3, "scanner axis X", b, e);
    header_line(scan, 3, "scanner axis Y", b, e);
    header_line(scan, 3, "scanner axis Z", b, e);
    Eigen::Matrix4d m;
    for (int r = 0; r < 4; ++r) {
      header_line(scan, 4, "a row of the 4x4 transform", b, e);
      for (int c = 0; c < 4; ++c) m(r, c) = v_[c];
    }
    if (!m.allFinite() || std::abs(m(0, 3)) > 1e-6 || std::abs(m(1, 3)) > 1e-6 || std::abs(m(2, 3)) > 1e-6 ||
        std::abs(m(3, 3) - 1.0) > 1e-6) {
      fail_at("scan " + std::to_string(scan) + ": the 4x4 transform's last column is " + std::to_string(m(0, 3)) +
              " " + std::to_string(m(1, 3)) + " " + std::to_string(m(2, 3)) + " " + std::to_string(m(3, 3)) +
              ": expected 0 0 0 1 (row-vector convention, translation in the last row)");
    }
    rot_t_ = m.topLeftCorner<3, 3>().transpose();  // column-vector form
    t_ = m.block<1, 3>(3, 0).transpose();
    identity_ = m.isIdentity(0.0);
    n_ = columns_ * rows_;
    i_ = 0;
    width_ = 0;
    in_scan_ = true;
    return true;
  }

  /// After start_scan: the width (4 or 7) of the scan's first point line, and the scan's other
  /// point lines skipped without parsing (line counts only); the scan is then ended. For the
  /// stream's first look at the file (colour in every scan, the points it holds).
  std::size_t skip_points() {
    const char* b = nullptr;
    const char* e = nullptr;
    std::size_t width = 0;
    for (; i_ < n_; ++i_) {
      if (!lines_.next(b, e)) ends_inside_scan();
      if (i_ == 0) {
        const std::size_t got = parse_numbers(b, e, v_, 7);
        width = got == 4 || got == 7 ? got : 0;
      }
    }
    in_scan_ = false;
    return width;
  }

  /// The notes so far: one per finished scan (and the summary once the file is done).
  /// `all_rgb`: whether every scan carries colour (known once the file is done, or from a first
  /// look); `rgb_given`: whether any colour was handed out.
  std::vector<std::string> notes(bool all_rgb, bool rgb_given) const {
    std::vector<std::string> out = scan_notes_;
    if (!done_) return out;
    if (!all_rgb && rgb_given) out.push_back("RGB dropped: only some scans carry colour");
    out.push_back(std::to_string(scans_) + " scan(s), " + std::to_string(no_return_) +
                  " no-return points (0 0 0) skipped; intensity kept as stored (range " + std::to_string(i_min_) +
                  " to " + std::to_string(i_max_) + ", PTX: [0, 1])" + (all_rgb ? ", RGB kept" : "") +
                  ", row/column kept");
    return out;
  }

  std::size_t scans() const { return scans_; }
  std::size_t no_return() const { return no_return_; }
  std::size_t grid_points() const { return n_; }
  bool done() const { return done_; }
  /// Whether every scan read so far carried colour.
  bool all_rgb_seen() const { return all_rgb_seen_; }

 private:
  [[noreturn]] void ends_inside_scan() const {
    throw InputError("load_cloud: " + name_ + " scan " + std::to_string(scans_) + " (header at line " +
                     std::to_string(header_line_no_) + ") declares " + std::to_string(rows_) + " rows x " +
                     std::to_string(columns_) + " columns = " + std::to_string(n_) +
                     " points, but the file ends after " + std::to_string(i_) + " point lines (line " +
                     std::to_string(lines_.line_no()) + ")");
  }
  [[noreturn]] void fail_at(const std::string& what) const {
    throw InputError("load_cloud: " + name_ + " line " + std::to_string(lines_.line_no()) + ": " + what);
  }
  // Reads one header line of exactly `count` numbers into v_.
  void header_line(std::size_t scan, std::size_t count, const char* what, const char*& b, const char*& e) {
    if (!lines_.next(b, e)) {
      throw InputError("load_cloud: " + name_ + " scan " + std::to_string(scan) + ": the file ends at line " +
                       std::to_string(lines_.line_no()) + " inside the scan header: expected " + what);
    }
    if (parse_numbers(b, e, v_, count) != count) {
      fail_at("scan " + std::to_string(scan) + ": expected " + what + " (" + std::to_string(count) +
              " numbers), found '" + excerpt(b, e) + "'");
    }
  }
  void end_scan() {
    in_scan_ = false;
    if (width_ != 7) all_rgb_seen_ = false;
    scan_notes_.push_back("PTX scan " + std::to_string(scans_) + ": " + std::to_string(columns_) + " columns x " +
                          std::to_string(rows_) + " rows, " + (width_ == 7 ? "x y z i r g b" : "x y z i") +
                          (identity_ ? ", identity transform" : ", moved into the common frame by its 4x4 transform"));
  }

  LineSource& lines_;
  const std::string& name_;
  double v_[8] = {};
  std::size_t scans_ = 0, no_return_ = 0;
  std::size_t columns_ = 0, rows_ = 1, n_ = 0, i_ = 0, width_ = 0, header_line_no_ = 0;
  bool in_scan_ = false, identity_ = true, done_ = false, all_rgb_seen_ = true;
  Eigen::Matrix3d rot_t_ = Eigen::Matrix3d::Identity();
  Eigen::Vector3d t_ = Eigen::Vector3d::Zero();
  float i_min_ = std::numeric_limits<float>::infinity(), i_max_ = -std::numeric_limits<float>::infinity();
  std::vector<std::string> scan_notes_;
};

// A PTX file read in blocks of lines (point_stream.hpp). A first look at open time reads every
// scan header and the first point line of each scan, skipping the other lines unparsed: the
// points the file holds and whether every scan has colour (as the whole read decides RGB at its
// end); later streams of the same unchanged large file reuse it (recall_first_pass). Then the points come
// scan by scan, a chunk at a time.
class PtxStream final : public LineStream {
 public:
  PtxStream(const std::filesystem::path& path, const std::string& name, bool gz) : LineStream(ByteSource::open(path, name, gz)) {
    // The first look, or its result for this very file (unchanged, 64 MiB or more) from an
    // earlier stream: a tiled run opens the file once per pass.
    const auto look = first_look(*src_, "ptx_look", [&] {
      FileLines lines(*src_);
      PtxParser<FileLines> first(lines, name_);
      std::uint64_t total = 0;
      bool all_rgb = true;
      while (first.start_scan()) {
        total += first.grid_points();
        if (first.skip_points() != 7) all_rgb = false;
      }
      if (first.scans() == 0) throw InputError("load_cloud: " + name_ + " holds no PTX scan (no header line)");
      return std::array<std::uint64_t, 2>{total, all_rgb ? 1U : 0U};
    });
    total_ = look[0];
    all_rgb_ = look[1] != 0;
    start_lines();
    parser_ = std::make_unique<PtxParser<FileLines>>(*lines_, name_);
    assemble_notes();
  }

 private:
  void fill(std::size_t max) override {
    const bool more = parser_->read(max, xyz_, intensity_, rgb_, nullptr, nullptr);
    given_ += intensity_.size();
    rgb_given_ = rgb_given_ || !rgb_.empty();
    if (more) return;
    assemble_notes();
    if (given_ == 0) {
      throw InputError("load_cloud: " + name_ + " holds " + std::to_string(parser_->no_return()) +
                       " grid points, all 0 0 0 (no return): expected at least one measured point");
    }
  }
  void shape(Cloud& chunk) override {
    if (!all_rgb_) chunk.rgb.clear();
    assemble_notes();
  }
  // The whole read's notes, in its order, as far as they are known; rgb_given_: some scan had
  // colour (parsed, though not handed out when another scan lacks it).
  void assemble_notes() {
    notes_ = parser_->notes(all_rgb_, rgb_given_);
    notes_.push_back("point lines streamed in chunks");
  }

  std::unique_ptr<PtxParser<FileLines>> parser_;
  std::uint64_t given_ = 0;
  bool all_rgb_ = true, rgb_given_ = false;
};

}  // namespace

ReadResult read_ptx(const ScanSource& source) {
  const std::string& name = source.display_name;
  TextLines lines(source.bytes, name);
  PtxParser<TextLines> parser(lines, name);
  std::vector<double> xyz;
  std::vector<float> intensity;
  std::vector<std::uint8_t> rgb;
  std::vector<std::int32_t> rows_out, cols_out;
  std::vector<std::size_t> scan_of;
  parser.read(std::numeric_limits<std::size_t>::max(), xyz, intensity, rgb, &rows_out, &cols_out, &scan_of);
  if (parser.scans() == 0) throw InputError("load_cloud: " + name + " holds no PTX scan (no header line)");
  const bool all_rgb = parser.all_rgb_seen();
  std::vector<std::string> notes = parser.notes(all_rgb, !rgb.empty());

  Cloud cloud = cloud_from(xyz);
  if (cloud.size() == 0) {
    throw InputError("load_cloud: " + name + " holds " + std::to_string(parser.no_return()) +
                     " grid points, all 0 0 0 (no return): expected at least one measured point");
  }
  cloud.intensity = std::move(intensity);
  cloud.row = std::move(rows_out);
  cloud.col = std::move(cols_out);
  // Several scans: each point's scan (rows and columns are per scan: mesh_organised_scans meshes
  // each scan's grid on its own), as the E57 reader gives them.
  if (parser.scans() > 1 && parser.scans() <= std::size_t{std::numeric_limits<std::uint16_t>::max()} + 1) {
    cloud.scan_id.reserve(scan_of.size());
    for (const std::size_t k : scan_of) cloud.scan_id.push_back(static_cast<std::uint16_t>(k));
  } else if (parser.scans() > 1) {
    notes.push_back("scan ids not kept: " + std::to_string(parser.scans()) + " scans, more than 65536");
  }
  if (all_rgb) cloud.rgb = std::move(rgb);
  return {std::move(cloud), std::move(notes)};
}

std::unique_ptr<PointStream> open_ptx_stream(const std::filesystem::path& path, const std::string& name, bool gz) {
  return std::make_unique<PtxStream>(path, name, gz);
}

}  // namespace hc::pipeline::detail
