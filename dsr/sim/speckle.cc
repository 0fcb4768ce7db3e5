// The frames' multiplicative speckle (simulate.h): the per-frame and world-fixed complex
// fields of each look, smoothed by a separable Gaussian kernel, and SpeckleField,
// SpeckleWorldGrid and SpeckleFields, which make it.
#include "dsr/sim/simulate.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <glog/logging.h>

#include "dsr/sim/simulate_internal.h"
#include "dsr/util/parallel.h"

namespace dsr {
namespace {

using sim_internal::kSpecklePhaseStream;
using sim_internal::kSpeckleStream;
using sim_internal::kSpeckleWorldStream;
using sim_internal::Moves;
using sim_internal::StreamSeed;

// Largest world speckle grid per axis, in voxels: far beyond any grid that fits in memory,
// it only keeps the index arithmetic in int.
constexpr int64_t kMaxSpeckleWorldSize = int64_t{1} << 24;

// The speckle kernel is cut at this many standard deviations. The cut weights would carry
// < 1e-4 of the kernel's squared sum; the kept ones are rescaled to a unit squared sum, so
// the speckle's mean stays exactly 1 and the cut only trims the far tail of its
// correlation.
constexpr double kSpeckleKernelSigmas = 3.0;

// The generator seed of one padded slice k of look `look` of frame `frame_index`'s per-frame
// speckle: the still frame's stream for phase 0, a stream of its own for each later phase.
uint64_t FrameSpeckleSeed(uint64_t seed, int frame_index, int phase, int look, int64_t k) {
  const uint64_t f = static_cast<uint64_t>(frame_index), l = static_cast<uint64_t>(look);
  const uint64_t slice = static_cast<uint64_t>(k);
  return phase == 0
             ? StreamSeed(seed, kSpeckleStream, {f, l, slice})
             : StreamSeed(seed, kSpecklePhaseStream, {f, static_cast<uint64_t>(phase), l, slice});
}

// The speckle's 1-D kernel: weights exp(-d^2 / (2 c^2)), |d| <= radius = ceil(3 c), scaled
// to sum w_d^2 = 1. The 3-D kernel (their product) then has a unit squared sum, so a
// smoothed unit-variance white field keeps its variance, E|z|^2 = 2 with N(0, 1) real and
// imaginary parts (c = 0: the single weight 1, no smoothing).
std::vector<double> SpeckleKernel(double c) {
  const int radius = static_cast<int>(std::ceil(kSpeckleKernelSigmas * c));
  const int taps = 2 * radius + 1;
  std::vector<double> w(taps, 1.0);
  if (radius > 0) {
    double squares = 0.0;
    for (int t = 0; t < taps; ++t) {
      const double d = t - radius;
      w[t] = std::exp(-d * d / (2.0 * c * c));
      squares += w[t] * w[t];
    }
    for (double& weight : w) weight /= std::sqrt(squares);
  }
  return w;
}

// Scratch of one frame look's smoothing (complex, interleaved [re, im], x fastest), reused
// over looks and frames.
struct FrameLookScratch {
  std::vector<double> white;    // the padded grid
  std::vector<double> along_x;  // x smoothed: n_x by the padded y and z
  std::vector<double> along_y;  // x and y smoothed: n_x n_y by the padded z
};

// Look `look` of frame `frame_index`'s per-frame complex field (of phase `phase`: seeds by
// FrameSpeckleSeed) on the frame grid `g`: white
// N(0, 1) components drawn on g padded by the kernel radius on every side (one generator
// per padded slice, its re and im draws in voxel order, so the draws do not depend on which
// thread takes the slice), then the three separable passes of `w`, each dropping the
// padding of one axis, so that every frame voxel sees the whole kernel. The last pass hands
// each frame voxel's smoothed value to add(k, j, i, re, im), in parallel over k: `add`
// must write only voxel (i, j, k)'s outputs.
template <typename Add>
void FrameSpeckleLook(const ImageGeometry& g,
                      const std::vector<double>& w,
                      uint64_t seed,
                      int frame_index,
                      int phase,
                      int look,
                      int num_threads,
                      FrameLookScratch* scratch,
                      const Add& add) {
  const int taps = static_cast<int>(w.size());
  const int radius = taps / 2;
  const Eigen::Vector3i& n = g.size;
  const Eigen::Vector3i p = n + Eigen::Vector3i::Constant(2 * radius);
  const int64_t p_slice = int64_t{p[0]} * p[1];
  std::vector<double>& white = scratch->white;
  std::vector<double>& along_x = scratch->along_x;
  std::vector<double>& along_y = scratch->along_y;
  white.resize(2 * p_slice * p[2]);
  along_x.resize(2 * int64_t{n[0]} * p[1] * p[2]);
  along_y.resize(2 * int64_t{n[0]} * n[1] * p[2]);
  ParallelFor(0, p[2], num_threads, [&](int64_t k) {
    std::mt19937_64 rng(FrameSpeckleSeed(seed, frame_index, phase, look, k));
    // Each component N(0, 1): |z|^2 / 2 then has mean 1 after the unit-norm kernel.
    std::normal_distribution<double> normal(0.0, 1.0);
    double* slice = white.data() + 2 * k * p_slice;
    for (int64_t v = 0; v < 2 * p_slice; ++v) slice[v] = normal(rng);
  });
  ParallelFor(0, p[2], num_threads, [&](int64_t k) {
    for (int j = 0; j < p[1]; ++j) {
      const double* in = white.data() + 2 * (k * p_slice + int64_t{j} * p[0]);
      double* out = along_x.data() + 2 * ((k * p[1] + j) * int64_t{n[0]});
      for (int i = 0; i < n[0]; ++i) {
        double re = 0.0, im = 0.0;
        for (int t = 0; t < taps; ++t) {
          re += w[t] * in[2 * (i + t)];
          im += w[t] * in[2 * (i + t) + 1];
        }
        out[2 * i] = re;
        out[2 * i + 1] = im;
      }
    }
  });
  ParallelFor(0, p[2], num_threads, [&](int64_t k) {
    for (int j = 0; j < n[1]; ++j) {
      double* out = along_y.data() + 2 * ((k * n[1] + j) * int64_t{n[0]});
      for (int i = 0; i < n[0]; ++i) {
        double re = 0.0, im = 0.0;
        for (int t = 0; t < taps; ++t) {
          const int64_t in = 2 * ((k * p[1] + j + t) * int64_t{n[0]} + i);
          re += w[t] * along_x[in];
          im += w[t] * along_x[in + 1];
        }
        out[2 * i] = re;
        out[2 * i + 1] = im;
      }
    }
  });
  ParallelFor(0, n[2], num_threads, [&](int64_t k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        double re = 0.0, im = 0.0;
        for (int t = 0; t < taps; ++t) {
          const int64_t in = 2 * (((k + t) * n[1] + j) * int64_t{n[0]} + i);
          re += w[t] * along_y[in];
          im += w[t] * along_y[in + 1];
        }
        add(k, j, i, re, im);
      }
    }
  });
}

