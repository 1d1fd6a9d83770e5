#pragma once
// The puppeteer side of the expression stream: frame sources (where expression parameters come
// from) and the ExpressionSender that numbers, encrypts and sends them.
//
// A frame source is anything that yields ExpressionFrames: a parameter file replayed at its
// capture rate (ReplayFileSource), an iPhone running Live Link Face (LiveLinkSource), and later
// the tracker on a camera or recording — it implements ExpressionFrameSource and the sender loop
// (`face-reenact send`) needs no change.
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "face_reenact/stream/livelink.h"
#include "face_reenact/stream/protocol.h"
#include "face_reenact/stream/stream_key.h"
#include "face_reenact/stream/udp.h"

namespace face_reenact::stream {

class ExpressionFrameSource {
 public:
  enum class Status {
    kFrame,  // *frame holds the next frame, due now
    kIdle,   // nothing due within max_wait; call again (lets the caller check for shutdown)
    kEnd,    // the source is exhausted
  };
  virtual ~ExpressionFrameSource() = default;
  // Waits at most `max_wait` for the next frame. The frame's capture_time_us is the wall-clock
  // time at which it was captured (or, for a replay, at which it is played).
  virtual Status next(ExpressionFrame* frame, std::chrono::milliseconds max_wait) = 0;
  virtual std::string description() const = 0;
  // Input the source rejected (malformed packets, ...), and the last reason.
  virtual uint64_t input_errors() const { return 0; }
  virtual std::string last_input_error() const { return {}; }
};

// ---------------------------------------------------------------------------------------------
// Parameter files (docs/stream-protocol.md, "Parameter files"): JSON Lines, one object per
// frame: {"expression": [52 numbers], "timestamp_us": int, "frame": int,
//         "neutral": [52 numbers], "pose": {"rotation": [3], "translation": [3]}}
// Only "expression" is required. Timestamps, when present, must be on every line and increase.
struct ParameterFrame {
  ExpressionFrame frame;  // capture_time_us unused here
  bool has_timestamp = false;
  int64_t timestamp_us = 0;
  int64_t frame_number = -1;
};

struct ParameterFileLimits {
  size_t max_bytes = size_t(1) << 30;
  size_t max_line_bytes = 1 << 16;
  size_t max_frames = 10'000'000;
};
// Throws face_reenact::Error naming the file and line of the first problem.
std::vector<ParameterFrame> load_parameter_file(const std::string& path, const ParameterFileLimits& limits = {});
// One line of a parameter file (no newline), the inverse of the parser.
std::string format_parameter_line(const ParameterFrame& frame);

class ReplayFileSource : public ExpressionFrameSource {
 public:
  struct Options {
    // > 0: play at this rate and ignore timestamps; 0: use the file's timestamps, or 30 Hz when
    // it has none.
    double rate_hz = 0;
    bool loop = false;
    // If playback falls behind its schedule by more than this (machine suspended, debugger),
    // the schedule restarts from now instead of sending a burst of stale frames.
    std::chrono::milliseconds max_lag{250};
    bool IsValid(std::string* why) const;
  };
  ReplayFileSource(std::vector<ParameterFrame> frames, Options options, std::string name);

  Status next(ExpressionFrame* frame, std::chrono::milliseconds max_wait) override;
  std::string description() const override;

  uint64_t schedule_resets() const { return schedule_resets_; }
  // Offset of frame `index` of loop `loop` from the start of playback (ns).
  int64_t schedule_offset_ns(size_t index, uint64_t loop) const;

 private:
  std::vector<ParameterFrame> frames_;
  Options options_;
  std::string name_;
  bool use_timestamps_ = false;
  int64_t period_ns_ = 0;       // fixed-rate period
  int64_t loop_length_ns_ = 0;  // duration of one pass
  size_t index_ = 0;
  uint64_t loop_ = 0;
  bool started_ = false;
  int64_t start_ns_ = 0;  // CLOCK_MONOTONIC of the schedule's origin
  uint64_t schedule_resets_ = 0;
};

// Listens for Live Link Face packets and turns each into a frame.
class LiveLinkSource : public ExpressionFrameSource {
 public:
  // Binds "0.0.0.0:port" (or "ADDR:PORT" / a multicast group via `listen`).
  explicit LiveLinkSource(const ListenSpec& listen);
  Status next(ExpressionFrame* frame, std::chrono::milliseconds max_wait) override;
  std::string description() const override;
  uint64_t input_errors() const override { return errors_; }
  std::string last_input_error() const override { return last_error_; }
  uint16_t port() const { return socket_.local_port(); }
  const std::string& subject_name() const { return subject_; }

 private:
  UdpSocket socket_;
  uint64_t errors_ = 0;
  std::string last_error_;
  std::string subject_;
};

// ---------------------------------------------------------------------------------------------
class ExpressionSender {
 public:
  struct Options {
    uint32_t stream_id = 1;
    // 0: start from the wall clock in microseconds, so a restarted sender continues above the
    // numbers it used before and receivers do not take its datagrams for replays.
    uint64_t first_sequence = 0;
    MulticastSendOptions multicast;
    bool IsValid(std::string* why) const;
  };
  struct Statistics {
    uint64_t sent = 0;
    uint64_t send_errors = 0;  // datagrams the OS refused (no route, port unreachable, ...)
    std::string last_error;
    uint64_t next_sequence = 0;
  };

  // Throws face_reenact::Error (invalid options, socket errors).
  ExpressionSender(const StreamKey& key, const UdpEndpoint& destination, Options options);

  // Encrypts and sends one frame. Returns false if the OS refused it (counted; the stream goes
  // on). Throws face_reenact::Error if the frame's values are invalid.
  bool send(const ExpressionFrame& frame);
  const Statistics& statistics() const { return stats_; }
  const UdpEndpoint& destination() const { return destination_; }

 private:
  StreamKey key_;
  UdpEndpoint destination_;
  Options options_;
  UdpSocket socket_;
  uint64_t sequence_ = 0;
  Statistics stats_;
};

}  // namespace face_reenact::stream
