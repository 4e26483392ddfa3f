/// hapticloud: command-line entry point. Subcommands live in *_command.cpp beside this file.
///
/// Exit codes (README, "Using it"): 0 success; 1 an input or config error (hc::Error: the message
/// names the file, key or value); 2 a usage error (unknown subcommand or option, missing or
/// malformed argument: the usage line follows); 3 an internal error (a bug: please report it);
/// 4 `run` wrote its output but the cross-check's verdict is fail (report.md says why);
/// 5 `tile-job` under scale.island_halo: auto met an island group its plan's halo cannot decide
/// (hc::pipeline::UndecidedIslandsError): plan again with scale.island_halo: true;
/// 6 `tile-merge` found that the in-core run lays its grid on the kept points' box, another one
/// (hc::pipeline::GridBoxError): plan again with `tile-plan --grid-box WORK/grid_box.json`.
/// `-v/--verbose` and `-q/--quiet` set the log level (spdlog, on stderr) for every subcommand.

#include "commands.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/tiling.hpp"

#include <CLI/CLI.hpp>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <exception>
#include <iostream>

namespace {

constexpr int kExitInput = 1;
constexpr int kExitUsage = 2;
constexpr int kExitInternal = 3;
constexpr int kExitVerdictFail = 4;
constexpr int kExitPlanAgain = 5;
constexpr int kExitGridBox = 6;

/// Progress and diagnostics go to stderr through one logger: "hapticloud: message".
void set_up_logging(int verbosity) {
  auto logger = spdlog::stderr_color_mt("hapticloud");
  logger->set_pattern("%v");
  spdlog::set_default_logger(logger);
  spdlog::set_level(verbosity < 0 ? spdlog::level::warn : verbosity > 0 ? spdlog::level::debug : spdlog::level::info);
}

}  // namespace

int main(int argc, char** argv) {
  hc::app::reexec_with_heap_huge_pages(argc, argv);  // before any thread or file: it may start the program again
  CLI::App app{"hapticloud: explore scanned heritage objects by touch, sight and sound.\n"
               "Turns point clouds into Monge grids z = f(x, y) and renders them haptically."};
  app.set_version_flag("--version", std::string("hapticloud ") + HC_VERSION);
  app.require_subcommand(1);
  int verbose = 0;
  bool quiet = false;
  // Global flags, accepted before or after the subcommand (subcommands fall through to them).
  app.add_flag("-v,--verbose", verbose, "More progress and diagnostics on stderr (repeat for more)");
  app.add_flag("-q,--quiet", quiet, "Only warnings and errors on stderr");
  app.fallthrough();
  app.parse_complete_callback([&] { set_up_logging(quiet ? -1 : verbose); });
  hc::app::add_run_command(app);
  hc::app::add_touch_command(app);
  hc::app::add_levels_command(app);
  hc::app::add_export_command(app);
  hc::app::add_explore_command(app);
#ifdef HC_HAVE_FALCON
  hc::app::add_falcon_command(app);
#endif
  for (CLI::App* sub : app.get_subcommands([](CLI::App*) { return true; })) sub->fallthrough();
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    // A usage error: what was wrong, then the usage line of the (sub)command.
    std::string what = e.what();
    if (app.get_subcommands().empty()) {
      // CLI11 reports an unknown first word as "a subcommand is required": name it instead.
      for (int i = 1; i < argc; ++i) {
        const std::string word = argv[i];
        if (word.empty() || word[0] == '-') continue;
        std::string names;
        for (const CLI::App* sub : app.get_subcommands([](CLI::App*) { return true; })) {
          names += (names.empty() ? "" : ", ") + sub->get_name();
        }
        what = "unknown subcommand '" + word + "' (expected one of " + names + ")";
        break;
      }
    }
    std::cerr << "hapticloud: usage error: " << what << "\n";
    const CLI::App* where = &app;
    for (const CLI::App* sub : app.get_subcommands()) where = sub;
    std::cerr << "usage: hapticloud " << (where == &app ? std::string("SUBCOMMAND ...") : where->get_name() + " ...")
              << " (see 'hapticloud " << (where == &app ? std::string() : where->get_name() + " ") << "--help')\n";
    return kExitUsage;
  } catch (const hc::app::VerdictFailed& e) {
    std::cerr << "hapticloud: verdict fail: " << e.what() << "\n";
    return kExitVerdictFail;
  } catch (const hc::pipeline::UndecidedIslandsError& e) {
    // Under auto an expected step of a tile job (the driver plans again), not an error.
    std::cerr << "hapticloud: " << (e.under_auto ? "plan again: " : "error: ") << e.what() << "\n";
    return e.under_auto ? kExitPlanAgain : kExitInput;
  } catch (const hc::pipeline::GridBoxError& e) {
    std::cerr << "hapticloud: plan again: " << e.what() << "\n";
    return kExitGridBox;
  } catch (const hc::Error& e) {
    std::cerr << "hapticloud: error: " << e.what() << "\n";
    return kExitInput;
  } catch (const std::exception& e) {
    std::cerr << "hapticloud: internal error: " << e.what() << "\n";
    return kExitInternal;
  }
  return 0;
}
