"""One options table: the tools' flags, the Python keyword arguments and the docs' option
reference come from it with the same names, defaults and help; flagfiles get the command
line's checks; registrations in two threads do not share options."""
import html
import importlib.util
import inspect
import json
import os
import pathlib
import re
import stat
import typing

import numpy as np
import pytest

import dsr
from cli import error_line, run_tool

ROOT = pathlib.Path(__file__).parents[2]
TOOLS = {"dsr_register", "dsr_fuse", "dsr_simulate", "dsr_compare"}


def table_json():
    run = run_tool("dsr_options", "--format=json")
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def test_python_lists_the_table_the_tools_print():
    ours = dsr.options()
    theirs = {o["name"]: o for o in table_json()}
    assert set(ours) == set(theirs)
    for name, option in ours.items():
        for key in ("type", "default", "group", "front_ends", "help"):
            assert option[key] == theirs[name][key], (name, key)


def flag_listing(tool):
    """name -> (help, type, default text) of `tool --helpshort` (gflags' listing)."""
    run = run_tool(tool, "--helpshort")
    assert run.returncode == 0, run.stderr
    entries, current = [], None
    for line in run.stdout.splitlines():
        if line.startswith("    -"):
            current = [line]
            entries.append(current)
        elif line.startswith("      ") and current is not None:
            current.append(line)
        else:
            current = None
    pattern = re.compile(r"^-(\w+) \((.*)\) type: (\w+) default: (.*)$")
    listing = {}
    for entry in entries:
        match = pattern.match(" ".join(" ".join(entry).split()))
        assert match, entry
        name, help_text, kind, default = match.groups()
        listing[name] = (help_text, kind, default)
    return listing


@pytest.mark.parametrize("tool", sorted(TOOLS))
def test_each_tool_lists_exactly_its_options_of_the_table(tool):
    listing = flag_listing(tool)
    table = {o["name"]: o for o in table_json() if tool in o["front_ends"]}
    assert set(listing) == set(table)
    for name, (help_text, kind, default) in listing.items():
        option = table[name]
        assert help_text == " ".join(option["help"].split()), name
        assert kind == option["type"], name
        # The table's default, or the tool's own where the table gives one.
        expected = option["front_end_defaults"].get(tool, option["default"])
        shown = default.strip('"')
        if option["type"] == "double":
            assert float(shown) == float(expected), name
        elif option["type"] == "bool":
            assert shown == {"0": "false", "1": "true"}.get(expected, expected), name
        else:
            assert shown == expected, name


def test_python_functions_take_their_options_and_refuse_the_others(tmp_path):
    table = dsr.options()
    register = {n for n, o in table.items() if "python:register" in o["front_ends"]}
    simulate = {n for n, o in table.items() if "python:simulate" in o["front_ends"]}
    assert {"max_iterations", "mode", "init", "preset", "uncertainty"} <= register
    assert {"seed", "num_frames", "speckle_looks"} <= simulate
    assert "speckle_looks" not in register and "pyramid_levels" not in simulate
    with pytest.raises(ValueError, match=r"--speckle_looks=2: unknown flag"):
        dsr.register([str(tmp_path / "a.nii.gz"), str(tmp_path / "b.nii.gz")], speckle_looks=2)


