// PTS reader (Leica Cyclone's unordered ASCII export), written from the format's published
// description: a line holding the point count, then that many lines `X Y Z [intensity] [R G B]`
// (3, 4, 6 or 7 numbers, the same on every line). Several such blocks may follow each other
// (several scans exported to one file); they are all read, in the file's single frame (PTS has
// no transform). Leica writes intensity as an integer in −2048..2047; it is kept as stored.

#include "readers.hpp"
#include "text_parse.hpp"

#include "hc/common/error.hpp"

#include <cmath>
#include <cstring>
#include <limits>

namespace hc::pipeline::detail {

namespace {

/// Parses up to 7 numbers of [b, e) into v; returns how many, 8 if there are more, SIZE_MAX if a
/// token is not a number.
std::size_t parse_up_to_7(const char* b, const char* e, double* v) {
  const char* p = b;
  std::size_t n = 0;
  for (;;) {
    while (p < e && is_space(*p)) ++p;
    if (p >= e) return n;
    if (n == 7) return 8;
    if (!parse_double(p, e, v[n])) return std::numeric_limits<std::size_t>::max();
    ++n;
  }
}

}  // namespace

ReadResult read_pts(const ScanSource& source) {
  const std::string& name = source.display_name;
  std::vector<double> xyz;
  std::vector<float> intensity;
  std::vector<std::uint8_t> rgb;
  std::size_t width = 0;            // numbers per point line, fixed by the first one
  std::size_t stated = 0;           // the current block's count line
  std::size_t in_block = 0;         // point lines seen in the current block
  std::size_t count_line = 0;       // line number of the current block's count line
  std::size_t blocks = 0;
  float i_min = std::numeric_limits<float>::infinity(), i_max = -i_min;
  bool integral_intensity = true;

  const auto close_block = [&](std::size_t where) {
    if (blocks > 0 && in_block != stated) {
      throw InputError("load_cloud: " + name + " line " + std::to_string(count_line) + ": the count line says " +
                       std::to_string(stated) + " points but " + std::to_string(in_block) +
                       " point lines follow it (up to line " + std::to_string(where) +
                       "): expected the count to match the points");
    }
  };

  std::size_t last_line = 0;
  for_each_line(source.bytes, [&](const char* b, const char* e, std::size_t line_no) {
    last_line = line_no;
    double v[7];
    const std::size_t got = parse_up_to_7(b, e, v);
    if (got == 0) return;  // blank line
    if (got == std::numeric_limits<std::size_t>::max()) {
      throw InputError("load_cloud: " + name + " line " + std::to_string(line_no) + ": '" +
                       std::string(first_token(b, e).substr(0, 40)) +
                       "' is not a number (expected a point count or X Y Z [intensity] [R G B])");
    }
    if (got == 1) {  // a count line opens a block
      if (!(v[0] >= 0) || v[0] != std::floor(v[0]) || v[0] > 1e12) {
        throw InputError("load_cloud: " + name + " line " + std::to_string(line_no) + ": point count " +
                         std::string(first_token(b, e).substr(0, 40)) + ": expected a non-negative integer");
      }
      close_block(line_no - 1);
      stated = static_cast<std::size_t>(v[0]);
      in_block = 0;
      count_line = line_no;
      ++blocks;
      xyz.reserve(xyz.size() + 3 * std::min<std::size_t>(stated, source.bytes.size() / 8));
      return;
    }
    if (blocks == 0) {
      throw InputError("load_cloud: " + name + " line " + std::to_string(line_no) +
                       ": expected the point count line first, found a line of " + std::to_string(got) + " numbers");
    }
    if (width == 0) {
      if (got != 3 && got != 4 && got != 6 && got != 7) {
        throw InputError("load_cloud: " + name + " line " + std::to_string(line_no) + ": " + std::to_string(got) +
                         " numbers: expected X Y Z [intensity] [R G B] (3, 4, 6 or 7 numbers)");
      }
      width = got;
    }
    if (got != width) {
      throw InputError("load_cloud: " + name + " line " + std::to_string(line_no) + ": " + std::to_string(got) +
                       " numbers where the first point line has " + std::to_string(width));
    }
    ++in_block;
    xyz.insert(xyz.end(), {v[0], v[1], v[2]});
    if (width == 4 || width == 7) {
      const float in = static_cast<float>(v[3]);
      intensity.push_back(in);
      i_min = std::min(i_min, in);
      i_max = std::max(i_max, in);
      integral_intensity = integral_intensity && v[3] == std::floor(v[3]);
    }
    if (width >= 6) {
      for (std::size_t c = width - 3; c < width; ++c) {
        if (!(v[c] >= 0.0 && v[c] <= 255.0)) {
          throw InputError("load_cloud: " + name + " line " + std::to_string(line_no) + ": colour value " +
                           std::to_string(v[c]) + ": expected 0 to 255");
        }
        rgb.push_back(static_cast<std::uint8_t>(std::lround(v[c])));
      }
    }
  });
  close_block(last_line);
  if (blocks == 0) throw InputError("load_cloud: " + name + " holds no PTS point count line");
  if (xyz.empty()) throw InputError("load_cloud: " + name + " holds no points (its count lines say 0)");

  Cloud cloud = cloud_from(xyz);
  std::vector<std::string> notes;
  notes.push_back("PTS, " + std::to_string(blocks) + " block(s), " + std::to_string(cloud.size()) + " points, " +
                  (width == 3 ? "X Y Z" : width == 4 ? "X Y Z intensity" : width == 6 ? "X Y Z R G B"
                                                                                     : "X Y Z intensity R G B"));
  if (!intensity.empty()) {
    const bool leica = integral_intensity && i_min >= -2048.0f && i_max <= 2047.0f && i_min < 0.0f;
    notes.push_back("intensity kept as stored, range " + std::to_string(static_cast<double>(i_min)) + " to " +
                    std::to_string(static_cast<double>(i_max)) +
                    (leica ? " (Leica's integer range -2048..2047)" : ""));
    cloud.intensity = std::move(intensity);
  }
  if (!rgb.empty()) {
    cloud.rgb = std::move(rgb);
    notes.push_back("RGB kept");
  }
  return {std::move(cloud), std::move(notes)};
}

}  // namespace hc::pipeline::detail
