#include "hc/session/lod_session.hpp"

#include "hc/common/error.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <limits>
#include <sstream>

namespace hc::session {
namespace {

std::vector<std::string> split_fields(std::string s) {
  std::replace(s.begin(), s.end(), ':', ' ');
  std::istringstream in(s);
  std::vector<std::string> out;
  for (std::string f; in >> f;) out.push_back(f);
  return out;
}

int to_int(const std::string& s, const std::string& action) {
  std::size_t used = 0;
  int v = 0;
  try {
    v = std::stoi(s, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != s.size() || s.empty()) {
    throw ConfigError("touch: --zoom-path action '" + action + "': '" + s + "' is not an integer");
  }
  return v;
}

ZoomAction parse_action(const std::string& text) {
  const std::vector<std::string> f = split_fields(text);
  const std::string expected =
      "expected 'T in', 'T out', 'T level L', 'T pan DX DY' or 'T window L X Y' (T in seconds)";
  if (f.size() < 2) throw ConfigError("touch: --zoom-path action '" + text + "': " + expected);
  ZoomAction a;
  a.text = text;
  std::size_t used = 0;
  try {
    a.t_s = std::stod(f[0], &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != f[0].size() || !std::isfinite(a.t_s) || a.t_s < 0.0) {
    throw ConfigError("touch: --zoom-path action '" + text + "': time '" + f[0] + "' is not a number >= 0 s");
  }
  const std::string& k = f[1];
  const auto args = [&](std::size_t n) {
    if (f.size() != n + 2) throw ConfigError("touch: --zoom-path action '" + text + "': " + expected);
  };
  if (k == "in") {
    args(0);
    a.kind = ZoomAction::Kind::kIn;
  } else if (k == "out") {
    args(0);
    a.kind = ZoomAction::Kind::kOut;
  } else if (k == "level") {
    args(1);
    a.kind = ZoomAction::Kind::kLevel;
    a.a = to_int(f[2], text);
  } else if (k == "pan") {
    args(2);
    a.kind = ZoomAction::Kind::kPan;
    a.a = to_int(f[2], text);
    a.b = to_int(f[3], text);
  } else if (k == "window") {
    args(3);
    a.kind = ZoomAction::Kind::kWindow;
    a.a = to_int(f[2], text);
    a.b = to_int(f[3], text);
    a.c = to_int(f[4], text);
  } else {
    throw ConfigError("touch: --zoom-path action '" + text + "': unknown action '" + k + "'; " + expected);
  }
  return a;
}

}  // namespace

std::vector<ZoomAction> parse_zoom_path(const std::string& file_or_spec) {
  std::vector<std::string> items;
  if (std::filesystem::is_regular_file(file_or_spec)) {
    std::ifstream in(file_or_spec);
    if (!in) throw InputError("touch: cannot read the zoom path '" + file_or_spec + "'");
    for (std::string line; std::getline(in, line);) {
      const auto hash = line.find('#');
      if (hash != std::string::npos) line.erase(hash);
      if (line.find_first_not_of(" \t\r") != std::string::npos) items.push_back(line);
    }
  } else {
    std::string cur;
    for (const char ch : file_or_spec + ",") {
      if (ch == ',' || ch == ';') {
        if (cur.find_first_not_of(" \t") != std::string::npos) items.push_back(cur);
        cur.clear();
      } else {
        cur += ch;
      }
    }
  }
  std::vector<ZoomAction> out;
  for (const std::string& item : items) {
    out.push_back(parse_action(item));
    if (out.size() > 1 && out.back().t_s < out[out.size() - 2].t_s) {
      throw ConfigError("touch: --zoom-path action '" + item + "' comes before the one listed above it; times must "
                        "not decrease");
    }
  }
  if (out.empty()) throw ConfigError("touch: --zoom-path '" + file_or_spec + "' holds no action");
  return out;
}

std::pair<int, int> parse_window_origin(const std::string& text) {
  const auto comma = text.find(',');
  if (comma == std::string::npos) {
    throw ConfigError("touch: --window '" + text + "': expected X,Y (first column and row of the window)");
  }
  return {to_int(text.substr(0, comma), "--window " + text), to_int(text.substr(comma + 1), "--window " + text)};
}

namespace {
std::shared_ptr<pipeline::LodPyramid> pyramid_of_layers(const SceneLayers& layers,
                                                       const pipeline::SurfaceLayerOptions& layer_options,
                                                       const pipeline::LodOptions& lod) {
  if (layers.depth.rows() == 0) throw InputError("touch: the scene has no depth layer for levels of detail");
  pipeline::LodLevel l0;
  l0.depth_m = layers.depth;
  if (layers.has_surface_layers()) {
    l0.envelope_m = layers.envelope;
    l0.texture_m = layers.texture;
    l0.mu_d = layers.mu_d;
    l0.mu_s = layers.mu_s;
    l0.has_layers = true;
  }
  return std::make_shared<pipeline::LodPyramid>(std::move(l0), layer_options, lod);
}
}  // namespace

LodSession::LodSession(const SceneLayers& layers, const haptics::SurfaceOptions& surface,
                       const Eigen::Vector3d& device_half_extent_m, int level, std::optional<std::pair<int, int>> origin,
                       std::vector<ZoomAction> actions, haptics::SharedState& shared,
                       const pipeline::SurfaceLayerOptions& layer_options, const pipeline::LodOptions& lod)
    : LodSession(pyramid_of_layers(layers, layer_options, lod), surface, device_half_extent_m, level, origin,
                 std::move(actions), shared) {}

LodSession::LodSession(std::shared_ptr<pipeline::LodPyramid> pyramid, const haptics::SurfaceOptions& surface,
                       const Eigen::Vector3d& device_half_extent_m, int level, std::optional<std::pair<int, int>> origin,
                       std::vector<ZoomAction> actions, haptics::SharedState& shared)
    : pyramid_(std::move(pyramid)), surface_options_(surface), actions_(std::move(actions)) {
  if (level < -1) {
    throw ConfigError("touch: --level " + std::to_string(level) + ": expected -1 (the coarsest) or a level >= 0");
  }
  if (!pyramid_) throw InputError("touch: no pyramid for levels of detail");
  LodControllerOptions co;
  co.surface = surface;
  co.device_half_extent_m = device_half_extent_m;
  controller_ = std::make_unique<LodController>(pyramid_, shared, co);
  const int start = level < 0 ? pyramid_->level_count() - 1 : level;
  if (start >= pyramid_->level_count()) {
    throw ConfigError("touch: --level " + std::to_string(level) + " does not exist: the scene has levels 0.." +
                      std::to_string(pyramid_->level_count() - 1));
  }
  if (origin) check_origin("--window " + std::to_string(origin->first) + "," + std::to_string(origin->second), start,
                           origin->first, origin->second);
  // Every scripted level and window is checked against the pyramid before anything is published.
  for (const ZoomAction& a : actions_) {
    if (a.kind == ZoomAction::Kind::kLevel || a.kind == ZoomAction::Kind::kWindow) {
      if (a.a < 0 || a.a >= pyramid_->level_count()) {
        throw ConfigError("touch: --zoom-path action '" + a.text + "': level " + std::to_string(a.a) +
                          " does not exist: the scene has levels 0.." + std::to_string(pyramid_->level_count() - 1));
      }
    }
    if (a.kind == ZoomAction::Kind::kWindow) check_origin("--zoom-path action '" + a.text + "'", a.a, a.b, a.c);
  }
  SwitchRecord first;
  if (origin) {
    first.window = controller_->set_window(start, origin->first, origin->second);
    first.request = "start: level " + std::to_string(start) + " window " + std::to_string(origin->first) + "," +
                    std::to_string(origin->second);
  } else {
    const GridGeometry& g = pyramid_->geometry(0);
    first.window = controller_->centre_window(start, g.x_of_col(0.5 * (g.cols - 1)), g.y_of_row(0.5 * (g.rows - 1)));
    first.request = "start: level " + std::to_string(start) + ", centred";
  }
  switch_of_tag_[first.window.tag] = switches_.size();
  switches_.push_back(first);
}

void LodSession::check_origin(const std::string& what, int level, int col0, int row0) const {
  const GridGeometry& g = pyramid_->geometry(level);
  if (col0 < 0 || col0 >= g.cols || row0 < 0 || row0 >= g.rows) {
    throw ConfigError("touch: " + what + ": window origin column " + std::to_string(col0) + ", row " +
                      std::to_string(row0) + " is outside level " + std::to_string(level) + " (columns 0.." +
                      std::to_string(g.cols - 1) + ", rows 0.." + std::to_string(g.rows - 1) + ")");
  }
}

double LodSession::next_time() const {
  return next_ < actions_.size() ? actions_[next_].t_s : std::numeric_limits<double>::infinity();
}

int LodSession::apply_due(double t_s, const Eigen::Vector3d& proxy_m) {
  int applied = 0;
  while (next_ < actions_.size() && actions_[next_].t_s <= t_s + 1e-12) {
    const ZoomAction& a = actions_[next_++];
    SwitchRecord rec;
    rec.t_s = t_s;
    rec.request = a.text;
    switch (a.kind) {
      case ZoomAction::Kind::kIn: rec.window = controller_->zoom_in(proxy_m); break;
      case ZoomAction::Kind::kOut: rec.window = controller_->zoom_out(proxy_m); break;
      case ZoomAction::Kind::kLevel: rec.window = controller_->set_level(a.a, proxy_m); break;
      case ZoomAction::Kind::kPan: rec.window = controller_->pan(a.a, a.b); break;
      case ZoomAction::Kind::kWindow: rec.window = controller_->set_window(a.a, a.b, a.c); break;
    }
    switch_of_tag_[rec.window.tag] = switches_.size();
    switches_.push_back(rec);
    ++applied;
  }
  return applied;
}

const haptics::HapticSurface& LodSession::surface_for(std::uint64_t tag) {
  if (eval_ && eval_tag_ == tag) return *eval_;
  // A row traced before the first window was adopted (tag 0) renders the first window.
  const auto it = switch_of_tag_.find(tag);
  const HapticWindow& w = switches_.at(it != switch_of_tag_.end() ? it->second : 0).window;
  const auto win = pyramid_->window(w.level, w.row0, w.col0, w.rows, w.cols);
  eval_ = make_window_surface(*win, surface_options_);
  eval_tag_ = tag;
  return *eval_;
}

std::string LodSession::json() const {
  nlohmann::ordered_json j;
  j["levels"] = nlohmann::ordered_json::array();
  for (int l = 0; l < pyramid_->level_count(); ++l) {
    const GridGeometry& g = pyramid_->geometry(l);
    j["levels"].push_back({{"level", l}, {"rows", g.rows}, {"cols", g.cols}, {"cell_size_m", g.cell_size_m}});
  }
  j["window_cells"] = controller_->window_cells();
  j["switches"] = nlohmann::ordered_json::array();
  for (const SwitchRecord& s : switches_) {
    const HapticWindow& w = s.window;
    // The request is the action as the user wrote it: nlohmann escapes quotes, backslashes and
    // control characters.
    j["switches"].push_back({{"t_s", s.t_s},
                             {"request", s.request},
                             {"level", w.level},
                             {"col0", w.col0},
                             {"row0", w.row0},
                             {"cols", w.cols},
                             {"rows", w.rows},
                             {"scale", w.map.scale},
                             {"tag", w.tag},
                             {"level_build_s", w.level_seconds},
                             {"window_build_s", w.window_seconds}});
  }
  return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

void LodSession::print(std::ostream& out) const {
  out << "  levels of detail: " << pyramid_->level_count() << " levels, window " << controller_->window_cells()
      << " samples; " << switches_.size() << " window(s):\n";
  for (const SwitchRecord& s : switches_) {
    const HapticWindow& w = s.window;
    out << "    t " << std::fixed << std::setprecision(3) << s.t_s << " s  " << s.request << " -> level " << w.level
        << " window " << w.col0 << "," << w.row0 << " (" << w.cols << "x" << w.rows << "), scale "
        << std::setprecision(4) << w.map.scale << ", built in " << std::setprecision(3)
        << (w.level_seconds + w.window_seconds) * 1000.0 << " ms\n";
  }
  out << std::defaultfloat;
}

}  // namespace hc::session
