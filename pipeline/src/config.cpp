#include "hc/pipeline/config.hpp"

#include "hc/common/error.hpp"
#include "hc/common/format.hpp"
#include "hc/common/units.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <utility>

namespace hc::pipeline {
namespace {

std::vector<std::string> split_dotted(const std::string& path) {
  std::vector<std::string> parts;
  std::stringstream ss(path);
  std::string part;
  while (std::getline(ss, part, '.')) parts.push_back(part);
  return parts;
}

// The integer `text` spells whole (std::stoi, nothing left over), or nothing.
std::optional<int> whole_int(const std::string& text) {
  std::size_t used = 0;
  int v = 0;
  try {
    v = std::stoi(text, &used);
  } catch (const std::exception&) {
    return std::nullopt;
  }
  if (used != text.size()) return std::nullopt;
  return v;
}

std::string scalar_text(const YAML::Node& n) {
  if (n.IsScalar()) return "'" + n.Scalar() + "'";
  YAML::Emitter e;
  e << YAML::Flow << n;
  return e.c_str();
}

/// Walks a YAML tree by dotted keys, remembers what was read (to reject unknown keys) and the
/// value used for every key (the resolved config), and formats errors with file and line.
class Reader {
 public:
  Reader(YAML::Node root, std::string origin, std::set<std::string> overridden)
      : root_(std::move(root)), origin_(std::move(origin)), overridden_(std::move(overridden)) {}

  std::optional<YAML::Node> find(const std::string& path) const {
    return find_in(root_, split_dotted(path), 0);
  }

  bool has(const std::string& path) {
    mark_known(path);
    return find(path).has_value();
  }

  [[noreturn]] void fail(const std::string& path, const std::string& what) const {
    throw ConfigError(where(path) + ": " + path + " " + what);
  }

  std::string where(const std::string& path) const {
    if (overridden_.count(path)) return origin_ + " (--set " + path + ")";
    const auto n = find(path);
    if (n && n->Mark().line >= 0) return origin_ + ":" + std::to_string(n->Mark().line + 1);
    return origin_;
  }

  double get_double(const std::string& path, double def, double lo, double hi, bool lo_open = false) {
    mark_known(path);
    double v = def;
    if (const auto n = find(path)) {
      if (!n->IsScalar()) fail(path, "= " + scalar_text(*n) + ": expected a number");
      try {
        v = n->as<double>();
      } catch (const YAML::Exception&) {
        fail(path, "= " + scalar_text(*n) + ": expected a number");
      }
    }
    if (!std::isfinite(v) || v < lo || v > hi || (lo_open && v == lo)) {
      fail(path, "= " + format_number(v) + ": expected a number in " + (lo_open ? "(" : "[") +
                     format_number(lo) + ", " + format_number(hi) + "]");
    }
    resolved_set(path, YAML::Node(v));
    return v;
  }

  long long get_int(const std::string& path, long long def, long long lo, long long hi) {
    mark_known(path);
    long long v = def;
    if (const auto n = find(path)) {
      try {
        if (!n->IsScalar()) throw YAML::Exception(YAML::Mark::null_mark(), "");
        v = n->as<long long>();
      } catch (const YAML::Exception&) {
        fail(path, "= " + scalar_text(*n) + ": expected an integer in [" + std::to_string(lo) + ", " +
                       std::to_string(hi) + "]");
      }
    }
    if (v < lo || v > hi) {
      fail(path, "= " + std::to_string(v) + ": expected an integer in [" + std::to_string(lo) + ", " +
                     std::to_string(hi) + "]");
    }
    resolved_set(path, YAML::Node(v));
    return v;
  }

  /// A finite number whose range its own module checks (audio::check, check_falcon_config).
  double get_number(const std::string& path, double def) {
    mark_known(path);
    double v = def;
    if (const auto n = find(path)) {
      try {
        if (!n->IsScalar()) throw YAML::Exception(YAML::Mark::null_mark(), "");
        v = n->as<double>();
      } catch (const YAML::Exception&) {
        fail(path, "= " + scalar_text(*n) + ": expected a number");
      }
    }
    if (!std::isfinite(v)) fail(path, "= " + format_number(v) + ": expected a finite number");
    resolved_set(path, YAML::Node(v));
    return v;
  }

  /// An integer whose range its own module checks; it must fit an int.
  int get_integer(const std::string& path, int def) {
    return static_cast<int>(get_int(path, def, std::numeric_limits<int>::min(), std::numeric_limits<int>::max()));
  }

  bool get_bool(const std::string& path, bool def) {
    mark_known(path);
    bool v = def;
    if (const auto n = find(path)) {
      try {
        if (!n->IsScalar()) throw YAML::Exception(YAML::Mark::null_mark(), "");
        v = n->as<bool>();
      } catch (const YAML::Exception&) {
        fail(path, "= " + scalar_text(*n) + ": expected true or false");
      }
    }
    resolved_set(path, YAML::Node(v));
    return v;
  }

  /// auto (or the key absent): nullopt; else true or false as get_bool reads them. The resolved
  /// config holds auto or the bool.
  std::optional<bool> get_bool_or_auto(const std::string& path) {
    mark_known(path);
    std::optional<bool> v;
    if (const auto n = find(path)) {
      if (!(n->IsScalar() && n->Scalar() == "auto")) {
        try {
          if (!n->IsScalar()) throw YAML::Exception(YAML::Mark::null_mark(), "");
          v = n->as<bool>();
        } catch (const YAML::Exception&) {
          fail(path, "= " + scalar_text(*n) + ": expected auto, true or false");
        }
      }
    }
    resolved_set(path, v ? YAML::Node(*v) : YAML::Node("auto"));
    return v;
  }

  std::string get_string(const std::string& path, const std::string& def,
                         const std::vector<std::string>& allowed = {}) {
    mark_known(path);
    std::string v = def;
    if (const auto n = find(path)) {
      if (!n->IsScalar()) fail(path, "= " + scalar_text(*n) + ": expected a string");
      v = n->Scalar();
    }
    if (!allowed.empty() && std::find(allowed.begin(), allowed.end(), v) == allowed.end()) {
      std::string list;
      for (const auto& a : allowed) list += (list.empty() ? "" : ", ") + a;
      fail(path, "= '" + v + "': expected one of: " + list);
    }
    resolved_set(path, YAML::Node(v));
    return v;
  }

  Eigen::Vector3d get_vec3(const std::string& path, const Eigen::Vector3d& def, double lo = -1e12,
                           double hi = 1e12) {
    mark_known(path);
    Eigen::Vector3d v = def;
    if (const auto n = find(path)) {
      bool ok = n->IsSequence() && n->size() == 3;
      for (std::size_t i = 0; ok && i < 3; ++i) {
        try {
          v[static_cast<Eigen::Index>(i)] = (*n)[i].as<double>();
        } catch (const YAML::Exception&) {
          ok = false;
        }
      }
      if (!ok) fail(path, "= " + scalar_text(*n) + ": expected a list of 3 numbers [x, y, z]");
    }
    for (int i = 0; i < 3; ++i) {
      if (!std::isfinite(v[i]) || v[i] < lo || v[i] > hi) {
        fail(path, "has a value out of range: expected 3 finite numbers in [" + format_number(lo) +
                       ", " + format_number(hi) + "]");
      }
    }
    YAML::Node out(YAML::NodeType::Sequence);
    for (int i = 0; i < 3; ++i) out.push_back(v[i]);
    resolved_set(path, out);
    return v;
  }

  std::vector<std::string> get_string_list(const std::string& path) {
    mark_known(path);
    std::vector<std::string> out;
    const auto n = find(path);
    if (!n) return out;
    if (n->IsScalar()) {
      out.push_back(n->Scalar());
    } else if (n->IsSequence()) {
      for (const auto& item : *n) {
        if (!item.IsScalar()) fail(path, "= " + scalar_text(*n) + ": expected a list of file names");
        out.push_back(item.Scalar());
      }
    } else {
      fail(path, "= " + scalar_text(*n) + ": expected a file name or a list of file names");
    }
    YAML::Node seq(YAML::NodeType::Sequence);
    for (const auto& s : out) seq.push_back(s);
    resolved_set(path, seq);
    return out;
  }

