// Contact-sound latency and mixer cost (issue 7; docs/audio.md).
//  - BM_EventToFirstSample/loopback: a contact onset handed to the live AudioEngine → the first
//    sample of its note leaving OpenAL Soft's loopback device, which the engine pulls in real
//    time like a sound card (so the whole OpenAL path is measured without hardware). Counters:
//    latency_median_ms, latency_max_ms (medians over `onsets` strikes).
//  - BM_EventToFirstSample/device: the same on the default sound device (estimated: event →
//    buffer queued + audio queued ahead + the device's reported latency); reports an error line
//    when the machine has no sound device.
//  - BM_MixerBlock: one 128-frame block with 8 notes and the sliding sound (the audio thread's
//    work per buffer; budget 2.67 ms at 48 kHz).

#include "hc/audio/engine.hpp"
#include "hc/audio/mixer.hpp"
#include "hc/haptics/clock.hpp"

#include <benchmark/benchmark.h>

#include <chrono>
#include <cmath>
#include <string>
#include <thread>
#include <vector>

namespace {

using namespace hc;

std::shared_ptr<const audio::AudioScene> pillars_scene(double tone_s) {
  audio::AudioConfig c;
  c.tone_seconds = tone_s;
  for (int i = 0; i < 7; ++i) {
    audio::RegionConfig r;
    r.name = audio::to_string(static_cast<audio::Note>(i));
    r.note = static_cast<audio::Note>(i);
    r.shape.x_min_m = 0.01 * i, r.shape.x_max_m = 0.01 * i + 0.008;
    r.shape.y_min_m = -0.01, r.shape.y_max_m = 0.01;
    c.regions.push_back(r);
  }
  return audio::build_audio_scene(c);
}

haptics::ContactEvent contact(haptics::ContactEventType type, double x, double force, double speed = 0.0) {
  haptics::ContactEvent e;
  e.type = type;
  e.t_s = static_cast<double>(haptics::monotonic_now_ns()) * 1e-9;
  e.position_m = haptics::Vec3{x, 0.0, 0.0};
  e.force_n = haptics::Vec3{0.0, 0.0, force};
  e.speed_m_per_s = speed;
  return e;
}

void BM_EventToFirstSample(benchmark::State& state) {
  audio::EngineOptions o;
  o.loopback = state.range(0) == 0;
  o.buffer_frames = static_cast<int>(state.range(1));
  audio::AudioEngine engine(pillars_scene(0.06), o);
  const audio::EngineReport report = engine.start();
  if (!report.device_open) {
    state.SkipWithError(report.detail.c_str());
    return;
  }
  std::uint64_t strikes = 0;
  for (auto _ : state) {
    const std::uint64_t before = engine.stats().latency_samples;
    engine.submit(contact(haptics::ContactEventType::kOnset, 0.004 + 0.01 * static_cast<double>(strikes % 7), 2.0));
    engine.submit(contact(haptics::ContactEventType::kRelease, 0.0, 0.0));
    for (int i = 0; i < 2000 && engine.stats().latency_samples == before; ++i) {
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(90));  // the 60 ms note dies out
    ++strikes;
  }
  const audio::EngineStats s = engine.stats();
  engine.stop();
  state.counters["latency_median_ms"] = s.latency_median_s * 1e3;
  state.counters["latency_max_ms"] = s.latency_max_s * 1e3;
  state.counters["onsets"] = static_cast<double>(s.latency_samples);
  state.counters["underruns"] = static_cast<double>(s.underruns);
  state.counters["queue_ms"] = report.queue_latency_s * 1e3;
  state.counters["device_ms"] = report.device_latency_s * 1e3;
  state.SetLabel(report.device);
}
// (0 = loopback, 1 = default device) × buffer frames.
BENCHMARK(BM_EventToFirstSample)
    ->Args({0, 64})
    ->Args({0, 128})
    ->Args({1, 64})
    ->Iterations(60)
    ->Unit(benchmark::kMillisecond);

void BM_MixerBlock(benchmark::State& state) {
  audio::Mixer mixer(pillars_scene(2.5));
  for (int i = 0; i < 8; ++i) {
    mixer.handle(contact(haptics::ContactEventType::kOnset, 0.004 + 0.01 * (i % 7), 3.0));
    mixer.handle(contact(haptics::ContactEventType::kRelease, 0.0, 0.0));
  }
  mixer.handle(contact(haptics::ContactEventType::kOnset, 0.004, 3.0));
  std::vector<float> block(static_cast<std::size_t>(state.range(0)));
  int k = 0;
  for (auto _ : state) {
    if (++k % 4 == 0) mixer.handle(contact(haptics::ContactEventType::kSlide, 0.004, 3.0, 0.05));
    if (k % 512 == 0) {  // strike 8 notes again every 1.4 s of audio, so 8–16 voices sound
      for (int i = 0; i < 8; ++i) {
        mixer.handle(contact(haptics::ContactEventType::kRelease, 0.0, 0.0));
        mixer.handle(contact(haptics::ContactEventType::kOnset, 0.004 + 0.01 * (i % 7), 3.0));
      }
    }
    mixer.render(block);
    benchmark::DoNotOptimize(block.data());
  }
  state.counters["voices_at_end"] = mixer.active_voices();
  state.SetItemsProcessed(state.iterations() * state.range(0));
}
BENCHMARK(BM_MixerBlock)->Arg(128)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
