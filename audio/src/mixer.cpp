#include "hc/audio/mixer.hpp"

#include "hc/common/error.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace hc::audio {
namespace {

/// Texture RMS over a (2·kHalf + 1)² window, NaN ignored (summed-area tables of h and h²).
constexpr int kHalf = 2;

std::vector<float> texture_rms(const HeightField& tex) {
  const int rows = tex.rows(), cols = tex.cols();
  const auto W = static_cast<std::size_t>(cols) + 1;
  std::vector<double> s2((static_cast<std::size_t>(rows) + 1) * W, 0.0);
  std::vector<double> s1(s2.size(), 0.0), cnt(s2.size(), 0.0);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      const double h = tex.at(r, c);
      const bool ok = std::isfinite(h);
      const std::size_t i = (static_cast<std::size_t>(r) + 1) * W + static_cast<std::size_t>(c) + 1;
      s1[i] = (ok ? h : 0.0) + s1[i - 1] + s1[i - W] - s1[i - W - 1];
      s2[i] = (ok ? h * h : 0.0) + s2[i - 1] + s2[i - W] - s2[i - W - 1];
      cnt[i] = (ok ? 1.0 : 0.0) + cnt[i - 1] + cnt[i - W] - cnt[i - W - 1];
    }
  }
  const auto box = [&](const std::vector<double>& s, int r0, int c0, int r1, int c1) {
    const auto a = static_cast<std::size_t>(r0), b = static_cast<std::size_t>(c0);
    const auto e = static_cast<std::size_t>(r1) + 1, f = static_cast<std::size_t>(c1) + 1;
    return s[e * W + f] - s[a * W + f] - s[e * W + b] + s[a * W + b];
  };
  std::vector<float> out(tex.geometry().cell_count(), 0.0F);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      const int r0 = std::max(0, r - kHalf), r1 = std::min(rows - 1, r + kHalf);
      const int c0 = std::max(0, c - kHalf), c1 = std::min(cols - 1, c + kHalf);
      const double n = box(cnt, r0, c0, r1, c1);
      if (n < 1.0) continue;
      const double mean = box(s1, r0, c0, r1, c1) / n;
      const double var = std::max(0.0, box(s2, r0, c0, r1, c1) / n - mean * mean);
      out[static_cast<std::size_t>(r) * static_cast<std::size_t>(cols) + static_cast<std::size_t>(c)] =
          static_cast<float>(std::sqrt(var));
    }
  }
  return out;
}

double clamp01(double v) noexcept { return v < 0.0 ? 0.0 : (v > 1.0 ? 1.0 : v); }

}  // namespace

double AudioScene::texture_rms_at(double x_m, double y_m) const noexcept {
  if (texture_rms_m.empty()) return 0.0;
  const GridGeometry& g = texture_grid;
  const double cu = (x_m - g.x0_m) / g.cell_size_m + 0.5;
  const double cv = (y_m - g.y0_m) / g.cell_size_m + 0.5;
  if (!(cu >= 0.0 && cv >= 0.0 && cu < g.cols && cv < g.rows)) return 0.0;
  return texture_rms_m[static_cast<std::size_t>(static_cast<int>(cv)) * static_cast<std::size_t>(g.cols) +
                       static_cast<std::size_t>(static_cast<int>(cu))];
}

std::shared_ptr<const AudioScene> build_audio_scene(const AudioConfig& config, const SceneInputs& inputs) {
  validate(config);
  auto scene = std::make_shared<AudioScene>();
  scene->config = config;
  const int rate = config.sample_rate_hz;
  for (const RegionConfig& r : config.regions) {
    if (r.clip.empty()) {
      Clip c = synth_stone_tone(note_frequency_hz(r.note, config.sa_hz) * r.pitch, rate, config.tone_seconds);
      c.source = std::string("synth:") + to_string(r.note);
      scene->clips.push_back(std::move(c));
    } else {
      try {
        scene->clips.push_back(decode_clip(r.clip, rate, r.pitch));
      } catch (const InputError& e) {
        throw InputError(std::string(e.what()) + " [audio region '" + r.name + "']");
      }
    }
  }
  LabelImage labels;
  const bool have_labels = !config.label_image.empty();
  if (have_labels) labels = read_label_pgm(config.label_image);
  scene->regions = RegionMap(config.regions, inputs.grid, config.region_cell_m, have_labels ? &labels : nullptr);
  if (inputs.texture != nullptr && inputs.texture->rows() > 0 && inputs.texture->cols() > 0) {
    scene->texture_grid = inputs.texture->geometry();
    scene->texture_rms_m = texture_rms(*inputs.texture);
  }
  return scene;
}

