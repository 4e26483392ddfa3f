#include "hc/session/scene_swap.hpp"

#include "hc/common/error.hpp"
#include "hc/haptics/device.hpp"

#include <algorithm>
#include <string>
#include <utility>

namespace hc::session {

const char* to_string(SwapPhase phase) noexcept {
  switch (phase) {
    case SwapPhase::kIdle: return "idle";
    case SwapPhase::kWaitDisarm: return "wait-disarm";
    case SwapPhase::kWaitAdopt: return "wait-adopt";
  }
  return "unknown";
}

bool SceneSwap::push(haptics::CommandType type) noexcept {
  return shared_.commands.try_push(haptics::Command::of(type));
}

bool SceneSwap::arm() noexcept {
  arm_pending_ = !push(haptics::CommandType::kArm);
  return !arm_pending_;
}

void SceneSwap::begin(PublishScene publish) {
  if (busy()) throw ConfigError(std::string("scene swap: a swap is already under way (") + to_string(phase_) + ")");
  if (!publish) throw ConfigError("scene swap: no publish hook given");
  publish_ = std::move(publish);
  arm_pending_ = false;  // a pending arm must not follow the disarm
  disarm_sent_ = push(haptics::CommandType::kDisarm);
  disarm_drained_ = false;
  disarm_tick_ = 0;
  tag_ = 0;
  phase_ = SwapPhase::kWaitDisarm;
}

void SceneSwap::check_disarmed(const haptics::Snapshot& sn) {
  // The disarm is applied once the servo has emptied the ring (it pops commands at the start of
  // a tick); a snapshot of a tick after the one read when the ring was found empty was made
  // after that tick's commands, so if it shows the device Open the force is zero.
  if (!disarm_drained_) {
    if (shared_.commands.size_approx() == 0) {
      disarm_drained_ = true;
      disarm_tick_ = sn.tick;
    }
    return;
  }
  if (sn.tick <= disarm_tick_ || sn.device_state != static_cast<std::uint8_t>(haptics::DeviceState::kOpen)) return;
  // Zero force: publish the new scene and wait until the servo has it.
  adopted_mark_ = shared_.counters.surfaces_adopted.load(std::memory_order_acquire);
  PublishScene publish = std::move(publish_);
  publish_ = nullptr;
  std::uint64_t tag = 0;
  try {
    tag = publish();
  } catch (...) {
    phase_ = SwapPhase::kIdle;  // stays disarmed
    throw;
  }
  if (tag == 0) {
    phase_ = SwapPhase::kIdle;
    throw InputError("scene swap: the publish hook returned surface tag 0 (its adoption cannot be recognised)");
  }
  tag_ = tag;
  phase_ = SwapPhase::kWaitAdopt;
}

void SceneSwap::check_adopted() {
  const bool adopted = shared_.counters.surfaces_adopted.load(std::memory_order_acquire) > adopted_mark_ &&
                       !shared_.surface_pending() &&
                       shared_.counters.surface_tag.load(std::memory_order_acquire) == tag_;
  if (!adopted) return;
  arm();  // retried by later steps while the ring is full
  phase_ = SwapPhase::kIdle;
  ++figures_.swaps_done;
}

SwapPhase SceneSwap::step() {
  if (arm_pending_) arm();
  if (phase_ == SwapPhase::kIdle) return phase_;
  haptics::Snapshot sn;
  shared_.snapshots.read(sn);
  if (phase_ == SwapPhase::kWaitAdopt) {
    figures_.max_device_force_n = std::max(figures_.max_device_force_n, sn.device_force_n.eigen().norm());
    figures_.seen_armed =
        figures_.seen_armed || sn.device_state == static_cast<std::uint8_t>(haptics::DeviceState::kArmed);
    check_adopted();
    return phase_;
  }
  // kWaitDisarm: the ring was full at begin(): retry until the disarm is in.
  if (!disarm_sent_) {
    disarm_sent_ = push(haptics::CommandType::kDisarm);
    if (!disarm_sent_) return phase_;
  }
  check_disarmed(sn);
  return phase_;
}

}  // namespace hc::session
