#pragma once
/// @file recording.hpp
/// Recorded device sessions (issue "Ecosystem"): `--record FILE` writes what a device reported
/// and what it was sent, tick by tick; `--device replay:FILE` plays the positions and buttons
/// back through the same servo path, one recorded sample per servo read, so a replay on the
/// same scene with the same settings renders the same forces.
///
/// File format (docs/recording.md), text, one servo tick per line, numbers as %.17g so that
/// every double reads back bit for bit; version 2 adds the servo rate and the event lines:
///
///     # hapticloud recording 2
///     # device: <name>; nominal_rate_hz: <rate>; max_force_n: <cap>; servo_rate_hz: <rate>
///     tick,time_ns,x_m,y_m,z_m,buttons,fx_n,fy_n,fz_n,status
///     0,1000000,0.0012,-0.0031,0.0207,0,0,0,0,0
///     @command,<tick>,<name>,<a>,<b>,<c>,<d>,<e>
///     @surface,<tick>,<tag>
///     @session,<tick>,<action>
///
/// tick: servo read index from 0; time_ns: the device's sample time [ns]; x, y, z: end-effector
/// position [m], device frame; buttons: bit mask; fx, fy, fz: the force sent after that read
/// [N], device frame (after the device's clamp; nan when no force followed the read); status:
/// the read's DeviceStatus (0 ok, 3 io_error, ...), replayed as it was. Event lines (anywhere
/// after the column line, in the order they were written): a servo Command applied
/// (`@command`) or rejected (`@rejected`) at the start of servo tick <tick> with its name
/// (to_string(CommandType)) and five arguments; a surface adopted at tick <tick> with its
/// publish tag (`@surface`); a session action (`@session`: `explore --script` syntax without
/// the frame, e.g. "window 0 49 49", "texture off") issued while the servo was about to run
/// tick <tick>.
/// Version 1 files (no servo rate, no events) still read.
///
/// Exactness: the servo loop's tick interval comes from its clock (force ramp, damping, switch
/// blending use it). On the simulated clock at the same rate (touch without --realtime) a
/// replay renders the recorded forces exactly; on a real clock (touch --realtime, explore) the
/// intervals jitter, so the forces agree only as closely as the two runs' timing does.
///
/// Real-time: RecordingDevice's read/write only copy into a lock-free ring (no allocation, no
/// I/O); a writer thread drains it (and the servo log) to the file every 20 ms. A full ring
/// drops samples and counts them (dropped()); a recording with drops says so and is not kept.

#include "hc/haptics/device.hpp"
#include "hc/haptics/clock.hpp"
#include "hc/haptics/shared_state.hpp"
#include "hc/haptics/spsc_ring.hpp"

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

namespace hc::haptics {

/// One recorded servo tick.
struct RecordedSample {
  std::uint64_t tick = 0;
  std::int64_t time_ns = 0;
  double position_m[3] = {0, 0, 0};  ///< device frame [m]
  std::uint32_t buttons = 0;
  double force_n[3] = {0, 0, 0};     ///< sent after this read [N], device frame; NaN if none
  std::uint8_t status = 0;           ///< the read's DeviceStatus
};

/// One event line of a recording (see the file format above).
struct RecordedEvent {
  enum class Kind : std::uint8_t { kCommand = 0, kRejected, kSurface, kSession };
  std::uint64_t tick = 0;        ///< servo tick index (the sample of that tick has the same index)
  Kind kind = Kind::kCommand;
  Command command{};             ///< kCommand, kRejected
  std::uint64_t surface_tag = 0; ///< kSurface
  std::string action;            ///< kSession
};

/// A whole recording as read back.
struct Recording {
  int version = 1;
  double servo_rate_hz = 0.0;    ///< the servo loop's rate [Hz]; 0 when not recorded (version 1)
  double max_force_n = 0.0;      ///< the recorded device's force cap [N]; 0 when not stated
  std::vector<RecordedSample> samples;
  std::vector<RecordedEvent> events;  ///< in file order
};

/// Wraps a device and records every read and the force sent after it (see the file format
/// above). The wrapper is the device the servo loop sees: its state (Open, Armed, Fault) is
/// mirrored onto the inner device on every write, so the inner device renders what the servo
/// sends; info() is the inner device's.
/// The file is written to `FILE.part-<random>` beside it. close() after keep_on_close() puts
/// it in place with link(2) (an existing FILE is never replaced; where the file system has no
/// hard links the .part file is kept and error() names it); a close without it (an error path,
/// the destructor) removes it, so a failed or interrupted session leaves no FILE.
/// Faults: a fault of the inner device is reported by the next read or write as kIoError, so
/// the servo loop faults this device; a fault of this device is copied onto the inner one; an
/// explicit reset_fault() of this device resets the inner one at the next write.
class RecordingDevice final : public HapticDevice {
 public:
  /// `inner` must outlive this object. Nothing is opened here.
  RecordingDevice(HapticDevice& inner, std::filesystem::path file);
  ~RecordingDevice() override;