double force_to_gain(const ForceGainMap& map, double force_n) noexcept {
  if (!(force_n >= map.threshold_n) || !std::isfinite(force_n)) return 0.0;
  const double g = force_n / map.full_force_n;
  return g < map.min_gain ? map.min_gain : (g > 1.0 ? 1.0 : g);
}

Mixer::Mixer(std::shared_ptr<const AudioScene> scene) : scene_(std::move(scene)) {
  if (!scene_) throw ConfigError("audio: Mixer needs a scene (build_audio_scene)");
  const double rate = scene_->config.sample_rate_hz;
  smooth_coeff_ = 1.0 - std::exp(-1.0 / (0.002 * rate));
  slide_coeff_ = 1.0 - std::exp(-1.0 / (0.01 * rate));
  release_coeff_ = 1.0 - std::exp(-1.0 / (scene_->config.limiter_release_s * rate));
  fade_step_ = 1.0 / (0.01 * rate);
  slide_timeout_frames_ = static_cast<std::uint64_t>(0.03 * rate);
  set_resonator(scene_->config.default_material);
}

void Mixer::set_volume(double volume) noexcept {
  volume_target_ = std::isfinite(volume) ? std::clamp(volume, 0.0, 4.0) : 0.0;
}

int Mixer::active_voices() const noexcept {
  int n = 0;
  for (const Voice& v : voices_) n += v.active ? 1 : 0;
  return n;
}

void Mixer::set_resonator(const Material& m) noexcept {
  const double rate = scene_->config.sample_rate_hz;
  const double f = std::min(m.resonance_hz, 0.45 * rate);
  const double w = 2.0 * std::numbers::pi * f / rate;
  const double r = std::exp(-std::numbers::pi * (f / m.q) / rate);
  slide_.a1 = 2.0 * r * std::cos(w);
  slide_.a2 = r * r;
  // Normalises the resonator's peak gain to about 1.
  slide_.b0 = (1.0 - r) * std::sqrt(1.0 - 2.0 * r * std::cos(2.0 * w) + r * r);
  slide_.material = &m;
}

float Mixer::next_noise() noexcept {
  slide_.rng = slide_.rng * 1664525u + 1013904223u;
  return static_cast<float>(static_cast<double>(slide_.rng >> 8) / 8388608.0 - 1.0);
}

void Mixer::start_voice(std::int32_t region, double gain) noexcept {
  int slot = -1;
  for (int i = 0; i < kMaxVoices; ++i) {
    if (!voices_[static_cast<std::size_t>(i)].active) {
      slot = i;
      break;
    }
  }
  if (slot < 0) {
    std::uint64_t oldest = ~std::uint64_t{0};
    for (int i = 0; i < kMaxVoices; ++i) {
      if (voices_[static_cast<std::size_t>(i)].started < oldest) {
        oldest = voices_[static_cast<std::size_t>(i)].started;
        slot = i;
      }
    }
    ++stats_.voices_stolen;
  }
  Voice& v = voices_[static_cast<std::size_t>(slot)];
  const RegionConfig& rc = scene_->config.regions[static_cast<std::size_t>(region)];
  v = Voice{};
  v.active = true;
  v.loop = rc.mode == PlayMode::kContinuous;
  v.region = region;
  v.gain = v.gain_target = gain;
  v.started = frames_;
  strike_voice_ = slot;
  ++stats_.onsets_played;
}

