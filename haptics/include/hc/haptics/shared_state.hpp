#pragma once
/// @file shared_state.hpp
/// Everything the servo thread shares with the rest of the program (docs/architecture.md,
/// "Threads and shared state"): snapshots out (triple buffer), contact events out (SPSC ring),
/// commands in (SPSC ring), a new surface in (pointer mailbox, the old one handed back on a
/// retire ring so the servo thread never frees memory), and atomic counters.
/// Every channel carries fixed-size, trivially copyable types. Made once by the app before any
/// thread starts and passed by reference; no globals.

#include "hc/haptics/haptic_surface.hpp"
#include "hc/haptics/spsc_ring.hpp"
#include "hc/haptics/triple_buffer.hpp"
#include "hc/haptics/workspace_map.hpp"

#include <Eigen/Core>

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

namespace hc::haptics {

/// Plain 3-vector for the channels (Eigen types are not trivially copyable).
struct Vec3 {
  double x = 0.0, y = 0.0, z = 0.0;
  static Vec3 of(const Eigen::Vector3d& v) noexcept { return Vec3{v.x(), v.y(), v.z()}; }
  Eigen::Vector3d eigen() const noexcept { return Eigen::Vector3d(x, y, z); }
};

/// The servo loop's state after one tick (for viewers and monitors). Positions and force_n in
/// the grid frame; device_force_n in device axes.
struct Snapshot {
  std::uint64_t tick = 0;       ///< tick counter since start
  std::uint64_t surface_tag = 0;  ///< tag of the surface rendered this tick (publish_surface)
  double t_s = 0.0;             ///< clock time of the tick [s]
  Vec3 hip_m;                   ///< X_h, grid frame [m]
  Vec3 proxy_m;                 ///< X_p, grid frame [m]
  Vec3 force_n;                 ///< rendered force, grid frame [N]
  Vec3 device_force_n;          ///< force sent to the device, device axes [N]
  double ramp = 0.0;            ///< force ramp [0, 1]
  float mu_d = 0.0F;            ///< μ_d at the proxy [-]
  float mu_s = 0.0F;            ///< μ_s at the proxy [-]
  float beta_rad = 0.0F;        ///< β [rad]
  std::int32_t region_id = -1;  ///< region under the proxy, −1 = none
  std::int16_t iterations = 0;  ///< Eq. 5 iterations this tick
  bool in_contact = false;
  bool sticking = false;
  bool gate_open = false;
  bool saturated = false;
  std::uint8_t device_state = 0;  ///< DeviceState as a number
  std::uint8_t proxy_status = 0;  ///< ProxyStatus as a number
  std::uint32_t buttons = 0;      ///< device buttons pressed this tick (DeviceReading::buttons)
};

/// kOnset: contact begins; kSlide: in contact and slipping (speed_m_per_s > 0); kPress: in
/// contact without slipping (stuck or still; speed 0), so that consumers see the force grow
/// after an onset; kRelease: contact ends. kSlide and kPress come at most every
/// ServoConfig::slide_event_every_ticks ticks.
enum class ContactEventType : std::uint8_t { kOnset = 0, kSlide, kRelease, kPress };

/// A contact event for audio and logging. position_m is the proxy, grid frame.
struct ContactEvent {
  ContactEventType type = ContactEventType::kOnset;
  std::int32_t region_id = -1;      ///< region under the proxy, −1 = none
  std::uint64_t tick = 0;
  double t_s = 0.0;
  Vec3 position_m;                  ///< proxy, grid frame [m]
  Vec3 force_n;                     ///< rendered force, grid frame [N]
  double speed_m_per_s = 0.0;       ///< proxy speed over the surface (slide events) [m/s]
};

/// A change of the device's buttons (for people who explore without the screen: level and
/// region changes from the grip). pressed/released are the bits that changed this tick.
struct ButtonEvent {
  std::uint64_t tick = 0;
  double t_s = 0.0;
  std::uint32_t buttons = 0;   ///< bit mask now pressed
  std::uint32_t pressed = 0;   ///< bits that went down this tick
  std::uint32_t released = 0;  ///< bits that went up this tick
};

enum class CommandType : std::uint8_t {
  kArm = 0,               ///< device Open → Armed (forces go through the gate and ramp)
  kDisarm,                ///< Armed → Open
  kResetFault,            ///< Fault → Open
  kSetStiffness,          ///< a = k [N/m], device frame; clamped to [0, max stable stiffness]
  kSetDamping,            ///< a = b [N·s/m]; clamped to [0, device max damping]
  kSetMaxForce,           ///< a = cap [N]; clamped to (0, device max force]
  kSetRho,                ///< a = ρ; clamped to [0.001, 1]
  kSetFrictionEnabled,    ///< a ≠ 0: friction on
  kSetWorkspace,          ///< a, b, c = origin [m], d = scale, e = rotation [rad]; rejected if invalid;
                          ///< the proxy keeps its device position and the force is blended (as
                          ///< for a surface published with a map, which LoD switches use)
  kStop,                  ///< ends the threaded loop after this tick
};

/// One command for the servo loop. Plain data; build it with the helpers.
struct Command {
  CommandType type = CommandType::kArm;
  double a = 0.0, b = 0.0, c = 0.0, d = 0.0, e = 0.0;

