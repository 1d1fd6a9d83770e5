#pragma once
// Everything a receiver knows about its expression streams, without any socket: it is fed
// datagrams (process) by one thread and sampled (sample) by any number of consumer threads.
// ExpressionReceiver wraps it with a UDP socket and a thread; tests and the fuzz target drive
// it directly with synthetic arrival times.
//
// Which streams are accepted (docs/stream-protocol.md, "Receiving"):
//  - with an allow-list (Options::allowed_streams, up to kMaxStreams ids), datagrams of other
//    stream ids are dropped before any cryptography;
//  - without one, the receiver locks onto the first stream that authenticates and from then on
//    treats every other stream id as unknown (until reset()).
// Of several allowed streams, one is *active*: its frames are applied; the others are standbys
// that take over only once the active one has been silent for Options::timeout (failover).
//
// Per active stream, latest wins: a datagram is applied only if its sequence number is higher
// and its capture time not older than the last applied one. Older-but-new sequence numbers
// (reordered) are counted and not applied; duplicates/replays and numbers older than the replay
// window are rejected.
#include <array>
#include <chrono>
#include <cstdint>
#include <functional>
#include <mutex>
#include <span>
#include <string>
#include <vector>

#include "face_reenact/stream/protocol.h"
#include "face_reenact/stream/replay_window.h"
#include "face_reenact/stream/stream_key.h"

namespace face_reenact::stream {

using SteadyClock = std::chrono::steady_clock;

// Sender's wall clock in microseconds since the Unix epoch (CLOCK_REALTIME).
uint64_t realtime_now_us();

// Counters of a receiver. received == applied + reordered + late + standby + rejected_total().
struct ReceiverStatistics {
  uint64_t received = 0;   // datagrams handed to the receiver
  uint64_t applied = 0;    // became the current remote expression
  uint64_t reordered = 0;  // authenticated, new, but older than the current one: not applied
  uint64_t late = 0;       // newer sequence number but older capture time: not applied
  uint64_t standby = 0;    // authenticated datagrams of a standby stream: not applied
  uint64_t lost = 0;       // sequence numbers skipped by the active stream and never seen since
  uint64_t sequence_jumps = 0;  // forward jumps too large to be losses (a sender restarted)
  uint64_t stream_switches = 0;  // times the active stream changed (lock-on counts as one)
  uint64_t kernel_drops = 0;     // datagrams the OS dropped because the socket buffer was full
  std::array<uint64_t, kNumDatagramErrors> rejected_by_reason{};
  uint64_t rejected(DatagramError e) const { return rejected_by_reason[static_cast<size_t>(e)]; }
  uint64_t rejected_total() const;
  // "received 412, applied 271, rejected 19, lost 38, reordered 120, late 2, kernel drops 0":
  // the counts as `receive`, `webcam --status` and `bench live` print them.
  std::string Counts() const;

  bool has_active_stream = false;
  uint32_t active_stream = 0;
  uint64_t last_sequence = 0;
  double rate_hz = 0;          // applied datagrams per second over the last measurement window
  double latency_ms = 0;       // smoothed (receive wall clock - capture time); needs synced clocks
  double latency_min_ms = 0;   // smallest seen: network delay + clock offset
  double latency_jitter_ms = 0;  // smoothed |latency - smoothed latency|
};

// What a consumer gets from sample(now).
struct RemoteExpression {
  // Blend weight of the remote expression in [0, 1]; use
  //   expression = weight * remote + (1 - weight) * own
  // 0 means "no remote expression": the caller uses the target's own expression.
  float weight = 0;
  bool has_frame = false;  // a frame was ever applied (its values below are meaningful)
  bool live = false;       // the stream delivered within the timeout
  std::array<float, kNumCoefficients> expression{};  // relative to the sender's neutral face
  bool has_rotation = false;
  std::array<float, 3> rotation{};
  bool has_translation = false;
  std::array<float, 3> translation{};
  uint32_t stream_id = 0;
  uint64_t sequence = 0;
  uint64_t capture_time_us = 0;
  double age_ms = 0;  // time since this frame arrived
};

// Passed to Options::on_applied for every applied datagram.
struct AppliedDatagram {
  DatagramHeader header;
  ExpressionFrame frame;
  uint64_t receive_time_us = 0;  // receiver wall clock
};

struct StreamStateOptions {
  std::vector<uint32_t> allowed_streams;  // empty: lock onto the first authenticated stream
  std::chrono::milliseconds timeout{500};  // silence after which the stream counts as stopped
  std::chrono::milliseconds ramp{250};     // cross-fade duration, both directions
  // Called on the processing thread after each applied datagram; must return quickly.
  std::function<void(const AppliedDatagram&)> on_applied;

  static constexpr size_t kMaxStreams = 16;
  bool IsValid(std::string* why) const;
};

class ExpressionStreamState {
 public:
  // Throws face_reenact::Error if the options are invalid.
  ExpressionStreamState(const StreamKey& key, StreamStateOptions options);

  // Processes one datagram that arrived at `arrival` (receiver wall clock `receive_time_us`).
  // Returns kNone when it was authenticated and accepted (applied or counted as reordered/late/
  // standby), else the rejection reason (also counted). Single producer: call from one thread.
  DatagramError process(std::span<const uint8_t> datagram, SteadyClock::time_point arrival,
                        uint64_t receive_time_us);
  // Adds datagrams the OS reported as dropped.
  void add_kernel_drops(uint64_t n);

  // Thread-safe, never waits on I/O (a short critical section copying ~600 bytes).
  RemoteExpression sample(SteadyClock::time_point now) const;
  ReceiverStatistics statistics(SteadyClock::time_point now) const;

  // Forgets the locked stream, windows and current frame (statistics are kept). Call it from
  // the thread that calls process().
  void reset();

 private:
  struct StreamSlot {
    uint32_t id = 0;
    bool used = false;
    ReplayWindow window;
    SteadyClock::time_point last_accepted{};
  };
  StreamSlot* find_slot(uint32_t stream_id);
  float weight_at(SteadyClock::time_point t) const;  // needs mu_
  void count_reject(DatagramError e);

  const StreamKey key_;
  const StreamStateOptions options_;
  const bool lock_on_first_;

  // Processing-thread state.
  std::array<StreamSlot, StreamStateOptions::kMaxStreams> slots_{};
  size_t num_slots_ = 0;

  // Shared with consumers.
  mutable std::mutex mu_;
  ReceiverStatistics stats_;
  bool has_active_ = false;
  size_t active_slot_ = 0;
  uint64_t highest_applied_seq_ = 0;
  uint64_t last_applied_capture_us_ = 0;
  // The current frame and the cross-fade state (see weight_at).
  bool has_frame_ = false;
  ExpressionFrame frame_;
  std::array<float, kNumCoefficients> relative_{};
  uint32_t frame_stream_ = 0;
  uint64_t frame_seq_ = 0;
  SteadyClock::time_point last_arrival_{};
  SteadyClock::time_point fade_in_start_{};
  float fade_in_from_ = 0;
  // Rate measurement: applied count at the start of the current one-second window.
  SteadyClock::time_point rate_window_start_{};
  uint64_t rate_window_applied_ = 0;
  bool latency_initialised_ = false;
};

}  // namespace face_reenact::stream
