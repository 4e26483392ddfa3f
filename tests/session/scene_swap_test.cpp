// SceneSwap: the re-scan swap protocol driven against a real ServoLoop and SimulatedDevice on a
// ManualClock, one servo tick at a time. The oracle is the device itself (its state and the last
// force written to it after every tick) and the servo's adopted surface tag, not the swap's own
// bookkeeping. Every wait has a deadline that fails the test; nothing is timed.

#include "hc/common/error.hpp"
#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/simulated_device.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/session/lod_controller.hpp"
#include "hc/session/scene_swap.hpp"

#include <gtest/gtest.h>

#include "session_fixtures.hpp"

#include <cmath>
#include <cstdint>
#include <memory>
#include <numbers>
#include <optional>
#include <stdexcept>
#include <vector>

namespace hc::session {
namespace {

using haptics::CommandType;
using haptics::DeviceState;

/// A sinusoid of amplitude `amp` [m], wavelength 40 mm, over a 100 mm square of n × n samples.
std::shared_ptr<LodPyramid> wave_pyramid(int n, double amp) {
  const double side = 0.1, cell = side / (n - 1);
  HeightField depth(GridGeometry{n, n, -side / 2, -side / 2, cell});
  const double k = 2 * std::numbers::pi / 0.04;
  for (int r = 0; r < n; ++r) {
    for (int c = 0; c < n; ++c) {
      depth.at(r, c) = static_cast<float>(amp * std::sin(k * depth.geometry().x_of_col(c)) *
                                          std::sin(k * depth.geometry().y_of_row(r)));
    }
  }
  return test::pyramid_of(std::move(depth), 100, 30);
}

/// What the device and the servo showed after one tick.
struct TickSeen {
  DeviceState state = DeviceState::kClosed;
  double force_n = 0.0;            ///< |last force written to the device| [N]
  std::uint64_t surface_tag = 0;   ///< counters.surface_tag
  std::uint64_t adopted = 0;       ///< counters.surfaces_adopted
};

/// A session pressing on scene A: its servo loop and device, armed and in contact.
class SwapRig {
 public:
  SwapRig() {
    lod_a = std::make_unique<LodController>(wave_pyramid(121, 0.004), shared, test::controller_options(false));
    // Two windows, so scene A's tag (2) differs from the first tag of scene B's controller (1).
    lod_a->set_level(1);
    const HapticWindow& w = lod_a->set_level(0);
    haptics::ScriptedPath path;
    path.kind = haptics::PathKind::kCircle;
    path.half_x_m = 0.01;
    path.z_above_m = 0.02;
    path.z_contact_m = -0.01;  // keeps pressing below the surface
    path.speed_m_per_s = 0.02;
    path.approach_s = 0.3;
    device = std::make_unique<haptics::SimulatedDevice>(clock, path, haptics::VirtualHand{},
                                                        haptics::SimulatedDevice::default_info());
    device->open();
    cfg.workspace = w.map;
    cfg.proxy.stiffness_n_per_m = 800.0;
    loop = std::make_unique<haptics::ServoLoop>(*device, shared, clock, cfg);
  }

  TickSeen tick() {
    loop->run_ticks(1, clock);
    TickSeen s{device->state(), device->last_force_n().norm(), shared.counters.surface_tag.load(),
               shared.counters.surfaces_adopted.load()};
    seen.push_back(s);
    return s;
  }
  void ticks(int n) {
    for (int i = 0; i < n; ++i) tick();
  }
  /// Publishes scene B's first window (the hook the UI gives the swap); records what the device
  /// showed at that moment.
  std::uint64_t publish_b() {
    ++publishes;
    state_at_publish = device->state();
    force_at_publish_n = device->last_force_n().norm();
    lod_b = std::make_unique<LodController>(wave_pyramid(121, 0.002), shared, test::controller_options(false));
    tag_b = lod_b->centre_window(0, 0.0, 0.0).tag;
    return tag_b;
  }
  /// Fills the command ring with harmless commands (the current ρ). @return how many went in.
  int fill_ring() {
    int n = 0;
    while (shared.commands.try_push(haptics::Command::of(CommandType::kSetRho, cfg.proxy.rho))) ++n;
    return n;
  }

