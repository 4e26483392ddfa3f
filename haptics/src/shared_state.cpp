#include "hc/haptics/shared_state.hpp"

#include "hc/common/error.hpp"

#include <sstream>

#include <linux/futex.h>
#include <sys/syscall.h>
#include <unistd.h>

namespace hc::haptics {

SharedState::SharedState(std::unique_ptr<const HapticSurface> initial) {
  if (initial) {
    current_ = new Published{initial.release(), WorkspaceMap{}, false, 0};
    published_.store(1, std::memory_order_relaxed);
  }
}

SharedState::~SharedState() {
  collect_retired();
  Published* pending = pending_.exchange(nullptr, std::memory_order_acq_rel);
  if (pending != nullptr) freed_.fetch_add(1, std::memory_order_relaxed);
  destroy(pending);
  if (current_ != nullptr) freed_.fetch_add(1, std::memory_order_relaxed);
  destroy(current_);
}

void SharedState::destroy(const Published* p) noexcept {
  if (p == nullptr) return;
  delete p->surface;
  delete p;
}

void SharedState::publish(Published* p) {
  published_.fetch_add(1, std::memory_order_relaxed);
  // Never seen by the servo: the exchange gave the previous pending publication back to us alone.
  Published* superseded = pending_.exchange(p, std::memory_order_acq_rel);
  if (superseded != nullptr) freed_.fetch_add(1, std::memory_order_relaxed);
  destroy(superseded);
  // Wake a servo loop sleeping until its next deadline (futex(2), FUTEX_WAKE): it adopts the
  // surface now, or once its minimum interval since the last tick has passed.
  signal_.fetch_add(1, std::memory_order_release);
  static_assert(sizeof(std::atomic<std::uint32_t>) == sizeof(std::uint32_t) &&
                std::atomic<std::uint32_t>::is_always_lock_free);
  (void)syscall(SYS_futex, reinterpret_cast<std::uint32_t*>(&signal_), FUTEX_WAKE_PRIVATE, 1, nullptr, nullptr, 0);
}

void SharedState::publish_surface(std::unique_ptr<const HapticSurface> surface) {
  auto p = std::make_unique<Published>();
  p->surface = surface.release();
  publish(p.release());
}

void SharedState::publish_surface(std::unique_ptr<const HapticSurface> surface, const WorkspaceMap& map,
                                  std::uint64_t tag) {
  if (!map.valid()) {
    std::ostringstream s;
    s << "shared state: publish_surface with an invalid workspace map (scale " << map.scale << ", origin "
      << map.origin_m.transpose() << ", rotation " << map.rotation_rad
      << "); expected finite values and scale > 0";
    throw ConfigError(s.str());
  }
  auto p = std::make_unique<Published>();
  p->map = map;
  p->has_map = true;
  p->tag = tag;
  p->surface = surface.release();
  publish(p.release());
}

std::size_t SharedState::collect_retired() noexcept {
  std::size_t n = 0;
  Published* p = nullptr;
  while (retired_.try_pop(p)) {
    destroy(p);
    ++n;
  }
  freed_.fetch_add(n, std::memory_order_relaxed);
  return n;
}

SharedState::Adoption SharedState::adopt() noexcept {
  Adoption a;
  if (pending_.load(std::memory_order_relaxed) != nullptr &&
      // Only the servo pushes to the retire ring, so room seen here is still there after the swap.
      retired_.size_approx() < kRetireCapacity) {
    Published* next = pending_.exchange(nullptr, std::memory_order_acq_rel);
    if (next != nullptr) {
      if (current_ != nullptr) (void)retired_.try_push(current_);
      current_ = next;
      a.changed = true;
      a.map = next->has_map ? &next->map : nullptr;
      counters.surfaces_adopted.fetch_add(1, std::memory_order_relaxed);
      counters.surface_tag.store(next->tag, std::memory_order_release);
    }
  }
  if (current_ != nullptr) {
    a.surface = current_->surface;
    a.tag = current_->tag;
  }
  return a;
}

const HapticSurface* SharedState::adopt_surface() noexcept { return adopt().surface; }

void SharedState::enable_servo_log() {
  if (!log_) log_ = std::make_unique<ServoLog>();
}

namespace {
constexpr const char* kCommandNames[] = {"arm",         "disarm",  "reset_fault",          "set_stiffness", "set_damping",
                                         "set_max_force", "set_rho", "set_friction_enabled", "set_workspace", "stop"};
}  // namespace

const char* to_string(CommandType type) noexcept {
  const auto i = static_cast<std::size_t>(type);
  return i < std::size(kCommandNames) ? kCommandNames[i] : "unknown";
}

bool command_type_from_string(const std::string& name, CommandType& out) {
  for (std::size_t i = 0; i < std::size(kCommandNames); ++i) {
    if (name == kCommandNames[i]) {
      out = static_cast<CommandType>(i);
      return true;
    }
  }
  return false;
}

}  // namespace hc::haptics
