#pragma once
// One exception type for every user-facing failure: its message is meant to be printed as is
// ("model file 'x': truncated section table"), so callers add context rather than codes.
#include <stdexcept>
#include <string>

namespace face_reenact {

class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace face_reenact
