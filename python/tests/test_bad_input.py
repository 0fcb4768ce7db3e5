"""The bad-input catalogue (tools/bad_input_catalogue_test.cc) through Python: every entry
that applies to the package raises ValueError with the message the command-line tool prints
for the same input, and leaves no file behind. The inputs are crafted as the catalogue's
are: MetaImage headers by hand, NIfTI files written by the tools and then damaged."""
import math

import numpy as np
import pytest

import dsr
from cli import cli_flags, error_line, run_tool

def write_mha(path, ndims="3", size="16 16 16", spacing="1 1 1", matrix="1 0 0 0 1 0 0 0 1",
              offset="0 0 0", channels=None, count=16 * 16 * 16, special=None,
              special_voxel=100):
    """A MetaImage with inline float data: a textured cube, valid apart from what the
    arguments break."""
    header = (f"ObjectType = Image\nNDims = {ndims}\nBinaryData = True\n"
              "BinaryDataByteOrderMSB = False\nCompressedData = False\n"
              f"TransformMatrix = {matrix}\nOffset = {offset}\nElementSpacing = {spacing}\n"
              f"DimSize = {size}\n")
    if channels is not None:
        header += f"ElementNumberOfChannels = {channels}\n"
    header += "ElementType = MET_FLOAT\nElementDataFile = LOCAL\n"
    data = 1.0 + ((np.arange(count * (channels or 1)) * 37) % 101).astype(np.float32)
    if special is not None:
        data[special_voxel] = special
    path.write_bytes(header.encode() + data.astype("<f4").tobytes())


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """The catalogue's inputs: a small simulated sequence and damaged or odd files."""
    d = tmp_path_factory.mktemp("catalogue")
    run = run_tool("dsr_simulate", f"--out_dir={d}", "--phantom_size=48",
                   "--frame_size=20,20,16", "--num_frames=3", "--max_rotation_deg=4",
                   "--max_translation_voxels=1", "--min_depth_voxels=2", "--sigma=5")
    assert run.returncode == 0, run.stderr
    data = (d / "frame_01.nii.gz").read_bytes()
    (d / "truncated.nii.gz").write_bytes(data[:len(data) // 2])
    (d / "corrupt.nii.gz").write_bytes(b"\x5a" * 64 + data[64:])
    (d / "empty.nii").write_bytes(b"")
    write_mha(d / "good.mha")
    write_mha(d / "flat2d.mha", ndims="2", size="64 64", spacing="1 1", matrix="1 0 0 1",
              offset="0 0")
    write_mha(d / "time4d.mha", ndims="4", size="16 16 16 3", spacing="1 1 1 1",
              matrix="1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", offset="0 0 0 0",
              count=16 * 16 * 16 * 3)
    write_mha(d / "vector.mha", channels=3)
    write_mha(d / "zero_spacing.mha", spacing="0 1 1")
    write_mha(d / "negative_spacing.mha", spacing="1 -2 1")
    write_mha(d / "singular_direction.mha", matrix="1 0 0 1 0 0 0 0 1")
    write_mha(d / "nanometre_spacing.mha", spacing="1e-9 1e-9 1e-9")
    write_mha(d / "huge_spacing.mha", spacing="1e9 1e9 1e9")
    write_mha(d / "nan.mha", special=math.nan)
    write_mha(d / "inf.mha", special=math.inf)
    write_mha(d / "negative.mha", special=-5.0, special_voxel=8 + 16 * (8 + 16 * 8))
    write_mha(d / "mask_other_size.mha")
    frame0 = dsr.read_image(d / "frame_00.nii.gz")
    zero = dsr.Image(np.zeros_like(frame0.array), frame0.spacing, frame0.origin,
                     frame0.direction)
    dsr.write_image(zero, d / "all_zero.nii.gz")
    dsr.write_image(zero, d / "mask_empty.nii.gz")
    ramp = np.broadcast_to(10.0 + 3.0 * np.arange(frame0.array.shape[2], dtype=np.float32),
                           frame0.array.shape)
    for name in ("ramp_a.nii.gz", "ramp_b.nii.gz"):
        dsr.write_image(dsr.Image(np.array(ramp), frame0.spacing, frame0.origin,
                                  frame0.direction), d / name)
    (d / "not_json.json").write_text('{"frames": [ this is not json')
    (d / "wrong_shape.json").write_text(
        '{"frames":[{"image":"a","T":[[1,0,0],[0,1,0],[0,0,1]]}]}')
    identity = np.eye(4).tolist()
    (d / "non_rigid.json").write_text(
        '{"frames":[{"image":"a","T":[[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]},'
        f'{{"image":"b","T":{identity}}},{{"image":"c","T":{identity}}}]}}')
    dsr.write_poses(d / "two_frames.json", [np.eye(4)] * 2, images=["a", "b"])
    apart = [np.eye(4), np.eye(4), np.eye(4)]
    apart[2] = np.eye(4)
    apart[2][0, 3] = 300.0
    dsr.write_poses(d / "apart.json", apart)
    apart[2][0, 3] = 1e300
    dsr.write_poses(d / "astronomical.json", apart)
    dsr.write_poses(d / "strangers.json", [np.eye(4)] * 3,
                    images=["x.nii.gz", "y.nii.gz", "z.nii.gz"])
    return d


FRAMES = ["frame_00.nii.gz", "frame_01.nii.gz", "frame_02.nii.gz"]
MASKS = ["mask_00.nii.gz", "mask_01.nii.gz", "mask_02.nii.gz"]
F0 = ["frame_00.nii.gz"]

# dsr_register entries: (images, masks or None, options). Options are the flags by name;
# "init" a file of the inputs. The CLI gets the same as --images, --masks and flags.
REGISTER = [
    # Image files.
    (F0 + ["missing.nii.gz"], None, {}),
    (F0 + ["."], None, {}),  # a folder
    (F0 + ["empty.nii"], None, {}),
    (F0 + ["corrupt.nii.gz"], None, {}),
    (F0 + ["truncated.nii.gz"], None, {}),
    (F0 + ["flat2d.mha"], None, {}),
    (F0 + ["time4d.mha"], None, {}),
    (F0 + ["vector.mha"], None, {}),
    (F0 + ["zero_spacing.mha"], None, {}),
    (F0 + ["negative_spacing.mha"], None, {}),
    (F0 + ["singular_direction.mha"], None, {}),
    (F0 + ["nan.mha"], None, {}),
    (F0 + ["inf.mha"], None, {}),
    (F0 + ["all_zero.nii.gz"], None, {}),
    (F0 + ["all_zero.nii.gz"], MASKS[:2], {}),
    (FRAMES, ["mask_00.nii.gz", "mask_other_size.mha", "mask_02.nii.gz"], {}),
    (FRAMES, ["mask_empty.nii.gz", "mask_01.nii.gz", "mask_02.nii.gz"], {}),
    (FRAMES, MASKS[:1], {}),
    # Frame sets.
    (F0, None, {}),
    (F0 + F0, None, {}),
    (FRAMES, MASKS, {"init": "apart.json"}),
    (["ramp_a.nii.gz", "ramp_b.nii.gz"], None, {"mask_erosion": 1}),
    (["good.mha", "nanometre_spacing.mha"], None, {}),
    (["good.mha", "huge_spacing.mha"], None, {}),
    (FRAMES, MASKS, {"init": "astronomical.json"}),
    # Poses files.
    (FRAMES, MASKS, {"init": "not_json.json"}),
    (FRAMES, MASKS, {"init": "wrong_shape.json"}),
    (FRAMES, MASKS, {"init": "non_rigid.json"}),
    (FRAMES, MASKS, {"init": "two_frames.json"}),
    (FRAMES, MASKS, {"init": "strangers.json"}),
    (FRAMES, MASKS, {"init": "no_such_start"}),
    # Flag values.
    (FRAMES, MASKS, {"panorama_spacing": -1}),
    (FRAMES, MASKS, {"panorama_spacing": 1e300}),
    (FRAMES, MASKS, {"max_iterations": 0}),
    (FRAMES, MASKS, {"max_iterations": "many"}),
    (FRAMES, MASKS, {"mode": "bundle_adjust"}),
    (FRAMES, MASKS, {"linear_solver": "MAGIC"}),
    (FRAMES, MASKS, {"trust_region": "ANNEALING"}),
    (FRAMES, MASKS, {"num_threads": -2}),
    (FRAMES, MASKS, {"step_tolerance": -1}),
    (FRAMES, MASKS, {"num_frames_typo": 3}),
    (FRAMES, MASKS, {"mode": "dba", "memory_budget_mb": 0.01}),
    (FRAMES, MASKS, {"min_kept_overlap": -0.1}),
    (FRAMES, MASKS, {"max_misfit_ratio": "nan"}),
    (FRAMES, MASKS, {"max_recoveries": 11}),
    (FRAMES, MASKS, {"max_misfit_ratio": 0, "min_kept_overlap": 0, "max_pair_mismatch_ratio": 0,
                     "max_structure_fraction": 0}),
    (FRAMES, MASKS, {"max_structure_fraction": 1}),
    (FRAMES, MASKS, {"max_structure_fraction": "nan"}),
    (FRAMES, MASKS, {"preset": "heart"}),
    (FRAMES, MASKS, {"max_pose_error_voxels": -1}),
    (FRAMES, MASKS, {"photometric": "gamma"}),
    (FRAMES, MASKS, {"max_pair_mismatch_ratio": 1}),
    (FRAMES, MASKS, {"max_pair_mismatch_ratio": "inf"}),
    (FRAMES, MASKS, {"search_rotations": 0}),
    (FRAMES, MASKS, {"search_pair_rotations": -5}),
    (FRAMES, MASKS, {"search_rotation_deg": 200}),
    (FRAMES, MASKS, {"search_max_axis": 4}),
    (FRAMES, MASKS, {"smoothing": 1e6}),
    (FRAMES, MASKS, {"intensity_transform": "log"}),
    (FRAMES, MASKS, {"panorama_sampling": "dither"}),
    (FRAMES, MASKS, {"mask_rule": "convex"}),
    (["good.mha", "negative.mha"], None, {"intensity_transform": "sqrt"}),
]


def entry_id(entry):
    images, masks, options = entry
    return "-".join([images[-1]] + [f"{k}={v}" for k, v in options.items()] +
                    (["masks"] if masks else []))


@pytest.mark.parametrize("entry", REGISTER, ids=[entry_id(e) for e in REGISTER])
def test_register_raises_the_clis_message(inputs, entry, tmp_path, monkeypatch):
    images, masks, options = entry
    cli = ["--images=" + ",".join(images), f"--out_poses={tmp_path / 'poses.json'}",
           "--pyramid_levels=1", "--progress=false", *cli_flags(options)]
    if masks is not None:
        cli.append("--masks=" + ",".join(masks))
    expected = error_line("dsr_register", *cli, cwd=inputs)
    monkeypatch.chdir(inputs)  # the same relative paths in both messages
    python_options = {"pyramid_levels": 1, **options}
    with pytest.raises(ValueError) as raised:
        dsr.register(images, masks, **python_options)
    assert str(raised.value) == expected
    assert list(tmp_path.iterdir()) == []


def test_images_in_memory_get_the_rules_of_files(inputs, monkeypatch):
    """What the catalogue checks of files, for images given in memory: named by their place
    in the list instead of a file."""
    monkeypatch.chdir(inputs)
    good = dsr.read_image("frame_00.nii.gz")
    zero = dsr.read_image("all_zero.nii.gz")
    with pytest.raises(ValueError, match=r"^image 1: no voxel left in the field of view"):
        dsr.register([good, zero])
    for value, name in ((np.nan, "NaN"), (np.inf, "Inf")):
        bad = dsr.Image(good.array.copy(), good.spacing, good.origin, good.direction)
        bad.array[3, 4, 5] = value
        with pytest.raises(ValueError, match=rf"^image 1: voxel \(5,4,3\) is {name}$"):
            dsr.register([good, bad])
        with pytest.raises(ValueError, match=rf"^image 1: voxel \(5,4,3\) is {name}$"):
            dsr.fuse([good, bad], [np.eye(4)] * 2)
    with pytest.raises(ValueError, match=r"^images: need at least 2 images, got 1$"):
        dsr.register([good])
    with pytest.raises(ValueError, match=r"^masks: 1 masks for 3 images$"):
        dsr.register([good, good, good], [good])
    with pytest.raises(ValueError, match=r"^image 1: spacing"):
        dsr.register([good, dsr.Image(good.array, (1.0, 0.0, 1.0))])


SIMULATE = [
    {"num_frames": 1},
    {"frame_size": "96,96"},
    {"sigma": -3},
    {"intensity_mapping": "doppler"},
    {"echo_reject": 255},
    {"echo_edge_sigma_mm": -1},
    {"echo_edge_weight": 2},
    {"source": "truncated.nii.gz"},
    {"source": "missing.nii.gz"},
]


@pytest.mark.parametrize("options", SIMULATE, ids=[str(o) for o in SIMULATE])
def test_simulate_raises_the_clis_message(inputs, options, tmp_path, monkeypatch):
    expected = error_line("dsr_simulate", f"--out_dir={tmp_path / 's'}", *cli_flags(options),
                          cwd=inputs)
    monkeypatch.chdir(inputs)
    with pytest.raises(ValueError) as raised:
        dsr.simulate(**options)
    assert str(raised.value) == expected


FUSE = [
    (FRAMES, "two_frames.json", {}),
    (FRAMES, "non_rigid.json", {}),
    (FRAMES, "missing.json", {}),
    (FRAMES, "apart.json", {"blend": "max"}),
    (["frame_00.nii.gz", "nan.mha"], "two_frames.json", {}),
]


@pytest.mark.parametrize("entry", FUSE, ids=[f"{e[1]}-{e[0][-1]}-{e[2]}" for e in FUSE])
def test_fuse_raises_the_clis_message(inputs, entry, tmp_path, monkeypatch):
    images, poses, options = entry
    masks = MASKS if len(images) == 3 else None
    cli = ["--images=" + ",".join(images), f"--poses={poses}", f"--out={tmp_path / 'p.nii.gz'}",
           *cli_flags(options)]
    if masks:
        cli.append("--masks=" + ",".join(masks))
    expected = error_line("dsr_fuse", *cli, cwd=inputs)
    monkeypatch.chdir(inputs)
    with pytest.raises(ValueError) as raised:
        dsr.fuse(images, poses, masks, **options)
    assert str(raised.value) == expected


def test_failed_writes_raise_os_errors_and_leave_nothing(inputs, tmp_path, monkeypatch):
    monkeypatch.chdir(inputs)
    result = dsr.register(FRAMES, MASKS, pyramid_levels=1)
    before = (inputs / "frame_02.nii.gz").read_bytes()
    for path in (tmp_path / "missing_folder" / "poses.json", tmp_path):
        with pytest.raises(OSError, match=str(path)):
            result.save(path)
    with pytest.raises(OSError, match="missing_folder"):
        dsr.write_tfm(result.poses[1], tmp_path / "missing_folder" / "f.tfm")
    with pytest.raises(OSError, match="missing_folder"):
        dsr.write_image(dsr.read_image("frame_00.nii.gz"), tmp_path / "missing_folder" / "f.nii")
    assert list(tmp_path.iterdir()) == []
    assert (inputs / "frame_02.nii.gz").read_bytes() == before
