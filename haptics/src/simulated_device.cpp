#include "hc/haptics/simulated_device.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <fstream>
#include <numbers>
#include <sstream>
#include <string>
#include <utility>

namespace hc::haptics {
namespace {

/// Smooth 0 → 1 over [0, 1] with zero slope at both ends.
double smooth(double s) noexcept {
  s = std::clamp(s, 0.0, 1.0);
  return s * s * (3.0 - 2.0 * s);
}

/// Triangle wave: position in [0, len] after travelling d, starting at 0, back and forth.
double ping_pong(double d, double len) noexcept {
  const double m = std::fmod(d, 2.0 * len);
  return m <= len ? m : 2.0 * len - m;
}

}  // namespace

PathKind path_kind_from_string(std::string_view name) {
  if (name == "hold") return PathKind::kHold;
  if (name == "line") return PathKind::kLine;
  if (name == "circle") return PathKind::kCircle;
  if (name == "raster") return PathKind::kRaster;
  if (name == "press-slide" || name == "press_slide") return PathKind::kPressSlide;
  throw ConfigError("unknown path '" + std::string(name) +
                    "' (expected one of: hold, line, circle, raster, press-slide)");
}

const char* to_string(PathKind kind) noexcept {
  switch (kind) {
    case PathKind::kHold: return "hold";
    case PathKind::kLine: return "line";
    case PathKind::kCircle: return "circle";
    case PathKind::kRaster: return "raster";
    case PathKind::kPressSlide: return "press-slide";
  }
  return "unknown";
}

void ScriptedPath::validate() const {
  const auto fail = [](const char* field, double value, const char* expected) {
    std::ostringstream s;
    s << "scripted path: " << field << " = " << value << ", expected " << expected;
    throw ConfigError(s.str());
  };
  if (!centre_m.allFinite()) fail("centre_m.x", centre_m.x(), "finite coordinates");
  if (!(half_x_m > 0) || !std::isfinite(half_x_m)) fail("half_x_m", half_x_m, "finite > 0");
  if (!(half_y_m > 0) || !std::isfinite(half_y_m)) fail("half_y_m", half_y_m, "finite > 0");
  if (!(speed_m_per_s > 0) || !std::isfinite(speed_m_per_s)) fail("speed_m_per_s", speed_m_per_s, "finite > 0");
  if (!(raster_spacing_m > 0) || !std::isfinite(raster_spacing_m)) {
    fail("raster_spacing_m", raster_spacing_m, "finite > 0");
  }
  if (!(approach_s > 0) || !std::isfinite(approach_s)) fail("approach_s", approach_s, "finite > 0");
  if (!std::isfinite(z_above_m) || !std::isfinite(z_contact_m) || !(z_contact_m < z_above_m)) {
    fail("z_contact_m", z_contact_m, "finite and below z_above_m");
  }
}

Eigen::Vector3d ScriptedPath::position_at(double t) const noexcept {
  if (!(t > 0.0)) t = 0.0;
  const double cx = centre_m.x(), cy = centre_m.y();
  const double dz = z_contact_m - z_above_m;
  if (kind == PathKind::kPressSlide) {
    const double slide_s = 2.0 * half_x_m / speed_m_per_s;
    const double cycle = 2.0 * approach_s + 2.0 * slide_s;
    const double u = std::fmod(t, cycle);
    const double x0 = cx - half_x_m;
    if (u < approach_s) return {x0, cy, z_above_m + dz * smooth(u / approach_s)};
    if (u < approach_s + slide_s) return {x0 + speed_m_per_s * (u - approach_s), cy, z_contact_m};
    if (u < 2 * approach_s + slide_s) {
      return {cx + half_x_m, cy, z_contact_m - dz * smooth((u - approach_s - slide_s) / approach_s)};
    }
    return {cx + half_x_m - speed_m_per_s * (u - 2 * approach_s - slide_s), cy, z_above_m};
  }
  // Start point of the in-plane pattern.
  const auto pattern = [&](double d) -> Eigen::Vector2d {
    switch (kind) {
      case PathKind::kHold: return {cx, cy};
      case PathKind::kLine: return {cx - half_x_m + ping_pong(d, 2.0 * half_x_m), cy};
      case PathKind::kCircle: {
        const double a = d / half_x_m;
        return {cx + half_x_m * std::cos(a), cy + half_x_m * std::sin(a)};
      }
      case PathKind::kRaster: {
        const int lines = 1 + static_cast<int>(std::floor(2.0 * half_y_m / raster_spacing_m + 1e-9));
        const double len_x = 2.0 * half_x_m;
        const double unit = len_x + raster_spacing_m;
        const double forward = lines * len_x + (lines - 1) * raster_spacing_m;
        const double s = ping_pong(d, forward);
        const int i = std::min(static_cast<int>(s / unit), lines - 1);
        const double r = s - i * unit;
        const double y = cy - half_y_m + i * raster_spacing_m;
        const bool even = i % 2 == 0;
        if (r <= len_x) return {even ? cx - half_x_m + r : cx + half_x_m - r, y};
        return {even ? cx + half_x_m : cx - half_x_m, y + (r - len_x)};
      }
      case PathKind::kPressSlide: break;
    }
    return {cx, cy};
  };
  if (t < approach_s) {
    const Eigen::Vector2d p = pattern(0.0);
    return {p.x(), p.y(), z_above_m + dz * smooth(t / approach_s)};
  }
  const Eigen::Vector2d p = pattern(speed_m_per_s * (t - approach_s));
  return {p.x(), p.y(), z_contact_m};
}

DeviceInfo SimulatedDevice::default_info() {
  DeviceInfo info;
  info.name = "simulated";
  info.workspace_half_extent_m = Eigen::Vector3d(0.05, 0.05, 0.05);
  info.max_force_n = 8.9;
  info.max_stable_stiffness_n_per_m = 2000.0;
  info.max_damping_n_s_per_m = 20.0;
  info.nominal_rate_hz = 1000.0;
  return info;
}

SimulatedDevice::SimulatedDevice(const Clock& clock, const ScriptedPath& path, const VirtualHand& hand,
                                 DeviceInfo info)
    : HapticDevice(std::move(info)), clock_(clock), path_(path), hand_(hand) {
  path_.validate();
  if (hand_.enabled) {
    const bool ok = hand_.stiffness_n_per_m > 0 && std::isfinite(hand_.stiffness_n_per_m) &&
                    hand_.damping_n_s_per_m >= 0 && std::isfinite(hand_.damping_n_s_per_m) &&
                    hand_.mass_kg > 0 && std::isfinite(hand_.mass_kg);
    if (!ok) {
      std::ostringstream s;
      s << "virtual hand: stiffness " << hand_.stiffness_n_per_m << " N/m, damping "
        << hand_.damping_n_s_per_m << " N s/m, mass " << hand_.mass_kg
        << " kg; expected finite stiffness > 0, damping >= 0, mass > 0";
      throw ConfigError(s.str());
    }
  }
}

void SimulatedDevice::do_open() {
  started_ = false;
  last_t_s_ = 0.0;
  target_m_ = path_.position_at(0.0);
  x_m_ = target_m_;
  v_m_per_s_.setZero();
  force_n_.setZero();
}

DeviceStatus SimulatedDevice::do_read(DeviceReading& out) noexcept {
  const std::int64_t now = clock_.now_ns();
  if (!started_) {
    started_ = true;
    start_ns_ = now;
  }
  const double t = static_cast<double>(now - start_ns_) * 1e-9;
  target_m_ = path_.position_at(t);
  if (!hand_.enabled) {
    x_m_ = target_m_;
  } else if (t > last_t_s_) {
    constexpr double kMaxSubstep = 2.5e-4;
    double remaining = t - last_t_s_;
    const int n = std::min(4000, static_cast<int>(std::ceil(remaining / kMaxSubstep)));
    const double h = remaining / n;
    for (int k = 0; k < n; ++k) {
      const Eigen::Vector3d target = path_.position_at(last_t_s_ + (k + 1) * h);
      const Eigen::Vector3d a = (hand_.stiffness_n_per_m * (target - x_m_) -
                                 hand_.damping_n_s_per_m * v_m_per_s_ + force_n_) / hand_.mass_kg;
      v_m_per_s_ += h * a;
      x_m_ += h * v_m_per_s_;
    }
    if (!x_m_.allFinite() || !v_m_per_s_.allFinite()) {  // never propagate a blown-up state
      x_m_ = target_m_;
      v_m_per_s_.setZero();
    }
  }
  last_t_s_ = std::max(last_t_s_, t);
  out.position_m = x_m_;
  out.time_ns = now;
  out.buttons = 0;
  return DeviceStatus::kOk;
}

DeviceStatus SimulatedDevice::do_write(const Eigen::Vector3d& force_n) noexcept {
  force_n_ = force_n;
  return DeviceStatus::kOk;
}

ReplayDevice::ReplayDevice(const Clock& clock, std::filesystem::path csv, DeviceInfo info)
    : HapticDevice(std::move(info)), clock_(clock), csv_(std::move(csv)) {}

double ReplayDevice::duration_s() const noexcept {
  return t_s_.empty() ? 0.0 : t_s_.back() - t_s_.front();
}

void ReplayDevice::do_open() {
  std::ifstream in(csv_);
  if (!in) throw InputError("replay: cannot open '" + csv_.string() + "'");
  std::vector<double> ts;
  std::vector<Eigen::Vector3d> ps;
  std::string line;
  int line_no = 0;
  bool header_seen = false;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const auto first = line.find_first_not_of(" \t");
    if (first == std::string::npos || line[first] == '#') continue;
    double v[4] = {0, 0, 0, 0};
    std::size_t pos = first;
    bool ok = true;
    for (int k = 0; k < 4 && ok; ++k) {
      while (pos < line.size() && (line[pos] == ' ' || line[pos] == '\t')) ++pos;
      const char* b = line.data() + pos;
      const char* e = line.data() + line.size();
      const auto [ptr, ec] = std::from_chars(b, e, v[k]);
      ok = ec == std::errc() && std::isfinite(v[k]);
      pos = static_cast<std::size_t>(ptr - line.data());
      while (pos < line.size() && (line[pos] == ' ' || line[pos] == '\t')) ++pos;
      if (k < 3) {
        ok = ok && pos < line.size() && line[pos] == ',';
        ++pos;
      }
    }
    if (ok) {
      while (pos < line.size() && (line[pos] == ' ' || line[pos] == '\t')) ++pos;
      ok = pos == line.size();
    }
    if (!ok) {
      if (ts.empty() && !header_seen && std::isalpha(static_cast<unsigned char>(line[first])) != 0) {
        header_seen = true;  // a header line such as "t,x,y,z"
        continue;
      }
      throw InputError("replay: " + csv_.string() + ":" + std::to_string(line_no) + ": '" + line +
                       "' is not four finite numbers t,x,y,z (seconds, metres)");
    }
    if (!ts.empty() && !(v[0] > ts.back())) {
      throw InputError("replay: " + csv_.string() + ":" + std::to_string(line_no) + ": time " +
                       std::to_string(v[0]) + " s does not increase (previous " +
                       std::to_string(ts.back()) + " s)");
    }
    ts.push_back(v[0]);
    ps.emplace_back(v[1], v[2], v[3]);
  }
  if (ts.empty()) throw InputError("replay: '" + csv_.string() + "' holds no samples t,x,y,z");
  t_s_ = std::move(ts);
  p_m_ = std::move(ps);
  started_ = false;
  cursor_ = 0;
}

DeviceStatus ReplayDevice::do_read(DeviceReading& out) noexcept {
  const std::int64_t now = clock_.now_ns();
  if (!started_) {
    started_ = true;
    start_ns_ = now;
    cursor_ = 0;
  }
  const double t = t_s_.front() + static_cast<double>(now - start_ns_) * 1e-9;
  out.time_ns = now;
  out.buttons = 0;
  if (t >= t_s_.back()) {
    out.position_m = p_m_.back();
    return DeviceStatus::kEndOfData;
  }
  if (t < t_s_[cursor_]) cursor_ = 0;  // clock went back: restart the search
  while (cursor_ + 1 < t_s_.size() && t_s_[cursor_ + 1] <= t) ++cursor_;
  const std::size_t i = cursor_;
  const double a = (t - t_s_[i]) / (t_s_[i + 1] - t_s_[i]);
  out.position_m = (1.0 - a) * p_m_[i] + a * p_m_[i + 1];
  return DeviceStatus::kOk;
}

}  // namespace hc::haptics
