#pragma once
/// @file offline.hpp
/// Offline rendering: what the live player would have played for a list of contact events,
/// sample-accurate to their times, through the same Mixer (for tests, reports and machines
/// without a sound device).

#include "hc/audio/mixer.hpp"
#include "hc/haptics/shared_state.hpp"

#include <filesystem>
#include <memory>
#include <span>
#include <vector>

namespace hc::audio {

/// Renders `events` (sorted by t_s, or stably sorted here) starting at time t0_s for duration_s
/// seconds plus `tail_s` of ring-out: event e is applied exactly before sample
/// round((e.t_s − t0_s)·rate) (events before t0_s at sample 0).
/// @param duration_s ≥ 0, tail_s ≥ 0, total ≤ 3600 s. @throws hc::ConfigError otherwise.
/// @return mono samples at scene.config.sample_rate_hz. Real-time: no.
std::vector<float> render_offline(std::shared_ptr<const AudioScene> scene,
                                  std::span<const haptics::ContactEvent> events, double t0_s,
                                  double duration_s, double tail_s = 1.0, MixerStats* stats = nullptr);

/// Sample index of time t_s for a render starting at t0_s (round to nearest, ≥ 0). Real-time: yes.
std::size_t sample_of_time(double t_s, double t0_s, int sample_rate_hz) noexcept;

}  // namespace hc::audio