// Look `look`'s world-fixed complex field on a world grid of `size` voxels, in `field`
// (resized; interleaved [re, im]): white N(0, 1) components drawn on the grid padded by the
// kernel radius R on every side (one generator per padded slice k, seeded from (seed,
// "speckleW", look, k), draws in voxel order), then smoothed in place by the three
// separable passes of `w`. The field keeps the padded strides: world voxel (i, j, k) is at
// 2 (i + p_x (j + p_y k)), p = size + 2R. In place is safe because output i of a line reads
// inputs i .. i + 2R only and the lines are walked upwards: the x and y passes own a slice
// each, the z pass a row j through every slice.
void WorldSpeckleLook(const Eigen::Vector3i& size,
                      const std::vector<double>& w,
                      uint64_t seed,
                      int look,
                      int num_threads,
                      std::vector<double>* field) {
  const int taps = static_cast<int>(w.size());
  const int radius = taps / 2;
  const Eigen::Vector3i p = size + Eigen::Vector3i::Constant(2 * radius);
  const int64_t p_slice = int64_t{p[0]} * p[1];
  field->resize(2 * p_slice * p[2]);
  double* z = field->data();
  ParallelFor(0, p[2], num_threads, [&](int64_t k) {
    std::mt19937_64 rng(StreamSeed(seed, kSpeckleWorldStream,
                                   {static_cast<uint64_t>(look), static_cast<uint64_t>(k)}));
    std::normal_distribution<double> normal(0.0, 1.0);
    double* slice = z + 2 * k * p_slice;
    for (int64_t v = 0; v < 2 * p_slice; ++v) slice[v] = normal(rng);
  });
  if (radius == 0) return;  // c = 0: white
  ParallelFor(0, p[2], num_threads, [&](int64_t k) {
    for (int j = 0; j < p[1]; ++j) {
      double* line = z + 2 * (k * p_slice + int64_t{j} * p[0]);
      for (int i = 0; i < size[0]; ++i) {
        double re = 0.0, im = 0.0;
        for (int t = 0; t < taps; ++t) {
          re += w[t] * line[2 * (i + t)];
          im += w[t] * line[2 * (i + t) + 1];
        }
        line[2 * i] = re;
        line[2 * i + 1] = im;
      }
    }
  });
  const int64_t row = 2 * int64_t{p[0]};  // doubles per padded row
  ParallelFor(0, p[2], num_threads, [&](int64_t k) {
    double* slice = z + 2 * k * p_slice;
    for (int j = 0; j < size[1]; ++j) {
      for (int i = 0; i < size[0]; ++i) {
        double re = 0.0, im = 0.0;
        for (int t = 0; t < taps; ++t) {
          const double* in = slice + (j + t) * row + 2 * i;
          re += w[t] * in[0];
          im += w[t] * in[1];
        }
        slice[j * row + 2 * i] = re;
        slice[j * row + 2 * i + 1] = im;
      }
    }
  });
  ParallelFor(0, size[1], num_threads, [&](int64_t j) {
    for (int k = 0; k < size[2]; ++k) {
      for (int i = 0; i < size[0]; ++i) {
        double re = 0.0, im = 0.0;
        for (int t = 0; t < taps; ++t) {
          const double* in = z + 2 * ((k + t) * p_slice + j * p[0] + i);
          re += w[t] * in[0];
          im += w[t] * in[1];
        }
        double* out = z + 2 * (k * p_slice + j * p[0] + i);
        out[0] = re;
        out[1] = im;
      }
    }
  });
}

