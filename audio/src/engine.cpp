#include "hc/audio/engine.hpp"

#include "hc/common/error.hpp"
#include "hc/haptics/clock.hpp"
#include "hc/haptics/spsc_ring.hpp"

#include <AL/al.h>
#include <AL/alc.h>
#include <AL/alext.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstring>
#include <ctime>
#include <limits>
#include <thread>
#include <vector>

namespace hc::audio {
namespace {

/// Latency histogram: 0.05 ms bins up to 200 ms (relaxed atomics: written by the audio thread,
/// read by anyone).
class AtomicLatencyHistogram {
 public:
  static constexpr int kBins = 4000;
  static constexpr double kBinS = 0.00005;
  void add(double s) noexcept {
    const int b = std::clamp(static_cast<int>(s / kBinS), 0, kBins - 1);
    bins_[static_cast<std::size_t>(b)].fetch_add(1, std::memory_order_relaxed);
    count_.fetch_add(1, std::memory_order_relaxed);
    double prev = max_.load(std::memory_order_relaxed);
    while (s > prev && !max_.compare_exchange_weak(prev, s, std::memory_order_relaxed)) {
    }
  }
  std::uint64_t count() const noexcept { return count_.load(std::memory_order_relaxed); }
  double max() const noexcept { return max_.load(std::memory_order_relaxed); }
  double median() const noexcept {
    const std::uint64_t n = count();
    if (n == 0) return std::numeric_limits<double>::quiet_NaN();
    std::uint64_t acc = 0;
    for (int b = 0; b < kBins; ++b) {
      acc += bins_[static_cast<std::size_t>(b)].load(std::memory_order_relaxed);
      if (2 * acc >= n) return (b + 0.5) * kBinS;
    }
    return max();
  }

 private:
  std::array<std::atomic<std::uint32_t>, kBins> bins_{};
  std::atomic<std::uint64_t> count_{0};
  std::atomic<double> max_{0.0};
};

double now_s() noexcept { return static_cast<double>(haptics::monotonic_now_ns()) * 1e-9; }

void sleep_s(double s) noexcept {
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(s);
  ts.tv_nsec = static_cast<long>((s - static_cast<double>(ts.tv_sec)) * 1e9);
  nanosleep(&ts, nullptr);
}

}  // namespace

struct AudioEngine::Impl {
  std::shared_ptr<const AudioScene> scene;
  EngineOptions options;
  Mixer mixer;
  haptics::SharedState* shared = nullptr;
  haptics::SpscRing<haptics::ContactEvent, 1024> inbox;

  ALCdevice* device = nullptr;
  ALCcontext* context = nullptr;
  ALuint source = 0;
  std::vector<ALuint> buffers;
  LPALCRENDERSAMPLESSOFT render_loopback = nullptr;

  std::thread thread;
  std::atomic<bool> stop_flag{false};
  std::atomic<bool> running{false};
  std::atomic<double> volume{1.0};
  std::atomic<std::uint64_t> events{0}, onsets{0}, streamed{0}, underruns{0}, submit_dropped{0};
  AtomicLatencyHistogram latency;
  double device_latency_s = 0.0;

  Impl(std::shared_ptr<const AudioScene> s, EngineOptions o) : scene(s), options(std::move(o)), mixer(std::move(s)) {}

  void close_device() noexcept {
    if (context != nullptr) {
      if (source != 0) {
        alSourceStop(source);
        alSourcei(source, AL_BUFFER, 0);
        alDeleteSources(1, &source);
        source = 0;
      }
      if (!buffers.empty()) alDeleteBuffers(static_cast<ALsizei>(buffers.size()), buffers.data());
      buffers.clear();
      alcMakeContextCurrent(nullptr);
      alcDestroyContext(context);
      context = nullptr;
    }
    if (device != nullptr) {
      alcCloseDevice(device);
      device = nullptr;
    }
  }

