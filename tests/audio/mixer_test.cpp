// The contact-sound mixer through the offline renderer: onset timing, force → gain, limiter,
// silence, retrigger and continuous modes, the sliding sound.

#include "hc/audio/mixer.hpp"
#include "hc/audio/offline.hpp"
#include "hc/common/error.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace hc::audio {
namespace {

using haptics::ContactEvent;
using haptics::ContactEventType;

constexpr int kRate = 48000;

/// Seven 10 mm boxes side by side along x (x from 0 to 0.07 m), one note each, no slide sound.
AudioConfig seven_boxes() {
  AudioConfig c;
  c.sample_rate_hz = kRate;
  c.tone_seconds = 0.5;
  c.slide_enabled = false;
  for (int i = 0; i < 7; ++i) {
    RegionConfig r;
    r.name = std::string("pillar") + std::to_string(i);
    r.shape.kind = ShapeKind::kBox;
    r.shape.x_min_m = 0.01 * i + 0.001;
    r.shape.x_max_m = 0.01 * (i + 1) - 0.001;
    r.shape.y_min_m = -0.005;
    r.shape.y_max_m = 0.005;
    r.note = static_cast<Note>(i);
    c.regions.push_back(r);
  }
  return c;
}

ContactEvent event(ContactEventType type, double t_s, double x_m, double force_n, double speed = 0.0) {
  ContactEvent e;
  e.type = type;
  e.t_s = t_s;
  e.position_m = haptics::Vec3{x_m, 0.0, 0.0};
  e.force_n = haptics::Vec3{0.0, 0.0, force_n};
  e.speed_m_per_s = speed;
  return e;
}

std::size_t first_nonzero(const std::vector<float>& s, float eps = 1e-6F) {
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (std::abs(s[i]) > eps) return i;
  }
  return s.size();
}

float peak(const std::vector<float>& s, std::size_t from = 0, std::size_t to = ~std::size_t{0}) {
  float p = 0.0F;
  for (std::size_t i = from; i < std::min(to, s.size()); ++i) p = std::max(p, std::abs(s[i]));
  return p;
}

TEST(AudioMixer, OnsetStartsAtTheEventSampleWithinOneMillisecond) {
  const auto scene = build_audio_scene(seven_boxes());
  for (double t : {0.1, 0.2503, 0.77771}) {
    const std::vector<ContactEvent> ev = {event(ContactEventType::kOnset, 10.0 + t, 0.035, 2.0)};
    const std::vector<float> out = render_offline(scene, ev, 10.0, 1.0, 0.0);
    // The event's sample, rounded to the nearest: t · rate (independent of sample_of_time).
    const auto expected = static_cast<std::size_t>(std::llround(t * kRate));
    const std::size_t got = first_nonzero(out);
    ASSERT_LT(got, out.size()) << "no sound at all for t = " << t;
    EXPECT_GE(got, expected) << "sound before the event";
    EXPECT_LE(got - expected, static_cast<std::size_t>(kRate / 1000)) << "more than 1 ms late";
    EXPECT_EQ(peak(out, 0, expected), 0.0F);
  }
}

TEST(AudioMixer, TwoOnsetsEachAtTheirSample) {
  AudioConfig c = seven_boxes();
  c.regions[0].clip.clear();
  const auto scene = build_audio_scene(c);
  const std::vector<ContactEvent> ev = {event(ContactEventType::kOnset, 0.1, 0.005, 2.0),
                                        event(ContactEventType::kRelease, 0.11, 0.005, 0.0),
                                        event(ContactEventType::kOnset, 0.6, 0.065, 2.0)};
  const std::vector<float> a = render_offline(scene, std::span(ev).first(2), 0.0, 1.2, 0.0);
  const std::vector<float> ab = render_offline(scene, ev, 0.0, 1.2, 0.0);
  const auto second = static_cast<std::size_t>(std::llround(0.6 * kRate));
  // Up to the second onset both renders agree exactly; the difference starts at its sample.
  std::size_t diff = ab.size();
  for (std::size_t i = 0; i < ab.size(); ++i) {
    if (a[i] != ab[i]) {
      diff = i;
      break;
    }
  }
  EXPECT_GE(diff, second);
  EXPECT_LE(diff - second, static_cast<std::size_t>(kRate / 1000));
}

TEST(AudioMixer, GainGrowsMonotonicallyWithForceUpToTheLimit) {
  const auto scene = build_audio_scene(seven_boxes());
  const ForceGainMap& map = scene->config.force;
  float previous = 0.0F;
  double previous_force = 0.0;
  for (double f : {0.1, 0.3, 0.6, 1.0, 1.5, 2.0, 2.5, 2.9, 3.0, 4.0, 8.0}) {
    const std::vector<ContactEvent> ev = {event(ContactEventType::kOnset, 0.0, 0.035, f)};
    const float p = peak(render_offline(scene, ev, 0.0, 0.3, 0.0));
    EXPECT_GE(p, previous) << "force " << f << " is quieter than " << previous_force;
    if (f * 1.0 <= map.full_force_n && previous_force / map.full_force_n >= map.min_gain) {
      EXPECT_GT(p, previous) << "force " << f << " not louder than " << previous_force;
    }
    EXPECT_NEAR(force_to_gain(map, f), std::clamp(f / map.full_force_n, map.min_gain, 1.0), 1e-12);
    previous = p;
    previous_force = f;
  }
  // Proportional between the limits: twice the force, twice the peak (no limiting here).
  const auto at = [&](double f) {
    const std::vector<ContactEvent> ev = {event(ContactEventType::kOnset, 0.0, 0.035, f)};
    return peak(render_offline(scene, ev, 0.0, 0.3, 0.0));
  };
  EXPECT_NEAR(at(2.0) / at(1.0), 2.0, 1e-3);
}