  /// Registers a key whose value is a list handled element by element by the caller.
  std::vector<YAML::Node> get_map_list(const std::string& path) {
    mark_known(path, /*leaf=*/true);
    std::vector<YAML::Node> out;
    const auto n = find(path);
    if (!n) return out;
    if (!n->IsSequence()) fail(path, "= " + scalar_text(*n) + ": expected a list");
    std::size_t i = 0;
    for (const auto& item : *n) {
      if (!item.IsMap()) {
        fail(path, "has an element [" + std::to_string(i) + "] = " + scalar_text(item) +
                       " that is not a key: value map (list indices count from 0)");
      }
      out.push_back(item);
      ++i;
    }
    return out;
  }

  /// Every map key in the file must have been read by some getter.
  void reject_unknown_keys() const { check_node(root_, ""); }

  /// Each of `sections` (dotted paths, parents before children) that the file or a --set gives
  /// must be a map of keys; a scalar, a list or an empty value (`grid:`) is a ConfigError naming
  /// the file, the line, the key and "expected a map" (issue 15 D3: such a section used to be
  /// ignored silently, the run going on with the defaults). A section under a parent that is
  /// not a map is reported through its parent.
  void require_maps(const std::vector<std::string>& sections) const {
    for (const auto& path : sections) {
      const auto parts = split_dotted(path);
      YAML::Node parent = root_;
      bool reachable = true;
      for (std::size_t i = 0; i + 1 < parts.size() && reachable; ++i) {
        const YAML::Node child = std::as_const(parent)[parts[i]];  // const: looks up, never inserts
        reachable = child.IsDefined() && child.IsMap();
        if (reachable) parent.reset(child);
      }
      if (!reachable) continue;
      const YAML::Node node = std::as_const(parent)[parts.back()];
      if (node.IsDefined() && !node.IsMap()) fail_not_map(path, parent, parts.back(), node);
    }
  }

  [[noreturn]] void fail_not_map(const std::string& path, const YAML::Node& parent, const std::string& key,
                                 const YAML::Node& node) const {
    std::string where = origin_;
    if (overridden_.count(path)) {
      where += " (--set " + path + ")";
    } else {
      for (const auto& kv : parent) {  // the key's own line: an empty value has no useful mark
        if (kv.first.IsScalar() && kv.first.Scalar() == key && kv.first.Mark().line >= 0) {
          where += ":" + std::to_string(kv.first.Mark().line + 1);
          break;
        }
      }
    }
    const std::string value = node.IsNull() ? " is empty" : " = " + scalar_text(node);
    throw ConfigError(where + ": " + path + value + ": expected a map (a section of `key: value` lines, " +
                      "for example `" + path.substr(path.rfind('.') == std::string::npos ? 0 : path.rfind('.') + 1) +
                      ": {…}`); remove it to use the defaults");
  }

  /// "file:line" of a node inside `path`'s value (a list element, one of its keys), or the
  /// --set form when `path` came from an override.
  std::string where_node(const std::string& path, const YAML::Node& n) const {
    if (overridden_.count(path)) return origin_ + " (--set " + path + ")";
    if (n.Mark().line >= 0) return origin_ + ":" + std::to_string(n.Mark().line + 1);
    return where(path);
  }

  YAML::Node resolved() const { return resolved_; }
  void resolved_set_raw(const std::string& path, const YAML::Node& v) { resolved_set(path, v); }

 private:
  static std::optional<YAML::Node> find_in(const YAML::Node& node, const std::vector<std::string>& parts,
                                           std::size_t i) {
    if (i == parts.size()) return node;
    if (!node.IsMap()) return std::nullopt;
    const YAML::Node child = node[parts[i]];
    if (!child.IsDefined() || child.IsNull()) return std::nullopt;
    return find_in(child, parts, i + 1);
  }

  void mark_known(const std::string& path, bool leaf = false) {
    known_.insert(path);
    if (leaf) leaves_.insert(path);
    for (std::size_t dot = path.find('.'); dot != std::string::npos; dot = path.find('.', dot + 1)) {
      known_.insert(path.substr(0, dot));
      sections_.insert(path.substr(0, dot));
    }
  }

  void check_node(const YAML::Node& node, const std::string& prefix) const {
    if (!node.IsMap()) return;
    std::map<std::string, int> seen_line;  // yaml-cpp keeps duplicate keys silently: reject them
    for (const auto& kv : node) {
      if (!kv.first.IsScalar()) {  // a YAML complex key ("? a: b"), a list or a map as a key
        const int l = kv.first.Mark().line;
        throw ConfigError(origin_ + (l >= 0 ? ":" + std::to_string(l + 1) : "") + ": a key " +
                          (prefix.empty() ? std::string("at the top level") : "in '" + prefix + "'") + " is " +
                          scalar_text(kv.first) + ": expected a plain name");
      }
      const std::string key = kv.first.Scalar();
      const std::string path = prefix.empty() ? key : prefix + "." + key;
      const int line = kv.first.Mark().line;
      if (const auto it = seen_line.find(key); it != seen_line.end()) {
        throw ConfigError(origin_ + ":" + std::to_string(line + 1) + ": duplicate key '" + path +
                          "' (first given on line " + std::to_string(it->second + 1) + ")");
      }
      seen_line.emplace(key, line);
      if (!known_.count(path)) {
        std::string hint;
        for (const auto& k : known_) {
          const auto dot = k.rfind('.');
          const std::string parent = dot == std::string::npos ? "" : k.substr(0, dot);
          if (parent == prefix) hint += (hint.empty() ? "" : ", ") + k.substr(dot == std::string::npos ? 0 : dot + 1);
        }
        throw ConfigError(origin_ + (line >= 0 ? ":" + std::to_string(line + 1) : "") + ": unknown key '" +
                          path + "'" + (hint.empty() ? "" : " (allowed here: " + hint + ")"));
      }
      // A key some getter read below this one is a section: it must be a map (a backstop for
      // sections missing from kSections; see require_maps).
      if (sections_.count(path) && !leaves_.count(path) && !kv.second.IsMap()) {
        fail_not_map(path, node, key, kv.second);
      }
      if (!leaves_.count(path)) check_node(kv.second, path);
    }
  }

  void resolved_set(const std::string& path, const YAML::Node& value) {
    const auto parts = split_dotted(path);
    YAML::Node cur = resolved_;
    for (std::size_t i = 0; i + 1 < parts.size(); ++i) {
      if (!cur[parts[i]] || !cur[parts[i]].IsMap()) cur[parts[i]] = YAML::Node(YAML::NodeType::Map);
      YAML::Node next = cur[parts[i]];
      cur.reset(next);
    }
    cur[parts.back()] = value;
  }

