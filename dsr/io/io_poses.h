// Poses file IO (docs/design.md section 1):
//   {"frames": [{"image": "frame_00.nii.gz", "T": [[r00,r01,r02,tx],[..],[..],[0,0,0,1]]}, ...]}
// T is frame_from_world (world -> frame physical mm, LPS), row-major 4x4. Extra keys are
// allowed and ignored on read (e.g. "world", "method"), so other tools can annotate the file.
// Optional per-frame fields written with a pose uncertainty (pipeline/uncertainty.h,
// docs/design.md section 8.6): "covariance", 6x6 row-major, of the tangent [rho (mm);
// phi (rad)] of T_est = Exp(delta) T (frame 0, the gauge, all zero), and
// "predicted_tre_mm", the expected mean TRE over the frame's field of view. Read ignores
// them.
// Optional per-frame intensity corrections, each on every frame or on none: "gain" (> 0)
// and "offset" (grey levels), such that frame i's corrected observation
// gain_i * I_i + offset_i is on frame 0's intensity scale (frame 0, the gauge: 1 and 0).
// dsr_simulate writes the ground truth (sim/simulate.h, Frame0IntensityCorrections). Read
// fills them; tools that do not use them ignore them.
#ifndef DSR_IO_IO_POSES_H_
#define DSR_IO_IO_POSES_H_

#include <string>
#include <vector>

#include <Eigen/Geometry>

namespace dsr {

struct PosesFile {
  std::vector<std::string> images;                     // as written in the file
  std::vector<Eigen::Isometry3d> frame_from_world;     // one per frame
  // Written when not empty (then one per frame); not filled by ReadPoses.
  std::vector<Eigen::Matrix<double, 6, 6>> covariance;
  std::vector<double> predicted_tre_mm;
  // Read and written when present: empty, or one per frame (gain > 0 and finite, offset
  // finite).
  std::vector<double> gain;
  std::vector<double> offset;
};

// Tolerance on |R^T R - I| and |det R - 1| and on the last row [0 0 0 1].
constexpr double kRigidTolerance = 1e-5;

// Reads and validates a poses file. `expected_frames` < 0 accepts any count >= 1; otherwise
// the count must match. Errors name the file, the frame and the broken rule (not JSON, no
// "frames" array, T not 4x4 numbers, non-finite entry, not rigid beyond kRigidTolerance,
// wrong frame count, "gain" or "offset" not a finite number, a gain <= 0, "gain" or
// "offset" on some frames but not on others). A rotation not orthonormal to double
// precision (|R^T R - I| > 1e-14) is projected to the nearest rotation; others are kept bit
// for bit, so that WritePoses followed by ReadPoses returns exactly the poses written (and
// the gains and offsets).
bool ReadPoses(const std::string& path,
               int expected_frames,
               PosesFile* poses,
               std::string* error);

// A pose from its 4x4 matrix with ReadPoses' rules: every entry finite, rigid within
// kRigidTolerance (else false with `error` = where + the broken rule, e.g. "pose 1: T is
// not rigid (det R = -1, a reflection; expected 1)"), a rotation not orthonormal to double
// precision projected to the nearest rotation. For poses that do not come from a file.
bool PoseFromMatrix(const Eigen::Matrix4d& m, const std::string& where,
                    Eigen::Isometry3d* pose, std::string* error);

// Serialises to the JSON text above, indented by 2, each number with the fewest digits
// (at most 17) that parse back to the same double: the round trip is exact. `images` is
// either empty (names written as "") or has one name per pose.
std::string PosesToJson(const PosesFile& poses);

// Writes atomically (temp file + rename). Refuses (naming the file and the frame) a
// non-finite T, covariance, predicted_tre_mm, gain or offset, and a gain <= 0.
bool WritePoses(const PosesFile& poses, const std::string& path, std::string* error);

}  // namespace dsr

#endif  // DSR_IO_IO_POSES_H_
