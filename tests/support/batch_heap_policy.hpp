#pragma once
// The batch commands' allocator policy for a test's lifetime: hc::pipeline::keep_freed_heap_for_reuse
// (run.hpp: mallopt M_MMAP_THRESHOLD and M_TRIM_THRESHOLD of 1 GiB, the threshold recorded for
// the tile loop's detail::LargeBlocksMapped) when made; glibc's default thresholds (fixed at
// 128 KiB), no recorded threshold and the free heap given back when it ends, for whatever runs
// next in the same process (ctest runs each test in a process of its own; a run of the whole
// binary does not). `taken` says which thresholds the C library took: AddressSanitizer's
// allocator answers mallopt with 0, and then no tile loop maps its large blocks on their own.

#include "hc/pipeline/run.hpp"
#include "run_internal.hpp"

#ifdef __GLIBC__
#include <malloc.h>
#endif

namespace hc::test {

struct BatchHeapPolicy {
  BatchHeapPolicy() : taken(hc::pipeline::keep_freed_heap_for_reuse()) {}
  ~BatchHeapPolicy() {
#ifdef __GLIBC__
    (void)mallopt(M_MMAP_THRESHOLD, 128 * 1024);
    (void)mallopt(M_TRIM_THRESHOLD, 128 * 1024);
    (void)malloc_trim(0);
#endif
    hc::pipeline::detail::g_kept_mmap_threshold.store(0);
  }
  BatchHeapPolicy(const BatchHeapPolicy&) = delete;
  BatchHeapPolicy& operator=(const BatchHeapPolicy&) = delete;
  /// Both thresholds taken (the heap tests' premise).
  bool both() const { return taken.mmap_threshold_set && taken.trim_threshold_set; }
  const hc::pipeline::HeapPolicyTaken taken;
};

}  // namespace hc::test
