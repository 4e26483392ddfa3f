#include "hc/session/interrupt_cleanup.hpp"

#include "hc/common/error.hpp"
#include "hc/pipeline/scene_io.hpp"

#include <pthread.h>
#include <unistd.h>

#include <cstring>
#include <string>

namespace hc::session {

namespace {

sigset_t interrupt_set() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGTERM);
  return set;
}

}  // namespace

InterruptCleanup::InterruptCleanup() {
  const sigset_t set = interrupt_set();
  if (const int rc = pthread_sigmask(SIG_BLOCK, &set, &previous_); rc != 0) {
    throw ResourceError(std::string("cannot block SIGINT/SIGTERM for the output clean-up: ") + std::strerror(rc));
  }
  try {
    watcher_ = std::thread([this, set] {
      for (;;) {
        int signo = 0;
        if (sigwait(&set, &signo) != 0) continue;
        if (done_.load()) return;  // the destructor's wake-up
        const int removed = pipeline::remove_live_staging_dirs(true);  // final: the lock stays held until _exit
        const std::string line = std::string("hapticloud: interrupted by ") + (signo == SIGINT ? "SIGINT" : "SIGTERM") +
                                 "; removed " + std::to_string(removed) + " unfinished output or scratch item(s)\n";
        const ssize_t written = ::write(STDERR_FILENO, line.data(), line.size());
        (void)written;
        ::_exit(128 + signo);
      }
    });
  } catch (...) {
    pthread_sigmask(SIG_SETMASK, &previous_, nullptr);
    throw ResourceError("cannot start the interrupt watcher thread");
  }
}

InterruptCleanup::~InterruptCleanup() {
  done_.store(true);
  pthread_kill(watcher_.native_handle(), SIGTERM);
  watcher_.join();
  pthread_sigmask(SIG_SETMASK, &previous_, nullptr);
}

}  // namespace hc::session
