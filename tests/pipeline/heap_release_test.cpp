// detail::StageHeapRelease and release_freed_heap_if_asked (run_internal.hpp): the tiled run's
// stages give freed heap back to the system when they end; nothing is given back without a
// holder, and holders nest. detail::TileHeapBudget gives it back before a tile only when the
// resident size grew past its budget since the last release, before a gathering whatever the
// budget (release_now), and only with a holder. detail::LargeBlocksMapped maps large blocks on
// their own while alive, under the kept policy with a holder.
//
// Oracle: the process's resident size from the kernel's statm file (proc(5); the library reads
// VmRSS of /proc/self/status), around a 256 MiB block taken from the heap, touched and freed
// under `hapticloud run`'s malloc policy (mallopt M_MMAP_THRESHOLD and M_TRIM_THRESHOLD of
// 1 GiB: freed heap is kept).
//
// These tests exist only in builds with glibc's allocator: they are compiled out of the
// sanitizer builds (CI's ASan and TSan stages), whose allocators keep freed blocks in a
// quarantine of their own, so no resident-size oracle holds there. `scripts/test` (the release
// build, CI's first stage) runs them.

#include "batch_heap_policy.hpp"
#include "run_internal.hpp"

#include <gtest/gtest.h>

#include <cstddef>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <memory>

#ifdef __GLIBC__
#include <malloc.h>
#include <unistd.h>
#endif

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define HC_TEST_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) || __has_feature(memory_sanitizer)
#define HC_TEST_SANITIZED 1
#endif
#endif

