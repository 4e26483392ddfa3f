#include "hc/audio/clip.hpp"

#include "hc/common/error.hpp"
#include "hc/common/format.hpp"

#include <sndfile.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <numbers>
#include <sstream>
#include <system_error>

namespace hc::audio {
namespace {

struct SndCloser {
  void operator()(SNDFILE* f) const noexcept { sf_close(f); }
};
using SndHandle = std::unique_ptr<SNDFILE, SndCloser>;

}  // namespace

std::vector<float> resample_linear(std::span<const float> in, double ratio) {
  if (!(ratio > 0.0) || !std::isfinite(ratio)) {
    throw ConfigError("audio: resampling ratio " + format_number(ratio) + ": expected a finite number > 0");
  }
  if (in.empty()) return {};
  if (ratio == 1.0) return {in.begin(), in.end()};
  const auto n_out = static_cast<std::size_t>(std::floor(static_cast<double>(in.size() - 1) * ratio)) + 1;
  std::vector<float> out(n_out);
  const double step = 1.0 / ratio;
  for (std::size_t i = 0; i < n_out; ++i) {
    const double x = static_cast<double>(i) * step;
    const auto k = static_cast<std::size_t>(x);
    const double f = x - static_cast<double>(k);
    const float a = in[std::min(k, in.size() - 1)];
    const float b = in[std::min(k + 1, in.size() - 1)];
    out[i] = static_cast<float>(a + f * (b - a));
  }
  return out;
}

Clip decode_clip(const std::filesystem::path& path, int target_rate_hz, double pitch) {
  if (target_rate_hz < 1000 || target_rate_hz > 384000) {
    throw ConfigError("audio: sample rate " + std::to_string(target_rate_hz) + " Hz: expected [1000, 384000]");
  }
  if (!(pitch >= 0.25 && pitch <= 4.0)) {
    throw ConfigError("audio: pitch " + format_number(pitch) + " for '" + path.string() + "': expected a number in [0.25, 4]");
  }
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw InputError("audio: clip '" + path.string() + "' does not exist (or is not a file)");
  }
  SF_INFO info{};
  SndHandle f(sf_open(path.string().c_str(), SFM_READ, &info));
  if (!f) {
    throw InputError("audio: clip '" + path.string() + "' cannot be decoded: " + sf_strerror(nullptr) +
                     " (expected a WAV, FLAC or OGG/Vorbis file libsndfile can read)");
  }
  if (info.channels < 1 || info.samplerate < 1 || info.frames <= 0) {
    throw InputError("audio: clip '" + path.string() + "' is empty or has an invalid header (" +
                     std::to_string(info.frames) + " frames, " + std::to_string(info.channels) + " channels, " +
                     std::to_string(info.samplerate) + " Hz)");
  }
  constexpr sf_count_t kMaxFrames = sf_count_t{1} << 28;  // ~1.5 h at 48 kHz: a sane cap
  if (info.frames > kMaxFrames) {
    throw ResourceError("audio: clip '" + path.string() + "' has " + std::to_string(info.frames) +
                        " frames; at most " + std::to_string(kMaxFrames) + " are held in memory");
  }
  std::vector<float> interleaved(static_cast<std::size_t>(info.frames) * static_cast<std::size_t>(info.channels));
  const sf_count_t got = sf_readf_float(f.get(), interleaved.data(), info.frames);
  // Fewer frames than the header declares: the file is cut short (a partial copy or download).
  if (sf_error(f.get()) != SF_ERR_NO_ERROR || got != info.frames) {
    throw InputError("audio: clip '" + path.string() + "' is corrupt: read " + std::to_string(got) + " of the " +
                     std::to_string(info.frames) + " frames its header declares (" + sf_strerror(f.get()) + ")");
  }
  const auto frames = static_cast<std::size_t>(got);
  const auto ch = static_cast<std::size_t>(info.channels);
  std::vector<float> mono(frames);
  for (std::size_t i = 0; i < frames; ++i) {
    float s = 0.0F;
    for (std::size_t c = 0; c < ch; ++c) s += interleaved[i * ch + c];
    mono[i] = s / static_cast<float>(ch);
    if (!std::isfinite(mono[i])) {
      throw InputError("audio: clip '" + path.string() + "' is corrupt: a non-finite sample at frame " +
                       std::to_string(i));
    }
  }
  Clip clip;
  clip.sample_rate_hz = target_rate_hz;
  clip.source = path.string();
  const double ratio = static_cast<double>(target_rate_hz) / (static_cast<double>(info.samplerate) * pitch);
  clip.samples = resample_linear(mono, ratio);
  return clip;
}

