#pragma once
// One exception type for every user-facing failure: its message is meant to be printed as is
// ("model file 'x': truncated section table"), so callers add context rather than codes.
#include <cstring>
#include <stdexcept>
#include <string>

namespace face_reenact {

class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// For the `IsValid(std::string* why)` checks: stores the reason (when asked) and returns false.
inline bool fail_why(std::string* why, const std::string& message) {
  if (why) *why = message;
  return false;
}

// errno's text for a message ("permission denied").
inline std::string errno_text(int err) { return std::strerror(err); }

}  // namespace face_reenact
