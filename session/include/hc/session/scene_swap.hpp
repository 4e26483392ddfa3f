#pragma once
/// @file scene_swap.hpp
/// The re-scan swap protocol (docs/architecture.md, "Re-scan"): a new object replaces the one
/// under the hand without a restart, with zero force while it changes. On the thread that feeds
/// the servo loop's command ring (the UI thread of `hapticloud explore`), once per frame:
///  1. push kDisarm (retried while the command ring is full);
///  2. wait until the servo has applied it: the ring drained after the push, then a snapshot of a
///     LATER tick shows the device Open (zero force; not merely "some command was applied");
///  3. call the publish hook, which publishes the new scene's first window (normally through a
///     new LodController) and returns its surface tag;
///  4. wait until the servo has adopted it (surfaces_adopted advanced, nothing pending, and the
///     adopted tag is the hook's);
///  5. push kArm (retried while the ring is full).
/// Between the confirmed disarm and the arm it records the largest device force and whether the
/// device was ever seen Armed (the session summary's figures). GL-free, no OpenCV/PCL/yaml.

#include "hc/haptics/shared_state.hpp"

#include <cstdint>
#include <functional>

namespace hc::session {

/// Where a swap is.
enum class SwapPhase : std::uint8_t {
  kIdle = 0,     ///< no swap under way
  kWaitDisarm,   ///< kDisarm pushed (or waiting for room in the ring); waiting until applied
  kWaitAdopt,    ///< the new scene is published; waiting until the servo renders it
};

/// "idle", "wait-disarm", "wait-adopt". Real-time: yes.
const char* to_string(SwapPhase phase) noexcept;

/// What the swaps looked like from the driving thread (for the session summary).
struct SceneSwapFigures {
  int swaps_done = 0;              ///< swaps that reached the re-arm (kArm pushed or pending)
  /// Largest |Snapshot::device_force_n| [N] (device axes) seen in a snapshot read by step()
  /// between a confirmed disarm and the re-arm, over all swaps. 0 when the protocol holds.
  double max_device_force_n = 0.0;
  bool seen_armed = false;         ///< a snapshot in that interval showed the device Armed
};

/// Publishes the new scene's first window and returns the tag it was published with
/// (SharedState::publish_surface, HapticWindow::tag; must be ≠ 0). Called on the driving thread.
using PublishScene = std::function<std::uint64_t()>;

/// The swap protocol above as a state machine driven by step(). Not thread-safe: begin(), arm()
/// and step() are called from ONE thread, the single producer of `shared.commands` and a reader
/// of `shared.snapshots` (the UI thread); never from the servo thread. Nothing blocks: each call
/// does one non-blocking check and returns.
class SceneSwap {
 public:
  /// @param shared the servo loop's shared state; must outlive this.
  explicit SceneSwap(haptics::SharedState& shared) noexcept : shared_(shared) {}

  /// Arms the device: pushes kArm now, or keeps it pending and retries at each step() while
  /// the command ring is full. @return true if it was pushed now. Real-time: no.
  bool arm() noexcept;
  /// Starts a swap: drops a pending arm (it must not follow the disarm), pushes kDisarm (or
  /// retries at each step() while the ring is full). `publish` is called by a later step(),
  /// once the device is disarmed.
  /// @throws hc::ConfigError if a swap is already under way or `publish` is empty.
  void begin(PublishScene publish);
  /// One check, once per frame: retries a pending push, advances the phase when the servo has
  /// done what the phase waits for, records the figures. Calls the publish hook at most once.
  /// If the hook throws, the swap ends (phase kIdle, the device stays disarmed: zero force, no
  /// re-arm) and the exception propagates. @throws hc::InputError if the hook returns tag 0.
  /// @return the phase after this step. Real-time: no (the hook allocates).
  SwapPhase step();

  SwapPhase phase() const noexcept { return phase_; }
  bool busy() const noexcept { return phase_ != SwapPhase::kIdle; }
  /// True while a kArm waits for room in the command ring.
  bool arm_pending() const noexcept { return arm_pending_; }
  const SceneSwapFigures& figures() const noexcept { return figures_; }

 private:
  bool push(haptics::CommandType type) noexcept;
  void check_disarmed(const haptics::Snapshot& sn);
  void check_adopted();

  haptics::SharedState& shared_;
  SwapPhase phase_ = SwapPhase::kIdle;
  PublishScene publish_;
  bool arm_pending_ = false;       // a kArm to push (ring was full)
  bool disarm_sent_ = false;       // the swap's kDisarm is in the ring
  bool disarm_drained_ = false;    // the ring was empty after the kDisarm was pushed
  std::uint64_t disarm_tick_ = 0;  // a snapshot newer than this tick counts
  std::uint64_t adopted_mark_ = 0; // counters.surfaces_adopted before the publish
  std::uint64_t tag_ = 0;          // the new scene's surface tag
  SceneSwapFigures figures_;
};

}  // namespace hc::session