// The world field of one look sampled at a continuous world-grid index u: the trilinear
// interpolant divided by the root of its variance factor, so that it has the variance of a
// grid value (SpeckleFields in simulate.h). Per axis the factor is
// (1 - t)^2 + t^2 + 2 t (1 - t) r1 = 1 - 2 t (1 - t) (1 - r1). An index off the grid (by
// rounding only: the grid holds every field-of-view voxel) reads the nearest border point.
struct WorldLookSampler {
  const double* field = nullptr;       // WorldSpeckleLook's layout
  Eigen::Vector3i size;                // the world grid's
  int64_t stride_y = 0;                // complex values per padded row
  int64_t stride_z = 0;                // complex values per padded slice
  double neighbour_correlation = 0.0;  // r1 = sum_d w_d w_d+1

  void Sample(const Eigen::Vector3d& u, double* re, double* im) const {
    int lower[3];
    double t[3];
    int64_t step[3];
    double variance = 1.0;
    for (int a = 0; a < 3; ++a) {
      const double x = std::clamp(u[a], 0.0, static_cast<double>(size[a] - 1));
      lower[a] = std::min(static_cast<int>(x), std::max(size[a] - 2, 0));
      t[a] = x - lower[a];
      step[a] = lower[a] + 1 < size[a] ? 1 : 0;
      variance *= 1.0 - 2.0 * t[a] * (1.0 - t[a]) * (1.0 - neighbour_correlation);
    }
    // Offsets in doubles ([re, im] interleaved) of the upper neighbour along each axis.
    const int64_t sx = 2 * step[0], sy = 2 * step[1] * stride_y, sz = 2 * step[2] * stride_z;
    const double* base = field + 2 * (lower[0] + lower[1] * stride_y + lower[2] * stride_z);
    const auto lerp = [](double a, double b, double s) { return a + s * (b - a); };
    double value[2];
    for (int part = 0; part < 2; ++part) {
      const double* c = base + part;
      const double x00 = lerp(c[0], c[sx], t[0]);
      const double x10 = lerp(c[sy], c[sy + sx], t[0]);
      const double x01 = lerp(c[sz], c[sz + sx], t[0]);
      const double x11 = lerp(c[sz + sy], c[sz + sy + sx], t[0]);
      value[part] = lerp(lerp(x00, x10, t[1]), lerp(x01, x11, t[1]), t[2]);
    }
    const double scale = 1.0 / std::sqrt(variance);
    *re = value[0] * scale;
    *im = value[1] * scale;
  }
};

}  // namespace

