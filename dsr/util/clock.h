// Wall time for reports and logs.
#ifndef DSR_UTIL_CLOCK_H_
#define DSR_UTIL_CLOCK_H_

#include <chrono>

namespace dsr {

// Seconds of steady-clock time since `start`.
inline double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// Adds the wall time of its scope to *total (seconds), e.g. a stage's share of a run.
class ScopedSeconds {
 public:
  explicit ScopedSeconds(double* total)
      : total_(total), start_(std::chrono::steady_clock::now()) {}
  ~ScopedSeconds() { *total_ += SecondsSince(start_); }
  ScopedSeconds(const ScopedSeconds&) = delete;
  ScopedSeconds& operator=(const ScopedSeconds&) = delete;

 private:
  double* total_;
  std::chrono::steady_clock::time_point start_;
};

}  // namespace dsr

#endif  // DSR_UTIL_CLOCK_H_
