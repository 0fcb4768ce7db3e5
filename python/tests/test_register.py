"""The Python package against the command-line tools it fronts: the same registration bit for
bit, the same one-line messages for bad input, and its own inputs (arrays, in-memory
simulation) giving the same results as files."""
import collections.abc
import inspect
import os
import pathlib
import threading
import time
import typing

import numpy as np
import pytest

import dsr
from cli import cli_flags, error_line, run_tool

SMALL = {"phantom_size": 64, "frame_size": "32,32,28", "max_rotation_deg": 6,
         "max_translation_voxels": 3, "min_depth_voxels": 2, "sigma": 10}
LEVELS = {"pyramid_levels": 2, "pyramid_min_size": 8}


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sequence") / "s"
    run = run_tool("dsr_simulate", f"--out_dir={folder}", "--num_frames=3", *cli_flags(SMALL))
    assert run.returncode == 0, run.stderr
    return folder


def files(folder, kind):
    return [str(folder / f"{kind}_{i:02d}.nii.gz") for i in range(3)]


def test_register_from_files_writes_the_clis_poses_file_bit_for_bit(sequence, tmp_path):
    cli_poses = tmp_path / "cli.json"
    run = run_tool("dsr_register", "--images=" + ",".join(files(sequence, "frame")),
                   "--masks=" + ",".join(files(sequence, "mask")), f"--out_poses={cli_poses}",
                   "--progress=false", *cli_flags(LEVELS))
    assert run.returncode == 0, run.stderr
    result = dsr.register(files(sequence, "frame"), files(sequence, "mask"), **LEVELS)
    result.save(tmp_path / "python.json")
    assert (tmp_path / "python.json").read_bytes() == cli_poses.read_bytes()
    written = dsr.read_poses(cli_poses, 3)
    assert written["images"] == ["frame_00.nii.gz", "frame_01.nii.gz", "frame_02.nii.gz"]
    for ours, theirs in zip(result.poses, written["frame_from_world"]):
        assert np.array_equal(ours, theirs)
    assert result.summary["mode"] == "dsr"
    assert result.summary["iterations"] > 0
    # The checks' figures: every frame judged and lined up, every pose determined.
    assert all(f is not None and f < 0.05 for f in result.summary["structure_fraction"])
    assert len(result.summary["pose_error_voxels"]) == 3
    assert all(0 <= e < 1 for e in result.summary["pose_error_voxels"])
    assert np.array_equal(result.poses[0], np.eye(4))


def test_intensity_transform_gives_the_clis_poses_and_gains(sequence, tmp_path):
    """--intensity_transform=sqrt with --photometric=affine: the same poses file (gains and
    offsets on the input's grey levels) and the transform in the summary."""
    options = {**LEVELS, "intensity_transform": "sqrt", "photometric": "affine"}
    cli_poses = tmp_path / "cli.json"
    run = run_tool("dsr_register", "--images=" + ",".join(files(sequence, "frame")),
                   "--masks=" + ",".join(files(sequence, "mask")), f"--out_poses={cli_poses}",
                   "--progress=false", *cli_flags(options))
    assert run.returncode == 0, run.stderr
    assert "registered sqrt(c I)" in run.stdout
    result = dsr.register(files(sequence, "frame"), files(sequence, "mask"), **options)
    result.save(tmp_path / "python.json")
    assert (tmp_path / "python.json").read_bytes() == cli_poses.read_bytes()
    assert result.summary["intensity_transform"] == "sqrt"
    assert result.summary["intensity_transform_scale"] > 0
    assert len(result.gain) == 3 and result.gain[0] == 1.0
    # No brightness change was simulated: the gains on the input's scale are near 1.
    assert all(abs(g - 1.0) < 0.05 for g in result.gain)


