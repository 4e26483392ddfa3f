#include "hc/haptics/stop_signal.hpp"

#include <csignal>

namespace hc::haptics {
namespace {

volatile std::sig_atomic_t g_stop = 0;

extern "C" void hc_on_stop_signal(int /*signal*/) { g_stop = 1; }

}  // namespace

void install_stop_signal_handlers() {
  struct sigaction sa {};
  sa.sa_handler = hc_on_stop_signal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = 0;
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
}

bool stop_requested() noexcept { return g_stop != 0; }
void request_stop() noexcept { g_stop = 1; }
void clear_stop_request() noexcept { g_stop = 0; }

}  // namespace hc::haptics
