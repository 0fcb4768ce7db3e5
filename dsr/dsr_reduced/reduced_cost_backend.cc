// The CPU backend of DSR's reduced cost (docs/design.md section 11).
#include "dsr/dsr_reduced/reduced_cost_backend.h"

namespace dsr {

bool CpuReducedCostBackend::Evaluate(const ReducedCostInputs& inputs,
                                     const std::vector<Eigen::Isometry3d>& frame_from_world,
                                     const std::vector<Photometric>& photometric,
                                     int64_t begin,
                                     int64_t end,
                                     bool with_jacobian,
                                     NormalEquations* out) const {
  AccumulateDsrCostSystem(*inputs.frames, *inputs.candidates, frame_from_world, photometric,
                          inputs.weights, begin, end, with_jacobian, inputs.context, out);
  return true;
}

std::shared_ptr<const ReducedCostBackend> DefaultReducedCostBackend() {
  static const std::shared_ptr<const ReducedCostBackend> cpu =
      std::make_shared<CpuReducedCostBackend>();
  return cpu;
}

}  // namespace dsr
