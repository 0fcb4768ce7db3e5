"""dsr.cohort on a LocalCluster of 2 worker processes: 4 small studies, one broken (3 results
and 1 recorded failure with its reason), a rerun that does no work, a killed worker whose
study is retried and never left half-written, and bad manifests refused before any work.
Then what a hostile or careless user gives: rows, flags and out_dirs that cannot be used (one
line each, before any work), refused rows beside good ones, two cohorts on one out_dir, a
rerun after the ground truth changed, a full disk."""
import contextlib
import csv
import json
import os
import re
import shutil
import signal
import threading
import time

import numpy as np
import pytest

import dsr
from dsr import cohort

distributed = pytest.importorskip("distributed")

SMALL = {"num_frames": 3, "phantom_size": 64, "frame_size": (32, 32, 28),
         "max_rotation_deg": 6, "max_translation_voxels": 3, "min_depth_voxels": 2, "sigma": 10}


def write_study(folder, seed):
    os.makedirs(folder, exist_ok=True)
    sequence = dsr.simulate(seed=seed, **SMALL)
    paths = []
    for i, frame in enumerate(sequence.frames):
        paths.append(os.path.join(folder, f"frame_{i:02d}.nii.gz"))
        dsr.write_image(frame, paths[-1])
    dsr.write_poses(os.path.join(folder, "gt_poses.json"), sequence.frame_from_world,
                    images=[os.path.basename(p) for p in paths])
    return paths


@pytest.fixture
def manifest(tmp_path):
    rows = ["study,images,gt_poses,options"]
    for s in range(1, 4):
        paths = write_study(tmp_path / f"s{s}", s)
        rows.append(f"s{s},{';'.join(os.path.relpath(p, tmp_path) for p in paths)},"
                    f"s{s}/gt_poses.json,--pyramid_levels=2")
    broken = write_study(tmp_path / "broken", 4)
    with open(broken[1], "wb") as f:
        f.write(b"not an image")
    rows.append(f"broken,{';'.join(broken)},,")
    path = tmp_path / "studies.csv"
    path.write_text("\n".join(rows) + "\n")
    return str(path)


