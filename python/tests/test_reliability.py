"""Inputs and outputs a hostile or careless user gives: special files, interrupted runs,
byte-order marks, paths that cannot be written, and arrays numpy would quietly convert. Each
gets one clear line (exit 2 for the tools, ValueError/TypeError/OSError in Python) or is
handled; nothing is replaced, nothing hangs."""
import os
import signal
import stat
import threading

import numpy as np
import pytest
import SimpleITK as sitk

import dsr
from cli import error_line, run_tool

SMALL = {"num_frames": 3, "phantom_size": 64, "frame_size": (32, 32, 28),
         "max_rotation_deg": 6, "max_translation_voxels": 3, "min_depth_voxels": 2, "sigma": 10}


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    folder = tmp_path_factory.mktemp("reliability")
    simulated = dsr.simulate(**SMALL)
    frames = []
    for i, frame in enumerate(simulated.frames):
        frames.append(str(folder / f"frame_{i:02d}.nii.gz"))
        dsr.write_image(frame, frames[-1])
    return folder, frames, simulated


def images_flag(frames):
    return "--images=" + ",".join(frames)


def special_outputs(folder):
    """A FIFO and, as root, a private character device standing in for /dev/null."""
    fifo = folder / "out.fifo"
    if not fifo.exists():
        os.mkfifo(fifo)
    outputs = [fifo]
    if os.geteuid() == 0:
        device = folder / "null"
        if not device.exists():
            os.mknod(device, stat.S_IFCHR | 0o600, os.makedev(1, 3))
        outputs.append(device)
    return outputs


def test_special_files_are_never_replaced_by_an_output(sequence):
    folder, frames, _ = sequence
    for special in special_outputs(folder):
        kind = stat.S_IFMT(os.stat(special).st_mode)
        line = error_line("dsr_register", images_flag(frames), f"--out_poses={special}")
        assert "not a regular file" in line and special.name in line
        line = error_line("dsr_fuse", images_flag(frames), f"--out={special}",
                          f"--poses={folder / 'none.json'}")
        assert special.name in line
        assert stat.S_IFMT(os.stat(special).st_mode) == kind
        result = dsr.register(frames, pyramid_levels=1)
        with pytest.raises(OSError, match="not a regular file"):
            result.save(special)
        assert stat.S_IFMT(os.stat(special).st_mode) == kind


def test_poses_inputs_that_never_end_are_refused_at_once(sequence):
    folder, frames, _ = sequence
    fifo = special_outputs(folder)[0]
    out = f"--out_poses={folder / 'p.json'}"
    for flag in ("--init", "--gt_poses"):
        line = error_line("dsr_register", images_flag(frames), out, f"{flag}={fifo}")
        assert "not a regular file" in line and flag in line
    line = error_line("dsr_fuse", images_flag(frames), f"--poses={fifo}",
                      f"--out={folder / 'pan.nii.gz'}")
    assert "not a regular file" in line and "--poses" in line


def test_a_zero_spacing_in_a_nifti_header_is_refused(sequence, tmp_path):
    _, frames, _ = sequence
    image = sitk.ReadImage(frames[1])
    path = tmp_path / "pixdim0.nii"
    sitk.WriteImage(image, str(path))
    data = bytearray(path.read_bytes())
    data[80:84] = np.float32(0.0).tobytes()  # pixdim[1]
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError, match=r"pixdim0\.nii: pixdim\[1\] is 0"):
        dsr.register([frames[0], str(path), frames[2]])


def test_one_outlier_voxel_is_named_not_registered(sequence, tmp_path):
    _, frames, _ = sequence
    image = sitk.ReadImage(frames[1])
    array = sitk.GetArrayFromImage(image)
    array[5, 5, 5] = 1e30
    spike = sitk.GetImageFromArray(array)
    spike.CopyInformation(image)
    path = tmp_path / "spike.nii.gz"
    sitk.WriteImage(spike, str(path))
    line = error_line("dsr_register", images_flag([frames[0], str(path), frames[2]]),
                      f"--out_poses={tmp_path / 'p.json'}")
    assert "spike.nii.gz" in line and "outlier intensity" in line and "(5,5,5)" in line


def test_a_byte_order_mark_is_skipped(sequence, tmp_path):
    _, frames, _ = sequence
    listing = tmp_path / "frames.txt"
    listing.write_bytes(b"\xef\xbb\xbf" + "\n".join(frames).encode() + b"\n")
    flags = tmp_path / "run.flags"
    flags.write_bytes(b"\xef\xbb\xbf--out_poses=" + str(tmp_path / "b.json").encode() + b"\n")
    run = run_tool("dsr_register", f"--images=@{listing}", f"--flagfile={flags}",
                   "--pyramid_levels=1", "--progress=false")
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "b.json").stat().st_size > 0
    python_flags = tmp_path / "python.flags"
    python_flags.write_bytes(b"\xef\xbb\xbf--pyramid_levels=1\n")
    assert dsr.register(frames, flagfile=str(python_flags)).summary["levels"] == 1