def test_echo_preset_sets_the_ultrasound_flags_as_the_cli_does(sequence, tmp_path):
    """preset="echo" is --preset=echo: the same poses file, the preset and the structure
    check in the summary; an explicit flag still wins over the preset."""
    options = {**LEVELS, "preset": "echo"}
    cli_poses = tmp_path / "cli.json"
    run = run_tool("dsr_register", "--images=" + ",".join(files(sequence, "frame")),
                   "--masks=" + ",".join(files(sequence, "mask")), f"--out_poses={cli_poses}",
                   "--progress=false", *cli_flags(options))
    assert run.returncode == 0, run.stderr
    assert ("preset echo: --photometric=affine --intensity_transform=sqrt "
            "--panorama_sampling=all_phases") in run.stdout
    result = dsr.register(files(sequence, "frame"), files(sequence, "mask"), **options)
    result.save(tmp_path / "python.json")
    assert (tmp_path / "python.json").read_bytes() == cli_poses.read_bytes()
    assert result.summary["preset"].startswith("preset echo: --photometric=affine")
    assert result.summary["intensity_transform"] == "sqrt"
    assert len(result.gain) == 3
    assert len(result.summary["structure_fraction"]) == 3
    # The preset looks for dropouts: each view's share left out is stated (0 where none).
    assert len(result.summary["dropout_fraction"]) == 3
    plain = dsr.register(files(sequence, "frame"), files(sequence, "mask"),
                         **{**options, "photometric": "none", "intensity_transform": "none"})
    assert (plain.summary["preset"] ==
            "preset echo: --panorama_sampling=all_phases --detect_dropouts=true")
    assert "intensity_transform" not in plain.summary and not plain.gain
    assert dsr.register(files(sequence, "frame"), files(sequence, "mask"),
                        **LEVELS).summary["dropout_fraction"] == []


def test_arrays_register_as_their_files_do(sequence):
    from_files = dsr.register(files(sequence, "frame"), files(sequence, "mask"), **LEVELS)
    images = [dsr.read_image(p) for p in files(sequence, "frame")]
    masks = [dsr.read_image(p) for p in files(sequence, "mask")]
    assert images[0].array.shape == (28, 32, 32)  # [k, j, i]
    from_arrays = dsr.register(images, masks, **LEVELS)
    for a, b in zip(from_arrays.poses, from_files.poses):
        assert np.array_equal(a, b)
    assert from_arrays.summary["field_of_view"] == "field of view: the given masks"
    # Without masks both derive them from the images (mask_rule, mask_erosion), and the
    # summary says which rule did.
    no_masks = dsr.register(files(sequence, "frame"), **LEVELS)
    from_arrays = dsr.register(images, **LEVELS)
    for a, b in zip(from_arrays.poses, no_masks.poses):
        assert np.array_equal(a, b)
    for result in (no_masks, from_arrays):
        assert (result.summary["field_of_view"] ==
                "field of view: convex hull of the non-zero voxels (frames 0-2)")
    nonzero = dsr.register(images, mask_rule="nonzero", **LEVELS)
    assert nonzero.summary["field_of_view"] == "field of view: non-zero voxels (frames 0-2)"


@pytest.mark.parametrize("reader", ["SimpleITK", "nibabel"])
def test_simpleitk_and_nibabel_images_register_as_their_files_do(sequence, reader):
    if reader == "SimpleITK":
        import SimpleITK as sitk  # noqa: PLC0415 (optional, only for this reader)
        read = sitk.ReadImage
    else:
        import nibabel  # noqa: PLC0415 (optional, only for this reader)
        read = nibabel.load
    from_files = dsr.register(files(sequence, "frame"), files(sequence, "mask"), **LEVELS)
    images = [read(p) for p in files(sequence, "frame")]
    masks = [read(p) for p in files(sequence, "mask")]
    ours = dsr.register(images, masks, **LEVELS)
    # The same voxels; the geometry as each library reads the NIfTI header (to rounding).
    for a, b in zip(ours.poses, from_files.poses):
        assert np.abs(a - b).max() < 1e-6


def test_simulate_in_memory_is_dsr_simulate(sequence):
    simulated = dsr.simulate(num_frames=3, **SMALL)
    for i, path in enumerate(files(sequence, "frame")):
        on_disk = dsr.read_image(path)
        assert np.array_equal(simulated.frames[i].array, on_disk.array)
        assert np.allclose(simulated.frames[i].spacing, on_disk.spacing)
    truth = dsr.read_poses(sequence / "gt_poses.json", 3)["frame_from_world"]
    for a, b in zip(simulated.frame_from_world, truth):
        assert np.array_equal(a, b)


