// OBJ reader: only `v x y z [w]` lines; everything else (vn, vt, f, g, usemtl, ...) is ignored.
// PCL's OBJReader stores x, y, z as float32; this keeps the text's double precision.

#include "readers.hpp"
#include "text_parse.hpp"

#include "hc/common/error.hpp"

namespace hc::pipeline::detail {

ReadResult read_obj(const ScanSource& source) {
  const std::string& text = source.bytes;
  const std::string& name = source.display_name;
  std::vector<double> xyz;
  xyz.reserve(text.size() / 24);
  for_each_line(text, [&](const char* b, const char* e, std::size_t line_no) {
    const char* p = b;
    while (p < e && (*p == ' ' || *p == '\t')) ++p;
    if (e - p < 2 || p[0] != 'v' || (p[1] != ' ' && p[1] != '\t')) return;
    p += 2;
    for (int a = 0; a < 3; ++a) {
      double v = 0.0;
      if (!parse_double(p, e, v)) {
        const std::string_view tok = first_token(p, e);
        throw InputError("load_cloud: " + name + " line " + std::to_string(line_no) + ": malformed vertex line (" +
                         (tok.empty() ? std::string("fewer than 3 coordinates")
                                      : "'" + std::string(tok.substr(0, 40)) + "' is not a number") +
                         "), expected 'v x y z'");
      }
      xyz.push_back(v);
    }
  });
  if (xyz.empty()) throw InputError("load_cloud: " + name + " holds no vertices ('v x y z' lines)");
  return {cloud_from(xyz), {"OBJ vertex lines"}};
}

}  // namespace hc::pipeline::detail