void Mixer::release_region_voices(std::int32_t region, bool all) noexcept {
  for (Voice& v : voices_) {
    if (v.active && v.region == region && (all || v.loop)) v.releasing = true;
  }
}

void Mixer::update_slide(const haptics::ContactEvent& e, std::int32_t region) noexcept {
  const AudioConfig& c = scene_->config;
  if (!c.slide_enabled) return;
  const Material& m = region >= 0 ? c.regions[static_cast<std::size_t>(region)].material : c.default_material;
  if (!slide_.active || &m != slide_.material) set_resonator(m);
  slide_.active = true;
  const double speed = std::isfinite(e.speed_m_per_s) ? e.speed_m_per_s : 0.0;
  const double force = e.force_n.eigen().norm();
  const double speed_f = clamp01(speed / m.speed_ref_m_per_s);
  // Without a texture map every surface counts as moderately rough; a smooth spot keeps 20 %.
  const double tex_f = scene_->texture_rms_m.empty()
                           ? 0.5
                           : std::max(0.2, clamp01(scene_->texture_rms_at(e.position_m.x, e.position_m.y) / m.texture_ref_m));
  const double force_f = clamp01(std::isfinite(force) ? force / c.force.full_force_n : 0.0);
  slide_.level_target = m.slide_gain * speed_f * tex_f * force_f;
  slide_.grain_rate_hz = speed / m.grain_m;
  slide_.last_event_frame = frames_;
}

void Mixer::handle(const haptics::ContactEvent& e) noexcept {
  ++stats_.events;
  const AudioConfig& c = scene_->config;
  const std::int32_t region = scene_->regions.lookup(e.position_m.x, e.position_m.y);
  const double force = std::isfinite(e.force_n.x + e.force_n.y + e.force_n.z) ? e.force_n.eigen().norm() : 0.0;
  const auto trigger = [&](std::int32_t id) {
    if (id < 0) {
      ++stats_.onsets_silent;
      return;
    }
    const RegionConfig& rc = c.regions[static_cast<std::size_t>(id)];
    const double g = force_to_gain(c.force, contact_peak_force_n_) * rc.gain;
    if (!(g > 0.0)) {
      ++stats_.onsets_silent;
      return;
    }
    for (int i = 0; i < kMaxVoices; ++i) {
      Voice& v = voices_[static_cast<std::size_t>(i)];
      if (!v.active || v.releasing || v.region != id) continue;
      if (rc.mode == PlayMode::kContinuous || !rc.retrigger) {
        // Still sounding: keep it (a loop follows the new force; a one-shot is not restarted).
        if (rc.mode == PlayMode::kContinuous) v.gain_target = g;
        strike_voice_ = i;
        return;
      }
      v.releasing = true;  // retrigger: fade the old strike out, start a new one
    }
    start_voice(id, g);
  };

  switch (e.type) {
    case haptics::ContactEventType::kOnset:
      in_contact_ = true;
      contact_region_ = region;
      contact_onset_t_s_ = e.t_s;
      contact_peak_force_n_ = force;
      strike_voice_ = -1;
      trigger(region);
      slide_.level_target = 0.0;
      slide_.level = 0.0;
      update_slide(e, region);
      break;
    case haptics::ContactEventType::kSlide:
    case haptics::ContactEventType::kPress:  // speed 0: the force grows, the slide sound fades
      if (!in_contact_ || region != contact_region_) {
        // Entered another region while in contact (or the onset was lost): a new strike.
        if (in_contact_ && contact_region_ >= 0) release_region_voices(contact_region_, false);
        const bool was_in_contact = in_contact_;
        in_contact_ = true;
        contact_region_ = region;
        contact_onset_t_s_ = e.t_s;
        contact_peak_force_n_ = force;
        strike_voice_ = -1;
        if (region >= 0 && (!was_in_contact || c.regions[static_cast<std::size_t>(region)].trigger_on_enter)) {
          trigger(region);
        }
      } else if (region >= 0) {
        const RegionConfig& rc = c.regions[static_cast<std::size_t>(region)];
        if (e.t_s - contact_onset_t_s_ <= c.force.strike_window_s && force > contact_peak_force_n_) {
          contact_peak_force_n_ = force;
          if (strike_voice_ >= 0) {
            Voice& v = voices_[static_cast<std::size_t>(strike_voice_)];
            if (v.active && !v.releasing && v.region == region) v.gain_target = force_to_gain(c.force, force) * rc.gain;
          }
        }
        if (rc.mode == PlayMode::kContinuous) {
          for (Voice& v : voices_) {
            if (v.active && v.loop && !v.releasing && v.region == region) {
              v.gain_target = force_to_gain(c.force, force) * rc.gain;
            }
          }
        }
      }
      update_slide(e, region);
      break;
    case haptics::ContactEventType::kRelease:
      if (contact_region_ >= 0) release_region_voices(contact_region_, false);
      in_contact_ = false;
      contact_region_ = -1;
      strike_voice_ = -1;
      slide_.level_target = 0.0;
      break;
  }
}