def test_registration_finds_the_simulated_poses():
    simulated = dsr.simulate(num_frames=4, seed=3, **SMALL)
    result = dsr.register(simulated.frames, simulated.masks, **LEVELS)
    world_from_frame0 = np.linalg.inv(simulated.frame_from_world[0])
    for estimate, truth in zip(result.poses, simulated.frame_from_world):
        relative = truth @ world_from_frame0  # the truth in frame 0's world
        assert np.abs(estimate[:3, 3] - relative[:3, 3]).max() < 0.2  # mm
        assert np.abs(estimate[:3, :3] - relative[:3, :3]).max() < 5e-3


@pytest.mark.parametrize("options", [
    {"max_iterations": 0},
    {"mode": "magic"},
    {"photometric": "linear"},
    {"panorama_spacing": 0},
    {"kernels": "avx3"},
    {"loss": "huber", "loss_scale": 0.0},
    {"mode": "ape", "photometric": "affine"},
    {"smoothing": 1e6},
])
def test_bad_options_raise_the_clis_message(sequence, options):
    images = files(sequence, "frame")
    expected = error_line("dsr_register", "--images=" + ",".join(images), "--out_poses=unused.json",
                          *cli_flags(options))
    with pytest.raises(ValueError) as raised:
        dsr.register(images, **options)
    assert str(raised.value) == expected


def test_bad_inputs_raise_value_errors(sequence, tmp_path):
    images = files(sequence, "frame")
    missing = str(tmp_path / "missing.nii.gz")
    expected = error_line("dsr_register", "--images=" + ",".join(images[:2] + [missing]),
                          "--out_poses=unused.json")
    with pytest.raises(ValueError) as raised:
        dsr.register(images[:2] + [missing])
    assert str(raised.value) == expected
    # A value a flag's validator refuses, then one of the same flag that is not a number:
    # each gets its own message.
    with pytest.raises(ValueError, match=r"^--panorama_spacing=0: must be in \[0.001, 1000\] "):
        dsr.register(images, panorama_spacing=0)
    with pytest.raises(ValueError, match=r"^--panorama_spacing=two: not a valid double$"):
        dsr.register(images, panorama_spacing="two")
    with pytest.raises(ValueError, match=r"^--pyramid_level=2: unknown flag$"):
        dsr.register(images, pyramid_level=2)
    with pytest.raises(ValueError, match="no spacing, origin or direction"):
        dsr.register([np.zeros((4, 4, 4))] * 2)
    with pytest.raises(ValueError, match="at least 2 images"):
        dsr.register(images[:1])
    with pytest.raises(ValueError, match="3 axes"):
        dsr.register([dsr.Image(np.ones((4, 4)))] * 2)
    with pytest.raises(ValueError, match="spacing"):
        dsr.register([dsr.Image(np.ones((8, 8, 8)), spacing=(1.0, 0.0, 1.0))] * 2)
    with pytest.raises(ValueError, match="not on its image's voxel grid"):
        dsr.register([dsr.Image(np.ones((8, 8, 8)))] * 2,
                     masks=[dsr.Image(np.ones((8, 8, 9)))] * 2)


def test_iteration_callback_reports_and_can_stop(sequence):
    seen = []
    dsr.register(files(sequence, "frame"), **LEVELS,
                 on_iteration=lambda label, record: seen.append((label, record)))
    assert seen and all("dsr" in label for label, _ in seen)
    assert {"iteration", "cost", "step_norm", "seconds", "step_accepted"} <= set(seen[0][1])
    with pytest.raises(dsr.RegistrationError):
        dsr.register(files(sequence, "frame"), **LEVELS, max_recoveries=0,
                     on_iteration=lambda label, record: False)

    def fail(label, record):
        raise KeyError("stop here")

    with pytest.raises(KeyError, match="stop here"):
        dsr.register(files(sequence, "frame"), **LEVELS, on_iteration=fail)


def test_other_python_threads_run_while_it_solves(sequence):
    ticks = 0
    done = threading.Event()

    def count():
        nonlocal ticks
        while not done.is_set():
            ticks += 1
            time.sleep(0.001)

    counter = threading.Thread(target=count)
    counter.start()
    start = time.perf_counter()
    try:
        dsr.register(files(sequence, "frame"), **LEVELS)
    finally:
        seconds = time.perf_counter() - start
        done.set()
        counter.join()
    # A millisecond sleep per tick: with the GIL held for the solve there would be ~none.
    assert ticks > 0.2 * seconds / 0.001


