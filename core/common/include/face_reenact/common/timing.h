#pragma once
// Wall-clock stage timing, as every per-stage report (Table 1 style) measures it.
#include <chrono>

namespace face_reenact {

using SteadyClock = std::chrono::steady_clock;

// Milliseconds from `start` to now.
inline double ms_since(SteadyClock::time_point start) {
  return std::chrono::duration<double, std::milli>(SteadyClock::now() - start).count();
}

// Milliseconds from `start` to `end`.
inline double ms_since(SteadyClock::time_point start, SteadyClock::time_point end) {
  return std::chrono::duration<double, std::milli>(end - start).count();
}

}  // namespace face_reenact