TEST(AudioMixer, BelowTheThresholdAnOnsetIsSilent) {
  AudioConfig c = seven_boxes();
  c.force.threshold_n = 0.5;
  c.force.strike_window_s = 0.0;
  const auto scene = build_audio_scene(c);
  const std::vector<ContactEvent> ev = {event(ContactEventType::kOnset, 0.0, 0.035, 0.2)};
  MixerStats stats;
  EXPECT_EQ(peak(render_offline(scene, ev, 0.0, 0.3, 0.0, &stats)), 0.0F);
  EXPECT_EQ(stats.onsets_silent, 1u);
}

TEST(AudioMixer, TheStrikeGainRisesWithTheForceInsideTheStrikeWindow) {
  const auto scene = build_audio_scene(seven_boxes());
  // The servo ramps force in: the onset tick's force is tiny, the force 20 ms later is not.
  const std::vector<ContactEvent> weak = {event(ContactEventType::kOnset, 0.0, 0.035, 0.02)};
  std::vector<ContactEvent> strong = weak;
  strong.push_back(event(ContactEventType::kSlide, 0.02, 0.035, 3.0, 0.01));
  const float p_weak = peak(render_offline(scene, weak, 0.0, 0.4, 0.0));
  const float p_strong = peak(render_offline(scene, strong, 0.0, 0.4, 0.0));
  EXPECT_GT(p_strong, 5.0F * p_weak);
  // A straight press that sticks sends press events (speed 0): they raise the strike as well.
  std::vector<ContactEvent> pressed = weak;
  pressed.push_back(event(ContactEventType::kPress, 0.02, 0.035, 3.0, 0.0));
  EXPECT_NEAR(peak(render_offline(scene, pressed, 0.0, 0.4, 0.0)), p_strong, 0.05F * p_strong);
  // Outside the window the force no longer changes the strike.
  std::vector<ContactEvent> late = weak;
  late.push_back(event(ContactEventType::kSlide, 0.2, 0.035, 3.0, 0.01));
  EXPECT_NEAR(peak(render_offline(scene, late, 0.0, 0.4, 0.0)), p_weak, 1e-6);
}

TEST(AudioMixer, NoClippingWithEveryRegionSoundingAtFullForce) {
  AudioConfig c = seven_boxes();
  for (auto& r : c.regions) r.gain = 16.0;
  c.master_gain = 4.0;
  const auto scene = build_audio_scene(c);
  std::vector<ContactEvent> ev;
  for (int i = 0; i < 7; ++i) {
    ev.push_back(event(ContactEventType::kOnset, 0.01 * i, 0.01 * i + 0.005, 50.0));
    ev.push_back(event(ContactEventType::kRelease, 0.01 * i + 0.005, 0.01 * i + 0.005, 0.0));
  }
  MixerStats stats;
  const std::vector<float> out = render_offline(scene, ev, 0.0, 0.5, 0.0, &stats);
  EXPECT_LE(peak(out), static_cast<float>(c.limiter_threshold));
  EXPECT_LE(peak(out), 1.0F);  // ≤ 0 dBFS
  EXPECT_LT(stats.limiter_min_gain, 0.2);  // the limiter did work here
  EXPECT_EQ(stats.onsets_played, 7u);
  // With the default gains the headroom alone keeps seven notes below the limit.
  const std::vector<float> plain = render_offline(build_audio_scene(seven_boxes()), ev, 0.0, 0.5, 0.0);
  EXPECT_LE(peak(plain), 1.0F);
}

TEST(AudioMixer, SilenceWithoutContact) {
  AudioConfig c = seven_boxes();
  c.slide_enabled = true;
  const auto scene = build_audio_scene(c);
  const std::vector<float> out = render_offline(scene, {}, 0.0, 1.0, 0.5);
  EXPECT_EQ(out.size(), static_cast<std::size_t>(1.5 * kRate));
  EXPECT_EQ(peak(out), 0.0F);
  // An onset outside every region with the sliding sound off: silent too.
  AudioConfig quiet = seven_boxes();
  const std::vector<ContactEvent> ev = {event(ContactEventType::kOnset, 0.1, 0.5, 3.0),
                                        event(ContactEventType::kRelease, 0.3, 0.5, 0.0)};
  EXPECT_EQ(peak(render_offline(build_audio_scene(quiet), ev, 0.0, 1.0)), 0.0F);
}