def test_outputs_that_cannot_be_written_are_refused_before_any_work(sequence, tmp_path):
    _, frames, _ = sequence
    poses = f"--out_poses={tmp_path / 'p.json'}"
    (tmp_path / "dangling").symlink_to(tmp_path / "missing")
    line = error_line("dsr_register", images_flag(frames), poses,
                      f"--out_tfm_dir={tmp_path / 'dangling'}")
    assert "--out_tfm_dir" in line and "symlink to a missing" in line
    line = error_line("dsr_register", images_flag(frames), f"--out_poses={tmp_path}/new.json/")
    assert "--out_poses" in line and "ends with '/'" in line
    long_name = tmp_path / ("a" * 300 + ".json")
    line = error_line("dsr_register", images_flag(frames), f"--out_poses={long_name}")
    assert "--out_poses" in line and "more than the 255" in line
    (tmp_path / "loopA").symlink_to(tmp_path / "loopB")
    (tmp_path / "loopB").symlink_to(tmp_path / "loopA")
    line = error_line("dsr_simulate", f"--out_dir={tmp_path / 'loopA'}", "--num_frames=2")
    assert "--out_dir" in line and "cannot be followed" in line


def test_a_flag_without_its_value_does_not_swallow_the_next(sequence, tmp_path):
    line = error_line("dsr_register", "--images", f"--out_poses={tmp_path / 'p.json'}")
    assert line.startswith("--images: needs a value") and "is a flag of its own" in line


def test_ctrl_c_stops_a_registration_between_iterations():
    """Without an on_iteration callback, KeyboardInterrupt arrives while the solve runs (at
    the first iteration after the signal), not when the registration ends: the signal comes
    0.2 s into a registration whose global search alone takes longer than that. Python's
    own SIGINT handler is installed for the test: a shell that starts the suite in the
    background (`cmd &`) hands it SIGINT ignored, and Python then keeps it ignored."""
    big = dsr.simulate(num_frames=8, frame_size=(48, 48, 40), phantom_size=128, seed=2)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(0.2, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            dsr.register(big.frames, masks=big.masks, init="global", uncertainty=True)
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)


def test_arrays_numpy_would_convert_quietly_are_named(sequence):
    _, _, simulated = sequence
    frames = list(simulated.frames)
    huge = list(frames)
    huge[1] = dsr.Image(frames[1].array.astype(np.float64) * 1e300, frames[1].spacing,
                        frames[1].origin, frames[1].direction)
    with pytest.raises(ValueError, match=r"image 1: voxel .* beyond float32's range"):
        dsr.register(huge)
    with pytest.raises(TypeError, match=r"images: a sequence of images or paths, not one path"):
        dsr.register("frame_00.nii.gz")
    vector = sitk.Compose([frames[1].to_simpleitk()] * 3)
    with pytest.raises(ValueError, match=r"image 1: vector pixels"):
        dsr.register([frames[0].to_simpleitk(), vector, frames[2].to_simpleitk()])
    flat = list(frames)
    flat[1] = dsr.Image(frames[1].array, frames[1].spacing, frames[1].origin, np.eye(2))
    with pytest.raises(ValueError, match=r"image 1: the direction needs 9 numbers"):
        dsr.register(flat)
    four = list(frames)
    four[1] = dsr.Image(frames[1].array[..., None], frames[1].spacing, frames[1].origin,
                        frames[1].direction)
    with pytest.raises(ValueError, match=r"image 1: 4D array"):
        dsr.register(four)


def test_a_nifti_origin_its_header_cannot_hold_is_named(sequence, tmp_path):
    _, frames, _ = sequence
    moved = []
    for i, path in enumerate(frames):
        image = sitk.ReadImage(path)
        image.SetOrigin(tuple(o + 1e9 for o in image.GetOrigin()))
        moved.append(str(tmp_path / f"f{i}.nii.gz"))
        sitk.WriteImage(image, moved[-1])
    line = error_line("dsr_register", images_flag(moved), f"--out_poses={tmp_path / 'p.json'}")
    assert "f0.nii.gz: origin 1e+09 mm" in line and "float32" in line


def test_bad_initial_poses_and_unknown_options_are_named(sequence):
    _, frames, _ = sequence
    start = [np.eye(4), np.eye(4), np.full((4, 4), np.nan)]
    with pytest.raises(ValueError, match=r"initial_poses: pose 2: .*not finite"):
        dsr.register(frames, initial_poses=start)
    with pytest.raises(ValueError, match=r"--out_dir=simout: unknown flag"):
        dsr.simulate(out_dir="simout", num_frames=2)
