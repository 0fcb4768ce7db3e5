#include "dsr/eval/eval.h"

#include <cmath>
#include <cstdio>
#include <sstream>

#include <glog/logging.h>

#include "dsr/model/observation.h"

namespace dsr {
namespace {

double Wrap(double a) {
  while (a > M_PI) a -= 2.0 * M_PI;
  while (a <= -M_PI) a += 2.0 * M_PI;
  return a;
}

}  // namespace

Eigen::Vector3d EulerZyxAngles(const Eigen::Matrix3d& r) {
  // R = Rz(g) Ry(b) Rx(a): r20 = -sin b, r21 = cos b sin a, r22 = cos b cos a,
  // r10 = sin g cos b, r00 = cos g cos b.
  const double beta = std::asin(std::max(-1.0, std::min(1.0, -r(2, 0))));
  const double alpha = std::atan2(r(2, 1), r(2, 2));
  const double gamma = std::atan2(r(1, 0), r(0, 0));
  return Eigen::Vector3d(alpha, beta, gamma);
}

PoseErrorSummary ComparePoses(const std::vector<Eigen::Isometry3d>& estimated,
                              const std::vector<Eigen::Isometry3d>& truth,
                              const std::vector<Mask>& masks,
                              int tre_stride) {
  CHECK_EQ(estimated.size(), truth.size());
  CHECK_EQ(estimated.size(), masks.size());
  CHECK_GE(tre_stride, 1);
  const std::vector<Eigen::Isometry3d> est = RelativeToFrame0(estimated);
  const std::vector<Eigen::Isometry3d> gt = RelativeToFrame0(truth);
  const int m = static_cast<int>(est.size());
  PoseErrorSummary out;
  out.frames.resize(m);
  for (int i = 1; i < m; ++i) {
    FramePoseError& e = out.frames[i];
    e.translation_mm = est[i].translation() - gt[i].translation();
    e.translation_voxels = e.translation_mm.cwiseQuotient(masks[i].geometry.spacing_mm);
    const Eigen::Vector3d a = EulerZyxAngles(est[i].linear());
    const Eigen::Vector3d b = EulerZyxAngles(gt[i].linear());
    for (int c = 0; c < 3; ++c) e.euler_rad[c] = Wrap(a[c] - b[c]);
    e.rotation_angle_rad =
        Eigen::AngleAxisd(est[i].linear() * gt[i].linear().transpose()).angle();
    const Eigen::Isometry3d est_inv = est[i].inverse(), gt_inv = gt[i].inverse();
    const ImageGeometry& g = masks[i].geometry;
    double sum = 0.0;
    Eigen::Vector3d displacement_sum = Eigen::Vector3d::Zero();
    int64_t count = 0;
    for (int k = 0; k < g.size[2]; k += tre_stride) {
      for (int j = 0; j < g.size[1]; j += tre_stride) {
        for (int ii = 0; ii < g.size[0]; ii += tre_stride) {
          if (masks[i].at(ii, j, k) == 0) continue;
          const Eigen::Vector3d x = g.IndexToPhysical(Eigen::Vector3d(ii, j, k));
          const Eigen::Vector3d displacement = est_inv * x - gt_inv * x;
          const double d = displacement.norm();
          displacement_sum += displacement;
          sum += d;
          e.tre_max_mm = std::max(e.tre_max_mm, d);
          ++count;
        }
      }
    }
    e.tre_mean_mm = count > 0 ? sum / count : 0.0;
    if (count > 0) e.centre_error_mm = displacement_sum / static_cast<double>(count);
  }
  if (m > 1) {
    for (int i = 1; i < m; ++i) {
      const FramePoseError& e = out.frames[i];
      out.mae_translation_voxels += e.translation_voxels.cwiseAbs().sum() / 3.0;
      out.mae_translation_mm += e.translation_mm.cwiseAbs().sum() / 3.0;
      out.mae_rotation_rad += e.euler_rad.cwiseAbs().sum() / 3.0;
      out.tre_mean_mm += e.tre_mean_mm;
      out.tre_max_mm = std::max(out.tre_max_mm, e.tre_max_mm);
      out.shared_offset_mm += e.centre_error_mm;
    }
    out.mae_translation_voxels /= m - 1;
    out.mae_translation_mm /= m - 1;
    out.mae_rotation_rad /= m - 1;
    out.tre_mean_mm /= m - 1;
    out.shared_offset_mm /= m - 1;
    for (int i = 1; i < m; ++i) {
      out.frame_spread_mm += (out.frames[i].centre_error_mm - out.shared_offset_mm).norm();
    }
    out.frame_spread_mm /= m - 1;
  }
  return out;
}

std::string PoseErrorSummary::Table() const {
  std::ostringstream s;
  char line[256];
  std::snprintf(line, sizeof(line), "%5s %28s %31s %10s %10s\n", "frame",
                "translation error (voxels)", "Euler angle error (rad)", "TRE mean", "TRE max");
  s << line;
  for (size_t i = 1; i < frames.size(); ++i) {
    const FramePoseError& e = frames[i];
    std::snprintf(line, sizeof(line),
                  "%5zu %9.4f %9.4f %9.4f   %10.2e %10.2e %10.2e %8.4fmm %8.4fmm\n", i,
                  e.translation_voxels[0], e.translation_voxels[1], e.translation_voxels[2],
                  e.euler_rad[0], e.euler_rad[1], e.euler_rad[2], e.tre_mean_mm, e.tre_max_mm);
    s << line;
  }
  std::snprintf(line, sizeof(line),
                "MAE: translation %.4f voxels (%.4f mm), rotation %.3e rad; TRE mean %.4f mm, "
                "max %.4f mm\n",
                mae_translation_voxels, mae_translation_mm, mae_rotation_rad, tre_mean_mm,
                tre_max_mm);
  s << line;
  std::snprintf(line, sizeof(line),
                "Centre errors: shared offset %.4f mm (%.4f %.4f %.4f in frame 0's axes), "
                "spread about it %.4f mm\n",
                shared_offset_mm.norm(), shared_offset_mm[0], shared_offset_mm[1],
                shared_offset_mm[2], frame_spread_mm);
  s << line;
  return s.str();
}

}  // namespace dsr