TEST(AudioMixer, ContinuousModeLoopsWhileTouchingAndStopsAfterRelease) {
  AudioConfig c = seven_boxes();
  c.regions[3].mode = PlayMode::kContinuous;
  c.tone_seconds = 0.1;
  const auto scene = build_audio_scene(c);
  std::vector<ContactEvent> ev = {event(ContactEventType::kOnset, 0.0, 0.035, 3.0)};
  for (int k = 1; k < 100; ++k) ev.push_back(event(ContactEventType::kSlide, 0.01 * k, 0.035, 3.0, 0.01));
  ev.push_back(event(ContactEventType::kRelease, 1.0, 0.035, 0.0));
  const std::vector<float> out = render_offline(scene, ev, 0.0, 1.5, 0.0);
  // Still sounding long after the 0.1 s clip would have ended…
  EXPECT_GT(peak(out, static_cast<std::size_t>(0.8 * kRate), static_cast<std::size_t>(0.95 * kRate)), 0.01F);
  // …and silent 20 ms after the release (10 ms fade).
  EXPECT_EQ(peak(out, static_cast<std::size_t>(1.02 * kRate)), 0.0F);
}

TEST(AudioMixer, RetriggerRestartsANoteAfterAReleaseUnlessDisabled) {
  const auto render = [](bool retrigger) {
    AudioConfig c = seven_boxes();
    c.regions[3].retrigger = retrigger;
    const std::vector<ContactEvent> ev = {event(ContactEventType::kOnset, 0.0, 0.035, 3.0),
                                          event(ContactEventType::kRelease, 0.05, 0.035, 0.0),
                                          event(ContactEventType::kOnset, 0.2, 0.035, 3.0)};
    MixerStats stats;
    render_offline(build_audio_scene(c), ev, 0.0, 0.5, 0.0, &stats);
    return stats.onsets_played;
  };
  EXPECT_EQ(render(true), 2u);
  EXPECT_EQ(render(false), 1u);
}

TEST(AudioMixer, SlidingIntoAnotherRegionStrikesIt) {
  const auto scene = build_audio_scene(seven_boxes());
  std::vector<ContactEvent> ev = {event(ContactEventType::kOnset, 0.0, 0.005, 2.0)};
  for (int k = 1; k <= 30; ++k) ev.push_back(event(ContactEventType::kSlide, 0.01 * k, 0.005 + 0.001 * k, 2.0, 0.1));
  MixerStats stats;
  render_offline(scene, ev, 0.0, 0.5, 0.0, &stats);
  EXPECT_EQ(stats.onsets_played, 4u);  // pillars 0, 1, 2, 3 (x from 5 to 35 mm)
}

TEST(AudioMixer, SlidingSoundGrowsWithSpeedAndTexture) {
  AudioConfig c;
  c.sample_rate_hz = kRate;
  c.slide_enabled = true;
  GridGeometry g{50, 50, -0.025, -0.025, 0.001};
  HeightField tex(g, 0.0F);
  for (int r = 0; r < 50; ++r) {
    for (int col = 25; col < 50; ++col) tex.at(r, col) = ((r + col) % 2 ? 1.0F : -1.0F) * 0.0002F;  // rough half x > 0
  }
  const auto scene = build_audio_scene(c, SceneInputs{&g, &tex});
  const auto rms = [&](double x, double speed) {
    std::vector<ContactEvent> ev = {event(ContactEventType::kOnset, 0.0, x, 2.0)};
    for (int k = 1; k <= 50; ++k) ev.push_back(event(ContactEventType::kSlide, 0.01 * k, x, 2.0, speed));
    const std::vector<float> out = render_offline(scene, ev, 0.0, 0.5, 0.0);
    double s = 0.0;
    for (std::size_t i = static_cast<std::size_t>(0.2 * kRate); i < out.size(); ++i) s += out[i] * out[i];
    return std::sqrt(s / static_cast<double>(out.size()));
  };
  EXPECT_GT(rms(0.01, 0.1), 1.5 * rms(-0.01, 0.1));  // rough beats smooth
  EXPECT_GT(rms(0.01, 0.1), 1.5 * rms(0.01, 0.02));  // fast beats slow
  EXPECT_EQ(rms(0.01, 0.0), 0.0);                   // sticking: silent
}

TEST(AudioMixer, ConfigErrorsNameTheKey) {
  AudioConfig c = seven_boxes();
  c.regions[2].gain = -1.0;
  try {
    build_audio_scene(c);
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("regions[2]"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("gain"), std::string::npos) << e.what();
  }
  AudioConfig d = seven_boxes();
  d.regions[1].name = d.regions[0].name;
  EXPECT_THROW(build_audio_scene(d), ConfigError);
  EXPECT_THROW(note_from_string("Do"), ConfigError);
  EXPECT_EQ(note_from_string("dha"), Note::kDha);
  EXPECT_NEAR(note_frequency_hz(Note::kPa, 200.0), 300.0, 1e-12);
}

}  // namespace
}  // namespace hc::audio
