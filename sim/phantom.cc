#include "sim/phantom.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "core/parallel.h"

namespace dsr {
namespace {

// Separable Gaussian smoothing in place (sigma in voxels, kernel radius 3 sigma).
void Smooth(const Eigen::Vector3i& n, double sigma, std::vector<float>* v) {
  const int r = std::max(1, static_cast<int>(std::ceil(3.0 * sigma)));
  std::vector<float> kernel(2 * r + 1);
  double sum = 0.0;
  for (int t = -r; t <= r; ++t) sum += kernel[t + r] = static_cast<float>(std::exp(-0.5 * t * t / (sigma * sigma)));
  for (float& k : kernel) k = static_cast<float>(k / sum);
  const int64_t stride[3] = {1, n[0], int64_t{n[0]} * n[1]};
  for (int axis = 0; axis < 3; ++axis) {
    const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
    ParallelFor(0, n[a2], 0, [&](int64_t q) {
      std::vector<float> line(n[axis]);
      for (int p = 0; p < n[a1]; ++p) {
        const int64_t base = p * stride[a1] + q * stride[a2];
        for (int t = 0; t < n[axis]; ++t) line[t] = (*v)[base + t * stride[axis]];
        for (int t = 0; t < n[axis]; ++t) {
          double acc = 0.0;
          for (int d = -r; d <= r; ++d) acc += kernel[d + r] * line[std::clamp(t + d, 0, n[axis] - 1)];
          (*v)[base + t * stride[axis]] = static_cast<float>(acc);
        }
      }
    });
  }
}

struct Ellipsoid {
  Eigen::Vector3d center, radii;
  Eigen::Matrix3d rotation;
  // Signed distance-like value: < 0 inside, scaled to millimetres near the surface.
  double Level(const Eigen::Vector3d& x) const {
    const Eigen::Vector3d local = rotation.transpose() * (x - center);
    const double q = local.cwiseQuotient(radii).norm();
    return (q - 1.0) * radii.minCoeff();
  }
};

double SoftStep(double d, double width) { return 0.5 * (1.0 - std::tanh(d / width)); }

}  // namespace

Image MakePhantom(const PhantomOptions& o) {
  ImageGeometry g;
  g.size = Eigen::Vector3i::Constant(o.size);
  g.spacing_mm = Eigen::Vector3d::Constant(o.spacing_mm);
  g.origin_mm = Eigen::Vector3d::Constant(-0.5 * (o.size - 1) * o.spacing_mm);
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const double extent = 0.5 * o.size * o.spacing_mm;

  // Four chambers (atria above, ventricles below) with walls, plus a few extra vessels.
  std::vector<Ellipsoid> chambers;
  std::vector<double> wall_brightness, wall_thickness;
  const Eigen::Vector3d layout[] = {{-0.22, -0.2, 0.18}, {0.22, -0.2, 0.18}, {-0.2, 0.2, -0.15},
                                    {0.2, 0.22, -0.15}, {0.0, -0.45, -0.35}, {0.45, 0.0, 0.4}};
  for (int c = 0; c < 6; ++c) {
    Ellipsoid e;
    e.center = extent * (layout[c] + 0.05 * Eigen::Vector3d(u(rng), u(rng), u(rng)));
    const double base = c < 4 ? 0.2 : 0.09;
    e.radii = extent * base * Eigen::Vector3d(1.0 + 0.3 * u(rng), 1.0 + 0.3 * u(rng), 1.0 + 0.3 * u(rng));
    e.rotation = Eigen::AngleAxisd(M_PI * u(rng), Eigen::Vector3d(u(rng), u(rng), u(rng) + 2.0).normalized())
                     .toRotationMatrix();
    chambers.push_back(e);
    wall_brightness.push_back(170.0 + 45.0 * u(rng));
    wall_thickness.push_back(o.spacing_mm * (4.0 + 2.0 * std::abs(u(rng))));
  }
  // Thin bright sheets (valve-like): planes clipped to discs between chambers.
  struct Sheet { Eigen::Vector3d center, normal; double radius; };
  std::vector<Sheet> sheets;
  for (int s = 0; s < 3; ++s) {
    sheets.push_back({extent * 0.25 * Eigen::Vector3d(u(rng), u(rng), u(rng)),
                      Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized(), extent * (0.15 + 0.05 * u(rng))});
  }

  // Slow background variation and fine texture, both from smoothed white noise.
  std::normal_distribution<float> n01(0.0f, 1.0f);
  const int64_t num = g.NumVoxels();
  std::vector<float> slow(num), fine(num);
  for (int64_t v = 0; v < num; ++v) slow[v] = n01(rng);
  for (int64_t v = 0; v < num; ++v) fine[v] = n01(rng);
  Smooth(g.size, 8.0, &slow);
  Smooth(g.size, 1.0, &fine);
  // Normalise both fields to unit standard deviation.
  for (std::vector<float>* f : {&slow, &fine}) {
    double s2 = 0.0;
    for (float x : *f) s2 += double{x} * x;
    const float scale = static_cast<float>(1.0 / std::sqrt(std::max(1e-12, s2 / num)));
    for (float& x : *f) x *= scale;
  }

  Image image(g);
  const int n = o.size;
  ParallelFor(0, n, 0, [&](int64_t k) {
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector3d x = g.IndexToPhysical(Eigen::Vector3d(i, j, k));
        const int64_t l = g.LinearIndex(i, j, static_cast<int>(k));
        double value = 95.0 + 18.0 * slow[l];  // background tissue
        for (size_t c = 0; c < chambers.size(); ++c) {
          const double d = chambers[c].Level(x);
          const double wall = SoftStep(d - wall_thickness[c], 1.5 * o.spacing_mm);
          const double pool = SoftStep(d, 1.2 * o.spacing_mm);
          const double wall_value = wall_brightness[c] * (1.0 + 0.15 * std::sin(0.08 * x.dot(chambers[c].rotation.col(0))));
          value = value * (1.0 - wall) + wall_value * wall;
          value = value * (1.0 - pool) + 25.0 * pool;
        }
        for (const Sheet& s : sheets) {
          const double dist = std::abs((x - s.center).dot(s.normal));
          const double radial = ((x - s.center) - (x - s.center).dot(s.normal) * s.normal).norm();
          value += 110.0 * SoftStep(dist - 0.8 * o.spacing_mm, 0.8 * o.spacing_mm) *
                   SoftStep(radial - s.radius, 2.0 * o.spacing_mm);
        }
        value += 20.0 * fine[l];  // speckle-like texture
        image.voxels[l] = static_cast<float>(std::clamp(value, 0.0, 255.0));
      }
    }
  });
  return image;
}

}  // namespace dsr
