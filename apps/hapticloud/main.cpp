/// hapticloud: command-line entry point. Subcommands live in *_command.cpp beside this file.

#include "commands.hpp"

#include "hc/common/error.hpp"

#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include <exception>
#include <iostream>

int main(int argc, char** argv) {
  CLI::App app{"hapticloud: explore scanned heritage objects by touch, sight and sound.\n"
               "Turns point clouds into Monge grids z = f(x, y) and renders them haptically."};
  app.set_version_flag("--version", std::string("hapticloud ") + HC_VERSION);
  app.require_subcommand(1);
  hc::app::add_run_command(app);
  hc::app::add_touch_command(app);
  hc::app::add_levels_command(app);
  hc::app::add_explore_command(app);
#ifdef HC_HAVE_FALCON
  hc::app::add_falcon_command(app);
#endif
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const hc::Error& e) {
    std::cerr << "hapticloud: error: " << e.what() << "\n";
    return 1;
  } catch (const std::exception& e) {
    std::cerr << "hapticloud: internal error: " << e.what() << "\n";
    return 2;
  }
  return 0;
}