Image SpeckleField(const ImageGeometry& g,
                   const SimulationOptions& options,
                   int frame_index,
                   int num_threads,
                   int phase) {
  std::string error;
  CHECK(options.Validate(&error)) << error;
  CHECK_GE(options.speckle_looks, 1);
  CHECK_EQ(options.speckle_world_fraction, 0.0) << "a world-fixed part needs SpeckleFields";
  CHECK_GE(frame_index, 0);
  CHECK_GE(phase, 0);
  const std::vector<double> w = SpeckleKernel(options.speckle_correlation_voxels);
  FrameLookScratch scratch;
  std::vector<double> sum(g.NumVoxels(), 0.0);
  for (int look = 0; look < options.speckle_looks; ++look) {
    // Each voxel adds its looks in look order: the same sum for any thread count.
    FrameSpeckleLook(g, w, options.seed, frame_index, phase, look, num_threads, &scratch,
                     [&](int64_t k, int j, int i, double re, double im) {
                       sum[g.LinearIndex(i, j, static_cast<int>(k))] += 0.5 * (re * re + im * im);
                     });
  }
  Image speckle(g, 0.0f);
  for (size_t l = 0; l < sum.size(); ++l) {
    speckle.voxels[l] = static_cast<float>(sum[l] / options.speckle_looks);
  }
  return speckle;
}

ImageGeometry SpeckleWorldGrid(const ImageGeometry& g,
                               const std::vector<Eigen::Isometry3d>& frame_from_world,
                               const SimulationOptions& options,
                               const BeatRegion* beat) {
  std::string error;
  CHECK(options.Validate(&error)) << error;
  CHECK(!frame_from_world.empty());
  CHECK((g.spacing_mm.array() == g.spacing_mm[0]).all())
      << "the frame spacing must be isotropic: " << g.spacing_mm.transpose();
  const double s = g.spacing_mm[0];
  const Mask fov = PyramidFieldOfView(g, options);
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  for (const Eigen::Isometry3d& frame_from_world_i : frame_from_world) {
    const Eigen::Isometry3d world_from_frame = frame_from_world_i.inverse();
    const auto extend = [&](int i, int j, int k) {
      const Eigen::Vector3d x_in_world =
          world_from_frame * g.IndexToPhysical(Eigen::Vector3d(i, j, k));
      lo = lo.cwiseMin(x_in_world);
      hi = hi.cwiseMax(x_in_world);
    };
    // The map is affine, so the box of the voxel centres is the box of each row's two
    // ends (they include every vertex of the set's convex hull).
    bool any = false;
    for (int k = 0; k < g.size[2]; ++k) {
      for (int j = 0; j < g.size[1]; ++j) {
        int first = -1, last = -1;
        for (int i = 0; i < g.size[0]; ++i) {
          if (!fov.at(i, j, k)) continue;
          if (first < 0) first = i;
          last = i;
        }
        if (first < 0) continue;
        any = true;
        extend(first, j, k);
        extend(last, j, k);
      }
    }
    if (!any) {  // an empty field of view: the whole frame grid
      for (int corner = 0; corner < 8; ++corner) {
        extend(corner & 1 ? g.size[0] - 1 : 0, corner & 2 ? g.size[1] - 1 : 0,
               corner & 4 ? g.size[2] - 1 : 0);
      }
    }
  }
  if (beat != nullptr) {  // psi_p keeps the ball's points in the ball (simulate.h)
    lo = lo.cwiseMin(beat->center_mm - Eigen::Vector3d::Constant(beat->radius_mm));
    hi = hi.cwiseMax(beat->center_mm + Eigen::Vector3d::Constant(beat->radius_mm));
  }
  ImageGeometry world;
  world.spacing_mm = Eigen::Vector3d::Constant(s);
  for (int a = 0; a < 3; ++a) {
    const double first = std::floor(lo[a] / s), last = std::ceil(hi[a] / s);
    CHECK(std::isfinite(first) && std::isfinite(last) && last - first < kMaxSpeckleWorldSize)
        << "world speckle grid from " << lo.transpose() << " to " << hi.transpose() << " mm";
    world.size[a] = static_cast<int>(last - first) + 1;
    world.origin_mm[a] = first * s;
  }
  return world;
}

