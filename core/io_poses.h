// Poses file IO (DESIGN.md section 1):
//   {"frames": [{"image": "frame_00.nii.gz", "T": [[r00,r01,r02,tx],[..],[..],[0,0,0,1]]}, ...]}
// T is frame_from_world (world -> frame physical mm, LPS), row-major 4x4. Extra keys are
// allowed and ignored on read (e.g. "world", "method"), so other tools can annotate the file.
#ifndef DSR_CORE_IO_POSES_H_
#define DSR_CORE_IO_POSES_H_

#include <string>
#include <vector>

#include <Eigen/Geometry>

namespace dsr {

struct PosesFile {
  std::vector<std::string> images;                     // as written in the file
  std::vector<Eigen::Isometry3d> frame_from_world;     // one per frame
};

// Tolerance on |R^T R - I| and |det R - 1| and on the last row [0 0 0 1].
constexpr double kRigidTolerance = 1e-5;

// Reads and validates a poses file. `expected_frames` < 0 accepts any count >= 1; otherwise
// the count must match. Errors name the file, the frame and the broken rule (not JSON, no
// "frames" array, T not 4x4 numbers, non-finite entry, not rigid beyond kRigidTolerance,
// wrong frame count). Rotations are re-orthonormalised to double precision.
bool ReadPoses(const std::string& path,
               int expected_frames,
               PosesFile* poses,
               std::string* error);

// Serialises to the JSON text above (17 significant digits, exact round trip).
std::string PosesToJson(const PosesFile& poses);

// Writes atomically (temp file + rename).
bool WritePoses(const PosesFile& poses, const std::string& path, std::string* error);

}  // namespace dsr

#endif  // DSR_CORE_IO_POSES_H_