void Mixer::render(std::span<float> out) noexcept {
  const std::size_t n = out.size();
  std::fill(out.begin(), out.end(), 0.0F);
  // Voices: one pass per voice over the block.
  for (Voice& v : voices_) {
    if (!v.active) continue;
    const std::vector<float>& clip = scene_->clips[static_cast<std::size_t>(v.region)].samples;
    const std::size_t len = clip.size();
    for (std::size_t i = 0; i < n; ++i) {
      if (v.releasing) {
        v.gain -= fade_step_;
        if (v.gain <= 0.0) {
          v.active = false;
          break;
        }
      } else {
        v.gain += (v.gain_target - v.gain) * smooth_coeff_;
      }
      if (v.pos >= len) {
        if (!v.loop || len == 0) {
          v.active = false;
          break;
        }
        v.pos = 0;
      }
      out[i] += static_cast<float>(v.gain * clip[v.pos++]);
    }
  }
  // Sliding sound: noise and grains through the material's resonator.
  if (slide_.active) {
    const double rate = scene_->config.sample_rate_hz;
    const double rough = slide_.material->roughness;
    for (std::size_t i = 0; i < n; ++i) {
      if (frames_ + i - slide_.last_event_frame > slide_timeout_frames_) slide_.level_target = 0.0;
      slide_.level += (slide_.level_target - slide_.level) * slide_coeff_;
      double x = (1.0 - rough) * next_noise();
      const double p = slide_.grain_rate_hz / rate;
      if (rough > 0.0 && 0.5 * (next_noise() + 1.0) < p) x += rough * 4.0 * next_noise();
      const double y = slide_.b0 * x + slide_.a1 * slide_.y1 - slide_.a2 * slide_.y2;
      slide_.y2 = slide_.y1;
      slide_.y1 = y;
      out[i] += static_cast<float>(slide_.level * y);
    }
    if (slide_.level < 1e-6 && slide_.level_target == 0.0) {
      slide_.active = false;
      slide_.level = 0.0;
      slide_.y1 = slide_.y2 = 0.0;
    }
  }
  // Output stage: master gain and volume, then a peak limiter with instant attack.
  const double master = scene_->config.master_gain;
  const double thr = scene_->config.limiter_threshold;
  for (std::size_t i = 0; i < n; ++i) {
    volume_ += (volume_target_ - volume_) * smooth_coeff_;
    const double x = out[i] * master * volume_;
    const double a = std::abs(x);
    const double needed = a > thr ? thr / a : 1.0;
    limiter_gain_ += (1.0 - limiter_gain_) * release_coeff_;
    if (needed < limiter_gain_) limiter_gain_ = needed;
    stats_.limiter_min_gain = std::min(stats_.limiter_min_gain, limiter_gain_);
    const double y = std::clamp(x * limiter_gain_, -thr, thr);
    out[i] = std::isfinite(y) ? static_cast<float>(y) : 0.0F;
  }
  frames_ += n;
}

}  // namespace hc::audio
