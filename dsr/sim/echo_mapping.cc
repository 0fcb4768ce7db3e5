// The echo-like intensity mapping of a simulation source; the model in echo_mapping.h.
#include "dsr/sim/echo_mapping.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include <glog/logging.h>

#include "dsr/image/pyramid.h"
#include "dsr/util/parallel.h"

namespace dsr {
namespace {

// The percentile of the gradient magnitude that maps to a full edge term: the strongest
// 1 % of the anatomy's gradients saturate, so one very strong edge (bone, the skin) does
// not dim every other interface.
constexpr double kEdgePercentile = 0.99;

// |grad G| at every voxel of `smoothed` (echo_mapping.h: central differences, one-sided on
// the border, through the physical-to-index matrix), each voxel written by one thread.
std::vector<float> GradientMagnitude(const Image& smoothed, int num_threads) {
  const ImageGeometry& g = smoothed.geometry;
  const Eigen::Vector3i& n = g.size;
  const Eigen::Matrix3d physical_from_index_gradient = g.PhysicalToIndexMatrix().transpose();
  const int64_t stride[3] = {1, n[0], int64_t{n[0]} * n[1]};
  std::vector<float> magnitude(g.NumVoxels());
  ParallelFor(0, n[2], num_threads, [&](int64_t k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        const int ijk[3] = {i, j, static_cast<int>(k)};
        const int64_t l = g.LinearIndex(i, j, static_cast<int>(k));
        Eigen::Vector3d d_index = Eigen::Vector3d::Zero();
        for (int a = 0; a < 3; ++a) {
          const int lo = std::max(ijk[a] - 1, 0), hi = std::min(ijk[a] + 1, n[a] - 1);
          if (hi == lo) continue;  // a single-voxel axis
          d_index[a] = (double{smoothed.voxels[l + (hi - ijk[a]) * stride[a]]} -
                        double{smoothed.voxels[l + (lo - ijk[a]) * stride[a]]}) /
                       (hi - lo);
        }
        magnitude[l] = static_cast<float>((physical_from_index_gradient * d_index).norm());
      }
    }
  });
  return magnitude;
}

}  // namespace

Image EchoIntensityMap(const Image& source,
                       const SimulationOptions& options,
                       int num_threads,
                       double* gradient_p99) {
  std::string error;
  CHECK(options.Validate(&error)) << error;
  CHECK(!source.empty());
  const ImageGeometry& g = source.geometry;
  CHECK_EQ(static_cast<int64_t>(source.voxels.size()), g.NumVoxels());

  // G_sigma * S with sigma in mm, i.e. sigma_mm / spacing voxels along each index axis.
  Image smoothed_storage;
  const Image* smoothed = &source;
  if (options.echo_edge_sigma_mm > 0.0) {
    smoothed_storage = SmoothInsideMask(source,
                                        Mask(g, 1),
                                        options.echo_edge_sigma_mm * g.spacing_mm.cwiseInverse(),
                                        num_threads);
    smoothed = &smoothed_storage;
  }
  const std::vector<float> magnitude = GradientMagnitude(*smoothed, num_threads);
  smoothed_storage = Image();

  // g99 over the anatomy (S > 0), gathered in voxel order; the order statistic does not
  // depend on how nth_element gets there.
  std::vector<float> anatomy;
  for (size_t l = 0; l < source.voxels.size(); ++l) {
    if (source.voxels[l] > 0.0f) anatomy.push_back(magnitude[l]);
  }
  double p99 = 0.0;
  if (!anatomy.empty()) {
    const size_t rank =
        static_cast<size_t>(std::floor(kEdgePercentile * static_cast<double>(anatomy.size() - 1)));
    std::nth_element(anatomy.begin(), anatomy.begin() + rank, anatomy.end());
    p99 = anatomy[rank];
  }
  anatomy = std::vector<float>();
  if (gradient_p99 != nullptr) *gradient_p99 = p99;

  const double reject = options.echo_reject, w = options.echo_edge_weight;
  Image mapped(g);
  ParallelFor(0, g.size[2], num_threads, [&](int64_t k) {
    const int64_t begin = k * g.size[0] * int64_t{g.size[1]};
    const int64_t end = begin + g.size[0] * int64_t{g.size[1]};
    for (int64_t l = begin; l < end; ++l) {
      const double tissue = std::max(0.0, double{source.voxels[l]} - reject) / (255.0 - reject);
      const double m = magnitude[l];
      // min(1, m / p99), with its limit when p99 = 0 (echo_mapping.h).
      const double edge = p99 > 0.0 ? std::min(1.0, m / p99) : (m > 0.0 ? 1.0 : 0.0);
      mapped.voxels[l] = static_cast<float>(
          255.0 * std::clamp((1.0 - w) * tissue + w * edge, 0.0, 1.0));
    }
  });
  return mapped;
}

}  // namespace dsr
