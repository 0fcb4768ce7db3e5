# Tests live next to what they test: each folder's CMakeLists registers its *_test.cc files
# with dsr_add_test (or dsr_add_tool_test for tests that run the tools); tests/ holds the
# testing support headers (tests/support/) and the whole-project checks. Both functions do
# nothing when DSR_BUILD_TESTS is off.
#
# The tests' own translation units are compiled with less optimisation than the build's
# (-O1 in Release, -O0 under the sanitizers); the libraries and tools they test keep the
# build's flags. The test code is more than half of CI's compile time and little of the
# Release run time.
#
# Under the sanitizers the tests' own code is checked by AddressSanitizer but not by
# UndefinedBehaviorSanitizer, which checks the libraries and tools they run: its
# instrumentation of the test code was a fifth of each test's compile time.
set(DSR_TEST_OPTIMISATION "")
if(DSR_SANITIZE)
  set(DSR_TEST_OPTIMISATION -O0 -fno-sanitize=undefined)
elseif(CMAKE_BUILD_TYPE STREQUAL "Release")
  set(DSR_TEST_OPTIMISATION -O1)
endif()

# One precompiled header for every test (GoogleTest, Eigen, Ceres and the standard headers
# the tests use), made once per build by dsr_test_pch and reused by each test target; it
# takes about an eighth off the tests' compile time under the sanitizers (CI's longest
# step). Every test links what the header names, so a test whose flags make the
# precompiled file unusable still compiles, from the headers themselves (GCC's
# -Winvalid-pch says so). A test's own includes still say what it uses.
if(DSR_BUILD_TESTS)
  file(WRITE ${CMAKE_BINARY_DIR}/dsr_test_pch.cc "int main() { return 0; }\n")
  add_executable(dsr_test_pch ${CMAKE_BINARY_DIR}/dsr_test_pch.cc)
  target_compile_options(dsr_test_pch PRIVATE ${DSR_TEST_OPTIMISATION})
  target_link_libraries(dsr_test_pch PRIVATE GTest::gtest GTest::gmock Ceres::ceres Eigen3::Eigen)
  target_precompile_headers(dsr_test_pch PRIVATE
    <algorithm> <cmath> <cstdint> <filesystem> <fstream> <limits> <memory> <random> <string>
    <vector> <Eigen/Core> <Eigen/Geometry> <ceres/ceres.h> <gtest/gtest.h> <gmock/gmock.h>)
endif()

# dsr_add_test(name libraries...): the GoogleTest executable `name` from `name`.cc in the
# calling folder, linked with `libraries`, each TEST a ctest test.
function(dsr_add_test name)
  if(NOT DSR_BUILD_TESTS)
    return()
  endif()
  add_executable(${name} ${name}.cc)
  target_compile_options(${name} PRIVATE ${DSR_TEST_OPTIMISATION})
  target_link_libraries(${name} PRIVATE ${ARGN} GTest::gtest GTest::gmock GTest::gtest_main
                        Ceres::ceres Eigen3::Eigen)
  target_precompile_headers(${name} REUSE_FROM dsr_test_pch)
  gtest_discover_tests(${name} DISCOVERY_TIMEOUT 60)
endfunction()

# dsr_add_tool_test(name libraries...): dsr_add_test for a test that runs the tools, which
# it finds as DSR_SIMULATE_BIN, DSR_REGISTER_BIN, DSR_FUSE_BIN and DSR_COMPARE_BIN.
function(dsr_add_tool_test name)
  if(NOT DSR_BUILD_TESTS)
    return()
  endif()
  dsr_add_test(${name} ${ARGN})
  target_compile_definitions(${name} PRIVATE
    DSR_SIMULATE_BIN="$<TARGET_FILE:dsr_simulate>" DSR_REGISTER_BIN="$<TARGET_FILE:dsr_register>"
    DSR_FUSE_BIN="$<TARGET_FILE:dsr_fuse>" DSR_COMPARE_BIN="$<TARGET_FILE:dsr_compare>")
  add_dependencies(${name} dsr_simulate dsr_register dsr_fuse dsr_compare)
endfunction()
