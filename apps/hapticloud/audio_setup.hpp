#pragma once
/// @file audio_setup.hpp
/// The app's bridge between the run config's `audio:` section (read by hc::pipeline) and
/// hc::audio (which knows nothing of YAML or the pipeline). Used by `touch` and `explore`.

#ifdef HC_HAVE_AUDIO

#include "hc/audio/audio_config.hpp"
#include "hc/pipeline/config.hpp"

namespace hc::app {

/// pipeline::AudioSpec → hc::audio::AudioConfig: material presets expanded and overridden,
/// −dBFS threshold to linear, note names parsed. Ranges are checked again by
/// hc::audio::build_audio_scene. @throws hc::ConfigError for an unknown note or material.
audio::AudioConfig audio_config_from(const pipeline::AudioSpec& spec);

}  // namespace hc::app

#endif
