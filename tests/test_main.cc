// main() of every GoogleTest binary: fills in the paths tests rely on (unless the environment
// already names them), then runs the tests. Programs the tests start inherit the same values.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>

#include "face_reenact/common/sanitizers.h"

namespace {
void default_env(const char* key, const char* value) { setenv(key, value, /*overwrite=*/0); }

#ifdef FR_ADDRESS_SANITIZER
// The sanitizer build leaves the cases of tests/release_only.txt to the release build (the file
// says why): their patterns join the negative part of the GoogleTest filter.
void leave_release_only_cases_out() {
  const char* all = std::getenv("FR_RUN_RELEASE_ONLY");
  if (all && std::string(all) == "1") return;
  const char* path = FR_TEST_SOURCE_DIR "/tests/release_only.txt";
  std::ifstream in(path);
  if (!in) {
    std::fprintf(stderr, "warning: %s is missing; running every case under the sanitizers\n", path);
    return;
  }
  std::string patterns;
  for (std::string line; std::getline(in, line);) {
    line = line.substr(0, line.find('#'));
    const size_t first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos) continue;
    line = line.substr(first, line.find_last_not_of(" \t\r") - first + 1);
    patterns += (patterns.empty() ? "" : ":") + line;
  }
  if (patterns.empty()) return;
  std::string filter = GTEST_FLAG_GET(filter);
  filter += (filter.find('-') == std::string::npos ? "-" : ":") + patterns;
  GTEST_FLAG_SET(filter, filter);
}
#endif
}  // namespace

int main(int argc, char** argv) {
#ifdef FR_ADDRESS_SANITIZER
  // LeakSanitizer reads LSAN_OPTIONS when the process starts, before main: when the
  // third-party suppressions are not in effect yet, start again with them.
  if (!std::getenv("LSAN_OPTIONS")) {
    setenv("LSAN_OPTIONS", "suppressions=" FR_TEST_SOURCE_DIR "/tests/lsan.supp", 1);
    execv("/proc/self/exe", argv);
  }
#endif
  default_env("FR_SOURCE_DIR", FR_TEST_SOURCE_DIR);
  default_env("FR_SHARED_DATA", FR_TEST_SHARED_DATA);
  default_env("FR_MODEL", FR_TEST_MODEL);
  default_env("FACE_REENACT_MODEL", std::getenv("FR_MODEL"));
  default_env("FR_CLI", FR_TEST_CLI);
  default_env("UBSAN_OPTIONS", "print_stacktrace=1:halt_on_error=1");
  default_env("LSAN_OPTIONS", "suppressions=" FR_TEST_SOURCE_DIR "/tests/lsan.supp");
  ::testing::InitGoogleTest(&argc, argv);
#ifdef FR_ADDRESS_SANITIZER
  leave_release_only_cases_out();
#endif
  return RUN_ALL_TESTS();
}
