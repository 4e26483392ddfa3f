#include "explore_script.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>

namespace hc::app {

std::string script_text(const std::string& arg) {
  if (arg.empty() || arg.front() != '@') return arg;
  const std::string path = arg.substr(1);
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError("explore: --script file '" + path + "' cannot be read");
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) throw InputError("explore: --script file '" + path + "': read error");
  std::string s = text.str();
  std::replace(s.begin(), s.end(), '\n', ';');
  return s;
}

std::vector<ScriptStep> parse_script(const std::string& text) {
  static const std::map<std::string, std::size_t> kArity = {
      {"finer", 0}, {"coarser", 0}, {"level", 1}, {"pan", 2}, {"centre", 2}, {"texture", 1},
      {"mu_s", 1}, {"model", 1}, {"rescan", 3}, {"stereo", 1}, {"display", 1}, {"window", 3}, {"stiffness", 1}};
  std::vector<ScriptStep> steps;
  std::stringstream all(text);
  std::string item;
  while (std::getline(all, item, ';')) {
    std::stringstream words(item);
    ScriptStep st;
    std::string frame;
    if (!(words >> frame)) continue;  // empty item
    const auto bad = [&](const std::string& why) {
      return ConfigError("explore: --script step '" + item + "': " + why +
                         " (expected FRAME ACTION ARGS with ACTION one of finer, coarser, level N, pan DX DY, "
                         "centre X_M Y_M, window LEVEL COL0 ROW0, texture on|off, mu_s V, model paper|curvature, stiffness N_PER_M, rescan AX AY AZ, stereo on|off, "
                         "display colour|grey|texture|mu_d|error)");
    };
    // FRAME is a UI frame number (≥ 1), or a session time in seconds written with an 's'
    // suffix ("12.5s"): time steps keep their pace when a loaded machine renders fewer frames.
    const bool timed = frame.size() > 1 && frame.back() == 's';
    try {
      std::size_t used = 0;
      if (timed) {
        const std::string number = frame.substr(0, frame.size() - 1);
        st.at_s = std::stod(number, &used);
        if (used != number.size() || !std::isfinite(st.at_s) || st.at_s < 0.0) throw std::invalid_argument("time");
        st.frame = 1;
      } else {
        st.frame = std::stoi(frame, &used);
        if (used != frame.size() || st.frame < 1) throw std::invalid_argument("frame");
      }
    } catch (const std::exception&) {
      throw bad(timed ? "the time must be a number of seconds ≥ 0 followed by 's'" : "the frame must be an integer ≥ 1");
    }
    if (!steps.empty() && (st.at_s >= 0.0) != (steps.back().at_s >= 0.0)) {
      throw bad("a script gives either frames or times ('12.5s'), not both");
    }
    if (!(words >> st.action) || kArity.count(st.action) == 0) throw bad("unknown action");
    for (std::string w; words >> w;) st.args.push_back(w);
    if (st.args.size() != kArity.at(st.action)) throw bad("wrong number of arguments");
    if (!steps.empty() && (st.frame < steps.back().frame || st.at_s < steps.back().at_s)) {
      throw bad("frames and times must not decrease");
    }
    steps.push_back(std::move(st));
  }
  return steps;
}

namespace {
std::string when_of(const ScriptStep& st) {
  return st.at_s >= 0.0 ? "time " + std::to_string(st.at_s) + " s" : "frame " + std::to_string(st.frame);
}
}  // namespace

double script_number(const ScriptStep& st, std::size_t i) {
  double v = 0.0;
  std::size_t used = 0;
  try {
    v = std::stod(st.args[i], &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != st.args[i].size() || !std::isfinite(v)) {
    throw ConfigError("explore: --script step at " + when_of(st) + ": '" + st.args[i] + "' is not a finite number");
  }
  return v;
}

int script_int(const ScriptStep& st, std::size_t i) {
  const double v = script_number(st, i);
  if (v != std::floor(v) || v < -1e9 || v > 1e9) {
    throw ConfigError("explore: --script step at " + when_of(st) + ": '" + st.args[i] + "' is not an integer");
  }
  return static_cast<int>(v);
}

void check_script_numbers(const ScriptStep& st) {
  const std::string& a = st.action;
  if (a == "level") (void)script_int(st, 0);
  if (a == "window") {
    for (std::size_t i = 0; i < 3; ++i) (void)script_int(st, i);
  }
  if (a == "pan" || a == "centre" || a == "rescan" || a == "mu_s" || a == "stiffness") {
    for (std::size_t i = 0; i < st.args.size(); ++i) (void)script_number(st, i);
  }
}

}  // namespace hc::app
