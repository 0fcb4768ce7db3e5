// Trilinear sampling of intensity and of the corners' central differences with the
// field-of-view validity rule (docs/design.md section 2). See frame.h for the gradient rule
// and the layout.
#include "dsr/image/frame.h"

#include <algorithm>
#include <cmath>

#include <glog/logging.h>

#include "dsr/util/huge_pages.h"

namespace dsr {
namespace {

// Box dilation of a byte map by `r` along one axis (separable, exact for a box).
void DilateAlongAxis(const Eigen::Vector3i& n, int axis, int r, std::vector<uint8_t>* map) {
  const int len = n[axis];
  const int64_t stride = axis == 0 ? 1 : (axis == 1 ? n[0] : int64_t{n[0]} * n[1]);
  const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
  const int64_t stride1 = a1 == 0 ? 1 : (a1 == 1 ? n[0] : int64_t{n[0]} * n[1]);
  const int64_t stride2 = a2 == 0 ? 1 : (a2 == 1 ? n[0] : int64_t{n[0]} * n[1]);
  std::vector<uint8_t> line(len);
  std::vector<int> prefix(len + 1);
  for (int p = 0; p < n[a1]; ++p) {
    for (int q = 0; q < n[a2]; ++q) {
      const int64_t base = p * stride1 + q * stride2;
      prefix[0] = 0;
      for (int t = 0; t < len; ++t) {
        line[t] = (*map)[base + t * stride];
        prefix[t + 1] = prefix[t] + (line[t] ? 1 : 0);
      }
      for (int t = 0; t < len; ++t) {
        const int lo = std::max(0, t - r), hi = std::min(len, t + r + 1);
        (*map)[base + t * stride] = prefix[hi] - prefix[lo] > 0 ? 1 : 0;
      }
    }
  }
}

}  // namespace

Frame::Frame(const Image& image, const Mask& mask)
    : Frame(std::vector<const Image*>{&image}, mask) {}

Frame::Frame(const std::vector<Image>& phases, const Mask& mask)
    : Frame(
          [&phases] {
            CHECK(!phases.empty()) << "a frame needs at least one phase";
            std::vector<const Image*> pointers;
            for (const Image& phase : phases) pointers.push_back(&phase);
            return pointers;
          }(),
          mask) {}

Frame::Frame(const Image& phase0, const std::vector<Image>& later_phases, const Mask& mask)
    : Frame(
          [&] {
            std::vector<const Image*> pointers(1, &phase0);
            for (const Image& phase : later_phases) pointers.push_back(&phase);
            return pointers;
          }(),
          mask) {}

const std::vector<Image>& LaterPhasesOf(const std::vector<std::vector<Image>>* later_phases,
                                        size_t view) {
  static const std::vector<Image> kNone;
  return later_phases == nullptr || later_phases->empty() ? kNone : later_phases->at(view);
}

Frame Frame::Borrowing(const Image& phase0, const std::vector<Image>& later_phases,
                       const Mask& mask) {
  std::vector<const Image*> pointers(1, &phase0);
  for (const Image& phase : later_phases) pointers.push_back(&phase);
  return Frame(pointers, mask, /*borrow=*/true);
}

Frame::Frame(const std::vector<const Image*>& phases, const Mask& mask)
    : Frame(phases, mask, /*borrow=*/false) {}

Frame::Frame(const std::vector<const Image*>& phases, const Mask& mask, bool borrow)
    : geometry_(phases.front()->geometry) {
  CHECK(geometry_.SameGrid(mask.geometry)) << "mask and image grids differ";
  for (const Image* image : phases) {
    CHECK(image->geometry.SameGrid(geometry_)) << "a frame's phases lie on different grids";
    CHECK_EQ(static_cast<int64_t>(image->voxels.size()), geometry_.NumVoxels());
  }
  index_from_physical_ = geometry_.PhysicalToIndexMatrix();
  gradient_to_physical_ = index_from_physical_.transpose();

  const Eigen::Vector3i n = geometry_.size;
  const int64_t num = geometry_.NumVoxels();
  const int64_t stride[3] = {1, n[0], int64_t{n[0]} * n[1]};
  const uint8_t* m = mask.voxels.data();

  // Stencil voxels (the gradient rule, frame.h): inside the mask with all 6 neighbours in
  // the grid and inside the mask, i.e. the mask eroded by the 6-neighbourhood, with the grid
  // border outside. Only they may be corners of a valid cell.
  std::vector<uint8_t> stencil(static_cast<size_t>(num), uint8_t{0});
  for (int k = 1; k + 1 < n[2]; ++k) {
    for (int j = 1; j + 1 < n[1]; ++j) {
      const int64_t row = geometry_.LinearIndex(0, j, k);
      // 0 or 1 without a branch per voxel (the compiler vectorises the row).
      for (int i = 1; i + 1 < n[0]; ++i) {
        const int64_t l = row + i;
        stencil[l] = (m[l] != 0) & (m[l - 1] != 0) & (m[l + 1] != 0) & (m[l - stride[1]] != 0) &
                     (m[l + stride[1]] != 0) & (m[l - stride[2]] != 0) & (m[l + stride[2]] != 0);
      }
    }
  }

  // Each phase's values, borrowed (an owner-less pointer) or copied.
  for (const Image* image : phases) {
    std::shared_ptr<const float> values;
    if (borrow) {
      values = std::shared_ptr<const float>(std::shared_ptr<const float>(), image->voxels.data());
    } else {
      auto copy = std::make_shared<std::vector<float>>();
      const float* v = image->voxels.data();
      AssignWithHugePages(copy.get(), v, v + image->voxels.size());
      values = std::shared_ptr<const float>(copy, copy->data());
    }
    if (values_ == nullptr) {
      values_ = std::move(values);
    } else {
      more_phases_.push_back(std::move(values));
    }
  }

  std::vector<uint8_t> valid(static_cast<size_t>(num / 8 + 2), uint8_t{0});
  int lo[3] = {n[0], n[1], n[2]}, hi[3] = {-1, -1, -1};  // valid cells' index range
  const uint8_t* c = stencil.data();
  std::vector<uint8_t> cells(static_cast<size_t>(std::max(0, n[0] - 1)));
  for (int k = 0; k + 1 < n[2]; ++k) {
    for (int j = 0; j + 1 < n[1]; ++j) {
      // The 4 stencil rows holding the corners of the cells (i, j, k), i = 0..n[0]-2; each
      // cell 0 or 1 (stencil voxels are), without a branch per cell.
      const uint8_t* r00 = c + geometry_.LinearIndex(0, j, k);
      const uint8_t* r10 = c + geometry_.LinearIndex(0, j + 1, k);
      const uint8_t* r01 = c + geometry_.LinearIndex(0, j, k + 1);
      const uint8_t* r11 = c + geometry_.LinearIndex(0, j + 1, k + 1);
      uint8_t any = 0;
      for (int i = 0; i + 1 < n[0]; ++i) {
        cells[i] = r00[i] & r00[i + 1] & r10[i] & r10[i + 1] & r01[i] & r01[i + 1] & r11[i] &
                   r11[i + 1];
        any |= cells[i];
      }
      if (any == 0) continue;
      const int64_t row = geometry_.LinearIndex(0, j, k);
      int first = -1, last = -1;
      for (int i = 0; i + 1 < n[0]; ++i) {
        const int64_t l = row + i;
        valid[l >> 3] |= static_cast<uint8_t>(cells[i] << (l & 7));
        num_valid_cells_ += cells[i];
        if (cells[i] != 0) {
          if (first < 0) first = i;
          last = i;
        }
      }
      lo[0] = std::min(lo[0], first);
      hi[0] = std::max(hi[0], last);
      lo[1] = std::min(lo[1], j);
      hi[1] = std::max(hi[1], j);
      lo[2] = std::min(lo[2], k);
      hi[2] = std::max(hi[2], k);
    }
  }
  if (num_valid_cells_ > 0) {
    valid_index_box_.extend(Eigen::Vector3d(lo[0], lo[1], lo[2]));
    valid_index_box_.extend(Eigen::Vector3d(hi[0] + 1, hi[1] + 1, hi[2] + 1));
  }
  valid_bits_ = std::make_shared<const std::vector<uint8_t>>(std::move(valid));
}

Frame Frame::Phase(int phase) const {
  CHECK(phase >= 0 && phase < num_phases()) << "phase " << phase << " of " << num_phases();
  Frame one = *this;
  one.more_phases_.clear();
  if (phase > 0) one.values_ = more_phases_[phase - 1];
  return one;
}

int NumPhases(const std::vector<Frame>& frames) {
  if (frames.empty()) return 1;
  const int phases = frames.front().num_phases();
  for (const Frame& frame : frames) {
    CHECK_EQ(frame.num_phases(), phases) << "frames with different numbers of phases";
  }
  return phases;
}

std::vector<Frame> PhaseFrames(const std::vector<Frame>& frames, int phase) {
  std::vector<Frame> out;
  out.reserve(frames.size());
  for (const Frame& frame : frames) out.push_back(frame.Phase(phase));
  return out;
}

FramesByPhase::FramesByPhase(const std::vector<Frame>& frames) {
  const int phases = NumPhases(frames);
  if (phases == 1) {
    phases_.push_back(&frames);
    return;
  }
  for (int p = 0; p < phases; ++p) {
    owned_.push_back(std::make_unique<const std::vector<Frame>>(PhaseFrames(frames, p)));
    phases_.push_back(owned_.back().get());
  }
}

bool Frame::IsValidIndex(const Eigen::Vector3d& ijk) const {
  const Eigen::Vector3i& n = geometry_.size;
  const double fi = std::floor(ijk[0]), fj = std::floor(ijk[1]), fk = std::floor(ijk[2]);
  // Compare as doubles first so huge or NaN coordinates never overflow an int.
  if (!(fi >= 0.0 && fj >= 0.0 && fk >= 0.0 && fi <= n[0] - 2 && fj <= n[1] - 2 &&
        fk <= n[2] - 2)) {
    return false;
  }
  return IsValidCell(geometry_.LinearIndex(static_cast<int>(fi), static_cast<int>(fj),
                                           static_cast<int>(fk)));
}

bool Frame::SampleAtIndex(const Eigen::Vector3d& ijk,
                          double* value,
                          Eigen::Vector3d* gradient_ijk) const {
  if (!IsValidIndex(ijk)) return false;
  const int i = static_cast<int>(std::floor(ijk[0]));
  const int j = static_cast<int>(std::floor(ijk[1]));
  const int k = static_cast<int>(std::floor(ijk[2]));
  const double fx = ijk[0] - i, fy = ijk[1] - j, fz = ijk[2] - k;
  const int64_t sy = geometry_.size[0], sz = sy * int64_t{geometry_.size[1]};
  const float* base = values() + geometry_.LinearIndex(i, j, k);
  double acc[4] = {0.0, 0.0, 0.0, 0.0};
  for (int c = 0; c < 8; ++c) {
    const int dx = c & 1, dy = (c >> 1) & 1, dz = (c >> 2) & 1;
    const double w = (dx ? fx : 1.0 - fx) * (dy ? fy : 1.0 - fy) * (dz ? fz : 1.0 - fz);
    float p[4];
    CornerSample(base + dx + dy * sy + dz * sz, sy, sz, p);
    for (int q = 0; q < 4; ++q) acc[q] += w * p[q];
  }
  *value = acc[0];
  if (gradient_ijk != nullptr) *gradient_ijk = Eigen::Vector3d(acc[1], acc[2], acc[3]);
  return true;
}

bool Frame::SampleSlopesAtIndex(const Eigen::Vector3d& ijk,
                                double* value,
                                Eigen::Vector3d* gradient_ijk,
                                Eigen::Vector3d* value_slope,
                                Eigen::Matrix3d* gradient_slope) const {
  if (!IsValidIndex(ijk)) return false;
  const int i = static_cast<int>(std::floor(ijk[0]));
  const int j = static_cast<int>(std::floor(ijk[1]));
  const int k = static_cast<int>(std::floor(ijk[2]));
  const double fx = ijk[0] - i, fy = ijk[1] - j, fz = ijk[2] - k;
  const int64_t sy = geometry_.size[0], sz = sy * int64_t{geometry_.size[1]};
  const float* base = values() + geometry_.LinearIndex(i, j, k);
  double acc[4] = {0.0, 0.0, 0.0, 0.0};
  double slope[4][3] = {};
  for (int c = 0; c < 8; ++c) {
    const int dx = c & 1, dy = (c >> 1) & 1, dz = (c >> 2) & 1;
    const double wx = dx ? fx : 1.0 - fx, wy = dy ? fy : 1.0 - fy, wz = dz ? fz : 1.0 - fz;
    const double w = wx * wy * wz;  // as SampleAtIndex: the same value and gradient
    // d w / d u_a: the corner's weight along a is f or 1 - f, of slope +1 or -1.
    const double dw[3] = {(dx ? 1.0 : -1.0) * wy * wz, wx * (dy ? 1.0 : -1.0) * wz,
                          wx * wy * (dz ? 1.0 : -1.0)};
    float p[4];
    CornerSample(base + dx + dy * sy + dz * sz, sy, sz, p);
    for (int q = 0; q < 4; ++q) {
      acc[q] += w * p[q];
      for (int a = 0; a < 3; ++a) slope[q][a] += dw[a] * p[q];
    }
  }
  *value = acc[0];
  *gradient_ijk = Eigen::Vector3d(acc[1], acc[2], acc[3]);
  *value_slope = Eigen::Vector3d(slope[0][0], slope[0][1], slope[0][2]);
  for (int q = 0; q < 3; ++q) {
    for (int a = 0; a < 3; ++a) (*gradient_slope)(q, a) = slope[1 + q][a];
  }
  return true;
}

bool Frame::Sample(const Eigen::Vector3d& x_in_frame_mm,
                   double* value,
                   Eigen::Vector3d* gradient_mm) const {
  Eigen::Vector3d gradient_ijk;
  if (!SampleAtIndex(ToIndex(x_in_frame_mm), value,
                     gradient_mm != nullptr ? &gradient_ijk : nullptr)) {
    return false;
  }
  if (gradient_mm != nullptr) *gradient_mm = gradient_to_physical_ * gradient_ijk;
  return true;
}

double Frame::InterpolateValue(const Eigen::Vector3d& ijk) const {
  const Eigen::Vector3i& n = geometry_.size;
  if (!ijk.allFinite()) return 0.0;
  double acc = 0.0;
  const double fl[3] = {std::floor(ijk[0]), std::floor(ijk[1]), std::floor(ijk[2])};
  for (int c = 0; c < 8; ++c) {
    const int d[3] = {c & 1, (c >> 1) & 1, (c >> 2) & 1};
    double w = 1.0;
    int idx[3];
    bool inside = true;
    for (int a = 0; a < 3; ++a) {
      const double corner = fl[a] + d[a];
      const double f = ijk[a] - fl[a];
      w *= d[a] ? f : 1.0 - f;
      inside = inside && corner >= 0.0 && corner <= n[a] - 1;
      idx[a] = inside ? static_cast<int>(corner) : 0;
    }
    if (inside && w != 0.0) acc += w * values()[geometry_.LinearIndex(idx[0], idx[1], idx[2])];
  }
  return acc;
}

std::vector<uint8_t> Frame::DilatedValidCells(int margin) const {
  const int64_t num = geometry_.NumVoxels();
  std::vector<uint8_t> map(static_cast<size_t>(num));
  for (int64_t l = 0; l < num; ++l) map[l] = IsValidCell(l) ? 1 : 0;
  if (margin > 0) {
    for (int axis = 0; axis < 3; ++axis) DilateAlongAxis(geometry_.size, axis, margin, &map);
  }
  return map;
}

}  // namespace dsr
