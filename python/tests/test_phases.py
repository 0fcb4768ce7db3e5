"""4D images (one 3D volume per heart phase, io/io_phases.h): dsr.write_image of a (T, z, y,
x) array writes NIfTI with a time axis and 3D Slicer's .seq.nrrd; SimpleITK reads what dsr
writes and dsr reads what SimpleITK writes, with the same voxels and geometry."""
import re

import numpy as np
import pytest
import SimpleITK as sitk

import dsr

PHASES = 3
SPACING = (0.7, 1.1, 2.3)
ORIGIN = (-3.7, 2.9, 5.3)


def rotation(angle, axis):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


DIRECTION = rotation(0.5, (1, -2, 0.5))


def phases_image():
    """Phases on an anisotropic, rotated, shifted grid, with voxels that differ by phase."""
    t, z, y, x = np.meshgrid(np.arange(PHASES), np.arange(5), np.arange(6), np.arange(7),
                             indexing="ij")
    array = (0.25 * ((x + 7 * y + 42 * z) * 37 % 211) - 3.1 + 100.0 * t).astype(np.float32)
    return dsr.Image(array, SPACING, ORIGIN, DIRECTION)


def expect_grid(image, dimension):
    assert image.GetDimension() == dimension
    assert image.GetSize()[:3] == (7, 6, 5)
    np.testing.assert_allclose(image.GetSpacing()[:3], SPACING, atol=1e-6)
    np.testing.assert_allclose(image.GetOrigin()[:3], ORIGIN, atol=1e-6)
    direction = np.asarray(image.GetDirection()).reshape(dimension, dimension)
    np.testing.assert_allclose(direction[:3, :3], DIRECTION, atol=1e-6)


def expect_same(read, written):
    assert read.array.shape == written.array.shape
    np.testing.assert_array_equal(read.array, written.array)
    np.testing.assert_allclose(read.spacing, SPACING, atol=1e-6)
    np.testing.assert_allclose(read.origin, ORIGIN, atol=1e-6)
    np.testing.assert_allclose(read.direction, DIRECTION, atol=1e-6)


def test_simpleitk_reads_a_4d_nifti_written_by_dsr(tmp_path):
    written = phases_image()
    path = tmp_path / "cine.nii.gz"
    dsr.write_image(written, path)
    image = sitk.ReadImage(str(path))
    expect_grid(image, 4)
    assert image.GetSize() == (7, 6, 5, PHASES)
    assert image.GetSpacing()[3] == 1.0  # one step per phase
    assert image.GetNumberOfComponentsPerPixel() == 1
    np.testing.assert_array_equal(sitk.GetArrayFromImage(image), written.array)  # [t, k, j, i]
    expect_same(dsr.read_image(path), written)


def test_simpleitk_reads_a_slicer_sequence_written_by_dsr(tmp_path):
    # ITK (so SimpleITK) reads a NRRD's list axis as the components of a 3D image: T values
    # per voxel, phase fastest; 3D Slicer reads the same file as a sequence of T volumes.
    written = phases_image()
    path = tmp_path / "cine.seq.nrrd"
    dsr.write_image(written, path)
    image = sitk.ReadImage(str(path))
    expect_grid(image, 3)
    assert image.GetNumberOfComponentsPerPixel() == PHASES
    values = sitk.GetArrayFromImage(image)  # [k, j, i, t]
    assert values.shape == (5, 6, 7, PHASES)
    np.testing.assert_array_equal(np.moveaxis(values, -1, 0), written.array)
    assert image.GetMetaData("DataNodeClassName") == "vtkMRMLScalarVolumeNode"
    assert image.GetMetaData("axis 0 index type") == "numeric"
    assert image.GetMetaData("axis 0 index values") == "0 1 2"
    expect_same(dsr.read_image(path), written)


def test_dsr_reads_4d_images_simpleitk_writes(tmp_path):
    written = phases_image()
    series = written.to_simpleitk()  # JoinSeries: a 4D image, 4th spacing 1
    assert series.GetDimension() == 4
    for name in ("itk.nii.gz", "itk.nrrd", "itk.mha"):
        sitk.WriteImage(series, str(tmp_path / name))
        expect_same(dsr.read_image(tmp_path / name), written)
    vector = sitk.Compose([sitk.GetImageFromArray(p) for p in written.array])
    vector.CopyInformation(dsr.Image(written.array[0], SPACING, ORIGIN, DIRECTION).to_simpleitk())
    sitk.WriteImage(vector, str(tmp_path / "vector.nrrd"))  # kind "vector": phases too
    expect_same(dsr.read_image(tmp_path / "vector.nrrd"), written)