std::vector<Image> SpeckleFields(const ImageGeometry& g,
                                 const std::vector<Eigen::Isometry3d>& frame_from_world,
                                 const SimulationOptions& options,
                                 int num_threads,
                                 int phase,
                                 const BeatRegion* beat) {
  std::string error;
  CHECK(options.Validate(&error)) << error;
  CHECK_GE(options.speckle_looks, 1);
  CHECK(!frame_from_world.empty());
  CHECK_GE(phase, 0);
  CHECK(phase == 0 || (beat != nullptr && phase < options.num_phases)) << phase;
  const int num_frames = static_cast<int>(frame_from_world.size());
  std::vector<Image> fields;
  const double rho = options.speckle_world_fraction;
  if (rho == 0.0) {
    for (int f = 0; f < num_frames; ++f) {
      fields.push_back(SpeckleField(g, options, f, num_threads, phase));
    }
    return fields;
  }
  const bool moves = Moves(beat, phase);
  const double t = static_cast<double>(phase) / options.num_phases;
  const std::vector<double> w = SpeckleKernel(options.speckle_correlation_voxels);
  const int radius = static_cast<int>(w.size()) / 2;
  const ImageGeometry world = SpeckleWorldGrid(g, frame_from_world, options, beat);
  WorldLookSampler sampler;
  sampler.size = world.size;
  sampler.stride_y = world.size[0] + 2 * radius;
  sampler.stride_z = sampler.stride_y * (world.size[1] + 2 * radius);
  for (size_t t = 0; t + 1 < w.size(); ++t) sampler.neighbour_correlation += w[t] * w[t + 1];
  // Frame index -> world-grid index, u = index_from_frame * ijk + shift.
  std::vector<Eigen::Matrix3d> index_from_frame(num_frames);
  std::vector<Eigen::Vector3d> shift(num_frames);
  std::vector<Eigen::Isometry3d> world_from_frames(num_frames);  // for a moving phase
  for (int f = 0; f < num_frames; ++f) {
    const Eigen::Isometry3d world_from_frame = frame_from_world[f].inverse();
    world_from_frames[f] = world_from_frame;
    index_from_frame[f] =
        world.PhysicalToIndexMatrix() * world_from_frame.linear() * g.IndexToPhysicalMatrix();
    shift[f] = world.PhysicalToIndex(world_from_frame * g.origin_mm);
  }
  // The looks' |z|^2 / 2 are summed in each frame's returned field (float: the field is
  // returned as float anyway, and 64 float additions lose < 1e-5 of it), in the field of
  // view only: Simulate uses nothing else, and the world sampling is most of the cost.
  const Mask fov = PyramidFieldOfView(g, options);
  for (int f = 0; f < num_frames; ++f) fields.emplace_back(g, 0.0f);
  const double world_weight = std::sqrt(rho), frame_weight = std::sqrt(1.0 - rho);
  std::vector<double> world_field;  // one look at a time
  FrameLookScratch scratch;
  for (int look = 0; look < options.speckle_looks; ++look) {
    WorldSpeckleLook(world.size, w, options.seed, look, num_threads, &world_field);
    sampler.field = world_field.data();
    for (int f = 0; f < num_frames; ++f) {
      float* sum = fields[f].voxels.data();
      const auto add = [&](int64_t k, int j, int i, double re, double im) {
        const int64_t l = g.LinearIndex(i, j, static_cast<int>(k));
        if (!fov.voxels[l]) return;
        double world_re = 0.0, world_im = 0.0;
        const Eigen::Vector3d ijk(i, j, static_cast<double>(k));
        if (moves) {  // the tissue's scatterers: the world field at psi_p(x)
          const Eigen::Vector3d x = world_from_frames[f] * g.IndexToPhysical(ijk);
          sampler.Sample(world.PhysicalToIndex(x - BeatDisplacement(*beat, t, x)), &world_re,
                         &world_im);
        } else {
          sampler.Sample(index_from_frame[f] * ijk + shift[f], &world_re, &world_im);
        }
        const double z_re = world_weight * world_re + frame_weight * re;
        const double z_im = world_weight * world_im + frame_weight * im;
        sum[l] = static_cast<float>(sum[l] + 0.5 * (z_re * z_re + z_im * z_im));
      };
      if (rho < 1.0) {
        FrameSpeckleLook(g, w, options.seed, f, phase, look, num_threads, &scratch, add);
      } else {  // the per-frame fields have weight 0: not drawn
        ParallelFor(0, g.size[2], num_threads, [&](int64_t k) {
          for (int j = 0; j < g.size[1]; ++j) {
            for (int i = 0; i < g.size[0]; ++i) add(k, j, i, 0.0, 0.0);
          }
        });
      }
    }
  }
  for (Image& field : fields) {
    for (size_t l = 0; l < field.voxels.size(); ++l) {
      field.voxels[l] = fov.voxels[l]
                            ? static_cast<float>(double{field.voxels[l]} / options.speckle_looks)
                            : 1.0f;
    }
  }
  return fields;
}

}  // namespace dsr
