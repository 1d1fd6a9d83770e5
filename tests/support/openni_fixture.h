#pragma once
// The shared OpenNI recording (../shared/data/rgbd/openni1_room_test.oni: a room, 640x480 RGB-D,
// 12 frames) for the tests that read .oni files through OpenNI2. Declares `var` with its path,
// or skips the test saying why: the shared data is absent (a user's clone), or the build runs
// under AddressSanitizer (OpenNI2 unloads its drivers at exit, and LeakSanitizer then reports
// their allocations with frames no suppression can name; the release build runs these tests).
#include <cstdlib>
#include <filesystem>
#include <string>

#include "face_reenact/common/sanitizers.h"

#ifdef FR_ADDRESS_SANITIZER
#define FR_SKIP_OPENNI_UNDER_ASAN() \
  GTEST_SKIP() << "OpenNI2's unloaded drivers defeat LeakSanitizer's attribution (run in the release build)"
#else
#define FR_SKIP_OPENNI_UNDER_ASAN() (void)0
#endif

#define FR_REQUIRE_ONI_FIXTURE(var)                                                            \
  std::string var;                                                                             \
  {                                                                                            \
    const char* shared_ = std::getenv("FR_SHARED_DATA");                                       \
    var = std::string(shared_ ? shared_ : "") + "/rgbd/openni1_room_test.oni";                 \
    if (!shared_ || !std::filesystem::exists(var)) GTEST_SKIP() << "no " << var << " (FR_SHARED_DATA)"; \
    FR_SKIP_OPENNI_UNDER_ASAN();                                                               \
  }
