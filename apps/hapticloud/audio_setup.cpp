#ifdef HC_HAVE_AUDIO

#include "audio_setup.hpp"

#include <cmath>

namespace hc::app {
namespace {

audio::Material material_from(const pipeline::AudioMaterialSpec& m) {
  audio::Material out = audio::material_preset(m.preset);
  const auto set = [](double& field, double v) {
    if (!std::isnan(v)) field = v;
  };
  set(out.slide_gain, m.slide_gain);
  set(out.resonance_hz, m.resonance_hz);
  set(out.q, m.q);
  set(out.grain_m, m.grain_m);
  set(out.roughness, m.roughness);
  set(out.speed_ref_m_per_s, m.speed_ref_m_per_s);
  set(out.texture_ref_m, m.texture_ref_m);
  return out;
}

}  // namespace

audio::AudioConfig audio_config_from(const pipeline::AudioSpec& spec) {
  audio::AudioConfig c;
  c.enabled = spec.enabled;
  c.sample_rate_hz = spec.sample_rate_hz;
  c.master_gain = spec.master_gain;
  c.limiter_threshold = std::pow(10.0, spec.limiter_threshold_dbfs / 20.0);
  c.limiter_release_s = spec.limiter_release_s;
  c.sa_hz = spec.sa_hz;
  c.tone_seconds = spec.tone_seconds;
  c.region_cell_m = spec.region_cell_m;
  c.label_image = spec.label_image;
  c.force.threshold_n = spec.force_threshold_n;
  c.force.full_force_n = spec.force_full_n;
  c.force.min_gain = spec.force_min_gain;
  c.force.strike_window_s = spec.strike_window_s;
  c.slide_enabled = spec.slide_enabled;
  c.default_material = material_from(spec.slide_material);
  for (const pipeline::AudioRegionSpec& r : spec.regions) {
    audio::RegionConfig out;
    out.name = r.name;
    if (r.shape == "polygon") {
      out.shape.kind = audio::ShapeKind::kPolygon;
      out.shape.polygon_m = r.polygon_m;
    } else if (r.shape == "label") {
      out.shape.kind = audio::ShapeKind::kLabel;
      out.shape.label = r.label;
    } else {
      out.shape.kind = audio::ShapeKind::kBox;
      out.shape.x_min_m = r.box_m[0];
      out.shape.y_min_m = r.box_m[1];
      out.shape.x_max_m = r.box_m[2];
      out.shape.y_max_m = r.box_m[3];
    }
    out.clip = r.clip;
    out.note = audio::note_from_string(r.note);
    out.gain = r.gain;
    out.pitch = r.pitch;
    out.retrigger = r.retrigger;
    out.trigger_on_enter = r.trigger_on_enter;
    out.mode = r.mode == "continuous" ? audio::PlayMode::kContinuous : audio::PlayMode::kOneShot;
    out.material = material_from(r.material);
    c.regions.push_back(std::move(out));
  }
  return c;
}

}  // namespace hc::app

#endif
