#pragma once
/// @file mixer.hpp
/// The one mixer shared by the live player (engine.hpp) and the offline renderer (offline.hpp):
/// contact events in, mono float samples out. An AudioScene (clips decoded into memory, the
/// region map, the texture-amplitude map) is built once at start; the Mixer then handles events
/// and renders blocks without allocating, locking or doing I/O.

#include "hc/audio/audio_config.hpp"
#include "hc/audio/clip.hpp"
#include "hc/audio/region_map.hpp"
#include "hc/common/height_field.hpp"
#include "hc/haptics/shared_state.hpp"

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

namespace hc::audio {

/// What the scene is built from besides the config (all optional, read during the build only).
struct SceneInputs {
  const GridGeometry* grid = nullptr;     ///< the rendered grid: regions are rasterised on it
  const HeightField* texture = nullptr;   ///< h = f − f_b [m]: loudness of the sliding sound
};

/// Everything the mixer reads, immutable after the build (shared by the threads that read it).
struct AudioScene {
  AudioConfig config;
  std::vector<Clip> clips;                ///< one per region (decoded or synthesised), at config rate
  RegionMap regions;
  /// Local texture RMS [m] per cell (5 × 5 window) on texture_grid; empty when no texture given.
  std::vector<float> texture_rms_m;
  GridGeometry texture_grid{};

  /// Texture RMS [m] at the nearest cell (0 without a texture map). Real-time: yes.
  double texture_rms_at(double x_m, double y_m) const noexcept;
};

/// Validates `config`, decodes every region's clip into memory (or synthesises its note),
/// rasterises the regions and computes the texture-amplitude map.
/// @throws hc::ConfigError (validate()) or hc::InputError naming the clip file that is missing
///         or corrupt (and the region), so nothing fails later during a session.
/// Real-time: no (reads files, allocates).
std::shared_ptr<const AudioScene> build_audio_scene(const AudioConfig& config, const SceneInputs& inputs = {});

/// g(F) of ForceGainMap (0 below the threshold). Real-time: yes.
double force_to_gain(const ForceGainMap& map, double force_n) noexcept;

/// Counters of a mixer (read by the owner thread).
struct MixerStats {
  std::uint64_t events = 0;
  std::uint64_t onsets_played = 0;     ///< voices started
  std::uint64_t onsets_silent = 0;     ///< onsets outside every region or below the threshold
  std::uint64_t voices_stolen = 0;     ///< a voice was taken from the oldest sound (pool full)
  double limiter_min_gain = 1.0;       ///< deepest limiter gain reduction so far [-]
};

/// Contact events → mono samples. One thread at a time (the audio thread, or the offline loop).
/// handle() applies an event at the start of the next render(); render() advances time.
/// Events of a contact are matched by order: onset → slides → release (one proxy).
class Mixer {
 public:
  static constexpr int kMaxVoices = 32;

  /// @param scene must be non-null. Allocates the voice pool. Real-time: no.
  explicit Mixer(std::shared_ptr<const AudioScene> scene);

  /// Applies a contact event now (before the next rendered sample). Real-time: yes.
  void handle(const haptics::ContactEvent& event) noexcept;

  /// Mixes `out.size()` samples (overwrites out): voices × master volume → peak limiter.
  /// Peak |out| ≤ limiter_threshold ≤ 1 always (the limiter has instant attack and a final
  /// clamp). Real-time: yes (no allocation, no locks).
  void render(std::span<float> out) noexcept;

  /// Master volume multiplier [0, 4] (clamped), applied smoothly. Real-time: yes.
  void set_volume(double volume) noexcept;
  double volume() const noexcept { return volume_target_; }

  /// Number of voices sounding. Real-time: yes.
  int active_voices() const noexcept;
  /// Samples rendered since construction.
  std::uint64_t frames_rendered() const noexcept { return frames_; }
  const MixerStats& stats() const noexcept { return stats_; }
  const AudioScene& scene() const noexcept { return *scene_; }

 private:
  struct Voice {
    bool active = false;
    bool loop = false;
    bool releasing = false;
    std::int32_t region = -1;
    std::size_t pos = 0;
    double gain = 0.0;          // current (smoothed)
    double gain_target = 0.0;
    std::uint64_t started = 0;  // frame it started (for stealing)
  };
  struct Slide {
    bool active = false;
    double level = 0.0;         // current loudness (smoothed)
    double level_target = 0.0;
    double grain_rate_hz = 0.0; // grains per second
    std::uint64_t last_event_frame = 0;  // frame of the last slide event (silence after 30 ms)
    const Material* material = nullptr;  // into the scene's config (outlives the mixer); no copy, no allocation
    double b0 = 0.0, a1 = 0.0, a2 = 0.0;  // resonator coefficients
    double y1 = 0.0, y2 = 0.0;
    std::uint32_t rng = 0x12345678u;
  };

  void start_voice(std::int32_t region, double gain) noexcept;
  void release_region_voices(std::int32_t region, bool all) noexcept;
  void update_slide(const haptics::ContactEvent& e, std::int32_t region) noexcept;
  void set_resonator(const Material& m) noexcept;
  float next_noise() noexcept;

  std::shared_ptr<const AudioScene> scene_;
  std::array<Voice, kMaxVoices> voices_{};
  Slide slide_{};
  // Contact state (one proxy).
  bool in_contact_ = false;
  std::int32_t contact_region_ = -1;
  double contact_onset_t_s_ = 0.0;
  double contact_peak_force_n_ = 0.0;
  int strike_voice_ = -1;
  // Output stage.
  double volume_target_ = 1.0;
  double volume_ = 1.0;
  double limiter_gain_ = 1.0;
  double release_coeff_ = 0.0;  // limiter recovery per sample
  double smooth_coeff_ = 0.0;   // gain smoothing per sample (~2 ms)
  double fade_step_ = 0.0;      // per-sample gain step of a 10 ms release fade
  double slide_coeff_ = 0.0;    // sliding loudness smoothing per sample (~10 ms)
  std::uint64_t slide_timeout_frames_ = 0;
  std::uint64_t frames_ = 0;
  MixerStats stats_{};
};

}  // namespace hc::audio
