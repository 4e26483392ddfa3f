#pragma once
/// @file servo_loop.hpp
/// The haptic servo loop: every tick reads the device, maps the HIP into the grid frame, steps
/// the proxy (proxy.hpp), writes the force, and publishes a snapshot and contact events
/// (shared_state.hpp). Runs on its own thread at 1 kHz by default (up to 10 kHz), paced by
/// absolute deadlines (clock_nanosleep, TIMER_ABSTIME; a published surface may wake it early:
/// ServoConfig::wake_on_surface_min_period), or without a thread "as fast as
/// possible" on a ManualClock for tests and scripted sessions.
/// Inside a tick nothing allocates, locks, does I/O or logs; set-up (constructor, start) may
/// throw and allocates everything in advance. Model: libfranka's control loop (a tiny loop body,
/// everything slow before it starts).

#include "hc/haptics/clock.hpp"
#include "hc/haptics/device.hpp"
#include "hc/haptics/proxy.hpp"
#include "hc/haptics/shared_state.hpp"
#include "hc/haptics/workspace_map.hpp"

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <thread>

namespace hc::haptics {

/// What the loop does about real-time scheduling (SCHED_FIFO and mlockall).
enum class RealtimeMode : std::uint8_t {
  kOff = 0,  ///< do not ask
  kWarn,     ///< ask; run anyway if refused and say so in the report
  kEnforce,  ///< ask; refuse to start (hc::ResourceError) if either is refused
};

/// Parses "off", "warn", "enforce". @throws hc::ConfigError naming the value and the allowed set.
RealtimeMode realtime_mode_from_string(std::string_view name);
const char* to_string(RealtimeMode mode) noexcept;

/// Configuration of a servo loop. Stiffness and damping in proxy are DEVICE-frame values
/// (N/m, N·s/m); the loop divides them by the workspace scale for the grid-frame proxy.
struct ServoConfig {
  double rate_hz = 1000.0;               ///< tick rate (0, 10000] [Hz]
  RealtimeMode realtime = RealtimeMode::kWarn;
  int fifo_priority = 80;                ///< SCHED_FIFO priority [1, 99]
  ProxyParams proxy;                     ///< proxy and force parameters (device units)
  WorkspaceMap workspace;                ///< device ↔ grid map
  int slide_event_every_ticks = 10;      ///< a slide event at most every N ticks of sliding, ≥ 1
  int max_commands_per_tick = 16;        ///< commands applied per tick, ≥ 1
  /// Surface switch (a surface adopted from the mailbox, e.g. a new level or window): the force
  /// sent to the device changes by at most this much per tick because of the switch [N], > 0.
  /// When the new surface's force differs more from the last one sent, the loop blends from the
  /// old force to the new one (the force "ramps in"), each tick moving by at most half this
  /// step and completing within switch_ramp_s or longer.
  double switch_max_force_step_n = 0.5;
  double switch_ramp_s = 0.05;           ///< shortest blend after a switch [s], ≥ 0
  /// Threaded loop: a surface published between two ticks (a LoD switch or pan) wakes the loop,
  /// which runs a tick at once to adopt it instead of waiting for the next deadline, but not
  /// sooner than this many periods after the previous tick (the damping's HIP velocity divides
  /// by that interval); the next deadline is then a whole period after that tick, and the tick
  /// on it is never early again (at most one early tick between two deadline ticks, however
  /// often surfaces are published). In [0.25, 1]: 1 turns the wake off (surfaces are adopted on
  /// deadlines only), 0.5 bounds the request → first tick wait by half a period. [periods].
  /// Issue 16: LoD switch p99 ≤ 1 ms. Without futex(2) the loop sleeps to its deadlines.
  double wake_on_surface_min_period = 0.5;
  /// Threaded loop: the thread wakes this long before each deadline, brings back into the CPU
  /// caches what the tick will use (warm_up(): a dry step of the proxy on a copy of its state,
  /// towards the HIP extrapolated by its last step, on the surface in use: the step's code and
  /// the cells it walks), and spins to the deadline. After the ~1 ms sleep a core that ran other
  /// work (the viewer, Mesa's llvmpipe, the hypervisor) has lost those lines, and each costs
  /// about 0.1 µs from memory: on the 2-core VM a session's tick compute p99.9 went from
  /// 3.5–5.2 µs to 2.2–2.9 µs (bench/README, issue 16, "the servo tick after a sleep"). The device
  /// is read only at the deadline, so the read → write time shrinks, not just the figure. It
  /// runs also when the wake comes after the deadline (the read then waits for one step), not
  /// before an early tick for a published surface; with warm_up_ns ≥
  /// (1 − wake_on_surface_min_period) periods no tick is early.
  /// Cost: a busy SCHED_FIFO spin of this much per period (2 % of a core at 20 µs and 1 kHz,
  /// 20 % at 10 kHz). 0 turns it off. In [0, a quarter period] [ns].
  std::int64_t warm_up_ns = 20000;
};

/// What start() obtained.
struct RealtimeReport {
  RealtimeMode mode = RealtimeMode::kOff;
  bool fifo_granted = false;   ///< the servo thread runs SCHED_FIFO
  int priority = 0;            ///< its priority when granted
  bool memory_locked = false;  ///< mlockall(MCL_CURRENT | MCL_FUTURE) succeeded
  /// A CPU wake-up latency of 0 µs is requested through /dev/cpu_dma_latency (Linux PM QoS,
  /// kernel documentation "PM Quality Of Service Interface") while the loop runs, so that idle
  /// CPUs stay out of deep idle states between ticks. Advisory: a refusal is reported in
  /// `detail` but never stops the loop, not even under enforce.
  bool cpu_latency_pinned = false;
  std::string detail;          ///< one line per refusal with errno text and what to check
};

/// Fixed-size histogram of durations [ns] (1 ns bins below 4096 ns, 64 ns bins up to
/// 266 µs, one overflow bin) with exact count, mean and max. add() is real-time safe.
class LatencyHistogram {
 public:
  void add(std::int64_t ns) noexcept;
  void reset() noexcept;
  std::uint64_t count() const noexcept { return count_; }
  double mean_ns() const noexcept { return count_ ? static_cast<double>(sum_) / static_cast<double>(count_) : 0.0; }
  std::int64_t max_ns() const noexcept { return max_; }
  /// Smallest bin upper edge below which a fraction q ∈ [0, 1] of the samples lie (the exact
  /// max for the overflow bin). 0 when empty. Real-time: no (O(bins)).
  double percentile_ns(double q) const noexcept;

