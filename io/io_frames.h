// A registration's input frames from files: each image with its mask, read in parallel.
#ifndef DSR_IO_IO_FRAMES_H_
#define DSR_IO_IO_FRAMES_H_

#include <string>
#include <vector>

#include "dsr/geometry/volume.h"

namespace dsr {

// The mask of an image given without one: its non-zero voxels eroded by `mask_erosion`
// voxels (MaskFromNonZero). False, with an error naming `name`, when no voxel is left.
bool MaskFromImage(const Image& image,
                   int mask_erosion,
                   const std::string& name,
                   Mask* mask,
                   std::string* error);

// Reads frames in parallel (decompression dominates) with their masks: `mask_paths` one per
// image, or empty for each image's non-zero voxels eroded by `mask_erosion` voxels
// (MaskFromNonZero). The first failing frame in input order is reported (one line naming
// the file).
bool ReadFrames(const std::vector<std::string>& image_paths,
                const std::vector<std::string>& mask_paths,
                int mask_erosion,
                int num_threads,
                std::vector<Image>* images,
                std::vector<Mask>* masks,
                std::string* error);

}  // namespace dsr

#endif  // DSR_IO_IO_FRAMES_H_
