#ifdef HC_HAVE_AUDIO

#include "touch_audio.hpp"

#include "hc/audio/offline.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iostream>
#include <thread>
#include <vector>

namespace hc::app {

TouchAudio::TouchAudio(const std::optional<audio::AudioConfig>& spec, const Scene& scene, std::string wav_out,
                       std::string live)
    : wav_out_(std::move(wav_out)), live_name_(std::move(live)) {
  const GridGeometry& grid = scene.geometry;  // a stored scene has no layer in memory
  const HeightField* texture = scene.layers.texture.rows() > 0 ? &scene.layers.texture : nullptr;
  scene_ = audio::build_audio_scene(spec.value_or(audio::AudioConfig{}), {&grid, texture});
  if (!scene_->config.regions.empty()) region_layer_ = scene_->regions.to_layer(grid);
  std::cout << "audio: " << scene_->config.regions.size() << " region(s)"
            << (spec ? "" : " (the input has no audio: section; sliding sound only)") << "\n";
}

TouchAudio::~TouchAudio() {
  if (live_) live_->stop();
}

session::TouchSessionHooks TouchAudio::start() {
  if (!live_name_.empty()) {
    audio::EngineOptions eo;
    eo.loopback = live_name_ == "loopback";
    if (live_name_ != "default" && !eo.loopback) eo.device_name = live_name_;
    live_ = std::make_unique<audio::AudioEngine>(scene_, eo);
    const audio::EngineReport rep = live_->start();  // events are forwarded by the hook
    std::cout << rep.detail << "\n";
  }
  session::TouchSessionHooks hooks;
  if (region_layer_.rows() > 0) hooks.region_id = &region_layer_;
  if (live_) hooks.on_event = [this](const haptics::ContactEvent& e) { live_->submit(e); };
  return hooks;
}

std::string TouchAudio::finish(const session::TouchSessionResult& r, double servo_rate_hz) {
  nlohmann::ordered_json j = nlohmann::ordered_json::object();
  if (live_) {
    std::this_thread::sleep_for(std::chrono::milliseconds(300));  // let the last notes start
    live_->stop();
    const audio::EngineStats st = live_->stats();
    j["audio_live"] = {{"device", live_name_}, {"events", st.events}, {"onsets_played", st.onsets_played},
                       {"underruns", st.underruns}, {"latency_median_ms", st.latency_median_s * 1e3},
                       {"latency_max_ms", st.latency_max_s * 1e3}};
    std::cout << "  audio live: " << st.onsets_played << " onsets played, event->first sample latency median "
              << st.latency_median_s * 1e3 << " ms (max " << st.latency_max_s * 1e3 << " ms), " << st.underruns
              << " underruns\n";
    live_.reset();
  }
  if (!wav_out_.empty()) {
    // The same mixer as the live player, sample-accurate to the event times.
    const double t0 = r.trace.empty() ? 0.0 : r.trace.front().t_s;
    audio::MixerStats ms;
    const std::vector<float> wav = audio::render_offline(
        scene_, r.events, t0, static_cast<double>(r.trace.size()) / servo_rate_hz, 1.0, &ms);
    audio::write_wav(wav_out_, wav, scene_->config.sample_rate_hz);
    float peak = 0.0F;
    for (float v : wav) peak = std::max(peak, std::abs(v));
    const double peak_dbfs = peak > 0.0F ? 20.0 * std::log10(static_cast<double>(peak)) : -200.0;
    j["audio"] = {{"file", wav_out_},
                  {"sample_rate_hz", scene_->config.sample_rate_hz},
                  {"seconds", static_cast<double>(wav.size()) / scene_->config.sample_rate_hz},
                  {"regions", scene_->config.regions.size()},
                  {"onsets_played", ms.onsets_played},
                  {"onsets_silent", ms.onsets_silent},
                  {"peak_dbfs", peak_dbfs},
                  {"limiter_min_gain", ms.limiter_min_gain},
                  {"latency_note", "live event-to-first-sample latency: bench/audio_bench (docs/audio.md)"}};
    std::cout << "  audio: wrote " << wav_out_ << " (" << wav.size() << " samples, " << ms.onsets_played
              << " notes, peak " << peak_dbfs << " dBFS)\n";
  }
  return j.dump(-1, ' ', false, nlohmann::ordered_json::error_handler_t::replace);
}

}  // namespace hc::app

#endif  // HC_HAVE_AUDIO
