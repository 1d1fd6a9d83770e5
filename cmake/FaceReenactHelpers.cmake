# Shared build settings for every face-reenact target.

# Applies the project's warning set (and sanitizers when FR_SANITIZE is on).
function(fr_target_defaults target)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic
                         -Wnon-virtual-dtor -Wno-missing-field-initializers)
  if(FR_WERROR)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
  if(FR_SANITIZE)
    target_compile_options(${target} PRIVATE -fsanitize=address,undefined -fno-omit-frame-pointer
                           -fno-sanitize-recover=undefined)
    target_link_options(${target} PRIVATE -fsanitize=address,undefined)
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
endfunction()

# fr_test(name SOURCES ... DEPS ... [LABELS ...] [TIMEOUT s]): one GoogleTest executable,
# registered test-by-test with CTest. Tests run from the build folder with
# FR_SOURCE_DIR / FR_SHARED_DATA / FR_MODEL in the environment.
function(fr_test name)
  cmake_parse_arguments(ARG "" "TIMEOUT" "SOURCES;DEPS;LABELS" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_DEPS} GTest::gtest GTest::gtest_main)
  fr_target_defaults(${name})
  if(NOT ARG_TIMEOUT)
    set(ARG_TIMEOUT 600)
  endif()
  gtest_discover_tests(${name}
    DISCOVERY_TIMEOUT 60
    PROPERTIES TIMEOUT ${ARG_TIMEOUT} LABELS "${ARG_LABELS}"
               ENVIRONMENT "FR_SOURCE_DIR=${PROJECT_SOURCE_DIR};FR_SHARED_DATA=${FR_SHARED_DATA};FR_MODEL=${FR_MODEL_FILE};FR_CLI=$<TARGET_FILE:face-reenact>;ASAN_OPTIONS=detect_leaks=1:abort_on_error=1;UBSAN_OPTIONS=print_stacktrace=1")
endfunction()

# fr_fuzzer(name SOURCES ... DEPS ...): a libFuzzer target (only with FR_FUZZ and clang).
function(fr_fuzzer name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS" ${ARGN})
  if(NOT FR_FUZZ)
    return()
  endif()
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_DEPS})
  target_compile_options(${name} PRIVATE -fsanitize=fuzzer,address,undefined)
  target_link_options(${name} PRIVATE -fsanitize=fuzzer,address,undefined)
endfunction()
