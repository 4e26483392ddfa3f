#include "hc/falcon/protocol.hpp"

#include <gtest/gtest.h>

#include <random>
#include <vector>

namespace hc::falcon {
namespace {

TEST(FalconProtocol, CommandFrameKnownBytes) {
  // Axis values as 'A' + nibble, least significant nibble first; byte 13 = 'A' + (LEDs | homing).
  const Frame f = encode_command(CommandFrame{{0x1234, -1, 0}, kLedGreen | kLedRed, true});
  const Frame expected{'<', 'A' + 4, 'A' + 3, 'A' + 2, 'A' + 1, 'A' + 15, 'A' + 15, 'A' + 15, 'A' + 15,
                       'A', 'A', 'A', 'A', 'A' + 0xB, 'A', '>'};
  EXPECT_EQ(f, expected);
}

TEST(FalconProtocol, StatusFrameKnownBytes) {
  StatusFrame s;
  s.encoder = {-32768, 32767, 5};
  s.buttons = 0x9;
  s.homed_mask = 0x5;
  const Frame f = encode_status(s);
  EXPECT_EQ(f[1], 'A');
  EXPECT_EQ(f[4], 'A' + 8);
  EXPECT_EQ(f[5], 'A' + 15);
  EXPECT_EQ(f[8], 'A' + 7);
  EXPECT_EQ(f[9], 'A' + 5);
  EXPECT_EQ(f[13], 'A' + 0x59);
}

TEST(FalconProtocol, RoundTripsRandomFrames) {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> v(-32768, 32767), b(0, 15), h(0, 7), led(0, 7), hb(0, 1);
  for (int k = 0; k < 2000; ++k) {
    CommandFrame c{{static_cast<std::int16_t>(v(rng)), static_cast<std::int16_t>(v(rng)), static_cast<std::int16_t>(v(rng))},
                   static_cast<std::uint8_t>(led(rng) << 1), hb(rng) == 1};
    CommandFrame c2;
    ASSERT_TRUE(decode_command(encode_command(c), c2));
    ASSERT_EQ(c, c2);
    StatusFrame s{{static_cast<std::int16_t>(v(rng)), static_cast<std::int16_t>(v(rng)), static_cast<std::int16_t>(v(rng))},
                  static_cast<std::uint8_t>(b(rng)), static_cast<std::uint8_t>(h(rng))};
    StatusFrame s2;
    ASSERT_TRUE(decode_status(encode_status(s), s2));
    ASSERT_EQ(s, s2);
  }
}

TEST(FalconProtocol, RejectsBadFrames) {
  const Frame good = encode_status(StatusFrame{{1, 2, 3}, 1, 7});
  StatusFrame out{{9, 9, 9}, 0, 0};
  const StatusFrame untouched = out;
  for (std::size_t i = 0; i < kFrameSize; ++i) {
    Frame bad = good;
    bad[i] = 0x20;  // below 'A', and neither '<' nor '>'
    EXPECT_FALSE(decode_status(bad, out)) << "byte " << i;
  }
  Frame nibble = good;
  nibble[3] = 'A' + 16;  // not a nibble
  EXPECT_FALSE(decode_status(nibble, out));
  EXPECT_FALSE(decode_status(std::span<const std::uint8_t>(good.data(), 15), out));  // short
  EXPECT_EQ(out, untouched);
  CommandFrame c;
  Frame cmd = encode_command(CommandFrame{});
  cmd[13] = 'A' + 16;  // command byte 13 is a nibble
  EXPECT_FALSE(decode_command(cmd, c));
}

TEST(FalconProtocol, AssemblerSkipsGarbageAndShortFrames) {
  FrameAssembler a;
  const Frame f1 = encode_status(StatusFrame{{10, 20, 30}, 0, 7});
  const Frame f2 = encode_status(StatusFrame{{-5, 6, -7}, 3, 7});
  std::vector<std::uint8_t> stream = {0x00, '>', 'A', '<', 0x7f, 0x13};  // junk with a false start
  stream.insert(stream.end(), f1.begin(), f1.begin() + 9);               // a cut frame
  stream.insert(stream.end(), f2.begin(), f2.end());                     // a good one
  std::size_t good = 0;
  for (std::size_t i = 0; i < stream.size(); i += 5) {  // arbitrary splits
    good += a.push(std::span<const std::uint8_t>(stream.data() + i, std::min<std::size_t>(5, stream.size() - i)));
  }
  EXPECT_EQ(good, 1U);
  Frame got{};
  ASSERT_TRUE(a.take(got));
  EXPECT_EQ(got, f2);
  EXPECT_FALSE(a.take(got));  // taken once
  EXPECT_GE(a.bad_frames(), 1U);
  EXPECT_GE(a.skipped_bytes(), 6U);
}

TEST(FalconProtocol, AssemblerKeepsTheNewestOfSeveral) {
  FrameAssembler a;
  std::vector<std::uint8_t> stream;
  for (int k = 0; k < 4; ++k) {
    const Frame f = encode_status(StatusFrame{{static_cast<std::int16_t>(k), 0, 0}, 0, 0});
    stream.insert(stream.end(), f.begin(), f.end());
  }
  EXPECT_EQ(a.push(stream), 4U);
  Frame got{};
  ASSERT_TRUE(a.take(got));
  StatusFrame s;
  ASSERT_TRUE(decode_status(got, s));
  EXPECT_EQ(s.encoder[0], 3);
}

TEST(FalconProtocol, AssemblerSurvivesRandomNoise) {
  std::mt19937 rng(3);
  std::uniform_int_distribution<int> byte(0, 255);
  FrameAssembler a;
  std::vector<std::uint8_t> noise(5000);
  for (auto& b : noise) b = static_cast<std::uint8_t>(byte(rng));
  a.push(noise);
  Frame junk{};
  (void)a.take(junk);  // whatever noise happened to form is discarded
  const Frame f = encode_status(StatusFrame{{1, 2, 3}, 0, 7});
  // After noise, a frame preceded by a few idle bytes is found again.
  const std::vector<std::uint8_t> sep(kFrameSize, 0x00);
  a.push(sep);
  a.push(f);
  Frame got{};
  ASSERT_TRUE(a.take(got));
  EXPECT_EQ(got, f);
}

}  // namespace
}  // namespace hc::falcon
