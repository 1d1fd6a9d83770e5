#pragma once
// When the live session renders each frame on a thread of its own while the worker tracks the
// next (LiveSession::Options::overlap_frames_when_behind; docs/real-time.md, "Two threads when
// behind"). On two CPU cores the two threads give up to a third more frames per second to a
// pipeline that cannot keep up with its input, but cost 7-20 ms of latency, and where another
// program takes the cores they gain little. So: one thread while it keeps up; two once it falls
// behind, kept only while they take clearly more frames than one did; one again, tried now and
// then, once the machine has time to spare.
#include <chrono>
#include <cstdint>
#include <string>

namespace face_reenact::live {

class FrameOverlapPolicy {
 public:
  using Clock = std::chrono::steady_clock;

  struct Options {
    // Frames are counted over windows this long; the decision is taken at the end of each.
    std::chrono::milliseconds window{2000};
    // Behind: the input delivered frames the worker never took (the capture thread keeps only the
    // newest), more than this share of them over a window. A worker that keeps up drops about
    // none (a 30 fps clip: 0-4 of 360 in 12 s, 27 fps one thread: 36 of 360). 3 % (29.1 of 30
    // fps) was measured too: beside a program taking 15 % of a core it started the second thread
    // where one showed 28.9-29.6 fps, for the same rate and 10-21 ms more latency.
    double behind_share = 0.05;
    // Two threads are kept when their first window kept up with the input (a 30 fps camera that
    // one thread showed at 28), or took at least this much more frames per second than one
    // thread's last (27 -> 30 fps from a faster camera); otherwise one thread again. -1 keeps
    // them whatever they take.
    double min_gain = 0.1;
    // ... and while the mean capture-to-output latency of their frames over a window stays within
    // this (the live target of docs/real-time.md; 0: no bound). Under a foreign load two threads
    // took 28 fps for 71 ms where one took 23 for 57.
    double max_latency_ms = 70;
    // Two threads are held this long before one thread is tried again; a try that falls behind
    // at once doubles the hold, up to max_hold (a machine that stays busy pays one window of the
    // slower rate every few minutes, not every 20 s). Two threads that gained too little, or came
    // too late, are not tried again for as long, doubling likewise.
    std::chrono::milliseconds first_hold{20000};
    std::chrono::milliseconds max_hold{160000};

    bool IsValid(std::string* why) const;
  };

  FrameOverlapPolicy();  // default options
  explicit FrameOverlapPolicy(const Options& options);  // throws face_reenact::Error when invalid

  // One frame the worker took: `input_sequence` is the input's count when it delivered the frame
  // (the frames between two taken ones were dropped). `tracked` false (calibrating, no face, a
  // failure) starts the window again: such frames' pace says nothing of the tracked frames'.
  // `latency_ms`: the capture-to-output latency of the frame published last (NaN: none yet).
  // Returns whether the frames from now on are to overlap.
  bool Update(Clock::time_point now, int64_t input_sequence, bool tracked, double latency_ms);

  bool overlapped() const { return overlapped_; }
  int switches() const { return switches_; }  // changes so far, either way
  // The share of the input's frames dropped over the last whole window (0 before the first).
  double last_dropped_share() const { return last_dropped_share_; }
  double last_latency_ms() const { return last_latency_ms_; }  // the mean over the last whole window (0 before)

 private:
  Options options_;
  bool overlapped_ = false;
  bool trying_one_ = false;  // one thread again after a hold: behind in its first window doubles the hold
  bool checking_two_ = false;  // two threads' first window: compared with one thread's rate
  std::chrono::milliseconds two_hold_, one_hold_;
  Clock::time_point overlapped_since_{};
  Clock::time_point two_not_before_{};  // after two threads that gained too little
  double one_rate_ = 0;  // frames per second one thread took in the window that made it two
  bool window_open_ = false;
  Clock::time_point window_start_{};
  int64_t window_first_sequence_ = 0;
  int64_t window_taken_ = 0;  // frames taken after the window's first
  double window_latency_ms_ = 0;  // summed over the window's frames with a latency
  int64_t window_latencies_ = 0;
  int switches_ = 0;
  double last_dropped_share_ = 0;
  double last_latency_ms_ = 0;
};

}  // namespace face_reenact::live
