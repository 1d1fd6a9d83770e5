// main() of every GoogleTest binary: fills in the paths tests rely on (unless the environment
// already names them), then runs the tests. Programs the tests start inherit the same values.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>

#if defined(__has_feature)
#if __has_feature(address_sanitizer)
#define FR_ADDRESS_SANITIZER 1
#endif
#endif

namespace {
void default_env(const char* key, const char* value) { setenv(key, value, /*overwrite=*/0); }
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
  return RUN_ALL_TESTS();
}
