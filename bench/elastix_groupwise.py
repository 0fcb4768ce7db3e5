#!/usr/bin/env python3
"""elastix groupwise rigid baseline for ONE sequence folder written by dsr_simulate.

Stacks the frames (frame_00 .. frame_NN) into one 4D image, registers it with elastix's
groupwise rigid registration (EulerStackTransform + VarianceOverLastDimensionMetric, the
same 4D image as fixed and moving image), converts elastix's per-frame Euler transforms
into dsr poses (frame_from_world, world = frame 0; docs/design.md section 1), writes them
as a dsr poses file and measures them against the folder's gt_poses.json exactly as dsr
does (eval/eval.cc, ComparePoses). Prints one CSV row with dsr_compare's results.csv
columns (method "elastix"); columns elastix has no equivalent for are left empty.

Usage (from the repository root; the venv has numpy and SimpleITK):
  .venv/bin/python bench/elastix_groupwise.py SEQUENCE_DIR --masks=fov|none
      [--work_dir=DIR] [--out_poses=FILE] [--header] [--threads=N]
      [--iterations=N] [--samples=N] [--keep_images]
  .venv/bin/python bench/elastix_groupwise.py SEQUENCE_DIR --masks=fov|none --eval_poses=FILE
      (no elastix: measures FILE, e.g. dsr_register's --out_poses, against gt_poses.json;
      prints the per-frame mean TRE on stderr and the CSV row on stdout)

Masks (the same field of view dsr registers and is measured with; TRE is taken over it):
  --masks=fov   the sequence's mask_XX images (dsr_compare --sequence_masks=true);
  --masks=none  each frame's non-zero voxels eroded by one voxel, computed exactly as dsr's
                MaskFromNonZero(frame, 1) (what dsr_register and dsr_compare
                --sequence_masks=false use without masks with --mask_rule=nonzero; their
                default is the convex hull of the non-zero voxels). Chosen over "no mask at all" so
                that elastix gets the same information as dsr: outside the field of view
                the frames are 0, and without a mask elastix would fit those zeros (the
                cone's edges) as if they were anatomy. dsr's TRE for "none" is measured
                over the same eroded masks, so the evaluation is the same as dsr's.
  Both masks are stacked like the frames and passed as -fMask (where samples are drawn)
  and -mMask (which frames a sample counts in: VarianceOverLastDimensionMetric drops the
  frames whose mask misses the mapped point); elastix erodes them on each pyramid level
  (ErodeMask, see the parameter file), while the TRE is measured over the masks as given.

Reference and gauge: elastix's reference space is the mean of the frames (SubtractMean);
the poses are re-expressed relative to frame 0 (T_i T_0^-1), as dsr's world is frame 0.
Starting poses: identity for every frame, as dsr's benchmark starts (--init=auto
starts from identity too, but recovers frames its checks flag; elastix has no such step).

Needs the `elastix` binary (Debian bookworm: apt-get install elastix, version 5.0.1).
elastix 5.0.1 seeds its random sampler with a fixed default seed: the same input gives
the same result. Time: about 35-70 s per 11-frame 96x96x80 sequence on the shared 2-core
machine with the defaults (3 levels x 1000 iterations x 2048 samples x 11 frames, both
cores); about 3 s of it is Python (reading, stacking, evaluation).
Exit status: 0 ok, 1 elastix failed or wrote no usable transform (the CSV row is still
printed with ok=0 and the failure), 2 bad input (one error line on stderr).
"""
import argparse
import json
import math
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
import SimpleITK as sitk

PROG = "elastix_groupwise.py"
IMAGE_EXTENSIONS = (".nii.gz", ".nii", ".mha", ".mhd", ".nrrd", ".nhdr")
CSV_COLUMNS = ("method,sequence,ok,mae_translation_voxels,mae_translation_mm,mae_rotation_rad,"
               "tre_mean_mm,tre_max_mm,iterations,seconds_per_iteration,"
               "intensity_differences_per_iteration,seconds,peak_memory_mb,added_memory_mb,"
               "failure,shared_offset_mm,shared_offset_x_mm,shared_offset_y_mm,"
               "shared_offset_z_mm,frame_spread_mm")
CONVENTION = "T maps world points to frame physical points (frame_from_world, LPS, mm)"
# Grids must agree like dsr's ImageGeometry::SameGrid (1e-4 mm, direction 1e-6).
GRID_TOLERANCE_MM = 1e-4
DIRECTION_TOLERANCE = 1e-6
# Debian's elastix 5.0.1 is compiled for 4D images of internal pixel type short only
# (ElastixTemplate<Image<short,4>>), so the 4D image is written as int16: intensities are
# scaled so that the largest |value| becomes this and rounded (quantisation step about
# 1/30000 of the range, far below the noise). The metric is a variance normalised by the
# initial variance, so the scale does not change the registration.
SHORT_RANGE = 30000.0