 private:
  static constexpr int kFineBins = 4096;   // [0, 4096) ns, 1 ns each
  static constexpr int kCoarseBins = 4096; // [4096, 266240) ns, 64 ns each
  std::array<std::uint64_t, kFineBins + kCoarseBins + 1> bins_{};
  std::uint64_t count_ = 0;
  std::int64_t sum_ = 0;
  std::int64_t max_ = 0;
};

/// Per-tick statistics, kept in fixed arrays (no allocation while running).
struct ServoStats {
  std::uint64_t ticks = 0;
  std::uint64_t overruns = 0;  ///< threaded: the tick ended after the next deadline;
                               ///< as fast as possible: compute time > period
  LatencyHistogram compute;    ///< tick compute time (device read to snapshot) [ns]
  LatencyHistogram lateness;   ///< wake-up time − the time asked for: the deadline, less
                               ///< ServoConfig::warm_up_ns (period jitter; threaded only,
                               ///< deadline ticks only) [ns]
  std::uint64_t surface_wake_ticks = 0;  ///< threaded: ticks run before their deadline to adopt a
                                         ///< published surface (wake_on_surface_min_period)
  std::uint64_t warm_ups = 0;  ///< warm_up() calls (threaded: one before each deadline tick,
                               ///< ServoConfig::warm_up_ns)
};

/// One trace row (trivially copyable). Grid frame, SI units.
struct TickRecord {
  double t_s = 0.0;
  Vec3 hip_m, proxy_m, force_n;
  float mu_d = 0.0F, mu_s = 0.0F, beta_rad = 0.0F;
  std::int32_t compute_ns = 0;
  std::int16_t iterations = 0;
  bool in_contact = false;
  bool sticking = false;
  std::uint8_t device_state = 0;
  std::uint32_t surface_tag = 0;  ///< tag of the surface rendered (Snapshot::surface_tag, low 32 bits)
};

class ServoLoop {
 public:
  /// Pre-allocates everything; `device`, `shared` and `clock` must outlive the loop. In the
  /// threaded mode `clock` should be a SteadyClock (timestamps); pacing always uses
  /// CLOCK_MONOTONIC.
  /// @throws hc::ConfigError naming the field: rate outside (0, 10000] Hz, priority outside
  ///         [1, 99], invalid workspace or proxy parameters, stiffness above the device's max
  ///         stable stiffness, damping above its max damping, max force above its max force.
  ServoLoop(HapticDevice& device, SharedState& shared, const Clock& clock, const ServoConfig& config);
  ~ServoLoop();
  ServoLoop(const ServoLoop&) = delete;
  ServoLoop& operator=(const ServoLoop&) = delete;

