// The process-wide stop request: SIGINT and SIGTERM only set the flag (the process goes on), and
// installing the handlers again (a device, then a session) keeps one flag for both.

#include "hc/haptics/stop_signal.hpp"

#include <gtest/gtest.h>

#include <csignal>

namespace hc::haptics {
namespace {

TEST(StopSignal, SigintAndSigtermSetTheOneFlag) {
  install_stop_signal_handlers();
  install_stop_signal_handlers();  // idempotent: a second installer shares the flag
  for (int sig : {SIGINT, SIGTERM}) {
    clear_stop_request();
    EXPECT_FALSE(stop_requested());
    ASSERT_EQ(std::raise(sig), 0);
    EXPECT_TRUE(stop_requested()) << "signal " << sig;
  }
  clear_stop_request();
  request_stop();
  EXPECT_TRUE(stop_requested());
  clear_stop_request();
  EXPECT_FALSE(stop_requested());
  std::signal(SIGINT, SIG_DFL);  // leave the process as it was for the other tests
  std::signal(SIGTERM, SIG_DFL);
}

}  // namespace
}  // namespace hc::haptics
