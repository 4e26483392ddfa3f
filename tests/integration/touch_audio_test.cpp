// End-to-end: `hapticloud touch --audio-out` on the temple relief (seven pillars, Sa..Ni): the WAV
// is sample-accurate to the contact events of events.csv, silent before the first strike, never
// clipped; a missing clip stops the command at start naming the file.

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "app_runner.hpp"
#include "test_paths.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using hc::test::is_png;
using hc::test::read_json;
using hc::test::run_app;

/// The temple config with the sliding sound switched off (so only strikes make sound) and
/// optionally one region's clip replaced.
fs::path temple_config(const fs::path& dir, const std::string& clip_for_sa = "") {
  std::ifstream in(fs::path(HC_SOURCE_DIR) / "configs" / "temple_relief.yaml");
  std::stringstream ss;
  ss << in.rdbuf();
  std::string text = ss.str();
  const std::string on = "slide: {enabled: true";
  const auto at = text.find(on);
  EXPECT_NE(at, std::string::npos);
  if (at != std::string::npos) text.replace(at, on.size(), "slide: {enabled: false");
  if (!clip_for_sa.empty()) {
    const std::string sa = "{name: Sa,  note: Sa,";
    const auto s = text.find(sa);
    EXPECT_NE(s, std::string::npos);
    if (s != std::string::npos) text.replace(s, sa.size(), "{name: Sa,  clip: " + clip_for_sa + ",");
  }
  const fs::path p = dir / "temple.yaml";
  std::ofstream(p) << text;
  return p;
}

struct Wav {
  int rate = 0, channels = 0, bits = 0;
  std::vector<std::int16_t> samples;
};

