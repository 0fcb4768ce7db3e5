"""dsr.cohort on a LocalCluster of 2 worker processes: 4 small studies, one broken (3 results
and 1 recorded failure with its reason), a rerun that does no work, a killed worker whose
study is retried and never left half-written, and bad manifests refused before any work."""
import os
import signal
import threading
import time

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
    """Kills, `times` times, the worker process that runs a task, once it runs one."""
    def kill():
        for _ in range(times):
            for _ in range(400):
                processing = {w: t for w, t in client.processing().items() if t}
                if processing:
                    break
                time.sleep(0.05)
            time.sleep(0.5)
            for worker in processing:
                pid = client.run(os.getpid, workers=[worker])[worker]
                os.kill(pid, signal.SIGKILL)
            time.sleep(1.0)
    threading.Thread(target=kill, daemon=True).start()


def test_bad_manifests_are_refused_before_any_work(tmp_path):
    paths = write_study(tmp_path / "s", 1)
    cases = [("study\ns1\n", "no column 'images'"),
             ("study,images,colour\ns1,a\n", "unknown column 'colour'"),
             (f"study,images\ns1,{';'.join(paths)}\ns1,{';'.join(paths)}\n",
              "row 3, column study: 's1' is given twice"),
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
