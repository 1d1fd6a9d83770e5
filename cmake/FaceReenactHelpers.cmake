# Shared build settings for every face-reenact target.

# Applies the project's warning set (and sanitizers when FR_SANITIZE is on).
# TEST_CODE: a test program or test helper. In the sanitizer build its own code is compiled
# without the sanitizers' instrumentation and linked with their runtimes, so the libraries, the CLI
# and the plugin it exercises are checked as they run in it; FR_LINKED_WITH_SANITIZERS tells
# sanitizers.h that the process is sanitized all the same. Instrumenting the test programs
# themselves doubled their compile time (ASan at -O1), a third of the sanitizer build's.
# The other executables (the CLI) compile at -O0 there: glue around the core libraries, which
# do the work and keep the build's -O1, and 2.4x faster to compile (docs/build-and-test.md).
function(fr_target_defaults target)
  cmake_parse_arguments(ARG "TEST_CODE" "" "" ${ARGN})
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic
                         -Wnon-virtual-dtor -Wno-missing-field-initializers)
  if(FR_WERROR)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
  if(FR_SANITIZE)
    target_link_options(${target} PRIVATE -fsanitize=address,undefined)
    if(ARG_TEST_CODE)
      target_compile_definitions(${target} PRIVATE FR_LINKED_WITH_SANITIZERS=1)
    else()
      target_compile_options(${target} PRIVATE -fsanitize=address,undefined -fno-omit-frame-pointer
                             -fno-sanitize-recover=undefined)
      get_target_property(type ${target} TYPE)
      if(type STREQUAL "EXECUTABLE")
        target_compile_options(${target} PRIVATE -O0)
      endif()
    endif()
  endif()
endfunction()

# fr_library(name SOURCES ... DEPS ...): a core module as a static library whose public
# headers live in <module>/include.
function(fr_library name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS;PRIVATE_DEPS" ${ARGN})
  add_library(${name} STATIC ${ARG_SOURCES})
  target_include_directories(${name} PUBLIC ${CMAKE_CURRENT_SOURCE_DIR}/include)
  target_link_libraries(${name} PUBLIC ${ARG_DEPS} PRIVATE ${ARG_PRIVATE_DEPS})
  fr_target_defaults(${name})
  fr_reuse_precompiled_headers(${name} fr_pch_library)
endfunction()

# fr_test(name SOURCES ... DEPS ... [LABELS ...] [TIMEOUT s]): one GoogleTest executable,
# registered test-by-test with CTest. Its main (tests/test_main.cc) puts FR_SOURCE_DIR,
# FR_SHARED_DATA, FR_MODEL (+ FACE_REENACT_MODEL) and FR_CLI into the environment unless the
# caller already set them, so tests and the programs they start see the same paths.
# In the sanitizer build the executable is one CTest test that runs all its cases in one process
# (a sanitized process takes about a second to start, and most cases are far shorter), leaving
# out those of tests/release_only.txt; TIMEOUT then bounds the whole run, at least
# FR_SANITIZER_TEST_TIMEOUT. RELEASE_ONLY: every case of the program is in release_only.txt, so
# the sanitizer build does not build it at all (its compile cost nothing would run); the release
# build labels its cases `release-only`, and tests/check_release_only.py fails when one of them
# is not in the list.
set(FR_SANITIZER_TEST_TIMEOUT 1200 CACHE STRING "Seconds a whole test executable may run in the sanitizer build")
function(fr_test name)
  cmake_parse_arguments(ARG "RELEASE_ONLY" "TIMEOUT" "SOURCES;DEPS;LABELS" ${ARGN})
  if(ARG_RELEASE_ONLY)
    if(FR_SANITIZE)
      return()
    endif()
    list(APPEND ARG_LABELS release-only)
  endif()
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_DEPS} fr_test_main GTest::gtest)
  fr_target_defaults(${name} TEST_CODE)
  fr_reuse_precompiled_headers(${name} fr_pch_test)
  # Recordings the tests make once and share (tests/support/cached_recording.h).
  target_compile_definitions(${name} PRIVATE FR_TEST_CACHE_DIR="${CMAKE_BINARY_DIR}/test-cache")
  if(NOT ARG_TIMEOUT)
    set(ARG_TIMEOUT 600)
  endif()
  if(FR_SANITIZE AND ARG_TIMEOUT LESS FR_SANITIZER_TEST_TIMEOUT)
    set(ARG_TIMEOUT ${FR_SANITIZER_TEST_TIMEOUT})
  endif()
  set(props TIMEOUT ${ARG_TIMEOUT})
  if(ARG_LABELS)
    list(APPEND props LABELS "${ARG_LABELS}")
  endif()
  if(FR_SANITIZE)
    add_test(NAME ${name} COMMAND ${name})
    set_tests_properties(${name} PROPERTIES ${props})
  else()
    gtest_discover_tests(${name} DISCOVERY_TIMEOUT 60 PROPERTIES ${props})
  endif()
endfunction()

# fr_fuzzer(name SOURCES ... DEPS ... [SEEDS dir-or-files...]): a libFuzzer target (only with
# FR_FUZZ and clang), registered with CTest as a bounded run of FR_FUZZ_SECONDS that starts
# from the seed inputs. The project libraries it names in DEPS (the parsers under test) get the
# fuzzer's coverage instrumentation; nothing else does. Instrumenting every target made the
# sanitizer build's tracker tests 3x slower (trace-cmp on every comparison in Eigen's loops:
# 59 s against 19 s for FaceTracker.CalibratesThenTracksASequence) for coverage no fuzzer uses.
set(FR_FUZZ_SECONDS 30 CACHE STRING "Seconds each fuzz target runs under CTest")
function(fr_fuzzer name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS;SEEDS" ${ARGN})
  if(NOT FR_FUZZ)
    return()
  endif()
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_DEPS})
  foreach(dep IN LISTS ARG_DEPS)
    if(dep MATCHES "^fr_" AND TARGET ${dep})
      target_compile_options(${dep} PRIVATE -fsanitize=fuzzer-no-link)
      # clang refuses a precompiled header built without the fuzzer's instrumentation.
      set_target_properties(${dep} PROPERTIES DISABLE_PRECOMPILE_HEADERS ON)
    endif()
  endforeach()
  target_compile_options(${name} PRIVATE -fsanitize=fuzzer,address,undefined)
  target_link_options(${name} PRIVATE -fsanitize=fuzzer,address,undefined)
  set(corpus ${CMAKE_CURRENT_BINARY_DIR}/${name}_corpus)
  add_test(NAME ${name}
           COMMAND ${CMAKE_COMMAND} -E env ASAN_OPTIONS=detect_leaks=1
                   LSAN_OPTIONS=suppressions=${PROJECT_SOURCE_DIR}/tests/lsan.supp
                   $<TARGET_FILE:${name}> -max_total_time=${FR_FUZZ_SECONDS} -rss_limit_mb=2048
                   -print_final_stats=1 ${corpus} ${ARG_SEEDS})
  set_tests_properties(${name} PROPERTIES LABELS fuzz TIMEOUT 600
                       FIXTURES_REQUIRED ${name}_corpus)
  add_test(NAME ${name}_corpus_dir COMMAND ${CMAKE_COMMAND} -E make_directory ${corpus})
  set_tests_properties(${name}_corpus_dir PROPERTIES FIXTURES_SETUP ${name}_corpus)
endfunction()
