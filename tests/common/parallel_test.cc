// ParallelFor: every item runs exactly once on any thread count, exceptions reach the caller,
// and calls from inside items (nested) or from several threads at once finish.
#include "face_reenact/common/parallel.h"

#include <gtest/gtest.h>

#include <atomic>
#include <set>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <vector>

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

}  // namespace
}  // namespace face_reenact