  /// Starts the servo thread (mlockall and SCHED_FIFO as configured) and returns what it got.
  /// @throws hc::InputError if the device is Closed; hc::ConfigError if already running;
  ///         hc::ResourceError under realtime: enforce when SCHED_FIFO or mlockall is refused
  ///         (the message says which, the errno text, and what to check). Real-time: no.
  RealtimeReport start();
  /// Stops and joins the servo thread (no-op if not running); then writes a zero force and
  /// releases the memory lock taken by start().
  void stop() noexcept;
  bool running() const noexcept { return thread_.joinable() && !finished_.load(std::memory_order_acquire); }

  /// As fast as possible, on this thread: n ticks, advancing `clock` by one period after each.
  /// @throws hc::ConfigError if `clock` is not the clock given to the constructor or the
  ///         threaded loop is running. The ticks themselves do not allocate.
  void run_ticks(std::uint64_t n, ManualClock& clock);
  /// One tick at the clock's current time, on this thread. Real-time: yes.
  void tick() noexcept;
  /// What the threaded loop runs before each deadline tick (ServoConfig::warm_up_ns): a dry
  /// step_proxy on a copy of the state, towards the HIP extrapolated by its last step, on the
  /// surface in use; the result is dropped and nothing a tick reads changes (only
  /// stats().warm_ups counts it), so the ticks come out the same with or without it. Public so
  /// that a test can check that on a ManualClock; not while the threaded loop runs. No errors
  /// (without a surface or before the first HIP it only counts itself).
  /// Real-time: yes (one step_proxy). Source: this project (cache warming before a deadline,
  /// measured in bench/README, issue 16, "the servo tick after a sleep").
  void warm_up() noexcept;

  /// Trace rows are written to `rows` (caller-owned) one per tick until it is full.
  /// Call before start() / run_ticks(). Real-time: yes.
  void set_trace(std::span<TickRecord> rows) noexcept {
    trace_ = rows;
    trace_size_ = 0;
  }
  std::size_t trace_size() const noexcept { return trace_size_; }

  /// Statistics (read after stop(), or between run_ticks calls).
  const ServoStats& stats() const noexcept { return stats_; }
  /// Proxy state after the last tick (same rule).
  const ProxyState& proxy_state() const noexcept { return state_; }
  const ServoConfig& config() const noexcept { return config_; }
  std::int64_t period_ns() const noexcept { return period_ns_; }

 private:
  /// What one tick knows beyond the members: its time and the surface it renders.
  struct TickFrame {
    double t_s = 0.0;   ///< clock time of the tick [s]
    double dt_s = 0.0;  ///< time since the previous tick [s] (one period on the first tick)
    const HapticSurface* surface = nullptr;  ///< surface rendered this tick (null: free space)
    std::uint64_t surface_tag = 0;           ///< its publish_surface tag
  };

