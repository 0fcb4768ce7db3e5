#!/usr/bin/env python3
"""dsr.register (the Python package) against dsr_register on the same files: wall time of
the call against the command's process, alternating, and whether both write the same poses
file. The target: at most 1.05x the command's time.

    .venv/bin/python bench/python_overhead.py [SEQUENCE_DIR] [--runs=5]

SEQUENCE_DIR: frames and masks as dsr_simulate writes them (default: the demo's sequence,
simulated into /tmp when missing). Needs the package installed (scripts/python_test.sh)
and the tools in DSR_TOOLS (default build/tools).
"""
import glob
import os
import statistics
import subprocess
import sys
import tempfile
import time

import dsr

tools = os.environ.get("DSR_TOOLS", "build/tools")
args = [a for a in sys.argv[1:] if not a.startswith("--runs=")]
runs = int(next((a.split("=", 1)[1] for a in sys.argv[1:] if a.startswith("--runs=")), "5"))
work = tempfile.mkdtemp(prefix="dsr_python_overhead_")
sequence = args[0] if args else os.path.join(work, "demo")
if not args:
    subprocess.run([f"{tools}/dsr_simulate", f"--out_dir={sequence}", "--seed=1"], check=True,
                   capture_output=True)
frames = sorted(glob.glob(os.path.join(sequence, "frame_*.nii.gz")))
masks = sorted(glob.glob(os.path.join(sequence, "mask_*.nii.gz")))
cli_poses, py_poses = os.path.join(work, "cli.json"), os.path.join(work, "python.json")
cli, py = [], []
for _ in range(runs):
    start = time.perf_counter()
    subprocess.run([f"{tools}/dsr_register", "--images=" + ",".join(frames),
                    "--masks=" + ",".join(masks), f"--out_poses={cli_poses}", "--progress=false"],
                   check=True, capture_output=True)
    cli.append(time.perf_counter() - start)
    start = time.perf_counter()
    dsr.register(frames, masks).save(py_poses)
    py.append(time.perf_counter() - start)
with open(cli_poses, "rb") as a, open(py_poses, "rb") as b:
    same = a.read() == b.read()
print(f"{len(frames)} frames, {runs} runs each, {os.cpu_count()} cores")
print(f"dsr_register (process): median {statistics.median(cli):.3f} s",
      [round(t, 3) for t in cli])
print(f"dsr.register (call):    median {statistics.median(py):.3f} s",
      [round(t, 3) for t in py])
print(f"ratio: median of paired runs {statistics.median(p / c for p, c in zip(py, cli)):.3f}")
print(f"same poses file: {same}")
sys.exit(0 if same else 1)