def test_poses_round_trip(tmp_path):
    poses = [np.eye(4), np.array([[1, 0, 0, 2.5], [0, 0, -1, 0], [0, 1, 0, -1], [0, 0, 0, 1.0]])]
    dsr.write_poses(tmp_path / "p.json", poses, images=["a", "b"], gain=[1.0, 1.2],
                    offset=[0.0, -3.0])
    back = dsr.read_poses(tmp_path / "p.json")
    assert back["images"] == ["a", "b"] and back["gain"] == [1.0, 1.2]
    assert all(np.array_equal(a, b) for a, b in zip(poses, back["frame_from_world"]))
    assert "max_iterations" in dsr.options() and "seed" in dsr.options()
    with pytest.raises(ValueError, match="gain: 1 entries for 2 poses"):
        dsr.write_poses(tmp_path / "q.json", poses, gain=[1.0])


def test_the_readmes_example_runs(tmp_path, monkeypatch):
    readme = (pathlib.Path(__file__).parents[2] / "README.md").read_text()
    section = readme.split("## From Python", 1)[1]
    code = section.split("```python\n", 1)[1].split("```", 1)[0]
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    exec(compile(code, "README.md", "exec"), {})
    assert dsr.read_poses(tmp_path / "poses.json", 5)["frame_from_world"][0].shape == (4, 4)
    assert (tmp_path / "panorama.png").stat().st_size > 1000


def test_numpy_scalars_are_option_values(sequence):
    images = files(sequence, "frame")
    plain = dsr.register(images, pyramid_levels=2, pyramid_min_size=8, panorama_spacing=1.0)
    numpy = dsr.register(images, pyramid_levels=np.int64(2), pyramid_min_size=8,
                         panorama_spacing=np.float64(1.0), uncertainty=np.False_)
    assert all(np.array_equal(a, b) for a, b in zip(plain.poses, numpy.poses))


def test_options_hold_for_their_call_only(sequence):
    images = files(sequence, "frame")
    first = dsr.register(images, **LEVELS)
    dsr.register(images, **LEVELS, max_iterations=1, max_recoveries=0, max_misfit_ratio=0)
    assert all(np.array_equal(a, b) for a, b in
               zip(dsr.register(images, **LEVELS).poses, first.poses))
    # Two registrations at once, each with its own options (the solve runs without the GIL).
    results = {}

    def run(name, **options):
        results[name] = dsr.register(images, **options).poses

    threads = [threading.Thread(target=run, args=("levels",), kwargs=LEVELS),
               threading.Thread(target=run, args=("coarse",),
                                kwargs={"pyramid_levels": 1, "max_iterations": 2,
                                        "max_recoveries": 0, "max_misfit_ratio": 0})]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    # Each equals its own run, one after the other.
    coarse = dsr.register(images, pyramid_levels=1, max_iterations=2, max_recoveries=0,
                          max_misfit_ratio=0)
    assert all(np.array_equal(a, b) for a, b in zip(results["levels"], first.poses))
    assert all(np.array_equal(a, b) for a, b in zip(results["coarse"], coarse.poses))
    assert not all(np.array_equal(a, b) for a, b in zip(coarse.poses, first.poses))
    assert all(np.array_equal(a, b) for a, b in
               zip(dsr.register(images, **LEVELS).poses, first.poses))


# A registration started from its own result lands within this (mm, and rotation matrix
# entries) of it: in the default mean gauge each solve's prior holds the frames' mean where
# that solve starts, and the cost is not exactly invariant under moving every frame
# together, so the fixed point moves with the start by a few thousandths of a voxel
# (docs/design.md 4.8; 4e-3 mm measured here, below 1e-3 with --gauge=frame0).
RESTART_TOLERANCE = 1e-2


def test_init_file_is_matched_to_the_images_by_name(sequence, tmp_path):
    images = files(sequence, "frame")
    result = dsr.register(images, **LEVELS)
    # The file lists the frames in another order; its names put them back.
    order = [2, 0, 1]
    dsr.write_poses(tmp_path / "init.json", [result.poses[i] for i in order],
                    images=[os.path.basename(images[i]) for i in order])
    again = dsr.register(images, init=tmp_path / "init.json", **LEVELS)
    for a, b in zip(again.poses, result.poses):
        assert np.abs(a - b).max() < RESTART_TOLERANCE


