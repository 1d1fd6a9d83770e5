#include "face_reenact/output/webcam_streamer.h"

#include <algorithm>
#include <condition_variable>
#include <csignal>
#include <cstdio>
#include <thread>

#include "face_reenact/common/error.h"

namespace face_reenact::output {

const char* sink_state_name(SinkState state) {
  return state == SinkState::kConnected ? "connected" : "disconnected";
}

std::string StreamStatistics::BriefReport() const {
  char line[512];
  std::snprintf(line, sizeof line,
                "written %lld (fresh %lld, repeated %lld), dropped %lld, missed deadlines %lld, write errors %lld, "
                "disconnects %lld, reconnects %lld, device %s",
                static_cast<long long>(frames_written), static_cast<long long>(pacer.fresh),
                static_cast<long long>(pacer.repeated), static_cast<long long>(pacer.dropped),
                static_cast<long long>(pacer.missed_deadlines), static_cast<long long>(write_errors),
                static_cast<long long>(disconnects), static_cast<long long>(reconnects), sink_state_name(state));
  std::string s(line);
  if (!last_error.empty()) s += " (last error: " + last_error + ")";
  return s;
}

std::string WebcamStreamer::Summary::BriefReport() const {
  char head[96];
  std::snprintf(head, sizeof head, "%.1f s, ", seconds);
  return stop_reason + ": " + head + statistics.BriefReport();
}

// ------------------------------------------------------------------------------------------
OutputLoop::OutputLoop(FrameSink* sink, Options options, std::vector<uint8_t> initial_frame)
    : sink_(sink), options_(options), pacer_(options.rate), current_(std::move(initial_frame)) {
  if (!sink_) throw Error("OutputLoop needs a sink");
  if (current_.empty()) throw Error("OutputLoop needs an initial frame");
  if (options_.reconnect_interval <= Nanos(0)) options_.reconnect_interval = std::chrono::seconds(2);
}

void OutputLoop::offer(std::vector<uint8_t>&& frame) {
  if (frame.size() != current_.size()) return;  // never send a frame of another size
  if (pacer_.has_fresh_frame()) spare_ = std::move(pending_);
  pending_ = std::move(frame);
  pacer_.frame_arrived();
  stats_.pacer = pacer_.statistics();
}

std::vector<uint8_t> OutputLoop::take_spare_buffer() { return std::move(spare_); }

void OutputLoop::write_current() {
  std::string why;
  switch (sink_->write_frame(current_, &why)) {
    case WriteOutcome::kWritten:
      ++stats_.frames_written;
      break;
    case WriteOutcome::kTransientError:
      ++stats_.write_errors;
      stats_.last_error = why;
      break;
    case WriteOutcome::kDeviceLost:
      ++stats_.disconnects;
      stats_.last_error = why;
      stats_.state = SinkState::kDisconnected;
      sink_->close();
      break;
  }
}

OutputLoop::Nanos OutputLoop::on_wake(Nanos now) {
  std::optional<FramePacer::Tick> tick = pacer_.on_wake(now);
  if (tick && tick->action == FramePacer::Action::kSendFresh) {
    std::swap(current_, pending_);
    spare_ = std::move(pending_);
  }
  stats_.pacer = pacer_.statistics();
  if (stats_.state == SinkState::kDisconnected) {
    if (tick) ++stats_.undelivered;
    if (now >= next_reconnect_) {
      std::string why;
      if (sink_->reopen(&why)) {
        stats_.state = SinkState::kConnected;
        ++stats_.reconnects;
        stats_.last_error.clear();
        write_current();  // the newest picture at once, not the priming black
      } else {
        stats_.last_error = why;
        next_reconnect_ = now + options_.reconnect_interval;
      }
    }
    return pacer_.next_deadline();
  }
  if (tick) {
    write_current();
    if (stats_.state == SinkState::kDisconnected) next_reconnect_ = now + options_.reconnect_interval;
  }
  return pacer_.next_deadline();
}

// ------------------------------------------------------------------------------------------
WebcamStreamer::WebcamStreamer(FrameSource* source, FrameSink* sink, Options options)
    : source_(source), sink_(sink), options_(std::move(options)) {
  if (!source_ || !sink_) throw Error("WebcamStreamer needs a source and a sink");
  std::string why;
  if (!options_.rate.IsValid(&why)) throw Error(why);
  frame_bytes(options_.format, options_.width, options_.height);  // validates the size
}

WebcamStreamer::Summary WebcamStreamer::run(const std::atomic<bool>& stop) {
  using Clock = std::chrono::steady_clock;
  using Nanos = std::chrono::nanoseconds;
  const size_t frame_size = frame_bytes(options_.format, options_.width, options_.height);
  std::vector<uint8_t> black(frame_size);
  fill_black(options_.format, options_.width, options_.height, black);
  OutputLoop loop(sink_, {options_.rate, options_.reconnect_interval}, std::move(black));

  // Shared between the producer thread and this (output) thread.
  std::mutex mutex;
  std::condition_variable wake_producer;
  std::vector<uint8_t> ready, recycled;
  bool have_ready = false, source_done = false, quit_producer = false;
  std::string source_error;
  int64_t source_frames = 0;

  const Clock::time_point start = Clock::now();
  auto stop_requested = [&] { return stop.load(std::memory_order_relaxed); };

  std::thread producer([&] {
    std::string error;
    try {
      while (true) {
        {
          std::lock_guard lock(mutex);
          if (quit_producer) return;
        }
        SourceFrame frame;
        SourceStatus status = source_->next(&frame, &error);
        if (status != SourceStatus::kFrame) {
          std::lock_guard lock(mutex);
          source_done = true;
          if (status == SourceStatus::kError) source_error = error.empty() ? "unknown source error" : error;
          return;
        }
        if (!source_->is_live()) {
          // A recorded frame is due at its timestamp: wait for it, waking for a stop.
          std::unique_lock lock(mutex);
          wake_producer.wait_until(lock, start + frame.timestamp, [&] { return quit_producer; });
          if (quit_producer) return;
        }
        cv::Mat fitted = letterbox_bgr(frame.bgr, options_.width, options_.height);
        std::vector<uint8_t> buffer;
        {
          std::lock_guard lock(mutex);
          buffer = std::move(recycled);
        }
        buffer.resize(frame_size);
        convert_bgr(fitted, options_.format, buffer);
        std::lock_guard lock(mutex);
        ready = std::move(buffer);
        have_ready = true;
        ++source_frames;
      }
    } catch (const std::exception& e) {
      std::lock_guard lock(mutex);
      source_done = true;
      source_error = std::string("frame conversion failed: ") + e.what();
    }
  });

  Summary summary;
  Clock::time_point next_status = start + std::chrono::seconds(1);
  while (true) {
    if (stop_requested()) {
      summary.stop_reason = "stop requested";
      break;
    }
    Nanos now = Clock::now() - start;
    bool finished = false;
    if (now >= loop.next_deadline()) {
      bool had_frame;
      {
        std::lock_guard lock(mutex);
        had_frame = have_ready;
        if (have_ready) {
          loop.offer(std::move(ready));
          have_ready = false;
        }
        if (recycled.empty()) recycled = loop.take_spare_buffer();
        if (source_done && !had_frame) finished = true;
      }
      loop.on_wake(now);
      if (finished) {
        std::lock_guard lock(mutex);
        if (!source_error.empty()) {
          summary.stop_reason = "source error: " + source_error;
          summary.source_failed = true;
          break;
        }
        if (!options_.hold_last_frame) {
          summary.stop_reason = "end of source";
          break;
        }
      }
    }
    if (options_.on_status && Clock::now() >= next_status) {
      StreamStatistics s = loop.statistics();
      {
        std::lock_guard lock(mutex);
        s.source_frames = source_frames;
      }
      options_.on_status(s);
      next_status += std::chrono::seconds(1);
    }
    // Sleep to the next deadline in slices, so a stop request is seen within 50 ms.
    Clock::time_point wake = std::min(start + loop.next_deadline(), Clock::now() + std::chrono::milliseconds(50));
    std::this_thread::sleep_until(wake);
  }

  {
    std::lock_guard lock(mutex);
    quit_producer = true;
  }
  wake_producer.notify_all();
  producer.join();
  summary.statistics = loop.statistics();
  summary.statistics.source_frames = source_frames;
  summary.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  return summary;
}

// ------------------------------------------------------------------------------------------
namespace {
std::atomic<bool> g_stop_flag{false};
volatile std::sig_atomic_t g_stop_signal = 0;
struct sigaction g_previous_int, g_previous_term, g_previous_pipe;

extern "C" void on_stop_signal(int signal_number) {
  g_stop_signal = signal_number;
  g_stop_flag.store(true);
}
}  // namespace

StopSignalGuard::StopSignalGuard() {
  g_stop_flag.store(false);
  g_stop_signal = 0;
  struct sigaction action {};
  action.sa_handler = on_stop_signal;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, &g_previous_int);
  sigaction(SIGTERM, &action, &g_previous_term);
  struct sigaction ignore {};
  ignore.sa_handler = SIG_IGN;
  sigemptyset(&ignore.sa_mask);
  sigaction(SIGPIPE, &ignore, &g_previous_pipe);
}

StopSignalGuard::~StopSignalGuard() {
  sigaction(SIGINT, &g_previous_int, nullptr);
  sigaction(SIGTERM, &g_previous_term, nullptr);
  sigaction(SIGPIPE, &g_previous_pipe, nullptr);
}

const std::atomic<bool>& StopSignalGuard::flag() const { return g_stop_flag; }
int StopSignalGuard::signal_number() const { return g_stop_signal; }

}  // namespace face_reenact::output