def test_four_studies_on_two_workers_one_broken(manifest, tmp_path):
    out = str(tmp_path / "out")
    environ = {}
    records = cohort.run(manifest, out, workers=2, progress=False, pyramid_min_size=8,
                         _on_start=lambda client: environ.update(client.run(
                             lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_"))))
    status = {r["study"]: r for r in records}
    # The workers keep glibc's allocator settings (Dask's trim threshold slows solves).
    assert len(environ) == 2 and set(environ.values()) == {None}
    assert [status[s]["status"] for s in ("s1", "s2", "s3")] == ["ok"] * 3
    # Errors against the ground truth each study's manifest row names.
    assert all(0 <= status[s]["tre_mean_mm"] < 0.5 for s in ("s1", "s2", "s3"))
    assert status["broken"]["status"] == "failed"
    assert "frame_01.nii.gz" in status["broken"]["reason"]
    # Each study's poses equal a registration of the same files in this process.
    again = dsr.register(
        [str(tmp_path / "s1" / f"frame_{i:02d}.nii.gz") for i in range(3)],
        pyramid_levels=2, pyramid_min_size=8, num_threads=1)
    again.save(tmp_path / "s1.json")
    with open(os.path.join(out, "s1", "poses.json"), "rb") as f:
        assert (tmp_path / "s1.json").read_bytes() == f.read()
    results = open(os.path.join(out, "results.csv")).read().splitlines()
    assert results[0].startswith("study,status,reason") and results[1].startswith("broken,failed")
    assert len(results) == 5
    # The cohort page: one row per study, failures first, thumbnails linking to the reports.
    page = open(os.path.join(out, "index.html")).read()
    assert page.count("<tr class=") == 4
    assert page.index('<tr class="failed">') < page.index('<tr class="ok">')
    assert 's1/report/panorama_slices.png' in page and 's1/report/index.md' in page
    assert os.path.exists(os.path.join(out, "s1", "report", "panorama_slices.png"))
    # In a real browser: headless Chromium renders one row per study and loads the pictures.
    dom = open_in_chromium(os.path.join(out, "index.html"))
    assert dom.count("<tr class=") == 4 and "4 studies, 1 failed" in dom
    # A rerun does no work: every record is kept as it was.
    times = {s: os.stat(os.path.join(out, s, "record.json")).st_mtime_ns for s in status}
    cohort.run(manifest, out, workers=2, progress=False, pyramid_min_size=8)
    assert times == {s: os.stat(os.path.join(out, s, "record.json")).st_mtime_ns for s in status}
    # A changed option is new work.
    cohort.run(manifest, out, workers=2, progress=False, pyramid_min_size=9)
    assert times["s1"] != os.stat(os.path.join(out, "s1", "record.json")).st_mtime_ns


def open_in_chromium(page):
    """The page's DOM after headless Chromium has loaded it and run its script."""
    import shutil  # noqa: PLC0415
    import subprocess  # noqa: PLC0415

    browser = shutil.which("chromium")
    if browser is None:
        pytest.skip("chromium is not installed (scripts/python_test.sh installs it)")
    run = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu",
                          "--dump-dom", "file://" + os.path.abspath(page)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    return run.stdout


def test_a_killed_worker_leaves_no_partial_study(tmp_path):
    paths = write_study(tmp_path / "long", 5)
    manifest = tmp_path / "one.csv"
    manifest.write_text("study,images\nlong," + ";".join(paths) + "\n")
    out = str(tmp_path / "out")
    long_solve = {"pyramid_levels": 1, "max_iterations": 100000, "function_tolerance": 0,
                  "gradient_tolerance": 0, "parameter_tolerance": 0, "step_tolerance": 0,
                  "max_rejected_steps": 0, "init": "global", "uncertainty": True}

    # The worker running the study is killed once it runs; Dask retries the study on the
    # other worker, which is killed too: the study is recorded as failed, with no poses file.
    records = cohort.run(str(manifest), out, workers=2, progress=False,
                         _on_start=lambda client: _kill_running_workers(client, 2), **long_solve)
    assert records[0]["status"] == "failed" and "died twice" in records[0]["reason"]
    assert not os.path.exists(os.path.join(out, "long", "poses.json"))
    assert not [f for f in os.listdir(os.path.join(out, "long")) if ".tmp-" in f]


def _kill_running_workers(client, times):
    """Kills, `times` times, the worker process that a task was given to, as soon as the
    scheduler has given it one: the study's solve is short, so any wait could let it end."""
    def kill():
        killed = set()  # a restarted worker comes back on a new address
        deadline = time.monotonic() + 60
        while len(killed) < times and time.monotonic() < deadline:
            busy = [w for w, tasks in client.processing().items() if tasks and w not in killed]
            if busy:
                pid = client.run(os.getpid, workers=busy[:1])[busy[0]]
                os.kill(pid, signal.SIGKILL)
                killed.add(busy[0])
            time.sleep(0.01)
    threading.Thread(target=kill, daemon=True).start()


def test_bad_manifests_are_refused_before_any_work(tmp_path):
    paths = write_study(tmp_path / "s", 1)
    cases = [("study\ns1\n", "no column 'images'"),
             ("study,images,colour\ns1,a\n", "unknown column 'colour'"),
             (f"study,images\ns1,{';'.join(paths)}\ns1,{';'.join(paths)}\n",
              r"row 2, column study: 's1' is given twice \(rows 2 and 3\); 1 more row refused "
              r"\(row 3\)"),
             (f"study,images\ns1,{';'.join(paths)}\nS1,{';'.join(paths)}\n",
              "'s1' is given twice .*differ only in case"),
             (f"study,images\ns1,{';'.join(paths)}\ns1,missing.nii.gz\n",
              r"row 2, column study: 's1' is given twice \(rows 2 and 3\)"),
             ("study,images,study\ns1,a,b\n",
              r"column 'study' is given twice in the header \(columns 1 and 3\)"),
             ("study,images,\ns1,a\n", "column 3 of the header has no name"),
             ("\n", "no header"),
             ("study,images\n\n", "no study"),
             ("study,images\ns1,missing.nii.gz;b.nii.gz\n",
              "row 2, column images: missing.nii.gz does not exist"),
             (f"study,images,options\ns1,{';'.join(paths)},--speckle_looks=2\n",
              "row 2, column options: --speckle_looks is not an option of dsr.register")]
    for text, message in cases:
        manifest = tmp_path / "m.csv"
        manifest.write_text(text)
        with pytest.raises(cohort.ManifestError, match=message):
            cohort.run(str(manifest), str(tmp_path / "out"), progress=False)
        assert not (tmp_path / "out").exists()
    # Files that are no manifest: refused at once (a FIFO or a device would never end).
    os.mkfifo(tmp_path / "fifo.csv")
    huge = tmp_path / "huge.csv"
    huge.write_bytes(b"study,images\n")
    os.truncate(huge, (64 << 20) + 1)  # sparse: nothing more written
    for manifest, message in [(tmp_path / "fifo.csv", "is a FIFO, not a regular file"),
                              ("/dev/zero", "is a character device, not a regular file"),
                              (tmp_path / "s", "is a folder"),
                              (tmp_path / "none.csv", "no such file"),
                              (huge, "67108865 bytes, more than the 64 MiB a manifest")]:
        start = time.monotonic()
        with pytest.raises(cohort.ManifestError, match=message):
            cohort.run(str(manifest), str(tmp_path / "out"), progress=False)
        assert time.monotonic() - start < 5 and not (tmp_path / "out").exists()


def test_the_command_line_runs_a_manifest_and_refuses_a_bad_one(manifest, tmp_path):
    import subprocess  # noqa: PLC0415
    import sys  # noqa: PLC0415

    out = tmp_path / "cli"
    run = subprocess.run([sys.executable, "-m", "dsr.cohort", f"--manifest={manifest}",
                          f"--out_dir={out}", "--workers=2", "--no_progress",
                          "--pyramid_min_size=8"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "3 studies registered, 1 failed" in run.stdout
    bad = tmp_path / "bad.csv"
    bad.write_text("study\ns1\n")
    run = subprocess.run([sys.executable, "-m", "dsr.cohort", f"--manifest={bad}",
                          f"--out_dir={tmp_path / 'none'}"], capture_output=True, text=True)
    assert run.returncode == 2 and "no column 'images'" in run.stderr


# A hostile or careless manifest, command line or out_dir: one line naming the row, flag or
# file, before any work, and never a traceback, a hang or a write outside --out_dir.
@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """One small study's frames and ground truth, and a folder to put manifests in."""
    folder = tmp_path_factory.mktemp("cohort_frames")
    return folder, write_study(folder / "d", 6)


def one_row(folder, study="s1", images=None, gt="", options="", frames_=None, extra=""):
    """A manifest of one row (its cells as given, joined by commas) in `folder`."""
    path = folder / "one.csv"
    path.write_text("study,images,masks,gt_poses,options\n"
                    f"{study},{images or ';'.join(frames_)},,{gt},{options}{extra}\n")
    return str(path)


ROW_CASES = {
    "a 300-character id": (dict(study="x" * 300),
                           r"row 2, column study: 'x{40}'\.\.\. \(300 characters\) is longer "
                           r"than 100 characters"),
    "the id results.csv": (dict(study="results.csv"),
                           r"'results.csv' is the name of a file the cohort writes in --out_dir"),
    "the id INDEX.HTML": (dict(study="INDEX.HTML"), r"'INDEX.HTML' is the name of a file"),
    "two gt_poses files": (dict(gt="d/gt_poses.json;d/gt_poses.json"),
                           r"column gt_poses: 2 files; a study has one ground-truth poses file"),
    "an unquoted comma": (dict(options="--phases=0,2"),
                          r"row 2: 6 cells, but the header has 5 columns \(a cell that holds a "
                          r"comma is quoted"),
    "a frame given twice": (dict(images="d/frame_00.nii.gz;d/frame_00.nii.gz"),
                            r"row 2: --images: .*frame_00\.nii\.gz is given twice"),
    "a newline in a path": (dict(images="\"d/new\nline.nii.gz;d/frame_01.nii.gz\""),
                            r"column images: '.*d/new\\nline\.nii\.gz' has a line break in its "
                            r"name"),
    "a FIFO as an image": (dict(images="d/fifo.nii.gz;d/frame_01.nii.gz"),
                           r"column images: .*fifo\.nii\.gz is a FIFO, not a regular file"),
    "a folder as an image": (dict(images="d;d/frame_01.nii.gz"), r"column images: d is a folder"),
    "a missing --init file": (dict(options="--init=d/none.json"),
                              r"column options: --init: d/none\.json does not exist"),
    "a bad option value": (dict(options="--max_iterations=0"),
                           r"column options: --max_iterations=0: must be >= 1"),
    "an unbalanced quote": (dict(options="--mode='dsr"), r"cannot be split into flags"),
    "a phase list with a space": (dict(options="'--phases= 1'"),
                                  r"column options: --phases= 1: must be all or"),
    "a phase list with a sign": (dict(options="--phases=+1"),
                                 r"column options: --phases=\+1: must be all or"),
    "an option twice": (dict(options="--max_iterations=3 --max_iterations=4"),
                        r"column options: --max_iterations is given twice"),
    "a ground truth of 2 frames": (dict(gt="d/gt2.json"), r"--gt_poses=.*gt2\.json: .*"),
}


@pytest.mark.parametrize("case", ROW_CASES, ids=list(ROW_CASES))
def test_a_row_that_cannot_run_is_refused_before_any_work(frames, tmp_path, case):
    folder, paths = frames
    if not (folder / "d" / "fifo.nii.gz").exists():
        os.mkfifo(folder / "d" / "fifo.nii.gz")
        (folder / "d" / "new\nline.nii.gz").write_bytes(open(paths[0], "rb").read())
        dsr.write_poses(folder / "d" / "gt2.json", [np.eye(4)] * 2)
    cells, message = ROW_CASES[case]
    manifest = one_row(folder, frames_=[os.path.relpath(p, folder) for p in paths], **cells)
    with pytest.raises(cohort.ManifestError, match=message):
        cohort.run(manifest, str(tmp_path / "out"), progress=False)
    with pytest.raises(cohort.ManifestError, match=message):
        cohort.read_manifest(manifest)
    assert not (tmp_path / "out").exists()


def test_a_thousand_bad_rows_are_reported_at_once_before_any_work(frames, tmp_path):
    _, paths = frames
    manifest = tmp_path / "rows.csv"
    manifest.write_text("study,images\n" + "".join(f"b{i},{paths[0]};{paths[0]}\n"
                                                    for i in range(1000)))
    start = time.monotonic()
    with pytest.raises(cohort.ManifestError,
                       match=r"row 2: --images: .* is given twice; 999 more rows refused "
                             r"\(rows 3, 4, 5, 6, 7, 8, 9, 10, \.\.\.\)$"):
        cohort.run(str(manifest), str(tmp_path / "out"), progress=False)
    assert time.monotonic() - start < 30 and not (tmp_path / "out").exists()


def cli(*args, environ=None, timeout=120):
    """python -m dsr.cohort with `args`: (exit status, stdout, stderr)."""
    import subprocess  # noqa: PLC0415
    import sys  # noqa: PLC0415

    run = subprocess.run([sys.executable, "-m", "dsr.cohort", "--no_progress", *map(str, args)],
                         capture_output=True, text=True, timeout=timeout,
                         env={**os.environ, **(environ or {})})
    return run.returncode, run.stdout, run.stderr


def one_error_line(stderr):
    """The one line of stderr, an error of dsr.cohort's (no traceback)."""
    lines = stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("dsr.cohort: error: "), stderr
    return lines[0]


FLAG_CASES = {
    "--workers=0": (["--workers=0"], r"--workers=0: must be a whole number >= 1"),
    "--workers=-1": (["--workers=-1"], r"--workers=-1: must be a whole number >= 1"),
    "--workers=two": (["--workers=two"], r"argument --workers: invalid int value: 'two'"),
    "--workers=1000": (["--workers=1000"], r"more than 4 threads for each of the \d+ CPUs"),
    "--threads_per_worker=0": (["--threads_per_worker=0"], r"--threads_per_worker=0: must be"),
    "--memory_limit=banana": (["--memory_limit=banana"],
                              r"--memory_limit=banana: not a size \(e\.g\. 4GB, 1\.5GiB\) or auto"),
    "--memory_limit=1": (["--memory_limit=1"],
                         r"--memory_limit=1: 1 B per worker is less than 256\.00 MiB, which a "
                         r"worker process needs"),
    "--memory_limit=0.5": (["--memory_limit=0.5"], r"--memory_limit=0\.5: 0 B per worker"),
    "an unknown option": (["--speckle_looks=2"],
                          r"options: --speckle_looks is not an option of dsr\.register"),
    "a bad shared value": (["--rebuild_tolerance=inf"],
                           r"options: --rebuild_tolerance=inf: must be finite and > 0"),
    "a missing --init": (["--init=none.json"], r"options: --init: none\.json does not exist"),
    "no --manifest": ([], r"the following arguments are required: --manifest"),
}


@pytest.mark.parametrize("case", FLAG_CASES, ids=list(FLAG_CASES))
def test_a_bad_flag_is_refused_in_one_line(frames, tmp_path, case, capsys):
    folder, paths = frames
    manifest = one_row(folder, frames_=paths)
    flags, message = FLAG_CASES[case]
    given = ([] if case == "no --manifest" else [f"--manifest={manifest}"])
    assert cohort.main(given + [f"--out_dir={tmp_path / 'out'}", "--no_progress"] + flags) == 2
    assert re.search(message, one_error_line(capsys.readouterr().err))
    assert not (tmp_path / "out").exists()


def test_an_unreachable_scheduler_is_one_line_within_dasks_timeout(frames, tmp_path):
    folder, paths = frames
    start = time.monotonic()
    status, _, stderr = cli(f"--manifest={one_row(folder, frames_=paths)}",
                            f"--out_dir={tmp_path / 'out'}", "--scheduler=tcp://127.0.0.1:1",
                            environ={"DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "2s"})
    assert status == 2 and time.monotonic() - start < 30
    assert re.search(r"--scheduler=tcp://127\.0\.0\.1:1: cannot connect \(Timed out trying to "
                     r"connect to tcp://127\.0\.0\.1:1 after 2 s\)", one_error_line(stderr))


def test_an_out_dir_that_cannot_be_used_is_refused_in_one_line(frames, tmp_path, capsys):
    folder, paths = frames
    manifest = one_row(folder, frames_=paths)
    (tmp_path / "afile").write_text("kept\n")
    read_only = tmp_path / "ro"
    read_only.mkdir()
    os.symlink(tmp_path / "nowhere", tmp_path / "dangling")
    cases = [(tmp_path / "afile", "is a file, not a folder"),
             (tmp_path / "dangling", r"is a symlink to a missing folder \(.*nowhere\)"),
             (manifest, "is the manifest itself"),
             (tmp_path / "afile" / "out", r"cannot be made \(.*afile is not a folder\)")]
    with mounted(read_only, "ro") as ro:
        if ro:
            cases.append((read_only / "out", r"cannot be made \(.*ro is on a read-only file "
                                             r"system\)"))
        for out_dir, message in cases:
            assert cohort.main([f"--manifest={manifest}", f"--out_dir={out_dir}"]) == 2
            assert re.search(f"--out_dir={re.escape(str(out_dir))}: {message}",
                             one_error_line(capsys.readouterr().err))
    assert (tmp_path / "afile").read_text() == "kept\n"
    # The manifest is never one of the cohort's own files.
    out = tmp_path / "out"
    out.mkdir()
    (out / "results.csv").write_text(open(manifest).read())
    assert cohort.main([f"--manifest={out / 'results.csv'}", f"--out_dir={out}"]) == 2
    assert "which the cohort writes: inputs are never overwritten" in \
        one_error_line(capsys.readouterr().err)


@contextlib.contextmanager
def mounted(folder, *options, size="1m"):
    """A tmpfs at `folder` (root only: yields False where it cannot be mounted)."""
    import subprocess  # noqa: PLC0415

    if os.geteuid() != 0:
        if "ro" in options:  # a folder this user cannot write stands in for it
            os.chmod(folder, 0o555)
            try:
                yield True
            finally:
                os.chmod(folder, 0o755)
            return
        yield False
        return
    mount = subprocess.run(["mount", "-t", "tmpfs", "-o", ",".join((f"size={size}",) + options),
                            "tmpfs", str(folder)], capture_output=True, text=True)
    if mount.returncode != 0:
        yield False
        return
    try:
        yield True
    finally:
        subprocess.run(["umount", str(folder)], check=True)


def test_a_second_cohort_on_one_out_dir_is_refused(frames, tmp_path, capsys):
    import fcntl  # noqa: PLC0415

    folder, paths = frames
    manifest = one_row(folder, frames_=paths)
    out = tmp_path / "out"
    with cohort._locked(str(out.mkdir() or out), manifest):  # as a running cohort holds it
        assert cohort.main([f"--manifest={manifest}", f"--out_dir={out}"]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert f"--out_dir={out}: another dsr.cohort runs on this folder (pid {os.getpid()} on " \
        in line and f"--manifest={manifest}); wait for it to end" in line
    assert sorted(os.listdir(out)) == [".dsr-cohort.lock"]
    fd = os.open(out / ".dsr-cohort.lock", os.O_RDWR)  # released with its holder
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    os.close(fd)


def test_refused_rows_are_reported_and_the_others_run(frames, tmp_path, capsys):
    """Bad rows beside a good one: refused in one line before any work, listed in the results
    with their reasons; the good study runs. Pre-existing entries named like a study are kept,
    and a symlink never takes outputs out of --out_dir. A relative --init in the options
    cell is the manifest folder's file. A rerun skips the finished study unless what decides
    its outputs changed: its ground truth added."""
    folder, paths = frames
    rel = [os.path.relpath(p, tmp_path) for p in paths]
    shutil.copytree(folder / "d", tmp_path / "d", ignore=shutil.ignore_patterns("fifo*", "new*"))
    out, victim = tmp_path / "out", tmp_path / "victim"
    out.mkdir()
    victim.mkdir()
    (out / "s8").write_text("precious\n")
    os.symlink(victim, out / "s7")
    rows = [f"s1,{';'.join(rel)},,,--init=d/gt_poses.json --pyramid_levels=2",
            f"{'x' * 300},{';'.join(rel)},,,",
            f"results.csv,{';'.join(rel)},,,",
            f"s2,{';'.join(rel)},,,--phases=0,2",
            f"s7,{';'.join(rel)},,,",
            f"s8,{';'.join(rel)},,,"]
    manifest = tmp_path / "m.csv"
    manifest.write_text("study,images,masks,gt_poses,options\n" + "\n".join(rows) + "\n")
    argv = [f"--manifest={manifest}", f"--out_dir={out}", "--workers=1", "--no_progress",
            "--pyramid_min_size=8"]
    assert cohort.main(argv) == 2
    captured = capsys.readouterr()
    line = one_error_line(captured.err)
    assert re.search(r"m\.csv: row 3, column study: 'x{40}'\.\.\. \(300 characters\) is longer "
                     r"than 100 characters.*; 4 more rows refused \(rows 4, 5, 6, 7\); the "
                     r"other 1 study runs", line), line
    assert "1 studies registered, 0 failed, 5 rows refused" in captured.out
    results = list(csv.DictReader(open(out / "results.csv")))
    assert [r["status"] for r in results] == ["refused"] * 5 + ["ok"]
    reasons = {r["study"]: r["reason"] for r in results}
    assert "s7 is a symlink (to " in reasons["s7"] and "exists and is not a folder" in \
        reasons["s8"] and "6 cells" in reasons["s2"] and "cohort writes" in reasons["results.csv"]
    assert os.listdir(victim) == [] and (out / "s8").read_text() == "precious\n"
    assert os.path.islink(out / "s7")
    # The study started at its ground truth, the manifest folder's d/gt_poses.json (not one
    # in the worker's working folder: the study would have failed, no such file).
    assert reasons["s1"] == "" and results[-1]["tre_mean_mm"] == ""
    (tmp_path / "good.csv").write_text("study,images,options\n" + rows[0].replace(",,,", ",") +
                                       "\n")
    [study] = cohort.read_manifest(str(tmp_path / "good.csv"))
    assert study.options["init"] == str(tmp_path / "d" / "gt_poses.json")
    # A rerun: the finished study is skipped.
    record = out / "s1" / "record.json"
    before = os.stat(record).st_mtime_ns
    assert cohort.main(argv) == 2
    assert os.stat(record).st_mtime_ns == before
    # Its ground truth added: it is done again, and the results have its errors.
    manifest.write_text(manifest.read_text().replace(
        f"s1,{';'.join(rel)},,,", f"s1,{';'.join(rel)},,d/gt_poses.json,"))
    assert cohort.main(argv) == 2
    assert os.stat(record).st_mtime_ns != before
    results = {r["study"]: r for r in csv.DictReader(open(out / "results.csv"))}
    assert float(results["s1"]["tre_mean_mm"]) < 0.5
    assert results["s1"]["gt_poses"] == str(tmp_path / "d" / "gt_poses.json")
    capsys.readouterr()


def test_a_full_disk_fails_the_studies_it_stops_and_keeps_the_results(frames, tmp_path, capsys):
    """On a full disk no study is ok with damaged files, each study it stopped is failed
    with the reason (and done again by a rerun), results.csv and index.html are written (their
    space was taken before the studies), and the command ends with one line, exit 1."""
    _, paths = frames
    manifest = tmp_path / "many.csv"
    manifest.write_text("study,images\n" + "".join(f"k{i},{';'.join(paths)}\n"
                                                    for i in range(8)))
    out = tmp_path / "full"
    out.mkdir()
    with mounted(out, size="900k") as ok:
        if not ok:
            pytest.skip("needs root to mount a small tmpfs")
        status = cohort.main([f"--manifest={manifest}", f"--out_dir={out}", "--workers=1",
                              "--no_progress", "--pyramid_levels=1", "--max_iterations=3"])
        captured = capsys.readouterr()
        assert status == 1, captured
        assert re.search(r"stud(y|ies) could not write their outputs \(first k\d: could not write "
                         r"its outputs \(.*full/k\d/.+\); a rerun does it again\)",
                         one_error_line(captured.err))
        results = list(csv.DictReader(open(out / "results.csv")))
        assert len(results) == 8 and "8 studies" in open(out / "index.html").read()
        status = {r["study"]: r["status"] for r in results}
        assert "ok" in status.values() and "failed" in status.values()
        for study, state in status.items():
            if state == "ok":
                json.load(open(out / study / "poses.json"))
                for picture in (out / study / "report").glob("*.png"):
                    assert picture.read_bytes().endswith(b"IEND\xaeB`\x82"), picture
            else:
                assert not (out / study / "record.json").exists()
