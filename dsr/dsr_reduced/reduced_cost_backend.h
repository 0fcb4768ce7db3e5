// The cost-evaluation backend of DSR's fast path: the extension point for where the
// reduced cost is computed (docs/design.md section 11). Every evaluation a DSR solve's
// chunk costs make (ReducedChunkCost, dsr_reduced/reduced_cost.h) is one call to a
// backend: the normal equations (cost, gradient, Gauss-Newton matrix) of the reduced cost
// over a range of candidate voxels at given poses. The backend does the per-voxel work;
// compressing the result for Ceres, caching passes (stream/streamed_cost.h) and the solve
// itself stay the same whatever the backend.
//
// The default, CpuReducedCostBackend, streams the voxels on the CPU
// (AccumulateDsrCostSystem, stream/reduced_system.h) with the kernels of
// SolveOptions::kernels (portable, AVX2, AVX-512). Another backend (a GPU one) implements
// Evaluate with the same contract and is handed to a solve in DsrOptions::backend; its
// reference is the CPU backend (cost, gradient and Gauss-Newton matrix to rounding, for
// the plain cost, with photometric parameters and with observation weights).
#ifndef DSR_DSR_REDUCED_REDUCED_COST_BACKEND_H_
#define DSR_DSR_REDUCED_REDUCED_COST_BACKEND_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "dsr/image/frame.h"
#include "dsr/model/observation.h"
#include "dsr/model/photometric.h"
#include "dsr/stream/reduced_system.h"
#include "dsr/stream/voxel_stream.h"

namespace dsr {

// What one DSR problem's cost is made of: the same objects for every evaluation of a
// solve (a backend that keeps copies elsewhere, on a device, may reuse them while these
// pointers and the solve stay the same; IRLS starts a new solve for each set of weights).
struct ReducedCostInputs {
  const std::vector<Frame>* frames = nullptr;    // frame 0 first; not owned
  const CandidateSet* candidates = nullptr;      // not owned
  const ObservationWeights* weights = nullptr;   // not owned; null: the plain cost f, else f_w
  StreamContext context;                         // the solve's threads and CPU kernels
};

class ReducedCostBackend {
 public:
  virtual ~ReducedCostBackend() = default;
  // For logs and errors, e.g. "cpu".
  virtual std::string Name() const = 0;
  // The normal equations over all m frames (p m x p m, p = 6, or 8 with photometric
  // parameters) of the cost of `inputs` over candidate voxels [begin, end) at
  // `frame_from_world` and `photometric` (frame 0 first; empty: none), as
  // AccumulateDsrCostSystem defines them: cost, observations, voxels and the per-frame
  // costs always, H (full, symmetric) and g only with `with_jacobian`. One call per
  // evaluation of a chunk; calls come from one thread at a time. False: the backend could
  // not evaluate (the Ceres evaluation then fails, as with a non-finite cost).
  virtual bool Evaluate(const ReducedCostInputs& inputs,
                        const std::vector<Eigen::Isometry3d>& frame_from_world,
                        const std::vector<Photometric>& photometric,
                        int64_t begin,
                        int64_t end,
                        bool with_jacobian,
                        NormalEquations* out) const = 0;
};

// Today's backend: the streamed CPU evaluation (stream/voxel_stream.h).
class CpuReducedCostBackend final : public ReducedCostBackend {
 public:
  std::string Name() const override { return "cpu"; }
  bool Evaluate(const ReducedCostInputs& inputs,
                const std::vector<Eigen::Isometry3d>& frame_from_world,
                const std::vector<Photometric>& photometric,
                int64_t begin,
                int64_t end,
                bool with_jacobian,
                NormalEquations* out) const override;
};

// The CPU backend, shared (what a null DsrOptions::backend means).
std::shared_ptr<const ReducedCostBackend> DefaultReducedCostBackend();

}  // namespace dsr

#endif  // DSR_DSR_REDUCED_REDUCED_COST_BACKEND_H_
