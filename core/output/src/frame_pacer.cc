#include "face_reenact/output/frame_pacer.h"

#include <cmath>
#include <numeric>

namespace face_reenact::output {

std::optional<FrameRate> FrameRate::from_double(double fps) {
  if (!std::isfinite(fps) || fps <= 0 || fps > kMaxFps) return std::nullopt;
  // Rates are given to 1/100 fps (29.97, 59.94); finer digits carry no meaning for a camera.
  int64_t hundredths = std::llround(fps * 100);
  if (hundredths <= 0) return std::nullopt;
  int64_t g = std::gcd(hundredths, int64_t{100});
  return FrameRate{hundredths / g, 100 / g};
}

bool FrameRate::IsValid(std::string* error) const {
  if (num <= 0 || den <= 0 || den > 1000000 || fps() > kMaxFps) {
    if (error)
      *error = "frame rate " + std::to_string(num) + "/" + std::to_string(den) + " must be in (0, " +
               std::to_string(int(kMaxFps)) + "] fps";
    return false;
  }
  return true;
}

FramePacer::FramePacer(FrameRate rate) : rate_(rate) {
  if (!rate_.IsValid(nullptr)) rate_ = FrameRate{30, 1};
}

FramePacer::Nanos FramePacer::deadline(int64_t tick) const {
  // tick * den / num seconds, split into whole multiples of num (exact integers) and a
  // remainder below one second's worth of ticks (long double, < 1 ns error), so no product
  // overflows for any stream length and nothing accumulates from tick to tick.
  constexpr int64_t kNs = 1'000'000'000;
  int64_t whole = tick / rate_.num;
  int64_t rest = tick % rate_.num;
  long double rest_ns = static_cast<long double>(rest) * rate_.den * kNs / rate_.num;
  return Nanos(whole * rate_.den * kNs + static_cast<int64_t>(std::floor(rest_ns)));
}

int64_t FramePacer::latest_tick_at(Nanos now) const {
  if (now.count() < 0) return -1;
  long double estimate = static_cast<long double>(now.count()) * rate_.num / (1e9L * rate_.den);
  int64_t k = static_cast<int64_t>(std::floor(estimate));
  while (deadline(k + 1) <= now) ++k;
  while (k > 0 && deadline(k) > now) --k;
  return k;
}

void FramePacer::frame_arrived() {
  if (fresh_pending_) ++stats_.dropped;
  fresh_pending_ = true;
}

std::optional<FramePacer::Tick> FramePacer::on_wake(Nanos now) {
  if (now < next_deadline()) return std::nullopt;
  int64_t latest = latest_tick_at(now);
  Tick tick{Action::kRepeatLast, latest, latest - next_tick_};
  stats_.missed_deadlines += tick.skipped;
  next_tick_ = latest + 1;
  if (fresh_pending_) {
    tick.action = Action::kSendFresh;
    fresh_pending_ = false;
    ++stats_.fresh;
  } else {
    ++stats_.repeated;
  }
  return tick;
}

}  // namespace face_reenact::output
