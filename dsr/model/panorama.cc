// Panorama grid construction and the closed-form (mean) panorama, eq. 10 of the paper.
#include "dsr/model/panorama.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include <glog/logging.h>

#include "dsr/util/option_fields.h"
#include "dsr/util/parallel.h"

namespace dsr {

bool CheckPanoramaSpacing(const ImageGeometry& frame0, double spacing_factor, std::string* error) {
  const double shortest_extent =
      frame0.size.cast<double>().cwiseProduct(frame0.spacing_mm).minCoeff();
  const double voxel = frame0.spacing_mm.minCoeff() * spacing_factor;
  if (voxel <= shortest_extent / 8.0) return true;
  std::ostringstream s;
  s.precision(3);
  s << "panorama_spacing=" << spacing_factor << ": panorama voxels of " << voxel
    << " mm leave fewer than 8 across frame 0's field of view (" << shortest_extent
    << " mm along its shortest axis); must be at most "
    << shortest_extent / 8.0 / frame0.spacing_mm.minCoeff();
  *error = s.str();
  return false;
}

bool StringToPanoramaSampling(const std::string& name, PanoramaSampling* sampling) {
  return FindNamed(name, {PanoramaSampling::kHalfVoxel, PanoramaSampling::kAllPhases},
                   PanoramaSamplingToString, sampling);
}

bool BuildPanoramaGrid(const std::vector<Frame>& frames,
                       const std::vector<Eigen::Isometry3d>& frame_from_world,
                       double spacing_factor,
                       ImageGeometry* grid,
                       std::string* error,
                       PanoramaSampling sampling) {
  CHECK(!frames.empty());
  CHECK_EQ(frames.size(), frame_from_world.size());
  Eigen::AlignedBox3d box;
  for (size_t i = 0; i < frames.size(); ++i) {
    const Eigen::AlignedBox3d fov = frames[i].ValidIndexBox();
    if (fov.isEmpty()) {
      *error = "frame " + std::to_string(i) + " has no valid field-of-view cell";
      return false;
    }
    const Eigen::Isometry3d world_from_frame = frame_from_world[i].inverse();
    for (int c = 0; c < 8; ++c) {
      const Eigen::Vector3d corner = fov.corner(static_cast<Eigen::AlignedBox3d::CornerType>(c));
      box.extend(world_from_frame * frames[i].geometry().IndexToPhysical(corner));
    }
  }
  ImageGeometry g;
  g.spacing_mm = frames[0].geometry().spacing_mm * spacing_factor;
  g.direction.setIdentity();
  g.origin_mm = box.min();
  // Where frame 0's voxel lattice is axis-aligned in world (its axes are world axes, up to
  // sign), the origin moves down to half a voxel off that lattice. Frame 0 is sampled at
  // one constant offset per axis; only 0 and 1/2 make trilinear interpolation a symmetric
  // filter, any other offset shifts frame 0's content and every frame-0-relative pose with
  // it; 0 would leave frame 0 uninterpolated, sharper and noisier than the other frames
  // (docs/design.md section 2.5).
  const ImageGeometry& g0 = frames[0].geometry();
  const Eigen::Isometry3d world_from_frame0 = frame_from_world[0].inverse();
  const Eigen::Matrix3d axes0 = world_from_frame0.linear() * g0.direction;
  const bool frame0_aligned =
      (axes0.cwiseAbs() - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() < 1e-9;
  if (frame0_aligned) {
    const Eigen::Vector3d anchor = world_from_frame0 * g0.IndexToPhysical(Eigen::Vector3d::Zero());
    for (int a = 0; a < 3; ++a) {
      const double step = g0.spacing_mm[a];
      g.origin_mm[a] =
          anchor[a] + step * (std::floor((box.min()[a] - anchor[a]) / step - 0.5 + 1e-9) + 0.5);
    }
  }
  // kAllPhases: the same origin, and a spacing 1 + 1/n times larger on every axis, n frame
  // 0's longest valid extent in voxels: with factor 1 the phase in frame 0's lattice
  // advances by 1/n per voxel, one sweep across its longest axis (less across shorter ones).
  // Also where frame 0 is not aligned (no half voxel to keep): a frame nearly parallel to a
  // grid of its own spacing would be sampled at one near-constant phase.
  if (sampling == PanoramaSampling::kAllPhases) {
    const double n = std::max(1.0, std::round(frames[0].ValidIndexBox().sizes().maxCoeff()));
    g.spacing_mm *= 1.0 + 1.0 / n;
  }
  double num_voxels = 1.0;
  for (int a = 0; a < 3; ++a) {
    const double n = std::ceil((box.max()[a] - g.origin_mm[a]) / g.spacing_mm[a] - 1e-9) + 1.0;
    num_voxels *= n;
    g.size[a] = static_cast<int>(std::min(n, 2e9));
  }
  if (!(num_voxels <= static_cast<double>(kMaxPanoramaVoxels))) {
    std::ostringstream s;
    s << "panorama grid of " << g.size[0] << "x" << g.size[1] << "x" << g.size[2]
      << " voxels (spacing " << g.spacing_mm.transpose() << " mm, extent "
      << (box.max() - box.min()).transpose()
      << " mm) is too large; check the poses or use a coarser --panorama_spacing";
    *error = s.str();
    return false;
  }
  *grid = g;
  return true;
}

Frame PanoramaAsFrame(const PanoramaImages& fused) {
  Mask observed(fused.count.geometry, 0);
  for (size_t l = 0; l < observed.voxels.size(); ++l) {
    observed.voxels[l] = fused.count.voxels[l] > 0;
  }
  return Frame(fused.mean, observed);
}

Image ResampleOntoGrid(const Frame& frame,
                       const Eigen::Isometry3d& frame_from_world,
                       const ImageGeometry& grid,
                       int num_threads) {
  Image out(grid, 0.0f);
  ParallelFor(0, grid.size[2], num_threads, [&](int64_t k) {
    for (int j = 0; j < grid.size[1]; ++j) {
      for (int i = 0; i < grid.size[0]; ++i) {
        double value;
        if (frame.Sample(frame_from_world * grid.IndexToPhysical(Eigen::Vector3d(i, j, k)), &value,
                         nullptr)) {
          out.voxels[grid.LinearIndex(i, j, static_cast<int>(k))] = static_cast<float>(value);
        }
      }
    }
  });
  return out;
}

Volume<float> ValidCellDistance(const Frame& frame) {
  const ImageGeometry& g = frame.geometry();
  Volume<float> d(g, 0.0f);
  const int nx = g.size[0], ny = g.size[1], nz = g.size[2];
  constexpr float kFar = 1e9f;
  for (int64_t l = 0; l < g.NumVoxels(); ++l) d.voxels[l] = frame.IsValidCell(l) ? kFar : 0.0f;
  // Two chamfer passes with unit 6-neighbour steps give the exact city-block distance;
  // voxels on the grid border have an outside neighbour (distance 1 at most).
  auto at = [&](int i, int j, int k) -> float {
    if (i < 0 || j < 0 || k < 0 || i >= nx || j >= ny || k >= nz) return 0.0f;
    return d.voxels[g.LinearIndex(i, j, k)];
  };
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        float& v = d.voxels[g.LinearIndex(i, j, k)];
        if (v == 0.0f) continue;
        v = std::min({v, at(i - 1, j, k) + 1, at(i, j - 1, k) + 1, at(i, j, k - 1) + 1});
      }
  for (int k = nz - 1; k >= 0; --k)
    for (int j = ny - 1; j >= 0; --j)
      for (int i = nx - 1; i >= 0; --i) {
        float& v = d.voxels[g.LinearIndex(i, j, k)];
        if (v == 0.0f) continue;
        v = std::min({v, at(i + 1, j, k) + 1, at(i, j + 1, k) + 1, at(i, j, k + 1) + 1});
      }
  return d;
}

namespace {

// Shared by both fusions: per voxel, each valid observation with weight `weight(f, p_ij)`,
// corrected by photometric[f] when given.
template <class Weight>
PanoramaImages Fuse(const std::vector<Frame>& frames,
                    const std::vector<Eigen::Isometry3d>& frame_from_world,
                    const ImageGeometry& grid,
                    int num_threads,
                    const std::vector<Photometric>& photometric,
                    const Weight& weight) {
  CHECK(photometric.empty() || photometric.size() == frames.size())
      << photometric.size() << " photometric corrections for " << frames.size() << " frames";
  const bool correct = !photometric.empty();
  PanoramaImages out;
  out.mean = Image(grid, 0.0f);
  out.count = Volume<uint8_t>(grid, 0);
  const int64_t slice = int64_t{grid.size[0]} * grid.size[1];
  std::vector<int64_t> seen(grid.size[2], 0), seen0(grid.size[2], 0);
  ParallelFor(0, grid.size[2], num_threads, [&](int64_t k) {
    for (int j = 0; j < grid.size[1]; ++j) {
      for (int i = 0; i < grid.size[0]; ++i) {
        const Eigen::Vector3d p = grid.IndexToPhysical(Eigen::Vector3d(i, j, k));
        double sum = 0.0, weights = 0.0;
        int count = 0;
        for (size_t f = 0; f < frames.size(); ++f) {
          double value;
          const Eigen::Vector3d x = frame_from_world[f] * p;
          if (frames[f].Sample(x, &value, nullptr)) {
            double w = weight(f, x);
            if (correct) {
              // Frame f's noise is u_f = 1 / gain_f times larger on frame 0's scale: its
              // corrected sample counts u_f^2 (docs/design.md 2.8).
              value = photometric[f].Correct(value);
              w *= photometric[f].unit() * photometric[f].unit();
            }
            sum += w * value;
            weights += w;
            ++count;
            if (f == 0) ++seen0[k];
          }
        }
        const int64_t l = k * slice + grid.LinearIndex(i, j, 0);
        out.count.voxels[l] = static_cast<uint8_t>(count);
        out.mean.voxels[l] = weights > 0.0 ? static_cast<float>(sum / weights) : 0.0f;
        if (count > 0) ++seen[k];
      }
    }
  });
  for (int k = 0; k < grid.size[2]; ++k) {
    out.seen_voxels += seen[k];
    out.frame0_voxels += seen0[k];
  }
  return out;
}

}  // namespace

PanoramaImages FusePanoramaMean(const std::vector<Frame>& frames,
                                const std::vector<Eigen::Isometry3d>& frame_from_world,
                                const ImageGeometry& grid,
                                int num_threads,
                                const std::vector<Photometric>& photometric) {
  return Fuse(frames, frame_from_world, grid, num_threads, photometric,
              [](size_t, const Eigen::Vector3d&) { return 1.0; });
}

PanoramaImages FusePanoramaFeather(const std::vector<Frame>& frames,
                                   const std::vector<Eigen::Isometry3d>& frame_from_world,
                                   const ImageGeometry& grid,
                                   double feather_voxels,
                                   int num_threads,
                                   const std::vector<Photometric>& photometric) {
  if (!(feather_voxels > 0.0)) {
    return FusePanoramaMean(frames, frame_from_world, grid, num_threads, photometric);
  }
  std::vector<Frame> distance(frames.size());
  ParallelFor(0, static_cast<int64_t>(frames.size()), num_threads, [&](int64_t f) {
    const Volume<float> d = ValidCellDistance(frames[f]);
    // A Frame over the distance volume gives its trilinear interpolation.
    distance[f] = Frame(d, Mask(d.geometry, 1));
  });
  return Fuse(frames, frame_from_world, grid, num_threads, photometric,
              [&](size_t f, const Eigen::Vector3d& x) {
                const double d = distance[f].InterpolateValue(distance[f].ToIndex(x));
                return std::clamp(d / feather_voxels, 1e-6, 1.0);
              });
}

bool PrepareFusion(const std::vector<Image>& images,
                   const std::vector<Mask>& masks,
                   const std::vector<std::string>& names,
                   const std::vector<Eigen::Isometry3d>& frame_from_world,
                   double spacing_factor,
                   int num_threads,
                   std::vector<Frame>* frames,
                   std::vector<Eigen::Isometry3d>* relative,
                   ImageGeometry* grid,
                   std::string* error) {
  const int m = static_cast<int>(images.size());
  CHECK_EQ(static_cast<int>(masks.size()), m);
  CHECK_EQ(static_cast<int>(names.size()), m);
  CHECK_EQ(static_cast<int>(frame_from_world.size()), m);
  frames->assign(m, Frame());
  ParallelFor(0, m, num_threads, [&](int64_t i) { (*frames)[i] = Frame(images[i], masks[i]); });
  for (int i = 0; i < m; ++i) {
    if ((*frames)[i].num_valid_cells() == 0) {
      *error = names[i] + ": no valid voxel in the field of view (the mask is too small)";
      return false;
    }
  }
  // The rule a registration applies too: a panorama voxel must resolve frame 0.
  if (!CheckPanoramaSpacing(images[0].geometry, spacing_factor, error)) return false;
  *relative = RelativeToFrame0(frame_from_world);
  return BuildPanoramaGrid(*frames, *relative, spacing_factor, grid, error);
}

PanoramaImages FusePanorama(const std::vector<Frame>& frames,
                            const std::vector<Eigen::Isometry3d>& frame_from_world,
                            const ImageGeometry& grid,
                            bool feather,
                            double feather_voxels,
                            int num_threads,
                            const std::vector<Photometric>& photometric) {
  return feather ? FusePanoramaFeather(frames, frame_from_world, grid, feather_voxels,
                                       num_threads, photometric)
                 : FusePanoramaMean(frames, frame_from_world, grid, num_threads, photometric);
}

}  // namespace dsr
