// Real-echo artefacts of the simulator (see echo_artifacts.h, docs/design.md 6.7).
#include "dsr/sim/echo_artifacts.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "dsr/util/parallel.h"

namespace dsr {
namespace {

// The apex's frame index (the centre of the k = 0 face).
Eigen::Vector3d Apex(const ImageGeometry& g) {
  return Eigen::Vector3d(0.5 * (g.size[0] - 1), 0.5 * (g.size[1] - 1), 0.0);
}

// Bilinear value of slice `k` of `v` (x-fastest on grid `n`) at (x, y), clamped to the slice.
double Bilinear(const std::vector<double>& v, const Eigen::Vector3i& n, int k, double x,
                double y) {
  x = std::clamp(x, 0.0, n[0] - 1.0);
  y = std::clamp(y, 0.0, n[1] - 1.0);
  const int i0 = std::min(static_cast<int>(x), std::max(0, n[0] - 2));
  const int j0 = std::min(static_cast<int>(y), std::max(0, n[1] - 2));
  const int i1 = std::min(i0 + 1, n[0] - 1), j1 = std::min(j0 + 1, n[1] - 1);
  const double wx = x - i0, wy = y - j0;
  const int64_t slice = int64_t{k} * n[0] * n[1];
  const auto at = [&](int i, int j) { return v[slice + int64_t{j} * n[0] + i]; };
  return (1.0 - wy) * ((1.0 - wx) * at(i0, j0) + wx * at(i1, j0)) +
         wy * ((1.0 - wx) * at(i0, j1) + wx * at(i1, j1));
}

// Normalised Gaussian smoothing of one line (`count` values `stride` apart from `first`)
// with standard deviation `sigma` voxels, inside `inside` (1) only: values outside neither
// contribute nor change.
void SmoothLine(float* first, const uint8_t* inside, int64_t stride, int count, double sigma,
                std::vector<double>* scratch) {
  const int radius = static_cast<int>(std::ceil(3.0 * sigma));
  scratch->assign(static_cast<size_t>(count), 0.0);
  for (int t = 0; t < count; ++t) {
    if (!inside[t * stride]) continue;
    double sum = 0.0, weight = 0.0;
    for (int d = -radius; d <= radius; ++d) {
      const int u = t + d;
      if (u < 0 || u >= count || !inside[u * stride]) continue;
      const double w = std::exp(-0.5 * d * d / (sigma * sigma));
      sum += w * first[u * stride];
      weight += w;
    }
    (*scratch)[t] = sum / weight;
  }
  for (int t = 0; t < count; ++t) {
    if (inside[t * stride]) first[t * stride] = static_cast<float>((*scratch)[t]);
  }
}

}  // namespace

bool HasBeamArtifacts(const SimulationOptions& o) {
  return o.echogenicity_range > 0.0 || o.shadow_strength > 0.0 || o.psf_lateral_mm > 0.0;
}

void ApplyBeamArtifacts(const Mask& fov, const SimulationOptions& o, Image* frame) {
  if (o.echogenicity_range > 0.0) ApplyEchogenicity(fov, o.echogenicity_range, frame);
  if (o.shadow_strength > 0.0) ApplyShadows(fov, o.shadow_strength, o.shadow_threshold, frame);
  if (o.psf_lateral_mm > 0.0) ApplyLateralBlur(fov, o.psf_lateral_mm, frame);
}

void ApplyEchogenicity(const Mask& fov, double range, Image* frame) {
  const ImageGeometry& g = frame->geometry;
  const Eigen::Vector3i n = g.size;
  const int64_t stride[3] = {1, n[0], int64_t{n[0]} * n[1]};
  const std::vector<float>& s = frame->voxels;
  const Eigen::Vector3d apex = Apex(g);
  std::vector<Eigen::Vector3f> gradient(s.size(), Eigen::Vector3f::Zero());
  std::vector<float> magnitudes;
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        const int64_t l = g.LinearIndex(i, j, k);
        if (!fov.voxels[l]) continue;
        const int ijk[3] = {i, j, k};
        Eigen::Vector3f d = Eigen::Vector3f::Zero();
        bool whole = true;
        for (int a = 0; a < 3 && whole; ++a) {
          whole = ijk[a] > 0 && ijk[a] + 1 < n[a] && fov.voxels[l - stride[a]] &&
                  fov.voxels[l + stride[a]];
          if (whole) d[a] = 0.5f * (s[l + stride[a]] - s[l - stride[a]]);
        }
        if (!whole) continue;  // 0 next to the field of view's border
        gradient[l] = d;
        if (d.norm() > 0.0f) magnitudes.push_back(d.norm());
      }
    }
  }
  if (magnitudes.empty()) return;
  const size_t rank = static_cast<size_t>(0.9 * (magnitudes.size() - 1));
  std::nth_element(magnitudes.begin(), magnitudes.begin() + rank, magnitudes.end());
  const double g90 = magnitudes[rank];
  if (!(g90 > 0.0)) return;
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        const int64_t l = g.LinearIndex(i, j, k);
        const double norm = gradient[l].norm();
        if (!fov.voxels[l] || norm == 0.0) continue;
        const Eigen::Vector3d beam = Eigen::Vector3d(i, j, k) - apex;
        if (beam.norm() == 0.0) continue;
        const double cosine = std::abs(gradient[l].cast<double>().dot(beam)) / (norm * beam.norm());
        const double factor =
            1.0 + range * std::min(1.0, norm / g90) * (2.0 * cosine * cosine - 1.0);
        frame->voxels[l] = static_cast<float>(s[l] * factor);
      }
    }
  }
}

