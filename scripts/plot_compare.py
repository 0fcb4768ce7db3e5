#!/usr/bin/env python3
"""Box plots of a dsr_compare CSV, like the paper's Fig. 1: mean absolute error of the
frame-0-relative translation components (voxels) and Euler angles (rad) per method, one
box per method over the sequences.

Usage: python3 scripts/plot_compare.py RESULTS_CSV [OUT_PNG]
(OUT_PNG defaults to mae_boxplots.png next to the CSV; scripts/plot_compare.sh sets up
matplotlib first.)"""
import csv
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def main():
    if len(sys.argv) not in (2, 3):
        sys.exit(__doc__)
    path = sys.argv[1]
    out = (sys.argv[2] if len(sys.argv) == 3
           else os.path.join(os.path.dirname(path), "mae_boxplots.png"))
    methods, translation, rotation = [], {}, {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            m = row["method"]
            if m not in methods:
                methods.append(m)
                translation[m], rotation[m] = [], []
            if row["ok"] != "1":
                continue
            translation[m].append(float(row["mae_translation_voxels"]))
            rotation[m].append(float(row["mae_rotation_rad"]))
    if not methods:
        sys.exit(f"{path}: no rows")
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, data, title, unit in (
        (axes[0], translation, "Translation", "MAE (voxels)"),
        (axes[1], rotation, "Rotation", "MAE (rad)"),
    ):
        ax.boxplot([data[m] if data[m] else [float("nan")] for m in methods],
                   tick_labels=methods, showfliers=True)
        ax.set_yscale("log")
        ax.set_title(title)
        ax.set_ylabel(unit)
        ax.tick_params(axis="x", rotation=25)
        ax.grid(True, axis="y", which="both", alpha=0.3)
    n = max(len(translation[m]) for m in methods)
    fig.suptitle(f"Frame-0-relative mean absolute errors over {n} sequences (dsr_compare)")
    fig.tight_layout()
    tmp = out + ".tmp.png"
    fig.savefig(tmp, dpi=110)
    os.replace(tmp, out)  # atomic: a reader never sees half a picture
    print(f"plot_compare: wrote {out}")


if __name__ == "__main__":
    main()
