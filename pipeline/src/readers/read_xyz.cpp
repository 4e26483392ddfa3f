// XYZ / TXT text reader: x y z per line, extra columns ignored, '#' comments and blank lines
// skipped, blanks or commas as separators. Values are parsed in double (std::from_chars).

#include "readers.hpp"
#include "text_parse.hpp"

#include "hc/common/error.hpp"

#include <cstring>

namespace hc::pipeline::detail {

ReadResult read_xyz(const ScanSource& source) {
  const std::string& text = source.bytes;
  const std::string& name = source.display_name;
  std::vector<double> xyz;
  xyz.reserve(text.size() / 16);
  for_each_line(text, [&](const char* b, const char* e, std::size_t line_no) {
    if (const void* hash = std::memchr(b, '#', static_cast<std::size_t>(e - b))) e = static_cast<const char*>(hash);
    const char* p = b;
    while (p < e && is_space(*p)) ++p;
    if (p == e) return;  // blank or comment-only line
    for (int a = 0; a < 3; ++a) {
      double v = 0.0;
      if (!parse_double(p, e, v)) {
        const std::string_view tok = first_token(p, e);
        throw InputError("load_cloud: " + name + " line " + std::to_string(line_no) + ": " +
                         (tok.empty() ? std::string("expected 3 numbers (x y z), found only ") + std::to_string(a)
                                      : "'" + std::string(tok.substr(0, 40)) + "' is not a number (expected x y z)"));
      }
      xyz.push_back(v);
    }
  });
  if (xyz.empty()) throw InputError("load_cloud: " + name + " holds no points (no 'x y z' line)");
  return {cloud_from(xyz), {"XYZ text"}};
}

}  // namespace hc::pipeline::detail
