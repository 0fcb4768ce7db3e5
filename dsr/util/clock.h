// Wall time for reports and logs.
#ifndef DSR_UTIL_CLOCK_H_
#define DSR_UTIL_CLOCK_H_

#include <chrono>

namespace dsr {

// Seconds of steady-clock time since `start`.
inline double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace dsr

#endif  // DSR_UTIL_CLOCK_H_