  static Command of(CommandType type, double value = 0.0) noexcept { return Command{type, value, 0, 0, 0, 0}; }
  static Command set_workspace(const WorkspaceMap& m) noexcept {
    return Command{CommandType::kSetWorkspace, m.origin_m.x(), m.origin_m.y(), m.origin_m.z(), m.scale,
                   m.rotation_rad};
  }
};

/// The names of the command types ("arm", "disarm", "reset_fault", "set_stiffness",
/// "set_damping", "set_max_force", "set_rho", "set_friction_enabled", "set_workspace", "stop"),
/// as recordings write them. Real-time: yes.
const char* to_string(CommandType type) noexcept;
/// Inverse of to_string(CommandType). @return false for an unknown name.
bool command_type_from_string(const std::string& name, CommandType& out);

/// What the servo loop did at a tick, for recordings (SharedState::enable_servo_log).
struct ServoLogEntry {
  enum class Kind : std::uint8_t {
    kCommand = 0,      ///< `command` was applied at the start of tick `tick`
    kRejected,         ///< `command` was rejected (invalid) at tick `tick`
    kSurface,          ///< the surface published with `surface_tag` was adopted at tick `tick`
  };
  std::uint64_t tick = 0;  ///< servo tick index, 0 = the loop's first tick (its first device read)
  Kind kind = Kind::kCommand;
  Command command{};
  std::uint64_t surface_tag = 0;
};

/// Counters written by the servo thread, read by anyone (relaxed atomics).
struct ServoCounters {
  std::atomic<std::uint64_t> ticks{0};
  std::atomic<std::uint64_t> overruns{0};           ///< ticks that ended after the next deadline
  std::atomic<std::uint64_t> events_dropped{0};     ///< contact or button events lost to a full ring
  std::atomic<std::uint64_t> commands_applied{0};
  std::atomic<std::uint64_t> commands_rejected{0};  ///< invalid (e.g. non-finite) commands
  std::atomic<std::uint64_t> device_errors{0};      ///< read/write statuses other than ok
  std::atomic<std::uint64_t> nonfinite_inputs{0};   ///< ticks with a NaN/inf HIP
  std::atomic<std::uint64_t> surfaces_adopted{0};
  std::atomic<std::uint64_t> surface_tag{0};        ///< tag of the surface in use (publish_surface)
  std::atomic<std::int64_t> worst_compute_ns{0};
  std::atomic<std::int64_t> worst_lateness_ns{0};
};

class SharedState {
 public:
  static constexpr std::size_t kEventCapacity = 1024;
  static constexpr std::size_t kCommandCapacity = 64;
  static constexpr std::size_t kRetireCapacity = 8;
  static constexpr std::size_t kButtonEventCapacity = 64;

  /// @param initial the surface the servo starts with (may be null: free space until one is
  ///        published). Real-time: no.
  explicit SharedState(std::unique_ptr<const HapticSurface> initial = nullptr);
  /// Frees the current, pending and retired surfaces. The servo loop must have stopped.
  ~SharedState();
  SharedState(const SharedState&) = delete;
  SharedState& operator=(const SharedState&) = delete;

  TripleBuffer<Snapshot> snapshots;                       ///< servo → readers
  SpscRing<ContactEvent, kEventCapacity> events;          ///< servo → one consumer (audio)
  SpscRing<Command, kCommandCapacity> commands;           ///< one producer (UI) → servo
  SpscRing<ButtonEvent, kButtonEventCapacity> button_events;  ///< servo → one consumer (session)
  ServoCounters counters;