  /// Opens the device and context; fills `report`. Never throws.
  void open(EngineReport& report) {
    const int rate = scene->config.sample_rate_hz;
    if (options.loopback) {
      auto open_loop = reinterpret_cast<LPALCLOOPBACKOPENDEVICESOFT>(
          alcGetProcAddress(nullptr, "alcLoopbackOpenDeviceSOFT"));
      auto supported = reinterpret_cast<LPALCISRENDERFORMATSUPPORTEDSOFT>(
          alcGetProcAddress(nullptr, "alcIsRenderFormatSupportedSOFT"));
      render_loopback = reinterpret_cast<LPALCRENDERSAMPLESSOFT>(alcGetProcAddress(nullptr, "alcRenderSamplesSOFT"));
      if (open_loop == nullptr || supported == nullptr || render_loopback == nullptr) {
        report.detail = "audio: OpenAL has no ALC_SOFT_loopback extension; no loopback output";
        return;
      }
      device = open_loop(nullptr);
      if (device == nullptr || supported(device, rate, ALC_MONO_SOFT, ALC_FLOAT_SOFT) == ALC_FALSE) {
        report.detail = "audio: the OpenAL loopback device refused mono float at " + std::to_string(rate) + " Hz";
        close_device();
        return;
      }
      const ALCint attrs[] = {ALC_FORMAT_CHANNELS_SOFT, ALC_MONO_SOFT, ALC_FORMAT_TYPE_SOFT, ALC_FLOAT_SOFT,
                              ALC_FREQUENCY, rate, 0};
      context = alcCreateContext(device, attrs);
      report.device = "loopback";
    } else {
      device = alcOpenDevice(options.device_name.empty() ? nullptr : options.device_name.c_str());
      if (device == nullptr) {
        report.detail = "audio: no sound output device" +
                        (options.device_name.empty() ? std::string() : " named '" + options.device_name + "'") +
                        " (OpenAL Soft opened none); contact sounds are off in this session. "
                        "Offline rendering still works: `hapticloud touch ... --audio-out FILE.wav`";
        return;
      }
      const ALCint attrs[] = {ALC_FREQUENCY, rate, ALC_REFRESH, options.device_refresh_hz, 0};
      context = alcCreateContext(device, attrs);
      const ALCchar* name = alcGetString(device, ALC_DEVICE_SPECIFIER);
      report.device = name != nullptr ? name : "default";
    }
    if (context == nullptr || alcMakeContextCurrent(context) == ALC_FALSE) {
      report.detail = "audio: OpenAL could not create a context on '" + report.device + "'";
      close_device();
      return;
    }
    alGetError();
    alGenSources(1, &source);
    buffers.assign(static_cast<std::size_t>(options.queued_buffers), 0);
    alGenBuffers(static_cast<ALsizei>(buffers.size()), buffers.data());
    if (alGetError() != AL_NO_ERROR) {
      report.detail = "audio: OpenAL could not create a source and buffers";
      close_device();
      return;
    }
    if (!options.loopback && alcIsExtensionPresent(device, "ALC_SOFT_device_clock") == ALC_TRUE) {
      auto get64 = reinterpret_cast<LPALCGETINTEGER64VSOFT>(alcGetProcAddress(device, "alcGetInteger64vSOFT"));
      if (get64 != nullptr) {
        ALCint64SOFT ns = 0;
        get64(device, ALC_DEVICE_LATENCY_SOFT, 1, &ns);
        device_latency_s = static_cast<double>(ns) * 1e-9;
      }
    }
    report.device_open = true;
    report.device_latency_s = device_latency_s;
    report.queue_latency_s = static_cast<double>(options.queued_buffers * options.buffer_frames) / rate;
    report.detail = "audio: " + report.device + ", mono 16-bit " + std::to_string(rate) + " Hz, " +
                    std::to_string(options.queued_buffers) + " x " + std::to_string(options.buffer_frames) +
                    " frames queued";
  }

  /// Drains every pending event into the mixer. @return the time of the earliest onset that
  /// started a voice (NaN if none).
  double drain() noexcept {
    double first_onset = std::numeric_limits<double>::quiet_NaN();
    haptics::ContactEvent e;
    const auto take = [&](const haptics::ContactEvent& ev) {
      const std::uint64_t before = mixer.stats().onsets_played;
      mixer.handle(ev);
      events.fetch_add(1, std::memory_order_relaxed);
      if (mixer.stats().onsets_played != before) {
        onsets.fetch_add(1, std::memory_order_relaxed);
        if (std::isnan(first_onset)) first_onset = ev.t_s;
      }
    };
    if (shared != nullptr) {
      while (shared->events.try_pop(e)) take(e);
    }
    while (inbox.try_pop(e)) take(e);
    return first_onset;
  }

