#pragma once
/// @file explore_script.hpp
/// `hapticloud explore --script "FRAME ACTION ARGS; ..."`: scripted actions for tests and demos.
/// Each step is what a key, the panel or the orientation tool would do at that frame; the
/// session (explore_session.hpp) runs it through the same entry points.

#include <cstddef>
#include <string>
#include <vector>

namespace hc::app {

/// One scripted action: at frame `frame`, what a key, the panel or the orientation tool would do.
struct ScriptStep {
  int frame = 0;               ///< UI frame (1 = the first), ≥ 1; 1 for a timed step
  double at_s = -1.0;          ///< session time [s] of a timed step ("12.5s"), ≥ 0; −1: frame step
  std::string action;          ///< finer | coarser | level | pan | centre | window | stiffness | texture | mu_s | model | rescan | stereo | display
  std::vector<std::string> args;
};

/// Parses "FRAME ACTION [ARGS...]; ..." (frames must not decrease; empty items are skipped).
/// FRAME may instead be a session time with an 's' suffix ("12.5s", seconds since the first
/// frame, not decreasing); one script uses frames or times, not both.
/// Arities: finer, coarser 0; level, texture, mu_s, model, stereo, display, stiffness 1; pan, centre 2;
/// rescan, window 3 (window LEVEL COL0 ROW0: that level, the window's first column and row, as
/// recordings note every window change).
/// Numbers are checked when the step runs (script_number). Any thread.
/// @throws hc::ConfigError naming the step and the expected form.
std::vector<ScriptStep> parse_script(const std::string& text);

/// The text of --script: the argument itself, or, when it starts with '@', the content of the
/// file it names (long scripts, e.g. bench/soak.py's 18 000 steps, exceed the 128 KiB limit of
/// one command-line argument). Newlines in a file separate steps like ';'.
/// @throws hc::InputError naming the file when it cannot be read.
std::string script_text(const std::string& arg);

/// Argument i of `st` as a finite number (the whole text: "2x", "nan", "inf" are refused).
/// @throws hc::ConfigError naming the frame and the text.
double script_number(const ScriptStep& st, std::size_t i);
/// Argument i of `st` as an integer in [−1e9, 1e9]. @throws hc::ConfigError as script_number.
int script_int(const ScriptStep& st, std::size_t i);
/// Checks every number of the step as its action reads it (script_number / script_int), so a
/// bad step is refused before the session starts. @throws hc::ConfigError as script_number.
void check_script_numbers(const ScriptStep& st);

}  // namespace hc::app
