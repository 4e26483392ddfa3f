#pragma once
/// @file interrupt_cleanup.hpp
/// Ctrl-C (SIGINT) or SIGTERM during a command that writes an output folder or scratch (`run`,
/// `tile-plan`, `tile-job`, `tile-merge`): the staging folders of the live pipeline::StagingDirs
/// and the scratch registered with pipeline::register_live_scratch_dir / _entries are removed, a
/// line says so, and the process exits with 128 + the signal number, so no `<out>.partial-<pid>`,
/// spill file, block copy or temporary file is left behind.

#include <atomic>
#include <thread>

#include <signal.h>

namespace hc::session {

/// While alive, SIGINT and SIGTERM are blocked in the constructing thread (and in every thread it
/// starts afterwards, which inherit the mask) and taken by a watcher thread (sigwait), which on a
/// signal calls pipeline::remove_live_staging_dirs(true) (final: the registry's lock stays held,
/// so no other thread creates or renames a scratch file after it), prints one line to stderr and
/// _exit()s with 128 + signo. Construct it in the main thread BEFORE any other thread starts (threads
/// started earlier keep their mask and may take the signal with its default action).
/// Not for sessions with a servo loop: they have their own stop flag (hc/haptics/stop_signal.hpp).
/// @throws hc::ResourceError if the mask cannot be set or the thread cannot start.
class InterruptCleanup {
 public:
  InterruptCleanup();
  ~InterruptCleanup();  ///< stops the watcher and restores the previous mask
  InterruptCleanup(const InterruptCleanup&) = delete;
  InterruptCleanup& operator=(const InterruptCleanup&) = delete;

 private:
  sigset_t previous_{};
  std::atomic<bool> done_{false};
  std::thread watcher_;
};

}  // namespace hc::session
