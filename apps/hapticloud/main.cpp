#include <CLI/CLI.hpp>

int main(int argc, char** argv) {
  CLI::App app{"hapticloud"};
  app.set_version_flag("--version", std::string("hapticloud ") + HC_VERSION);
  CLI11_PARSE(app, argc, argv);
  return 0;
}
