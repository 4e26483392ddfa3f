// Private helpers of the pipeline stages (stage_util.hpp): detail::run_tasks_on_two, the write
// stage's two threads taking the scene's files and the previews in turn.
//
// Every task runs exactly once (counted per task, 1000 tasks), on two threads (the first task
// waits until another thread has taken one: a single thread would leave one id); an empty list
// returns; a single task runs on the calling thread; after a task throws, the exception rethrown
// is the one of the task earliest in the list among those that threw, whichever finished first,
// and no task after a failure is started once both threads have seen it.
//
// detail::floor_of and detail::ceil_of (the inline floor and ceiling the point loops use)
// against the C library's std::floor and std::ceil: a set of hard cases, and a random sweep of
// both signs and all magnitudes.

#include "stage_util.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <functional>
#include <limits>
#include <mutex>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace hc::pipeline::stage_util_test {
namespace {

using hc::pipeline::detail::ceil_of;
using hc::pipeline::detail::floor_of;
using hc::pipeline::detail::run_tasks_on_two;

TEST(RunTasksOnTwo, RunsEveryTaskOnceOnBothThreads) {
  constexpr int kTasks = 1000;
  std::vector<std::atomic<int>> runs(kTasks);
  std::mutex m;
  std::set<std::thread::id> threads;
  std::vector<std::function<void()>> tasks;
  for (int k = 0; k < kTasks; ++k) {
    tasks.emplace_back([&, k] {
      runs[static_cast<std::size_t>(k)].fetch_add(1);
      {
        const std::lock_guard<std::mutex> lock(m);
        threads.insert(std::this_thread::get_id());
      }
      // Task 0 waits (at most 10 s) until another thread has taken a task: one thread alone
      // would wait the whole time and leave one thread id.
      const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(10);
      while (k == 0 && std::chrono::steady_clock::now() < until) {
        {
          const std::lock_guard<std::mutex> lock(m);
          if (threads.size() == 2) break;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
      }
    });
  }
  run_tasks_on_two(tasks);
  for (int k = 0; k < kTasks; ++k) EXPECT_EQ(runs[static_cast<std::size_t>(k)].load(), 1) << "task " << k;
  EXPECT_EQ(threads.size(), 2U) << "one thread took every task";
  EXPECT_NO_THROW(run_tasks_on_two({}));
}

// A single task runs once, on the calling thread, and its exception reaches the caller.
TEST(RunTasksOnTwo, ASingleTaskRunsOnTheCallingThread) {
  std::thread::id ran_on;
  int runs = 0;
  run_tasks_on_two({[&] {
    ran_on = std::this_thread::get_id();
    ++runs;
  }});
  EXPECT_EQ(runs, 1);
  EXPECT_EQ(ran_on, std::this_thread::get_id());
  EXPECT_THROW(run_tasks_on_two({[] { throw std::runtime_error("the only task"); }}), std::runtime_error);
}

TEST(RunTasksOnTwo, RethrowsTheEarliestTaskInTheListThatThrewAndStartsNoneAfter) {
  std::atomic<int> started_after{0};
  std::vector<std::function<void()>> tasks;
  // Task 0 throws last (after a wait), task 1 at once: the rethrown one is still task 0's.
  tasks.emplace_back([] {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    throw std::runtime_error("task 0");
  });
  tasks.emplace_back([] { throw std::runtime_error("task 1"); });
  for (int k = 0; k < 100; ++k) tasks.emplace_back([&] { started_after.fetch_add(1); });
  try {
    run_tasks_on_two(tasks);
    ADD_FAILURE() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()), "task 0");
  }
  // Task 1 threw while task 0 was still running: the thread that ran it starts nothing more,
  // nor does the other after task 0.
  EXPECT_EQ(started_after.load(), 0);
}

// The same value, or both NaN; +0 and −0 count as equal (floor_of's documented difference).
bool same(double a, double b) { return (std::isnan(a) && std::isnan(b)) || a == b; }

std::vector<double> hard_cases() {
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<double> v = {0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 1.5, -1.5, 2.5, -2.5, 1e-300, -1e-300,
                           std::numeric_limits<double>::denorm_min(), -std::numeric_limits<double>::denorm_min(),
                           0x1p52, -0x1p52, 0x1p52 - 0.5, -0x1p52 + 0.5, 0x1p53, -0x1p53, 0x1p63, -0x1p63, 1e300, -1e300,
                           inf, -inf, std::numeric_limits<double>::quiet_NaN()};
  // Either side of integers, small and large.
  for (const double n : {1.0, 2.0, 3.0, 1023.0, 1048576.0, 4503599627370495.0}) {
    for (const double s : {1.0, -1.0}) {
      v.push_back(std::nextafter(s * n, 0.0));
      v.push_back(std::nextafter(s * n, s * inf));
    }
  }
  return v;
}

TEST(StageUtil, FloorAndCeilingEqualTheLibrarys) {
  for (const double x : hard_cases()) {
    EXPECT_TRUE(same(floor_of(x), std::floor(x))) << "floor_of(" << x << ") = " << floor_of(x);
    EXPECT_TRUE(same(ceil_of(x), std::ceil(x))) << "ceil_of(" << x << ") = " << ceil_of(x);
  }
  // Random doubles of both signs and every magnitude (random bit patterns), and coordinates
  // about a centre as the point loops see them (cells of 0.4 mm over ±10 m).
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> coord(-10.0, 10.0);
  int wrong = 0;
  for (int i = 0; i < 200000; ++i) {
    const std::uint64_t bits = rng();
    double x = 0.0;
    std::memcpy(&x, &bits, sizeof x);
    const double y = coord(rng) / 4e-4;
    for (const double v : {x, y}) {
      if (!same(floor_of(v), std::floor(v)) || !same(ceil_of(v), std::ceil(v))) ++wrong;
    }
  }
  EXPECT_EQ(wrong, 0);
}

}  // namespace
}  // namespace hc::pipeline::stage_util_test
