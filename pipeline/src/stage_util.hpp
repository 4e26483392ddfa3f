#pragma once
/// @file stage_util.hpp
/// Private helpers shared by the pipeline stages' .cpp files (not installed, not public API).

#include "hc/pipeline/cloud.hpp"

#include <signal.h>

#include <algorithm>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <atomic>
#include <exception>
#include <filesystem>
#include <functional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

namespace hc::pipeline::detail {

using Clock = std::chrono::steady_clock;

/// Wall time [s] since t0 on the steady clock (stage reports).
inline double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

/// ⌊v⌋ (floor_of) and ⌈v⌉ (ceil_of) of a double, inline: truncation corrected by one, where
/// std::floor and std::ceil are library calls on the baseline x86-64 target (no SSE4.1
/// roundsd), a few ns each in loops over every point. Equal to std::floor / std::ceil for
/// every double up to the sign of a zero result (|v| ≥ 2^52 is already integral; NaN and ±∞
/// go to the library). The correction is an integer subtraction of the comparison, without a
/// branch: written as a conditional, GCC 12 branched on it, and on values of either sign
/// (coordinates about a centre) the branch mispredicted on about half of them (until
/// 2026-11-25 it was part of the 3.7 CPU s the tiled run's stage tile_scale spent at 10^8
/// points in its pass of cell keys).
inline double floor_of(double v) noexcept {
  if (!(std::abs(v) < 0x1p52)) return std::floor(v);
  const auto i = static_cast<std::int64_t>(v);
  return static_cast<double>(i - static_cast<std::int64_t>(static_cast<double>(i) > v));
}
inline double ceil_of(double v) noexcept {
  if (!(std::abs(v) < 0x1p52)) return std::ceil(v);
  const auto i = static_cast<std::int64_t>(v);
  return static_cast<double>(i + static_cast<std::int64_t>(static_cast<double>(i) < v));
}

/// Progress within a stage (the tiled run's passes, the level builder's): at most once per
/// `interval_s` [s], a StageReport of `stage` with figures progress_fraction (in [0, 1]) and
/// eta_s (the time left at the pass's mean rate [s]) and the note `pass`, given to `fn` with
/// done = false. `fn` (a ProgressFn, run.hpp) is held by reference and must outlive this.
class PassProgress {
 public:
  PassProgress(const std::function<void(const StageReport&, bool)>& fn, const char* stage, std::string pass, double interval_s)
      : fn_(fn), stage_(stage), pass_(std::move(pass)), interval_s_(interval_s), t0_(detail::Clock::now()), last_(t0_) {}
  void operator()(double fraction) {
    if (!fn_) return;
    const auto now = detail::Clock::now();
    if (std::chrono::duration<double>(now - last_).count() < interval_s_ || !(fraction > 0.0)) return;
    last_ = now;
    const double elapsed = std::chrono::duration<double>(now - t0_).count();
    StageReport r;
    r.stage = stage_;
    r.figure("progress_fraction", std::min(1.0, fraction));
    r.figure("eta_s", elapsed * (1.0 - std::min(1.0, fraction)) / fraction);
    r.notes.push_back(pass_);
    fn_(r, false);
  }

 private:
  const std::function<void(const StageReport&, bool)>& fn_;
  const char* stage_;
  std::string pass_;
  double interval_s_;
  detail::Clock::time_point t0_, last_;
};

/// Writes `bytes` to the file `target` whole or not at all: into a temporary beside it
/// ("." + its name + ".tmp-<host>-<pid>-<random>", registered for the signal clean-up, flushed
/// to disk with fsync) renamed over it (rename(2): a reader sees the old file or the new one),
/// the temporary removed however this ends. Used for a plan's files (tiled_run.cpp, where it is
/// defined, and whose stale-scratch clean-up knows the temporary's name) and scene.yaml's
/// rewrite (add_level0_surface_layers). @throws hc::InputError "cannot write TARGET: reason".
void write_atomically(const std::filesystem::path& target, const std::string& bytes);

/// An empty report of stage `stage` that received `in` points.
inline StageReport make_report(const char* stage, std::size_t in) {
  StageReport r;
  r.stage = stage;
  r.count_in = in;
  return r;
}

/// The value of the report's first figure called `name`, or `fallback` when it has none.
inline double figure_of(const StageReport& r, const std::string& name, double fallback) {
  for (const auto& [n, v] : r.figures)
    if (n == name) return v;
  return fallback;
}

/// Sets the report's first figure called `name` to `value`, or appends it.
inline void set_figure(StageReport& r, const std::string& name, double value) {
  for (auto& [n, v] : r.figures) {
    if (n == name) {
      v = value;
      return;
    }
  }
  r.figure(name, value);
}

/// SplitMix64 (Steele, Lea & Flood 2014): a 64-bit mix for deterministic sampling.
inline std::uint64_t splitmix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

/// Whether no process `pid` (> 0) exists on this host: kill(pid, 0) fails with ESRCH (POSIX
/// kill(2); a process of another user, EPERM, exists). For scratch named by process number.
inline bool process_gone(long pid) { return ::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH; }

/// Runs a() on a second thread and b() on this one, joins, then rethrows a's exception if it
/// threw, else b's. Used by stages that split their work in two (the machines have two cores).
template <class A, class B>
void run_two(A&& a, B&& b) {
  std::exception_ptr error_a, error_b;
  std::thread worker([&] {
    try {
      a();
    } catch (...) {
      error_a = std::current_exception();
    }
  });
  try {
    b();
  } catch (...) {
    error_b = std::current_exception();
  }
  worker.join();
  if (error_a) std::rethrow_exception(error_a);
  if (error_b) std::rethrow_exception(error_b);
}

/// Runs independent tasks on two threads (this one and a second), each taking the next task
/// not yet taken, in the list's order: put the longest first. After a task throws, each thread
/// starts no task once it has seen the failure (the other may already have taken one more);
/// running tasks finish, then the exception of the task earliest in the list that threw is
/// rethrown. An empty list returns at once; a single task runs on this thread (no second thread
/// is started, its exception passes through).
inline void run_tasks_on_two(const std::vector<std::function<void()>>& tasks) {
  if (tasks.empty()) return;
  if (tasks.size() == 1) {
    tasks.front()();
    return;
  }
  std::atomic<std::size_t> next{0};
  std::atomic<bool> failed{false};
  std::vector<std::exception_ptr> errors(tasks.size());
  auto work = [&] {
    while (!failed.load(std::memory_order_acquire)) {
      const std::size_t k = next.fetch_add(1);
      if (k >= tasks.size()) break;
      try {
        tasks[k]();
      } catch (...) {
        errors[k] = std::current_exception();
        failed.store(true, std::memory_order_release);
      }
    }
  };
  run_two(work, work);
  for (const std::exception_ptr& e : errors)
    if (e) std::rethrow_exception(e);
}

}  // namespace hc::pipeline::detail
