#include "face_reenact/stream/replay_window.h"

#include <gtest/gtest.h>

#include <random>
#include <set>

namespace face_reenact::stream {
namespace {

using V = ReplayWindow::Verdict;

TEST(ReplayWindow, AcceptsNewRejectsDuplicatesAndTooOld) {
  ReplayWindow w;
  EXPECT_EQ(w.check(100), V::kNew);
  w.mark(100);
  EXPECT_EQ(w.check(100), V::kDuplicate);
  EXPECT_EQ(w.check(99), V::kNew);  // reordered, never seen
  w.mark(99);
  EXPECT_EQ(w.check(99), V::kDuplicate);
  EXPECT_EQ(w.check(101), V::kNew);
  w.mark(100 + ReplayWindow::kSize);
  EXPECT_EQ(w.check(100), V::kTooOld);
  EXPECT_EQ(w.check(101), V::kNew);
  EXPECT_EQ(w.check(100 + ReplayWindow::kSize), V::kDuplicate);
}

TEST(ReplayWindow, HugeJumpClearsTheWindow) {
  ReplayWindow w;
  for (uint64_t s = 1; s <= 50; ++s) w.mark(s);
  w.mark(1'000'000'000'000ull);
  EXPECT_EQ(w.check(1'000'000'000'000ull), V::kDuplicate);
  EXPECT_EQ(w.check(1'000'000'000'000ull - 1), V::kNew);
  EXPECT_EQ(w.check(50), V::kTooOld);
}

TEST(ReplayWindow, ExtremeSequenceNumbers) {
  ReplayWindow w;
  w.mark(0);
  EXPECT_EQ(w.check(0), V::kDuplicate);
  w.mark(UINT64_MAX);
  EXPECT_EQ(w.check(UINT64_MAX), V::kDuplicate);
  EXPECT_EQ(w.check(UINT64_MAX - 1), V::kNew);
  EXPECT_EQ(w.check(0), V::kTooOld);
}

TEST(ReplayWindow, MatchesAReferenceModelOnRandomTraffic) {
  std::mt19937_64 rng(1234);
  ReplayWindow w;
  std::set<uint64_t> seen;
  uint64_t highest = 0;
  bool any = false;
  uint64_t base = 5000;
  for (int step = 0; step < 200000; ++step) {
    // Mostly increasing traffic with reordering, duplicates and occasional jumps.
    const int kind = static_cast<int>(rng() % 100);
    uint64_t s;
    if (kind < 60) s = ++base;
    else if (kind < 85) s = base - rng() % 1500;
    else if (kind < 98) s = base - rng() % 40;
    else s = (base += rng() % 3000);
    V expected;
    if (!any || s > highest) expected = V::kNew;
    else if (highest - s >= ReplayWindow::kSize) expected = V::kTooOld;
    else expected = seen.count(s) ? V::kDuplicate : V::kNew;
    ASSERT_EQ(w.check(s), expected) << "step " << step << " seq " << s;
    if (expected == V::kNew) {
      w.mark(s);
      seen.insert(s);
      if (!any || s > highest) highest = s;
      any = true;
    }
    if (seen.size() > 4000) seen.erase(seen.begin(), seen.lower_bound(highest - 2 * ReplayWindow::kSize));
  }
}

}  // namespace
}  // namespace face_reenact::stream
