#pragma once
// When to send frames to the virtual webcam, as pure logic over a clock the caller supplies
// (so it is tested with a fake clock, deterministically).
//
// Deadlines are absolute: tick k is due at start + k / fps, computed from k every time rather
// than by adding a rounded period, so the stream never drifts. At each deadline the writer
// sends exactly one frame:
//   - the newest frame the producer delivered since the last deadline (older undelivered ones
//     are dropped: a fast producer is thinned to the rate);
//   - or, when none arrived (the producer is late), the last frame again: readers such as
//     Chrome stall or show an error when a camera stops delivering.
// When the writer itself wakes late (a stalled write, a loaded machine) the missed deadlines
// are skipped, not made up in a burst, and counted.
#include <chrono>
#include <cstdint>
#include <optional>
#include <string>

namespace face_reenact::output {

// An exact frame rate num/den frames per second (30000/1001 = 29.97).
struct FrameRate {
  int64_t num = 30;
  int64_t den = 1;

  // 30 -> 30/1, 29.97 -> 2997/100 (reduced). Returns nullopt outside (0, kMaxFps] or non-finite.
  static std::optional<FrameRate> from_double(double fps);
  double fps() const { return double(num) / double(den); }
  bool IsValid(std::string* error) const;
};

inline constexpr double kMaxFps = 240;

struct PacerStatistics {
  int64_t fresh = 0;            // deadlines that sent a new frame
  int64_t repeated = 0;         // deadlines that re-sent the last frame (producer late)
  int64_t dropped = 0;          // produced frames replaced before any deadline took them
  int64_t missed_deadlines = 0; // deadlines skipped because the writer woke late
};

class FramePacer {
 public:
  using Nanos = std::chrono::nanoseconds;  // time since the stream started
  enum class Action { kSendFresh, kRepeatLast };
  struct Tick {
    Action action;
    int64_t tick_index;      // which deadline this is
    int64_t skipped = 0;     // deadlines passed over before it (writer woke late)
  };

  explicit FramePacer(FrameRate rate);

  // Absolute deadline of tick k (k >= 0), exact to the nanosecond below.
  Nanos deadline(int64_t tick) const;
  Nanos next_deadline() const { return deadline(next_tick_); }

  // The producer delivered a frame. If the previous one was not sent yet, it is dropped.
  void frame_arrived();
  bool has_fresh_frame() const { return fresh_pending_; }

  // The writer woke at `now`. Before the next deadline: nullopt (nothing to send). Otherwise
  // the action for the latest deadline <= now; the pacer then waits for the one after now.
  std::optional<Tick> on_wake(Nanos now);

  const PacerStatistics& statistics() const { return stats_; }
  const FrameRate& rate() const { return rate_; }

 private:
  int64_t latest_tick_at(Nanos now) const;  // largest k with deadline(k) <= now

  FrameRate rate_;
  int64_t next_tick_ = 0;
  bool fresh_pending_ = false;
  PacerStatistics stats_;
};

}  // namespace face_reenact::output
