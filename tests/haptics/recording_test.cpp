// Recorded sessions (recording.hpp): RecordingDevice against a log the test keeps itself of what
// the inner device reported and what was sent; read_recording and TickReplayDevice against that
// same log; the refusals. The end-to-end replay of a servo session (forces reproduced to 1e-9 N)
// is in tests/integration/touch_command_test.cpp.

#include "hc/haptics/recording.hpp"
#include "hc/haptics/simulated_device.hpp"

#include "hc/common/error.hpp"
#include "test_paths.hpp"
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace hc::haptics {
namespace {

namespace fs = std::filesystem;

TEST(Recording, EveryReadAndTheClampedForceAfterItReadBackBitForBit) {
  const fs::path dir = hc::test::temp_dir("recording");
  const fs::path file = dir / "session.csv";
  ManualClock clock(5'000'000);
  ScriptedPath path;
  path.kind = PathKind::kCircle;
  SimulatedDevice inner(clock, path, VirtualHand{}, SimulatedDevice::default_info());
  std::vector<DeviceReading> seen;
  std::vector<Eigen::Vector3d> sent;
  {
    RecordingDevice rec(inner, file);
    rec.open();
    EXPECT_EQ(inner.state(), DeviceState::kOpen);
    ASSERT_TRUE(rec.arm());
    for (int k = 0; k < 3000; ++k) {  // more than the writer drains in one 20 ms round
      DeviceReading r;
      rec.read(r);
      seen.push_back(r);
      // A force that exceeds the 8.9 N cap every 10th tick: the recording holds what was sent.
      const Eigen::Vector3d f(0.001 * k, -0.5, k % 10 == 0 ? 20.0 : 1.0);
      rec.write(f);
      EXPECT_EQ(inner.state(), DeviceState::kArmed);  // mirrored
      sent.push_back(inner.last_force_n());
      clock.advance_ns(1'000'000);
    }
    rec.keep_on_close();
    rec.close();
    EXPECT_EQ(rec.error(), "");
    EXPECT_EQ(rec.dropped(), 0u);
    EXPECT_EQ(rec.written(), 3000u);
  }
  EXPECT_FALSE(hc::test::has_entry_named_with(dir, ".part-"));
  const std::vector<RecordedSample> got = read_recording(file);
  ASSERT_EQ(got.size(), seen.size());
  for (std::size_t k = 0; k < got.size(); ++k) {
    EXPECT_EQ(got[k].tick, k);
    EXPECT_EQ(got[k].time_ns, seen[k].time_ns);
    for (int a = 0; a < 3; ++a) {
      EXPECT_EQ(got[k].position_m[a], seen[k].position_m[a]) << k;  // exact: %.17g
      EXPECT_EQ(got[k].force_n[a], sent[k][a]) << k;
    }
    EXPECT_LE(Eigen::Vector3d(got[k].force_n[0], got[k].force_n[1], got[k].force_n[2]).norm(),
              SimulatedDevice::default_info().max_force_n + 1e-12);
  }

  // The replay gives the same positions, one per read, its times shifted to the replay clock.
  ManualClock replay_clock(42);
  TickReplayDevice replay(replay_clock, file, SimulatedDevice::default_info());
  replay.open();
  ASSERT_EQ(replay.sample_count(), seen.size());
  for (std::size_t k = 0; k < seen.size(); ++k) {
    DeviceReading r;
    ASSERT_EQ(replay.read(r), DeviceStatus::kOk) << k;
    EXPECT_EQ(r.position_m, seen[k].position_m) << k;
    EXPECT_EQ(r.time_ns, 42 + (seen[k].time_ns - seen[0].time_ns)) << k;
  }
  DeviceReading last;
  EXPECT_EQ(replay.read(last), DeviceStatus::kEndOfData);
  EXPECT_EQ(last.position_m, seen.back().position_m);
}

TEST(Recording, AnExistingFileIsNeverReplacedAndBadRecordingsNameTheLine) {
  const fs::path dir = hc::test::temp_dir("recording_refuse");
  const fs::path file = dir / "mine.csv";
  { std::ofstream(file) << "the user's notes\n"; }
  ManualClock clock;
  SimulatedDevice inner(clock, ScriptedPath{}, VirtualHand{}, SimulatedDevice::default_info());
  RecordingDevice rec(inner, file);
  EXPECT_THROW(rec.open(), InputError);
  EXPECT_EQ(inner.state(), DeviceState::kClosed);
  std::ifstream in(file);
  std::string text;
  std::getline(in, text);
  EXPECT_EQ(text, "the user's notes");
  EXPECT_FALSE(hc::test::has_entry_named_with(dir, ".part-"));
  RecordingDevice nowhere(inner, dir / "missing" / "r.csv");
  EXPECT_THROW(nowhere.open(), InputError);

  // Not a recording; a broken line; a tick missing.
  EXPECT_THROW(read_recording(file), InputError);
  const fs::path bad = dir / "bad.csv";
  { std::ofstream(bad) << "# hapticloud recording 1\ntick,time_ns,x_m,y_m,z_m,buttons,fx_n,fy_n,fz_n,status\n0,0,0,0,0,0,0,0,0,0\n1,5,zero,0,0,0,0,0,0,0\n"; }
  try {
    read_recording(bad);
    FAIL() << "expected hc::InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("bad.csv:4"), std::string::npos) << e.what();
  }
  const fs::path gap = dir / "gap.csv";
  { std::ofstream(gap) << "# hapticloud recording 1\n0,0,0,0,0,0,0,0,0,0\n2,5,0,0,0,0,0,0,0,0\n"; }
  try {
    read_recording(gap);
    FAIL() << "expected hc::InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("tick 2, expected 1"), std::string::npos) << e.what();
  }
}

// Version 2: what the servo log and the session say is written with its tick, read back as
// it was given, after the samples' header with the servo rate; version 1 files still read.
TEST(Recording, EventsOfTheServoLogAndTheSessionAreWrittenWithTheirTicks) {
  const fs::path dir = hc::test::temp_dir("recording_events");
  ManualClock clock;
  SimulatedDevice inner(clock, ScriptedPath{}, VirtualHand{}, SimulatedDevice::default_info());
  SharedState shared;
  RecordingDevice rec(inner, dir / "r.csv");
  EXPECT_THROW(rec.watch(shared, 0.0), ConfigError);
  rec.watch(shared, 2000.0);
  ASSERT_NE(shared.servo_log(), nullptr);
  rec.open();
  const Command stiff{CommandType::kSetStiffness, 650.25, 0, 0, 0, 0};
  const Command ws{CommandType::kSetWorkspace, 0.001, -0.002, 0.0125, 2.5, 0.1};
  for (int k = 0; k < 10; ++k) {
    DeviceReading r;
    (void)rec.read(r);
    if (k == 3) shared.log({3, ServoLogEntry::Kind::kCommand, stiff, 0});
    if (k == 4) shared.log({4, ServoLogEntry::Kind::kRejected, ws, 0});
    if (k == 5) shared.log({5, ServoLogEntry::Kind::kSurface, Command{}, 77});
    if (k == 7) {
      shared.counters.ticks.store(7);
      rec.note("window 2 10 20");
    }
    (void)rec.write(Eigen::Vector3d::Zero());
    clock.advance_ns(1000000);
  }
  rec.keep_on_close();
  rec.close();
  ASSERT_EQ(rec.error(), "");
  const Recording got = read_recording_file(dir / "r.csv");
  EXPECT_EQ(got.version, 2);
  EXPECT_EQ(got.servo_rate_hz, 2000.0);
  EXPECT_EQ(got.max_force_n, SimulatedDevice::default_info().max_force_n);
  EXPECT_EQ(got.samples.size(), 10u);
  ASSERT_EQ(got.events.size(), 4u);
  EXPECT_EQ(got.events[0].kind, RecordedEvent::Kind::kCommand);
  EXPECT_EQ(got.events[0].tick, 3u);
  EXPECT_EQ(got.events[0].command.type, CommandType::kSetStiffness);
  EXPECT_EQ(got.events[0].command.a, 650.25);
  EXPECT_EQ(got.events[1].kind, RecordedEvent::Kind::kRejected);
  EXPECT_EQ(got.events[1].command.type, CommandType::kSetWorkspace);
  EXPECT_EQ(got.events[1].command.e, 0.1);  // %.17g: bit for bit
  EXPECT_EQ(got.events[1].command.b, -0.002);
  EXPECT_EQ(got.events[2].kind, RecordedEvent::Kind::kSurface);
  EXPECT_EQ(got.events[2].tick, 5u);
  EXPECT_EQ(got.events[2].surface_tag, 77u);
  EXPECT_EQ(got.events[3].kind, RecordedEvent::Kind::kSession);
  EXPECT_EQ(got.events[3].tick, 7u);
  EXPECT_EQ(got.events[3].action, "window 2 10 20");
  // Every command name reads back as itself.
  for (int t = 0; t <= static_cast<int>(CommandType::kStop); ++t) {
    CommandType back{};
    ASSERT_TRUE(command_type_from_string(to_string(static_cast<CommandType>(t)), back));
    EXPECT_EQ(static_cast<int>(back), t);
  }
  // Version 1; a malformed event names its line.
  { std::ofstream(dir / "v1.csv") << "# hapticloud recording 1\n0,0,0,0,0,0,0,0,0,0\n"; }
  EXPECT_EQ(read_recording_file(dir / "v1.csv").version, 1);
  EXPECT_EQ(read_recording_file(dir / "v1.csv").servo_rate_hz, 0.0);
  for (const std::string bad : {"@command,3,fly,0,0,0,0,0", "@command,3,arm,0,0", "@surface,x,1", "@teleport,1,2"}) {
    { std::ofstream(dir / "bad.csv") << "# hapticloud recording 2\n0,0,0,0,0,0,0,0,0,0\n" << bad << "\n"; }
    try {
      (void)read_recording_file(dir / "bad.csv");
      ADD_FAILURE() << bad << " was accepted";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("bad.csv:3"), std::string::npos) << e.what();
    }
  }
}

TEST(Recording, FaultsCrossTheWrapperBothWaysAndAFailedSessionKeepsNoFile) {
  const fs::path dir = hc::test::temp_dir("recording_fault");
  ManualClock clock;
  SimulatedDevice inner(clock, ScriptedPath{}, VirtualHand{}, SimulatedDevice::default_info());
  {
    RecordingDevice rec(inner, dir / "r.csv");
    rec.open();
    ASSERT_TRUE(rec.arm());
    DeviceReading r;
    ASSERT_EQ(rec.read(r), DeviceStatus::kOk);
    rec.write(Eigen::Vector3d(0, 0, 1));
    EXPECT_EQ(inner.state(), DeviceState::kArmed);
    // The wrapper faults (the servo loop's doing): the inner device follows at the next write.
    rec.fault();
    rec.read(r);
    rec.write(Eigen::Vector3d(0, 0, 1));
    EXPECT_EQ(inner.state(), DeviceState::kFault);
    EXPECT_EQ(inner.last_force_n(), Eigen::Vector3d::Zero());
    // An explicit reset of the wrapper resets the inner device too.
    ASSERT_TRUE(rec.reset_fault());
    rec.read(r);
    rec.write(Eigen::Vector3d::Zero());
    EXPECT_EQ(inner.state(), DeviceState::kOpen);
    // The inner device faults by itself: the wrapper's next read says so as an I/O error.
    ASSERT_TRUE(rec.arm());
    rec.read(r);
    rec.write(Eigen::Vector3d::Zero());
    inner.fault();
    EXPECT_EQ(rec.read(r), DeviceStatus::kIoError);
    rec.write(Eigen::Vector3d::Zero());
    rec.keep_on_close();
    rec.close();
    ASSERT_EQ(rec.error(), "");
  }
  // The replay gives the recorded statuses back: the I/O error at the same tick.
  const std::vector<RecordedSample> got = read_recording(dir / "r.csv");
  ASSERT_EQ(got.size(), 5u);
  EXPECT_EQ(got[4].status, static_cast<std::uint8_t>(DeviceStatus::kIoError));
  ManualClock replay_clock;
  TickReplayDevice replay(replay_clock, dir / "r.csv", SimulatedDevice::default_info());
  replay.open();
  DeviceReading r;
  for (int k = 0; k < 4; ++k) EXPECT_EQ(replay.read(r), DeviceStatus::kOk) << k;
  EXPECT_EQ(replay.read(r), DeviceStatus::kIoError);

  // A session that ends by an exception (no keep_on_close): no FILE and no temporary left.
  {
    RecordingDevice rec(inner, dir / "failed.csv");
    rec.open();
    DeviceReading x;
    rec.read(x);
  }  // destroyed: closed without keeping
  EXPECT_FALSE(fs::exists(dir / "failed.csv"));
  EXPECT_FALSE(hc::test::has_entry_named_with(dir, ".part-"));
}

}  // namespace
}  // namespace hc::haptics
