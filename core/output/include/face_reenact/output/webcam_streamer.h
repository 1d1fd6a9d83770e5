#pragma once
// Drives a virtual webcam: frames from a FrameSource, converted on a producer thread, go out
// to a FrameSink on absolute deadlines (FramePacer) from the calling thread. The sink may fail
// and come back: a lost device is closed and reopened on a timer while the stream keeps its
// clock, so readers that survive see frames again as soon as the device is back.
//
// OutputLoop is the deterministic core (no threads, no clock of its own), tested with a fake
// clock and a fake sink; WebcamStreamer adds the producer thread and the real clock.
#include <atomic>
#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "face_reenact/output/frame_pacer.h"
#include "face_reenact/output/frame_sink.h"
#include "face_reenact/output/frame_source.h"
#include "face_reenact/output/pixel_conversion.h"

namespace face_reenact::output {

enum class SinkState { kConnected, kDisconnected };
const char* sink_state_name(SinkState state);

struct StreamStatistics {
  PacerStatistics pacer;           // fresh / repeated / dropped / missed deadlines
  int64_t frames_written = 0;      // successful writes (fresh + repeated)
  int64_t write_errors = 0;        // transient write failures (frame skipped)
  int64_t disconnects = 0;         // times the device was lost
  int64_t reconnects = 0;          // times it came back
  int64_t undelivered = 0;         // deadlines that passed while disconnected
  int64_t source_frames = 0;       // frames the source delivered
  SinkState state = SinkState::kConnected;
  std::string last_error;          // the latest write/reopen error, empty when none

  std::string BriefReport() const;  // one line for --status and the summary
};

class OutputLoop {
 public:
  using Nanos = std::chrono::nanoseconds;
  struct Options {
    FrameRate rate{30, 1};
    Nanos reconnect_interval = std::chrono::seconds(2);
  };

  // `initial_frame` is what is repeated until the producer delivers (the writer's priming
  // frame, black). The sink must already be open.
  OutputLoop(FrameSink* sink, Options options, std::vector<uint8_t> initial_frame);

  // Producer side: a converted frame (same size as initial_frame) is ready.
  void offer(std::vector<uint8_t>&& frame);
  // Output side: called at (or after) next_deadline(); writes what the pacer decides, or
  // handles the disconnected state. Returns the deadline to sleep until next.
  Nanos on_wake(Nanos now);
  Nanos next_deadline() const { return pacer_.next_deadline(); }

  const StreamStatistics& statistics() const { return stats_; }
  // Frame buffers handed back for reuse by the producer (avoids an allocation per frame).
  std::vector<uint8_t> take_spare_buffer();

 private:
  void write_current();

  FrameSink* sink_;
  Options options_;
  FramePacer pacer_;
  std::vector<uint8_t> current_;  // what was last sent (or is repeated)
  std::vector<uint8_t> pending_;  // the newest offered, not yet sent
  std::vector<uint8_t> spare_;
  Nanos next_reconnect_{0};
  StreamStatistics stats_;
};

class WebcamStreamer {
 public:
  struct Options {
    int width = 1280;
    int height = 720;
    PixelFormat format = PixelFormat::kYuyv;
    FrameRate rate{30, 1};
    std::chrono::nanoseconds reconnect_interval = std::chrono::seconds(2);
    // At the end of the source: stop, or keep repeating the last frame until stopped (a still
    // image, or a clip the user wants to freeze on).
    bool hold_last_frame = false;
    // Called about once a second from the output thread (the --status line).
    std::function<void(const StreamStatistics&)> on_status;
  };

  struct Summary {
    StreamStatistics statistics;
    std::string stop_reason;  // "stop requested", "end of source", "source error: ..."
    bool source_failed = false;
    double seconds = 0;
    std::string BriefReport() const;
  };

  WebcamStreamer(FrameSource* source, FrameSink* sink, Options options);

  // Streams until `stop` becomes true, the source ends (unless hold_last_frame) or fails.
  // Never returns later than about one frame period after `stop` is set.
  Summary run(const std::atomic<bool>& stop);

 private:
  FrameSource* source_;
  FrameSink* sink_;
  Options options_;
};

// Installs SIGINT/SIGTERM handlers that set the returned flag (and ignores SIGPIPE); the
// previous handlers come back when the guard is destroyed.
class StopSignalGuard {
 public:
  StopSignalGuard();
  ~StopSignalGuard();
  StopSignalGuard(const StopSignalGuard&) = delete;
  StopSignalGuard& operator=(const StopSignalGuard&) = delete;
  const std::atomic<bool>& flag() const;
  int signal_number() const;  // the signal that arrived, 0 if none
};

}  // namespace face_reenact::output
