"""The cohort runner against one study after another: 8 paper-size studies (11 frames of
96x96x80 from the built-in phantom, the paper's protocol, seeds 1-8) registered by
`python -m dsr.cohort --workers=2` (2 worker processes of 1 thread) and by `dsr_register`
run once per study with the same outputs (poses and report; all cores, its default), alternating A/B over `--pairs` pairs; prints the
ratio of each pair and their median, and checks that both write the same poses files.

Usage: DSR_TOOLS=build/tools .venv/bin/python bench/cohort.py [--pairs=3] [--work=DIR (default build/cohort_bench)]
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


def one_after_another(work, studies, out):
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
                        f"--report_dir={out}/seed{seed}_report", "--progress=false"],
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
    ratios = []
    for pair in range(args.pairs):
        runs = [("cohort", lambda: cohort(manifest, os.path.join(args.work, "out_cohort"))),
                ("serial", lambda: one_after_another(args.work, args.studies,
                                                     os.path.join(args.work, "out_serial")))]
        if pair % 2:
            runs.reverse()
        times = dict((name, run()) for name, run in runs)
        ratios.append(times["cohort"] / times["serial"])
        print(f"pair {pair + 1}: cohort {times['cohort']:.1f} s, one after another "
              f"{times['serial']:.1f} s, ratio {ratios[-1]:.3f}", flush=True)
    same = all(filecmp.cmp(os.path.join(args.work, "out_cohort", f"seed{s}", "poses.json"),
                           os.path.join(args.work, "out_serial", f"seed{s}.json"), shallow=False)
               for s in range(1, args.studies + 1))
    print(f"median ratio {statistics.median(ratios):.3f} over {len(ratios)} pairs; poses files "
          f"{'identical' if same else 'DIFFERENT'}")


if __name__ == "__main__":
    main()