Clip synth_stone_tone(double fundamental_hz, int sample_rate_hz, double seconds) {
  if (sample_rate_hz < 1000 || sample_rate_hz > 384000) {
    throw ConfigError("audio: sample rate " + std::to_string(sample_rate_hz) + " Hz: expected [1000, 384000]");
  }
  if (!(fundamental_hz > 20.0 && fundamental_hz < sample_rate_hz / 8.0)) {
    throw ConfigError("audio: tone frequency " + format_number(fundamental_hz) + " Hz: expected (20, " +
                      format_number(sample_rate_hz / 8.0) + ")");
  }
  if (!(seconds > 0.0 && seconds <= 20.0)) {
    throw ConfigError("audio: tone length " + format_number(seconds) + " s: expected (0, 20]");
  }
  // Partials of a struck stone column: inharmonic ratios, amplitudes and 60 dB decay times
  // chosen by ear (higher partials decay faster); a 3 ms noise burst for the strike.
  constexpr double kRatio[5] = {1.0, 2.02, 2.76, 4.1, 5.4};
  constexpr double kAmp[5] = {1.0, 0.45, 0.35, 0.18, 0.1};
  constexpr double kT60[5] = {1.8, 1.0, 0.7, 0.4, 0.25};
  const auto n = static_cast<std::size_t>(std::ceil(seconds * sample_rate_hz));
  Clip clip;
  clip.sample_rate_hz = sample_rate_hz;
  clip.samples.assign(n, 0.0F);
  const double dt = 1.0 / sample_rate_hz;
  const double nyquist = 0.5 * sample_rate_hz;
  for (int p = 0; p < 5; ++p) {
    const double f = fundamental_hz * kRatio[p];
    if (f >= 0.9 * nyquist) continue;
    const double w = 2.0 * std::numbers::pi * f * dt;
    const double decay = std::exp(-6.907755 * dt / kT60[p]);  // ln(1000) per T60
    double env = kAmp[p];
    for (std::size_t k = 0; k < n; ++k) {
      clip.samples[k] += static_cast<float>(env * std::sin(w * static_cast<double>(k)));
      env *= decay;
    }
  }
  std::uint32_t rng = 0x9E3779B9u;
  const auto burst = static_cast<std::size_t>(0.003 * sample_rate_hz);
  for (std::size_t k = 0; k < std::min(burst, n); ++k) {
    rng = rng * 1664525u + 1013904223u;
    const double noise = static_cast<double>(rng >> 8) / 8388608.0 - 1.0;
    const double env = 0.6 * (1.0 - static_cast<double>(k) / static_cast<double>(burst));
    clip.samples[k] += static_cast<float>(noise * env);
  }
  // A 1 ms raised-cosine fade-in against a click at the very first sample, and a fade-out.
  const auto fade_in = std::min<std::size_t>(n, static_cast<std::size_t>(0.001 * sample_rate_hz));
  for (std::size_t k = 0; k < fade_in; ++k) {
    clip.samples[k] *= static_cast<float>(0.5 - 0.5 * std::cos(std::numbers::pi * static_cast<double>(k) / static_cast<double>(fade_in)));
  }
  const auto fade_out = std::min<std::size_t>(n, static_cast<std::size_t>(0.05 * sample_rate_hz));
  for (std::size_t k = 0; k < fade_out; ++k) {
    clip.samples[n - 1 - k] *= static_cast<float>(static_cast<double>(k) / static_cast<double>(fade_out));
  }
  float peak = 0.0F;
  for (float s : clip.samples) peak = std::max(peak, std::abs(s));
  if (peak > 0.0F) {
    for (float& s : clip.samples) s *= 0.8F / peak;
  }
  clip.source = "synth:" + format_number(fundamental_hz) + "Hz";
  return clip;
}

void write_wav(const std::filesystem::path& path, std::span<const float> samples, int sample_rate_hz) {
  SF_INFO info{};
  info.samplerate = sample_rate_hz;
  info.channels = 1;
  info.format = SF_FORMAT_WAV | SF_FORMAT_PCM_16;
  SndHandle f(sf_open(path.string().c_str(), SFM_WRITE, &info));
  if (!f) {
    throw InputError("audio: cannot write '" + path.string() + "': " + sf_strerror(nullptr));
  }
  sf_command(f.get(), SFC_SET_CLIPPING, nullptr, SF_TRUE);
  const auto n = static_cast<sf_count_t>(samples.size());
  if (sf_writef_float(f.get(), samples.data(), n) != n) {
    throw InputError("audio: writing '" + path.string() + "' failed: " + sf_strerror(f.get()));
  }
}

}  // namespace hc::audio
