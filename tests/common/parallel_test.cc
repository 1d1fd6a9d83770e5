// ParallelFor: every item runs exactly once on any thread count, exceptions reach the caller,
// and calls from inside items (nested) or from several threads at once finish. NamedThread and
// RunBeside: one kept, named thread for work handed over again and again.
#include "face_reenact/common/parallel.h"

#include <gtest/gtest.h>
#include <pthread.h>

#include <atomic>
#include <chrono>
#include <future>
#include <mutex>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "face_reenact/common/thread_cpu.h"

namespace face_reenact {
namespace {

TEST(ParallelFor, RunsEveryItemExactlyOnceForAnyThreadCount) {
  for (int threads : {0, 1, 2, 3, 8, 64}) {
    for (int count : {0, 1, 2, 7, 100}) {
      std::vector<std::atomic<int>> runs(static_cast<size_t>(count));
      ParallelFor(count, threads, [&](int k) { runs[static_cast<size_t>(k)].fetch_add(1); });
      for (int k = 0; k < count; ++k) EXPECT_EQ(runs[static_cast<size_t>(k)].load(), 1) << threads << " " << count;
    }
  }
}

TEST(ParallelFor, RunsItemsOnTwoThreadsAtOnce) {
  // Items that wait for each other can only finish when two threads run them at the same time;
  // repeated, so helpers taken from the pool for one call serve the next ones too.
  for (int call = 0; call < 20; ++call) {
    std::atomic<int> arrived{0};
    std::set<std::thread::id> seen;
    std::mutex m;
    ParallelFor(2, 2, [&](int) {
      arrived.fetch_add(1);
      while (arrived.load() < 2) std::this_thread::yield();
      std::lock_guard<std::mutex> lock(m);
      seen.insert(std::this_thread::get_id());
    });
    EXPECT_EQ(seen.size(), 2u);
  }
}

TEST(ParallelFor, RethrowsAnItemsExceptionAfterTheOthersRan) {
  std::atomic<int> ran{0};
  EXPECT_THROW(ParallelFor(50, 4,
                           [&](int k) {
                             ran.fetch_add(1);
                             if (k == 17) throw std::runtime_error("item 17");
                           }),
               std::runtime_error);
  EXPECT_EQ(ran.load(), 50);
  // The pool is still usable afterwards.
  std::atomic<int> again{0};
  ParallelFor(10, 4, [&](int) { again.fetch_add(1); });
  EXPECT_EQ(again.load(), 10);
}

TEST(ParallelFor, NestedCallsFinish) {
  std::atomic<int> leaves{0};
  ParallelFor(8, 4, [&](int) { ParallelFor(8, 4, [&](int) { ParallelFor(4, 2, [&](int) { leaves.fetch_add(1); }); }); });
  EXPECT_EQ(leaves.load(), 8 * 8 * 4);
}

TEST(ParallelFor, CallsFromSeveralThreadsAtOnceFinish) {
  std::atomic<long> sum{0};
  std::vector<std::thread> callers;
  for (int c = 0; c < 4; ++c) {
    callers.emplace_back([&] {
      for (int call = 0; call < 200; ++call) ParallelFor(16, 3, [&](int k) { sum.fetch_add(k); });
    });
  }
  for (auto& t : callers) t.join();
  EXPECT_EQ(sum.load(), 4L * 200 * (15 * 16 / 2));
}

double helpers_cpu_seconds() {
  double s = 0;
  for (const ThreadInfo& t : ProcessThreads())
    if (t.name == "fr-parallel") s += t.cpu_s;
  return s;
}

TEST(ParallelFor, AnIdlePoolGivesItsCoresBack) {
  // Helpers and callers watch for work for a moment before they sleep (waking a thread costs
  // more than most calls take); that watch must end. After a burst of calls the helpers use no
  // more CPU while nothing is asked of them: over 300 ms, far less than a watch that never
  // stopped would (300 ms per helper).
  if (ProcessThreads().empty()) GTEST_SKIP() << "/proc/self/task is not readable here";
  std::atomic<long> sum{0};
  for (int call = 0; call < 500; ++call) ParallelFor(4, 4, [&](int k) { sum.fetch_add(k); });
  EXPECT_EQ(sum.load(), 500L * 6);
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  const double before = helpers_cpu_seconds();
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  EXPECT_LT(helpers_cpu_seconds() - before, 0.05) << "the pool's helpers kept a core busy with no work";
}

}  // namespace
}  // namespace face_reenact

