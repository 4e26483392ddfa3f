#pragma once
/// @file commands.hpp
/// Subcommands of the `hapticloud` program. Each add_* registers one subcommand on `app`; its
/// callback throws hc::Error on failure, which main() turns into a one-line cause and exit 1.

#include <CLI/CLI.hpp>

#include <cmath>
#include <exception>
#include <string>

namespace hc::app {

/// A CLI11 check that the option's value is a finite number in [lo, hi] ((lo, hi] with lo_open).
/// CLI::Range lets NaN through (every comparison with NaN is false); this does not. A failure is
/// a usage error (exit 2) naming the option, the value and the range.
inline CLI::Validator finite_in(double lo, double hi, bool lo_open = false) {
  const std::string range = std::string(lo_open ? "(" : "[") + std::to_string(lo) + ", " + std::to_string(hi) + "]";
  return CLI::Validator(
      [lo, hi, lo_open, range](std::string& text) -> std::string {
        double v = 0.0;
        try {
          std::size_t used = 0;
          v = std::stod(text, &used);
          if (used != text.size()) return "'" + text + "' is not a number";
        } catch (const std::exception&) {
          return "'" + text + "' is not a number";
        }
        if (!std::isfinite(v) || v < lo || v > hi || (lo_open && v == lo)) {
          return "value " + text + " is out of range: expected a finite number in " + range;
        }
        return std::string();
      },
      "NUMBER in " + range);
}

/// `hapticloud run CONFIG.yaml [--out DIR] [--set key=value ...]`: the offline pipeline; also
/// `tile-plan`, `tile-job` and `tile-merge`, the tiled run in separate processes (tiling.hpp).
void add_run_command(CLI::App& app);

/// Thrown by `run` after it wrote its output when the cross-check's verdict is "fail"; main()
/// prints the message and exits kExitVerdictFail (4), so a wrong surface never looks like success.
class VerdictFailed : public std::exception {
 public:
  explicit VerdictFailed(std::string message) : message_(std::move(message)) {}
  const char* what() const noexcept override { return message_.c_str(); }

 private:
  std::string message_;
};

/// `hapticloud touch SCENE_OR_CONFIG ...`: a headless scripted haptic session (issue 3).
void add_touch_command(CLI::App& app);

/// `hapticloud levels SCENE`: speed against error per level of detail (issue 4).
void add_levels_command(CLI::App& app);

/// `hapticloud export SCENE --format ply|stl|obj --out FILE`: the height field as a triangle mesh.
void add_export_command(CLI::App& app);

#ifdef HC_HAVE_FALCON
/// `hapticloud devices` and `hapticloud falcon-check` (issue 5).
void add_falcon_command(CLI::App& app);
#endif

/// `hapticloud explore CONFIG_OR_SCENE [--device falcon|mouse|sim] ...`: the interactive session (issue 6).
void add_explore_command(CLI::App& app);

}  // namespace hc::app
