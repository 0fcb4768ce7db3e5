// Solve options for tests that compare fixed points: every Ceres tolerance at its floor and
// the pose stopping rule off, so a solve goes as far as Ceres goes (IRLS then stops when the
// weights stop changing). DSR_TEST_LOG set: progress lines on stderr.
#ifndef DSR_TESTS_SUPPORT_FIXED_POINT_OPTIONS_H_
#define DSR_TESTS_SUPPORT_FIXED_POINT_OPTIONS_H_

#include <cstdlib>

#include "dsr/solve/solve_options.h"

namespace dsr {
namespace testing_solve {

inline SolveOptions FixedPointOptions(int max_iterations) {
  SolveOptions o;
  o.progress = std::getenv("DSR_TEST_LOG") != nullptr;
  o.num_threads = 2;
  o.max_iterations = max_iterations;
  o.function_tolerance = 1e-20;
  o.gradient_tolerance = 1e-20;
  o.parameter_tolerance = 1e-15;
  o.step_tolerance = 0.0;
  o.max_rejected_steps = 0;
  return o;
}

}  // namespace testing_solve
}  // namespace dsr

#endif  // DSR_TESTS_SUPPORT_FIXED_POINT_OPTIONS_H_
