#include "commands.hpp"

namespace hc::app {
void add_run_command(CLI::App& app) {
  app.add_subcommand("run", "Run a YAML-configured pipeline: scan in, scene and report out.");
}
}  // namespace hc::app
