#pragma once
/// @file engine.hpp
/// The live contact-sound player: its own thread drains contact events (from the servo loop's
/// ring or from submit()), feeds the shared Mixer and streams small buffers to OpenAL Soft.
/// The servo loop never waits for it (the ring drops and counts when full). OpenAL stays inside
/// the .cpp (pimpl).
///
/// Typical use (e.g. `hapticloud explore`):
///   auto scene = hc::audio::build_audio_scene(config, {&grid, &texture});  // may throw
///   hc::audio::AudioEngine audio(scene);
///   const auto report = audio.start(shared);   // never throws for a missing sound device
///   if (!report.device_open) log(report.detail);
///   audio.set_volume(0.8);  ...  audio.stop();

#include "hc/audio/mixer.hpp"
#include "hc/haptics/shared_state.hpp"

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace hc::audio {

/// Output options of the live engine.
struct EngineOptions {
  int buffer_frames = 64;        ///< frames per streamed buffer [16, 4096] (64 = 1.33 ms at 48 kHz)
  int queued_buffers = 3;        ///< buffers kept queued at OpenAL [2, 16] (64 × 3: 4 ms queued)
  int device_refresh_hz = 500;   ///< ALC_REFRESH asked of the device (its mixing period = 1/this)
  std::string device_name;       ///< OpenAL device name; empty = the default device
  /// Use OpenAL Soft's loopback device (ALC_SOFT_loopback) paced by the engine's own clock
  /// instead of a sound card: the full OpenAL path without a device (benchmarks, tests).
  bool loopback = false;
};

/// What start() obtained.
struct EngineReport {
  bool device_open = false;       ///< false: no sound device; events are drained and dropped
  std::string device;             ///< OpenAL device name (or "loopback")
  std::string detail;             ///< one line: why there is no sound, or the output format
  double queue_latency_s = 0.0;   ///< audio queued ahead of a new sound: queued_buffers × buffer
  double device_latency_s = 0.0;  ///< the device's own latency when OpenAL reports it, else 0
};

/// Running counters (any thread; relaxed snapshots).
struct EngineStats {
  std::uint64_t events = 0;          ///< contact events handled
  std::uint64_t onsets_played = 0;
  std::uint64_t buffers = 0;         ///< buffers streamed
  std::uint64_t underruns = 0;       ///< the OpenAL source ran dry and was restarted
  std::uint64_t submit_dropped = 0;  ///< submit() calls refused (inbox full)
  /// Event time → its first sample leaving the engine's queue toward the device (median and
  /// max over onsets) [s]. With `loopback` it is measured at the loopback output; with a device
  /// it is estimated: (time the buffer is queued − event time) + audio queued ahead of it +
  /// the device's reported latency. NaN until an onset has sounded.
  double latency_median_s = 0.0;
  double latency_max_s = 0.0;
  std::uint64_t latency_samples = 0;
};

class AudioEngine {
 public:
  /// @param scene built by build_audio_scene (non-null). Real-time: no.
  explicit AudioEngine(std::shared_ptr<const AudioScene> scene, EngineOptions options = {});
  /// stop().
  ~AudioEngine();
  AudioEngine(const AudioEngine&) = delete;
  AudioEngine& operator=(const AudioEngine&) = delete;

  /// Starts the audio thread as the sole consumer of shared.events (nobody else may pop them
  /// while it runs). Event times (ContactEvent::t_s) must be CLOCK_MONOTONIC seconds (a servo
  /// loop on a SteadyClock) for the latency figures to mean anything.
  /// Without a sound device it does not throw: report.device_open = false, report.detail says
  /// so and suggests `--audio-out FILE.wav`, and the thread still drains the ring.
  /// @throws hc::ConfigError if already running or an option is out of range (naming it).
  /// Real-time: no.
  EngineReport start(haptics::SharedState& shared);
  /// The same, with events handed in through submit() instead of a SharedState.
  EngineReport start();

  /// Hands one event to the audio thread (one producer thread at a time). @return false (and
  /// counts it) when the inbox (1024 events) is full. Real-time: yes (wait-free).
  bool submit(const haptics::ContactEvent& event) noexcept;

  /// Master volume [0, 4] (clamped), from any thread. Real-time: yes.
  void set_volume(double volume) noexcept;
  double volume() const noexcept;

  /// Stops and joins the audio thread, closes the device (no-op when not running).
  void stop() noexcept;
  bool running() const noexcept;

  EngineStats stats() const noexcept;
  const EngineOptions& options() const noexcept;

  /// Names of the OpenAL output devices ("" entries skipped); empty without a device or
  /// without the enumeration extension. Real-time: no.
  static std::vector<std::string> output_devices();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hc::audio
