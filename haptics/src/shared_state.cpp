#include "hc/haptics/shared_state.hpp"

namespace hc::haptics {

SharedState::SharedState(std::unique_ptr<const HapticSurface> initial) : current_(initial.release()) {}

SharedState::~SharedState() {
  collect_retired();
  delete pending_.exchange(nullptr, std::memory_order_acq_rel);
  delete current_;
}

void SharedState::publish_surface(std::unique_ptr<const HapticSurface> surface) {
  const HapticSurface* previous = pending_.exchange(surface.release(), std::memory_order_acq_rel);
  delete previous;  // never seen by the servo: the exchange gave it back to us alone
}

std::size_t SharedState::collect_retired() noexcept {
  std::size_t n = 0;
  const HapticSurface* s = nullptr;
  while (retired_.try_pop(s)) {
    delete s;
    ++n;
  }
  return n;
}

const HapticSurface* SharedState::adopt_surface() noexcept {
  if (pending_.load(std::memory_order_relaxed) == nullptr) return current_;
  // Only the servo pushes to the retire ring, so room seen here is still there after the swap.
  if (retired_.size_approx() >= kRetireCapacity) return current_;
  const HapticSurface* next = pending_.exchange(nullptr, std::memory_order_acq_rel);
  if (next == nullptr) return current_;
  if (current_ != nullptr) (void)retired_.try_push(current_);
  current_ = next;
  counters.surfaces_adopted.fetch_add(1, std::memory_order_relaxed);
  return current_;
}

}  // namespace hc::haptics