def test_initial_poses_start_the_registration(sequence):
    images = files(sequence, "frame")
    result = dsr.register(images, **LEVELS)
    again = dsr.register(images, initial_poses=result.poses, **LEVELS)
    for a, b in zip(again.poses, result.poses):
        assert np.abs(a - b).max() < RESTART_TOLERANCE
    with pytest.raises(ValueError, match="initial_poses: 2 poses for 3 images"):
        dsr.register(images, initial_poses=result.poses[:2], **LEVELS)


def test_fuse_writes_dsr_fuses_panorama(sequence, tmp_path):
    frames, masks = files(sequence, "frame"), files(sequence, "mask")
    result = dsr.register(frames, masks, **LEVELS)
    result.save(tmp_path / "poses.json")
    for blend in ("feather", "mean"):
        run = run_tool("dsr_fuse", "--images=" + ",".join(frames), "--masks=" + ",".join(masks),
                       f"--poses={tmp_path / 'poses.json'}", f"--blend={blend}",
                       f"--out={tmp_path / 'pano.nii.gz'}", f"--out_count={tmp_path / 'n.nii.gz'}")
        assert run.returncode == 0, run.stderr
        for poses in (result, tmp_path / "poses.json"):
            mean, count = dsr.fuse(frames, poses, masks, blend=blend)
            assert np.array_equal(mean.array, dsr.read_image(tmp_path / "pano.nii.gz").array)
            assert np.array_equal(count.array, dsr.read_image(tmp_path / "n.nii.gz").array)
            assert count.array.max() == 3
    # As SimpleITK images: the same voxels and grid as dsr_fuse's file.
    import SimpleITK as sitk  # noqa: PLC0415 (optional dependency)
    mean, count = dsr.fuse(frames, result, masks, blend="mean")
    written = sitk.ReadImage(str(tmp_path / "pano.nii.gz"))
    ours = mean.to_simpleitk()
    assert np.array_equal(sitk.GetArrayFromImage(ours), sitk.GetArrayFromImage(written))
    for get in ("GetSpacing", "GetOrigin", "GetDirection"):
        assert np.allclose(getattr(ours, get)(), getattr(written, get)(), atol=1e-5)
    assert count.to_simpleitk().GetSize() == written.GetSize()
    # Arrays and plain pose matrices give the same panorama as the files.
    images = [dsr.read_image(p) for p in frames]
    mean, _ = dsr.fuse(images, result.poses, [dsr.read_image(p) for p in masks], blend="mean")
    assert np.array_equal(mean.array, dsr.read_image(tmp_path / "pano.nii.gz").array)
    with pytest.raises(ValueError, match="2 poses for 3 images"):
        dsr.fuse(frames, result.poses[:2], masks)


def test_write_tfm_writes_dsr_registers_transform(sequence, tmp_path):
    frames = files(sequence, "frame")
    run = run_tool("dsr_register", "--images=" + ",".join(frames), "--progress=false",
                   f"--out_poses={tmp_path / 'p.json'}", f"--out_tfm_dir={tmp_path / 'tfm'}",
                   *cli_flags(LEVELS))
    assert run.returncode == 0, run.stderr
    poses = dsr.read_poses(tmp_path / "p.json")["frame_from_world"]
    dsr.write_tfm(poses[1], tmp_path / "frame_01.tfm")
    written = (tmp_path / "tfm" / "frame_01.tfm").read_bytes()
    assert (tmp_path / "frame_01.tfm").read_bytes() == written


def test_progress_bar_counts_the_iterations(sequence, capsys):
    seen = []
    dsr.register(files(sequence, "frame"), **LEVELS, progress_bar=True,
                 on_iteration=lambda label, record: seen.append(label))
    bar = capsys.readouterr().err
    assert f"{len(seen)}it" in bar.replace(" ", "") and "dsr" in bar and "cost=" in bar


def test_every_public_annotation_resolves():
    """The package's annotations resolve (typing.get_type_hints), so type checkers and
    documentation tools can read them: dsr.Sequence, the simulator's sequence, does not
    shadow typing.Sequence."""
    for name in dsr.__all__:
        item = getattr(dsr, name)
        if inspect.isfunction(item):
            typing.get_type_hints(item)
        elif inspect.isclass(item):
            for _, method in inspect.getmembers(item, inspect.isfunction):
                typing.get_type_hints(method)
    images = typing.get_type_hints(dsr.register)["images"]
    assert typing.get_origin(images) is collections.abc.Sequence
