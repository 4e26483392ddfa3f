#include "hc/audio/audio_config.hpp"

#include "hc/common/error.hpp"
#include "hc/common/format.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <set>
#include <sstream>

namespace hc::audio {
namespace {

constexpr const char* kNoteNames[7] = {"Sa", "Re", "Ga", "Ma", "Pa", "Dha", "Ni"};
constexpr double kNoteRatios[7] = {1.0, 9.0 / 8.0, 5.0 / 4.0, 4.0 / 3.0, 3.0 / 2.0, 5.0 / 3.0, 15.0 / 8.0};

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

/// Thrown inside check() to carry the first issue out of the nested checks.
struct Issue {
  ConfigIssue issue;
};

void check_range(const std::string& key, double v, double lo, double hi, bool lo_open = false, bool hi_open = false) {
  const bool ok = std::isfinite(v) && (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi);
  if (!ok) {
    throw Issue{{key, "= " + format_number(v) + ": expected a number in " + (lo_open ? "(" : "[") + format_number(lo) + ", " + format_number(hi) +
                          (hi_open ? ")" : "]")}};
  }
}

void check_material(const std::string& p, const Material& m) {
  check_range(p + ".slide_gain", m.slide_gain, 0.0, 4.0);
  check_range(p + ".resonance_hz", m.resonance_hz, 20.0, 20000.0, true, true);
  check_range(p + ".q", m.q, 0.3, 100.0);
  check_range(p + ".grain_m", m.grain_m, 0.0, 0.1, true);
  check_range(p + ".roughness", m.roughness, 0.0, 1.0);
  check_range(p + ".speed_ref_m_per_s", m.speed_ref_m_per_s, 0.0, 10.0, true);
  check_range(p + ".texture_ref_m", m.texture_ref_m, 0.0, 0.1, true);
}

}  // namespace

Note note_from_string(const std::string& name) {
  const std::string l = lower(name);
  for (int i = 0; i < 7; ++i) {
    if (l == lower(kNoteNames[i])) return static_cast<Note>(i);
  }
  throw ConfigError("audio: note '" + name + "' is unknown: expected one of Sa, Re, Ga, Ma, Pa, Dha, Ni");
}

const char* to_string(Note note) noexcept {
  const auto i = static_cast<std::size_t>(note);
  return i < 7 ? kNoteNames[i] : "?";
}

double note_frequency_hz(Note note, double sa_hz) noexcept {
  const auto i = static_cast<std::size_t>(note);
  return sa_hz * (i < 7 ? kNoteRatios[i] : 1.0);
}

Material material_preset(const std::string& name) {
  Material m;
  const std::string l = lower(name);
  m.name = l;
  if (l == "granite") {
    m.slide_gain = 0.25, m.resonance_hz = 2200.0, m.q = 4.0, m.grain_m = 0.0005, m.roughness = 0.5;
  } else if (l == "sandstone") {
    m.slide_gain = 0.3, m.resonance_hz = 1500.0, m.q = 1.5, m.grain_m = 0.0003, m.roughness = 0.3;
  } else if (l == "marble") {
    m.slide_gain = 0.15, m.resonance_hz = 3000.0, m.q = 6.0, m.grain_m = 0.002, m.roughness = 0.2;
  } else if (l == "bronze") {
    m.slide_gain = 0.2, m.resonance_hz = 3500.0, m.q = 30.0, m.grain_m = 0.001, m.roughness = 0.6;
  } else if (l == "wood") {
    m.slide_gain = 0.3, m.resonance_hz = 800.0, m.q = 3.0, m.grain_m = 0.001, m.roughness = 0.7;
  } else {
    throw ConfigError("audio: material '" + name + "' is unknown: expected one of granite, sandstone, marble, bronze, wood");
  }
  return m;
}

void check_all(const AudioConfig& c) {
  if (c.sample_rate_hz < 8000 || c.sample_rate_hz > 192000) {
    throw Issue{{"sample_rate_hz", "= " + std::to_string(c.sample_rate_hz) + ": expected an integer in [8000, 192000]"}};
  }
  check_range("master_gain", c.master_gain, 0.0, 4.0);
  if (!(c.limiter_threshold > 0.0 && c.limiter_threshold <= 1.0)) {
    const double dbfs = c.limiter_threshold > 0.0 ? 20.0 * std::log10(c.limiter_threshold) : -HUGE_VAL;
    throw Issue{{"limiter.threshold_dbfs", "= " + format_number(dbfs) + " (linear " + format_number(c.limiter_threshold) +
                                               "): expected a number in [-40, 0] dBFS, i.e. (0, 1] linear"}};
  }
  check_range("limiter.release_s", c.limiter_release_s, 0.0, 10.0, true);
  check_range("tones.sa_hz", c.sa_hz, 20.0, 4000.0, true);
  check_range("tones.seconds", c.tone_seconds, 0.05, 20.0, true);
  check_range("region_cell_m", c.region_cell_m, 0.0, 1.0, true);
  check_range("force.threshold_n", c.force.threshold_n, 0.0, 100.0);
  check_range("force.full_force_n", c.force.full_force_n, 0.0, 100.0, true);
  check_range("force.min_gain", c.force.min_gain, 0.0, 1.0);
  check_range("force.strike_window_s", c.force.strike_window_s, 0.0, 1.0);
  check_material("slide.material", c.default_material);
  if (note_frequency_hz(Note::kNi, c.sa_hz) * 2.0 >= 0.5 * c.sample_rate_hz) {
    throw Issue{{"tones.sa_hz", "= " + format_number(c.sa_hz) + " is too high for sample_rate_hz = " +
                                    std::to_string(c.sample_rate_hz) + ": the synthesised partials would alias"}};
  }
  std::set<std::string> names;
  for (std::size_t i = 0; i < c.regions.size(); ++i) {
    const RegionConfig& r = c.regions[i];
    const std::string p = "regions[" + std::to_string(i) + "]";
    if (r.name.empty()) throw Issue{{p + ".name", "is empty: expected a name"}};
    if (!names.insert(r.name).second) {
      throw Issue{{"regions", "has the name '" + r.name + "' twice (element " + std::to_string(i) +
                                  "): expected unique names"}};
    }
    const std::string& q = p;
    check_range(q + ".gain", r.gain, 0.0, 16.0);
    check_range(q + ".pitch", r.pitch, 0.25, 4.0);
    check_material(q + ".material", r.material);
    const RegionShape& s = r.shape;
    switch (s.kind) {
      case ShapeKind::kBox:
        if (!(std::isfinite(s.x_min_m) && std::isfinite(s.x_max_m) && std::isfinite(s.y_min_m) &&
              std::isfinite(s.y_max_m) && s.x_max_m > s.x_min_m && s.y_max_m > s.y_min_m)) {
          throw Issue{{q + ".box_m", "= [" + format_number(s.x_min_m) + ", " + format_number(s.y_min_m) + ", " + format_number(s.x_max_m) + ", " +
                                         format_number(s.y_max_m) +
                                         "]: expected [x_min, y_min, x_max, y_max] with x_max > x_min and y_max > y_min"}};
        }
        break;
      case ShapeKind::kPolygon:
        if (s.polygon_m.size() < 3) {
          throw Issue{{q + ".polygon_m", "has " + std::to_string(s.polygon_m.size()) +
                                             " vertices: expected at least 3 [x, y] pairs"}};
        }
        for (const auto& v : s.polygon_m) {
          if (!std::isfinite(v[0]) || !std::isfinite(v[1])) {
            throw Issue{{q + ".polygon_m", "has a non-finite vertex"}};
          }
        }
        break;
      case ShapeKind::kLabel:
        if (s.label < 1) {
          throw Issue{{q + ".label", "= " + std::to_string(s.label) + ": expected an integer in [1, 65535]"}};
        }
        if (c.label_image.empty()) {
          throw Issue{{"regions", "element " + q.substr(8, q.size() - 9) + " uses a label but audio.label_image is not given"}};
        }
        break;
    }
  }
}

std::optional<ConfigIssue> check(const AudioConfig& config) {
  try {
    check_all(config);
  } catch (const Issue& e) {
    return e.issue;
  }
  return std::nullopt;
}

void validate(const AudioConfig& config) {
  if (const auto issue = check(config)) throw ConfigError("audio." + issue->key + " " + issue->message);
}

}  // namespace hc::audio
