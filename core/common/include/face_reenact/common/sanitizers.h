#pragma once
// Whether this translation unit is built under a sanitizer, in one place (clang's __has_feature,
// GCC's __SANITIZE_*__ macros):
//   FR_ADDRESS_SANITIZER    AddressSanitizer (and so LeakSanitizer): the test runner's
//                           release-only cases, the Vulkan and OpenNI drivers kept loaded or
//                           skipped for leak checks;
//   FR_SANITIZER_ALLOCATOR  a sanitizer's own allocator serves malloc (ASan, MSan, TSan), so
//                           glibc's allocator statistics do not describe this process.
// Code compiled without the instrumentation but linked into an ASan + UBSan process (the
// sanitizer build's test programs, cmake/FaceReenactHelpers.cmake) is told so by
// FR_LINKED_WITH_SANITIZERS: the process is sanitized all the same.
#if defined(__has_feature)
#if __has_feature(address_sanitizer)
#define FR_ADDRESS_SANITIZER 1
#endif
#if __has_feature(address_sanitizer) || __has_feature(memory_sanitizer) || __has_feature(thread_sanitizer)
#define FR_SANITIZER_ALLOCATOR 1
#endif
#endif
#if defined(__SANITIZE_ADDRESS__)
#ifndef FR_ADDRESS_SANITIZER
#define FR_ADDRESS_SANITIZER 1
#endif
#endif
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#ifndef FR_SANITIZER_ALLOCATOR
#define FR_SANITIZER_ALLOCATOR 1
#endif
#endif
#if defined(FR_LINKED_WITH_SANITIZERS)
#ifndef FR_ADDRESS_SANITIZER
#define FR_ADDRESS_SANITIZER 1
#endif
#ifndef FR_SANITIZER_ALLOCATOR
#define FR_SANITIZER_ALLOCATOR 1
#endif
#endif
