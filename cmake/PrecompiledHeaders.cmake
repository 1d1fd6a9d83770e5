# Precompiled headers: the standard library, Eigen, nlohmann-json and OpenCV's core parse once per
# build instead of once per source file (a third of a typical file's compile time here; the build
# is most of `./setup.sh test`'s time on two cores). Each PCH lives on a small host target, and the
# targets that share its compile flags reuse it: clang refuses a PCH built for another PIE/PIC
# setting or other sanitizers, so libraries (PIC) and executables (PIE) have one host each, and a
# library that a fuzzer instruments (fr_fuzzer) drops it. FR_PRECOMPILED_HEADERS=OFF builds
# without, which is how a missing #include is caught.
option(FR_PRECOMPILED_HEADERS "Precompile the common third-party headers" ON)

set(FR_PCH_STANDARD <algorithm> <array> <atomic> <chrono> <cmath> <cstdint> <cstring> <filesystem>
    <fstream> <functional> <map> <memory> <mutex> <optional> <span> <sstream> <string>
    <string_view> <unordered_map> <variant> <vector>)
set(FR_PCH_THIRD_PARTY <Eigen/Core> <Eigen/Geometry> <nlohmann/json.hpp> <opencv2/core.hpp>)

# fr_pch_host(name LIBRARY|EXECUTABLE [TEST_CODE] HEADERS... LINK targets...): a target whose only
# job is to own a precompiled header that others reuse (fr_reuse_precompiled_headers); TEST_CODE
# for the test programs' (fr_target_defaults).
function(fr_pch_host name kind)
  cmake_parse_arguments(ARG "TEST_CODE" "" "HEADERS;LINK" ${ARGN})
  if(NOT FR_PRECOMPILED_HEADERS)
    return()
  endif()
  set(source ${CMAKE_CURRENT_BINARY_DIR}/${name}.cc)
  if(kind STREQUAL "EXECUTABLE")
    file(CONFIGURE OUTPUT ${source} CONTENT "int main() { return 0; }\n")
    add_executable(${name} ${source})
  else()
    file(CONFIGURE OUTPUT ${source} CONTENT "// owns the precompiled header of ${name}\n")
    add_library(${name} STATIC ${source})
  endif()
  target_link_libraries(${name} PRIVATE ${ARG_LINK})
  if(ARG_TEST_CODE)
    fr_target_defaults(${name} TEST_CODE)
  else()
    fr_target_defaults(${name})
  endif()
  target_precompile_headers(${name} PRIVATE ${ARG_HEADERS})
endfunction()

# fr_reuse_precompiled_headers(target host): target compiles with host's precompiled header.
function(fr_reuse_precompiled_headers target host)
  if(FR_PRECOMPILED_HEADERS AND TARGET ${host})
    target_precompile_headers(${target} REUSE_FROM ${host})
  endif()
endfunction()
