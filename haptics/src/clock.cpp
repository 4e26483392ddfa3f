#include "hc/haptics/clock.hpp"

#include <ctime>

namespace hc::haptics {

std::int64_t monotonic_now_ns() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

std::int64_t SteadyClock::now_ns() const noexcept { return monotonic_now_ns(); }

}  // namespace hc::haptics
