/// `hapticloud run`: the offline pipeline from a YAML config to a scene and a report.

#include "commands.hpp"

#include "hc/common/format.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/tiling.hpp"
#include "hc/session/interrupt_cleanup.hpp"
#include "hc/session/level_timing.hpp"

#include <spdlog/spdlog.h>

#ifdef __GLIBC__
#include <gnu/libc-version.h>
#endif
#include <sys/auxv.h>
#include <unistd.h>

#include <climits>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>

namespace hc::app {
namespace {

struct RunArgs {
  std::string config;
  std::string out;
  std::vector<std::string> sets;
  bool force = false;
};

// Stage progress on the log: the tiled run's passes with their percentage and time left.
void log_progress(const pipeline::StageReport& s, bool done) {
  if (!done) {
    double fraction = -1.0, eta = 0.0;
    for (const auto& [name, v] : s.figures) {
      if (name == "progress_fraction") fraction = v;
      if (name == "eta_s") eta = v;
    }
    if (fraction >= 0.0) {  // within a long stage of the tiled run
      spdlog::info("  {} {:.0f} % ({}; about {:.0f} s left)", s.stage, 100.0 * fraction,
                   s.notes.empty() ? std::string() : s.notes.front(), eta);
    } else {
      spdlog::debug("  {} ...", s.stage);
    }
  } else {
    spdlog::info("  {}: {} -> {} in {} ms", s.stage, s.count_in, s.count_out, static_cast<long>(s.seconds * 1000.0 + 0.5));
    for (const auto& note : s.notes) spdlog::debug("    {}", note);
  }
}

// What `run` and `tile-merge` print of a written run; throws VerdictFailed on a failed verdict.
void print_summary(const pipeline::RunSummary& summary, const std::filesystem::path& out) {
  if (!summary.moved_aside.empty()) {
    std::cout << "kept the earlier content of " << out.string() << " as " << summary.moved_aside.string() << "\n";
  }
  std::cout << "scene: " << (out / "scene").string() << "\nreport: " << (out / "report.md").string()
            << "\ngrid: " << summary.grid.rows << " x " << summary.grid.cols << " cells of "
            << summary.grid.cell_size_m * 1000.0 << " mm, " << summary.valid_cells << " valid; total "
            << static_cast<long>(summary.total_seconds * 1000.0 + 0.5) << " ms\n";
  if (summary.cross_check) {
    const auto& c = *summary.cross_check;
    std::cout << "cross-check: points vs surface RMS " << c.point_vertical.rms_mm << " mm, p95 "
              << c.point_vertical.p95_mm << " mm; grid vs points RMS " << c.cell_to_point.rms_mm
              << " mm; supported " << 100.0 * c.supported_fraction << " %\n";
  }
  if (summary.verdict) {
    const auto& v = *summary.verdict;
    std::cout << "verdict: " << v.status;
    if (summary.input_check) {
      const auto& in = *summary.input_check;
      auto pct = [&in](std::size_t k) { return hc::format_number(100.0 * in.fraction(k), 2, hc::NumberStyle::kFixed) + " %"; };
      std::cout << " (input: " << pct(in.on_surface) << " on the surface, " << pct(in.removed) << " removed, "
                << pct(in.hidden) << " hidden, " << pct(in.no_data) << " on no data)";
    }
    std::cout << "\n";
    std::string fail_reasons;
    for (const auto& r : v.reasons) {
      std::cout << "  " << r.level << " (" << r.code << "): " << r.message << "\n";
      if (r.level == "fail") fail_reasons += (fail_reasons.empty() ? "" : "; ") + r.code;
    }
    if (v.status == "fail") {
      throw VerdictFailed("the surface in " + out.string() + " failed the cross-check (" + fail_reasons +
                          "); see " + (out / "report.md").string());
    }
  }
}

void run(const RunArgs& a) {
  // Before any stage starts a thread: Ctrl-C removes the unfinished output folder.
  const session::InterruptCleanup cleanup;
  const pipeline::RunConfig cfg = pipeline::load_run_config(a.config, a.sets);
  const std::filesystem::path out = a.out.empty() ? std::filesystem::path("runs") / cfg.name : std::filesystem::path(a.out);
  spdlog::info("hapticloud run {} -> {}", a.config, out.string());
  keep_freed_memory_for_reuse();
  pipeline::set_stage_memory_measurement(true);  // report.json: peak_rss_mb per stage
  const pipeline::RunSummary summary = pipeline::run_pipeline(
      cfg, out, log_progress, a.force ? pipeline::ExistingOutput::kMoveAside : pipeline::ExistingOutput::kRefuse,
      session::servo_level_timing());
  print_summary(summary, out);
}

struct TilePlanArgs {
  std::string config, work;
  std::vector<std::string> sets;
  std::string grid_box;  // --grid-box: a tile-merge's WORK/grid_box.json, or empty
};

struct TileJobArgs {
  std::string plan;
  std::vector<std::size_t> tiles;
};

struct TileMergeArgs {
  std::string plan, out;
  bool force = false;
};

}  // namespace

void keep_freed_memory_for_reuse() {
  const pipeline::HeapPolicyTaken taken = pipeline::keep_freed_heap_for_reuse();
  if (!taken.mmap_threshold_set || !taken.trim_threshold_set) {
    spdlog::debug("mallopt: M_MMAP_THRESHOLD {}, M_TRIM_THRESHOLD {}: the C library's default stays for what it refused",
                  taken.mmap_threshold_set ? "set" : "refused", taken.trim_threshold_set ? "set" : "refused");
  }
}

void reexec_with_heap_huge_pages(int argc, char** argv) {
#if defined(__linux__) && defined(__GLIBC__)
  // Started again by this call: once is all (the marker is not passed on to children).
  constexpr const char* kStarted = "HAPTICLOUD_HEAP_HUGE_PAGES_STARTED";
  if (std::getenv(kStarted) != nullptr) {
    (void)unsetenv(kStarted);
    return;
  }
  // In secure-execution mode (set-user-ID, or file capabilities such as cap_sys_nice for the
  // servo loop) glibc erases this tunable from the environment: no use, and without the marker
  // a loop of starts.
  if (getauxval(AT_SECURE) != 0) return;
  const char* sub = nullptr;
  for (int i = 1; i < argc && argv[i] != nullptr; ++i) {
    if (argv[i][0] != '-') {
      sub = argv[i];
      break;
    }
  }
  if (sub == nullptr) return;
  const std::string name = sub;
  if (name != "run" && name != "tile-plan" && name != "tile-job" && name != "tile-merge") return;
  const char* off = std::getenv("HAPTICLOUD_HEAP_HUGE_PAGES");
  if (off != nullptr && std::strcmp(off, "off") == 0) return;
  const char* before = std::getenv("GLIBC_TUNABLES");
  if (before != nullptr && std::strstr(before, "glibc.malloc.hugetlb") != nullptr) return;
  int major = 0, minor = 0;
  if (std::sscanf(gnu_get_libc_version(), "%d.%d", &major, &minor) != 2 || major < 2 || (major == 2 && minor < 35)) return;
  std::string mode;
  std::getline(std::ifstream("/sys/kernel/mm/transparent_hugepage/enabled"), mode);
  if (mode.find("[madvise]") == std::string::npos) return;
  // The program's own path (readlink: under a tool that runs it, such as valgrind, the path of
  // the program run, not the tool's).
  char exe[PATH_MAX];
  const ssize_t len = readlink("/proc/self/exe", exe, sizeof exe - 1);
  if (len <= 0) return;
  exe[len] = '\0';
  const std::optional<std::string> kept = before != nullptr ? std::optional<std::string>(before) : std::nullopt;
  // Not started again: the environment as it was, so that it tells the truth about this process.
  const auto put_back = [&] {
    (void)unsetenv(kStarted);
    if (kept) {
      (void)setenv("GLIBC_TUNABLES", kept->c_str(), 1);
    } else {
      (void)unsetenv("GLIBC_TUNABLES");
    }
  };
  const std::string value = kept && !kept->empty() ? *kept + ":glibc.malloc.hugetlb=1" : "glibc.malloc.hugetlb=1";
  if (setenv("GLIBC_TUNABLES", value.c_str(), 1) != 0 || setenv(kStarted, "1", 1) != 0) {
    put_back();
    return;
  }
  execv(exe, argv);
  put_back();
#else
  (void)argc;
  (void)argv;
#endif
}

void add_run_command(CLI::App& app) {
  auto args = std::make_shared<RunArgs>();
  CLI::App* cmd = app.add_subcommand("run", "Run a YAML-configured pipeline: scan in, scene and report out.");
  cmd->add_option("config", args->config, "Run configuration (YAML), e.g. configs/happy_buddha.yaml")->required();
  cmd->add_option("--out", args->out,
                  "Output folder (default: runs/<config name>); an earlier output there is replaced atomically, "
                  "anything else is refused");
  cmd->add_flag("--force", args->force,
                "Write --out even if it holds something else: that is kept as <out>.replaced-<time>, never deleted");
  cmd->add_option("--set", args->sets, "Override a config key, e.g. --set grid.n=400 (repeatable)");
  cmd->callback([args] { run(*args); });

  auto plan = std::make_shared<TilePlanArgs>();
  CLI::App* pc = app.add_subcommand(
      "tile-plan", "Plan a tiled run for tile jobs elsewhere (docs/scale.md): read the scan, spill its points into tiles "
                   "in a work folder, write WORK/plan.json");
  pc->add_option("config", plan->config, "Run configuration (YAML)")->required();
  pc->add_option("--work", plan->work, "Work folder for the plan and the tiles (new or empty; on storage every job sees)")
      ->required();
  pc->add_option("--set", plan->sets, "Override a config key, e.g. --set grid.n=400 (repeatable)");
  pc->add_option("--grid-box", plan->grid_box,
                 "Lay the grid on the box a tile-merge wrote (WORK/grid_box.json; it exits 6 for it): the kept points' box, "
                 "as the in-core run lays it (scale.grid_on_kept_points)");
  pc->callback([plan] {
    // Before any thread starts: Ctrl-C removes the plan's spill files (or the folder it made).
    const session::InterruptCleanup cleanup;
    keep_freed_memory_for_reuse();
    spdlog::info("hapticloud tile-plan {} -> {}", plan->config, plan->work);
    const auto info = pipeline::write_tile_plan(plan->config, plan->sets, plan->work, log_progress, plan->grid_box);
    std::cout << "plan: " << info.plan_file.string() << "\ntiles: " << info.tiles << "\nspill: "
              << hc::format_number(static_cast<double>(info.spill_bytes) / 1e6, 1, hc::NumberStyle::kFixed) << " MB\n";
  });

  auto job = std::make_shared<TileJobArgs>();
  CLI::App* jc = app.add_subcommand(
      "tile-job", "Process tiles of a plan (hapticloud tile-plan): filters and gridding of each tile with its halo; "
                  "writes WORK/part_<t>.bin and WORK/kept_<t>.bin (safe to run again)");
  jc->add_option("plan", job->plan, "The plan: WORK/plan.json")->required();
  jc->add_option("--tiles", job->tiles, "Tile indices, e.g. --tiles 0,1,5")->required()->delimiter(',');
  jc->callback([job] {
    // Before any thread starts: Ctrl-C removes the job's block copies and temporary files.
    const session::InterruptCleanup cleanup;
    keep_freed_memory_for_reuse();
    pipeline::run_tile_jobs(job->plan, job->tiles);
  });

  auto merge = std::make_shared<TileMergeArgs>();
  CLI::App* mc = app.add_subcommand(
      "tile-merge", "Merge the tile results of a plan into a scene and a report (as hapticloud run); refuses a plan "
                    "with a tile missing");
  mc->add_option("plan", merge->plan, "The plan: WORK/plan.json")->required();
  mc->add_option("--out", merge->out, "Output folder (default: runs/<config name>), as for hapticloud run");
  mc->add_flag("--force", merge->force, "As for hapticloud run: an earlier other content is kept aside, never deleted");
  mc->callback([merge] {
    keep_freed_memory_for_reuse();
    const session::InterruptCleanup cleanup;
    pipeline::set_stage_memory_measurement(true);
    // Level 0's surface layers made tile by tile in the tiled scene, as hapticloud run does.
    auto m = pipeline::merge_tile_jobs(merge->plan, log_progress, pipeline::SurfaceLayersAt::kSceneLevels);
    const std::filesystem::path out =
        merge->out.empty() ? std::filesystem::path("runs") / m.config.name : std::filesystem::path(merge->out);
    spdlog::info("hapticloud tile-merge {} -> {}", merge->plan, out.string());
    const pipeline::RunSummary summary =
        pipeline::write_run(std::move(m.built), m.config, out, log_progress,
                            merge->force ? pipeline::ExistingOutput::kMoveAside : pipeline::ExistingOutput::kRefuse,
                            session::servo_level_timing());
    print_summary(summary, out);
  });
}

}  // namespace hc::app