def test_the_docs_reference_lists_every_option_with_its_default_and_help(tmp_path):
    spec = importlib.util.spec_from_file_location("gen_options",
                                                  ROOT / "docs" / "gen_options.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    table = table_json()
    (tmp_path / "table.json").write_text(json.dumps(table))
    assert gen.main([str(tmp_path / "table.json"),
                     "--out", str(tmp_path / "options.md")]) in (0, None)
    page = html.unescape((tmp_path / "options.md").read_text())
    for option in table:
        assert option["name"] in page
        assert " ".join(option["help"].split()) in page, option["name"]


def test_a_flagfile_gets_the_command_lines_checks(tmp_path):
    images = [str(tmp_path / "a.nii.gz"), str(tmp_path / "b.nii.gz")]
    with pytest.raises(ValueError, match=r"no_such\.flags: no such file"):
        dsr.register(images, flagfile=str(tmp_path / "no_such.flags"))
    loop = tmp_path / "rec.flags"
    loop.write_text(f"--flagfile={loop}\n")
    with pytest.raises(ValueError, match=r"rec\.flags: includes itself"):
        dsr.register(images, flagfile=str(loop))
    typo = tmp_path / "typo.flags"
    typo.write_text("--typo_flag=3\n")
    with pytest.raises(ValueError, match=r"typo\.flags: line 1: unknown flag --typo_flag"):
        dsr.register(images, flagfile=str(typo))
    junk = tmp_path / "junk.flags"
    junk.write_text("junk line\n")
    with pytest.raises(ValueError, match=r"junk\.flags: line 1: 'junk line' is not --flag"):
        dsr.register(images, flagfile=str(junk))
    with pytest.raises(ValueError, match=r"is a folder"):
        dsr.register(images, flagfile=str(tmp_path))
    bad = tmp_path / "bad.flags"
    bad.write_text("--mask_erosion=99\n")
    with pytest.raises(ValueError, match=r"--mask_erosion=99: must be in \[0, 50\]"):
        dsr.register(images, flagfile=str(bad))


def test_a_flagfiles_values_are_used(tmp_path):
    sequence = dsr.simulate(num_frames=3, phantom_size=64, frame_size=(32, 32, 28),
                            max_rotation_deg=6, max_translation_voxels=3, min_depth_voxels=2,
                            sigma=10)
    flags = tmp_path / "levels.flags"
    flags.write_text("# two levels\n--pyramid_levels=2\n--pyramid_min_size=8\n")
    from_file = dsr.register(sequence.frames, masks=sequence.masks, flagfile=str(flags))
    given = dsr.register(sequence.frames, masks=sequence.masks, pyramid_levels=2,
                         pyramid_min_size=8)
    assert all(np.array_equal(a, b) for a, b in zip(from_file.poses, given.poses))
    assert from_file.summary["levels"] == 2


# The guards the command line has, from the application layer they share.
@pytest.fixture(scope="module")
def small():
    return dsr.simulate(num_frames=3, phantom_size=64, frame_size=(32, 32, 28),
                        max_rotation_deg=6, max_translation_voxels=3, min_depth_voxels=2,
                        sigma=10)


def test_simulate_refuses_up_front_what_would_not_fit():
    with pytest.raises(ValueError,
                       match=r"--frame_size=2048,2048,2048 --num_frames=2: needs about"):
        dsr.simulate(frame_size=(2048, 2048, 2048), num_frames=2, phantom_size=16)


def test_complex_images_are_refused(small):
    images = list(small.frames)
    images[1] = dsr.Image(images[1].array.astype(np.complex64), images[1].spacing,
                          images[1].origin, images[1].direction)
    with pytest.raises(ValueError, match=r"image 1: complex pixels"):
        dsr.register(images, masks=small.masks)


def test_masks_in_memory_are_read_as_mask_files(small):
    """Non-zero = inside, whatever the type: a mask of 0.5 is the mask of 1."""
    halves = [dsr.Image(m.array * 0.5, m.spacing, m.origin, m.direction) for m in small.masks]
    ones = dsr.register(small.frames, masks=small.masks, pyramid_levels=2, pyramid_min_size=8)
    half = dsr.register(small.frames, masks=halves, pyramid_levels=2, pyramid_min_size=8)
    assert all(np.array_equal(a, b) for a, b in zip(ones.poses, half.poses))
    bad = list(halves)
    bad[1] = dsr.Image(np.full_like(halves[1].array, np.nan), halves[1].spacing,
                       halves[1].origin, halves[1].direction)
    with pytest.raises(ValueError, match=r"mask 1: a voxel is NaN"):
        dsr.register(small.frames, masks=bad)


def test_fuse_refuses_poses_that_are_not_rigid(small):
    for bad, cause in [(np.full((4, 4), np.nan), "not finite"),
                       (np.diag([3.0, 1, 1, 1]), "not rigid"),
                       (np.diag([-1.0, 1, 1, 1]), "reflection")]:
        poses = [np.eye(4), bad, np.eye(4)]
        with pytest.raises(ValueError, match=rf"pose 1: .*{cause}"):
            dsr.fuse(small.frames, poses, masks=small.masks)


def test_writes_never_replace_a_registrations_inputs(tmp_path, small):
    paths = []
    for i, frame in enumerate(small.frames):
        paths.append(str(tmp_path / f"f{i}.nii.gz"))
        dsr.write_image(frame, paths[-1])
    before = [pathlib.Path(p).read_bytes() for p in paths]
    result = dsr.register(paths, pyramid_levels=2, pyramid_min_size=8)
    with pytest.raises(OSError, match=r"f1\.nii\.gz.*inputs are never overwritten"):
        result.save(paths[1])
    with pytest.raises(OSError, match=r"f2\.nii\.gz.*inputs are never overwritten"):
        dsr.write_image(small.frames[0], paths[2])
    with pytest.raises(OSError, match=r"f0\.nii\.gz.*inputs are never overwritten"):
        dsr.write_poses(paths[0], result.poses)
    assert [pathlib.Path(p).read_bytes() for p in paths] == before
    fifo = tmp_path / "poses.json"
    os.mkfifo(fifo)
    with pytest.raises(OSError, match=r"poses\.json: is a FIFO"):
        result.save(fifo)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_keyword_arguments_are_typed_and_documented_from_the_table():
    table = dsr.options()
    for function, front_end in [(dsr.register, "python:register"), (dsr.fuse, "python:fuse"),
                                (dsr.simulate, "python:simulate")]:
        parameters = inspect.signature(function).parameters
        for name, option in table.items():
            if front_end not in option["front_ends"]:
                continue
            assert name in parameters, (function.__name__, name)
            assert name in function.__doc__
            default = option["front_end_defaults"].get(front_end, option["default"])
            assert str(parameters[name].default).lower() == default.lower() or \
                parameters[name].default == pytest.approx(float(default)), (name, default)
            if name in ("mode", "init", "blend"):
                continue  # written out in the function itself
            assert parameters[name].kind == inspect.Parameter.KEYWORD_ONLY
            expected = {"bool": bool, "int32": int, "uint64": int, "double": float,
                        "string": str}[option["type"]]
            assert parameters[name].annotation is expected, name
        assert "flagfile" in parameters
    assert inspect.signature(dsr.register).parameters["max_iterations"].default == 100
    assert inspect.signature(dsr.simulate).parameters["num_frames"].default == 11
    assert table["blend"]["front_end_defaults"] == {"python:fuse": "feather"}
    assert table["init"]["front_end_defaults"] == {"dsr_compare": "identity"}
    typing.get_type_hints(dsr.register)  # the annotations resolve


def test_simulate_phases_are_a_beating_source_whose_phase_0_is_the_still_sequence():
    small = dict(num_frames=3, phantom_size=64, frame_size=(32, 32, 28), max_rotation_deg=6,
                 max_translation_voxels=3, min_depth_voxels=2, sigma=10)
    still = dsr.simulate(**small)
    assert still.phases == []
    # A 28-voxel depth: the default beat radius is 7 mm, so at most 1.75 mm.
    beating = dsr.simulate(num_phases=3, beat_amplitude_mm=1.5, **small)
    assert len(beating.phases) == 3 and all(len(view) == 3 for view in beating.phases)
    for i, view in enumerate(beating.phases):
        assert view[0] is beating.frames[i]
        assert np.array_equal(view[0].array, still.frames[i].array)
        assert not np.array_equal(view[1].array, view[0].array)
    with pytest.raises(ValueError, match=r"--num_phases=65: must be in \[1, 64\]"):
        dsr.simulate(num_phases=65, **small)


# What a careless caller passes: None for the flagfile, names twice, NUL characters,
# non-finite numbers, a generator, 4D masks. Each accepted as the command line takes the
# same, or a ValueError naming the argument.
def test_flagfile_none_is_no_flagfile(small):
    given = dsr.register(small.frames, masks=small.masks, pyramid_levels=1, flagfile=None)
    plain = dsr.register(small.frames, masks=small.masks, pyramid_levels=1)
    assert all(np.array_equal(a, b) for a, b in zip(given.poses, plain.poses))
    dsr.fuse(small.frames, given, masks=small.masks, flagfile=None)
    assert dsr.simulate(num_frames=2, phantom_size=32, frame_size=(8, 8, 8), min_depth_voxels=0,
                        max_rotation_deg=0, max_translation_voxels=0, flagfile=None).frames


def test_names_given_twice_are_refused(small, tmp_path):
    names = ["a", "a", "b"]
    with pytest.raises(ValueError, match=r"names: 'a' is given twice \(images 0 and 1\); each "
                                         r"image needs its own name"):
        dsr.register(small.frames, masks=small.masks, names=names)
    with pytest.raises(ValueError, match=r"names: 'a' is given twice \(images 0 and 1\)"):
        dsr.fuse(small.frames, [np.eye(4)] * 3, masks=small.masks, names=names)
    with pytest.raises(TypeError, match=r"names: a sequence of names"):
        dsr.register(small.frames, masks=small.masks, names="abc")


def test_a_nul_character_is_refused_naming_the_option(tmp_path):
    images = [str(tmp_path / "a.nii.gz"), str(tmp_path / "b.nii.gz")]
    for options, shown in [({"max_iterations": "50\0junk"}, r"--max_iterations=50\\0junk"),
                           ({"mode": "dsr\0pairwise"}, r"--mode=dsr\\0pairwise"),
                           ({"init": "auto\0"}, r"--init=auto\\0")]:
        with pytest.raises(ValueError, match=shown + r": contains a NUL character") as error:
            dsr.register(images, **options)
        assert "\0" not in str(error.value)
    with pytest.raises(ValueError, match=r"--seed=1\\0: contains a NUL character"):
        dsr.simulate(seed="1\0")
    with pytest.raises(ValueError, match=r"images: the path of image 1 contains a NUL"):
        dsr.register([images[0], images[1] + "\0x"])
    with pytest.raises(ValueError, match=r"names: name 0 contains a NUL character"):
        dsr.register(images, names=["a\0", "b"])


@pytest.mark.parametrize("front_end", ["python:register", "python:fuse", "python:simulate"])
def test_every_floating_point_option_must_be_finite(front_end, tmp_path):
    """Every double option of every function refuses inf and nan, naming itself, by its own
    rule or by the one every double option has (from keyword arguments and flagfiles)."""
    images = [str(tmp_path / "a.nii.gz"), str(tmp_path / "b.nii.gz")]
    call = {"python:register": lambda **o: dsr.register(images, **o),
            "python:fuse": lambda **o: dsr.fuse(images, [np.eye(4)] * 2, **o),
            "python:simulate": lambda **o: dsr.simulate(**o)}[front_end]
    doubles = [n for n, o in dsr.options().items()
               if front_end in o["front_ends"] and o["type"] == "double"]
    assert doubles
    for name in doubles:
        for value, text in ((float("inf"), "inf"), (float("-inf"), "-inf"), (float("nan"), "nan")):
            with pytest.raises(ValueError, match=rf"^--{name}={text}: .*"):
                call(**{name: value})
    # From a flagfile too (register's --rebuild_tolerance, whose own rule once took inf).
    name = "rebuild_tolerance" if front_end == "python:register" else doubles[0]
    flags = tmp_path / "inf.flags"
    flags.write_text(f"--{name}=inf\n")
    with pytest.raises(ValueError, match=rf"--{name}=inf: must be"):
        call(flagfile=str(flags))
    with pytest.raises(ValueError, match=r"^--rebuild_tolerance=inf: must be finite and > 0$"):
        dsr.register(images, rebuild_tolerance=float("inf"))


def test_fuse_takes_poses_from_any_iterable(small):
    listed = dsr.fuse(small.frames, list(small.frame_from_world), masks=small.masks)
    generated = dsr.fuse(small.frames, (p for p in small.frame_from_world), masks=small.masks)
    assert np.array_equal(listed[0].array, generated[0].array)
    with pytest.raises(ValueError, match=r"poses: a Result, a poses file or one 4x4 array per "
                                         r"image, not int"):
        dsr.fuse(small.frames, 5, masks=small.masks)
    with pytest.raises(ValueError, match=r"pose 1: not a 4x4 array of numbers"):
        dsr.fuse(small.frames, [np.eye(4), "abc", np.eye(4)], masks=small.masks)


def test_a_4d_mask_array_is_taken_as_a_4d_mask_file(small, tmp_path):
    """Phases equal: the view's 3D mask, as dsr_register takes such a 4D mask file; phases
    that differ: refused with dsr_register's message."""
    def stacked(mask, change=False):
        array = np.stack([mask.array, mask.array]).astype(np.float32)
        if change:
            array[1, 0, 0, 0] = 1 - array[1, 0, 0, 0]
        return dsr.Image(array, mask.spacing, mask.origin, mask.direction)

    flat = dsr.register(small.frames, masks=small.masks, pyramid_levels=1)
    four = dsr.register(small.frames, masks=[stacked(m) for m in small.masks], pyramid_levels=1)
    assert all(np.array_equal(a, b) for a, b in zip(flat.poses, four.poses))
    panorama = dsr.fuse(small.frames, flat, masks=[stacked(m) for m in small.masks])[0]
    assert np.array_equal(panorama.array, dsr.fuse(small.frames, flat, masks=small.masks)[0].array)
    masks = [stacked(m, change=i == 1) for i, m in enumerate(small.masks)]
    frames, files = [], []
    for i, (frame, mask) in enumerate(zip(small.frames, masks)):
        frames.append(str(tmp_path / f"f{i}.nii.gz"))
        files.append(str(tmp_path / f"m{i}.nii.gz"))
        dsr.write_image(frame, frames[-1])
        dsr.write_image(mask, files[-1])
    line = error_line("dsr_register", "--images=" + ",".join(frames), "--masks=" + ",".join(files),
                      f"--out_poses={tmp_path / 'p.json'}")
    assert line.startswith(files[1] + ": mask phase 1 differs from phase 0 at voxel (0,0,0)")
    for call in (lambda: dsr.register(small.frames, masks=masks),
                 lambda: dsr.fuse(small.frames, flat, masks=masks)):
        with pytest.raises(ValueError) as error:
            call()
        assert str(error.value) == "mask 1" + line[len(files[1]):]
