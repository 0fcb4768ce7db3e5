#!/usr/bin/env python3
"""The driver of bench/speed_ab.sh: runs two dsr_register builds in turn on each sequence.

Standard library only (the machine's python3). Each case is SIZE:DIR, a dsr_simulate output
folder; each round runs both builds once on it, the order alternating between rounds (A B,
B A, ...), and takes each run's wall time and peak resident memory from the process itself
(os.wait4). The 'us' cases run this build twice instead: its defaults against
--preset=echo. Writes OUT/speed_ab.md (and OUT/speed_ab.json, every run's figures) and
prints the table.
"""
import argparse
import glob
import json
import os
import re
import statistics
import subprocess
import sys
import time

STAGES = re.compile(r"time ([0-9.]+) s \(load ([0-9.]+) s, pyramid ([0-9.]+) s, "
                    r"solves ([0-9.]+) s(?:, checks ([0-9.]+) s)?\)")
CHECKS = re.compile(r"checks [0-9.]+ s: structure ([0-9.]+) s, determination ([0-9.]+) s, "
                    r"brightness ([0-9.]+) s, uncertainty ([0-9.]+) s, other ([0-9.]+) s")
TRE = re.compile(r"TRE mean ([0-9.e+-]+) mm")


def run_once(command, log_path):
    """Runs command, its output to log_path; returns (status, seconds, peak MiB, output)."""
    with open(log_path, "w") as log:
        start = time.monotonic()
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(process.pid, 0)
        seconds = time.monotonic() - start
    process.returncode = os.waitstatus_to_exitcode(status)
    with open(log_path) as log:
        text = log.read()
    return process.returncode, seconds, usage.ru_maxrss / 1024.0, text


def figures(text):
    """This build's stage breakdown and TRE from its summary (empty where not printed)."""
    out = {}
    stages = STAGES.search(text)
    if stages:
        for name, value in zip(("total", "load", "pyramid", "solves", "checks"), stages.groups()):
            if value is not None:
                out[name] = float(value)
    checks = CHECKS.search(text)
    if checks:
        for name, value in zip(("structure", "determination", "brightness", "uncertainty",
                                "other"), checks.groups()):
            out[name] = float(value)
    tre = TRE.search(text)
    if tre:
        out["tre_mm"] = float(tre.group(1))
    return out


def spread(values, digits=2):
    """'median (min-max)' of values."""
    if not values:
        return "-"
    f = f"{{:.{digits}f}}"
    low, middle, high = (f.format(v) for v in (min(values), statistics.median(values),
                                                max(values)))
    return f"{middle} ({low}-{high})"


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--this", required=True)
    parser.add_argument("--baseline", required=True)
    parser.add_argument("--baseline_name", required=True)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--out", required=True)
    parser.add_argument("cases", nargs="+")
    args = parser.parse_args()
    logs = os.path.join(args.out, "logs")
    os.makedirs(logs, exist_ok=True)
    rows, stages, every_run = [], [], []
    for case in args.cases:
        size, directory = case.split(":", 1)
        name = os.path.basename(directory)
        images = ",".join(sorted(glob.glob(os.path.join(directory, "frame_*.nii.gz"))))
        masks = ",".join(sorted(glob.glob(os.path.join(directory, "mask_*.nii.gz"))))
        common = [f"--images={images}", f"--masks={masks}", "--progress=false",
                  f"--gt_poses={os.path.join(directory, 'gt_poses.json')}"]
        if size == "us":
            variants = {"auto": [args.this], "echo": [args.this, "--preset=echo"]}
        else:
            variants = {"this": [args.this], "baseline": [args.baseline]}
        order = list(variants)
        result = {v: [] for v in order}
        for round_index in range(args.runs):
            for variant in (order if round_index % 2 == 0 else order[::-1]):
                poses = os.path.join(args.out, f"poses_{name}_{variant}.json")
                command = variants[variant] + common + [f"--out_poses={poses}"]
                log = os.path.join(logs, f"{name}_{variant}_{round_index + 1}.txt")
                status, seconds, peak, text = run_once(command, log)
                run = {"case": name, "variant": variant, "round": round_index + 1,
                       "status": status, "seconds": seconds, "peak_mib": peak}
                run.update(figures(text))
                every_run.append(run)
                result[variant].append(run)
                print(f"{name} {variant} round {round_index + 1}: exit {status}, "
                      f"{seconds:.2f} s, {peak:.0f} MiB", file=sys.stderr)
        a, b = order
        ratios = [ra["seconds"] / rb["seconds"] for ra, rb in zip(result[a], result[b])]
        rows.append({
            "case": name, "a": a, "b": b,
            "a_time": spread([r["seconds"] for r in result[a]]),
            "b_time": spread([r["seconds"] for r in result[b]]),
            "ratio": spread(ratios),
            "a_mem": spread([r["peak_mib"] for r in result[a]], 0),
            "b_mem": spread([r["peak_mib"] for r in result[b]], 0),
            "status": ",".join(str(r["status"]) for r in result[a] + result[b]),
            "tre": " / ".join(spread([r["tre_mm"] for r in result[v] if "tre_mm" in r], 4)
                              for v in order),
        })
        for variant in order:
            runs = result[variant]
            share = [100.0 * r["checks"] / r["seconds"] for r in runs if "checks" in r]
            stages.append([f"{name} {variant}"] +
                          [spread([r[k] for r in runs if k in r])
                           for k in ("total", "load", "pyramid", "solves", "checks",
                                     "structure", "determination", "brightness")] +
                          [spread(share, 1)])
    lines = [f"Runs per build and sequence: {args.runs}, alternating; A = this build "
             f"(or --photometric=auto on the us sequences), B = {args.baseline_name} (or "
             f"--preset=echo). Wall time and peak memory of the whole process; medians "
             f"(min-max).", "",
             "| sequence | A / B | A time (s) | B time (s) | A/B time ratio | A peak (MiB) | "
             "B peak (MiB) | mean TRE A / B (mm) | exits |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['a']} / {r['b']} | {r['a_time']} | {r['b_time']} | "
                     f"{r['ratio']} | {r['a_mem']} | {r['b_mem']} | {r['tre']} | "
                     f"{r['status']} |")
    lines += ["", "Stages as each build's summary line states them (s; '-' where a build does "
              "not state it; solves exclude the checks where the checks are timed):", "",
              "| run | registration | load | pyramid | solves | checks | structure | "
              "determination | brightness | checks share (%) |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    lines += ["| " + " | ".join(row) + " |" for row in stages]
    table = "\n".join(lines) + "\n"
    with open(os.path.join(args.out, "speed_ab.md"), "w") as f:
        f.write(table)
    with open(os.path.join(args.out, "speed_ab.json"), "w") as f:
        json.dump(every_run, f, indent=1)
    print(table)


if __name__ == "__main__":
    main()
