"""The cohort runner against one study after another: 8 paper-size studies (11 frames of
96x96x80 from the built-in phantom, the paper's protocol, seeds 1-8) registered by
`python -m dsr.cohort --workers=2` (2 worker processes of 1 thread) and by `dsr_register`
run once per study with the same outputs (poses and report), at its default (all cores) and
at the cohort's 1 thread per study, the three in turn (order rotated) over `--pairs` rounds;
prints each round's ratios and their medians, and checks that all write the same poses files.

Usage: DSR_TOOLS=build/tools .venv/bin/python bench/cohort.py [--pairs=3]
       [--work=DIR (default build/cohort_bench)]
"""
import argparse
import filecmp
import os
import shutil
import statistics
import subprocess
import sys
import time

TOOLS = os.environ.get("DSR_TOOLS", "build/tools")


def simulate(work, studies):
    rows = ["study,images,masks"]
    for seed in range(1, studies + 1):
        folder = os.path.join(work, f"seed{seed}")
        if not os.path.exists(os.path.join(folder, "gt_poses.json")):
            subprocess.run([os.path.join(TOOLS, "dsr_simulate"), f"--out_dir={folder}",
                            f"--seed={seed}"], check=True, capture_output=True)
        frames = ";".join(os.path.join(folder, f"frame_{i:02d}.nii.gz") for i in range(11))
        masks = ";".join(os.path.join(folder, f"mask_{i:02d}.nii.gz") for i in range(11))
        rows.append(f"seed{seed},{frames},{masks}")
    manifest = os.path.join(work, "studies.csv")
    with open(manifest, "w") as f:
        f.write("\n".join(rows) + "\n")
    return manifest


def cohort(manifest, out):
    shutil.rmtree(out, ignore_errors=True)
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "dsr.cohort", f"--manifest={manifest}",
                    f"--out_dir={out}", "--workers=2", "--threads_per_worker=1",
                    "--no_progress"], check=True, capture_output=True)
    return time.perf_counter() - start


def one_after_another(work, studies, out, threads=None):
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(out)
    start = time.perf_counter()
    for seed in range(1, studies + 1):
        folder = os.path.join(work, f"seed{seed}")
        frames = ",".join(os.path.join(folder, f"frame_{i:02d}.nii.gz") for i in range(11))
        masks = ",".join(os.path.join(folder, f"mask_{i:02d}.nii.gz") for i in range(11))
        # The cohort's outputs: poses and a report per study.
        subprocess.run([os.path.join(TOOLS, "dsr_register"), f"--images={frames}",
                        f"--masks={masks}", f"--out_poses={out}/seed{seed}.json",
                        f"--report_dir={out}/seed{seed}_report", "--progress=false"] +
                       ([f"--num_threads={threads}"] if threads else []),
                       check=True, capture_output=True)
    return time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--studies", type=int, default=8)
    parser.add_argument("--work", default="build/cohort_bench")
    args = parser.parse_args()
    args.work = os.path.abspath(args.work)
    os.makedirs(args.work, exist_ok=True)
    manifest = simulate(args.work, args.studies)
    ratios, ratios_1 = [], []
    for pair in range(args.pairs):
        runs = [("cohort", lambda: cohort(manifest, os.path.join(args.work, "out_cohort"))),
                ("serial", lambda: one_after_another(args.work, args.studies,
                                                     os.path.join(args.work, "out_serial"))),
                ("serial_1", lambda: one_after_another(args.work, args.studies,
                                                       os.path.join(args.work, "out_serial_1"),
                                                       threads=1))]
        runs = runs[pair % 3:] + runs[:pair % 3]
        times = dict((name, run()) for name, run in runs)
        ratios.append(times["cohort"] / times["serial"])
        ratios_1.append(times["cohort"] / times["serial_1"])
        print(f"round {pair + 1}: cohort {times['cohort']:.1f} s, one after another "
              f"{times['serial']:.1f} s (all cores, ratio {ratios[-1]:.3f}), "
              f"{times['serial_1']:.1f} s (1 thread, ratio {ratios_1[-1]:.3f})", flush=True)
    same = all(filecmp.cmp(os.path.join(args.work, "out_cohort", f"seed{s}", "poses.json"),
                           os.path.join(args.work, folder, f"seed{s}.json"), shallow=False)
               for s in range(1, args.studies + 1) for folder in ("out_serial", "out_serial_1"))
    print(f"median ratio {statistics.median(ratios):.3f} against dsr_register at all cores, "
          f"{statistics.median(ratios_1):.3f} against it at 1 thread, over {len(ratios)} rounds; "
          f"poses files {'identical' if same else 'DIFFERENT'}")


if __name__ == "__main__":
    main()
