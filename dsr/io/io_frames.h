// A registration's input frames from files: each image with its mask, read in parallel.
#ifndef DSR_IO_IO_FRAMES_H_
#define DSR_IO_IO_FRAMES_H_

#include <string>
#include <vector>

#include "dsr/geometry/field_of_view.h"
#include "dsr/geometry/volume.h"

namespace dsr {

// The mask of an image given without one, by `field_of_view`'s rule and erosion
// (FieldOfViewFromImage); `used` (optional) the rule that built it (the non-zero rule where
// no hull fits). False, with an error naming `name`, when no voxel is left.
bool MaskFromImage(const Image& image,
                   const FieldOfViewOptions& field_of_view,
                   const std::string& name,
                   Mask* mask,
                   MaskRule* used,
                   std::string* error);

// Reads frames in parallel (decompression dominates) with their masks: `mask_paths` one per
// image, or empty for each image's mask by `field_of_view` (MaskFromImage). `mask_rules`
// (optional): without mask files, the rule that built each frame's mask; with them, empty.
// The first failing frame in input order is reported (one line naming the file).
// With `later_phases` (views recorded over the heart cycle, docs/design.md section 12), each
// image is a view (ReadView: a 3D or 4D file, or 3D files joined by ';'): images[i] its
// phase 0, (*later_phases)[i] its phases 1..T-1; a mask may then be 4D with equal phases
// (ReadMaskPhases), and a mask built from the image is phase 0's. Without it a 4D image is
// refused as ReadImage refuses it. `phases` (views only; empty: all) are the phases each
// view reads, in that order (ReadView): phase phases[0] becomes images[i], the others its
// later phases, and no other phase is read.
bool ReadFrames(const std::vector<std::string>& image_paths,
                const std::vector<std::string>& mask_paths,
                const FieldOfViewOptions& field_of_view,
                int num_threads,
                std::vector<Image>* images,
                std::vector<Mask>* masks,
                std::vector<MaskRule>* mask_rules,
                std::string* error,
                std::vector<std::vector<Image>>* later_phases = nullptr,
                const std::vector<int>& phases = {});

}  // namespace dsr

#endif  // DSR_IO_IO_FRAMES_H_
