// dsr_fuse: the panorama of registered frames (paper eq. 10, or a feathered blend) on the
// shared panorama grid, and the field-of-view enlargement ratio the paper reports.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <set>

#include <gflags/gflags.h>
#include <glog/logging.h>

#include "core/frame.h"
#include "core/io_image.h"
#include "core/io_poses.h"
#include "core/observation.h"
#include "core/panorama.h"
#include "core/parallel.h"
#include "tools/tool_util.h"

DEFINE_string(images, "", "Comma-separated frame images, frame 0 first (as registered). Required.");
DEFINE_string(masks, "", "Comma-separated field-of-view masks, one per image; empty: each "
              "image's non-zero voxels eroded by --mask_erosion voxels.");
DEFINE_int32(mask_erosion, 1, "Erosion (voxels) of the non-zero region when no --masks are "
             "given, in [0, 50].");
DEFINE_string(poses, "", "Poses JSON (dsr_register --out_poses), one entry per image. Required.");
DEFINE_string(out, "", "Output panorama image (.nii, .nii.gz, .mha, .nrrd). Required.");
DEFINE_string(blend, "mean", "mean (paper eq. 10: per-voxel mean of the observations) or "
              "feather (weights fall off towards each field-of-view edge, so seams vanish).");
DEFINE_double(feather_voxels, 8.0, "--blend=feather: depth (frame voxels) over which a frame's "
              "weight rises from 0 at its field-of-view edge to 1, > 0.");
DEFINE_double(panorama_spacing, 1.0, "Panorama spacing as a multiple of frame 0's spacing, > 0.");
DEFINE_string(out_count, "", "Optional output image of k_j, the number of frames observing "
              "each panorama voxel.");
DEFINE_int32(num_threads, 0, "Threads, 0 = all hardware threads.");

int main(int argc, char** argv) {
  dsr::InitTool(
      "fuses registered frames into one panorama and prints the field-of-view enlargement.\n"
      "  dsr_fuse --images=a.nii.gz,b.nii.gz,... --poses=poses.json --out=panorama.nii.gz\n"
      "      [--masks=...] [--blend=mean|feather] [--panorama_spacing=1]\n"
      "Exit status: 0 ok, 2 bad input, 1 a write failed.",
      {"images", "poses", "out"}, &argc, &argv);
  using dsr::Fail;
  std::string error;
  if (FLAGS_blend != "mean" && FLAGS_blend != "feather") {
    return Fail("--blend=" + FLAGS_blend + ": must be mean or feather");
  }
  if (!(FLAGS_feather_voxels > 0.0) || !std::isfinite(FLAGS_feather_voxels)) {
    return Fail("--feather_voxels=" + std::to_string(FLAGS_feather_voxels) + ": must be > 0");
  }
  if (!(FLAGS_panorama_spacing > 0.0) || !std::isfinite(FLAGS_panorama_spacing)) {
    return Fail("--panorama_spacing=" + std::to_string(FLAGS_panorama_spacing) + ": must be > 0");
  }
  if (FLAGS_mask_erosion < 0 || FLAGS_mask_erosion > 50) {
    return Fail("--mask_erosion=" + std::to_string(FLAGS_mask_erosion) + ": must be in [0, 50]");
  }
  if (FLAGS_num_threads < 0) return Fail("--num_threads: must be >= 0");
  const std::vector<std::string> image_paths = dsr::SplitCommaList(FLAGS_images);
  const std::vector<std::string> mask_paths = dsr::SplitCommaList(FLAGS_masks);
  const int m = static_cast<int>(image_paths.size());
  if (m < 1) return Fail("--images: no image given");
  if (!mask_paths.empty() && static_cast<int>(mask_paths.size()) != m) {
    return Fail("--masks: " + std::to_string(mask_paths.size()) + " masks for " +
                std::to_string(m) + " images");
  }
  std::vector<std::string> inputs;
  std::set<std::string> unique;
  for (const std::string& p : image_paths) {
    if (!unique.insert(dsr::CanonicalPath(p)).second) return Fail("--images: " + p + " is given twice");
    inputs.push_back(dsr::CanonicalPath(p));
  }
  for (const std::string& p : mask_paths) inputs.push_back(dsr::CanonicalPath(p));
  inputs.push_back(dsr::CanonicalPath(FLAGS_poses));
  for (const auto& [flag, path] : {std::pair<std::string, std::string>{"out", FLAGS_out},
                                   {"out_count", FLAGS_out_count}}) {
    if (!dsr::CheckOutputFile(flag, path, inputs, &error)) return Fail(error);
    if (!path.empty() && !dsr::HasSupportedImageExtension(path)) {
      return Fail("--" + flag + "=" + path + ": unsupported extension (.nii, .nii.gz, .mha, .mhd, .nrrd, .nhdr)");
    }
  }
  if (FLAGS_out == FLAGS_out_count) return Fail("--out_count=" + FLAGS_out_count + ": same file as --out");
  dsr::PosesFile poses;
  if (!dsr::ReadPoses(FLAGS_poses, m, &poses, &error)) return Fail("--poses: " + error);
  std::vector<dsr::Image> images;
  std::vector<dsr::Mask> masks;
  if (!dsr::ReadFrames(image_paths, mask_paths, FLAGS_mask_erosion, FLAGS_num_threads, &images,
                       &masks, &error)) {
    return Fail(error);
  }
  std::vector<dsr::Frame> frames(m);
  dsr::ParallelFor(0, m, FLAGS_num_threads, [&](int64_t i) { frames[i] = dsr::Frame(images[i], masks[i]); });
  for (int i = 0; i < m; ++i) {
    if (frames[i].num_valid_cells() == 0) {
      return Fail(image_paths[i] + ": no valid voxel in the field of view (the mask is too small)");
    }
  }
  const std::vector<Eigen::Isometry3d> frame_from_world = dsr::RelativeToFrame0(poses.frame_from_world);
  dsr::ImageGeometry grid;
  if (!dsr::BuildPanoramaGrid(frames, frame_from_world, FLAGS_panorama_spacing, &grid, &error)) {
    return Fail(error);
  }
  const dsr::PanoramaImages fused =
      FLAGS_blend == "feather"
          ? dsr::FusePanoramaFeather(frames, frame_from_world, grid, FLAGS_feather_voxels, FLAGS_num_threads)
          : dsr::FusePanoramaMean(frames, frame_from_world, grid, FLAGS_num_threads);
  if (!dsr::WriteImage(fused.mean, FLAGS_out, &error)) return Fail(error, dsr::kExitFailed);
  if (!FLAGS_out_count.empty() && !dsr::WriteMask(fused.count, FLAGS_out_count, &error)) {
    return Fail(error, dsr::kExitFailed);
  }
  std::printf("dsr_fuse: %d frames, %s blend, panorama %dx%dx%d voxels of %.3gx%.3gx%.3g mm; "
              "field-of-view enlargement %.3f (%lld voxels seen / %lld in frame 0's field of view)"
              "; wrote %s\n",
              m, FLAGS_blend.c_str(), grid.size[0], grid.size[1], grid.size[2], grid.spacing_mm[0],
              grid.spacing_mm[1], grid.spacing_mm[2], fused.EnlargementRatio(),
              static_cast<long long>(fused.seen_voxels), static_cast<long long>(fused.frame0_voxels),
              FLAGS_out.c_str());
  return EXIT_SUCCESS;
}