void ApplyShadows(const Mask& fov, double strength, double threshold, Image* frame) {
  const ImageGeometry& g = frame->geometry;
  const Eigen::Vector3i n = g.size;
  const Eigen::Vector3d apex = Apex(g);
  // Per voxel the share its value lets through; the transmission built slice by slice.
  std::vector<double> pass(frame->voxels.size(), 1.0), transmission(frame->voxels.size(), 1.0);
  for (size_t l = 0; l < pass.size(); ++l) {
    if (!fov.voxels[l]) continue;
    const double over = (frame->voxels[l] - threshold) / (255.0 - threshold);
    pass[l] = 1.0 - strength * std::clamp(over, 0.0, 1.0);
  }
  for (int k = 1; k < n[2]; ++k) {
    const double back = static_cast<double>(k - 1) / k;  // the beam's point in slice k - 1
    ParallelFor(0, n[1], 0, [&](int64_t j) {
      for (int i = 0; i < n[0]; ++i) {
        const double x = apex[0] + (i - apex[0]) * back, y = apex[1] + (j - apex[1]) * back;
        const double through = Bilinear(transmission, n, k - 1, x, y) *
                               Bilinear(pass, n, k - 1, x, y);
        transmission[g.LinearIndex(i, static_cast<int>(j), k)] = through;
      }
    });
  }
  for (size_t l = 0; l < pass.size(); ++l) {
    if (fov.voxels[l]) frame->voxels[l] = static_cast<float>(frame->voxels[l] * transmission[l]);
  }
}

void ApplyLateralBlur(const Mask& fov, double sigma_mm_at_full_depth, Image* frame) {
  const ImageGeometry& g = frame->geometry;
  const Eigen::Vector3i n = g.size;
  if (n[2] < 2) return;
  ParallelFor(1, n[2], 0, [&](int64_t k) {
    const double sigma_mm = sigma_mm_at_full_depth * static_cast<double>(k) / (n[2] - 1);
    std::vector<double> scratch;
    const double sx = sigma_mm / g.spacing_mm[0], sy = sigma_mm / g.spacing_mm[1];
    for (int j = 0; j < n[1]; ++j) {  // along i
      const int64_t l = g.LinearIndex(0, j, static_cast<int>(k));
      SmoothLine(&frame->voxels[l], &fov.voxels[l], 1, n[0], sx, &scratch);
    }
    for (int i = 0; i < n[0]; ++i) {  // along j
      const int64_t l = g.LinearIndex(i, 0, static_cast<int>(k));
      SmoothLine(&frame->voxels[l], &fov.voxels[l], n[0], n[1], sy, &scratch);
    }
  });
}

std::vector<uint8_t> DropoutWedge(const ImageGeometry& g, const Mask& fov,
                                  const SimulationOptions& o, uint64_t seed_stream) {
  if (o.dropout_fraction <= 0.0) return {};
  std::mt19937_64 rng(seed_stream);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double has = u(rng), width_draw = u(rng), position = u(rng);
  if (has >= o.dropout_view_fraction) return {};
  const double half_opening = 0.5 * o.azimuth_deg * M_PI / 180.0;
  const double width = 2.0 * half_opening * o.dropout_fraction * (0.5 + 0.5 * width_draw);
  const double from = -half_opening + position * (2.0 * half_opening - width);
  const Eigen::Vector3d apex = Apex(g);
  std::vector<uint8_t> lost(static_cast<size_t>(g.NumVoxels()), 0);
  for (int k = 1; k < g.size[2]; ++k) {
    for (int j = 0; j < g.size[1]; ++j) {
      for (int i = 0; i < g.size[0]; ++i) {
        const int64_t l = g.LinearIndex(i, j, k);
        const double angle = std::atan((i - apex[0]) / k);
        lost[l] = fov.voxels[l] && angle >= from && angle < from + width ? 1 : 0;
      }
    }
  }
  return lost;
}

}  // namespace dsr
