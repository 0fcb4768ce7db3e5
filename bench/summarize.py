#!/usr/bin/env python3
"""Summarises bench/compare.sh's results folder: summary.md (markdown tables with the
ratios the performance targets are stated in) and scaling.png (log-log time per iteration
and peak memory versus frames and versus voxels, with fitted slopes).

Usage: python3 bench/summarize.py RESULTS_DIR CORES"""
import csv
import json
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def rows(folder):
    path = os.path.join(folder, "results.csv")
    if not os.path.exists(path):
        return []
    with open(path, newline="") as f:
        out = list(csv.DictReader(f))
    # dsr_compare labels a method with its initialiser and model ("dsr+auto+affine"):
    # the comparisons key on the method itself.
    for x in out:
        x["label"] = x["method"]  # what names its poses file
        x["method"] = x["method"].split("+")[0]
    return out


def poses(path):
    with open(path) as f:
        return [fr["T"] for fr in json.load(f)["frames"]]


def pose_difference(a, b):
    """Largest rotation angle (rad) and translation difference (mm) over frames."""
    worst_r = worst_t = 0.0
    for ta, tb in zip(a, b):
        # R = Ra Rb^T
        tr = sum(ta[i][k] * tb[i][k] for i in range(3) for k in range(3))
        worst_r = max(worst_r, math.acos(max(-1.0, min(1.0, (tr - 1.0) / 2.0))))
        worst_t = max(worst_t, math.sqrt(sum((ta[i][3] - tb[i][3]) ** 2 for i in range(3))))
    return worst_r, worst_t