def test_3d_images_are_unchanged_and_bad_phases_are_named(tmp_path):
    written = phases_image()
    one = dsr.Image(written.array[1], SPACING, ORIGIN, DIRECTION)
    dsr.write_image(one, tmp_path / "one.nrrd")
    back = dsr.read_image(tmp_path / "one.nrrd")
    assert back.array.ndim == 3
    expect_same(back, one)
    bad = written.array.copy()
    bad[2, 1, 2, 3] = np.nan
    with pytest.raises(ValueError, match=r"image: phase 2: voxel \(3,2,1\) is NaN"):
        dsr.write_image(dsr.Image(bad, SPACING, ORIGIN, DIRECTION), tmp_path / "bad.nii.gz")
    moved = dsr.Image(written.array, SPACING, ORIGIN, DIRECTION)
    dsr.write_image(moved, tmp_path / "moved.nrrd")
    # A 4D image is a view over the heart cycle: every view needs the same phases.
    with pytest.raises(ValueError, match=r"frame_01: 1 phase, but frame_00 has 3"):
        dsr.register([dsr.read_image(tmp_path / "moved.nrrd"), one])
    assert not (tmp_path / "bad.nii.gz").exists()


# Registering and fusing views recorded over the heart cycle (docs/design.md section 12).

def beating(**extra):
    return dsr.simulate(num_frames=3, phantom_size=64, frame_size="32,32,28",
                        max_rotation_deg=6, max_translation_voxels=3, min_depth_voxels=2,
                        sigma=10, num_phases=3, beat_amplitude_mm=1.5, beat_radius_mm=7,
                        **extra)


def write_views(folder, views, masks):
    """The views as 4D files and their masks, in folder: (view paths, mask paths)."""
    paths = [str(folder / f"view_{i}.nii.gz") for i in range(len(views))]
    mask_paths = [str(folder / f"mask_{i}.nii.gz") for i in range(len(views))]
    for view, mask, path, mask_path in zip(views, masks, paths, mask_paths):
        dsr.write_image(view, path)
        dsr.write_image(mask, mask_path)
    return paths, mask_paths


SMALL = {"pyramid_levels": 2, "pyramid_min_size": 8, "num_threads": 1}


def test_views_register_with_one_pose_each_in_memory_and_from_files(tmp_path):
    sequence = beating(seed=4)
    views = sequence.views()
    assert views[1].array.shape == (3, 28, 32, 32)
    result = dsr.register(views, sequence.masks, **SMALL)
    assert len(result.poses) == 3
    world_from_frame0 = np.linalg.inv(sequence.frame_from_world[0])
    # Within 0.1 mm (and 0.1 in each rotation entry) of the truth: three small noisy views
    # (32 x 32 x 28 voxels of 1 mm, sigma 10) registered without gains and offsets, as
    # photometric=auto finds none here (1.7 % against the 3 % limit); the largest entry off
    # is 0.050 mm.
    for pose, true_pose in zip(result.poses, sequence.frame_from_world):
        np.testing.assert_allclose(pose, true_pose @ world_from_frame0, atol=0.1)
    # The same views as 4D files: the same poses, bit for bit.
    paths, masks = write_views(tmp_path, views, sequence.masks)
    from_files = dsr.register(paths, masks, **SMALL)
    for a, b in zip(result.poses, from_files.poses):
        np.testing.assert_array_equal(a, b)
    # One phase alone is another registration (its own noise only).
    one = dsr.register(views, sequence.masks, phases="1", **SMALL)
    assert any(not np.array_equal(a, b) for a, b in zip(result.poses, one.poses))
    # The panorama of every phase: (T, z, y, x); the count is the views' (3D).
    mean, count = dsr.fuse(views, result, sequence.masks, blend="mean")
    assert mean.array.ndim == 4 and mean.array.shape[0] == 3
    assert count.array.ndim == 3 and count.array.shape == mean.array.shape[1:]
    assert not np.array_equal(mean.array[0], mean.array[1])
    picked, _ = dsr.fuse(views, result, sequence.masks, blend="mean", phases="1")
    np.testing.assert_array_equal(picked.array, mean.array[1])


def test_phases_picked_from_files_are_those_picked_in_memory(tmp_path):
    """From 4D files, --phases reads only the phases picked: the same poses and fusion as
    the views in memory with the same phases picked."""
    sequence = beating(seed=4)
    views = sequence.views()
    paths, masks = write_views(tmp_path, views, sequence.masks)
    in_memory = dsr.register(views, sequence.masks, phases="2,0", **SMALL)
    from_files = dsr.register(paths, masks, phases="2,0", **SMALL)
    for a, b in zip(in_memory.poses, from_files.poses):
        np.testing.assert_array_equal(a, b)
    fused, _ = dsr.fuse(views, in_memory, sequence.masks, blend="mean", phases="1")
    fused_from_files, _ = dsr.fuse(paths, from_files, masks, blend="mean", phases="1")
    np.testing.assert_array_equal(fused_from_files.array, fused.array)