class InputError(Exception):
    """Bad input: one line on stderr, exit status 2."""


class Parser(argparse.ArgumentParser):
    def error(self, message):
        raise InputError(message)


# ----------------------------------------------------------------------------------------
# Sequence folder, images, masks
# ----------------------------------------------------------------------------------------

def has_image_extension(name):
    return any(name.endswith(e) for e in IMAGE_EXTENSIONS)


def list_sequence(folder, use_masks):
    if not os.path.isdir(folder):
        raise InputError(f"{folder}: not a folder (expected a dsr_simulate sequence folder)")
    names = sorted(os.listdir(folder))
    frames = [os.path.join(folder, n) for n in names
              if n.startswith("frame_") and has_image_extension(n)]
    masks = [os.path.join(folder, n) for n in names
             if n.startswith("mask_") and has_image_extension(n)]
    if len(frames) < 2:
        raise InputError(f"{folder}: expected at least 2 frame_XX images, found {len(frames)}")
    if use_masks and len(masks) != len(frames):
        raise InputError(f"{folder}: expected one mask_XX image per frame_XX image, found "
                         f"{len(frames)} frames and {len(masks)} masks (--masks=none "
                         "registers without them)")
    gt = os.path.join(folder, "gt_poses.json")
    if not os.path.isfile(gt):
        raise InputError(f"{folder}: no gt_poses.json (the ground truth to measure against)")
    return frames, (masks if use_masks else []), gt


def geometry(image):
    return {
        "size": tuple(image.GetSize()),
        "spacing": np.array(image.GetSpacing(), dtype=np.float64),
        "origin": np.array(image.GetOrigin(), dtype=np.float64),
        "direction": np.array(image.GetDirection(), dtype=np.float64).reshape(3, 3),
    }


def grid_difference(a, b):
    """Empty when the grids agree (dsr's SameGrid), else what differs."""
    def text(v):
        return ",".join(f"{float(x):g}" for x in v)
    if a["size"] != b["size"]:
        return f"size {text(a['size'])} vs {text(b['size'])} voxels"
    if np.abs(a["spacing"] - b["spacing"]).max() > GRID_TOLERANCE_MM:
        return f"spacing {text(a['spacing'])} vs {text(b['spacing'])} mm"
    if np.abs(a["origin"] - b["origin"]).max() > GRID_TOLERANCE_MM:
        return f"origin {text(a['origin'])} vs {text(b['origin'])} mm"
    if np.abs(a["direction"] - b["direction"]).max() > DIRECTION_TOLERANCE:
        return "direction differs"
    return ""


def read_image(path):
    try:
        image = sitk.ReadImage(path, sitk.sitkFloat32)
    except RuntimeError as e:
        first = str(e).strip().splitlines()
        raise InputError(f"{path}: cannot read the image ({first[-1] if first else 'unknown'})")
    if image.GetDimension() != 3 or image.GetNumberOfComponentsPerPixel() != 1:
        raise InputError(f"{path}: expected a 3D scalar image, got {image.GetDimension()}D with "
                         f"{image.GetNumberOfComponentsPerPixel()} components")
    return image


def mask_from_nonzero(volume, erosion_voxels):
    """dsr's MaskFromNonZero (geometry/volume.cc) on a [k, j, i] float array: 1 except the zero
    voxels connected to the grid border through zero voxels (6-neighbour), then eroded by
    `erosion_voxels` along each axis in turn with the grid border counting as outside."""
    zero = (volume == 0.0).astype(np.uint8)
    labels = sitk.GetArrayFromImage(
        sitk.ConnectedComponent(sitk.GetImageFromArray(zero), False))  # False: 6-connected
    faces = np.concatenate([labels[0].ravel(), labels[-1].ravel(), labels[:, 0].ravel(),
                            labels[:, -1].ravel(), labels[:, :, 0].ravel(),
                            labels[:, :, -1].ravel()])
    border_labels = np.unique(faces[faces != 0])
    mask = ~np.isin(labels, border_labels) | (zero == 0)
    r = erosion_voxels
    if r > 0:
        for axis in (2, 1, 0):  # i, j, k: dsr erodes along index axis 0, 1, 2 in turn
            n = mask.shape[axis]
            padded = np.concatenate([
                np.zeros_like(np.take(mask, range(r), axis=axis)), mask,
                np.zeros_like(np.take(mask, range(r), axis=axis))], axis=axis)
            out = np.ones_like(mask)
            for s in range(0, 2 * r + 1):
                out &= np.take(padded, range(s, s + n), axis=axis)
            mask = out
    return mask.astype(np.uint8)


