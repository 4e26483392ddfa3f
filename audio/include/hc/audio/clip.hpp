#pragma once
/// @file clip.hpp
/// Audio clips held in memory: decoding (libsndfile: WAV, FLAC, OGG/Vorbis, ...), resampling,
/// the synthesised struck-stone tones, and writing WAV files. Everything here runs at start or
/// offline, never on the audio thread's hot path.

#include "hc/audio/audio_config.hpp"

#include <cstddef>
#include <filesystem>
#include <span>
#include <string>
#include <vector>

namespace hc::audio {

/// Mono float samples in [−1, 1] at sample_rate_hz.
struct Clip {
  std::vector<float> samples;
  int sample_rate_hz = 48000;
  std::string source;  ///< file name or "synth:<note>" (for reports)

  double seconds() const noexcept {
    return sample_rate_hz > 0 ? static_cast<double>(samples.size()) / sample_rate_hz : 0.0;
  }
};

/// Decodes a whole file into memory, averages its channels to mono and resamples it to
/// target_rate_hz / pitch (so that playing it at target_rate_hz sounds `pitch` times higher).
/// Resampling is linear interpolation (adequate for pitch factors near 1; docs/audio.md).
/// @param pitch (0.25 … 4), playback-rate factor.
/// @throws hc::InputError naming the file when it is missing, unreadable, not a sound file
///         libsndfile knows, corrupt (a read error) or empty; hc::ConfigError for a bad
///         pitch or rate. Real-time: no.
Clip decode_clip(const std::filesystem::path& path, int target_rate_hz, double pitch = 1.0);

/// Linear-interpolation resampling of mono samples by `ratio` = out_rate / in_rate (> 0).
/// Real-time: no (allocates).
std::vector<float> resample_linear(std::span<const float> in, double ratio);

/// A synthesised struck-stone tone: a short noise click (the strike) plus a few inharmonic,
/// exponentially decaying partials (ratios 1, 2.02, 2.76, 4.1, 5.4 of the fundamental, higher
/// partials decaying faster), peak-normalised to 0.8. Deterministic.
/// @param fundamental_hz (20, rate/8); seconds (0, 20]. @throws hc::ConfigError otherwise.
/// Real-time: no.
Clip synth_stone_tone(double fundamental_hz, int sample_rate_hz, double seconds);

/// Writes mono float samples as a 16-bit PCM WAV (values outside [−1, 1] clip).
/// @throws hc::InputError naming the file when it cannot be written. Real-time: no.
void write_wav(const std::filesystem::path& path, std::span<const float> samples, int sample_rate_hz);

}  // namespace hc::audio
