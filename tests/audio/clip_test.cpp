// Clips: decoding WAV, FLAC and OGG written here with libsndfile, clear errors for missing and
// corrupt files at start, the synthesised stone tones, and the region map.

#include "hc/audio/clip.hpp"
#include "hc/audio/mixer.hpp"
#include "hc/audio/region_map.hpp"
#include "hc/common/error.hpp"
#include "test_paths.hpp"

#include <gtest/gtest.h>
#include <sndfile.h>

#include <cmath>
#include <fstream>
#include <numbers>
#include <vector>

namespace hc::audio {
namespace {

/// A 440 Hz sine, 0.25 s, stereo (left = right) at `rate`, written by libsndfile itself.
void write_sine(const std::filesystem::path& p, int format, int rate) {
  SF_INFO info{};
  info.samplerate = rate;
  info.channels = 2;
  info.format = format;
  SNDFILE* f = sf_open(p.string().c_str(), SFM_WRITE, &info);
  ASSERT_NE(f, nullptr) << sf_strerror(nullptr);
  std::vector<float> s(static_cast<std::size_t>(rate / 4) * 2);
  for (std::size_t i = 0; i < s.size() / 2; ++i) {
    s[2 * i] = s[2 * i + 1] = static_cast<float>(0.5 * std::sin(2 * std::numbers::pi * 440.0 * static_cast<double>(i) / rate));
  }
  ASSERT_EQ(sf_writef_float(f, s.data(), static_cast<sf_count_t>(s.size() / 2)), static_cast<sf_count_t>(s.size() / 2));
  sf_close(f);
}

double rms(const std::vector<float>& s) {
  double a = 0.0;
  for (float v : s) a += v * v;
  return std::sqrt(a / static_cast<double>(s.size()));
}

/// Zero crossings per second ≈ 2·f.
double frequency_of(const std::vector<float>& s, int rate) {
  int crossings = 0;
  for (std::size_t i = 1; i < s.size(); ++i) crossings += (s[i - 1] < 0.0F) != (s[i] < 0.0F) ? 1 : 0;
  return 0.5 * crossings * rate / static_cast<double>(s.size());
}

TEST(AudioClip, DecodesWavFlacAndOggWrittenByLibsndfile) {
  const auto dir = test::temp_dir("clips");
  struct Case {
    const char* name;
    int format;
    double rms_tol;
  };
  const Case cases[] = {{"a.wav", SF_FORMAT_WAV | SF_FORMAT_PCM_16, 1e-3},
                        {"a.flac", SF_FORMAT_FLAC | SF_FORMAT_PCM_16, 1e-3},
                        {"a.ogg", SF_FORMAT_OGG | SF_FORMAT_VORBIS, 0.03}};
  for (const Case& c : cases) {
    write_sine(dir / c.name, c.format, 44100);
    const Clip clip = decode_clip(dir / c.name, 48000);
    EXPECT_EQ(clip.sample_rate_hz, 48000) << c.name;
    EXPECT_NEAR(clip.seconds(), 0.25, 0.002) << c.name;                  // resampled 44.1 → 48 kHz
    EXPECT_NEAR(rms(clip.samples), 0.5 / std::sqrt(2.0), c.rms_tol) << c.name;  // stereo averaged
    EXPECT_NEAR(frequency_of(clip.samples, 48000), 440.0, 10.0) << c.name;
  }
  // Pitch 2: half as long, an octave up.
  const Clip up = decode_clip(dir / "a.wav", 48000, 2.0);
  EXPECT_NEAR(up.seconds(), 0.125, 0.002);
  EXPECT_NEAR(frequency_of(up.samples, 48000), 880.0, 20.0);
}

TEST(AudioClip, MissingOrCorruptClipIsAClearErrorAtStartNamingTheFile) {
  const auto dir = test::temp_dir("bad");
  AudioConfig c;
  RegionConfig r;
  r.name = "north pillar";
  r.shape.x_max_m = r.shape.y_max_m = 0.01;
  r.clip = dir / "nowhere.wav";
  c.regions.push_back(r);
  try {
    build_audio_scene(c);
    FAIL() << "expected an InputError";
  } catch (const InputError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("nowhere.wav"), std::string::npos) << m;
    EXPECT_NE(m.find("does not exist"), std::string::npos) << m;
    EXPECT_NE(m.find("north pillar"), std::string::npos) << m;
  }
  std::ofstream(dir / "garbage.wav") << "RIFF this is not a wave file at all, just text";
  c.regions[0].clip = dir / "garbage.wav";
  try {
    build_audio_scene(c);
    FAIL() << "expected an InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("garbage.wav"), std::string::npos) << e.what();
  }
  // A FLAC stream cut short (a partial copy) decodes fewer frames than its header declares:
  // corrupt, an error at start.
  write_sine(dir / "cut.flac", SF_FORMAT_FLAC | SF_FORMAT_PCM_16, 44100);
  std::filesystem::resize_file(dir / "cut.flac", std::filesystem::file_size(dir / "cut.flac") / 3);
  c.regions[0].clip = dir / "cut.flac";
  try {
    build_audio_scene(c);
    FAIL() << "expected an InputError for cut.flac";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("cut.flac"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("frames its header declares"), std::string::npos) << e.what();
  }
  // A WAV cut short: libsndfile trusts the file size over the header, so the samples that are
  // there decode (a third of the clip), resampled to the output rate.
  write_sine(dir / "cut.wav", SF_FORMAT_WAV | SF_FORMAT_PCM_16, 44100);
  const auto full = build_audio_scene([&] {
    AudioConfig w = c;
    w.regions[0].clip = dir / "cut.wav";
    return w;
  }())->clips[0].samples.size();
  std::filesystem::resize_file(dir / "cut.wav", std::filesystem::file_size(dir / "cut.wav") / 3);
  c.regions[0].clip = dir / "cut.wav";
  const auto cut = build_audio_scene(c)->clips[0].samples.size();
  EXPECT_GT(cut, full / 4);
  EXPECT_LT(cut, full / 2);
}

TEST(AudioClip, SynthesisedStoneToneHasItsFundamentalAndDecays) {
  const Clip c = synth_stone_tone(220.0, 48000, 2.0);
  ASSERT_EQ(c.samples.size(), 96000u);
  float peak = 0.0F;
  for (float s : c.samples) peak = std::max(peak, std::abs(s));
  EXPECT_NEAR(peak, 0.8F, 1e-6);
  EXPECT_EQ(c.samples[0], 0.0F);
  const std::vector<float> early(c.samples.begin() + 4800, c.samples.begin() + 14400);
  const std::vector<float> late(c.samples.begin() + 72000, c.samples.begin() + 81600);
  EXPECT_GT(rms(early), 4.0 * rms(late));  // it decays
  // Late in the tone only the fundamental is left (the higher partials decay faster).
  EXPECT_NEAR(frequency_of(late, 48000), 220.0, 8.0);
  EXPECT_THROW(synth_stone_tone(10.0, 48000, 1.0), ConfigError);
}

TEST(AudioClip, WrittenWavReadsBack) {
  const auto dir = test::temp_dir("wav");
  std::vector<float> s(4800);
  for (std::size_t i = 0; i < s.size(); ++i) s[i] = static_cast<float>(0.25 * std::sin(0.01 * static_cast<double>(i)));
  write_wav(dir / "x.wav", s, 48000);
  const Clip back = decode_clip(dir / "x.wav", 48000);
  ASSERT_EQ(back.samples.size(), s.size());
  for (std::size_t i = 0; i < s.size(); ++i) ASSERT_NEAR(back.samples[i], s[i], 1.0 / 32768 + 1e-6);
}

TEST(AudioRegions, BoxesPolygonsAndLabelsLookUpByNearestSample) {
  std::vector<RegionConfig> regions(3);
  regions[0].shape = RegionShape{ShapeKind::kBox, 0.0, 0.0, 0.01, 0.01, {}, 0};
  regions[1].shape.kind = ShapeKind::kPolygon;
  regions[1].shape.polygon_m = {{0.02, 0.0}, {0.04, 0.0}, {0.03, 0.02}};  // triangle
  regions[2].shape.kind = ShapeKind::kLabel;
  regions[2].shape.label = 7;
  const GridGeometry g{41, 61, -0.01, -0.01, 0.001};
  LabelImage labels{g.rows, g.cols, std::vector<std::int32_t>(g.cell_count(), 0)};
  labels.labels[static_cast<std::size_t>(30) * 61 + 5] = 7;  // row 30 (y = 0.02), col 5 (x = −0.005)
  const RegionMap map(regions, &g, 0.0, &labels);
  EXPECT_EQ(map.lookup(0.005, 0.005), 0);
  EXPECT_EQ(map.lookup(0.03, 0.005), 1);
  EXPECT_EQ(map.lookup(0.022, 0.018), -1);  // outside the triangle, inside its bounding box
  EXPECT_EQ(map.lookup(-0.005, 0.02), 2);
  EXPECT_EQ(map.lookup(0.015, 0.005), -1);
  EXPECT_EQ(map.lookup(1.0, 0.0), -1);
  EXPECT_EQ(map.lookup(std::nan(""), 0.0), -1);
  const HeightField layer = map.to_layer(g);
  EXPECT_EQ(layer.at(15, 15), 0.0F);  // x = 0.005, y = 0.005
  EXPECT_TRUE(std::isnan(layer.at(0, 0)));
  // A label image of the wrong size is named in the error.
  LabelImage small{3, 3, std::vector<std::int32_t>(9, 0)};
  EXPECT_THROW(RegionMap(regions, &g, 0.0, &small), ConfigError);
}

TEST(AudioRegions, ReadsA16BitPgmLabelImage) {
  const auto dir = test::temp_dir("pgm");
  {
    std::ofstream f(dir / "labels.pgm", std::ios::binary);
    f << "P5\n# labels\n3 2\n65535\n";
    const unsigned char px[] = {0, 0, 0, 1, 1, 2, 0, 3, 0, 4, 0, 5};
    f.write(reinterpret_cast<const char*>(px), sizeof px);
  }
  const LabelImage img = read_label_pgm(dir / "labels.pgm");
  EXPECT_EQ(img.rows, 2);
  EXPECT_EQ(img.cols, 3);
  EXPECT_EQ(img.labels, (std::vector<std::int32_t>{0, 1, 258, 3, 4, 5}));
  std::ofstream(dir / "cut.pgm", std::ios::binary) << "P5 3 2 255\n\x01";
  EXPECT_THROW(read_label_pgm(dir / "cut.pgm"), InputError);
}

}  // namespace
}  // namespace hc::audio