  haptics::SharedState shared;
  haptics::ManualClock clock;
  haptics::ServoConfig cfg;
  std::unique_ptr<LodController> lod_a, lod_b;
  std::unique_ptr<haptics::SimulatedDevice> device;
  std::unique_ptr<haptics::ServoLoop> loop;
  std::vector<TickSeen> seen;
  int publishes = 0;
  DeviceState state_at_publish = DeviceState::kClosed;
  double force_at_publish_n = -1.0;
  std::uint64_t tag_b = 0;
};

constexpr int kTicksPerFrame = 5;
constexpr int kMaxFrames = 2000;  // deadline: a swap takes a handful of frames

/// Steps the swap once per frame (kTicksPerFrame servo ticks) until it is idle with no arm
/// pending. @return false when the deadline passed.
bool run_until_done(SwapRig& rig, SceneSwap& swap) {
  for (int f = 0; f < kMaxFrames; ++f) {
    swap.step();
    if (!swap.busy() && !swap.arm_pending()) return true;
    rig.ticks(kTicksPerFrame);
  }
  return false;
}

/// Checks the per-tick record from `from` on: the device leaves Armed at d, is Armed again at
/// a > d, writes zero force for every tick in [d, a), and scene B's surface is adopted at a tick
/// s with d < s ≤ a (before the arm is applied), and rendered from then on.
void expect_zero_force_swap(const SwapRig& rig, std::size_t from) {
  const auto& seen = rig.seen;
  std::optional<std::size_t> d, a, s;
  for (std::size_t k = from; k < seen.size(); ++k) {
    if (!d && seen[k].state != DeviceState::kArmed) d = k;
    if (d && !a && seen[k].state == DeviceState::kArmed) a = k;
    if (!s && seen[k].surface_tag == rig.tag_b && seen[k].adopted > seen[from].adopted) s = k;
  }
  ASSERT_TRUE(d.has_value()) << "the device was never disarmed";
  ASSERT_TRUE(a.has_value()) << "the device was never re-armed";
  ASSERT_TRUE(s.has_value()) << "scene B was never adopted";
  for (std::size_t k = *d; k < *a; ++k) {
    EXPECT_EQ(seen[k].state, DeviceState::kOpen) << "tick " << k;
    EXPECT_EQ(seen[k].force_n, 0.0) << "tick " << k << " between the disarm and the re-arm";
  }
  EXPECT_GT(*s, *d) << "scene B was adopted before the device was disarmed";
  EXPECT_LE(*s, *a) << "the device was armed before scene B was adopted";
  for (std::size_t k = *s; k < seen.size(); ++k) EXPECT_EQ(seen[k].surface_tag, rig.tag_b) << "tick " << k;
}

TEST(SceneSwap, TheForceIsZeroFromTheDisarmUntilTheReArmAndTheNewSceneIsAdoptedFirst) {
  SwapRig rig;
  SceneSwap swap(rig.shared);
  EXPECT_TRUE(swap.arm());
  rig.ticks(2000);
  ASSERT_EQ(rig.device->state(), DeviceState::kArmed);
  ASSERT_GT(rig.seen.back().force_n, 0.5) << "the hand presses on scene A before the swap";
  const std::size_t from = rig.seen.size();

  swap.begin([&] { return rig.publish_b(); });
  EXPECT_EQ(swap.phase(), SwapPhase::kWaitDisarm);
  EXPECT_THROW(swap.begin([&] { return rig.publish_b(); }), ConfigError);  // one swap at a time
  for (int i = 0; i < 5; ++i) EXPECT_EQ(swap.step(), SwapPhase::kWaitDisarm) << "no servo tick: not disarmed yet";
  EXPECT_EQ(rig.publishes, 0);
  ASSERT_TRUE(run_until_done(rig, swap)) << "the swap did not end within " << kMaxFrames << " frames";
  rig.ticks(500);  // the re-arm is applied

  EXPECT_EQ(rig.publishes, 1);
  EXPECT_EQ(rig.state_at_publish, DeviceState::kOpen);
  EXPECT_EQ(rig.force_at_publish_n, 0.0);
  expect_zero_force_swap(rig, from);
  EXPECT_EQ(rig.device->state(), DeviceState::kArmed);
  // (Forces come back only once the hand is near the surface again: the proxy's small-force gate
  // keeps them off while the hand, which sank while disarmed, presses deep; proxy.hpp.)
  EXPECT_EQ(rig.shared.counters.commands_rejected.load(), 0U);
  const SceneSwapFigures& f = swap.figures();
  EXPECT_EQ(f.swaps_done, 1);
  EXPECT_EQ(f.max_device_force_n, 0.0);
  EXPECT_FALSE(f.seen_armed);
}

TEST(SceneSwap, AFullCommandRingDelaysTheDisarmUntilThereIsRoom) {
  SwapRig rig;
  SceneSwap swap(rig.shared);
  swap.arm();
  rig.ticks(1500);
  ASSERT_EQ(rig.device->state(), DeviceState::kArmed);
  const std::size_t from = rig.seen.size();
  ASSERT_EQ(rig.fill_ring(), static_cast<int>(haptics::SharedState::kCommandCapacity));
  swap.begin([&] { return rig.publish_b(); });
  for (int i = 0; i < 5; ++i) EXPECT_EQ(swap.step(), SwapPhase::kWaitDisarm);  // no tick: no room
  EXPECT_EQ(rig.publishes, 0);
  EXPECT_EQ(rig.device->state(), DeviceState::kArmed);
  ASSERT_TRUE(run_until_done(rig, swap)) << "the swap did not end within " << kMaxFrames << " frames";
  rig.ticks(500);
  EXPECT_EQ(rig.publishes, 1);
  EXPECT_EQ(rig.state_at_publish, DeviceState::kOpen);
  expect_zero_force_swap(rig, from);
  EXPECT_EQ(rig.device->state(), DeviceState::kArmed);
  EXPECT_EQ(swap.figures().swaps_done, 1);
  EXPECT_EQ(swap.figures().max_device_force_n, 0.0);
}

TEST(SceneSwap, AFullCommandRingAtTheReArmIsRetriedUntilTheArmIsIn) {
  SwapRig rig;
  SceneSwap swap(rig.shared);
  swap.arm();
  rig.ticks(1500);
  const std::size_t from = rig.seen.size();
  swap.begin([&] { return rig.publish_b(); });
  int frames = 0;
  while (swap.step() != SwapPhase::kWaitAdopt) {
    ASSERT_LT(++frames, kMaxFrames) << "the new scene was never published";
    rig.ticks(kTicksPerFrame);
  }
  // The servo adopts scene B; then the ring fills up before the UI's next frame.
  for (frames = 0; rig.shared.counters.surface_tag.load() != rig.tag_b || rig.shared.surface_pending(); ++frames) {
    ASSERT_LT(frames, kMaxFrames) << "scene B was never adopted";
    rig.tick();
  }
  rig.fill_ring();
  EXPECT_EQ(swap.step(), SwapPhase::kIdle);
  EXPECT_TRUE(swap.arm_pending());
  EXPECT_EQ(swap.figures().swaps_done, 1);
  for (int i = 0; i < 5; ++i) {
    swap.step();
    EXPECT_TRUE(swap.arm_pending()) << "no tick: still no room";
  }
  EXPECT_EQ(rig.device->state(), DeviceState::kOpen);
  ASSERT_TRUE(run_until_done(rig, swap)) << "the arm never went in within " << kMaxFrames << " frames";
  for (frames = 0; rig.device->state() != DeviceState::kArmed; ++frames) {
    ASSERT_LT(frames, 100 * kMaxFrames) << "the device was never re-armed";
    rig.tick();
  }
  rig.ticks(10);
  expect_zero_force_swap(rig, from);
}

TEST(SceneSwap, TheReArmWaitsUntilTheServoHasAdoptedTheNewScene) {
  SwapRig rig;
  SceneSwap swap(rig.shared);
  swap.arm();
  rig.ticks(1500);
  const std::size_t from = rig.seen.size();
  swap.begin([&] { return rig.publish_b(); });
  int frames = 0;
  while (swap.step() != SwapPhase::kWaitAdopt) {
    ASSERT_LT(++frames, kMaxFrames) << "the new scene was never published";
    rig.ticks(kTicksPerFrame);
  }
  // The servo is slow (no tick between UI frames): scene B waits in the mailbox, so no arm.
  for (int i = 0; i < 20; ++i) {
    EXPECT_EQ(swap.step(), SwapPhase::kWaitAdopt);
    EXPECT_FALSE(swap.arm_pending());
    EXPECT_EQ(rig.shared.commands.size_approx(), 0U) << "nothing may be queued before the adoption";
  }
  EXPECT_TRUE(rig.shared.surface_pending());
  ASSERT_TRUE(run_until_done(rig, swap)) << "the swap did not end within " << kMaxFrames << " frames";
  rig.ticks(500);
  expect_zero_force_swap(rig, from);
  EXPECT_EQ(rig.device->state(), DeviceState::kArmed);
  EXPECT_EQ(swap.figures().swaps_done, 1);
}

TEST(SceneSwap, AFailingPublishEndsTheSwapWithTheDeviceDisarmed) {
  SwapRig rig;
  SceneSwap swap(rig.shared);
  swap.arm();
  rig.ticks(1500);
  EXPECT_THROW(swap.begin(PublishScene{}), ConfigError);
  EXPECT_FALSE(swap.busy());
  swap.begin([]() -> std::uint64_t { throw InputError("the re-scan's scene is empty"); });
  bool thrown = false;
  for (int f = 0; f < kMaxFrames && !thrown; ++f) {
    try {
      swap.step();
    } catch (const InputError&) {
      thrown = true;
    }
    rig.ticks(kTicksPerFrame);
  }
  ASSERT_TRUE(thrown) << "the hook was never called";
  EXPECT_FALSE(swap.busy());
  rig.ticks(500);
  for (int i = 0; i < 5; ++i) swap.step();
  EXPECT_EQ(rig.device->state(), DeviceState::kOpen) << "no re-arm after a failed swap";
  EXPECT_EQ(rig.seen.back().force_n, 0.0);
  EXPECT_EQ(swap.figures().swaps_done, 0);
  // A hook returning tag 0 cannot be waited for: an error, not a hang.
  swap.begin([] { return std::uint64_t{0}; });
  const auto drive = [&] {
    for (int f = 0; f < kMaxFrames; ++f) {
      swap.step();
      rig.ticks(kTicksPerFrame);
    }
  };
  EXPECT_THROW(drive(), InputError);
  EXPECT_FALSE(swap.busy());
}

}  // namespace
}  // namespace hc::session