def load_sequence(frames, masks, use_masks):
    """Returns (images, arrays [k,j,i] float32, masks [k,j,i] uint8, geometry)."""
    images = [read_image(p) for p in frames]
    g0 = geometry(images[0])
    for path, image in zip(frames[1:], images[1:]):
        diff = grid_difference(geometry(image), g0)
        if diff:
            raise InputError(f"{path}: its grid differs from {os.path.basename(frames[0])}'s "
                             f"({diff}); the 4D stack needs every frame on one 3D grid")
    arrays = [sitk.GetArrayFromImage(im) for im in images]
    mask_arrays = []
    for i, array in enumerate(arrays):
        if use_masks:
            mask_image = read_image(masks[i])
            diff = grid_difference(geometry(mask_image), g0)
            if diff:
                raise InputError(f"{masks[i]}: mask grid does not match the image grid ({diff})")
            m = (sitk.GetArrayFromImage(mask_image) != 0).astype(np.uint8)
            if not m.any():
                raise InputError(f"{masks[i]}: mask has no voxel inside (every voxel is 0)")
        else:
            m = mask_from_nonzero(array, 1)
            if not m.any():
                raise InputError(f"{frames[i]}: no voxel left after eroding the non-zero voxels")
        mask_arrays.append(m)
    return images, arrays, mask_arrays, g0


# ----------------------------------------------------------------------------------------
# Poses: reading, writing, elastix conversion
# ----------------------------------------------------------------------------------------

def read_poses(path, frame_paths):
    """dsr poses file (io/io_poses.h) -> list of 4x4 frame_from_world, in frame order.
    Entries are matched to the frames by their "image" names when every entry has one that
    names a frame (as dsr_register matches --gt_poses), else taken in order."""
    try:
        with open(path) as f:
            doc = json.load(f)
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read the poses file ({e})")
    entries = doc.get("frames") if isinstance(doc, dict) else None
    if not isinstance(entries, list) or not entries:
        raise InputError(f"{path}: not a dsr poses file (no non-empty \"frames\" array)")
    if len(entries) != len(frame_paths):
        raise InputError(f"{path}: {len(entries)} poses for {len(frame_paths)} frames")
    poses = []
    for n, e in enumerate(entries):
        try:
            t = np.array(e["T"], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{path}: frame {n}: \"T\" is not 4 rows of 4 numbers")
        if t.shape != (4, 4) or not np.isfinite(t).all():
            raise InputError(f"{path}: frame {n}: \"T\" is not 4 rows of 4 finite numbers")
        r = t[:3, :3]
        if (np.abs(r.T @ r - np.eye(3)).max() > 1e-5 or abs(np.linalg.det(r) - 1) > 1e-5
                or np.abs(t[3] - [0, 0, 0, 1]).max() > 1e-5):
            raise InputError(f"{path}: frame {n}: \"T\" is not rigid within 1e-5")
        poses.append(t)
    names = [os.path.basename(e.get("image", "")) if isinstance(e.get("image"), str) else ""
             for e in entries]
    frame_names = [os.path.basename(p) for p in frame_paths]
    if all(names) and sorted(names) == sorted(frame_names):
        by_name = dict(zip(names, poses))
        poses = [by_name[n] for n in frame_names]
    return poses


def write_poses(path, frame_paths, poses, extra):
    doc = {"convention": CONVENTION}
    doc.update(extra)
    doc["frames"] = [{"image": os.path.basename(p), "T": [[float(v) for v in row] for row in t]}
                     for p, t in zip(frame_paths, poses)]
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(doc, f, indent=2)  # repr() of floats: the shortest exact digits
        f.write("\n")
    os.replace(tmp, path)


def euler_matrix(ax, ay, az, compute_zyx=False):
    """elastix's AdvancedEuler3DTransform::ComputeMatrix (Common/Transforms/
    itkAdvancedEuler3DTransform.hxx, elastix 5.0.1), the same as itk::Euler3DTransform:
    R = Rz Rx Ry by default (ComputeZYX false), R = Rz Ry Rx with ComputeZYX true."""
    cx, sx, cy, sy, cz, sz = (math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay),
                              math.cos(az), math.sin(az))
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx if compute_zyx else rz @ rx @ ry


def parse_transform_parameters(path):
    """elastix TransformParameters file -> {key: [values as strings]}."""
    params = {}
    with open(path) as f:
        for line in f:
            line = line.split("//", 1)[0].strip()
            m = re.match(r"^\((\w+)\s*(.*)\)$", line)
            if m:
                params[m.group(1)] = [v.strip('"') for v in m.group(2).split()]
    return params