  YAML::Node root_;
  std::string origin_;
  std::set<std::string> overridden_;
  std::set<std::string> known_;
  std::set<std::string> leaves_;
  std::set<std::string> sections_;
  YAML::Node resolved_{YAML::NodeType::Map};
};

void apply_override(YAML::Node& root, const std::string& spec, const std::string& origin,
                    std::set<std::string>& overridden) {
  const auto eq = spec.find('=');
  if (eq == std::string::npos || eq == 0) {
    throw ConfigError(origin + ": --set '" + spec + "': expected key=value (for example grid.n=400)");
  }
  const std::string key = spec.substr(0, eq);
  YAML::Node value;
  try {
    value = YAML::Load(spec.substr(eq + 1));
  } catch (const YAML::Exception& e) {
    throw ConfigError(origin + ": --set '" + spec + "': the value is not valid YAML (" + e.msg + ")");
  }
  const auto parts = split_dotted(key);
  YAML::Node cur = root;
  for (std::size_t i = 0; i + 1 < parts.size(); ++i) {
    if (cur[parts[i]] && !cur[parts[i]].IsNull() && !cur[parts[i]].IsMap()) {
      std::string section;
      for (std::size_t j = 0; j <= i; ++j) section += (j ? "." : "") + parts[j];
      const int line = cur[parts[i]].Mark().line;
      throw ConfigError(origin + (line >= 0 ? ":" + std::to_string(line + 1) : "") + ": --set '" + spec + "': " +
                        section + " = " + scalar_text(cur[parts[i]]) + ": expected a map");
    }
    if (!cur[parts[i]] || !cur[parts[i]].IsMap()) cur[parts[i]] = YAML::Node(YAML::NodeType::Map);
    YAML::Node next = cur[parts[i]];
    cur.reset(next);
  }
  cur[parts.back()] = value;
  overridden.insert(key);
}

SyntheticSpec read_synthetic(Reader& r, const std::string& p) {
  SyntheticSpec s;
  s.kind = surface_kind_from_string(r.get_string(p + ".surface", "sinusoid",
                                                 {"plane", "tilted_plane", "sphere_cap", "step", "sinusoid",
                                                  "temple_relief"}));
  s.half_extent_m = r.get_double(p + ".half_extent_m", s.half_extent_m, 0.0, 100.0, true);
  s.density_per_m2 = r.get_double(p + ".density_per_m2", s.density_per_m2, 0.0, 1e12, true);
  s.noise_sigma_m = r.get_double(p + ".noise_sigma_m", s.noise_sigma_m, 0.0, 1.0);
  s.seed = static_cast<std::uint64_t>(r.get_int(p + ".seed", 1, 0, std::numeric_limits<int>::max()));
  s.amplitude_m = r.get_double(p + ".amplitude_m", s.amplitude_m, 0.0, 10.0);
  s.wavelength_m = r.get_double(p + ".wavelength_m", s.wavelength_m, 0.0, 100.0, true);
  s.slope_x = r.get_double(p + ".slope_x", s.slope_x, -100.0, 100.0);
  s.slope_y = r.get_double(p + ".slope_y", s.slope_y, -100.0, 100.0);
  s.sphere_radius_m = r.get_double(p + ".sphere_radius_m", s.sphere_radius_m, 0.0, 100.0, true);
  return s;
}

ViewTransform read_view(Reader& r) {
  ViewTransform v;
  const bool axis = r.has("view.rotation.axis") || r.has("view.rotation.angle_deg");
  const bool euler = r.has("view.rotation.euler_deg") || r.has("view.rotation.order");
  const bool quat = r.has("view.rotation.quaternion_wxyz");
  if (int(axis) + int(euler) + int(quat) > 1) {
    r.fail("view.rotation", "mixes forms: give either axis + angle_deg, euler_deg + order, or quaternion_wxyz");
  }
  if (axis) {
    const Eigen::Vector3d a = r.get_vec3("view.rotation.axis", Eigen::Vector3d::UnitZ());
    if (a.norm() < 1e-12) r.fail("view.rotation.axis", "= [0, 0, 0]: expected a non-zero axis");
    v.rotation = rotation_from_axis_angle(a, r.get_double("view.rotation.angle_deg", 0.0, -360.0, 360.0));
  } else if (euler) {
    const Eigen::Vector3d e = r.get_vec3("view.rotation.euler_deg", Eigen::Vector3d::Zero(), -360.0, 360.0);
    const std::string order =
        r.get_string("view.rotation.order", "xyz", {"xyz", "xzy", "yxz", "yzx", "zxy", "zyx"});
    v.rotation = rotation_from_euler(e, order);
  } else if (quat) {
    r.has("view.rotation.quaternion_wxyz");
    const auto n = r.find("view.rotation.quaternion_wxyz");
    double q[4] = {1, 0, 0, 0};
    bool ok = n && n->IsSequence() && n->size() == 4;
    for (std::size_t i = 0; ok && i < 4; ++i) {
      try {
        q[i] = (*n)[i].as<double>();
      } catch (const YAML::Exception&) {
        ok = false;
      }
    }
    const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (!ok || !(norm > 1e-9)) {
      r.fail("view.rotation.quaternion_wxyz", "is invalid: expected 4 numbers [w, x, y, z] with a non-zero norm");
    }
    v.rotation = rotation_from_quaternion(q[0], q[1], q[2], q[3]);
    YAML::Node seq(YAML::NodeType::Sequence);
    for (double x : q) seq.push_back(x / norm);
    r.resolved_set_raw("view.rotation.quaternion_wxyz", seq);
  } else {
    r.resolved_set_raw("view.rotation.quaternion_wxyz", YAML::Load("[1, 0, 0, 0]"));
  }
  v.translation_m = r.get_vec3("view.translation_m", Eigen::Vector3d::Zero(), -1e4, 1e4);
  v.scale = r.get_double("view.scale", 1.0, 0.0, 1e6, true);
  return v;
}

/// audio.* (issue 7): contact sounds, parsed straight into hc::audio::AudioConfig. This reader
/// checks types, names and shapes (with the key's line); the ranges are checked once, by
/// hc::audio::check, whose issue is reported here with the key's line.
const std::vector<std::string> kAudioMaterials = {"granite", "sandstone", "marble", "bronze", "wood"};
const std::vector<std::string> kAudioNotes = {"Sa", "Re", "Ga", "Ma", "Pa", "Dha", "Ni"};

void read_material_overrides(Reader& r, const std::string& p, audio::Material& m) {
  const auto over = [&](const char* key, double& field) {
    if (r.has(p + "." + key)) field = r.get_number(p + "." + key, field);
  };
  over("slide_gain", m.slide_gain);
  over("resonance_hz", m.resonance_hz);
  over("q", m.q);
  over("grain_m", m.grain_m);
  over("roughness", m.roughness);
  over("speed_ref_m_per_s", m.speed_ref_m_per_s);
  over("texture_ref_m", m.texture_ref_m);
}

audio::Material read_material(Reader& r, const std::string& p) {
  const auto n = r.find(p);
  if (n && n->IsScalar()) return audio::material_preset(r.get_string(p, "granite", kAudioMaterials));
  audio::Material m = audio::material_preset(r.get_string(p + ".preset", "granite", kAudioMaterials));
  read_material_overrides(r, p, m);
  return m;
}

/// One element of audio.regions, checked key by key (a list element has no dotted path).
audio::RegionConfig read_audio_region(Reader& r, const YAML::Node& node, std::size_t i,
                                      const std::filesystem::path& base) {
  const std::string list = "audio.regions";
  const std::string p = list + "[" + std::to_string(i) + "]";
  const auto fail = [&](const std::string& what) -> void {
    throw ConfigError(r.where(list) + ": " + p + (what.rfind(".", 0) == 0 ? "" : " ") + what);
  };
  static const std::vector<std::string> kKeys = {"name", "box_m", "polygon_m", "label", "clip", "note", "gain",
                                                 "pitch", "retrigger", "trigger_on_enter", "mode", "material"};
  for (const auto& kv : node) {
    const std::string key = kv.first.as<std::string>();
    if (std::find(kKeys.begin(), kKeys.end(), key) == kKeys.end()) {
      std::string allowed;
      for (const auto& k : kKeys) allowed += (allowed.empty() ? "" : ", ") + k;
      fail("has an unknown key '" + key + "' (allowed here: " + allowed + ")");
    }
  }
  const auto number = [&](const YAML::Node& v, const std::string& key) {
    double d = 0.0;
    try {
      if (!v.IsScalar()) throw YAML::Exception(YAML::Mark::null_mark(), "");
      d = v.as<double>();
    } catch (const YAML::Exception&) {
      fail("." + key + " = " + scalar_text(v) + ": expected a number");
    }
    if (!std::isfinite(d)) fail("." + key + " is not finite");
    return d;
  };
  const auto boolean = [&](const YAML::Node& v, const std::string& key) {
    try {
      if (!v.IsScalar()) throw YAML::Exception(YAML::Mark::null_mark(), "");
      return v.as<bool>();
    } catch (const YAML::Exception&) {
      fail("." + key + " = " + scalar_text(v) + ": expected true or false");
    }
    return false;
  };
  const auto text = [&](const YAML::Node& v, const std::string& key) {
    if (!v.IsScalar()) fail("." + key + " = " + scalar_text(v) + ": expected a string");
    return v.Scalar();
  };
  audio::RegionConfig s;
  if (!node["name"]) fail("lacks 'name': every region needs a unique name");
  s.name = text(node["name"], "name");
  const int shapes = int(bool(node["box_m"])) + int(bool(node["polygon_m"])) + int(bool(node["label"]));
  if (shapes != 1) fail("('" + s.name + "') needs exactly one of box_m, polygon_m, label");
  if (node["box_m"]) {
    const YAML::Node b = node["box_m"];
    if (!b.IsSequence() || b.size() != 4) fail(".box_m = " + scalar_text(b) + ": expected [x_min, y_min, x_max, y_max] in metres");
    s.shape.kind = audio::ShapeKind::kBox;
    s.shape.x_min_m = number(b[0], "box_m");
    s.shape.y_min_m = number(b[1], "box_m");
    s.shape.x_max_m = number(b[2], "box_m");
    s.shape.y_max_m = number(b[3], "box_m");
  } else if (node["polygon_m"]) {
    s.shape.kind = audio::ShapeKind::kPolygon;
    const YAML::Node poly = node["polygon_m"];
    if (!poly.IsSequence()) fail(".polygon_m: expected a list of at least 3 [x, y] pairs in metres");
    for (const auto& v : poly) {
      if (!v.IsSequence() || v.size() != 2) fail(".polygon_m has a vertex that is not an [x, y] pair");
      s.shape.polygon_m.push_back({number(v[0], "polygon_m"), number(v[1], "polygon_m")});
    }
  } else {
    s.shape.kind = audio::ShapeKind::kLabel;
    const double l = number(node["label"], "label");
    if (l != std::floor(l) || std::abs(l) > 1e9) fail(".label = " + scalar_text(node["label"]) + ": expected an integer in [1, 65535]");
    s.shape.label = static_cast<std::int32_t>(l);
  }
  if (node["clip"]) s.clip = base / text(node["clip"], "clip");
  if (node["note"]) {
    const std::string note = text(node["note"], "note");
    if (std::find(kAudioNotes.begin(), kAudioNotes.end(), note) == kAudioNotes.end()) {
      fail(".note = '" + note + "': expected one of Sa, Re, Ga, Ma, Pa, Dha, Ni");
    }
    s.note = audio::note_from_string(note);
  }
  if (node["gain"]) s.gain = number(node["gain"], "gain");
  if (node["pitch"]) s.pitch = number(node["pitch"], "pitch");
  if (node["retrigger"]) s.retrigger = boolean(node["retrigger"], "retrigger");
  if (node["trigger_on_enter"]) s.trigger_on_enter = boolean(node["trigger_on_enter"], "trigger_on_enter");
  if (node["mode"]) {
    const std::string mode = text(node["mode"], "mode");
    if (mode != "one_shot" && mode != "continuous") fail(".mode = '" + mode + "': expected one_shot or continuous");
    s.mode = mode == "continuous" ? audio::PlayMode::kContinuous : audio::PlayMode::kOneShot;
  }
  if (node["material"]) {
    const YAML::Node m = node["material"];
    const auto preset_ok = [&](const std::string& v) {
      if (std::find(kAudioMaterials.begin(), kAudioMaterials.end(), v) == kAudioMaterials.end()) {
        fail(".material = '" + v + "': expected one of granite, sandstone, marble, bronze, wood (or a map with preset and overrides)");
      }
      return v;
    };
    if (m.IsScalar()) {
      s.material = audio::material_preset(preset_ok(m.Scalar()));
    } else if (m.IsMap()) {
      s.material = audio::material_preset(m["preset"] ? preset_ok(text(m["preset"], "material.preset")) : "granite");
      double* fields[] = {&s.material.slide_gain, &s.material.resonance_hz, &s.material.q, &s.material.grain_m,
                          &s.material.roughness, &s.material.speed_ref_m_per_s, &s.material.texture_ref_m};
      const char* names[] = {"slide_gain", "resonance_hz", "q", "grain_m", "roughness", "speed_ref_m_per_s", "texture_ref_m"};
      for (const auto& kv : m) {
        const std::string key = kv.first.as<std::string>();
        if (key == "preset") continue;
        const auto it = std::find(std::begin(names), std::end(names), key);
        if (it == std::end(names)) {
          fail(".material has an unknown key '" + key + "' (allowed: preset, slide_gain, resonance_hz, q, grain_m, "
               "roughness, speed_ref_m_per_s, texture_ref_m)");
        }
        *fields[it - std::begin(names)] = number(kv.second, "material." + key);
      }
    } else {
      fail(".material: expected a preset name or a map");
    }
  }
  return s;
}

void read_audio(Reader& r, RunConfig& c, const std::filesystem::path& base) {
  if (!r.has("audio")) return;
  audio::AudioConfig a;
  a.enabled = r.get_bool("audio.enabled", true);
  a.sample_rate_hz = r.get_integer("audio.sample_rate_hz", a.sample_rate_hz);
  a.master_gain = r.get_number("audio.master_gain", a.master_gain);
  const double threshold_dbfs = r.get_number("audio.limiter.threshold_dbfs", -1.0);
  a.limiter_threshold = std::pow(10.0, threshold_dbfs / 20.0);
  a.limiter_release_s = r.get_number("audio.limiter.release_s", a.limiter_release_s);
  a.sa_hz = r.get_number("audio.tones.sa_hz", a.sa_hz);
  a.tone_seconds = r.get_number("audio.tones.seconds", a.tone_seconds);
  a.region_cell_m = r.get_number("audio.region_cell_m", a.region_cell_m);
  if (r.has("audio.label_image")) a.label_image = base / r.get_string("audio.label_image", "");
  a.force.threshold_n = r.get_number("audio.force.threshold_n", a.force.threshold_n);
  a.force.full_force_n = r.get_number("audio.force.full_force_n", a.force.full_force_n);
  a.force.min_gain = r.get_number("audio.force.min_gain", a.force.min_gain);
  a.force.strike_window_s = r.get_number("audio.force.strike_window_s", a.force.strike_window_s);
  a.slide_enabled = r.get_bool("audio.slide.enabled", true);
  a.default_material = read_material(r, "audio.slide.material");
  const auto regions = r.get_map_list("audio.regions");
  YAML::Node resolved(YAML::NodeType::Sequence);
  for (std::size_t i = 0; i < regions.size(); ++i) {
    a.regions.push_back(read_audio_region(r, regions[i], i, base));
    resolved.push_back(regions[i]);
  }
  r.resolved_set_raw("audio.regions", resolved);
  // The one range check, the audio module's own; reported at the key's line.
  if (const auto issue = audio::check(a)) {
    const std::string key = "audio." + issue->key;
    const std::string at = key.rfind("audio.regions", 0) == 0 ? std::string("audio.regions") : key;
    throw ConfigError(r.where(at) + ": " + key + " " + issue->message);
  }
  c.audio = std::move(a);
}

[[noreturn]] void pcl_fail(const Reader& r, const std::string& key, const YAML::Node& n, const std::string& what) {
  throw ConfigError(r.where_node(key, n) + ": " + what);
}

/// filters.pcl (issue 18): an ordered list of PCL filters, each a map with `name` (the PCL
/// class) and that class's parameters (pcl_filters.hpp, docs/config.md). Unknown names and
/// parameters, missing required parameters and values out of range are errors naming the
/// element's key, its line and what is allowed.
void read_pcl_filters(Reader& r, RunConfig& c) {
  struct Param {
    const char* key;
    enum Type { kNumber, kInt, kBool, kAxis, kVec3 } type;
    double lo, hi;
    bool lo_open;
    bool required;
  };
  using T = Param::Type;
  struct Kind {
    const char* name;
    PclFilterKind kind;
    std::vector<Param> params;
  };
  const double kMaxInt = 2147483647.0;
  const std::vector<Kind> kinds = {
      {"StatisticalOutlierRemoval", PclFilterKind::kStatisticalOutlierRemoval,
       {{"mean_k", T::kInt, 1, 1000, false, false}, {"stddev_mul", T::kNumber, 0, 100, true, false}}},
      {"RadiusOutlierRemoval", PclFilterKind::kRadiusOutlierRemoval,
       {{"radius_m", T::kNumber, 0, 10, true, true}, {"min_neighbors", T::kInt, 0, 1e6, false, false}}},
      {"VoxelGrid", PclFilterKind::kVoxelGrid, {{"leaf_m", T::kNumber, 0, 10, true, true}}},
      {"ApproximateVoxelGrid", PclFilterKind::kApproximateVoxelGrid, {{"leaf_m", T::kNumber, 0, 10, true, true}}},
      {"UniformSampling", PclFilterKind::kUniformSampling, {{"radius_m", T::kNumber, 0, 10, true, true}}},
      {"MovingLeastSquares", PclFilterKind::kMovingLeastSquares,
       {{"search_radius_m", T::kNumber, 0, 10, true, true}, {"polynomial_order", T::kInt, 0, 5, false, false}}},
      {"PassThrough", PclFilterKind::kPassThrough,
       {{"field", T::kAxis, 0, 0, false, true},
        {"min_m", T::kNumber, -1e6, 1e6, false, true},
        {"max_m", T::kNumber, -1e6, 1e6, false, true},
        {"negative", T::kBool, 0, 0, false, false}}},
      {"CropBox", PclFilterKind::kCropBox,
       {{"min_m", T::kVec3, -1e6, 1e6, false, true},
        {"max_m", T::kVec3, -1e6, 1e6, false, true},
        {"negative", T::kBool, 0, 0, false, false}}},
      {"EuclideanClusterExtraction", PclFilterKind::kEuclideanClusterExtraction,
       {{"tolerance_m", T::kNumber, 0, 10, true, true},
        {"min_cluster_size", T::kInt, 1, kMaxInt, false, false},
        {"max_cluster_size", T::kInt, 1, kMaxInt, false, false},
        {"keep_clusters", T::kInt, 1, 1e6, false, false}}},
  };
  std::string all_names;
  for (const auto& k : kinds) all_names += (all_names.empty() ? "" : ", ") + std::string(k.name);

  const std::string key = "filters.pcl";
  const auto items = r.get_map_list(key);
  YAML::Node resolved(YAML::NodeType::Sequence);
  for (std::size_t i = 0; i < items.size(); ++i) {
    const YAML::Node& item = items[i];
    const std::string at = key + "[" + std::to_string(i) + "]";
    const YAML::Node name_node = item["name"];
    if (!name_node.IsDefined() || !name_node.IsScalar()) {
      pcl_fail(r, key, item, at + " lacks 'name': expected the PCL class, one of: " + all_names);
    }
    const std::string name = name_node.Scalar();
    const auto kind = std::find_if(kinds.begin(), kinds.end(), [&](const Kind& k) { return name == k.name; });
    if (kind == kinds.end()) pcl_fail(r, key, name_node, at + ".name = '" + name + "': expected one of: " + all_names);
    std::string allowed = "name";
    for (const auto& p : kind->params) allowed += ", " + std::string(p.key);
    for (const auto& kv : item) {
      const std::string k = kv.first.Scalar();
      if (k == "name") continue;
      const bool known = std::any_of(kind->params.begin(), kind->params.end(), [&](const Param& p) { return k == p.key; });
      if (!known) pcl_fail(r, key, kv.first, "unknown key '" + at + "." + k + "' for " + name + " (allowed here: " + allowed + ")");
    }
    PclFilterSpec spec;
    spec.kind = kind->kind;
    spec.name = name;
    YAML::Node out(YAML::NodeType::Map);
    out["name"] = name;
    for (const auto& p : kind->params) {
      const YAML::Node v = item[p.key];
      const std::string pk = at + "." + p.key + " (" + name + ")";
      if (!v.IsDefined() || v.IsNull()) {
        if (p.required) pcl_fail(r, key, item, at + " (" + name + ") lacks '" + p.key + "' (parameters: " + allowed + ")");
        continue;
      }
      const std::string range = std::string(p.lo_open ? "(" : "[") + format_number(p.lo) + ", " + format_number(p.hi) + "]";
      switch (p.type) {
        case T::kNumber:
        case T::kInt: {
          double d = 0.0;
          bool ok = v.IsScalar();
          if (ok) {
            try {
              d = v.as<double>();
            } catch (const YAML::Exception&) {
              ok = false;
            }
          }
          const bool integer = p.type == T::kInt;
          const std::string expected = integer ? ": expected an integer in " + range : ": expected a number in " + range;
          if (!ok) pcl_fail(r, key, v, pk + " = " + scalar_text(v) + expected);
          if (!std::isfinite(d) || d < p.lo || d > p.hi || (p.lo_open && d == p.lo) || (integer && d != std::floor(d))) {
            pcl_fail(r, key, v, pk + " = " + scalar_text(v) + expected);
          }
          const std::string n = p.key;
          if (n == "mean_k") spec.mean_k = static_cast<int>(d);
          else if (n == "stddev_mul") spec.stddev_mul = d;
          else if (n == "radius_m") spec.radius_m = d;
          else if (n == "min_neighbors") spec.min_neighbors = static_cast<int>(d);
          else if (n == "leaf_m") spec.leaf_m = d;
          else if (n == "search_radius_m") spec.search_radius_m = d;
          else if (n == "polynomial_order") spec.polynomial_order = static_cast<int>(d);
          else if (n == "min_m") spec.min_m = d;
          else if (n == "max_m") spec.max_m = d;
          else if (n == "tolerance_m") spec.tolerance_m = d;
          else if (n == "min_cluster_size") spec.min_cluster_size = static_cast<int>(d);
          else if (n == "max_cluster_size") spec.max_cluster_size = static_cast<int>(d);
          else if (n == "keep_clusters") spec.keep_clusters = static_cast<int>(d);
          break;
        }
        case T::kBool: {
          try {
            if (!v.IsScalar()) throw YAML::Exception(YAML::Mark::null_mark(), "");
            spec.negative = v.as<bool>();
          } catch (const YAML::Exception&) {
            pcl_fail(r, key, v, pk + " = " + scalar_text(v) + ": expected true or false");
          }
          break;
        }
        case T::kAxis: {
          if (!v.IsScalar() || (v.Scalar() != "x" && v.Scalar() != "y" && v.Scalar() != "z")) {
            pcl_fail(r, key, v, pk + " = " + scalar_text(v) + ": expected one of: x, y, z");
          }
          spec.field = v.Scalar();
          break;
        }
        case T::kVec3: {
          Eigen::Vector3d x;
          bool ok = v.IsSequence() && v.size() == 3;
          for (std::size_t a = 0; ok && a < 3; ++a) {
            try {
              x[static_cast<Eigen::Index>(a)] = v[a].as<double>();
            } catch (const YAML::Exception&) {
              ok = false;
            }
          }
          ok = ok && x.allFinite() && (x.array() >= p.lo).all() && (x.array() <= p.hi).all();
          if (!ok) pcl_fail(r, key, v, pk + " = " + scalar_text(v) + ": expected a list of 3 numbers [x, y, z] in " + range + " m");
          (std::string(p.key) == "min_m" ? spec.box_min_m : spec.box_max_m) = x;
          break;
        }
      }
      out[p.key] = v;
    }
    if (spec.kind == PclFilterKind::kPassThrough && spec.min_m > spec.max_m) {
      pcl_fail(r, key, item["max_m"], at + ".max_m (PassThrough) = " + format_number(spec.max_m) + ": expected a number >= min_m (" +
                                  format_number(spec.min_m) + ")");
    }
    if (spec.kind == PclFilterKind::kCropBox && (spec.box_max_m.array() < spec.box_min_m.array()).any()) {
      pcl_fail(r, key, item["max_m"], at + ".max_m (CropBox): expected max_m >= min_m on every axis");
    }
    if (spec.kind == PclFilterKind::kEuclideanClusterExtraction && spec.max_cluster_size < spec.min_cluster_size) {
      pcl_fail(r, key, item["max_cluster_size"], at + ".max_cluster_size (EuclideanClusterExtraction) = " +
                                            std::to_string(spec.max_cluster_size) + ": expected an integer >= min_cluster_size (" +
                                            std::to_string(spec.min_cluster_size) + ")");
    }
    c.filters.pcl.push_back(std::move(spec));
    resolved.push_back(out);
  }
  if (!items.empty()) r.resolved_set_raw(key, resolved);
}

/// falcon.* (issue 5): parsed straight into hc::falcon::FalconConfig; ranges checked once, by
/// hc::falcon::check_falcon_config, reported at the key's line.
void read_falcon(Reader& r, RunConfig& c, const std::filesystem::path& base) {
  falcon::FalconConfig& f = c.falcon;
  if (r.has("falcon.firmware")) f.firmware_path = (base / r.get_string("falcon.firmware", "")).string();
  f.device_index = r.get_integer("falcon.index", f.device_index);
  f.max_force_n = r.get_number("falcon.max_force_n", f.max_force_n);
  f.max_missed_ticks = r.get_integer("falcon.max_missed_ticks", f.max_missed_ticks);
  if (const auto issue = falcon::check_falcon_config(f)) {
    const std::string key = "falcon." + issue->key;
    throw ConfigError(r.where(key) + ": " + key + " " + issue->message);
  }
}

/// Every section of the run config (docs/config.md), parents before children. A section read
/// only when present (audio, input.synthetic, filters.crop, view.rotation) is listed too, so
/// that an empty one (`audio:`) is an error rather than "absent". audio.slide.material is not
/// a section: it is a preset name or a map.
const std::vector<std::string> kSections = {
    "input",  "input.synthetic", "view",          "view.rotation", "filters",       "filters.outliers",
    "filters.outliers.far_clusters", "filters.crop", "grid",      "cross_check",   "layers",        "layers.texture", "layers.friction",
    "audio",  "audio.limiter",   "audio.tones",   "audio.force",   "audio.slide",   "falcon",
    "lod",    "scale"};

RunConfig build(Reader& r, const std::filesystem::path& origin) {
  r.require_maps(kSections);
  RunConfig c;
  c.source = origin;
  c.name = r.get_string("name", origin.stem().string());
  const std::filesystem::path base = origin.has_parent_path() ? origin.parent_path() : ".";

  // input
  c.input.units = r.get_string("input.units", "m", {"m", "cm", "mm", "ft", "us-ft", "in"});
  if (r.has("input.las.drop_classes")) {  // a list of LAS classification codes, 0..255
    const YAML::Node n = *r.find("input.las.drop_classes");
    const std::string expected = ": expected a list of LAS classification codes, integers in [0, 255] (e.g. [7, 18])";
    if (!n.IsSequence()) r.fail("input.las.drop_classes", "= " + scalar_text(n) + expected);
    c.input.las_drop_classes.clear();
    for (const auto& item : n) {
      long long v = -1;
      try {
        if (!item.IsScalar()) throw YAML::Exception(YAML::Mark::null_mark(), "");
        v = item.as<long long>();
      } catch (const YAML::Exception&) {
        r.fail("input.las.drop_classes", "has the element " + scalar_text(item) + expected);
      }
      if (v < 0 || v > 255) r.fail("input.las.drop_classes", "has the element " + std::to_string(v) + expected);
      c.input.las_drop_classes.push_back(static_cast<int>(v));
    }
  }
  {
    YAML::Node seq(YAML::NodeType::Sequence);
    for (int v : c.input.las_drop_classes) seq.push_back(v);
    r.resolved_set_raw("input.las.drop_classes", seq);
  }
  c.input.max_extent_m = r.get_double("input.max_extent_m", kDefaultMaxExtentM, 0.0, 1e9, true);
  c.input.as_points = r.get_bool("input.as_points", false);
  for (const auto& f : r.get_string_list("input.files")) c.input.files.push_back(base / f);
  if (r.has("input.conf")) c.input.conf = base / r.get_string("input.conf", "");
  if (r.has("input.synthetic")) c.input.synthetic = read_synthetic(r, "input.synthetic");
  if (c.input.files.empty() && !c.input.synthetic) {
    r.fail("input", "is missing its scans: expected input.files (a list of scan files) or input.synthetic");
  }
  if (!c.input.files.empty() && c.input.synthetic) {
    r.fail("input", "has both files and synthetic: expected exactly one of them");
  }
  c.input.shared_frame = r.get_bool("input.shared_frame", false);
  if (c.input.shared_frame && c.input.conf) {
    r.fail("input.shared_frame", "is true and input.conf is set: expected one of them (input.conf places scans "
                                 "by their poses; input.shared_frame takes files already in one frame)");
  }
  if (c.input.shared_frame && c.input.synthetic) r.fail("input.shared_frame", "is true with input.synthetic: expected input.files");
  if (c.input.files.size() > 1 && !c.input.conf && !c.input.shared_frame) {
    r.fail("input.files", "lists several scans but input.conf is missing: expected a scanalyze .conf "
                          "giving each scan's pose, or input.shared_frame: true when the files are parts of one "
                          "scan in one frame (the tiles of a survey)");
  }

  c.view = read_view(r);

  // filters
  c.filters.outliers.enabled = r.get_bool("filters.outliers.enabled", true);
  c.filters.outliers.k = static_cast<int>(r.get_int("filters.outliers.k", 16, 1, 256));
  c.filters.outliers.std_multiplier = r.get_double("filters.outliers.std_multiplier", 2.0, 0.0, 100.0, true);
  c.filters.outliers.scope = r.get_string("filters.outliers.scope", "all", {"all", "front"}) == "front"
                                 ? OutlierScope::kFront
                                 : OutlierScope::kAll;
  {
    auto& o = c.filters.outliers;
    o.method = r.get_string("filters.outliers.method", "robust", {"robust", "statistical"}) == "statistical"
                   ? OutlierMethod::kStatistical
                   : OutlierMethod::kRobust;
    o.local_ratio = r.get_double("filters.outliers.local_ratio", 3.0, 1.0, 100.0, true);
    o.mad_multiplier = r.get_double("filters.outliers.mad_multiplier", 8.0, 0.0, 100.0, true);
    // 0 (off) or (1, 100]: one message for every value outside both.
    o.off_surface_ratio = r.get_double("filters.outliers.off_surface_ratio", 2.0, -1e300, 1e300);
    if (!(o.off_surface_ratio == 0.0 || (o.off_surface_ratio > 1.0 && o.off_surface_ratio <= 100.0))) {
      r.fail("filters.outliers.off_surface_ratio",
             "= " + format_number(o.off_surface_ratio) + ": expected 0 (off) or a number in (1, 100]");
    }
    o.despike = r.get_bool("filters.outliers.despike", true);
    if (o.method == OutlierMethod::kRobust && o.scope == OutlierScope::kFront) {
      r.fail("filters.outliers.scope", "= front applies to method statistical only: expected scope all with method robust, "
                                       "or method statistical");
    }
    auto& f = o.far_clusters;
    f.enabled = r.get_bool("filters.outliers.far_clusters.enabled", true);
    f.link_m = r.get_double("filters.outliers.far_clusters.link_m", 0.0, 0.0, 1e3);
    f.far_distance_m = r.get_double("filters.outliers.far_clusters.far_distance_m", 0.0, 0.0, 1e6);
    f.max_points = static_cast<std::size_t>(r.get_int("filters.outliers.far_clusters.max_points", 1000, 0, 1LL << 32));
    f.max_fraction = r.get_double("filters.outliers.far_clusters.max_fraction", 0.01, 0.0, 1.0);
  }
  if (r.has("filters.crop")) {
    const Eigen::Vector3d lo = r.get_vec3("filters.crop.min_m", Eigen::Vector3d::Constant(-1e3));
    const Eigen::Vector3d hi = r.get_vec3("filters.crop.max_m", Eigen::Vector3d::Constant(1e3));
    if ((hi.array() <= lo.array()).any()) r.fail("filters.crop", "is empty: expected max_m > min_m on every axis");
    c.filters.crop_m = std::make_pair(lo, hi);
  }
  c.filters.voxel_m = r.get_double("filters.voxel_m", 0.0, 0.0, 10.0);
  read_pcl_filters(r, c);

  // grid
  auto& g = c.grid.reproject;
  const bool has_n = r.has("grid.n");
  const bool has_cell = r.has("grid.cell_size_m");
  if (has_n && has_cell) r.fail("grid", "gives both n and cell_size_m: expected exactly one");
  if (has_cell) {
    g.grid.cell_size_m = r.get_double("grid.cell_size_m", 0.0, 0.0, 100.0, true);
  } else {
    g.grid.n_long_side = static_cast<int>(r.get_int("grid.n", 800, 2, 65536));
  }
  g.grid.max_cells = static_cast<std::size_t>(r.get_int("grid.max_cells", 64LL * 1024 * 1024, 4, 1LL << 34));
  g.splat_radius_cells = r.get_double("grid.splat_radius_cells", 0.0, 0.0, 16.0);
  const std::string splat_mode = r.get_string("grid.splat_mode", "disc", {"disc", "interpolate", "plane"});
  g.splat_mode = splat_mode == "interpolate" ? SplatMode::kInterpolate
                 : splat_mode == "plane"     ? SplatMode::kPlane
                                             : SplatMode::kDisc;
  g.see_through_depth_m = r.get_double("grid.see_through_depth_m", 0.0, 0.0, 100.0);
  g.see_through_window_cells = static_cast<int>(r.get_int("grid.see_through_window_cells", 3, 1, 64));
  {
    const std::string up = r.get_string("grid.upsample", "off");
    const std::string expected = "expected auto, off, or an integer factor in [1, " +
                                 std::to_string(kMaxUpsampleFactor) + "]";
    if (up == "auto") {
      g.upsample_factor = 0;
    } else if (up == "off") {
      g.upsample_factor = 1;
    } else {
      const std::optional<int> k = whole_int(up);
      if (!k || *k < 1 || *k > kMaxUpsampleFactor) r.fail("grid.upsample", "= '" + up + "': " + expected);
      g.upsample_factor = *k;
    }
  }
  c.grid.hole_fill_max_cells = static_cast<int>(r.get_int("grid.hole_fill_max_cells", 0, 0, 1 << 24));
  c.grid.hole_fill_max_step_m = r.get_double("grid.hole_fill_max_step_m", 0.0, 0.0, 1e4);
  c.grid.organised_mesh = r.get_string("grid.organised", "splat", {"splat", "mesh"}) == "mesh";
  c.grid.organised_max_edge_factor = r.get_double("grid.organised_max_edge_factor", 4.0, 1.0, 100.0);
  c.grid.organised_blend_m = r.get_double("grid.organised_blend_m", 0.0, 0.0, 1.0);

  // cross-check
  c.cross_check.enabled = r.get_bool("cross_check.enabled", true);
  c.cross_check.tolerance_m = r.get_double("cross_check.tolerance_m", 0.0005, 0.0, 1.0, true);
  c.cross_check.compare_naive = r.get_bool("cross_check.compare_naive", false);
  c.cross_check.hidden_band_m = r.get_double("cross_check.hidden_band_m", 0.002, 0.0, 10.0, true);
  {  // the honest cross-check and the verdict (honest_check.hpp)
    HonestCheckOptions& h = c.cross_check.honest;
    h.tolerance_m = c.cross_check.tolerance_m;
    h.hidden_band_m = c.cross_check.hidden_band_m;
    h.isolation_radius_spacings =
        r.get_double("cross_check.isolation_radius_spacings", h.isolation_radius_spacings, 1.0, 1000.0);
    h.isolation_min_neighbours =
        static_cast<int>(r.get_int("cross_check.isolation_min_neighbours", h.isolation_min_neighbours, 1, 1000));
    h.spike_window_cells = static_cast<int>(r.get_int("cross_check.spike_window_cells", h.spike_window_cells, 3, 15));
    if (h.spike_window_cells % 2 == 0) {
      r.fail("cross_check.spike_window_cells", "= " + std::to_string(h.spike_window_cells) + ": expected an odd integer in [3, 15]");
    }
    h.spike_min_height_m = r.get_double("cross_check.spike_min_height_m", h.spike_min_height_m, 0.0, 1e6, true);
    h.spike_mad_factor = r.get_double("cross_check.spike_mad_factor", h.spike_mad_factor, 0.0, 1e6, true);
    h.spike_max_cells = static_cast<int>(r.get_int("cross_check.spike_max_cells", h.spike_max_cells, 1, 10000));
    h.confirm_by_splat_footprint = r.get_bool("cross_check.confirm_by_splat_footprint", h.confirm_by_splat_footprint);
    h.island_max_cells = static_cast<int>(r.get_int("cross_check.island_max_cells", h.island_max_cells, 1, 1 << 30));
    h.max_spike_cells = static_cast<int>(r.get_int("cross_check.max_spike_cells", h.max_spike_cells, 0, 1 << 30));
    h.max_spike_fraction = r.get_double("cross_check.max_spike_fraction", h.max_spike_fraction, 0.0, 1.0);
    h.spike_allowance_max_m = r.get_double("cross_check.spike_allowance_max_m", h.spike_allowance_max_m, 0.0, 1e3);
    h.max_spikes_kept_cells =
        static_cast<int>(r.get_int("cross_check.max_spikes_kept_cells", h.max_spikes_kept_cells, 0, 1 << 30));
    h.max_island_cells = static_cast<int>(r.get_int("cross_check.max_island_cells", h.max_island_cells, 0, 1 << 30));
    h.max_removed_fraction = r.get_double("cross_check.max_removed_fraction", h.max_removed_fraction, 0.0, 1.0);
    h.max_surface_lost_fraction =
        r.get_double("cross_check.max_surface_lost_fraction", h.max_surface_lost_fraction, 0.0, 1.0);
    h.min_visible_on_surface_fraction =
        r.get_double("cross_check.min_visible_on_surface_fraction", h.min_visible_on_surface_fraction, 0.0, 1.0);
    h.min_supported_fraction = r.get_double("cross_check.min_supported_fraction", h.min_supported_fraction, 0.0, 1.0);
    h.max_filter_threshold_spacings =
        r.get_double("cross_check.max_filter_threshold_spacings", h.max_filter_threshold_spacings, 0.0, 1e9, true);
  }

  // surface layers
  auto& L = c.layers.options;
  c.layers.enabled = r.get_bool("layers.enabled", true);
  L.sigma_space_cells = r.get_double("layers.texture.sigma_space_cells", L.sigma_space_cells, 0.0, 100.0, true);
  L.sigma_range_m = r.get_double("layers.texture.sigma_range_m", L.sigma_range_m, 0.0, 10.0, true);
  L.friction_model = friction_model_from_string(
      r.get_string("layers.friction.model", "paper", {"paper", "curvature"}));
  L.mu_min = r.get_double("layers.friction.mu_min", L.mu_min, 0.0, 10.0);
  L.mu_max = r.get_double("layers.friction.mu_max", L.mu_max, 0.0, 10.0);
  if (L.mu_max < L.mu_min) {
    r.fail("layers.friction.mu_max", "= " + format_number(L.mu_max) + ": expected a number ≥ mu_min (" +
                                         format_number(L.mu_min) + ")");
  }
  L.workspace_radius_m = r.get_double("layers.friction.workspace_radius_m", L.workspace_radius_m, 0.0, 10.0, true);
  L.curvature_gain_m = r.get_double("layers.friction.curvature_gain_m", L.curvature_gain_m, 0.0, 100.0);
  L.friction_scale = friction_scale_from_string(r.get_string("layers.friction.scale", to_string(L.friction_scale),
                                                             {"scene", "device", "level_median"}));
  L.mu_s = r.get_double("layers.friction.mu_s", L.mu_s, 0.0, 10.0);
  const auto regions = r.get_map_list("layers.friction.mu_s_regions");
  YAML::Node resolved_regions(YAML::NodeType::Sequence);
  for (std::size_t i = 0; i < regions.size(); ++i) {
    const std::string p = "layers.friction.mu_s_regions[" + std::to_string(i) + "]";
    StaticFrictionRegion reg;
    double* fields[] = {&reg.x_min_m, &reg.y_min_m, &reg.x_max_m, &reg.y_max_m, &reg.mu_s};
    const char* names[] = {"x_min_m", "y_min_m", "x_max_m", "y_max_m", "mu_s"};
    for (const auto& kv : regions[i]) {
      const std::string key = kv.first.as<std::string>();
      if (std::find(std::begin(names), std::end(names), key) == std::end(names)) {
        throw ConfigError(r.where("layers.friction.mu_s_regions") + ": unknown key '" + p + "." + key +
                          "' (allowed here: x_min_m, y_min_m, x_max_m, y_max_m, mu_s)");
      }
    }
    YAML::Node out(YAML::NodeType::Map);
    for (int k = 0; k < 5; ++k) {
      const YAML::Node v = regions[i][names[k]];
      if (!v.IsDefined() || !v.IsScalar()) {
        r.fail("layers.friction.mu_s_regions", "element " + std::to_string(i) + " lacks '" + names[k] +
                                                   "': expected x_min_m, y_min_m, x_max_m, y_max_m, mu_s");
      }
      try {
        *fields[k] = v.as<double>();
      } catch (const YAML::Exception&) {
        r.fail("layers.friction.mu_s_regions", "element " + std::to_string(i) + " has " + names[k] + " = '" +
                                                   v.Scalar() + "': expected a number");
      }
      out[names[k]] = *fields[k];
    }
    if (reg.x_max_m <= reg.x_min_m || reg.y_max_m <= reg.y_min_m || reg.mu_s < 0.0 || reg.mu_s > 10.0) {
      r.fail("layers.friction.mu_s_regions", "element " + std::to_string(i) +
                                                 " is invalid: expected x_max_m > x_min_m, y_max_m > y_min_m and mu_s in [0, 10]");
    }
    L.mu_s_regions.push_back(reg);
    resolved_regions.push_back(out);
  }
  r.resolved_set_raw("layers.friction.mu_s_regions", resolved_regions);

  read_audio(r, c, base);

  // Novint Falcon (issue 5; hc::falcon reads these through the app)
  read_falcon(r, c, base);

  // levels of detail (lod.hpp; docs/lod.md)
  c.lod.min_cells = static_cast<int>(r.get_int("lod.min_cells", c.lod.min_cells, 2, 65536));
  c.lod.valid_fraction = r.get_double("lod.valid_fraction", c.lod.valid_fraction, 0.0, 1.0, true);
  c.lod.antialias_sigma_cells = r.get_double("lod.antialias_sigma_cells", c.lod.antialias_sigma_cells, 0.5, 4.0);
  c.lod.memory_budget_mb = r.get_double("lod.memory_budget_mb", c.lod.memory_budget_mb, 0.0, 1e6, true);
  c.lod.window_cells = static_cast<int>(r.get_int("lod.window_cells", c.lod.window_cells, 2, 4096));
  c.lod.report = r.get_bool("lod.report", c.lod.report);
  c.lod.report_cross_check = r.get_bool("lod.report_cross_check", c.lod.report_cross_check);
  c.lod.report_sample_points = static_cast<std::size_t>(
      r.get_int("lod.report_sample_points", static_cast<long long>(c.lod.report_sample_points), 0, 1LL << 40));

  // the streaming tiled run (tiling.hpp; docs/scale.md)
  {
    const std::string t = r.get_string("scale.tiled", "auto", {"auto", "on", "off"});
    c.scale.tiled = t == "on" ? ScaleConfig::Tiled::kOn : t == "off" ? ScaleConfig::Tiled::kOff : ScaleConfig::Tiled::kAuto;
    c.scale.tiled_above_points = static_cast<std::uint64_t>(
        r.get_int("scale.tiled_above_points", static_cast<long long>(c.scale.tiled_above_points), 1, 1LL << 50));
    c.scale.tile_cells = static_cast<int>(r.get_int("scale.tile_cells", c.scale.tile_cells, 16, 65536));
    c.scale.tile_max_points = static_cast<std::uint64_t>(
        r.get_int("scale.tile_max_points", static_cast<long long>(c.scale.tile_max_points), 0, 1LL << 40));
    if (c.scale.tile_max_points > 0 && c.scale.tile_max_points < 1000) {
      r.fail("scale.tile_max_points", "= " + std::to_string(c.scale.tile_max_points) + ": expected 0 (no bound) or at least 1000");
    }
    {
      const std::string fh = r.get_string("scale.filter_halo_cells", "auto");
      if (fh == "auto") {
        c.scale.filter_halo_cells = ScaleConfig::kAutoFilterHalo;
      } else {
        const std::optional<int> f = whole_int(fh);
        if (!f || *f < 0 || *f > 4096) r.fail("scale.filter_halo_cells", "= '" + fh + "': expected auto or an integer in [0, 4096]");
        c.scale.filter_halo_cells = *f;
      }
    }
    {
      const std::optional<bool> ih = r.get_bool_or_auto("scale.island_halo");
      c.scale.island_halo = !ih ? ScaleConfig::Tiled::kAuto : *ih ? ScaleConfig::Tiled::kOn : ScaleConfig::Tiled::kOff;
    }
    c.scale.grid_on_kept_points = r.get_bool("scale.grid_on_kept_points", c.scale.grid_on_kept_points);
    c.scale.chunk_points = static_cast<std::size_t>(
        r.get_int("scale.chunk_points", static_cast<long long>(c.scale.chunk_points), 1024, 1LL << 28));
    if (r.has("scale.scratch")) c.scale.scratch = base / r.get_string("scale.scratch", "");
    c.scale.level0_file = r.get_bool("scale.level0_file", c.scale.level0_file);
    if (r.has("scale.block_copies")) {
      r.fail("scale.block_copies", "was removed on 2026-11-27: the robust test's strays are judged in one gathering per band of "
                                   "tiles, which makes no block copies (docs/scale.md); delete the key (scale.band_mb bounds a band)");
    }
    c.scale.band_mb = r.get_double("scale.band_mb", c.scale.band_mb, 0.0, 65536.0);
    c.scale.max_gatherings = static_cast<int>(r.get_int("scale.max_gatherings", c.scale.max_gatherings, 1, 64));
    c.scale.progress_interval_s = r.get_double("scale.progress_interval_s", c.scale.progress_interval_s, 0.0, 3600.0);
    const std::string st = r.get_string("scale.scene_tiles", "auto", {"auto", "on", "off"});
    c.scale.scene_tiles = st == "on" ? ScaleConfig::Tiled::kOn : st == "off" ? ScaleConfig::Tiled::kOff : ScaleConfig::Tiled::kAuto;
    c.scale.scene_tiles_above_cells = static_cast<std::uint64_t>(r.get_int(
        "scale.scene_tiles_above_cells", static_cast<long long>(c.scale.scene_tiles_above_cells), 1, 1LL << 50));
    c.scale.scene_tile_cells = static_cast<int>(r.get_int("scale.scene_tile_cells", c.scale.scene_tile_cells, 16, 4096));
    if (c.scale.scene_tile_cells % 16 != 0) {
      r.fail("scale.scene_tile_cells", "= " + std::to_string(c.scale.scene_tile_cells) +
                                           ": expected a multiple of 16 (TIFF tiles are multiples of 16 samples)");
    }
    c.scale.preview_max_side = static_cast<int>(r.get_int("scale.preview_max_side", c.scale.preview_max_side, 64, 65536));
  }

  r.reject_unknown_keys();
  YAML::Emitter e;
  e << r.resolved();
  c.resolved_yaml = e.c_str();
  return c;
}

/// The 1-based number of the line, at or before `error_line` (else just after it), whose
/// indentation holds a tab; 0 if none. yaml-cpp reports a tab-indented line as "illegal map
/// value" or "illegal tab when looking for indentation" without naming the tab.
int tab_indented_line(const std::string& text, int error_line) {
  std::vector<int> tabbed;
  std::istringstream in(text);
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    const auto first = line.find_first_not_of(" \t");
    const std::string indent = line.substr(0, first == std::string::npos ? line.size() : first);
    if (first != std::string::npos && indent.find('\t') != std::string::npos) tabbed.push_back(n);
  }
  int best = 0;
  for (int n : tabbed) {
    if (n <= error_line) best = n;
  }
  if (best == 0) {
    for (int n : tabbed) {
      if (n == error_line + 1) best = n;
    }
  }
  return best;
}

}  // namespace

