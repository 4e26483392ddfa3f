#pragma once
/// @file clock.hpp
/// Injectable clocks: the real monotonic clock, and a manual clock that tests and "as fast as
/// possible" sessions advance by hand so that simulated time is exact and reproducible.

#include <atomic>
#include <cstdint>

namespace hc::haptics {

/// A source of time in nanoseconds. now_ns() is real-time safe in every implementation.
class Clock {
 public:
  virtual ~Clock() = default;
  /// Current time [ns]; monotonic (never decreases). Real-time: yes. Thread-safe: yes.
  virtual std::int64_t now_ns() const noexcept = 0;
};

/// CLOCK_MONOTONIC, the clock the servo loop's absolute deadlines use.
class SteadyClock final : public Clock {
 public:
  std::int64_t now_ns() const noexcept override;
};

/// Time that only moves when told to. Thread-safe (atomic).
class ManualClock final : public Clock {
 public:
  explicit ManualClock(std::int64_t start_ns = 0) : t_ns_(start_ns) {}
  std::int64_t now_ns() const noexcept override { return t_ns_.load(std::memory_order_acquire); }
  /// Moves time forward by dt_ns ≥ 0 (negative values are ignored). Real-time: yes.
  void advance_ns(std::int64_t dt_ns) noexcept {
    if (dt_ns > 0) t_ns_.fetch_add(dt_ns, std::memory_order_acq_rel);
  }

 private:
  std::atomic<std::int64_t> t_ns_;
};

/// CLOCK_MONOTONIC now [ns]. Real-time: yes (vDSO).
std::int64_t monotonic_now_ns() noexcept;

}  // namespace hc::haptics
