#include "face_reenact/stream/stream_state.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>

#include "face_reenact/common/error.h"

namespace face_reenact::stream {
namespace {

// Forward sequence gaps up to this many count as lost datagrams; larger ones are a restarted
// sender (sequence numbers start from its clock in microseconds, see ExpressionSender).
constexpr uint64_t kMaxCountedGap = 65536;
constexpr double kLatencySmoothing = 1.0 / 16.0;

double seconds(SteadyClock::duration d) { return std::chrono::duration<double>(d).count(); }

}  // namespace

uint64_t realtime_now_us() {
  timespec ts;
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<uint64_t>(ts.tv_sec) * 1000000u + static_cast<uint64_t>(ts.tv_nsec) / 1000u;
}

uint64_t ReceiverStatistics::rejected_total() const {
  uint64_t n = 0;
  for (uint64_t r : rejected_by_reason) n += r;
  return n;
}

std::string ReceiverStatistics::Counts() const {
  char line[256];
  std::snprintf(line, sizeof line,
                "received %llu, applied %llu, rejected %llu, lost %llu, reordered %llu, late %llu, kernel drops %llu",
                static_cast<unsigned long long>(received), static_cast<unsigned long long>(applied),
                static_cast<unsigned long long>(rejected_total()), static_cast<unsigned long long>(lost),
                static_cast<unsigned long long>(reordered), static_cast<unsigned long long>(late),
                static_cast<unsigned long long>(kernel_drops));
  return line;
}

bool StreamStateOptions::IsValid(std::string* why) const {
  auto bad = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (allowed_streams.size() > kMaxStreams)
    return bad("at most " + std::to_string(kMaxStreams) + " allowed streams, got " +
               std::to_string(allowed_streams.size()));
  for (size_t i = 0; i < allowed_streams.size(); ++i)
    for (size_t j = i + 1; j < allowed_streams.size(); ++j)
      if (allowed_streams[i] == allowed_streams[j])
        return bad("stream id " + std::to_string(allowed_streams[i]) + " is listed twice");
  if (timeout.count() <= 0) return bad("timeout must be positive");
  if (ramp.count() < 0) return bad("ramp must not be negative");
  return true;
}

ExpressionStreamState::ExpressionStreamState(const StreamKey& key, StreamStateOptions options)
    : key_(key), options_(std::move(options)), lock_on_first_(options_.allowed_streams.empty()) {
  std::string why;
  if (!options_.IsValid(&why)) throw Error("expression receiver: " + why);
  for (uint32_t id : options_.allowed_streams) {
    slots_[num_slots_].id = id;
    slots_[num_slots_].used = true;
    ++num_slots_;
  }
}

ExpressionStreamState::StreamSlot* ExpressionStreamState::find_slot(uint32_t stream_id) {
  for (size_t i = 0; i < num_slots_; ++i)
    if (slots_[i].id == stream_id) return &slots_[i];
  return nullptr;
}

void ExpressionStreamState::count_reject(DatagramError e) {
  std::lock_guard<std::mutex> lock(mu_);
  ++stats_.received;
  ++stats_.rejected_by_reason[static_cast<size_t>(e)];
}

void ExpressionStreamState::add_kernel_drops(uint64_t n) {
  std::lock_guard<std::mutex> lock(mu_);
  stats_.kernel_drops += n;
}

DatagramError ExpressionStreamState::process(std::span<const uint8_t> datagram,
                                             SteadyClock::time_point arrival, uint64_t receive_time_us) {
  DatagramHeader header;
  DatagramError e = parse_datagram_header(datagram, &header);
  if (e != DatagramError::kNone) {
    count_reject(e);
    return e;
  }
  StreamSlot* slot = find_slot(header.stream_id);
  if (!slot && !(lock_on_first_ && num_slots_ == 0)) {
    count_reject(DatagramError::kUnknownStream);
    return DatagramError::kUnknownStream;
  }
  if (slot) {
    // Cheap replay check before the authentication; the window moves only after it.
    switch (slot->window.check(header.sequence)) {
      case ReplayWindow::Verdict::kDuplicate: count_reject(DatagramError::kReplay); return DatagramError::kReplay;
      case ReplayWindow::Verdict::kTooOld: count_reject(DatagramError::kTooOld); return DatagramError::kTooOld;
      case ReplayWindow::Verdict::kNew: break;
    }
  }
  ExpressionFrame frame;
  e = open_datagram(key_, datagram, header, &frame);
  if (e == DatagramError::kAuthFailed) {
    count_reject(e);
    return e;
  }
  if (!slot) {  // the first authenticated stream: lock onto it
    slot = &slots_[0];
    slot->id = header.stream_id;
    slot->used = true;
    slot->window.reset();
    num_slots_ = 1;
  }
  // Authenticated: the sequence number is spent even if the values are bad.
  const bool was_empty = slot->window.empty();
  const uint64_t prev_highest = slot->window.highest();
  slot->window.mark(header.sequence);
  if (e == DatagramError::kInvalidValues) {
    count_reject(e);
    return e;
  }
  slot->last_accepted = arrival;
  const size_t slot_index = static_cast<size_t>(slot - slots_.data());

  bool apply = false;
  {
    std::lock_guard<std::mutex> lock(mu_);
    ++stats_.received;
    bool fresh = false;
    if (!has_active_ || active_slot_ != slot_index) {
      const bool active_silent =
          !has_active_ || arrival - slots_[active_slot_].last_accepted > options_.timeout;
      if (!active_silent) {
        ++stats_.standby;
        return DatagramError::kNone;
      }
      has_active_ = true;
      active_slot_ = slot_index;
      ++stats_.stream_switches;
      fresh = true;
    }
    if (fresh) {
      apply = true;
    } else if (was_empty || header.sequence > prev_highest) {
      const uint64_t gap = was_empty ? 0 : header.sequence - prev_highest - 1;
      if (gap <= kMaxCountedGap)
        stats_.lost += gap;
      else
        ++stats_.sequence_jumps;
      if (has_frame_ && frame.capture_time_us < last_applied_capture_us_)
        ++stats_.late;
      else
        apply = true;
    } else {
      ++stats_.reordered;  // it was counted lost when the gap opened
      if (stats_.lost > 0) --stats_.lost;
    }
    if (!apply) return DatagramError::kNone;

    if (!has_frame_) {
      fade_in_start_ = arrival;
      fade_in_from_ = 0;
    } else if (arrival - last_arrival_ > options_.timeout) {
      fade_in_from_ = weight_at(arrival);  // fade back in from wherever the fade-out got to
      fade_in_start_ = arrival;
    }
    has_frame_ = true;
    last_arrival_ = arrival;
    frame_ = frame;
    relative_ = frame.relative_expression();
    frame_stream_ = header.stream_id;
    frame_seq_ = header.sequence;
    highest_applied_seq_ = header.sequence;
    last_applied_capture_us_ = frame.capture_time_us;

    ++stats_.applied;
    stats_.has_active_stream = true;
    stats_.active_stream = header.stream_id;
    stats_.last_sequence = header.sequence;
    if (stats_.applied == 1 || arrival - rate_window_start_ > std::chrono::seconds(5)) {
      rate_window_start_ = arrival;
      rate_window_applied_ = stats_.applied;
    } else if (arrival - rate_window_start_ >= std::chrono::seconds(1)) {
      stats_.rate_hz = double(stats_.applied - rate_window_applied_) / seconds(arrival - rate_window_start_);
      rate_window_start_ = arrival;
      rate_window_applied_ = stats_.applied;
    }
    const double latency = (double(receive_time_us) - double(frame.capture_time_us)) / 1000.0;
    if (!latency_initialised_) {
      stats_.latency_ms = stats_.latency_min_ms = latency;
      stats_.latency_jitter_ms = 0;
      latency_initialised_ = true;
    } else {
      stats_.latency_jitter_ms += kLatencySmoothing * (std::fabs(latency - stats_.latency_ms) - stats_.latency_jitter_ms);
      stats_.latency_ms += kLatencySmoothing * (latency - stats_.latency_ms);
      stats_.latency_min_ms = std::min(stats_.latency_min_ms, latency);
    }
  }
  if (options_.on_applied) options_.on_applied(AppliedDatagram{header, frame, receive_time_us});
  return DatagramError::kNone;
}

// The cross-fade is a closed-form function of time, so it does not depend on how often the
// consumer samples: while live, the weight rises linearly from fade_in_from_ (at
// fade_in_start_) to 1 over `ramp`; once the stream has been silent for `timeout`, it falls
// linearly from the value it had reached to 0 over `ramp`.
float ExpressionStreamState::weight_at(SteadyClock::time_point t) const {
  if (!has_frame_) return 0.f;
  const double ramp = seconds(options_.ramp);
  const SteadyClock::time_point dead_at = last_arrival_ + options_.timeout;
  auto rising = [&](SteadyClock::time_point at) {
    if (ramp <= 0) return 1.0;
    return std::clamp(fade_in_from_ + seconds(at - fade_in_start_) / ramp, 0.0, 1.0);
  };
  if (t <= dead_at) return static_cast<float>(rising(t));
  if (ramp <= 0) return 0.f;
  return static_cast<float>(std::clamp(rising(dead_at) - seconds(t - dead_at) / ramp, 0.0, 1.0));
}

RemoteExpression ExpressionStreamState::sample(SteadyClock::time_point now) const {
  RemoteExpression r;
  std::lock_guard<std::mutex> lock(mu_);
  if (!has_frame_) return r;
  r.has_frame = true;
  r.weight = weight_at(now);
  r.live = now - last_arrival_ <= options_.timeout;
  r.expression = relative_;
  r.has_rotation = frame_.has_rotation;
  r.rotation = frame_.rotation;
  r.has_translation = frame_.has_translation;
  r.translation = frame_.translation;
  r.stream_id = frame_stream_;
  r.sequence = frame_seq_;
  r.capture_time_us = frame_.capture_time_us;
  r.age_ms = std::max(0.0, seconds(now - last_arrival_) * 1000.0);
  return r;
}

ReceiverStatistics ExpressionStreamState::statistics(SteadyClock::time_point now) const {
  std::lock_guard<std::mutex> lock(mu_);
  ReceiverStatistics s = stats_;
  // Until a full window has passed, measure over the part that has.
  const auto partial = last_arrival_ - rate_window_start_;
  if (has_frame_ && stats_.rate_hz == 0 && partial >= std::chrono::milliseconds(200))
    s.rate_hz = double(stats_.applied - rate_window_applied_) / seconds(partial);
  if (!has_frame_ || now - last_arrival_ > options_.timeout) s.rate_hz = 0;
  return s;
}

void ExpressionStreamState::reset() {
  std::lock_guard<std::mutex> lock(mu_);
  if (lock_on_first_) {
    for (auto& slot : slots_) slot = StreamSlot{};
    num_slots_ = 0;
  } else {
    for (size_t i = 0; i < num_slots_; ++i) {
      slots_[i].window.reset();
      slots_[i].last_accepted = {};
    }
  }
  has_active_ = false;
  has_frame_ = false;
  stats_.has_active_stream = false;
  highest_applied_seq_ = 0;
  last_applied_capture_us_ = 0;
  latency_initialised_ = false;
}

}  // namespace face_reenact::stream
