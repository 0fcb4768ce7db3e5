// A frame prepared for sampling (docs/design.md section 2).
//
// Sampling at a physical point x (mm, frame coordinates): u = (D S)^-1 (x - o); the value
// I(u) by trilinear interpolation of the voxels, and the gradient by trilinear
// interpolation of the corners' central differences (index units), converted to
// physical units: grad_x I = (D S)^-T grad_u I (= D S^-1 grad_u I for an orthonormal D).
//
// The gradient rule, one for every mode (all of them sample through this class or its
// raw values): no gradient reads a voxel outside the field-of-view mask.
//  * Stencil voxels: inside the mask with all 6 neighbours inside the mask (the grid border
//    counts as outside), i.e. the mask eroded by the 6-neighbourhood. Only they carry a
//    gradient, the central difference g_a(l) = (I(l + e_a) - I(l - e_a)) / 2; all other
//    voxels store 0, which no valid sample reads.
//  * The sample is valid (sigma_ij = 1) when all 8 trilinear neighbours of u are stencil
//    voxels.
// Why: at the mask border a central difference would read the background (0 in volumes
// exported with their field of view), and a Gauss-Newton fixed point with such Jacobians
// is not the minimiser of the cost: every frame ends offset the same way. Differences
// kept inside the mask by going one-sided at its border are biased as well: such a g(l)
// involves the noise of I(l) itself, which the sample's value shares, so J^T r has a
// non-zero mean along the border normal. Interpolated central differences are
// uncorrelated with the interpolated value at every u (in 1D, value (1-w) I0 + w I1,
// gradient (1-w)(I1 - I-1)/2 + w(I2 - I0)/2: covariance -(1-w)w/2 + w(1-w)/2 = 0). The
// exact slope of the trilinear interpolant (piecewise constant) measured worse than
// either. The price is the outermost voxel layer of the mask, in which no valid cell has
// a corner.
//
// Memory layout: the voxel values of each phase, x-fastest, 4 bytes per voxel (a frame
// borrows its images' storage or holds one copy), plus one bit per voxel for the
// valid-cell map (cell (i,j,k) is valid when its 8 corners (i..i+1, j..j+1, k..k+1) are
// stencil voxels; bit l % 8 of byte l / 8 for linear index l). The central differences are
// formed where a sample reads them (CornerSample below), in float as a stored gradient
// volume would hold them, so a sample is the same, bit for bit, as one from such a volume:
// 4.125 bytes per voxel instead of 16.125, and a sample's 32 voxels (the cell's 8 corners
// and their 24 outer neighbours) are 12 rows of 4 floats. The bit map (0.8 MB for 6M
// voxels) stays in cache where a byte map would not.
#ifndef DSR_IMAGE_FRAME_H_
#define DSR_IMAGE_FRAME_H_

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "dsr/geometry/volume.h"

namespace dsr {

// The value and the 3 central differences [I, gu, gv, gw] at the stencil voxel `v` points
// to (x-fastest values, strides `sy` and `sz` in voxels), in float: the one formula every
// sampler (the Frame's own, the stream's portable and SIMD ones) takes a corner from.
inline void CornerSample(const float* v, int64_t sy, int64_t sz, float out[4]) {
  out[0] = v[0];
  out[1] = 0.5f * (v[1] - v[-1]);
  out[2] = 0.5f * (v[sy] - v[-sy]);
  out[3] = 0.5f * (v[sz] - v[-sz]);
}

class Frame {
 public:
  Frame() = default;
  // `mask` must lie on `image`'s grid (CHECKed; validate user input with ReadMask first).
  Frame(const Image& image, const Mask& mask);
  // A view recorded over T = phases.size() >= 1 phases (an ECG-gated loop; docs/design.md
  // section 12): one grid, one mask and so one valid-cell map, one volume of values per
  // phase. Every phase must lie on the mask's grid (CHECKed). One phase is the frame above.
  Frame(const std::vector<Image>& phases, const Mask& mask);
  // The same from the phases' images held elsewhere (non-null, in phase order).
  Frame(const std::vector<const Image*>& phases, const Mask& mask);
  // A frame that reads the phases' voxels where they are, copying none (4 bytes per voxel
  // and phase saved): `phase0` and `later_phases` must outlive the frame and every copy of
  // it, unchanged. For frames a function builds from its inputs and drops before it returns.
  static Frame Borrowing(const Image& phase0, const std::vector<Image>& later_phases,
                         const Mask& mask);
  // A view given as its phase 0 and its later phases (empty: a 3D frame), as the pipeline
  // and the front ends hold them.
  Frame(const Image& phase0, const std::vector<Image>& later_phases, const Mask& mask);
  // Number of phases (1 for a 3D frame). values() and the sampling functions read
  // phase 0; Phase(p) gives phase p as a one-phase frame.
  int num_phases() const { return 1 + static_cast<int>(more_phases_.size()); }
  // Phase `phase` (in [0, num_phases())) as a one-phase frame sharing this one's data and
  // geometry (cheap: no voxel is copied; borrowed values stay borrowed).
  Frame Phase(int phase) const;

  const ImageGeometry& geometry() const { return geometry_; }
  int64_t num_valid_cells() const { return num_valid_cells_; }
  // The same frame with its physical coordinates moved by `shift` (origin + shift), its data
  // shared: the pipeline's local frames (docs/design.md 1.2).
  Frame Translated(const Eigen::Vector3d& shift) const {
    Frame moved = *this;
    moved.geometry_.origin_mm += shift;
    return moved;
  }