def elastix_poses(path, m):
    """EulerStackTransform parameters -> frame_from_world of each frame (world = frame 0).

    Sub-transform i (time index i of the 4D image) has parameters (ax, ay, az, tx, ty, tz)
    and maps a point x of the fixed (reference) space to the moving image, i.e. to frame i:
        T_i(x) = R (x - c) + c + t,   R = euler_matrix(ax, ay, az),  c = CenterOfRotationPoint.
    The reference space is elastix's mean frame (SubtractMean); dsr's world is frame 0's
    physical space, so frame_from_world_i = T_i T_0^-1."""
    p = parse_transform_parameters(path)
    if p.get("Transform", [""])[0] != "EulerStackTransform":
        raise ValueError(f"{path}: Transform is {p.get('Transform')}, not EulerStackTransform")
    values = [float(v) for v in p.get("TransformParameters", [])]
    n_sub = int(p.get("NumberOfSubTransforms", ["0"])[0])
    if n_sub != m or len(values) != 6 * m:
        raise ValueError(f"{path}: {n_sub} sub-transforms and {len(values)} parameters for "
                         f"{m} frames (expected {m} and {6 * m})")
    stack_origin = float(p.get("StackOrigin", ["0"])[0])
    stack_spacing = float(p.get("StackSpacing", ["1"])[0])
    if stack_origin != 0.0 or stack_spacing != 1.0:
        raise ValueError(f"{path}: unexpected StackOrigin/StackSpacing (the stack is written "
                         "with origin 0 and spacing 1 along the frame axis)")
    c = np.array([float(v) for v in p["CenterOfRotationPoint"]], dtype=np.float64)
    compute_zyx = p.get("ComputeZYX", ["false"])[0].lower() == "true"
    reference_to_frame = []
    for i in range(m):
        ax, ay, az, tx, ty, tz = values[6 * i:6 * i + 6]
        r = euler_matrix(ax, ay, az, compute_zyx)
        t = np.eye(4)
        t[:3, :3] = r
        t[:3, 3] = c + np.array([tx, ty, tz]) - r @ c
        reference_to_frame.append(t)
    t0_inv = rigid_inverse(reference_to_frame[0])
    poses = [t @ t0_inv for t in reference_to_frame]
    poses[0] = np.eye(4)  # exactly the gauge (T_0 T_0^-1)
    return poses, values


