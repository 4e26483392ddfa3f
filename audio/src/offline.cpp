#include "hc/audio/offline.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cmath>
#include <string>

namespace hc::audio {

std::size_t sample_of_time(double t_s, double t0_s, int sample_rate_hz) noexcept {
  const double k = std::round((t_s - t0_s) * sample_rate_hz);
  return k > 0.0 && std::isfinite(k) ? static_cast<std::size_t>(k) : 0;
}

std::vector<float> render_offline(std::shared_ptr<const AudioScene> scene,
                                  std::span<const haptics::ContactEvent> events, double t0_s, double duration_s,
                                  double tail_s, MixerStats* stats) {
  if (!scene) throw ConfigError("audio: render_offline needs a scene (build_audio_scene)");
  if (!(duration_s >= 0.0) || !(tail_s >= 0.0) || !(duration_s + tail_s <= 3600.0) || !std::isfinite(t0_s)) {
    throw ConfigError("audio: offline render of " + std::to_string(duration_s) + " s + " + std::to_string(tail_s) +
                      " s tail from t0 = " + std::to_string(t0_s) + ": expected 0 ≤ duration + tail ≤ 3600 s");
  }
  const int rate = scene->config.sample_rate_hz;
  std::vector<haptics::ContactEvent> sorted(events.begin(), events.end());
  std::stable_sort(sorted.begin(), sorted.end(),
                   [](const haptics::ContactEvent& a, const haptics::ContactEvent& b) { return a.t_s < b.t_s; });
  const auto total = static_cast<std::size_t>(std::ceil((duration_s + tail_s) * rate));
  std::vector<float> out(total, 0.0F);
  Mixer mixer(std::move(scene));
  // The live engine's block size: render up to each event's sample, apply it, go on.
  constexpr std::size_t kBlock = 128;
  std::size_t cursor = 0;
  std::size_t next = 0;
  while (cursor < total) {
    while (next < sorted.size() && sample_of_time(sorted[next].t_s, t0_s, rate) <= cursor) {
      mixer.handle(sorted[next]);
      ++next;
    }
    std::size_t end = std::min(total, cursor + kBlock);
    if (next < sorted.size()) end = std::min(end, std::max(cursor + 1, sample_of_time(sorted[next].t_s, t0_s, rate)));
    mixer.render(std::span<float>(out.data() + cursor, end - cursor));
    cursor = end;
  }
  if (stats != nullptr) *stats = mixer.stats();
  return out;
}

}  // namespace hc::audio
