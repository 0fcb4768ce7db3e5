// dsr_fuse: the panorama of registered frames (paper eq. 10, or a feathered blend) on the
// shared panorama grid, and the field-of-view enlargement ratio the paper reports.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>

#include <gflags/gflags.h>
#include <glog/logging.h>

#include "dsr/image/frame.h"
#include "dsr/io/io_frames.h"
#include "dsr/io/io_image.h"
#include "dsr/io/io_poses.h"
#include "dsr/model/observation.h"
#include "dsr/model/panorama.h"
#include "dsr/app/output_plan.h"
#include "dsr/tools/flags.h"
#include "dsr/tools/tool_util.h"
#include "dsr/util/parallel.h"


namespace {

std::string Number(double value) {
  std::ostringstream s;
  s << value;
  return s.str();
}

int Main(int argc, char** argv) {
  dsr::InitTool(
      "fuses registered frames into one panorama and prints the field-of-view enlargement.\n"
      "  dsr_fuse --images=a.nii.gz,b.nii.gz,... --poses=poses.json --out=panorama.nii.gz\n"
      "      [--masks=...] [--blend=mean|feather] [--panorama_spacing=1]\n"
      "Exit status: 0 ok, 2 bad input, 1 a write failed.",
      dsr::kDsrFuse, {"images", "poses", "out"}, &argc, &argv);
  using dsr::Fail;
  std::string error;
  std::vector<std::string> image_paths, mask_paths;
  if (!dsr::FrameFilesFrom(dsr::ToolSettings(), 1, &image_paths, &mask_paths, &error)) return Fail(error);
  const int m = static_cast<int>(image_paths.size());
  for (const auto& [flag, path] : {std::pair<std::string, std::string>{"out", dsr::StringFlag("out")},
                                   {"out_count", dsr::StringFlag("out_count")}}) {
    if (!path.empty() && !dsr::HasSupportedImageExtension(path)) {
      return Fail("--" + flag + "=" + path + ": unsupported extension (.nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr)");
    }
  }
  // Every file this run reads and writes, before anything is read.
  dsr::OutputPlan plan;
  plan.AddFrameInputs(image_paths, mask_paths, dsr::StringFlag("images"), dsr::StringFlag("masks"));
  plan.AddInputFile("poses", dsr::StringFlag("poses"));
  plan.AddOutputImage("out", dsr::StringFlag("out"));
  plan.AddOutputImage("out_count", dsr::StringFlag("out_count"));
  if (!plan.Check(&error)) return Fail(error);
  dsr::PosesFile poses;
  if (!dsr::ReadPoses(dsr::StringFlag("poses"), m, &poses, &error)) return Fail("--poses: " + error);
  std::vector<dsr::Image> images;
  std::vector<dsr::Mask> masks;
  std::vector<dsr::MaskRule> mask_rules;
  const dsr::FieldOfViewOptions field_of_view = dsr::ToolConfig().field_of_view;
  if (!dsr::ReadFrames(image_paths, mask_paths, field_of_view, dsr::IntFlag("num_threads"), &images, &masks,
                       &mask_rules, &error)) {
    return Fail(error);
  }
  // After the frames, so that a broken frame is reported as such first.
  if (!dsr::MatchPosesToImages("poses", dsr::StringFlag("poses"), image_paths, &poses, &error)) return Fail(error);
  std::vector<dsr::Frame> frames;
  std::vector<Eigen::Isometry3d> frame_from_world;
  dsr::ImageGeometry grid;
  if (!dsr::PrepareFusion(images, masks, image_paths, poses.frame_from_world,
                          dsr::DoubleFlag("panorama_spacing"), dsr::IntFlag("num_threads"), &frames, &frame_from_world,
                          &grid, &error)) {
    return Fail(error);
  }
  // The mean (float) and k_j (uint8); writing adds a float copy and ITK's image of each
  // output, one at a time, and --out_count a float image of k_j.
  const double bytes_per_voxel = 5.0 + 8.0 + (dsr::StringFlag("out_count").empty() ? 0.0 : 4.0);
  if (!dsr::CheckMemoryEstimate(
          "--panorama_spacing=" + Number(dsr::DoubleFlag("panorama_spacing")),
          bytes_per_voxel * static_cast<double>(grid.NumVoxels()),
          "a panorama of " + std::to_string(grid.size[0]) + "x" + std::to_string(grid.size[1]) +
              "x" + std::to_string(grid.size[2]) + " voxels",
          &error)) {
    return Fail(error);
  }
  // The file's gains and offsets (re-gauged to frame 0 by MatchPosesToImages), if any.
  const std::vector<dsr::Photometric> photometric = dsr::PhotometricFromPoses(poses);
  const dsr::PanoramaImages fused =
      dsr::FusePanorama(frames, frame_from_world, grid, dsr::ToolConfig().feather, dsr::DoubleFlag("feather_voxels"),
                        dsr::IntFlag("num_threads"), photometric);
  if (!dsr::WriteImage(fused.mean, dsr::StringFlag("out"), &error)) return Fail(error, dsr::kExitFailed);
  if (!dsr::StringFlag("out_count").empty()) {
    dsr::Image count(grid, 0.0f);
    std::copy(fused.count.voxels.begin(), fused.count.voxels.end(), count.voxels.begin());
    if (!dsr::WriteImage(count, dsr::StringFlag("out_count"), &error)) return Fail(error, dsr::kExitFailed);
  }
  std::printf("dsr_fuse: %d frames, %s blend%s, panorama %dx%dx%d voxels of %.3gx%.3gx%.3g mm; "
              "field-of-view enlargement %.3f (%lld voxels seen / %lld in frame 0's field of view)"
              "; wrote %s\n",
              m, dsr::StringFlag("blend").c_str(),
              photometric.empty() ? "" : " of intensities corrected by --poses' gain and offset",
              grid.size[0], grid.size[1], grid.size[2], grid.spacing_mm[0],
              grid.spacing_mm[1], grid.spacing_mm[2], fused.EnlargementRatio(),
              static_cast<long long>(fused.seen_voxels), static_cast<long long>(fused.frame0_voxels),
              dsr::StringFlag("out").c_str());
  std::printf("dsr_fuse: %s\n",
              dsr::FieldOfViewSummary(mask_rules, field_of_view.mask_rule).c_str());
  return EXIT_SUCCESS;
}

}  // namespace

int main(int argc, char** argv) { return dsr::RunToolMain(argc, argv, &Main); }