  void fill(ALuint buffer, std::vector<float>& block, std::vector<std::int16_t>& pcm) noexcept {
    mixer.set_volume(volume.load(std::memory_order_relaxed));
    mixer.render(block);
    for (std::size_t i = 0; i < block.size(); ++i) {
      pcm[i] = static_cast<std::int16_t>(std::lrint(std::clamp(block[i], -1.0F, 1.0F) * 32767.0F));
    }
    alBufferData(buffer, AL_FORMAT_MONO16, pcm.data(), static_cast<ALsizei>(pcm.size() * sizeof(std::int16_t)),
                 scene->config.sample_rate_hz);
    streamed.fetch_add(1, std::memory_order_relaxed);
  }

  void run_without_device() noexcept {
    while (!stop_flag.load(std::memory_order_acquire)) {
      haptics::ContactEvent e;
      std::uint64_t n = 0;
      if (shared != nullptr) {
        while (shared->events.try_pop(e)) ++n;
      }
      while (inbox.try_pop(e)) ++n;
      events.fetch_add(n, std::memory_order_relaxed);
      sleep_s(0.002);
    }
  }

  void run() noexcept {
    const int rate = scene->config.sample_rate_hz;
    const auto frames = static_cast<std::size_t>(options.buffer_frames);
    const double period_s = static_cast<double>(frames) / rate;
    std::vector<float> block(frames);
    std::vector<std::int16_t> pcm(frames);
    std::vector<float> loop_out(frames);
    for (ALuint b : buffers) fill(b, block, pcm);
    alSourceQueueBuffers(source, static_cast<ALsizei>(buffers.size()), buffers.data());
    alSourcePlay(source);
    double pending_onset = std::numeric_limits<double>::quiet_NaN();  // loopback: awaiting its first sample
    // Loopback: an onset is timed only if the output was silent just before it; otherwise the first
    // audible sample could belong to a note still ringing, and the figure would be too small.
    bool loop_silent = true;
    double next_pump = now_s();
    while (!stop_flag.load(std::memory_order_acquire)) {
      if (render_loopback != nullptr) {
        // The loopback device is our sound card: pull one period per period, on time.
        const double t = now_s();
        if (t >= next_pump) {
          render_loopback(device, loop_out.data(), static_cast<ALCsizei>(frames));
          next_pump += period_s;
          if (next_pump < t - 10 * period_s) next_pump = t;  // fell far behind: resynchronise
          bool found = false;
          if (!std::isnan(pending_onset)) {
            for (std::size_t i = 0; i < frames; ++i) {
              if (std::abs(loop_out[i]) > 1e-4F) {
                latency.add(t + static_cast<double>(i) / rate - pending_onset);
                pending_onset = std::numeric_limits<double>::quiet_NaN();
                found = true;
                break;
              }
            }
          }
          loop_silent = !found && std::none_of(loop_out.begin(), loop_out.end(),
                                               [](float x) { return std::abs(x) > 1e-4F; });
        }
      }
      ALint processed = 0;
      alGetSourcei(source, AL_BUFFERS_PROCESSED, &processed);
      for (ALint k = 0; k < processed; ++k) {
        ALuint b = 0;
        alSourceUnqueueBuffers(source, 1, &b);
        const double onset_t = drain();
        fill(b, block, pcm);
        alSourceQueueBuffers(source, 1, &b);
        if (!std::isnan(onset_t)) {
          if (render_loopback != nullptr) {
            if (std::isnan(pending_onset) && loop_silent) pending_onset = onset_t;
          } else {
            // Audio ahead of this buffer: the rest of the queue minus what has played of its head.
            ALint offset = 0;
            alGetSourcei(source, AL_SAMPLE_OFFSET, &offset);
            const double ahead = static_cast<double>((options.queued_buffers - 1) * options.buffer_frames - offset) / rate;
            latency.add(now_s() - onset_t + std::max(0.0, ahead) + device_latency_s);
          }
        }
      }
      ALint state = AL_PLAYING;
      alGetSourcei(source, AL_SOURCE_STATE, &state);
      if (state != AL_PLAYING) {
        underruns.fetch_add(1, std::memory_order_relaxed);
        alSourcePlay(source);
      }
      sleep_s(render_loopback != nullptr ? std::min(period_s / 4.0, 0.0005) : period_s / 4.0);
    }
    alSourceStop(source);
  }
};

AudioEngine::AudioEngine(std::shared_ptr<const AudioScene> scene, EngineOptions options) {
  if (!scene) throw ConfigError("audio: AudioEngine needs a scene (build_audio_scene)");
  impl_ = std::make_unique<Impl>(std::move(scene), std::move(options));
}

AudioEngine::~AudioEngine() { stop(); }

EngineReport AudioEngine::start(haptics::SharedState& shared) {
  if (running()) throw ConfigError("audio: the engine is already running");
  impl_->shared = &shared;
  return start();
}

EngineReport AudioEngine::start() {
  Impl& m = *impl_;
  if (m.thread.joinable()) throw ConfigError("audio: the engine is already running");
  const EngineOptions& o = m.options;
  if (o.buffer_frames < 16 || o.buffer_frames > 4096) {
    throw ConfigError("audio: buffer_frames = " + std::to_string(o.buffer_frames) + ": expected [16, 4096]");
  }
  if (o.queued_buffers < 2 || o.queued_buffers > 16) {
    throw ConfigError("audio: queued_buffers = " + std::to_string(o.queued_buffers) + ": expected [2, 16]");
  }
  if (o.device_refresh_hz < 10 || o.device_refresh_hz > 2000) {
    throw ConfigError("audio: device_refresh_hz = " + std::to_string(o.device_refresh_hz) + ": expected [10, 2000]");
  }
  EngineReport report;
  m.open(report);
  m.stop_flag.store(false, std::memory_order_release);
  m.running.store(true, std::memory_order_release);
  if (report.device_open) {
    m.thread = std::thread([&m] { m.run(); });
  } else {
    m.thread = std::thread([&m] { m.run_without_device(); });
  }
  return report;
}

bool AudioEngine::submit(const haptics::ContactEvent& event) noexcept {
  if (impl_->inbox.try_push(event)) return true;
  impl_->submit_dropped.fetch_add(1, std::memory_order_relaxed);
  return false;
}

void AudioEngine::set_volume(double volume) noexcept {
  impl_->volume.store(std::isfinite(volume) ? std::clamp(volume, 0.0, 4.0) : 0.0, std::memory_order_relaxed);
}

double AudioEngine::volume() const noexcept { return impl_->volume.load(std::memory_order_relaxed); }

void AudioEngine::stop() noexcept {
  if (!impl_) return;
  Impl& m = *impl_;
  if (m.thread.joinable()) {
    m.stop_flag.store(true, std::memory_order_release);
    m.thread.join();
  }
  m.close_device();
  m.running.store(false, std::memory_order_release);
  m.shared = nullptr;
}

bool AudioEngine::running() const noexcept { return impl_->running.load(std::memory_order_acquire); }

EngineStats AudioEngine::stats() const noexcept {
  const Impl& m = *impl_;
  EngineStats s;
  s.events = m.events.load(std::memory_order_relaxed);
  s.onsets_played = m.onsets.load(std::memory_order_relaxed);
  s.buffers = m.streamed.load(std::memory_order_relaxed);
  s.underruns = m.underruns.load(std::memory_order_relaxed);
  s.submit_dropped = m.submit_dropped.load(std::memory_order_relaxed);
  s.latency_samples = m.latency.count();
  s.latency_median_s = m.latency.median();
  s.latency_max_s = m.latency.max();
  return s;
}

const EngineOptions& AudioEngine::options() const noexcept { return impl_->options; }

std::vector<std::string> AudioEngine::output_devices() {
  std::vector<std::string> out;
  const bool all = alcIsExtensionPresent(nullptr, "ALC_ENUMERATE_ALL_EXT") == ALC_TRUE;
  if (!all && alcIsExtensionPresent(nullptr, "ALC_ENUMERATION_EXT") != ALC_TRUE) return out;
  const ALCchar* list = alcGetString(nullptr, all ? ALC_ALL_DEVICES_SPECIFIER : ALC_DEVICE_SPECIFIER);
  while (list != nullptr && *list != '\0') {
    out.emplace_back(list);
    list += std::strlen(list) + 1;
  }
  return out;
}

}  // namespace hc::audio
