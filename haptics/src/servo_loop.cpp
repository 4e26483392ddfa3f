#include "hc/haptics/servo_loop.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <ctime>
#include <sstream>

#include <fcntl.h>
#include <linux/futex.h>
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/syscall.h>
#include <unistd.h>

namespace hc::haptics {
namespace {

constexpr std::int64_t kNsPerS = 1000000000LL;

timespec to_timespec(std::int64_t ns) noexcept {
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(ns / kNsPerS);
  ts.tv_nsec = static_cast<long>(ns % kNsPerS);
  return ts;
}

// A spin-wait hint (x86 PAUSE, AArch64 YIELD: less power, and on x86 no memory-order
// mis-speculation when the spin ends).
inline void cpu_relax() noexcept {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_ia32_pause();
#elif defined(__aarch64__)
  __asm__ volatile("yield");
#endif
}

/// Sleeps until CLOCK_MONOTONIC reaches `ns` (absolute; at once if already past). Real-time: yes.
void sleep_until_ns(std::int64_t ns) noexcept {
  const timespec ts = to_timespec(ns);
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

}  // namespace

RealtimeMode realtime_mode_from_string(std::string_view name) {
  if (name == "off") return RealtimeMode::kOff;
  if (name == "warn") return RealtimeMode::kWarn;
  if (name == "enforce") return RealtimeMode::kEnforce;
  throw ConfigError("unknown realtime mode '" + std::string(name) + "' (expected one of: off, warn, enforce)");
}

const char* to_string(RealtimeMode mode) noexcept {
  switch (mode) {
    case RealtimeMode::kOff: return "off";
    case RealtimeMode::kWarn: return "warn";
    case RealtimeMode::kEnforce: return "enforce";
  }
  return "unknown";
}

// ---------------------------------------------------------------- histogram

void LatencyHistogram::add(std::int64_t ns) noexcept {
  if (ns < 0) ns = 0;
  std::size_t bin = 0;
  if (ns < kFineBins) {
    bin = static_cast<std::size_t>(ns);
  } else if (ns < kFineBins + 64LL * kCoarseBins) {
    bin = static_cast<std::size_t>(kFineBins + (ns - kFineBins) / 64);
  } else {
    bin = kFineBins + kCoarseBins;
  }
  ++bins_[bin];
  ++count_;
  sum_ += ns;
  max_ = std::max(max_, ns);
}

void LatencyHistogram::reset() noexcept {
  bins_.fill(0);
  count_ = 0;
  sum_ = 0;
  max_ = 0;
}

double LatencyHistogram::percentile_ns(double q) const noexcept {
  if (count_ == 0) return 0.0;
  q = std::clamp(q, 0.0, 1.0);
  const double target = q * static_cast<double>(count_);
  std::uint64_t seen = 0;
  for (std::size_t b = 0; b < bins_.size(); ++b) {
    seen += bins_[b];
    if (bins_[b] != 0 && static_cast<double>(seen) >= target) {
      if (b < static_cast<std::size_t>(kFineBins)) return static_cast<double>(b);
      if (b < static_cast<std::size_t>(kFineBins + kCoarseBins)) {
        return std::min(static_cast<double>(max_),
                        static_cast<double>(kFineBins + (static_cast<std::int64_t>(b) - kFineBins + 1) * 64));
      }
      return static_cast<double>(max_);
    }
  }
  return static_cast<double>(max_);
}

// ---------------------------------------------------------------- loop

ServoLoop::ServoLoop(HapticDevice& device, SharedState& shared, const Clock& clock, const ServoConfig& config)
    : device_(device), shared_(shared), clock_(clock), config_(config) {
  const auto fail = [](const char* field, double value, const std::string& expected) {
    std::ostringstream s;
    s << "servo loop: " << field << " = " << value << ", expected " << expected;
    throw ConfigError(s.str());
  };
  if (!(config_.rate_hz > 0.0 && config_.rate_hz <= 10000.0)) fail("rate_hz", config_.rate_hz, "a rate in (0, 10000] Hz");
  if (config_.fifo_priority < 1 || config_.fifo_priority > 99) fail("fifo_priority", config_.fifo_priority, "[1, 99]");
  if (config_.slide_event_every_ticks < 1) fail("slide_event_every_ticks", config_.slide_event_every_ticks, ">= 1");
  if (config_.max_commands_per_tick < 1) fail("max_commands_per_tick", config_.max_commands_per_tick, ">= 1");
  if (!(std::isfinite(config_.switch_max_force_step_n) && config_.switch_max_force_step_n > 0.0)) {
    fail("switch_max_force_step_n", config_.switch_max_force_step_n, "a finite force > 0 N");
  }
  if (!(std::isfinite(config_.switch_ramp_s) && config_.switch_ramp_s >= 0.0)) {
    fail("switch_ramp_s", config_.switch_ramp_s, "a finite time >= 0 s");
  }
  if (!(config_.wake_on_surface_min_period >= 0.25 && config_.wake_on_surface_min_period <= 1.0)) {
    fail("wake_on_surface_min_period", config_.wake_on_surface_min_period, "[0.25, 1] periods");
  }
  if (!(config_.warm_up_ns >= 0 && static_cast<double>(config_.warm_up_ns) <= 0.25e9 / config_.rate_hz)) {
    fail("warm_up_ns", static_cast<double>(config_.warm_up_ns), "[0, a quarter of the period] ns");
  }
  if (!config_.workspace.valid()) fail("workspace.scale", config_.workspace.scale, "finite > 0 with a finite origin and rotation");
  validate_proxy_params(config_.proxy);
  const DeviceInfo& info = device_.info();
  if (config_.proxy.stiffness_n_per_m > info.max_stable_stiffness_n_per_m) {
    fail("proxy.stiffness_n_per_m", config_.proxy.stiffness_n_per_m,
         "at most the device's max stable stiffness " + std::to_string(info.max_stable_stiffness_n_per_m) + " N/m");
  }
  if (config_.proxy.damping_n_s_per_m > info.max_damping_n_s_per_m) {
    fail("proxy.damping_n_s_per_m", config_.proxy.damping_n_s_per_m,
         "at most the device's max damping " + std::to_string(info.max_damping_n_s_per_m) + " N s/m");
  }
  if (config_.proxy.max_force_n > info.max_force_n) {
    fail("proxy.max_force_n", config_.proxy.max_force_n,
         "at most the device's max force " + std::to_string(info.max_force_n) + " N");
  }
  period_ns_ = std::max<std::int64_t>(1, std::llround(1e9 / config_.rate_hz));
  update_grid_params();
}

ServoLoop::~ServoLoop() { stop(); }

void ServoLoop::update_grid_params() noexcept {
  grid_params_ = config_.proxy;
  grid_params_.stiffness_n_per_m = config_.workspace.stiffness_to_grid(config_.proxy.stiffness_n_per_m);
  grid_params_.damping_n_s_per_m = config_.workspace.stiffness_to_grid(config_.proxy.damping_n_s_per_m);
}

void ServoLoop::switch_map(const WorkspaceMap& next) noexcept {
  // The proxy keeps its DEVICE position (so the spring to the hand, and the force, carry over);
  // in grid terms it moves old map → device → new map.
  const WorkspaceMap old = config_.workspace;
  if (state_.initialized) {
    state_.proxy_m = next.to_grid(old.to_device(state_.proxy_m));
    state_.hip_m = next.to_grid(old.to_device(state_.hip_m));
    slide_from_m_ = next.to_grid(old.to_device(slide_from_m_));
  }
  config_.workspace = next;
  hip_step_m_.setZero();  // a step in the old map's frame
  update_grid_params();
  // Blend from the force sent last; ended at once in the tick if the new force is close to it.
  blend_from_n_ = last_device_force_n_;
  blend_ = 0.0;
}

void ServoLoop::apply(const Command& c) noexcept {
  const DeviceInfo& info = device_.info();
  bool ok = true;
  switch (c.type) {
    case CommandType::kArm: ok = device_.arm(); break;
    case CommandType::kDisarm: device_.disarm(); break;
    case CommandType::kResetFault: ok = device_.reset_fault(); break;
    case CommandType::kSetStiffness:
      ok = std::isfinite(c.a);
      if (ok) config_.proxy.stiffness_n_per_m = std::clamp(c.a, 0.0, info.max_stable_stiffness_n_per_m);
      break;
    case CommandType::kSetDamping:
      ok = std::isfinite(c.a);
      if (ok) config_.proxy.damping_n_s_per_m = std::clamp(c.a, 0.0, info.max_damping_n_s_per_m);
      break;
    case CommandType::kSetMaxForce:
      ok = std::isfinite(c.a) && c.a > 0.0;
      if (ok) config_.proxy.max_force_n = std::min(c.a, info.max_force_n);
      break;
    case CommandType::kSetRho:
      ok = std::isfinite(c.a);
      if (ok) config_.proxy.rho = std::clamp(c.a, 0.001, 1.0);
      break;
    case CommandType::kSetFrictionEnabled: config_.proxy.friction_enabled = c.a != 0.0; break;
    case CommandType::kSetWorkspace: {
      WorkspaceMap m;
      m.origin_m = Eigen::Vector3d(c.a, c.b, c.c);
      m.scale = c.d;
      m.rotation_rad = c.e;
      ok = m.valid();
      if (ok) switch_map(m);  // the proxy keeps its device position; the force is blended
      break;
    }
    case CommandType::kStop: stop_requested_ = true; break;
  }
  if (ok) {
    update_grid_params();
    shared_.counters.commands_applied.fetch_add(1, std::memory_order_relaxed);
  } else {
    shared_.counters.commands_rejected.fetch_add(1, std::memory_order_relaxed);
  }
  shared_.log({tick_count_, ok ? ServoLogEntry::Kind::kCommand : ServoLogEntry::Kind::kRejected, c, 0});
}

void ServoLoop::tick() noexcept { tick_impl(0); }

// One tick: read → update → write, then publish. Every phase below is noexcept and free of
// allocation, locks and I/O; the member state they share is listed in servo_loop.hpp.
void ServoLoop::tick_impl(std::int64_t lateness_ns) noexcept {
  const std::int64_t t_start = monotonic_now_ns();
  TickFrame frame = advance_time();
  apply_commands();
  adopt_surface(frame);
  // Read.
  DeviceReading reading;
  const bool have_reading = read_device(reading);
  if (have_reading) publish_buttons(reading, frame);
  // Update: proxy and force in the grid frame, then the switch blend in device axes.
  const bool was_in_contact = state_.in_contact;
  update_proxy(reading, have_reading, frame);
  const Eigen::Vector3d device_force = blend_switch(config_.workspace.force_to_device(state_.force_n), frame);
  // Write.
  write_device(device_force);
  // Publish.
  emit_contact_events(was_in_contact, frame);
  const Snapshot snap = publish_snapshot(frame);
  const std::int64_t compute_ns = monotonic_now_ns() - t_start;
  record_stats(compute_ns, lateness_ns);
  record_trace(snap, compute_ns);
  ++tick_count_;
}

ServoLoop::TickFrame ServoLoop::advance_time() noexcept {
  const std::int64_t now = clock_.now_ns();
  TickFrame frame;
  frame.dt_s = have_prev_tick_ ? static_cast<double>(now - prev_tick_ns_) * 1e-9
                               : static_cast<double>(period_ns_) * 1e-9;
  frame.t_s = static_cast<double>(now) * 1e-9;
  prev_tick_ns_ = now;
  have_prev_tick_ = true;
  return frame;
}

void ServoLoop::apply_commands() noexcept {
  for (int k = 0; k < config_.max_commands_per_tick; ++k) {
    Command c;
    if (!shared_.commands.try_pop(c)) break;
    apply(c);
  }
}

void ServoLoop::adopt_surface(TickFrame& frame) noexcept {
  const SharedState::Adoption adoption = shared_.adopt();
  frame.surface = adoption.surface;
  frame.surface_tag = adoption.tag;
  if (!adoption.changed) return;
  shared_.log({tick_count_, ServoLogEntry::Kind::kSurface, Command{}, adoption.tag});
  // Surface and map switch together (the map, when published with the surface).
  if (adoption.map != nullptr) {
    switch_map(*adoption.map);
  } else {
    // Blend from the force sent last; ended at once in blend_switch if the new force is close to it.
    blend_from_n_ = last_device_force_n_;
    blend_ = 0.0;
  }
}

bool ServoLoop::read_device(DeviceReading& reading) noexcept {
  const DeviceStatus rs = device_.read(reading);
  if (rs == DeviceStatus::kNoData) return false;  // nothing to render yet: zero force, gate closed
  const bool read_ok = rs == DeviceStatus::kOk || rs == DeviceStatus::kEndOfData;
  if (!read_ok && rs != DeviceStatus::kFault) {
    shared_.counters.device_errors.fetch_add(1, std::memory_order_relaxed);
    // Once: fault() also sends a zero force, which a device in Fault gets from write() anyway.
    if (device_.state() != DeviceState::kFault) device_.fault();
  }
  return read_ok || rs == DeviceStatus::kFault;  // a device in Fault still reads
}

void ServoLoop::publish_buttons(const DeviceReading& reading, const TickFrame& frame) noexcept {
  if (reading.buttons == prev_buttons_) return;
  ButtonEvent b;
  b.tick = tick_count_;
  b.t_s = frame.t_s;
  b.buttons = reading.buttons;
  b.pressed = reading.buttons & ~prev_buttons_;
  b.released = prev_buttons_ & ~reading.buttons;
  prev_buttons_ = reading.buttons;
  if (!shared_.button_events.try_push(b)) shared_.counters.events_dropped.fetch_add(1, std::memory_order_relaxed);
}

void ServoLoop::update_proxy(const DeviceReading& reading, bool have_reading, const TickFrame& frame) noexcept {
  if (!have_reading) {
    hip_step_m_.setZero();
    state_.force_n.setZero();
    state_.gate_open = false;
    state_.ramp = 0.0;
    return;
  }
  const HipInput in{config_.workspace.to_grid(reading.position_m), frame.dt_s,
                    device_.state() == DeviceState::kArmed};
  const bool had_hip = state_.initialized;
  const Eigen::Vector3d hip_before = state_.hip_m;
  state_ = step_proxy(state_, in, frame.surface, grid_params_);
  hip_step_m_ = had_hip && state_.initialized ? Eigen::Vector3d(state_.hip_m - hip_before) : Eigen::Vector3d::Zero();
  if (state_.status == ProxyStatus::kNonFiniteInput) {
    shared_.counters.nonfinite_inputs.fetch_add(1, std::memory_order_relaxed);
    device_.fault();
  }
}

Eigen::Vector3d ServoLoop::blend_switch(const Eigen::Vector3d& device_force, const TickFrame& frame) noexcept {
  if (!(blend_ < 1.0)) return device_force;
  // After a surface switch: move from the last force sent towards the new one by at most half
  // the configured step per tick (plus the new force's own change), over switch_ramp_s or more.
  const Eigen::Vector3d diff = device_force - blend_from_n_;
  const double gap = diff.norm();
  if (blend_ == 0.0 && !(gap > config_.switch_max_force_step_n)) {  // first tick of the switch
    blend_ = 1.0;  // the switch causes no step above the limit: nothing to blend
    return device_force;
  }
  const double step_s = frame.dt_s > 0.0 ? frame.dt_s : static_cast<double>(period_ns_) * 1e-9;
  double inc = config_.switch_ramp_s > 0.0 ? step_s / config_.switch_ramp_s : 1.0;
  if (gap > 0.0) inc = std::min(inc, 0.5 * config_.switch_max_force_step_n / gap);
  blend_ = std::min(1.0, blend_ + inc);
  Eigen::Vector3d blended = blend_from_n_ + blend_ * diff;
  if (!blended.allFinite()) blended.setZero();
  state_.force_n = config_.workspace.force_to_grid(blended);  // grid axes, for snapshot and trace
  return blended;
}

void ServoLoop::write_device(const Eigen::Vector3d& device_force) noexcept {
  const DeviceStatus ws = device_.write(device_force);
  last_device_force_n_ = device_.last_force_n();
  if (ws == DeviceStatus::kIoError) {
    shared_.counters.device_errors.fetch_add(1, std::memory_order_relaxed);
    device_.fault();
  }
}

std::int32_t ServoLoop::region_at_proxy(const TickFrame& frame) const noexcept {
  return frame.surface != nullptr ? frame.surface->region_id(state_.proxy_m.x(), state_.proxy_m.y()) : -1;
}

void ServoLoop::push_contact_event(ContactEventType type, double speed_m_per_s, const TickFrame& frame) noexcept {
  ContactEvent e;
  e.type = type;
  e.region_id = region_at_proxy(frame);
  e.tick = tick_count_;
  e.t_s = frame.t_s;
  e.position_m = Vec3::of(state_.proxy_m);
  e.force_n = Vec3::of(state_.force_n);
  e.speed_m_per_s = speed_m_per_s;
  if (!shared_.events.try_push(e)) shared_.counters.events_dropped.fetch_add(1, std::memory_order_relaxed);
}

void ServoLoop::emit_contact_events(bool was_in_contact, const TickFrame& frame) noexcept {
  const double t_s = frame.t_s;
  if (!was_in_contact && state_.in_contact) {
    push_contact_event(ContactEventType::kOnset, 0.0, frame);
    slide_from_m_ = state_.proxy_m;
    slide_from_s_ = t_s;
    ticks_since_slide_ = 0;
  } else if (was_in_contact && !state_.in_contact) {
    push_contact_event(ContactEventType::kRelease, 0.0, frame);
  } else if (state_.in_contact && ++ticks_since_slide_ >= config_.slide_event_every_ticks) {
    const double moved = (state_.proxy_m - slide_from_m_).norm();
    const double elapsed = t_s - slide_from_s_;
    if (!state_.sticking && moved > 0.0 && elapsed > 0.0) {
      push_contact_event(ContactEventType::kSlide, moved / elapsed, frame);
    } else {
      push_contact_event(ContactEventType::kPress, 0.0, frame);
    }
    slide_from_m_ = state_.proxy_m;
    slide_from_s_ = t_s;
    ticks_since_slide_ = 0;
  }
}

Snapshot ServoLoop::publish_snapshot(const TickFrame& frame) noexcept {
  Snapshot snap;
  snap.tick = tick_count_;
  snap.surface_tag = frame.surface_tag;
  snap.t_s = frame.t_s;
  snap.hip_m = Vec3::of(state_.hip_m);
  snap.proxy_m = Vec3::of(state_.proxy_m);
  snap.force_n = Vec3::of(state_.force_n);
  snap.device_force_n = Vec3::of(device_.last_force_n());  // zero if the write faulted the device
  snap.ramp = state_.ramp;
  snap.mu_d = static_cast<float>(state_.mu_d);
  snap.mu_s = static_cast<float>(state_.mu_s);
  snap.beta_rad = state_.in_contact ? static_cast<float>(state_.beta_rad()) : 0.0F;
  snap.region_id = state_.in_contact ? region_at_proxy(frame) : -1;
  snap.iterations = static_cast<std::int16_t>(state_.iterations);
  snap.in_contact = state_.in_contact;
  snap.sticking = state_.sticking;
  snap.gate_open = state_.gate_open;
  snap.saturated = state_.saturated;
  snap.device_state = static_cast<std::uint8_t>(device_.state());
  snap.proxy_status = static_cast<std::uint8_t>(state_.status);
  snap.buttons = prev_buttons_;
  shared_.snapshots.write(snap);
  return snap;
}

void ServoLoop::record_stats(std::int64_t compute_ns, std::int64_t lateness_ns) noexcept {
  ServoCounters& counters = shared_.counters;
  stats_.compute.add(compute_ns);
  ++stats_.ticks;
  if (threaded_ && lateness_ns != kNoDeadline) stats_.lateness.add(lateness_ns);
  if (!threaded_ && compute_ns > period_ns_) {
    ++stats_.overruns;
    counters.overruns.fetch_add(1, std::memory_order_relaxed);
  }
  counters.ticks.fetch_add(1, std::memory_order_relaxed);
  if (compute_ns > counters.worst_compute_ns.load(std::memory_order_relaxed)) {
    counters.worst_compute_ns.store(compute_ns, std::memory_order_relaxed);
  }
  if (lateness_ns > counters.worst_lateness_ns.load(std::memory_order_relaxed)) {
    counters.worst_lateness_ns.store(lateness_ns, std::memory_order_relaxed);
  }
}

void ServoLoop::record_trace(const Snapshot& snap, std::int64_t compute_ns) noexcept {
  if (trace_size_ >= trace_.size()) return;
  TickRecord& r = trace_[trace_size_++];
  r.t_s = snap.t_s;
  r.hip_m = snap.hip_m;
  r.proxy_m = snap.proxy_m;
  r.force_n = snap.force_n;
  r.mu_d = snap.mu_d;
  r.mu_s = snap.mu_s;
  r.beta_rad = snap.beta_rad;
  r.compute_ns = static_cast<std::int32_t>(std::min<std::int64_t>(compute_ns, 2000000000LL));
  r.iterations = snap.iterations;
  r.in_contact = snap.in_contact;
  r.sticking = snap.sticking;
  r.device_state = snap.device_state;
  r.surface_tag = static_cast<std::uint32_t>(snap.surface_tag);
}

void ServoLoop::run_ticks(std::uint64_t n, ManualClock& clock) {
  if (&clock != &clock_) {
    throw ConfigError("servo loop: run_ticks needs the ManualClock the loop was constructed with");
  }
  if (threaded_) throw ConfigError("servo loop: run_ticks while the servo thread runs");
  for (std::uint64_t k = 0; k < n && !stop_requested_; ++k) {
    tick_impl(0);
    clock.advance_ns(period_ns_);
  }
}

RealtimeReport ServoLoop::start() {
  if (thread_.joinable()) throw ConfigError("servo loop: start() while already running");
  if (device_.state() == DeviceState::kClosed) {
    throw InputError("servo loop: device '" + device_.info().name + "' is closed; open() it before start()");
  }
  RealtimeReport report;
  report.mode = config_.realtime;
  std::string detail;
  if (config_.realtime != RealtimeMode::kOff) {
    if (mlockall(MCL_CURRENT | MCL_FUTURE) == 0) {
      report.memory_locked = true;
    } else {
      detail += std::string("mlockall refused: ") + std::strerror(errno) +
                " (check the memlock limit: ulimit -l, or CAP_IPC_LOCK)\n";
    }
  }
  go_.store(0, std::memory_order_release);
  stop_flag_.store(false, std::memory_order_release);
  finished_.store(false, std::memory_order_release);
  stop_requested_ = false;
  threaded_ = true;  // written before the thread exists: the thread sees it
  thread_ = std::thread([this] { thread_main(); });
  if (config_.realtime != RealtimeMode::kOff) {
    sched_param sp{};
    sp.sched_priority = config_.fifo_priority;
    const int rc = pthread_setschedparam(thread_.native_handle(), SCHED_FIFO, &sp);
    if (rc == 0) {
      report.fifo_granted = true;
      report.priority = config_.fifo_priority;
    } else {
      detail += "SCHED_FIFO priority " + std::to_string(config_.fifo_priority) + " refused: " +
                std::strerror(rc) + " (check CAP_SYS_NICE or the rtprio limit: ulimit -r, /etc/security/limits.conf)\n";
    }
  }
  const bool refused = config_.realtime == RealtimeMode::kEnforce && !(report.fifo_granted && report.memory_locked);
  if (config_.realtime != RealtimeMode::kOff && !refused) {
    // PM QoS: the request holds while the file stays open (written as a binary s32 [µs]).
    const int fd = open("/dev/cpu_dma_latency", O_WRONLY | O_CLOEXEC);
    const std::int32_t zero_us = 0;
    const ssize_t written = fd >= 0 ? write(fd, &zero_us, sizeof zero_us) : -1;
    if (written == static_cast<ssize_t>(sizeof zero_us)) {
      cpu_latency_fd_ = fd;
      report.cpu_latency_pinned = true;
    } else {
      const std::string why = written >= 0 ? std::string("short write") : std::string(std::strerror(errno));
      detail += "CPU wake-up latency request (/dev/cpu_dma_latency) refused: " + why +
                " (advisory; needs write access to /dev/cpu_dma_latency)\n";
      if (fd >= 0) close(fd);
    }
  }
  if (!detail.empty()) detail.pop_back();
  report.detail = detail;
  memory_locked_ = report.memory_locked;
  if (refused) {
    go_.store(-1, std::memory_order_release);
    thread_.join();
    threaded_ = false;
    if (memory_locked_) munlockall();
    memory_locked_ = false;
    throw ResourceError("servo loop: realtime: enforce, but " + detail);
  }
  go_.store(1, std::memory_order_release);
  return report;
}

void ServoLoop::thread_main() noexcept {
  while (go_.load(std::memory_order_acquire) == 0) std::this_thread::yield();
  if (go_.load(std::memory_order_acquire) < 0) {
    finished_.store(true, std::memory_order_release);
    return;
  }
  const bool wake = config_.wake_on_surface_min_period < 1.0;
  const auto min_gap_ns = static_cast<std::int64_t>(config_.wake_on_surface_min_period * static_cast<double>(period_ns_));
  std::int64_t deadline = monotonic_now_ns();
  std::int64_t last_tick = deadline;  // the start counts as a tick for the wake's minimum gap
  bool last_early = false;
  const std::int64_t warm_ns = config_.warm_up_ns;
  while (!stop_flag_.load(std::memory_order_acquire) && !stop_requested_) {
    deadline += period_ns_;
    bool early = false;
    // Asleep until warm_ns before the deadline (a surface published before then may wake it
    // for an early tick), then the caches warmed and a spin to the deadline.
    if (wake && !last_early) {  // at most one early tick between two deadline ticks
      early = sleep_until_tick(deadline - warm_ns, last_tick + min_gap_ns);
    } else {
      sleep_until_ns(deadline - warm_ns);
    }
    const std::int64_t woke_ns = monotonic_now_ns();
    std::int64_t wake_ns = woke_ns;  // when the tick starts
    // Also when the wake came after the deadline: the tick starts later by the step, but its
    // read → write time is what the warm-up shortens.
    if (!early && warm_ns > 0) {
      warm_up();
      while ((wake_ns = monotonic_now_ns()) < deadline) cpu_relax();
    }
    // Lateness: the wake-up against the time it was asked for (the scheduler's jitter), as
    // without the warm-up, not the spin's end against the deadline.
    tick_impl(early ? kNoDeadline : woke_ns - (deadline - warm_ns));
    last_tick = wake_ns;
    last_early = early;
    if (early) {
      ++stats_.surface_wake_ticks;
      deadline = wake_ns;  // the next tick a whole period after this one
    }
    const std::int64_t end = monotonic_now_ns();
    if (end > deadline + period_ns_) {
      ++stats_.overruns;
      shared_.counters.overruns.fetch_add(1, std::memory_order_relaxed);
      // Skip the deadlines already missed instead of running late ticks back to back.
      deadline += (end - deadline) / period_ns_ * period_ns_;
    }
  }
  finished_.store(true, std::memory_order_release);
}

void ServoLoop::warm_up() noexcept {
  ++stats_.warm_ups;
  // The surface the last tick adopted: only this thread adopts, and the producer frees a
  // surface only after the servo has retired it.
  const HapticSurface* surface = shared_.current_surface();
  if (surface == nullptr || !state_.initialized) return;
  // The HIP where it will be if it keeps its last step: the real step then walks the same cells.
  const HipInput in{state_.hip_m + hip_step_m_, static_cast<double>(period_ns_) * 1e-9, device_.state() == DeviceState::kArmed};
  warm_sink_ = step_proxy(state_, in, surface, grid_params_).proxy_m.z();
}

bool ServoLoop::sleep_until_tick(std::int64_t deadline_ns, std::int64_t earliest_wake_ns) noexcept {
  // The futex word changes with every publication; reading it before testing for a surface
  // means a publication after the test makes FUTEX_WAIT return at once (no lost wake-up).
  auto* word = const_cast<std::uint32_t*>(reinterpret_cast<const std::uint32_t*>(&shared_.surface_signal()));
  while (true) {
    const std::uint32_t seen = shared_.surface_signal().load(std::memory_order_acquire);
    if (shared_.surface_adoptable() && earliest_wake_ns < deadline_ns) {
      sleep_until_ns(earliest_wake_ns);
      return monotonic_now_ns() < deadline_ns;
    }
    if (monotonic_now_ns() >= deadline_ns) return false;
    // FUTEX_WAIT_BITSET takes an absolute timeout on CLOCK_MONOTONIC (futex(2)); it returns on
    // a wake, a changed word (EAGAIN), a signal (EINTR) or the timeout (ETIMEDOUT).
    const timespec ts = to_timespec(deadline_ns);
    if (syscall(SYS_futex, word, FUTEX_WAIT_BITSET_PRIVATE, seen, &ts, nullptr, FUTEX_BITSET_MATCH_ANY) != 0 &&
        errno != EAGAIN && errno != EINTR && errno != ETIMEDOUT) {
      sleep_until_ns(deadline_ns);  // no futex (a sandbox refusing the call): as without the wake
      return false;
    }
  }
}

void ServoLoop::stop() noexcept {
  if (!thread_.joinable()) return;
  stop_flag_.store(true, std::memory_order_release);
  thread_.join();
  threaded_ = false;
  (void)device_.write(Eigen::Vector3d::Zero());
  if (memory_locked_) munlockall();  // the lock was taken for the servo thread only
  memory_locked_ = false;
  if (cpu_latency_fd_ >= 0) close(cpu_latency_fd_);  // ends the PM QoS request
  cpu_latency_fd_ = -1;
}

}  // namespace hc::haptics
