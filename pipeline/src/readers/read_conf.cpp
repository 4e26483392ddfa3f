// scanalyze .conf reader (read_scanalyze_conf of hc/pipeline/ingest.hpp): the poses of the
// views of a multi-view scan, one `bmesh FILE tx ty tz qx qy qz qw` line each.

#include "text_parse.hpp"
#include "hc/pipeline/ingest.hpp"

#include "hc/common/error.hpp"

#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <system_error>
#include <vector>

namespace hc::pipeline {

Eigen::Affine3d ScanPose::scan_to_world() const {
  Eigen::Affine3d m = Eigen::Affine3d::Identity();
  m.linear() = rotation.normalized().toRotationMatrix().transpose();
  m.translation() = translation;
  return m;
}

std::vector<ScanPose> read_scanalyze_conf(const std::filesystem::path& conf_path) {
  const std::string name = detail::quoted(conf_path);
  std::error_code ec;
  if (!std::filesystem::exists(conf_path, ec)) {
    throw InputError("read_scanalyze_conf: file " + name + " does not exist");
  }
  std::ifstream in(conf_path);
  if (!in) throw InputError("read_scanalyze_conf: cannot open " + name);
  std::vector<ScanPose> poses;
  std::string line;
  std::size_t line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ls(line);
    std::string kw;
    if (!(ls >> kw) || kw[0] == '#') continue;
    if (kw == "camera" || kw == "mesh") continue;
    const std::string where = "read_scanalyze_conf: " + name + " line " + std::to_string(line_no) + ": ";
    if (kw != "bmesh") {
      throw InputError(where + "unknown keyword '" + kw + "' (expected bmesh, mesh or camera)");
    }
    ScanPose pose;
    std::vector<std::string> tok;
    std::string t;
    ls >> pose.file;
    while (ls >> t) tok.push_back(t);
    if (pose.file.empty() || tok.size() != 7) {
      throw InputError(where + "malformed bmesh line '" + line + "' (expected 'bmesh FILE tx ty tz qx qy qz qw')");
    }
    double v[7];
    for (int i = 0; i < 7; ++i) {
      const char* p = tok[static_cast<std::size_t>(i)].data();
      const char* e = p + tok[static_cast<std::size_t>(i)].size();
      if (!detail::parse_double(p, e, v[i]) || p != e || !std::isfinite(v[i])) {
        throw InputError(where + "malformed bmesh line: '" + tok[static_cast<std::size_t>(i)] +
                         "' is not a finite number (expected 'bmesh FILE tx ty tz qx qy qz qw')");
      }
    }
    pose.translation = Eigen::Vector3d(v[0], v[1], v[2]);
    const Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);  // scanalyze writes w last
    const double norm = q.norm();
    if (std::abs(norm - 1.0) > 1e-3) {
      throw InputError(where + "the quaternion (" + tok[3] + ", " + tok[4] + ", " + tok[5] + ", " + tok[6] +
                       ") has norm " + std::to_string(norm) + ", expected a unit quaternion");
    }
    pose.rotation = q.normalized();
    poses.push_back(std::move(pose));
  }
  if (poses.empty()) throw InputError("read_scanalyze_conf: " + name + " has no 'bmesh' line");
  return poses;
}

}  // namespace hc::pipeline
