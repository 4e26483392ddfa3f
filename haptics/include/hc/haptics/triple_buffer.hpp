#pragma once
/// @file triple_buffer.hpp
/// Latest-value channel from one writer to one reader: the writer never waits, the reader gets
/// the most recent complete value. The servo loop publishes its snapshot through it every tick.

#include <array>
#include <atomic>
#include <cstdint>
#include <type_traits>

namespace hc::haptics {

/// Three slots: one owned by the writer, one by the reader, one "middle" exchanged atomically.
/// write() fills the writer's slot and swaps it into the middle (marked fresh); read() swaps a
/// fresh middle into the reader's slot. No locks, no allocation, O(1) copies of T.
/// One writer thread and one reader thread.
/// @tparam T trivially copyable.
template <class T>
class TripleBuffer {
  static_assert(std::is_trivially_copyable_v<T>, "TripleBuffer carries trivially copyable types only");

 public:
  TripleBuffer() = default;
  TripleBuffer(const TripleBuffer&) = delete;
  TripleBuffer& operator=(const TripleBuffer&) = delete;

  /// Writer only: publishes `value`. Real-time: yes (wait-free).
  void write(const T& value) noexcept {
    slots_[write_].value = value;
    const std::uint8_t prev = middle_.exchange(static_cast<std::uint8_t>(write_ | kFresh),
                                               std::memory_order_acq_rel);
    write_ = static_cast<std::uint8_t>(prev & kIndexMask);
  }

  /// Reader only: copies the latest published value into `out` (a value-initialised T before
  /// the first write). @return true when it is newer than the previous read(). Real-time: yes.
  bool read(T& out) noexcept {
    bool fresh = false;
    if ((middle_.load(std::memory_order_relaxed) & kFresh) != 0) {
      const std::uint8_t prev = middle_.exchange(read_, std::memory_order_acq_rel);
      read_ = static_cast<std::uint8_t>(prev & kIndexMask);
      fresh = true;
    }
    out = slots_[read_].value;
    return fresh;
  }

 private:
  static constexpr std::uint8_t kIndexMask = 0x3;
  static constexpr std::uint8_t kFresh = 0x4;
  struct alignas(64) Slot {
    T value{};
  };
  std::array<Slot, 3> slots_{};
  alignas(64) std::atomic<std::uint8_t> middle_{1};
  alignas(64) std::uint8_t write_ = 0;  // writer-owned
  alignas(64) std::uint8_t read_ = 2;   // reader-owned
};

}  // namespace hc::haptics
