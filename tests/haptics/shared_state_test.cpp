// Channels between the servo thread and the rest: single-threaded semantics, and concurrent
// producer/consumer runs meant to be run under the ThreadSanitizer preset (tsan) as well.

#include "hc/haptics/shared_state.hpp"
#include "hc/haptics/spsc_ring.hpp"
#include "hc/haptics/triple_buffer.hpp"

#include "haptics_test_support.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <memory>
#include <thread>
#include <type_traits>

namespace hc::haptics {
namespace {

static_assert(std::is_trivially_copyable_v<Snapshot>);
static_assert(std::is_trivially_copyable_v<ContactEvent>);
static_assert(std::is_trivially_copyable_v<Command>);

TEST(SpscRing, FifoAndCapacity) {
  SpscRing<int, 4> ring;
  int v = 0;
  EXPECT_FALSE(ring.try_pop(v));
  for (int k = 0; k < 4; ++k) EXPECT_TRUE(ring.try_push(k));
  EXPECT_FALSE(ring.try_push(99));  // full: nothing stored
  EXPECT_EQ(ring.size_approx(), 4U);
  for (int k = 0; k < 4; ++k) {
    ASSERT_TRUE(ring.try_pop(v));
    EXPECT_EQ(v, k);
  }
  EXPECT_FALSE(ring.try_pop(v));
  // Wrap around many times.
  for (int k = 0; k < 1000; ++k) {
    ASSERT_TRUE(ring.try_push(k));
    ASSERT_TRUE(ring.try_pop(v));
    ASSERT_EQ(v, k);
  }
}

TEST(SpscRing, ConcurrentProducerConsumerKeepsOrderAndLosesNothing) {
  struct Item {
    std::uint64_t seq;
    std::uint64_t check;
  };
  auto ring = std::make_unique<SpscRing<Item, 256>>();
  constexpr std::uint64_t kN = 200000;
  std::thread producer([&] {
    for (std::uint64_t k = 0; k < kN; ++k) {
      while (!ring->try_push(Item{k, k * 2654435761ULL})) std::this_thread::yield();
    }
  });
  std::uint64_t expected = 0;
  Item it{};
  while (expected < kN) {
    if (ring->try_pop(it)) {
      ASSERT_EQ(it.seq, expected);
      ASSERT_EQ(it.check, expected * 2654435761ULL);
      ++expected;
    } else {
      std::this_thread::yield();
    }
  }
  producer.join();
  EXPECT_FALSE(ring->try_pop(it));
}

TEST(TripleBuffer, ReaderSeesLatestCompleteValues) {
  struct Value {
    std::uint64_t seq = 0;
    double a = 0, b = 0, c = 0;
  };
  TripleBuffer<Value> tb;
  Value out;
  EXPECT_FALSE(tb.read(out));  // nothing written yet
  EXPECT_EQ(out.seq, 0U);
  tb.write(Value{1, 1, 2, 3});
  tb.write(Value{2, 2, 4, 6});
  EXPECT_TRUE(tb.read(out));
  EXPECT_EQ(out.seq, 2U);  // the latest, not the first
  EXPECT_FALSE(tb.read(out));
  EXPECT_EQ(out.seq, 2U);
}

TEST(TripleBuffer, ConcurrentWriterNeverTearsAValue) {
  struct Value {
    std::uint64_t seq = 0;
    std::uint64_t words[12] = {};
  };
  auto tb = std::make_unique<TripleBuffer<Value>>();
  constexpr std::uint64_t kN = 200000;
  std::atomic<bool> done{false};
  std::thread writer([&] {
    Value v;
    for (std::uint64_t k = 1; k <= kN; ++k) {
      v.seq = k;
      for (auto& w : v.words) w = k;
      tb->write(v);
    }
    done.store(true, std::memory_order_release);
  });
  std::uint64_t last = 0, reads = 0, fresh = 0;
  Value v;
  while (!done.load(std::memory_order_acquire) || last < kN) {
    if (tb->read(v)) ++fresh;
    ++reads;
    for (const auto w : v.words) ASSERT_EQ(w, v.seq) << "torn value";
    ASSERT_GE(v.seq, last) << "went back in time";
    last = v.seq;
  }
  writer.join();
  EXPECT_EQ(last, kN);
  EXPECT_GT(fresh, 0U);
  EXPECT_GE(reads, fresh);
}

std::unique_ptr<const HapticSurface> constant_surface(double z) {
  const HeightField f = test::make_field(3, 3, 0.01, 0, 0, [z](double, double) { return z; });
  return test::make_surface(f);
}

TEST(SharedState, MailboxAdoptsAndRetires) {
  SharedState shared(constant_surface(1.0));
  EXPECT_NEAR(shared.adopt_surface()->height(0, 0), 1.0, 1e-6);
  shared.publish_surface(constant_surface(2.0));
  shared.publish_surface(constant_surface(3.0));  // replaces the un-adopted 2.0 (freed here)
  EXPECT_TRUE(shared.surface_pending());
  EXPECT_NEAR(shared.adopt_surface()->height(0, 0), 3.0, 1e-6);
  EXPECT_FALSE(shared.surface_pending());
  EXPECT_EQ(shared.counters.surfaces_adopted.load(), 1U);
  EXPECT_EQ(shared.collect_retired(), 1U);  // 1.0 came back to be freed outside the servo
  EXPECT_EQ(shared.collect_retired(), 0U);
  // A full retire ring defers adoption instead of freeing on the servo side.
  for (std::size_t k = 0; k < SharedState::kRetireCapacity; ++k) {
    shared.publish_surface(constant_surface(10.0 + static_cast<double>(k)));
    shared.adopt_surface();
  }
  shared.publish_surface(constant_surface(42.0));
  EXPECT_NEAR(shared.adopt_surface()->height(0, 0), 10.0 + SharedState::kRetireCapacity - 1, 1e-5);
  EXPECT_TRUE(shared.surface_pending());
  EXPECT_EQ(shared.collect_retired(), SharedState::kRetireCapacity);
  EXPECT_NEAR(shared.adopt_surface()->height(0, 0), 42.0, 1e-5);
}

TEST(SharedState, ConcurrentSurfaceSwapsAreSafe) {
  SharedState shared(constant_surface(0.0));
  std::atomic<bool> stop{false};
  std::atomic<std::uint64_t> adopted_reads{0};
  std::thread servo([&] {
    double last = 0.0;
    while (!stop.load(std::memory_order_acquire)) {
      const HapticSurface* s = shared.adopt_surface();
      const double z = s->height(0.01, 0.01);  // touches the surface's memory
      ASSERT_GE(z, last - 1e-6) << "an older surface came back";
      last = z;
      adopted_reads.fetch_add(1, std::memory_order_relaxed);
    }
  });
  for (int k = 1; k <= 2000; ++k) {
    shared.publish_surface(constant_surface(k));
    shared.collect_retired();
    if (k % 100 == 0) std::this_thread::yield();
  }
  while (shared.surface_pending()) {
    shared.collect_retired();
    std::this_thread::yield();
  }
  stop.store(true, std::memory_order_release);
  servo.join();
  shared.collect_retired();
  EXPECT_GT(adopted_reads.load(), 0U);
  EXPECT_NEAR(shared.current_surface()->height(0, 0), 2000.0, 1e-3);
}

TEST(SharedState, EventAndCommandChannelsAcrossThreads) {
  SharedState shared;
  constexpr int kN = 50000;
  std::thread servo([&] {
    int sent = 0;
    Command c;
    int received = 0;
    while (sent < kN || received < kN) {
      if (sent < kN) {
        ContactEvent e;
        e.tick = static_cast<std::uint64_t>(sent);
        if (shared.events.try_push(e)) ++sent;
      }
      while (shared.commands.try_pop(c)) {
        ASSERT_EQ(c.a, static_cast<double>(received));
        ++received;
      }
    }
  });
  int got = 0, pushed = 0;
  ContactEvent e;
  while (got < kN || pushed < kN) {
    if (pushed < kN && shared.commands.try_push(Command::of(CommandType::kSetRho, pushed))) ++pushed;
    while (shared.events.try_pop(e)) {
      ASSERT_EQ(e.tick, static_cast<std::uint64_t>(got));
      ++got;
    }
  }
  servo.join();
}

// Surface accounting (the soak benchmark's "every surface retired"): the expected counts follow
// from the publication protocol step by step (shared_state.hpp), not from the implementation.
TEST(SharedState, SurfaceAccountingFollowsPublishSupersedeAdoptAndCollect) {
  const HeightField depth = test::make_square(8, 0.1, [](double, double) { return 0.0; });
  SharedState shared(test::make_surface(depth));  // the initial surface: published 1
  EXPECT_EQ(shared.surfaces_published(), 1U);
  EXPECT_EQ(shared.surfaces_freed(), 0U);
  shared.publish_surface(test::make_surface(depth));  // A pending
  shared.publish_surface(test::make_surface(depth));  // B supersedes A before adoption: A freed
  EXPECT_EQ(shared.surfaces_published(), 3U);
  EXPECT_EQ(shared.surfaces_freed(), 1U);
  ASSERT_NE(shared.adopt_surface(), nullptr);  // B current, the initial one to the retire ring
  EXPECT_EQ(shared.surfaces_freed(), 1U);       // the servo never frees
  EXPECT_EQ(shared.collect_retired(), 1U);
  EXPECT_EQ(shared.surfaces_freed(), 2U);
  // Many switches, each adopted and collected: exactly one surface (the current) stays held.
  for (int k = 0; k < 50; ++k) {
    shared.publish_surface(test::make_surface(depth));
    ASSERT_NE(shared.adopt_surface(), nullptr);
    shared.collect_retired();
  }
  EXPECT_EQ(shared.surfaces_published(), 53U);
  EXPECT_EQ(shared.surfaces_published() - shared.surfaces_freed(), 1U);
}

TEST(SharedState, SurfaceAccountingUnderARunningServoHoldsAtMostCurrentPendingAndRing) {
  const HeightField depth = test::make_square(8, 0.1, [](double, double) { return 0.0; });
  auto shared = std::make_unique<SharedState>();
  std::atomic<bool> stop{false};
  std::thread servo([&] {
    while (!stop.load(std::memory_order_acquire)) (void)shared->adopt_surface();
  });
  constexpr std::uint64_t kN = 2000;
  std::uint64_t worst_held = 0;
  for (std::uint64_t k = 0; k < kN; ++k) {
    shared->publish_surface(test::make_surface(depth));
    shared->collect_retired();
    worst_held = std::max(worst_held, shared->surfaces_published() - shared->surfaces_freed());
  }
  stop.store(true, std::memory_order_release);
  servo.join();
  shared->collect_retired();
  EXPECT_EQ(shared->surfaces_published(), kN);
  EXPECT_LE(worst_held, 2U + SharedState::kRetireCapacity);
  EXPECT_LE(shared->surfaces_published() - shared->surfaces_freed(), 2U);  // current + pending
}

}  // namespace
}  // namespace hc::haptics
