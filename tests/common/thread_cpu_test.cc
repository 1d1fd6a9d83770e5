#include "face_reenact/common/thread_cpu.h"

#include <gtest/gtest.h>
#include <pthread.h>

#include <atomic>
#include <chrono>
#include <thread>

namespace face_reenact {
namespace {

TEST(ThreadCpuTest, ParsesAStatLineWhoseNameHoldsSpacesAndParentheses) {
  // Fields after the name: state ppid pgrp session tty tpgid flags minflt cminflt majflt cmajflt
  // utime(14) stime(15) cutime cstime priority nice(19) ...
  const std::string stat = "4242 (fr (a) b) S 1 1 1 0 -1 4194368 10 0 0 0 250 50 0 0 30 10 1 0 100 0";
  ThreadInfo info;
  ASSERT_TRUE(ParseThreadStat(stat, 100.0, &info));
  EXPECT_EQ(info.tid, 4242);
  EXPECT_EQ(info.name, "fr (a) b");
  EXPECT_DOUBLE_EQ(info.cpu_s, 3.0);  // (250 + 50) ticks at 100 Hz
  EXPECT_EQ(info.nice, 10);
}

TEST(ThreadCpuTest, MalformedStatLinesAreRejected) {
  ThreadInfo info;
  EXPECT_FALSE(ParseThreadStat("", 100.0, &info));
  EXPECT_FALSE(ParseThreadStat("12 no-parentheses S 1 1", 100.0, &info));
  EXPECT_FALSE(ParseThreadStat("12 (short) S 1 1 1", 100.0, &info));  // ends before utime
  EXPECT_FALSE(ParseThreadStat("12 (x) S 1 1 1 0 -1 4 10 0 0 0 250 50 0 0 30 10", 0.0, &info));
}

TEST(ThreadCpuTest, ABusyNamedThreadIsListedWithTheCpuTimeItUsed) {
  std::atomic<bool> named{false}, done{false};
  std::thread busy([&] {
    pthread_setname_np(pthread_self(), "fr-test-busy");
    named = true;
    // Spin for about 300 ms of CPU time (the kernel counts it in 10 ms ticks).
    const auto until = std::chrono::steady_clock::now() + std::chrono::milliseconds(300);
    volatile double x = 0;
    while (std::chrono::steady_clock::now() < until) x = x + 1.0;
    while (!done) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  });
  while (!named) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  double busy_cpu = -1;
  for (const ThreadInfo& t : ProcessThreads())
    if (t.name == "fr-test-busy") busy_cpu = t.cpu_s;
  done = true;
  busy.join();
  ASSERT_GE(busy_cpu, 0) << "the named thread is not listed";
  // On a loaded machine the spin gets less of a core than it asked for, never more.
  EXPECT_GT(busy_cpu, 0.05);
  EXPECT_LT(busy_cpu, 1.0);
  EXPECT_GE(ProcessCpuSeconds(), busy_cpu);
}

}  // namespace
}  // namespace face_reenact
