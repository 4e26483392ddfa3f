#pragma once
/// @file commands.hpp
/// Subcommands of the `hapticloud` program. Each add_* registers one subcommand on `app`; its
/// callback throws hc::Error on failure, which main() turns into a one-line cause and exit 1.

#include <CLI/CLI.hpp>

namespace hc::app {

/// `hapticloud run CONFIG.yaml [--out DIR] [--set key=value ...]`: the offline pipeline.
void add_run_command(CLI::App& app);

/// `hapticloud touch SCENE_OR_CONFIG ...`: a headless scripted haptic session (issue 3).
void add_touch_command(CLI::App& app);

/// `hapticloud levels SCENE`: speed against error per level of detail (issue 4).
void add_levels_command(CLI::App& app);

#ifdef HC_HAVE_FALCON
/// `hapticloud devices` and `hapticloud falcon-check` (issue 5).
void add_falcon_command(CLI::App& app);
#endif

/// `hapticloud explore CONFIG_OR_SCENE [--device falcon|mouse|sim] ...`: the interactive session (issue 6).
void add_explore_command(CLI::App& app);

}  // namespace hc::app
