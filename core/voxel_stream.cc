#include "core/voxel_stream.h"

namespace dsr {

std::vector<PosedFrame> PoseFrames(const std::vector<Frame>& frames,
                                   const std::vector<Eigen::Isometry3d>& frame_from_world) {
  std::vector<PosedFrame> out(frames.size());
  for (size_t i = 0; i < frames.size(); ++i) {
    const Frame& f = frames[i];
    PosedFrame& pf = out[i];
    const Eigen::Vector3i& n = f.geometry().size;
    pf.data = f.interleaved();
    pf.valid = f.valid_cells();
    for (int d = 0; d < 3; ++d) pf.max_cell[d] = n[d] - 2.0;
    pf.stride_y = n[0];
    pf.stride_z = int64_t{n[0]} * n[1];
    const Eigen::Matrix3d rotation = frame_from_world[i].linear();
    const Eigen::Vector3d translation = frame_from_world[i].translation();
    const Eigen::Matrix3d a = f.index_from_physical() * rotation;
    const Eigen::Vector3d b = f.index_from_physical() * (translation - f.geometry().origin_mm);
    for (int row = 0; row < 3; ++row) {
      for (int col = 0; col < 3; ++col) {
        pf.a[3 * row + col] = a(row, col);
        pf.r[3 * row + col] = rotation(row, col);
        pf.g[3 * row + col] = f.gradient_to_physical()(row, col);
      }
      pf.b[row] = b[row];
      pf.t[row] = translation[row];
    }
  }
  return out;
}

}  // namespace dsr