  /// One tick, read → update → write, then publish: the phases below, in this order. Each is
  /// noexcept and real-time safe (no allocation, lock, I/O or log).
  /// `lateness_ns`: wake-up − deadline, or kNoDeadline for a tick run early to adopt a surface.
  void tick_impl(std::int64_t lateness_ns) noexcept;
  static constexpr std::int64_t kNoDeadline = -1;
  /// Threaded loop: sleeps until `deadline_ns` (CLOCK_MONOTONIC), or, when a surface becomes
  /// adoptable, until max(now, earliest_wake_ns) if that comes first. @return true when it woke
  /// for a surface before the deadline.
  bool sleep_until_tick(std::int64_t deadline_ns, std::int64_t earliest_wake_ns) noexcept;
  /// Clock time and dt of this tick; remembers the time for the next one.
  TickFrame advance_time() noexcept;
  /// Applies at most max_commands_per_tick queued commands (apply()).
  void apply_commands() noexcept;
  /// Adopts a newly published surface (and its map, via switch_map(); without a map the
  /// force blend starts alone); writes the surface in use and its tag to `frame`.
  void adopt_surface(TickFrame& frame) noexcept;
  /// Reads the device. A status other than ok / end-of-data / fault counts a device error and
  /// faults the device. @return true when `reading` holds a position to render (a device in
  /// Fault still reads; its force is zero anyway).
  bool read_device(DeviceReading& reading) noexcept;
  /// Pushes a ButtonEvent when the buttons changed since the last good read.
  void publish_buttons(const DeviceReading& reading, const TickFrame& frame) noexcept;
  /// Steps the proxy with the HIP mapped to the grid frame (forces enabled only when Armed);
  /// a non-finite HIP faults the device. Without a reading: zero force, gate closed, ramp 0.
  void update_proxy(const DeviceReading& reading, bool have_reading, const TickFrame& frame) noexcept;
  /// The surface-switch blend (see switch_max_force_step_n) of the force about to be sent
  /// [N, device axes]: returns the force to send; while blending, also writes it back in grid
  /// axes to state_.force_n (WorkspaceMap::force_to_grid) for the snapshot and the trace.
  Eigen::Vector3d blend_switch(const Eigen::Vector3d& device_force_n, const TickFrame& frame) noexcept;
  /// Sends the force (HapticDevice::write clamps it and enforces the device state); an I/O
  /// error counts a device error and faults the device.
  void write_device(const Eigen::Vector3d& device_force_n) noexcept;
  /// Onset, release, and (every slide_event_every_ticks ticks in contact) slide or press events.
  void emit_contact_events(bool was_in_contact, const TickFrame& frame) noexcept;
  void push_contact_event(ContactEventType type, double speed_m_per_s, const TickFrame& frame) noexcept;
  /// Region under the proxy on the tick's surface, −1 without a surface or region.
  std::int32_t region_at_proxy(const TickFrame& frame) const noexcept;
  /// Writes this tick's Snapshot to the triple buffer and returns it.
  Snapshot publish_snapshot(const TickFrame& frame) noexcept;
  /// Compute-time and lateness histograms, overruns, and the shared counters.
  void record_stats(std::int64_t compute_ns, std::int64_t lateness_ns) noexcept;
  /// One trace row, while the caller's trace span has room.
  void record_trace(const Snapshot& snap, std::int64_t compute_ns) noexcept;
  void apply(const Command& command) noexcept;
  void update_grid_params() noexcept;
  /// A new workspace map at a tick boundary: the proxy keeps its device position, the grid
  /// parameters follow the scale, and the force blend starts (see switch_max_force_step_n).
  void switch_map(const WorkspaceMap& next) noexcept;
  void thread_main() noexcept;

  HapticDevice& device_;
  SharedState& shared_;
  const Clock& clock_;
  ServoConfig config_;
  ProxyParams grid_params_;
  std::int64_t period_ns_ = 1000000;
  ProxyState state_{};
  ServoStats stats_{};
  std::span<TickRecord> trace_{};
  std::size_t trace_size_ = 0;
  std::uint64_t tick_count_ = 0;
  std::int64_t prev_tick_ns_ = 0;
  bool have_prev_tick_ = false;
  // Surface switch: blend of the device force from blend_from_n_ (the last force sent before
  // the switch, device axes) to the newly rendered force; blend_ in [0, 1], active while < 1.
  Eigen::Vector3d last_device_force_n_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d blend_from_n_ = Eigen::Vector3d::Zero();
  double blend_ = 1.0;
  // Slide events: proxy position and time at the last one.
  Eigen::Vector3d slide_from_m_ = Eigen::Vector3d::Zero();
  double slide_from_s_ = 0.0;
  int ticks_since_slide_ = 0;
  std::uint32_t prev_buttons_ = 0;  // buttons at the previous good read (button events)
  double warm_sink_ = 0.0;  // where warm_up() drops its step
  Eigen::Vector3d hip_step_m_ = Eigen::Vector3d::Zero();  // the HIP's change over the last tick, grid frame [m]

  std::thread thread_;
  std::atomic<int> go_{0};  // 0 wait, 1 run, −1 abandon
  std::atomic<bool> stop_flag_{false};
  std::atomic<bool> finished_{false};
  bool stop_requested_ = false;  // a kStop command (servo thread only)
  bool threaded_ = false;        // set before the thread starts, cleared after it is joined
  bool memory_locked_ = false;   // mlockall taken by start(), released by stop()
  int cpu_latency_fd_ = -1;      // /dev/cpu_dma_latency held open by start(), closed by stop()
};

}  // namespace hc::haptics