RunConfig parse_run_config(const std::string& yaml_text, const std::filesystem::path& origin,
                           const std::vector<std::string>& overrides) {
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const YAML::ParserException& e) {
    if (const int tab_line = tab_indented_line(yaml_text, e.mark.line + 1); tab_line > 0) {
      throw InputError(origin.string() + ":" + std::to_string(tab_line) +
                       ": not valid YAML: a tab in the indentation (YAML indents with spaces only; " +
                       "yaml-cpp says: " + e.msg + ")");
    }
    throw InputError(origin.string() + ":" + std::to_string(e.mark.line + 1) + ":" +
                     std::to_string(e.mark.column + 1) + ": not valid YAML: " + e.msg);
  }
  if (root.IsNull()) root = YAML::Node(YAML::NodeType::Map);
  if (!root.IsMap()) throw ConfigError(origin.string() + ": expected a YAML map of sections (input, grid, ...)");
  std::set<std::string> overridden;
  for (const auto& o : overrides) apply_override(root, o, origin.string(), overridden);
  Reader reader(root, origin.string(), overridden);
  try {
    return build(reader, origin);
  } catch (const YAML::Exception& e) {
    // Every key is checked by the reader; this is the backstop for a node shape it did not expect.
    throw ConfigError(origin.string() + ":" + std::to_string(e.mark.line + 1) + ": unexpected YAML structure (" +
                      e.msg + ")");
  }
}

RunConfig load_run_config(const std::filesystem::path& path, const std::vector<std::string>& overrides) {
  std::ifstream in(path);
  if (!in) throw InputError(path.string() + ": cannot open the config file (does it exist?)");
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_run_config(ss.str(), path, overrides);
}

}  // namespace hc::pipeline

namespace hc::pipeline {
bool writes_tiled_scene(const ScaleConfig& config, const GridGeometry& grid) {
  if (config.scene_tiles == ScaleConfig::Tiled::kOn) return true;
  if (config.scene_tiles == ScaleConfig::Tiled::kOff) return false;
  return static_cast<std::uint64_t>(grid.cell_count()) > config.scene_tiles_above_cells;
}
}  // namespace hc::pipeline
