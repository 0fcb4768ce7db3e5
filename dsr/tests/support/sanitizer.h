// Whether a test binary is built with AddressSanitizer (the second pass of
// scripts/test.sh, DSR_SANITIZE=ON), and the one way tests skip themselves there.
#ifndef DSR_TESTS_SUPPORT_SANITIZER_H_
#define DSR_TESTS_SUPPORT_SANITIZER_H_

#include <gtest/gtest.h>

namespace dsr {
namespace testing_support {

#if defined(__SANITIZE_ADDRESS__)
constexpr bool kUnderAddressSanitizer = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
constexpr bool kUnderAddressSanitizer = true;
#else
constexpr bool kUnderAddressSanitizer = false;
#endif
#else
constexpr bool kUnderAddressSanitizer = false;
#endif

// For tests that repeat one check over many seeds, trials or voxels: `full` in the Release
// pass, `reduced` under the sanitizers, where the same code runs 20-60x slower and what
// matters is that every path still runs once, not the statistics of many runs.
template <typename T>
constexpr T FullUnlessSanitized(T full, T reduced) {
  return kUnderAddressSanitizer ? reduced : full;
}

}  // namespace testing_support
}  // namespace dsr

// Skips the calling test in the sanitizer pass, naming `why`; the Release pass runs it.
#define DSR_SKIP_UNDER_SANITIZER(why) \
  if (::dsr::testing_support::kUnderAddressSanitizer) GTEST_SKIP() << (why)

// For tests that solve to machine precision or search many poses: 20-60x slower under the
// sanitizers (minutes each), while the code they run is exercised there by smaller tests.
#define DSR_SKIP_HEAVY_UNDER_SANITIZER()                                                  \
  DSR_SKIP_UNDER_SANITIZER("numerically heavy: run by the Release pass; its code runs " \
                           "under the sanitizers in smaller tests")

#endif  // DSR_TESTS_SUPPORT_SANITIZER_H_