def rigid_inverse(t):
    out = np.eye(4)
    out[:3, :3] = t[:3, :3].T
    out[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return out


# ----------------------------------------------------------------------------------------
# Evaluation: eval/eval.cc ComparePoses, reproduced
# ----------------------------------------------------------------------------------------

def euler_zyx_angles(r):
    """dsr's EulerZyxAngles: (alpha, beta, gamma) with R = Rz(gamma) Ry(beta) Rx(alpha)."""
    beta = math.asin(max(-1.0, min(1.0, -r[2, 0])))
    alpha = math.atan2(r[2, 1], r[2, 2])
    gamma = math.atan2(r[1, 0], r[0, 0])
    return np.array([alpha, beta, gamma])


def wrap(a):
    while a > math.pi:
        a -= 2.0 * math.pi
    while a <= -math.pi:
        a += 2.0 * math.pi
    return a


def compare_poses(estimated, truth, masks, geom, tre_stride=2):
    """Frame-0-relative errors as dsr's ComparePoses: per frame i >= 1 the translation error
    (mm, voxels), Euler angle error, and the TRE over every `tre_stride`-th voxel (along each
    axis, from index 0) of frame i's mask: |T_est^-1 x - T_gt^-1 x| in world mm, and the mean
    of T_est^-1 x - T_gt^-1 x (the centre error); over frames, the centre errors' mean (the
    shared offset, in frame 0's axes) and mean distance from it (the spread)."""
    est0_inv, gt0_inv = rigid_inverse(estimated[0]), rigid_inverse(truth[0])
    est = [t @ est0_inv for t in estimated]
    gt = [t @ gt0_inv for t in truth]
    m = len(est)
    index_to_physical = geom["direction"] @ np.diag(geom["spacing"])
    frames = []
    for i in range(1, m):
        translation_mm = est[i][:3, 3] - gt[i][:3, 3]
        translation_voxels = translation_mm / geom["spacing"]
        a, b = euler_zyx_angles(est[i][:3, :3]), euler_zyx_angles(gt[i][:3, :3])
        euler = np.array([wrap(a[c] - b[c]) for c in range(3)])
        sub = masks[i][::tre_stride, ::tre_stride, ::tre_stride]  # [k, j, i]
        kk, jj, ii = np.nonzero(sub)
        ijk = np.stack([ii, jj, kk], axis=0).astype(np.float64) * tre_stride
        x = geom["origin"][:, None] + index_to_physical @ ijk
        est_inv, gt_inv = rigid_inverse(est[i]), rigid_inverse(gt[i])
        pe = est_inv[:3, :3] @ x + est_inv[:3, 3:4]
        pg = gt_inv[:3, :3] @ x + gt_inv[:3, 3:4]
        d = np.sqrt(((pe - pg) ** 2).sum(axis=0))
        centre = (pe - pg).mean(axis=1) if d.size else np.zeros(3)
        frames.append({
            "translation_mm": translation_mm, "translation_voxels": translation_voxels,
            "euler_rad": euler,
            "tre_mean_mm": float(d.sum() / d.size) if d.size else 0.0,
            "tre_max_mm": float(d.max()) if d.size else 0.0,
            "centre_error_mm": centre,
        })
    n = max(1, m - 1)

    def mae(key):  # mean over frames of the mean absolute component
        return sum(np.abs(f[key]).sum() / 3.0 for f in frames) / n
    shared = sum((f["centre_error_mm"] for f in frames), np.zeros(3)) / n
    return {
        "frames": frames,
        "mae_translation_voxels": mae("translation_voxels"),
        "mae_translation_mm": mae("translation_mm"),
        "mae_rotation_rad": mae("euler_rad"),
        "tre_mean_mm": sum(f["tre_mean_mm"] for f in frames) / n,
        "tre_max_mm": max((f["tre_max_mm"] for f in frames), default=0.0),
        "shared_offset_mm": shared,
        "frame_spread_mm": sum(float(np.linalg.norm(f["centre_error_mm"] - shared))
                               for f in frames) / n,
    }


# ----------------------------------------------------------------------------------------
# elastix
# ----------------------------------------------------------------------------------------

def rotation_scales(geom, center):
    """What elastix's AutomaticScalesEstimation gives an Euler transform on this grid: the
    mean over the grid's voxels of the squared Jacobian of each parameter at identity,
    |e_a x (p - c)|^2 for the angle about axis a, 1 for a translation. Written explicitly
    because the stack transforms' own AutomaticScalesEstimationStackTransform in 5.0.1 copies
    the first sub-transform's scales from samples of the last time point only."""
    n = geom["size"]
    axes = [np.arange(n[a], dtype=np.float64) for a in range(3)]
    ii, jj, kk = np.meshgrid(*axes, indexing="ij")
    ijk = np.stack([ii.ravel(), jj.ravel(), kk.ravel()])
    p = geom["origin"][:, None] + geom["direction"] @ np.diag(geom["spacing"]) @ ijk
    q2 = (p - center[:, None]) ** 2
    return [float((q2[1] + q2[2]).mean()), float((q2[0] + q2[2]).mean()),
            float((q2[0] + q2[1]).mean())]


def parameter_file(m, center, scales, iterations, samples):
    """The elastix parameter file, every setting with where it comes from."""
    per_frame = " ".join(f"{s:.6f}" for s in scales) + " 1 1 1"
    all_scales = " ".join([per_frame] * m)
    c = " ".join(repr(float(v)) for v in center)
    return f"""// dsr bench/elastix_groupwise.py: groupwise rigid registration of {m} frames stacked
// along the 4th axis. Sources: elastix's default "groupwise" parameter map
// (Core/Main/elxParameterObject.cxx, GetDefaultParameterMap), the model zoo's groupwise
// files Par0039 (par_groupwise_*.txt, Huizinga et al. 2016: 4D stacks, RandomCoordinate,
// SubtractMean, MovingImageDerivativeScales 1 1 1 0, pyramid schedules with 0 on the frame
// axis) and Par0012 (Metz et al. 2011: 4D short images, NumSamplesLastDimension),
// the model zoo's rule for validity masks (ErodeMask), and elastix 5.0.1's sources
// (EulerStackTransform, VarianceOverLastDimensionMetric, the smoothing pyramid).

// ---- Image types: Debian's elastix 5.0.1 is built for 4D images of type short only
// (as Par0012's 4D files use); the script writes the stack as int16.
(FixedInternalImagePixelType "short")
(MovingInternalImagePixelType "short")
(FixedImageDimension 4)
(MovingImageDimension 4)
(UseDirectionCosines "true")                // physical (LPS mm) coordinates, as dsr

// ---- Components
(Registration "MultiResolutionRegistration")  // default groupwise map
(Transform "EulerStackTransform")             // one Euler3D (rigid) transform per frame
(Metric "VarianceOverLastDimensionMetric")    // Metz et al.'s groupwise metric
(Optimizer "AdaptiveStochasticGradientDescent")  // default map, Par0012, Par0039
(ImageSampler "RandomCoordinate")            // default map, Par0039: off-grid samples
(Interpolator "ReducedDimensionBSplineInterpolator")  // default groupwise map
(BSplineInterpolationOrder 1)                // Par0012, Par0039: linear, as dsr samples
(ResampleInterpolator "FinalReducedDimensionBSplineInterpolator")  // default groupwise map
(FinalBSplineInterpolationOrder 3)           // default map (only for a result image)
(Resampler "DefaultResampler")
(FixedImagePyramid "FixedSmoothingImagePyramid")    // default map, Par0012, Par0039
(MovingImagePyramid "MovingSmoothingImagePyramid")

// ---- Multi-resolution: 3 levels, as dsr's --pyramid_levels=3 (factors 4, 2, 1: Gaussian
// sigma 2, 1, 0.5 voxels, no downsampling). The frame axis is never smoothed (0), as in
// Par0012/Par0039. One schedule for both pyramids, as Par0039: the metric reads only the
// moving image, but the fixed pyramid's schedule sets the fixed mask's erosion (below), so
// that samples are drawn where the eroded moving masks are (with the fixed image left
// unsmoothed, as Par0012 does, the fixed mask is eroded by 1 voxel only and on the
// phantom's --masks=none sequences fewer than a quarter of the samples land inside the
// eroded moving masks at the coarsest level: elastix stops, "Too many samples map outside
// moving image buffer").
(NumberOfResolutions 3)
(ImagePyramidSchedule 4 4 4 0  2 2 2 0  1 1 1 0)

// ---- Metric
(SubtractMean "true")                  // Par0012, Par0039: the mean of the frames' parameters
                                       // is kept at 0 (reference = mean frame, no bias to one)
(SampleLastDimensionRandomly "false")  // all {m} frames at every sample (Par0012 samples 5
                                       // random time points of long series; with {m} frames
                                       // every frame at every iteration costs little)
(MovingImageDerivativeScales 1 1 1 0)  // Par0012, Par0039: no gradient along the frame axis

// ---- Transform
(CenterOfRotationPoint {c})  // the 3D grid's centre. Given explicitly: elastix 5.0.1's
       // EulerStackTransform::InitializeTransform leaves the default centre at (0, 0, 0) (a
       // self-assignment bug), a corner of these grids, which couples rotation and translation.
(Scales {all_scales})
       // per parameter (ax ay az tx ty tz per frame): what AutomaticScalesEstimation gives
       // an Euler transform on this grid (mean squared Jacobian: mm^2 for angles, 1 for
       // translations); AutomaticScalesEstimationStackTransform is not used (in 5.0.1 it
       // copies the first frame's scales from samples of the last frame only).
(HowToCombineTransforms "Compose")  // Par0012, Par0039 (no initial transform here anyway)

// ---- Optimizer: ASGD with automatic gain estimation (default map, Par0012, Par0039).
(AutomaticParameterEstimation "true")
(ASGDParameterEstimationMethod "Original")  // Par0039
(MaximumNumberOfIterations {iterations})    // per level (Par0039: 1000; ASGD has no other
                                            // stopping rule, every level runs them all)
(NumberOfSamplesForExactGradient 20000)     // Par0012 (the gain estimation's exact gradient)

// ---- Sampler
(NumberOfSpatialSamples {samples})  // per iteration, each evaluated in all {m} frames
                                    // (default map and Par0039: 2048)
(NewSamplesEveryIteration "true")   // default map, Par0012, Par0039 (stochastic gradient)
(CheckNumberOfSamples "true")       // default map, Par0039: fail if < 1/4 of samples valid
(MaximumNumberOfSamplingAttempts 8) // default map

// ---- Masks: erode them on each level by about the pyramid's smoothing width (moving
// mask: 2 x schedule + 1 voxels, fixed mask: schedule + 1; itkErodeMaskImageFilter), as
// elastix's parameter files say for masks that "indicate which pixels are valid" (the
// model zoo's comment: "If the mask serves as region of interest, set it to false. If the
// mask indicates which pixels are valid, then set it to true."). The frames are 0 outside
// their field of view, so without erosion the smoothed and interpolated values at the
// field of view's edge mix in those zeros: on a 5-frame MNI152 sequence (+/-3 deg, +/-3
// voxels) that biased every frame by about 1 mm (mean TRE 1.03 mm; 0.03 mm with erosion,
// dsr 0.031 mm). Par0012/Par0039 set it false (their masks are regions of interest).
// The erosion also runs along the frame axis (radius 1 there, schedule 0): with
// --masks=fov every frame has the same mask, so nothing changes; with --masks=none a
// frame's mask loses the voxels its neighbouring frames' masks lack.
(ErodeMask "true")

// ---- Output
(DefaultOutputPrecision 17)       // TransformParameters with full double precision
(WriteResultImage "false")        // only the transform is needed
(WriteTransformParametersEachResolution "false")
(WriteTransformParametersEachIteration "false")
(ShowExactMetricValue "false")
(DefaultPixelValue 0)
"""


def stack_4d(arrays, geom, dtype, scale=1.0):
    """[k, j, i] arrays -> one 4D SimpleITK image (frame index = 4th axis, origin 0,
    spacing 1), the 3D grid's spacing, origin and direction on the first three axes."""
    volume = np.stack(arrays, axis=0)
    if dtype == np.int16:
        volume = np.clip(np.rint(volume * scale), -32768, 32767)
    image = sitk.GetImageFromArray(volume.astype(dtype), isVector=False)
    image.SetSpacing(tuple(geom["spacing"]) + (1.0,))
    image.SetOrigin(tuple(geom["origin"]) + (0.0,))
    d = np.eye(4)
    d[:3, :3] = geom["direction"]
    image.SetDirection(tuple(d.ravel()))
    return image


def first_error_line(text):
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    for key in ("Description:", "ERROR", "Error", "error", "exception", "Exception"):
        for line in lines:
            if key in line:
                return line
    return lines[-1] if lines else "no output"


def run_elastix(args, arrays, masks, geom, work):
    """Writes the inputs, runs elastix, returns (result dict)."""
    m = len(arrays)
    peak = max(float(np.abs(a).max()) for a in arrays)
    scale = SHORT_RANGE / peak if peak > 0 else 1.0
    image_path = os.path.join(work, "stack4d.mha")
    mask_path = os.path.join(work, "mask4d.mha")
    sitk.WriteImage(stack_4d(arrays, geom, np.int16, scale), image_path)
    sitk.WriteImage(stack_4d(masks, geom, np.uint8), mask_path)
    n = np.array(geom["size"], dtype=np.float64)
    center = geom["origin"] + geom["direction"] @ (geom["spacing"] * (n - 1.0) / 2.0)
    params_path = os.path.join(work, "parameters.txt")
    with open(params_path, "w") as f:
        f.write(parameter_file(m, center, rotation_scales(geom, center), args.iterations,
                               args.samples))
    out_dir = os.path.join(work, "elastix")
    os.makedirs(out_dir, exist_ok=True)
    command = [args.elastix, "-f", image_path, "-m", image_path, "-fMask", mask_path,
               "-mMask", mask_path, "-p", params_path, "-out", out_dir]
    if args.threads > 0:
        command += ["-threads", str(args.threads)]
    log_path = os.path.join(work, "elastix_stdout.log")
    start = time.monotonic()
    with open(log_path, "w") as log:
        try:
            status = subprocess.run(command, stdout=log, stderr=subprocess.STDOUT).returncode
        except OSError as e:
            raise InputError(f"cannot run {args.elastix}: {e}")
    seconds = time.monotonic() - start
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    if not args.keep_images:
        for p in (image_path, mask_path):
            os.remove(p)
    with open(log_path, errors="replace") as f:
        text = f.read()
    result = {"seconds": seconds, "peak_memory_mb": peak_mb, "failure": "",
              "log": log_path, "parameters": params_path}
    # ASGD stops only at MaximumNumberOfIterations: count the levels that reached it.
    levels = len(re.findall(r"Maximum number of iterations has been reached", text))
    result["iterations"] = levels * args.iterations if levels == 3 else ""
    tp = os.path.join(out_dir, "TransformParameters.0.txt")
    if status != 0:
        result["failure"] = f"elastix exited with status {status}: {first_error_line(text)}"
    elif not os.path.isfile(tp):
        result["failure"] = f"elastix wrote no {tp}: {first_error_line(text)}"
    else:
        try:
            result["poses"], result["parameters_values"] = elastix_poses(tp, m)
        except (ValueError, KeyError) as e:
            result["failure"] = f"unusable elastix transform: {e}"
    return result


# ----------------------------------------------------------------------------------------

def fmt(v):
    """dsr_compare's number format (std::ostream, precision 9)."""
    if v == "" or v is None:
        return ""
    if isinstance(v, int):
        return str(v)
    return f"{v:.9g}"


def csv_field(text):
    if not any(ch in text for ch in ",\"\n"):
        return text
    return '"' + text.replace('"', '""').replace("\n", " ") + '"'


def csv_row(method, sequence, ok, errors, run):
    e = errors or {}
    fields = [csv_field(method), csv_field(sequence), "1" if ok else "0",
              fmt(e.get("mae_translation_voxels", "")), fmt(e.get("mae_translation_mm", "")),
              fmt(e.get("mae_rotation_rad", "")), fmt(e.get("tre_mean_mm", "")),
              fmt(e.get("tre_max_mm", "")), fmt(run.get("iterations", "")), "", "",
              fmt(run.get("seconds", "")), fmt(run.get("peak_memory_mb", "")), "",
              csv_field(run.get("failure", ""))]
    shared = e.get("shared_offset_mm")
    fields += ([fmt(float(np.linalg.norm(shared)))] + [fmt(float(v)) for v in shared] +
               [fmt(e["frame_spread_mm"])]) if shared is not None else [""] * 5
    return ",".join(fields)


def sequence_name(folder):
    return os.path.basename(os.path.normpath(os.path.abspath(folder)))


def main(argv):
    parser = Parser(prog=PROG, add_help=True)
    parser.add_argument("sequence")
    parser.add_argument("--masks", required=True, choices=("fov", "none"))
    parser.add_argument("--work_dir", default="",
                        help="keep the parameter file, elastix's log and transform here "
                             "(default: a temporary folder, removed)")
    parser.add_argument("--out_poses", default="", help="write the poses (dsr format) here")
    parser.add_argument("--eval_poses", default="",
                        help="no elastix: measure this poses file against gt_poses.json")
    parser.add_argument("--header", action="store_true", help="print the CSV header first")
    parser.add_argument("--method", default="elastix", help="the CSV row's method column")
    parser.add_argument("--elastix", default="elastix", help="the elastix binary")
    parser.add_argument("--threads", type=int, default=0,
                        help="elastix -threads (0: elastix's default, every core)")
    parser.add_argument("--iterations", type=int, default=1000,
                        help="ASGD iterations per pyramid level")
    parser.add_argument("--samples", type=int, default=2048,
                        help="random sample positions per iteration")
    parser.add_argument("--keep_images", action="store_true",
                        help="keep the 4D image and mask in --work_dir")
    args = parser.parse_args(argv[1:])
    if args.iterations < 1 or args.samples < 1 or args.threads < 0:
        raise InputError("--iterations and --samples must be >= 1, --threads >= 0")

    use_masks = args.masks == "fov"
    frames, masks, gt_path = list_sequence(args.sequence, use_masks)
    truth = read_poses(gt_path, frames)
    name = sequence_name(args.sequence)
    _images, arrays, mask_arrays, geom = load_sequence(frames, masks, use_masks)
    if args.header:
        print(CSV_COLUMNS)

    if args.eval_poses:
        estimated = read_poses(args.eval_poses, frames)
        errors = compare_poses(estimated, truth, mask_arrays, geom)
        for i, f in enumerate(errors["frames"], start=1):
            print(f"{PROG}: frame {i}: TRE mean {f['tre_mean_mm']:.9f} mm, "
                  f"max {f['tre_max_mm']:.9f} mm", file=sys.stderr)
        print(f"{PROG}: TRE mean {errors['tre_mean_mm']:.12f} mm, max "
              f"{errors['tre_max_mm']:.12f} mm", file=sys.stderr)
        print(csv_row(args.method, name, True, errors, {}))
        return 0

    if shutil.which(args.elastix) is None:
        raise InputError(f"elastix not found ('{args.elastix}'; Debian: apt-get install elastix)")
    temporary = not args.work_dir
    work = tempfile.mkdtemp(prefix="elastix_groupwise_") if temporary else args.work_dir
    os.makedirs(work, exist_ok=True)
    try:
        run = run_elastix(args, arrays, mask_arrays, geom, work)
        if run["failure"]:
            print(f"{PROG}: {name}: {run['failure']} (log: {run['log']})", file=sys.stderr)
            print(csv_row(args.method, name, False, None, run))
            return 1
        if args.out_poses:
            write_poses(args.out_poses, frames, run["poses"],
                        {"method": "elastix EulerStackTransform + VarianceOverLastDimensionMetric"})
        errors = compare_poses(run["poses"], truth, mask_arrays, geom)
        print(csv_row(args.method, name, True, errors, run))
        return 0
    finally:
        if temporary:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    try:
        sys.exit(main(sys.argv))
    except InputError as e:
        print(f"{PROG}: {e}", file=sys.stderr)
        sys.exit(2)
