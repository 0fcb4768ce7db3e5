"""One options table: the tools' flags, the Python keyword arguments and the docs' option
reference come from it with the same names, defaults and help; flagfiles get the command
line's checks; registrations in two threads do not share options."""
import html
import importlib.util
import json
import pathlib
import re

import numpy as np
import pytest

import dsr
from cli import run_tool

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
    tool_defaults = {"dsr_compare": {"init", "min_kept_overlap", "max_misfit_ratio",
                                     "max_pair_mismatch_ratio", "max_structure_fraction",
                                     "max_pose_error_voxels", "progress"}}
    for name, (help_text, kind, default) in listing.items():
        option = table[name]
        assert help_text == " ".join(option["help"].split()), name
        assert kind == option["type"], name
        if name in tool_defaults.get(tool, set()):
            continue  # the tool's own default (dsr_compare measures, checks off)
        shown = default.strip('"')
        if option["type"] == "double":
            assert float(shown) == float(option["default"]), name
        else:
            assert shown == option["default"], name


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
    spec = importlib.util.spec_from_file_location("gen_options", ROOT / "docs" / "gen_options.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    table = table_json()
    (tmp_path / "table.json").write_text(json.dumps(table))
    assert gen.main([str(tmp_path / "table.json"), "--out", str(tmp_path / "options.md")]) in (0, None)
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