  /// Samples written so far (after close(): all of them).
  std::uint64_t written() const noexcept { return written_.load(std::memory_order_relaxed); }
  /// Samples lost because the ring was full (the writer fell behind by more than 16 384 ticks).
  std::uint64_t dropped() const noexcept { return dropped_.load(std::memory_order_relaxed); }
  /// Empty after a successful close(); otherwise why the file is missing or incomplete.
  const std::string& error() const noexcept { return error_; }
  /// The session ended as it should: the next close() puts FILE in place.
  void keep_on_close() noexcept { keep_ = true; }
  /// Before open(): also record what the servo loop driving this device applies and adopts
  /// (SharedState::enable_servo_log; `shared` must outlive this object) and its rate [Hz, > 0]
  /// in the header. A servo log that overflowed while this device was open makes the recording
  /// not kept, like lost ticks.
  /// @throws hc::ConfigError for a rate not > 0 or not finite, or when the device is open
  ///         already (the writer thread reads what watch() sets).
  void watch(SharedState& shared, double servo_rate_hz);
  /// A session action (`explore --script` syntax without the frame, one line), recorded with the
  /// servo tick about to run (SharedState::counters.ticks). Call it from the thread that opens
  /// and closes this device (explore: the UI thread), between open() and close(); ignored before
  /// watch() or when not open.
  void note(const std::string& action);

 protected:
  /// Opens the inner device, then creates the temporary file and starts the writer thread.
  /// @throws hc::InputError naming FILE when it exists or its folder cannot take the file; what
  ///         the inner device's open() throws.
  void do_open() override;
  /// Stops the writer, closes the inner device and puts FILE in place (error() says otherwise).
  void do_close() noexcept override;
  DeviceStatus do_read(DeviceReading& out) noexcept override;
  DeviceStatus do_write(const Eigen::Vector3d& force_n) noexcept override;

 private:
  void writer_loop();
  void push(const RecordedSample& s) noexcept;

  HapticDevice& inner_;
  std::filesystem::path file_, tmp_;
  std::unique_ptr<SpscRing<RecordedSample, 16384>> ring_;
  std::thread writer_;
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> written_{0}, dropped_{0};
  RecordedSample pending_{};
  bool has_pending_ = false;
  std::uint64_t next_tick_ = 0;
  std::string error_;
  bool keep_ = false;
  bool inner_faulted_by_mirror_ = false;  // the inner Fault came from this device's (servo thread)
  bool write_failed_ = false;  // writer thread only, read after join
  SharedState* shared_ = nullptr;
  double servo_rate_hz_ = 0.0;
  std::uint64_t log_dropped_at_open_ = 0;  // the servo log's drop count when this recording opened
  std::mutex notes_mutex_;
  std::vector<std::pair<std::uint64_t, std::string>> notes_;  // guarded by notes_mutex_
};

/// Reads a recording, version 1 or 2. @throws hc::InputError naming the file and line for a
/// missing file, a first line that is not "# hapticloud recording 1" or "... 2", a sample line
/// that is not ten numbers, ticks that do not count up from 0 by one, an event line that does
/// not parse (an unknown command name, a wrong count of numbers), or no samples.
Recording read_recording_file(const std::filesystem::path& file);
/// The samples of read_recording_file(file). @throws as it.
std::vector<RecordedSample> read_recording(const std::filesystem::path& file);

/// Plays a recording back: the k-th read() returns sample k's position, buttons and status,
/// its time shifted so that the first sample is at the clock's time of the first read; after
/// the last sample the last position is held and read() returns kEndOfData. Forces written are
/// kept (last_force_n()). info(): as given, with max_force_n taken from the recording's header
/// when it states one (so the replay clamps as the recorded device did).
class TickReplayDevice final : public HapticDevice {
 public:
  TickReplayDevice(const Clock& clock, std::filesystem::path file, DeviceInfo info);
  /// The same from a recording already read (read_recording_file); open() then reads nothing.
  /// max_force_n from the recording when it states one.
  /// @throws hc::InputError when the recording holds no samples.
  TickReplayDevice(const Clock& clock, Recording recording, DeviceInfo info);
  std::size_t sample_count() const noexcept { return samples_.size(); }
  /// After open(): the recording's header values and events (its samples are held apart:
  /// `recording().samples` is empty).
  const Recording& recording() const noexcept { return recording_; }

 protected:
  /// Reads the file (read_recording_file), unless constructed from a Recording.
  /// @throws as read_recording_file.
  void do_open() override;
  void do_close() noexcept override {}
  DeviceStatus do_read(DeviceReading& out) noexcept override;
  DeviceStatus do_write(const Eigen::Vector3d&) noexcept override { return DeviceStatus::kOk; }

 private:
  const Clock& clock_;
  std::filesystem::path file_;
  Recording recording_;
  bool given_ = false;  // constructed from a Recording: recording_ holds it, samples_ too
  std::vector<RecordedSample> samples_;
  std::size_t next_ = 0;
  std::int64_t start_ns_ = 0;
};

}  // namespace hc::haptics