def slope(xs, ys):
    lx = [math.log(x) for x in xs]
    ly = [math.log(y) for y in ys]
    n = len(lx)
    mx, my = sum(lx) / n, sum(ly) / n
    sxx = sum((x - mx) ** 2 for x in lx)
    return sum((x - mx) * (y - my) for x, y in zip(lx, ly)) / sxx if sxx > 0 else float("nan")


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    out, cores = sys.argv[1], sys.argv[2]
    md = [f"# bench/compare.sh results\n\nMachine: {cores} cores. One run; compare ratios.\n"]

    # Kernels.
    kernels = os.path.join(out, "kernels.json")
    times = {}  # kernel benchmark medians by run name
    if os.path.exists(kernels):
        with open(kernels) as f:
            bench = json.load(f)["benchmarks"]
        md.append("## Kernels (Google Benchmark, medians of 3)\n\n"
                  "| benchmark | time (ms) | ns per observation / sample |\n|---|---|---|")
        for b in bench:
            if b.get("aggregate_name") != "median":
                continue
            per = b.get("ns_per_observation", b.get("ns_per_sample", float("nan")))
            if "ns_per_sample" in b:
                per = (b["ns_per_sample"] * 1e9 if b["ns_per_sample"] < 1e-3
                       else b["ns_per_sample"])
            t = b["real_time"] * {"ns": 1e-6, "us": 1e-3, "ms": 1.0, "s": 1e3}[b["time_unit"]]
            md.append(f"| {b['run_name']} | {t:.3f} | {per:.3g} |")
        times = {b["run_name"]: b["real_time"] for b in bench
                 if b.get("aggregate_name") == "median"}
        for threads in (1, 2):
            dsr = times.get(f"BM_DsrEvaluation/1/{threads}/real_time")
            ape = times.get(f"BM_ApeEvaluation/1/{threads}/real_time")
            if dsr and ape:
                md.append(f"\nOne evaluation with Jacobians, {threads} "
                          f"thread{'s' if threads > 1 else ''}: APE / DSR = {ape / dsr:.2f}x.")
        md.append("")

    # (a) DSR vs DBA.
    r = {x["method"]: x for x in rows(os.path.join(out, "dsr_vs_dba"))}
    if "dsr" in r and "dba" in r and r["dsr"]["ok"] == "1" and r["dba"]["ok"] == "1":
        d, b = r["dsr"], r["dba"]
        tr = float(b["seconds_per_iteration"]) / float(d["seconds_per_iteration"])
        mr = float(b["peak_memory_mb"]) / float(d["peak_memory_mb"])
        ar = float(b["added_memory_mb"]) / float(d["added_memory_mb"])
        pr, pt = pose_difference(
            poses(os.path.join(out, "dsr_vs_dba", "poses", f"seed1_{d['label']}.json")),
            poses(os.path.join(out, "dsr_vs_dba", "poses", f"seed1_{b['label']}.json")))
        md.append("## (a) DSR vs DBA (6 frames of 80x80x64, 3-level pyramid, "
                  "registered from identity)\n")
        md.append("| method | time / iteration (s) | total (s) | peak memory (MB) "
                  "| added memory (MB) | MAE translation (voxels) |\n|---|---|---|---|---|---|")
        for m in (d, b):
            md.append(f"| {m['method']} | {float(m['seconds_per_iteration']):.4f} "
                      f"| {float(m['seconds']):.2f} | {float(m['peak_memory_mb']):.0f} "
                      f"| {float(m['added_memory_mb']):.0f} "
                      f"| {float(m['mae_translation_voxels']):.4f} |")
        md.append(f"\nDBA / DSR: {tr:.1f}x time per iteration, "
                  f"{float(b['seconds']) / float(d['seconds']):.1f}x total time, "
                  f"{ar:.1f}x the memory the registration adds "
                  f"(peak minus the process at the run's start), "
                  f"{mr:.1f}x the process's peak; "
                  f"poses differ by at most {pr:.2e} rad and {pt:.2e} mm.")
        floor = os.path.join(out, "library_floor_kb.txt")
        if os.path.exists(floor):
            with open(floor) as f:
                kb = f.read().strip().splitlines()[-1]
            md.append(f"A dsr_register process holds {float(kb) / 1024:.0f} MB before it reads "
                      "anything (shared libraries: ITK, OpenCV, Ceres and theirs), in either mode.")
        md.append("")

    def median(v):
        v = sorted(v)
        n = len(v)
        return v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])

    # (b) DSR vs APE: one row per run (folders dsr_vs_ape_rK, or dsr_vs_ape), each run
    # timing both methods back to back; the ratios are taken per run, then the median.
    runs = []
    for name in sorted(os.listdir(out)):
        if name == "dsr_vs_ape" or name.startswith("dsr_vs_ape_r"):
            r = {x["method"]: x for x in rows(os.path.join(out, name))}
            if "dsr" in r and "ape" in r:
                runs.append((name, r["dsr"], r["ape"]))
    if runs:
        md.append(f"## (b) DSR vs APE (11 frames of 96x96x80, {len(runs)} runs)\n")
        md.append("| run | DSR time / iteration (s) | APE time / iteration (s) | APE / DSR time "
                  "| DSR intensity differences / iteration "
                  "| APE intensity differences / iteration "
                  "| MAE translation DSR / APE (voxels) |\n|---|---|---|---|---|---|---|")
        time_ratios, diff_ratios = [], []
        for name, d, a in runs:
            tr = float(a["seconds_per_iteration"]) / float(d["seconds_per_iteration"])
            dr = (float(a["intensity_differences_per_iteration"])
                  / float(d["intensity_differences_per_iteration"]))
            time_ratios.append(tr)
            diff_ratios.append(dr)
            md.append(f"| {name} | {float(d['seconds_per_iteration']):.3f} "
                      f"| {float(a['seconds_per_iteration']):.3f} | {tr:.2f}x | "
                      f"{float(d['intensity_differences_per_iteration']):.3g} "
                      f"| {float(a['intensity_differences_per_iteration']):.3g} | "
                      f"{float(d['mae_translation_voxels']):.4f} "
                      f"/ {float(a['mae_translation_voxels']):.4f} |")
        md.append(f"\nAPE / DSR: {median(diff_ratios):.2f}x intensity differences, "
                  f"{median(time_ratios):.2f}x time per iteration "
                  f"(median of the runs; range {min(time_ratios):.2f}-{max(time_ratios):.2f}x).\n")

    # (c) scaling: each point run several times (folders NAME_rK); medians per point.
    def series(prefix, key):
        groups = {}
        for name in sorted(os.listdir(out)):
            if not name.startswith(prefix) or not os.path.isdir(os.path.join(out, name)):
                continue
            base = name.rsplit("_r", 1)[0] if "_r" in name else name
            for x in rows(os.path.join(out, name)):
                if x["ok"] == "1":
                    groups.setdefault(base, []).append(x)
        pts = []
        for base, xs in groups.items():
            pts.append((key(base, xs[0]),
                        median([float(x["seconds_per_iteration"]) for x in xs]),
                        median([float(x["peak_memory_mb"]) for x in xs]),
                        median([float(x["intensity_differences_per_iteration"]) for x in xs]),
                        median([float(x["seconds"]) for x in xs]),
                        median([float(x["tre_mean_mm"]) for x in xs]), f"{base} ({len(xs)} runs)"))
        return sorted(pts)

    frames = series("frames_", lambda n, x: int(n.split("_")[1]))
    sizes = series("size_", lambda n, x: math.prod(int(v) for v in n.split("_")[1].split("x")))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, pts, label in ((axes[0], frames, "frames (96x96x80 each)"),
                           (axes[1], sizes, "voxels per frame (11 frames)")):
        if len(pts) < 2:
            continue
        xs = [p[0] for p in pts]
        s_t = slope(xs, [p[1] for p in pts])
        s_m = slope(xs, [p[2] for p in pts])
        ax.loglog(xs, [p[1] for p in pts], "o-", label=f"time / iteration (slope {s_t:.2f})")
        ax2 = ax.twinx()
        ax2.loglog(xs, [p[2] for p in pts], "s--", color="tab:orange",
                   label=f"peak memory (slope {s_m:.2f})")
        ax.set_xlabel(label)
        ax.set_ylabel("seconds per iteration")
        ax2.set_ylabel("peak memory (MB)")
        h1, l1 = ax.get_legend_handles_labels()
        h2, l2 = ax2.get_legend_handles_labels()
        ax.legend(h1 + h2, l1 + l2, loc="upper left", fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
        # The work itself: observations grow faster than frames or voxels (more observers
        # per voxel at the same motions), so the slope against them is the per-unit cost.
        s_d = slope(xs, [p[3] for p in pts])
        s_td = slope([p[3] for p in pts], [p[1] for p in pts])
        md.append(f"## (c) DSR versus {label}\n\nlog-log slopes: time per iteration {s_t:.2f}, "
                  f"peak memory {s_m:.2f}; intensity differences {s_d:.2f}, "
                  f"so time per iteration against intensity differences {s_td:.2f}\n")
        md.append("| point | x | intensity differences / iteration "
                  "| time / iteration (s, median) | total (s, median) | peak memory (MB) "
                  "| TRE mean (mm) |\n|---|---|---|---|---|---|---|")
        for p in pts:
            md.append(f"| {p[6]} | {p[0]} | {p[3]:.3g} | {p[1]:.3f} | {p[4]:.2f} "
                      f"| {p[2]:.0f} | {p[5]:.4f} |")
        md.append("")
    fig.suptitle("DSR cost growth (bench/compare.sh)")
    fig.tight_layout()
    tmp = os.path.join(out, "scaling.tmp.png")
    fig.savefig(tmp, dpi=110)
    os.replace(tmp, os.path.join(out, "scaling.png"))

    # (d) threads: medians over the runs.
    t = {}
    for n in (1, 2):
        xs = []
        for name in sorted(os.listdir(out)):
            if name == f"threads_{n}" or name.startswith(f"threads_{n}_r"):
                xs += [x for x in rows(os.path.join(out, name)) if x["ok"] == "1"]
        if xs:
            t[n] = (median([float(x["seconds_per_iteration"]) for x in xs]),
                    median([float(x["seconds"]) for x in xs]), len(xs))
    if 1 in t and 2 in t:
        md.append("## (d) threads (11 frames of 96x96x80, medians)\n")
        md.append("| threads | runs | time / iteration (s) | total (s) |\n|---|---|---|---|")
        for n in (1, 2):
            md.append(f"| {n} | {t[n][2]} | {t[n][0]:.3f} | {t[n][1]:.2f} |")
        md.append(f"\n2 threads: {t[1][0] / t[2][0]:.2f}x faster per iteration, "
                  f"{t[1][1] / t[2][1]:.2f}x in total.\n")

    # (e) photometric parameters: per run, affine's time per iteration over none's.
    photometric = []
    for name in sorted(os.listdir(out)):
        if name.startswith("photometric_none_r"):
            run = name[len("photometric_none_r"):]
            affine = os.path.join(out, f"photometric_affine_r{run}")
            if not os.path.isdir(affine):
                continue
            n = [x for x in rows(os.path.join(out, name)) if x["ok"] == "1"]
            a = [x for x in rows(affine) if x["ok"] == "1"]
            if n and a:
                photometric.append((run, n[0], a[0]))
    if photometric:
        md.append("## (e) photometric parameters "
                  f"(11 frames of 96x96x80, {len(photometric)} runs)\n")
        md.append("| run | none: time / iteration (s) | affine: time / iteration (s) "
                  "| affine / none | iterations none / affine "
                  "| TRE none / affine (mm) |\n|---|---|---|---|---|---|")
        ratios = []
        for run, n, a in photometric:
            ratio = float(a["seconds_per_iteration"]) / float(n["seconds_per_iteration"])
            ratios.append(ratio)
            md.append(f"| r{run} | {float(n['seconds_per_iteration']):.4f} "
                      f"| {float(a['seconds_per_iteration']):.4f} | {ratio:.2f}x | "
                      f"{n['iterations']} / {a['iterations']} "
                      f"| {float(n['tre_mean_mm']):.4f} / {float(a['tre_mean_mm']):.4f} |")
        md.append(f"\nTime per iteration with photometric parameters: {median(ratios):.2f}x "
                  f"(median of the runs; range {min(ratios):.2f}-{max(ratios):.2f}x).\n")
        dsr, wide = (times.get("BM_DsrEvaluation/1/1/real_time"),
                     times.get("BM_DsrPhotometricEvaluation/1/1/real_time"))
        if dsr and wide:
            md.append(f"One evaluation with Jacobians, 1 thread: {wide:.1f} ms with the parameters "
                      f"against {dsr:.1f} ms ({wide / dsr:.2f}x).\n")

    tmp = os.path.join(out, "summary.md.tmp")
    with open(tmp, "w") as f:
        f.write("\n".join(md) + "\n")
    os.replace(tmp, os.path.join(out, "summary.md"))
    print(open(os.path.join(out, "summary.md")).read())


if __name__ == "__main__":
    main()
