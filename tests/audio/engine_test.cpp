// The live engine through OpenAL Soft's loopback device (no sound card needed): events from a
// SharedState ring and from submit() reach the mixer and come out of OpenAL.

#include "hc/audio/engine.hpp"
#include "hc/common/error.hpp"
#include "hc/haptics/clock.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <thread>

namespace hc::audio {
namespace {

std::shared_ptr<const AudioScene> one_box_scene() {
  AudioConfig c;
  c.tone_seconds = 0.1;
  c.slide_enabled = false;
  RegionConfig r;
  r.name = "pillar";
  r.shape.x_min_m = -0.01, r.shape.x_max_m = 0.01, r.shape.y_min_m = -0.01, r.shape.y_max_m = 0.01;
  c.regions.push_back(r);
  return build_audio_scene(c);
}

haptics::ContactEvent onset_now() {
  haptics::ContactEvent e;
  e.type = haptics::ContactEventType::kOnset;
  e.t_s = static_cast<double>(haptics::monotonic_now_ns()) * 1e-9;
  e.force_n = haptics::Vec3{0, 0, 2.0};
  return e;
}

/// Polls `done` every millisecond, at most ~20 s (a stuck engine fails instead of hanging).
template <class F>
bool wait_for(F done) {
  for (int i = 0; i < 20000 && !done(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  return done();
}

TEST(AudioEngine, LoopbackPlaysSubmittedOnsetsAndMeasuresTheirLatency) {
  EngineOptions o;
  o.loopback = true;
  AudioEngine engine(one_box_scene(), o);
  const EngineReport report = engine.start();
  ASSERT_TRUE(report.device_open) << report.detail;
  EXPECT_EQ(report.device, "loopback");
  EXPECT_TRUE(engine.running());
  EXPECT_THROW(engine.start(), ConfigError);
  ASSERT_TRUE(engine.submit(onset_now()));
  ASSERT_TRUE(wait_for([&] { return engine.stats().latency_samples >= 1; }));
  const EngineStats s = engine.stats();
  EXPECT_EQ(s.events, 1u);
  EXPECT_EQ(s.onsets_played, 1u);
  EXPECT_GT(s.latency_median_s, 0.0);
  EXPECT_GT(s.buffers, 0u);
  engine.set_volume(9.0);
  EXPECT_EQ(engine.volume(), 4.0);
  engine.stop();
  EXPECT_FALSE(engine.running());
}

TEST(AudioEngine, DrainsTheSharedContactRing) {
  haptics::SharedState shared;
  EngineOptions o;
  o.loopback = true;
  AudioEngine engine(one_box_scene(), o);
  ASSERT_TRUE(engine.start(shared).device_open);
  for (int i = 0; i < 3; ++i) {
    haptics::ContactEvent e = onset_now();
    ASSERT_TRUE(shared.events.try_push(e));
    e.type = haptics::ContactEventType::kRelease;
    ASSERT_TRUE(shared.events.try_push(e));
  }
  ASSERT_TRUE(wait_for([&] { return engine.stats().events >= 6; }));
  EXPECT_EQ(shared.events.size_approx(), 0u);
  EXPECT_EQ(engine.stats().onsets_played, 3u);
  engine.stop();
}

TEST(AudioEngine, WithoutASoundDeviceItSaysSoAndStillDrainsTheRing) {
  haptics::SharedState shared;
  EngineOptions o;
  o.device_name = "hapticloud-test: no such device";
  AudioEngine engine(one_box_scene(), o);
  const EngineReport report = engine.start(shared);
  EXPECT_FALSE(report.device_open);
  EXPECT_NE(report.detail.find("no sound output device"), std::string::npos) << report.detail;
  EXPECT_NE(report.detail.find("--audio-out"), std::string::npos) << report.detail;
  for (int i = 0; i < 100; ++i) ASSERT_TRUE(shared.events.try_push(onset_now()));
  ASSERT_TRUE(wait_for([&] { return engine.stats().events >= 100; }));
  EXPECT_EQ(engine.stats().onsets_played, 0u);
  engine.stop();
}

TEST(AudioEngine, RejectsOutOfRangeOptionsNamingThem) {
  EngineOptions o;
  o.buffer_frames = 8;
  AudioEngine engine(one_box_scene(), o);
  try {
    engine.start();
    FAIL() << "expected a ConfigError";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("buffer_frames = 8"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(engine.running());
}

}  // namespace
}  // namespace hc::audio
