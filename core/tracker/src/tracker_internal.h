#pragma once
// Small helpers shared by the tracker's sources (not part of the public API).
#include <string>

#include "face_reenact/common/timing.h"

namespace face_reenact::tracker::internal {

using Clock = SteadyClock;

// For IsValid(std::string* why): stores the reason (when asked) and returns false.
inline bool fail(std::string* why, const std::string& message) {
  if (why) *why = message;
  return false;
}

}  // namespace face_reenact::tracker::internal