  // Continuous index of a physical point (frame coordinates, mm).
  Eigen::Vector3d ToIndex(const Eigen::Vector3d& x_in_frame_mm) const {
    return index_from_physical_ * (x_in_frame_mm - geometry_.origin_mm);
  }
  // (D S)^-1 and (D S)^-T, for callers that fold a pose into the index map.
  const Eigen::Matrix3d& index_from_physical() const { return index_from_physical_; }
  const Eigen::Matrix3d& gradient_to_physical() const { return gradient_to_physical_; }

  // True when the trilinear cell of continuous index `ijk` is valid (sigma = 1: its 8
  // corners are stencil voxels, see above).
  bool IsValidIndex(const Eigen::Vector3d& ijk) const;

  // Samples at a physical point. Returns false (sigma = 0) and leaves outputs untouched
  // when the sample is not valid. `gradient_mm` may be null.
  bool Sample(const Eigen::Vector3d& x_in_frame_mm,
              double* value,
              Eigen::Vector3d* gradient_mm) const;

  // Same at a continuous index; the gradient is in index units (d/du).
  bool SampleAtIndex(const Eigen::Vector3d& ijk,
                     double* value,
                     Eigen::Vector3d* gradient_ijk) const;

  // SampleAtIndex's value and gradient (bit for bit), and the slopes of both interpolants
  // inside the sample's cell, in index units: value_slope[a] = d value / d u_a (the exact
  // derivative of the trilinear value, not the interpolated central differences) and
  // gradient_slope(q, a) = d gradient_q / d u_a. For the pose uncertainty's curvature
  // (pipeline/uncertainty.h), which differentiates the gradient of the cost.
  bool SampleSlopesAtIndex(const Eigen::Vector3d& ijk,
                           double* value,
                           Eigen::Vector3d* gradient_ijk,
                           Eigen::Vector3d* value_slope,
                           Eigen::Matrix3d* gradient_slope) const;

  // Trilinear value without the mask rule, 0 outside the grid: for resampling and display.
  double InterpolateValue(const Eigen::Vector3d& ijk) const;

  // True when the cell at linear index `l` (its lowest corner) is valid.
  bool IsValidCell(int64_t l) const { return (valid_bits()[l >> 3] >> (l & 7)) & 1; }

  // Valid-cell map dilated by `margin` cells (box of half-width `margin`), one byte per
  // voxel: used to build candidate observations with a margin (model/observation.h).
  std::vector<uint8_t> DilatedValidCells(int margin) const;

  // Bounding box (continuous index) of the valid cells: [min cell, max cell + 1]; empty
  // when no cell is valid.
  const Eigen::AlignedBox3d& ValidIndexBox() const { return valid_index_box_; }
  // The centre of that box in the frame's physical coordinates (mm).
  Eigen::Vector3d ValidCentre() const {
    return geometry_.IndexToPhysical(valid_index_box_.center());
  }

  // Phase 0's voxel values (x-fastest) and the valid-cell bit map (see above; one spare
  // zero byte at the end), for fast paths.
  const float* values() const { return values_.get(); }
  const uint8_t* valid_bits() const { return valid_bits_ ? valid_bits_->data() : nullptr; }

 private:
  Frame(const std::vector<const Image*>& phases, const Mask& mask, bool borrow);
  ImageGeometry geometry_;
  Eigen::Matrix3d index_from_physical_ = Eigen::Matrix3d::Identity();
  Eigen::Matrix3d gradient_to_physical_ = Eigen::Matrix3d::Identity();
  // Shared and immutable: copying a Frame (e.g. into a two-frame sub-problem) is cheap.
  // Phase 0's values: owned (shared among copies) or borrowed (no owner).
  std::shared_ptr<const float> values_;
  std::shared_ptr<const std::vector<uint8_t>> valid_bits_;
  // Phases 1..T-1's values (phase 0's are values_); empty for a 3D frame.
  std::vector<std::shared_ptr<const float>> more_phases_;
  int64_t num_valid_cells_ = 0;
  Eigen::AlignedBox3d valid_index_box_;
};

// View `view`'s later phases in a [view][phase - 1] set (docs/design.md section 12); none
// (an empty vector) when the set is null or empty: 3D views.
const std::vector<Image>& LaterPhasesOf(const std::vector<std::vector<Image>>* later_phases,
                                        size_t view);

// The frames' common number of phases (CHECKed equal; 1 for none): a registration's views
// all have the same phases, aligned by index.
int NumPhases(const std::vector<Frame>& frames);

// Every frame's phase `phase` (Frame::Phase): the one-phase frames of that phase, the
// problem the theorem eliminates phase by phase.
std::vector<Frame> PhaseFrames(const std::vector<Frame>& frames, int phase);

// Every phase's one-phase frames, kept where problems that point to them can find them for
// their lifetime: for a 3D sequence (one phase) the given vector itself, nothing copied.
// `frames` must outlive this object.
class FramesByPhase {
 public:
  explicit FramesByPhase(const std::vector<Frame>& frames);
  int size() const { return static_cast<int>(phases_.size()); }
  const std::vector<Frame>& operator[](int phase) const { return *phases_[phase]; }

 private:
  std::vector<std::unique_ptr<const std::vector<Frame>>> owned_;
  std::vector<const std::vector<Frame>*> phases_;
};

}  // namespace dsr

#endif  // DSR_IMAGE_FRAME_H_
