#include "face_reenact/live/frame_overlap.h"

#include <algorithm>
#include <cmath>

#include "face_reenact/common/error.h"

namespace face_reenact::live {

bool FrameOverlapPolicy::Options::IsValid(std::string* why) const {
  auto fail = [&](const char* text) {
    if (why) *why = text;
    return false;
  };
  if (window.count() <= 0) return fail("window must be positive");
  if (!(behind_share > 0.0 && behind_share < 1.0)) return fail("behind_share must be in (0, 1)");
  if (!(min_gain >= -1.0 && min_gain <= 1.0)) return fail("min_gain must be in [-1, 1]");
  if (!(max_latency_ms >= 0.0 && std::isfinite(max_latency_ms))) return fail("max_latency_ms must be 0 or positive");
  if (first_hold < window) return fail("first_hold must be at least one window");
  if (max_hold < first_hold) return fail("max_hold must be at least first_hold");
  return true;
}

FrameOverlapPolicy::FrameOverlapPolicy() : FrameOverlapPolicy(Options()) {}

FrameOverlapPolicy::FrameOverlapPolicy(const Options& options)
    : options_(options), two_hold_(options.first_hold), one_hold_(options.first_hold) {
  std::string why;
  if (!options_.IsValid(&why)) throw Error("frame overlap policy: " + why);
}

bool FrameOverlapPolicy::Update(Clock::time_point now, int64_t input_sequence, bool tracked, double latency_ms) {
  if (!tracked) {
    window_open_ = false;
    return overlapped_;
  }
  if (!window_open_ || input_sequence < window_first_sequence_) {  // (an input reopened counts afresh)
    window_open_ = true;
    window_start_ = now;
    window_first_sequence_ = input_sequence;
    window_taken_ = 0;
    window_latency_ms_ = 0;
    window_latencies_ = 0;
    return overlapped_;
  }
  ++window_taken_;
  if (std::isfinite(latency_ms) && latency_ms >= 0) {
    window_latency_ms_ += latency_ms;
    ++window_latencies_;
  }
  if (now - window_start_ < options_.window) return overlapped_;
  const double seconds = std::chrono::duration<double>(now - window_start_).count();
  const int64_t delivered = input_sequence - window_first_sequence_;
  last_dropped_share_ = delivered > 0 ? std::max(0.0, 1.0 - static_cast<double>(window_taken_) / delivered) : 0.0;
  const double rate = window_taken_ / seconds;
  const bool behind = last_dropped_share_ > options_.behind_share;
  last_latency_ms_ = window_latencies_ > 0 ? window_latency_ms_ / window_latencies_ : 0.0;
  const bool too_late = options_.max_latency_ms > 0 && last_latency_ms_ > options_.max_latency_ms;
  window_start_ = now;
  window_first_sequence_ = input_sequence;
  window_taken_ = 0;
  window_latency_ms_ = 0;
  window_latencies_ = 0;
  auto change = [&](bool overlapped) {
    overlapped_ = overlapped;
    ++switches_;
  };
  if (!overlapped_) {
    if (behind && now >= two_not_before_) {
      // A try of one thread that fell behind at once: the machine is still busy, try later.
      two_hold_ = trying_one_ ? std::min(options_.max_hold, 2 * two_hold_) : options_.first_hold;
      change(true);
      overlapped_since_ = now;
      one_rate_ = rate;
      checking_two_ = true;
    }
    trying_one_ = false;
  } else if (too_late || (checking_two_ && behind && rate < one_rate_ * (1.0 + options_.min_gain))) {
    // Not worth their latency (the cores are taken by something else): one thread, for a while.
    checking_two_ = false;
    change(false);
    two_not_before_ = now + one_hold_;
    one_hold_ = std::min(options_.max_hold, 2 * one_hold_);
  } else if (checking_two_) {
    checking_two_ = false;
    one_hold_ = options_.first_hold;
  } else if (now - overlapped_since_ >= two_hold_) {
    change(false);
    trying_one_ = true;
  }
  return overlapped_;
}

}  // namespace face_reenact::live
