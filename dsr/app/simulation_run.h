// A simulation run as every front end makes it (dsr_simulate, dsr.simulate, dsr_compare):
// the source (the built-in phantom or a file) with the memory the run will need checked
// before any of it is allocated, the sequence, and the files it is written to.
#ifndef DSR_APP_SIMULATION_RUN_H_
#define DSR_APP_SIMULATION_RUN_H_

#include <string>

#include "dsr/app/output_plan.h"
#include "dsr/geometry/volume.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"

namespace dsr {

// The names of frame f's files in a sequence folder: "frame_03.nii.gz", "mask_03.nii.gz".
std::string SimulatedFrameName(int f);
std::string SimulatedMaskName(int f);

// For clear cases, before any work: true when the simulation of `options` from a source on the grid
// `source` fits in the memory this process can allocate (CheckMemoryEstimate): the frames (float;
// num_phases per view) and masks (uint8), the field of view and one frame's copies while it is
// written, the source, and the effects' scratch: the attenuation (double) and the speckle's three
// complex double grids, padded by 3 speckle_correlation_voxels per side, its sum (double) and its
// field (float); with speckle_world_fraction also every frame's field (float) and one look's world
// field (complex double on the world grid padded likewise: at most the source's axis-aligned box in
// frame voxels). With the echo intensity mapping the source's map adds, at its peak, 13 bytes per
// source voxel. A grid without voxels (a source not read yet) checks the frames alone. Otherwise
// false with `error` naming --frame_size and --num_frames.
bool CheckSimulationMemory(const SimulationOptions& options, const ImageGeometry& source,
                           std::string* error);

// The source of a simulation: `source_path` read (checked against CheckSimulationMemory once
// its grid is known), or, when empty, the built-in phantom of `phantom` (checked before it
// is made). False with a one-line `error` ("--source: ...", or the memory estimate's).
bool LoadSimulationSource(const SimulationOptions& options, const PhantomOptions& phantom,
                          const std::string& source_path, Image* source, std::string* error);

// The files a sequence of `num_frames` views of `num_phases` phases writes into `folder`
// (--out_dir): frames (one per view; with num_phases > 1 a 4D image of its phases), masks
// (one per view), gt_poses.json and, with `write_source`, source.nii.gz.
void PlanSequenceFiles(const std::string& folder, int num_frames, int num_phases,
                       bool write_source, OutputPlan* plan);

// Writes the sequence into `folder` (PlanSequenceFiles' names; each file atomically, the
// ground truth last) with, when the options have brightness changes, each frame's "gain"
// and "offset" in gt_poses.json. A beating sequence (num_phases() > 1) writes view i as one
// 4D NIfTI of its phases (io/io_phases.h), with the view's pose (all its phases share it).
// False with `error` naming the file.
bool WriteSequence(const std::string& folder, const SimulationOptions& options,
                   const SimulatedSequence& sequence, const Image* source, std::string* error);

}  // namespace dsr

#endif  // DSR_APP_SIMULATION_RUN_H_
