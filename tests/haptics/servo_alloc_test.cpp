// Zero allocation inside the servo tick: this file replaces the global operator new/delete of
// the whole hc_haptics_tests executable with counting versions (they count only while
// g_counting is set, and otherwise behave like the standard ones).

// The replacement operator new below returns malloc'd memory, so freeing it with free() is
// right; GCC cannot see that through inlining and warns. Only for this file.
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"

#include "hc/haptics/servo_loop.hpp"
#include "hc/haptics/simulated_device.hpp"

#include "haptics_test_support.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <new>
#include <thread>

namespace {
std::atomic<bool> g_counting{false};
std::atomic<long> g_allocations{0};

void* counted_alloc(std::size_t n) {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1, std::memory_order_relaxed);
  return std::malloc(n == 0 ? 1 : n);
}
void* counted_aligned_alloc(std::size_t n, std::align_val_t al) {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1, std::memory_order_relaxed);
  const std::size_t a = static_cast<std::size_t>(al);
  return std::aligned_alloc(a, (n + a - 1) / a * a);
}
}  // namespace

void* operator new(std::size_t n) {
  if (void* p = counted_alloc(n)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t n) {
  if (void* p = counted_alloc(n)) return p;
  throw std::bad_alloc();
}
void* operator new(std::size_t n, const std::nothrow_t&) noexcept { return counted_alloc(n); }
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept { return counted_alloc(n); }
void* operator new(std::size_t n, std::align_val_t al) {
  if (void* p = counted_aligned_alloc(n, al)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t n, std::align_val_t al) {
  if (void* p = counted_aligned_alloc(n, al)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }

namespace hc::haptics {
namespace {

TEST(ServoAllocation, CounterSeesAllocations) {
  g_allocations = 0;
  g_counting = true;
  static int* volatile sink = nullptr;  // keeps the compiler from eliding the pair
  sink = new int(3);
  delete sink;
  g_counting = false;
  EXPECT_EQ(g_allocations.load(), 1);
}

TEST(ServoAllocation, NoAllocationOver100000TicksAfterWarmUp) {
  const HeightField f = test::make_square(200, 0.1, [](double x, double y) { return test::sinusoid(x, y); });
  SurfaceOptions opt;
  opt.default_mu_d = 0.3;
  opt.default_mu_s = 0.4;
  HeightField ids = test::make_square(200, 0.1, [](double x, double) { return x < 0 ? 1.0 : 2.0; });
  SharedState shared(std::make_unique<HapticSurface>(SurfaceLayers{&f, nullptr, nullptr, nullptr, nullptr, &ids}, opt));
  ManualClock clock;
  ScriptedPath path;
  path.kind = PathKind::kRaster;
  path.half_x_m = 0.03;
  path.half_y_m = 0.03;
  path.z_contact_m = -0.01;
  path.speed_m_per_s = 0.08;
  SimulatedDevice dev(clock, path);
  dev.open();
  ServoConfig cfg;
  cfg.proxy.damping_n_s_per_m = 1.0;
  ServoLoop loop(dev, shared, clock, cfg);
  std::vector<TickRecord> trace(200000);
  loop.set_trace(trace);
  shared.commands.try_push(Command::of(CommandType::kArm));
  loop.run_ticks(2000, clock);  // warm-up
  // A surface published before the window is adopted inside it; commands arrive inside it.
  const HeightField g = test::make_square(200, 0.1, [](double x, double y) { return test::sinusoid(x, y) + 0.0005; });
  shared.publish_surface(test::make_surface(g, opt));
  ContactEvent e;
  g_allocations = 0;
  g_counting = true;
  for (int block = 0; block < 10; ++block) {
    shared.commands.try_push(Command::of(CommandType::kSetStiffness, 700.0 + block));
    loop.run_ticks(10000, clock);
    while (shared.events.try_pop(e)) {
    }
  }
  g_counting = false;
  EXPECT_EQ(g_allocations.load(), 0) << "allocations inside servo ticks";
  EXPECT_EQ(loop.stats().ticks, 102000U);
  EXPECT_EQ(shared.counters.surfaces_adopted.load(), 1U);
  EXPECT_GT(shared.counters.commands_applied.load(), 10U);
  shared.collect_retired();
}

TEST(ServoAllocation, SurfaceSwitchWithMapAndForceBlendDoesNotAllocate) {
  // A LoD switch: surface and workspace map adopted together, the proxy carried over and the
  // force step blended; none of it allocates on the servo side.
  const HeightField f = test::make_square(200, 0.1, [](double x, double y) { return test::sinusoid(x, y); });
  SharedState shared(test::make_surface(f));
  ManualClock clock;
  ScriptedPath path;
  path.kind = PathKind::kCircle;
  path.half_x_m = 0.01;
  path.z_contact_m = -0.01;
  SimulatedDevice dev(clock, path);
  dev.open();
  ServoLoop loop(dev, shared, clock, ServoConfig{});
  shared.commands.try_push(Command::of(CommandType::kArm));
  loop.run_ticks(3000, clock);  // warm-up, in contact
  const HeightField g = test::make_square(100, 0.05, [](double x, double y) { return test::sinusoid(x, y) + 0.004; });
  WorkspaceMap m;
  m.scale = 0.5;
  m.origin_m = Eigen::Vector3d(0.0, 0.0, 0.002);
  shared.publish_surface(test::make_surface(g), m, 11);
  ContactEvent e;
  g_allocations = 0;
  g_counting = true;
  loop.run_ticks(5000, clock);
  g_counting = false;
  while (shared.events.try_pop(e)) {
  }
  EXPECT_EQ(g_allocations.load(), 0) << "allocations inside servo ticks";
  EXPECT_EQ(shared.counters.surface_tag.load(), 11U);
  EXPECT_DOUBLE_EQ(loop.config().workspace.scale, 0.5);
  shared.collect_retired();
}

TEST(ServoAllocation, ThreadedTicksDoNotAllocate) {
  const HeightField f = test::make_square(100, 0.1, [](double x, double y) { return test::sinusoid(x, y); });
  SharedState shared(test::make_surface(f));
  SteadyClock clock;
  ScriptedPath path;
  path.z_contact_m = -0.01;
  SimulatedDevice dev(clock, path);
  dev.open();
  ServoConfig cfg;
  cfg.rate_hz = 4000;
  cfg.realtime = RealtimeMode::kOff;
  ServoLoop loop(dev, shared, clock, cfg);
  shared.commands.try_push(Command::of(CommandType::kArm));
  loop.start();
  while (shared.counters.ticks.load() < 500) std::this_thread::sleep_for(std::chrono::milliseconds(2));
  g_allocations = 0;
  g_counting = true;  // only the servo thread runs while this thread waits
  const std::uint64_t from = shared.counters.ticks.load();
  while (shared.counters.ticks.load() < from + 2000) std::this_thread::sleep_for(std::chrono::milliseconds(2));
  g_counting = false;
  loop.stop();
  EXPECT_EQ(g_allocations.load(), 0);
}

}  // namespace
}  // namespace hc::haptics