def test_uneven_phases_are_refused_naming_the_view():
    sequence = beating(seed=5)
    views = sequence.views()
    views[2] = dsr.Image(views[2].array[:2], views[2].spacing, views[2].origin,
                         views[2].direction)
    with pytest.raises(ValueError, match="frame_02: 2 phases, but frame_00 has 3"):
        dsr.register(views, sequence.masks, **SMALL)
    with pytest.raises(ValueError, match="frame_00 has 3 phases .0 to 2., no phase 5"):
        dsr.register(sequence.views(), sequence.masks, phases="0,5", **SMALL)


def test_phases_are_digits_separated_by_single_commas():
    """phases= has the command line's grammar: a space, a sign or an empty item anywhere is
    refused, naming the option, before any work."""
    sequence = beating(seed=5)
    for bad in (" 1", "1 ", "+1", "0,1,", ",0", "0,,1"):
        with pytest.raises(ValueError, match=f"--phases={re.escape(bad)}: must be all or"):
            dsr.register(sequence.views(), sequence.masks, phases=bad, **SMALL)
    with pytest.raises(ValueError, match=r"--phases=0,1,: must be all or"):
        dsr.fuse(sequence.views(), [np.eye(4)] * 3, sequence.masks, phases="0,1,")


def test_a_blank_phase_is_refused_in_memory_and_from_files(tmp_path):
    """A phase of one value in every voxel has nothing to register: refused naming the
    image (or file) and the phase, as dsr_register refuses it."""
    sequence = beating(seed=5)
    views = sequence.views()
    blank = views[1].array.copy()
    blank[2] = 0.0
    views[1] = dsr.Image(blank, views[1].spacing, views[1].origin, views[1].direction)
    with pytest.raises(ValueError, match=r"image 1 phase 2 has the same value \(0\) in every "
                                         r"voxel"):
        dsr.register(views, sequence.masks, **SMALL)
    paths, masks = write_views(tmp_path, views, sequence.masks)
    with pytest.raises(ValueError, match=r"view_1\.nii\.gz: phase 2 has the same value \(0\)"):
        dsr.register(paths, masks, **SMALL)
    assert dsr.read_image(paths[1]).array.shape[0] == 3  # a reader of any 4D image takes it


def test_dsr_fuse_writes_a_4d_panorama_simpleitk_and_slicer_read(tmp_path):
    """dsr_simulate's 4D views, registered and fused by the tools: SimpleITK reads the
    NIfTI panorama as 4D, and the .seq.nrrd carries 3D Slicer's sequence keys."""
    from cli import run_tool  # noqa: PLC0415

    folder = tmp_path / "seq"
    sim = run_tool("dsr_simulate", f"--out_dir={folder}", "--phantom_size=64",
                   "--frame_size=32,32,28", "--num_frames=3", "--max_rotation_deg=6",
                   "--max_translation_voxels=3", "--min_depth_voxels=2", "--sigma=10",
                   "--num_phases=3", "--beat_amplitude_mm=1.5", "--beat_radius_mm=7")
    assert sim.returncode == 0, sim.stderr
    images = ",".join(str(folder / f"frame_0{i}.nii.gz") for i in range(3))
    masks = ",".join(str(folder / f"mask_0{i}.nii.gz") for i in range(3))
    poses = tmp_path / "poses.json"
    reg = run_tool("dsr_register", f"--images={images}", f"--masks={masks}",
                   f"--out_poses={poses}", "--pyramid_levels=2", "--pyramid_min_size=8")
    assert reg.returncode == 0, reg.stderr
    for name in ("panorama.nii.gz", "panorama.seq.nrrd"):
        fuse = run_tool("dsr_fuse", f"--images={images}", f"--masks={masks}",
                        f"--poses={poses}", f"--out={tmp_path / name}")
        assert fuse.returncode == 0, fuse.stderr
    image = sitk.ReadImage(str(tmp_path / "panorama.nii.gz"))
    assert image.GetDimension() == 4 and image.GetSize()[3] == 3
    array = sitk.GetArrayFromImage(image)  # [t, k, j, i]
    ours = dsr.read_image(tmp_path / "panorama.nii.gz").array
    np.testing.assert_array_equal(array, ours)
    header = (tmp_path / "panorama.seq.nrrd").read_bytes().split(b"\n\n", 1)[0].decode()
    for line in ("dimension: 4", "kinds: list domain domain domain",
                 "DataNodeClassName:=vtkMRMLScalarVolumeNode", "axis 0 index type:=numeric",
                 "axis 0 index values:=0 1 2"):
        assert line in header.splitlines(), header
    np.testing.assert_array_equal(dsr.read_image(tmp_path / "panorama.seq.nrrd").array, ours)
