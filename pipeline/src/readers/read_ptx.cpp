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
#include "text_parse.hpp"

#include "hc/common/error.hpp"

#include <Eigen/Core>

#include <cmath>
#include <cstring>
#include <limits>

namespace hc::pipeline::detail {

namespace {

/// Walks the lines of a text buffer, skipping blank ones, counting line numbers from 1.
class Lines {
 public:
  explicit Lines(const std::string& text) : p_(text.data()), end_(text.data() + text.size()) {}

  /// The next non-blank line in [b, e); false at the end of the text.
  bool next(const char*& b, const char*& e) {
    while (p_ < end_) {
      const void* nl = std::memchr(p_, '\n', static_cast<std::size_t>(end_ - p_));
      const char* line_end = nl ? static_cast<const char*>(nl) : end_;
      b = p_;
      e = line_end;
      p_ = nl ? line_end + 1 : end_;
      ++line_no_;
      const char* q = b;
      while (q < e && is_space(*q)) ++q;
      if (q < e) return true;
    }
    return false;
  }
  std::size_t line_no() const { return line_no_; }

 private:
  const char* p_;
  const char* end_;
  std::size_t line_no_ = 0;
};

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

}  // namespace

ReadResult read_ptx(const ScanSource& source) {
  const std::string& name = source.display_name;
  Lines lines(source.bytes);
  const char* b = nullptr;
  const char* e = nullptr;
  double v[8];

  std::vector<double> xyz;
  std::vector<float> intensity;
  std::vector<std::uint8_t> rgb;
  std::vector<std::int32_t> rows_out, cols_out;
  std::vector<std::string> notes;
  bool all_rgb = true;
  std::size_t scans = 0, no_return = 0;
  float i_min = std::numeric_limits<float>::infinity(), i_max = -i_min;

  const auto fail_at = [&](const std::string& what) {
    throw InputError("load_cloud: " + name + " line " + std::to_string(lines.line_no()) + ": " + what);
  };
  // Reads one header line of exactly `count` numbers.
  const auto header_line = [&](std::size_t scan, std::size_t count, const char* what) {
    if (!lines.next(b, e)) {
      throw InputError("load_cloud: " + name + " scan " + std::to_string(scan) + ": the file ends at line " +
                       std::to_string(lines.line_no()) + " inside the scan header: expected " + what);
    }
    if (parse_numbers(b, e, v, count) != count) {
      fail_at("scan " + std::to_string(scan) + ": expected " + what + " (" + std::to_string(count) +
              " numbers), found '" + excerpt(b, e) + "'");
    }
  };

  while (lines.next(b, e)) {
    const std::size_t scan = ++scans;
    // columns, rows
    std::size_t dims[2] = {0, 0};
    for (int d = 0; d < 2; ++d) {
      if (d == 1) header_line(scan, 1, "the row count");
      const std::size_t got = parse_numbers(b, e, v, 1);
      if (got != 1 || !(v[0] >= 1) || v[0] != std::floor(v[0]) || v[0] > 1e9) {
        fail_at(std::string("scan ") + std::to_string(scan) + ": expected the " + (d == 0 ? "column" : "row") +
                " count (one integer ≥ 1) of a PTX scan header, found '" + excerpt(b, e) + "'" +
                (scan > 1 && d == 0 ? " (more point lines than scan " + std::to_string(scan - 1) +
                                          "'s rows × columns?)"
                                    : ""));
      }
      dims[d] = static_cast<std::size_t>(v[0]);
    }
    const std::size_t columns = dims[0], rows = dims[1];
    const std::size_t header_line_no = lines.line_no() - 1;
    header_line(scan, 3, "the scanner position x y z");
    header_line(scan, 3, "scanner axis X");
    header_line(scan, 3, "scanner axis Y");
    header_line(scan, 3, "scanner axis Z");
    Eigen::Matrix4d m;
    for (int r = 0; r < 4; ++r) {
      header_line(scan, 4, "a row of the 4x4 transform");
      for (int c = 0; c < 4; ++c) m(r, c) = v[c];
    }
    if (!m.allFinite() || std::abs(m(0, 3)) > 1e-6 || std::abs(m(1, 3)) > 1e-6 || std::abs(m(2, 3)) > 1e-6 ||
        std::abs(m(3, 3) - 1.0) > 1e-6) {
      fail_at("scan " + std::to_string(scan) + ": the 4x4 transform's last column is " + std::to_string(m(0, 3)) +
              " " + std::to_string(m(1, 3)) + " " + std::to_string(m(2, 3)) + " " + std::to_string(m(3, 3)) +
              ": expected 0 0 0 1 (row-vector convention, translation in the last row)");
    }
    const Eigen::Matrix3d rot_t = m.topLeftCorner<3, 3>().transpose();  // column-vector form
    const Eigen::Vector3d t = m.block<1, 3>(3, 0).transpose();
    const bool identity = m.isIdentity(0.0);

    const std::size_t n = columns * rows;
    std::size_t width = 0;  // 4 or 7 values per line, fixed by the scan's first point line
    for (std::size_t i = 0; i < n; ++i) {
      if (!lines.next(b, e)) {
        throw InputError("load_cloud: " + name + " scan " + std::to_string(scan) + " (header at line " +
                         std::to_string(header_line_no) + ") declares " + std::to_string(rows) + " rows x " +
                         std::to_string(columns) + " columns = " + std::to_string(n) +
                         " points, but the file ends after " + std::to_string(i) + " point lines (line " +
                         std::to_string(lines.line_no()) + ")");
      }
      const std::size_t got = parse_numbers(b, e, v, 7);
      if (width == 0 && (got == 4 || got == 7)) width = got;
      if (got != width) {
        fail_at("scan " + std::to_string(scan) + " point " + std::to_string(i + 1) + " of " + std::to_string(n) +
                ": expected " + (width ? std::to_string(width) : std::string("4 or 7")) +
                " numbers (x y z intensity [r g b]), found '" + excerpt(b, e) + "'");
      }
      if (v[0] == 0.0 && v[1] == 0.0 && v[2] == 0.0) {
        ++no_return;
        continue;
      }
      Eigen::Vector3d p(v[0], v[1], v[2]);
      if (!identity) p = rot_t * p + t;
      xyz.insert(xyz.end(), {p.x(), p.y(), p.z()});
      const float in = static_cast<float>(v[3]);
      intensity.push_back(in);
      i_min = std::min(i_min, in);
      i_max = std::max(i_max, in);
      if (width == 7) {
        for (int c = 4; c < 7; ++c) {
          if (!(v[c] >= 0.0 && v[c] <= 255.0)) {
            fail_at("scan " + std::to_string(scan) + ": colour value " + std::to_string(v[c]) +
                    ": expected 0 to 255");
          }
          rgb.push_back(static_cast<std::uint8_t>(std::lround(v[c])));
        }
      }
      rows_out.push_back(static_cast<std::int32_t>(i % rows));
      cols_out.push_back(static_cast<std::int32_t>(i / rows));
    }
    if (width != 7) all_rgb = false;
    notes.push_back("PTX scan " + std::to_string(scan) + ": " + std::to_string(columns) + " columns x " +
                    std::to_string(rows) + " rows, " + (width == 7 ? "x y z i r g b" : "x y z i") +
                    (identity ? ", identity transform" : ", moved into the common frame by its 4x4 transform"));
  }
  if (scans == 0) throw InputError("load_cloud: " + name + " holds no PTX scan (no header line)");

  Cloud cloud = cloud_from(xyz);
  if (cloud.size() == 0) {
    throw InputError("load_cloud: " + name + " holds " + std::to_string(no_return) +
                     " grid points, all 0 0 0 (no return): expected at least one measured point");
  }
  cloud.intensity = std::move(intensity);
  cloud.row = std::move(rows_out);
  cloud.col = std::move(cols_out);
  if (all_rgb) {
    cloud.rgb = std::move(rgb);
  } else if (!rgb.empty()) {
    notes.push_back("RGB dropped: only some scans carry colour");
  }
  notes.push_back(std::to_string(scans) + " scan(s), " + std::to_string(no_return) +
                  " no-return points (0 0 0) skipped; intensity kept as stored (range " + std::to_string(i_min) +
                  " to " + std::to_string(i_max) + ", PTX: [0, 1])" + (all_rgb ? ", RGB kept" : "") +
                  ", row/column kept");
  return {std::move(cloud), std::move(notes)};
}

}  // namespace hc::pipeline::detail
