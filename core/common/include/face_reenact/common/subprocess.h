#pragma once
// Runs an external program (no shell, arguments passed as given) and reports how it ended.
#include <string>
#include <vector>

namespace face_reenact {

struct SubprocessResult {
  int exit_code = -1;   // -1 when it could not be started or was killed by a signal
  std::string output;   // stdout and stderr together, truncated to the last 64 KiB
};

SubprocessResult run_subprocess(const std::vector<std::string>& argv);

}  // namespace face_reenact
