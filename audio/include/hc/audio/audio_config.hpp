#pragma once
/// @file audio_config.hpp
/// Plain, validated settings of the contact sounds (issue 7): audio regions in the grid frame,
/// their clips and options, the force → gain mapping, the limiter and the sliding-sound
/// materials. No YAML here: the run config's `audio:` section (docs/config.md) is parsed by the
/// config reader (hc::pipeline) straight into these structs, and check() below is the one place
/// their ranges are checked. This header and audio_config.cpp form the small target
/// hc::audio_config (standard library and hc::common only), which hc::pipeline links without
/// linking the audio engine.

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace hc::audio {

/// The seven notes of the Indian scale (svaras), Sa to Ni.
enum class Note : std::uint8_t { kSa = 0, kRe, kGa, kMa, kPa, kDha, kNi };

/// Parses "Sa", "Re", "Ga", "Ma", "Pa", "Dha", "Ni" (case-insensitive).
/// @throws hc::ConfigError naming the value and the allowed set.
Note note_from_string(const std::string& name);
const char* to_string(Note note) noexcept;
/// Frequency [Hz] of `note` in just intonation over the tonic Sa = sa_hz (ratios 1, 9/8, 5/4,
/// 4/3, 3/2, 5/3, 15/8). Real-time: yes.
double note_frequency_hz(Note note, double sa_hz) noexcept;

/// Where a region is, in the grid frame (x, y) [m]; z is ignored (the grid looks along −z).
enum class ShapeKind : std::uint8_t {
  kBox = 0,   ///< axis-aligned box [x_min, x_max] × [y_min, y_max]
  kPolygon,   ///< simple polygon (even-odd rule), ≥ 3 vertices
  kLabel,     ///< the cells of the label image whose value equals `label`
};

struct RegionShape {
  ShapeKind kind = ShapeKind::kBox;
  double x_min_m = 0.0, y_min_m = 0.0, x_max_m = 0.0, y_max_m = 0.0;  ///< kBox [m]
  std::vector<std::array<double, 2>> polygon_m;                       ///< kPolygon vertices (x, y) [m]
  std::int32_t label = 0;                                             ///< kLabel value ≥ 1
};

/// What an onset plays.
enum class PlayMode : std::uint8_t {
  kOneShot = 0,  ///< the clip plays once from an onset (the paper)
  kContinuous,   ///< the clip loops while the proxy touches the region; gain follows the force
};

/// Sound of sliding over a material (beyond the paper): noise and grains through a resonator,
/// loudness from slip speed, texture amplitude under the proxy and force (docs/audio.md).
struct Material {
  std::string name = "granite";
  double slide_gain = 0.25;         ///< [0, 4] loudness of the sliding sound [-]; 0 = silent
  double resonance_hz = 2200.0;     ///< (20, 20000) centre of the resonator [Hz]
  double q = 4.0;                   ///< [0.3, 100] resonator quality factor [-]
  double grain_m = 0.0005;          ///< (0, 0.1] mean distance between grain clicks [m]
  double roughness = 0.5;           ///< [0, 1] 0 = smooth hiss, 1 = grains only [-]
  double speed_ref_m_per_s = 0.1;   ///< (0, 10] slip speed of full loudness [m/s]
  double texture_ref_m = 0.0002;    ///< (0, 0.1] texture RMS of full loudness [m]
};

/// Material presets: "granite", "sandstone", "marble", "bronze", "wood".
/// @throws hc::ConfigError naming the value and the allowed set.
Material material_preset(const std::string& name);

/// One audio region.
struct RegionConfig {
  std::string name;                ///< shown in reports; unique
  RegionShape shape;
  std::filesystem::path clip;      ///< WAV/FLAC/OGG; empty = a synthesised struck-stone tone
  Note note = Note::kSa;           ///< the synthesised tone's note (when `clip` is empty)
  double gain = 1.0;               ///< [0, 16] region gain [-]
  double pitch = 1.0;              ///< [0.25, 4] playback-rate factor (2 = an octave up) [-]
  bool retrigger = true;           ///< a new onset after a release restarts a sounding clip
  bool trigger_on_enter = true;    ///< sliding into the region while in contact counts as an onset
  PlayMode mode = PlayMode::kOneShot;
  Material material;               ///< the sliding sound on this region
};

/// Force → gain (docs/audio.md): g(F) = clamp(F / full_force_n, min_gain, 1) for F ≥ threshold_n,
/// else the onset is silent. F is the largest |force| seen on the contact within strike_window_s
/// of its onset (the servo ramps force in, so the onset tick's own force is tiny).
struct ForceGainMap {
  double threshold_n = 0.0;        ///< [0, 100] onsets below this force are silent [N]
  double full_force_n = 3.0;       ///< (0, 100] force of full gain [N]
  double min_gain = 0.1;           ///< [0, 1] gain of the weakest audible onset [-]
  double strike_window_s = 0.05;   ///< [0, 1] the gain may rise with the force this long [s]
};

/// Settings of the whole audio side.
struct AudioConfig {
  bool enabled = true;
  int sample_rate_hz = 48000;           ///< [8000, 192000]
  double master_gain = 0.5;             ///< [0, 4] before the limiter (0.5 = 6 dB headroom) [-]
  double limiter_threshold = 0.891;     ///< (0, 1] peak limit, linear (0.891 = −1 dBFS) [-]
  double limiter_release_s = 0.05;      ///< (0, 10] limiter recovery time constant [s]
  double sa_hz = 196.0;                 ///< (20, 4000) tonic of the synthesised notes [Hz]
  double tone_seconds = 2.5;            ///< (0.05, 20] length of a synthesised tone [s]
  double region_cell_m = 0.0005;        ///< (0, 1] raster cell of the region map when no grid is given [m]
  std::filesystem::path label_image;    ///< 8/16-bit PGM aligned with the grid (row 0 = grid row 0), or empty
  ForceGainMap force;
  bool slide_enabled = true;            ///< the continuous sliding sound
  Material default_material;            ///< sliding outside every region
  std::vector<RegionConfig> regions;
};

/// A setting out of range: `key` is its run-config key below `audio.` (e.g. "master_gain",
/// "limiter.threshold_dbfs", "regions[2].gain"), `message` the value and what was expected
/// ("= 9: expected a number in [0, 4]").
struct ConfigIssue {
  std::string key;
  std::string message;
};

/// Checks ranges, shapes, label use and uniqueness of names: the first violation, or nothing.
/// The one range check of the audio settings (the config reader and validate() both use it).
/// Real-time: no.
std::optional<ConfigIssue> check(const AudioConfig& config);

/// check() as an exception. @throws hc::ConfigError "audio.<key> <message>". Real-time: no.
void validate(const AudioConfig& config);

}  // namespace hc::audio