/// Minimal RIFF/WAVE reader for 16-bit PCM (what --audio-out writes).
Wav read_wav(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::vector<char> b((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  Wav w;
  const auto u32 = [&](std::size_t o) {
    return static_cast<std::uint32_t>(static_cast<unsigned char>(b[o])) |
           static_cast<std::uint32_t>(static_cast<unsigned char>(b[o + 1])) << 8 |
           static_cast<std::uint32_t>(static_cast<unsigned char>(b[o + 2])) << 16 |
           static_cast<std::uint32_t>(static_cast<unsigned char>(b[o + 3])) << 24;
  };
  const auto u16 = [&](std::size_t o) {
    return static_cast<int>(static_cast<unsigned char>(b[o]) | static_cast<unsigned char>(b[o + 1]) << 8);
  };
  if (b.size() < 12 || std::string(b.data(), 4) != "RIFF" || std::string(b.data() + 8, 4) != "WAVE") return w;
  for (std::size_t o = 12; o + 8 <= b.size();) {
    const std::string id(b.data() + o, 4);
    const std::uint32_t size = u32(o + 4);
    if (id == "fmt ") {
      w.channels = u16(o + 10);
      w.rate = static_cast<int>(u32(o + 12));
      w.bits = u16(o + 22);
    } else if (id == "data") {
      const std::size_t n = std::min<std::size_t>(size, b.size() - o - 8) / 2;
      w.samples.resize(n);
      for (std::size_t i = 0; i < n; ++i) w.samples[i] = static_cast<std::int16_t>(u16(o + 8 + 2 * i));
    }
    o += 8 + size + (size & 1);
  }
  return w;
}

struct EventRow {
  double t_s;
  std::string type;
  int region;
};

std::vector<EventRow> read_events(const fs::path& p) {
  std::ifstream in(p);
  std::string line;
  std::getline(in, line);  // header
  std::vector<EventRow> rows;
  while (std::getline(in, line)) {
    std::stringstream ls(line);
    std::string t, type, region;
    std::getline(ls, t, ',');
    std::getline(ls, type, ',');
    std::getline(ls, region, ',');
    rows.push_back({std::stod(t), type, std::stoi(region)});
  }
  return rows;
}

TEST(TouchAudio, TempleReliefWavIsSampleAccurateToTheContactEvents) {
  const fs::path dir = hc::test::temp_dir("temple");
  const fs::path out = dir / "touch";
  const fs::path wav_path = dir / "temple.wav";
  std::string log;
  ASSERT_EQ(run_app("touch " + temple_config(dir).string() + " --seconds 6 --out " + out.string() +
                        " --audio-out " + wav_path.string(),
                    &log),
            0)
      << log;
  const json summary = json::parse(std::ifstream(out / "summary.json"));
  ASSERT_TRUE(summary.contains("audio")) << summary.dump(2);
  EXPECT_EQ(summary["audio"]["regions"].get<int>(), 7);
  EXPECT_GT(summary["audio"]["onsets_played"].get<int>(), 3);  // the raster crosses several pillars
  EXPECT_LE(summary["audio"]["peak_dbfs"].get<double>(), 0.0);

  const Wav wav = read_wav(wav_path);
  ASSERT_EQ(wav.rate, 48000);
  ASSERT_EQ(wav.channels, 1);
  ASSERT_EQ(wav.bits, 16);
  EXPECT_EQ(wav.samples.size(), static_cast<std::size_t>((6.0 + 1.0) * 48000));  // session + 1 s tail

  // The first event on a pillar strikes its note: silence up to its sample, sound within 1 ms.
  const std::vector<EventRow> events = read_events(out / "events.csv");
  const EventRow* first = nullptr;
  std::set<int> pillars;
  for (const EventRow& e : events) {
    if (e.region >= 0 && e.type != "release") {
      if (first == nullptr) first = &e;
      pillars.insert(e.region);
    }
  }
  ASSERT_NE(first, nullptr) << "no contact event on any pillar";
  EXPECT_GE(pillars.size(), 4u);
  const auto k = static_cast<std::size_t>(std::llround(first->t_s * 48000));
  ASSERT_LT(k + 48, wav.samples.size());
  for (std::size_t i = 0; i < k; ++i) ASSERT_EQ(wav.samples[i], 0) << "sound at sample " << i << " before " << k;
  int loudest = 0;
  for (std::size_t i = k; i <= k + 48; ++i) loudest = std::max(loudest, std::abs(static_cast<int>(wav.samples[i])));
  EXPECT_GT(loudest, 0) << "nothing within 1 ms of the strike at sample " << k;
  // No clipping: nothing at full scale.
  for (std::int16_t s : wav.samples) ASSERT_LT(std::abs(static_cast<int>(s)), 32767);
}

TEST(TouchAudio, AMissingClipStopsAtStartNamingTheFile) {
  const fs::path dir = hc::test::temp_dir("missing");
  std::string log;
  const int rc = run_app("touch " + temple_config(dir, "no_such_pillar.flac").string() + " --seconds 1 --out " +
                             (dir / "touch").string() + " --audio-out " + (dir / "x.wav").string(),
                         &log);
  EXPECT_EQ(rc, 1) << log;
  EXPECT_NE(log.find("no_such_pillar.flac"), std::string::npos) << log;
  EXPECT_NE(log.find("Sa"), std::string::npos) << log;
  EXPECT_FALSE(fs::exists(dir / "x.wav"));
  EXPECT_FALSE(fs::exists(dir / "touch" / "trace.csv"));  // no session ran
}

TEST(TouchAudio, ABadAudioKeyNamesTheKeyAndLine) {
  const fs::path dir = hc::test::temp_dir("badkey");
  std::ifstream in(temple_config(dir));
  std::stringstream ss;
  ss << in.rdbuf();
  std::string text = ss.str();
  const std::string ni = "note: Ni,";
  const auto at = text.find(ni);
  ASSERT_NE(at, std::string::npos);
  text.replace(at, ni.size(), "note: Do,");
  std::ofstream(dir / "bad.yaml") << text;
  std::string log;
  EXPECT_EQ(run_app("touch " + (dir / "bad.yaml").string() + " --seconds 1 --out " + (dir / "touch").string() +
                        " --audio-out " + (dir / "x.wav").string(),
                    &log),
            1)
      << log;
  EXPECT_NE(log.find("audio.regions[6].note = 'Do'"), std::string::npos) << log;
  EXPECT_NE(log.find("Sa, Re, Ga, Ma, Pa, Dha, Ni"), std::string::npos) << log;
  EXPECT_NE(log.find("bad.yaml:"), std::string::npos) << log;  // file and line
}

}  // namespace