namespace face_reenact {
namespace {

std::string current_thread_name() {
  char name[16] = {};
  pthread_getname_np(pthread_self(), name, sizeof name);
  return name;
}

int threads_named(const std::string& name) {
  int n = 0;
  for (const ThreadInfo& t : ProcessThreads()) n += t.name == name;
  return n;
}

// The kept thread has its name from the moment it exists (a thread started per job carried its
// creator's name until it renamed itself, which a per-thread CPU table could catch), runs every
// job on that one thread in the order given, and hands results and exceptions back.
TEST(NamedThread, IsNamedBeforeItIsSeenAndRunsEveryJobInOrder) {
  std::thread::id kept;
  {
    NamedThread worker("fr-test-kept");
    EXPECT_EQ(threads_named("fr-test-kept"), 1);
    std::vector<int> order;
    std::vector<std::future<int>> results;
    for (int k = 0; k < 20; ++k) {
      results.push_back(worker.Submit([&order, &kept, k] {
        EXPECT_EQ(current_thread_name(), "fr-test-kept");
        if (k == 0) kept = std::this_thread::get_id();
        EXPECT_EQ(std::this_thread::get_id(), kept);
        order.push_back(k);
        return k * k;
      }));
    }
    for (int k = 0; k < 20; ++k) EXPECT_EQ(results[static_cast<size_t>(k)].get(), k * k);
    for (int k = 0; k < 20; ++k) EXPECT_EQ(order[static_cast<size_t>(k)], k);
    auto failed = worker.Submit([]() -> int { throw std::runtime_error("job failed"); });
    EXPECT_THROW(failed.get(), std::runtime_error);
    EXPECT_EQ(worker.Submit([] { return 7; }).get(), 7);  // still serving after a failure
  }
  EXPECT_EQ(threads_named("fr-test-kept"), 0);  // joined
  EXPECT_NE(kept, std::this_thread::get_id());
}

// Destroyed with jobs still queued, it runs them before it joins: a job may hold the only copy of
// work whose owner waits for it elsewhere (the albedo texture's build).
TEST(NamedThread, RunsTheJobsAlreadySubmittedBeforeItJoins) {
  std::atomic<int> ran{0};
  {
    NamedThread worker("fr-test-drain");
    for (int k = 0; k < 5; ++k) {
      worker.Submit([&ran] {
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
        ran.fetch_add(1);
      });
    }
  }
  EXPECT_EQ(ran.load(), 5);
}

// Both halves run at once (each waits for the other to start), the kept thread serves every
// step, and an exception from the caller's half waits for the other half first.
TEST(RunBeside, RunsBothHalvesAtOnceOnTheKeptThread) {
  NamedThread beside("fr-test-beside");
  std::set<std::thread::id> beside_ids;
  for (int step = 0; step < 10; ++step) {
    std::atomic<int> started{0};
    double waited = -1;
    const int r = RunBeside(
        beside,
        [&] {
          started.fetch_add(1);
          while (started.load() < 2) std::this_thread::yield();
          beside_ids.insert(std::this_thread::get_id());
          return step;
        },
        [&] {
          started.fetch_add(1);
          while (started.load() < 2) std::this_thread::yield();
        },
        &waited);
    EXPECT_EQ(r, step);
    EXPECT_GE(waited, 0.0);
  }
  EXPECT_EQ(beside_ids.size(), 1u);
  std::atomic<bool> beside_done{false};
  EXPECT_THROW(RunBeside(
                   beside,
                   [&] {
                     std::this_thread::sleep_for(std::chrono::milliseconds(20));
                     beside_done = true;
                     return 0;
                   },
                   [] { throw std::runtime_error("here failed"); }),
               std::runtime_error);
  EXPECT_TRUE(beside_done.load());
}

}  // namespace
}  // namespace face_reenact
