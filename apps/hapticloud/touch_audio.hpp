#pragma once
/// @file touch_audio.hpp
/// Contact sounds of a `hapticloud touch` session (issue 7): the app's wiring between a scripted
/// session (hc::session, which knows no audio) and hc::audio. Only in builds with hc::audio.

#ifdef HC_HAVE_AUDIO

#include "hc/audio/engine.hpp"
#include "hc/common/scene.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/session/touch_session.hpp"

#include <memory>
#include <string>

namespace hc::app {

class TouchAudio {
 public:
  /// Decodes the clips and rasterises the regions of `spec` (the run config's audio: section;
  /// nullopt: no section, the sliding sound only) on
  /// the scene's grid BEFORE the session, so a bad clip stops here. `wav_out`: offline render of
  /// the session's contact sounds (empty: none); `live`: "default", "loopback" or an OpenAL
  /// device name (empty: no live playback).
  /// @throws hc::ConfigError / hc::InputError from hc::audio naming the key or file.
  TouchAudio(const std::optional<audio::AudioConfig>& spec, const Scene& scene, std::string wav_out, std::string live);
  ~TouchAudio();

  /// Starts live playback (when asked for) and returns the hooks that feed it the contact events
  /// and carry the region ids into them. The object must outlive the session.
  session::TouchSessionHooks start();
  /// Stops live playback, writes the WAV (sample round((t − t0)·rate), t0 = the first tick) and
  /// returns the summary members ("audio_live", "audio") as a JSON object text; prints a line each.
  std::string finish(const session::TouchSessionResult& result, double servo_rate_hz);

 private:
  std::shared_ptr<const audio::AudioScene> scene_;
  HeightField region_layer_;
  std::unique_ptr<audio::AudioEngine> live_;
  std::string wav_out_, live_name_;
};

}  // namespace hc::app

#endif