  /// Producer side (one non-real-time thread): hands a new surface to the servo, which adopts it
  /// at its next tick boundary. A previously published surface the servo has not adopted yet is
  /// freed here. Real-time: no.
  void publish_surface(std::unique_ptr<const HapticSurface> surface);
  /// Producer side: the same, with the workspace map the surface is to be rendered with. The
  /// servo adopts surface and map at the same tick boundary and carries the proxy over (it keeps
  /// the proxy's device position; servo_loop.hpp). `tag` (≠ 0 to be useful) identifies the
  /// surface: once adopted it is in counters.surface_tag and every Snapshot::surface_tag.
  /// @throws hc::ConfigError if `map` is invalid (WorkspaceMap::valid). Real-time: no.
  void publish_surface(std::unique_ptr<const HapticSurface> surface, const WorkspaceMap& map,
                       std::uint64_t tag = 0);
  /// Producer side: frees the surfaces the servo has handed back. @return how many. Real-time: no.
  std::size_t collect_retired() noexcept;
  /// Surface accounting (producer side; any thread may read): publications made (the initial
  /// surface counts as one) and publications freed (superseded before adoption, handed back by the
  /// servo and collected, or freed at destruction). While the session runs,
  /// published − freed ≤ 2 + kRetireCapacity (current, pending and the retire ring); a larger
  /// difference that grows over a session is a leak (the soak benchmark, bench/soak.py, reports
  /// both). Real-time: no (the servo never touches them).
  std::uint64_t surfaces_published() const noexcept { return published_.load(std::memory_order_relaxed); }
  std::uint64_t surfaces_freed() const noexcept { return freed_.load(std::memory_order_relaxed); }
  /// True while a published surface waits for adoption.
  bool surface_pending() const noexcept { return pending_.load(std::memory_order_acquire) != nullptr; }
  /// Servo side: true when the next adopt() would take a new surface (one is pending and the
  /// retire ring has room). Real-time: yes.
  bool surface_adoptable() const noexcept {
    return pending_.load(std::memory_order_acquire) != nullptr && retired_.size_approx() < kRetireCapacity;
  }
  /// The word the threaded servo loop sleeps on between ticks (a Linux futex, FUTEX_WAIT_BITSET
  /// with an absolute CLOCK_MONOTONIC timeout; futex(2)). Every publication increments it and
  /// wakes the sleeper, so that the loop can adopt the surface before its next deadline
  /// (ServoConfig::wake_on_surface_min_period). Real-time: yes (a load).
  const std::atomic<std::uint32_t>& surface_signal() const noexcept { return signal_; }

  /// Servo side: adopts a pending surface if the retire ring has room (else keeps the current
  /// one and retries next tick) and returns the surface to render this tick (may be null).
  /// Real-time: yes (no allocation, no free).
  const HapticSurface* adopt_surface() noexcept;
  /// What adopt() found this tick.
  struct Adoption {
    const HapticSurface* surface = nullptr;  ///< the surface to render this tick (may be null)
    const WorkspaceMap* map = nullptr;       ///< the map published with a surface adopted THIS
                                             ///< tick, else null (keep the current map)
    bool changed = false;                    ///< a new surface was adopted this tick
    std::uint64_t tag = 0;                   ///< tag of `surface`
  };
  /// Servo side: adopt_surface() that also reports whether the surface changed this tick and the
  /// map published with it. Real-time: yes (no allocation, no free).
  Adoption adopt() noexcept;

  /// The servo log (what the loop applied and adopted, tick by tick), off until enabled.
  using ServoLog = SpscRing<ServoLogEntry, 4096>;
  /// Turns the log on (allocates its ring); call before the servo loop starts. The servo pushes
  /// an entry per applied or rejected command and per adopted surface; one consumer drains
  /// servo_log() (a recorder's writer thread). A full ring drops entries and counts them in
  /// servo_log_dropped(). Real-time: no.
  void enable_servo_log();
  /// The log's ring, or null while the log is off. Real-time: yes.
  ServoLog* servo_log() noexcept { return log_.get(); }
  std::uint64_t servo_log_dropped() const noexcept { return log_dropped_.load(std::memory_order_relaxed); }
  /// Servo side: appends to the log when it is on. Real-time: yes.
  void log(const ServoLogEntry& e) noexcept {
    if (log_ && !log_->try_push(e)) log_dropped_.fetch_add(1, std::memory_order_relaxed);
  }

  /// Servo side: the surface in use.
  const HapticSurface* current_surface() const noexcept { return current_ ? current_->surface : nullptr; }

 private:
  /// One publication: the surface with its optional map (owned; freed by the producer side).
  struct Published {
    const HapticSurface* surface = nullptr;
    WorkspaceMap map;
    bool has_map = false;
    std::uint64_t tag = 0;
  };
  static void destroy(const Published* p) noexcept;
  void publish(Published* p);

  std::unique_ptr<ServoLog> log_;
  std::atomic<std::uint64_t> log_dropped_{0};
  std::atomic<Published*> pending_{nullptr};
  std::atomic<std::uint32_t> signal_{0};  // futex word: +1 per publication (surface_signal)
  Published* current_ = nullptr;  // owned; touched by the servo thread only
  SpscRing<Published*, kRetireCapacity> retired_;
  std::atomic<std::uint64_t> published_{0};  // producer side only
  std::atomic<std::uint64_t> freed_{0};      // producer side only
};

}  // namespace hc::haptics