namespace hc::pipeline::heap_release_test {
namespace {

#if defined(__GLIBC__) && !defined(HC_TEST_SANITIZED)
using hc::pipeline::detail::release_freed_heap_if_asked;
using hc::pipeline::detail::StageHeapRelease;

constexpr std::size_t kBlock = std::size_t{256} << 20;  // the block each test takes and frees
constexpr std::size_t kSlack = std::size_t{32} << 20;   // other allocations, page tables

// Resident size [bytes] from /proc/self/statm (its second field, in pages): a reading of its
// own, not the library's (status); 0 if unreadable.
std::size_t resident_bytes() {
  std::ifstream statm("/proc/self/statm");
  std::size_t size_pages = 0, resident_pages = 0;
  if (!(statm >> size_pages >> resident_pages)) return 0;
  return resident_pages * static_cast<std::size_t>(sysconf(_SC_PAGESIZE));
}

// Takes `bytes` from the heap, writes every page and frees it: the block's pages stay resident
// as free heap under the 1 GiB trim threshold.
void touch_and_free(std::size_t bytes) {
  std::unique_ptr<char[]> block(new char[bytes]);
  std::memset(block.get(), 1, bytes);
  // Read back so the stores cannot be dropped.
  volatile char sink = block[bytes / 2];
  (void)sink;
}

TEST(StageHeapRelease, GivesFreedHeapBackOnlyWhileHeld) {
  const hc::test::BatchHeapPolicy policy;  // glibc's defaults back when the test ends
  ASSERT_TRUE(policy.both());
  ASSERT_GT(resident_bytes(), 0U) << "/proc/self/status has no VmRSS";

  // The premise: freed, the block stays resident.
  const std::size_t before = resident_bytes();
  touch_and_free(kBlock);
  const std::size_t kept = resident_bytes();
  ASSERT_GT(kept, before + kBlock - kSlack) << "the freed block should stay resident under the 1 GiB trim threshold";

  // No holder: nothing is given back.
  release_freed_heap_if_asked();
  EXPECT_GT(resident_bytes(), kept - kSlack);

  {
    const StageHeapRelease outer;
    {
      const StageHeapRelease inner;
    }
    // The outer holder is still alive after the inner one ends: given back.
    release_freed_heap_if_asked();
    EXPECT_LT(resident_bytes(), kept - kBlock + kSlack);
  }

  // Both gone: a freed block stays resident again.
  const std::size_t after_release = resident_bytes();
  touch_and_free(kBlock);
  const std::size_t kept_again = resident_bytes();
  release_freed_heap_if_asked();
  EXPECT_GT(resident_bytes(), kept_again - kSlack);
  EXPECT_GT(kept_again, after_release + kBlock - kSlack);
}

using hc::pipeline::detail::TileHeapBudget;

// Without a StageHeapRelease alive: `step` (before_tile or release_now) of a budget of
// `budget_bytes`, after a freed block past it, gives nothing back and counts nothing.
void expect_nothing_given_back_without_a_holder(std::size_t budget_bytes, bool (TileHeapBudget::*step)()) {
  TileHeapBudget budget(budget_bytes);
  touch_and_free(kBlock);
  const std::size_t kept = resident_bytes();
  EXPECT_FALSE((budget.*step)());
  EXPECT_GT(resident_bytes(), kept - kSlack);
  EXPECT_EQ(budget.releases(), 0U);
}

TEST(TileHeapBudget, GivesBackOnlyPastItsBudgetAndWithAHolder) {
  const hc::test::BatchHeapPolicy policy;
  ASSERT_TRUE(policy.both());
  // The library's reading (status), which the budget compares, agrees with this test's (statm).
  const std::size_t r0 = hc::pipeline::detail::resident_bytes(), r1 = resident_bytes();
  EXPECT_LT(r0 > r1 ? r0 - r1 : r1 - r0, kSlack);

  // Without a holder: the budget is passed, nothing is given back.
  expect_nothing_given_back_without_a_holder(std::size_t{64} << 20, &TileHeapBudget::before_tile);
  const StageHeapRelease holder;
  malloc_trim(0);
  {
    // Within a budget larger than what was freed: kept for the next tile.
    TileHeapBudget budget(std::size_t{512} << 20);
    touch_and_free(kBlock);
    const std::size_t kept = resident_bytes();
    EXPECT_FALSE(budget.before_tile());
    EXPECT_GT(resident_bytes(), kept - kSlack);
  }
  malloc_trim(0);
  {
    // Past a smaller budget: given back, counted; then the resident size is the new base.
    TileHeapBudget budget(std::size_t{64} << 20);
    touch_and_free(kBlock);
    const std::size_t kept = resident_bytes();
    EXPECT_TRUE(budget.before_tile());
    EXPECT_LT(resident_bytes(), kept - kBlock + kSlack);
    EXPECT_EQ(budget.releases(), 1U);
    EXPECT_FALSE(budget.before_tile()) << "nothing grew since the release";
  }
}

// release_now (before a band's gathering of strays and its first sweep): gives back whatever the
// budget says, only with a holder; counted; the resident size after it is the new base.
TEST(TileHeapBudget, ReleasesNowWithinItsBudgetOnlyWithAHolder) {
  const hc::test::BatchHeapPolicy policy;
  ASSERT_TRUE(policy.both());
  expect_nothing_given_back_without_a_holder(std::size_t{1} << 30, &TileHeapBudget::release_now);
  const StageHeapRelease holder;
  malloc_trim(0);
  // A budget of 1 GiB, which before_tile keeps the freed block under: release_now gives it back.
  TileHeapBudget budget(std::size_t{1} << 30);
  touch_and_free(kBlock);
  const std::size_t kept = resident_bytes();
  ASSERT_FALSE(budget.before_tile()) << "the premise: within the budget, before_tile keeps the block";
  EXPECT_GT(resident_bytes(), kept - kSlack);
  EXPECT_TRUE(budget.release_now());
  EXPECT_LT(resident_bytes(), kept - kBlock + kSlack);
  EXPECT_EQ(budget.releases(), 1U);
  // The base is the resident size after the release: a block of a quarter of the budget is then
  // kept.
  touch_and_free(kBlock);
  EXPECT_FALSE(budget.before_tile());
  EXPECT_EQ(budget.releases(), 1U);
}

using hc::pipeline::detail::LargeBlocksMapped;

// LargeBlocksMapped (the tile loop of a run of several bands): while alive, with the threshold
// keep_freed_heap_for_reuse() set and a holder, a block of its threshold or more is given back
// when freed (mapped on its own); once it ends, the kept threshold is back and a freed block
// stays resident again; without a holder, or before the process set the kept policy, it changes
// nothing; nested guards keep the threshold until the outer one ends. Mutation: a constructor
// that does not set the threshold keeps the block resident (the second check fails); a
// destructor that does not restore it gives the last block back; one that restores at every
// guard's end fails the nested check.
TEST(LargeBlocksMapped, MapsLargeBlocksOnlyUnderTheKeptPolicyWithAHolderAndRestoresIt) {
  constexpr std::size_t kThreshold = std::size_t{8} << 20;
  hc::pipeline::detail::g_kept_mmap_threshold.store(0);  // as in a process that never set the kept policy
  {
    const StageHeapRelease holder;
    const LargeBlocksMapped mapped(kThreshold);
    EXPECT_FALSE(mapped.active()) << "no kept threshold to restore: nothing changed";
  }
  const hc::test::BatchHeapPolicy policy;  // glibc's defaults and no recorded threshold after
  ASSERT_TRUE(policy.both());
  {
    // No holder: the kept policy stands; a freed block stays resident.
    const LargeBlocksMapped mapped(kThreshold);
    EXPECT_FALSE(mapped.active());
    const std::size_t before = resident_bytes();
    touch_and_free(kBlock);
    EXPECT_GT(resident_bytes(), before + kBlock - kSlack);
  }
  const StageHeapRelease holder;
  malloc_trim(0);
  {
    const LargeBlocksMapped mapped(kThreshold);
    EXPECT_TRUE(mapped.active());
    const std::size_t before = resident_bytes();
    touch_and_free(kBlock);
    EXPECT_LT(resident_bytes(), before + kSlack) << "the block was unmapped when freed";
  }
  {
    // Nested: the inner guard's end leaves the outer's threshold in force.
    const LargeBlocksMapped outer(kThreshold);
    {
      const LargeBlocksMapped inner(kThreshold);
      EXPECT_TRUE(inner.active());
    }
    const std::size_t before = resident_bytes();
    touch_and_free(kBlock);
    EXPECT_LT(resident_bytes(), before + kSlack) << "still mapped while the outer guard lives";
  }
  // The kept threshold back: freed, a block stays resident (nothing trims it: no stage ended).
  const std::size_t before = resident_bytes();
  touch_and_free(kBlock);
  EXPECT_GT(resident_bytes(), before + kBlock - kSlack);
}

#endif  // glibc, no sanitizer

}  // namespace
}  // namespace hc::pipeline::heap_release_test
