// Private helpers of the pipeline stages (stage_util.hpp): detail::run_tasks_on_two, the write
// stage's two threads taking the scene's files and the previews in turn.
//
// Every task runs exactly once (counted per task, 1000 tasks), on two threads (the first task
// waits until another thread has taken one: a single thread would leave one id); an empty list
// returns; a single task runs on the calling thread; after a task throws, the exception rethrown
// is the one of the task earliest in the list among those that threw, whichever finished first,
// and no task after a failure is started once both threads have seen it.

#include "stage_util.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <functional>
#include <mutex>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace hc::pipeline::stage_util_test {
namespace {

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

}  // namespace
}  // namespace hc::pipeline::stage_util_test
