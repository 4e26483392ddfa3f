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

/// For the batch commands (run, tile-plan, tile-job, tile-merge; the first argument that is not
/// a flag names it): starts the program again in place (execv(3) of /proc/self/exe, the same
/// arguments and process) with glibc's tunable glibc.malloc.hugetlb=1 added to GLIBC_TUNABLES,
/// so that malloc asks for transparent huge pages (madvise(MADV_HUGEPAGE)) on the memory it
/// takes from the system. The point stages read windows of millions of points in no order; with
/// 4 KiB pages most of those reads also miss the TLB (10⁸-point wall, N = 4096, tiled: CPU
/// 141–144 s → 133–137 s over two pairs of rounds, docs/scale.md).
/// Only where it can act: Linux with glibc ≥ 2.35 (older ones have no such tunable) and
/// transparent huge pages in mode madvise (mode always gives them already, never refuses them).
/// Not when GLIBC_TUNABLES names glibc.malloc.hugetlb already (the user's choice), nor when
/// HAPTICLOUD_HEAP_HUGE_PAGES=off, nor in secure-execution mode (set-user-ID or file
/// capabilities: glibc erases the tunable there). The program started again knows it by
/// HAPTICLOUD_HEAP_HUGE_PAGES_STARTED, which it removes from its environment at once: it starts
/// again at most once and passes nothing on. When the exec fails, the environment is put back
/// and the program goes on as it was. Call first in main(), before any thread or file is
/// opened. Source: glibc manual, "Memory Allocation Tunables" (glibc.malloc.hugetlb); the
/// kernel's admin-guide/mm/transhuge.rst; getauxval(3) (AT_SECURE).
void reexec_with_heap_huge_pages(int argc, char** argv);

/// The batch commands' allocator policy (run, tile-plan, tile-job, tile-merge, levels):
/// pipeline::keep_freed_heap_for_reuse (run.hpp, with the reasons and figures); what the C
/// library refused is logged at debug level. Sessions (touch, explore) keep the C library's
/// default. Call once, before any thread starts.
void keep_freed_memory_for_reuse();

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
