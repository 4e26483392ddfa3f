#pragma once
/// @file spsc_ring.hpp
/// Fixed-capacity single-producer single-consumer ring of trivially copyable values, lock-free
/// and allocation-free: the servo loop's channel for contact events (out) and commands (in).

#include <array>
#include <atomic>
#include <cstddef>
#include <type_traits>

namespace hc::haptics {

/// Bounded SPSC queue. Exactly one thread may push and one (other) thread may pop; each side's
/// calls are wait-free (no locks, no allocation, O(1)). When full, try_push() fails and the
/// producer decides (the servo loop drops the event and counts it).
/// @tparam T        trivially copyable.
/// @tparam Capacity power of two ≥ 2.
/// Memory order: a push's slot write happens-before the matching pop's read (release/acquire).
template <class T, std::size_t Capacity>
class SpscRing {
  static_assert(std::is_trivially_copyable_v<T>, "SpscRing carries trivially copyable types only");
  static_assert(Capacity >= 2 && (Capacity & (Capacity - 1)) == 0, "Capacity: a power of two");

 public:
  SpscRing() = default;
  SpscRing(const SpscRing&) = delete;
  SpscRing& operator=(const SpscRing&) = delete;

  /// Producer only. @return false (and nothing stored) when full. Real-time: yes.
  bool try_push(const T& value) noexcept {
    const std::size_t tail = tail_.load(std::memory_order_relaxed);
    if (tail - head_cache_ == Capacity) {
      head_cache_ = head_.load(std::memory_order_acquire);
      if (tail - head_cache_ == Capacity) return false;
    }
    slots_[tail & (Capacity - 1)] = value;
    tail_.store(tail + 1, std::memory_order_release);
    return true;
  }

  /// Consumer only. @return false when empty (out unchanged). Real-time: yes.
  bool try_pop(T& out) noexcept {
    const std::size_t head = head_.load(std::memory_order_relaxed);
    if (head == tail_cache_) {
      tail_cache_ = tail_.load(std::memory_order_acquire);
      if (head == tail_cache_) return false;
    }
    out = slots_[head & (Capacity - 1)];
    head_.store(head + 1, std::memory_order_release);
    return true;
  }

  /// Number of stored values; exact from either side when the other is idle, else a snapshot.
  std::size_t size_approx() const noexcept {
    return tail_.load(std::memory_order_acquire) - head_.load(std::memory_order_acquire);
  }
  static constexpr std::size_t capacity() noexcept { return Capacity; }

 private:
  // Consumer-owned line: its index and its cached view of the producer's index.
  alignas(64) std::atomic<std::size_t> head_{0};
  std::size_t tail_cache_ = 0;
  // Producer-owned line.
  alignas(64) std::atomic<std::size_t> tail_{0};
  std::size_t head_cache_ = 0;
  alignas(64) std::array<T, Capacity> slots_{};
};

}  // namespace hc::haptics
