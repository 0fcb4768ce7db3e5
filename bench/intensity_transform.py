#!/usr/bin/env python3
"""Experiment: does a variance-stabilising intensity transform help DSR on speckled data?

Copies each sequence folder (frame_XX, mask_XX, gt_poses.json, as dsr_simulate writes
them, e.g. bench/accuracy.sh's OUT/sequences/SOURCE/PROTOCOL/seedN) with every frame's
intensities I replaced by T(I), then registers the copies and the originals with
dsr_compare (the same runner, initialiser and error measures as bench/accuracy.sh) and
prints, per source (the folder two levels up, e.g. phantom), the median and mean TRE per
transform and on how many sequences the transform is more accurate than none. T: none, sqrt (16 sqrt(I), 0..255 -> 0..255) or log
(40 log(1 + I)). The ground truth's gains and offsets are dropped from the copies (they are
in the original grey levels). Python only prepares files and reads results: registration and
error measures are the C++ tools'.

    .venv/bin/python bench/intensity_transform.py --out=/tmp/vst --transforms=none,sqrt \
        [--photometric=affine] [--tools=build/tools] SEQUENCE_DIR [SEQUENCE_DIR ...]
"""
import argparse
import csv
import os
import pathlib
import shutil
import statistics
import subprocess
import sys

import numpy as np

import dsr

TRANSFORMS = {
    "none": lambda a: a,
    "sqrt": lambda a: 16.0 * np.sqrt(np.maximum(a, 0.0)),
    "log": lambda a: 40.0 * np.log1p(np.maximum(a, 0.0)),
}


def copy_transformed(source: pathlib.Path, target: pathlib.Path, transform: str) -> None:
    target.mkdir(parents=True, exist_ok=True)
    frames = sorted(source.glob("frame_*.nii.gz"))
    for frame in frames:
        image = dsr.read_image(frame)
        image.array = TRANSFORMS[transform](image.array.astype(np.float64)).astype(np.float32)
        dsr.write_image(image, target / frame.name)
    for mask in sorted(source.glob("mask_*.nii.gz")):
        shutil.copyfile(mask, target / mask.name)
    truth = dsr.read_poses(source / "gt_poses.json", len(frames))
    dsr.write_poses(target / "gt_poses.json", truth["frame_from_world"], images=truth["images"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--transforms", default="none,sqrt")
    parser.add_argument("--photometric", default="none", choices=["none", "affine"])
    parser.add_argument("--tools", default="build/tools")
    parser.add_argument("sequences", nargs="+")
    args = parser.parse_args()
    transforms = args.transforms.split(",")
    for t in transforms:
        if t not in TRANSFORMS:
            parser.error(f"--transforms: unknown transform '{t}' ({', '.join(TRANSFORMS)})")
    out = pathlib.Path(args.out)
    tre = {}
    for t in transforms:
        folders = []
        for s in args.sequences:
            source = pathlib.Path(s)
            name = "_".join(source.parts[-3:])
            target = out / "sequences" / t / name
            copy_transformed(source, target, t)
            folders.append(str(target))
        run = out / "runs" / t
        result = subprocess.run(
            [os.path.join(args.tools, "dsr_compare"), f"--out_dir={run}", "--methods=dsr",
             f"--sequences={','.join(folders)}", "--sequence_masks=true", "--init=auto",
             f"--photometric={args.photometric}"],
            capture_output=True, text=True)
        if result.returncode != 0:
            print(f"intensity_transform.py: dsr_compare failed: {result.stderr[-500:]}",
                  file=sys.stderr)
            return 1
        with open(run / "results.csv") as f:
            tre[t] = {row["sequence"]: float(row["tre_mean_mm"]) for row in csv.DictReader(f)
                      if row["ok"] == "1"}
    print("| source | transform | runs | median TRE (mm) | mean TRE (mm) | more accurate than none |")
    print("|---|---|---|---|---|---|")
    sources = sorted({name.split("_")[0] for t in transforms for name in tre[t]})
    for source in sources:
        for t in transforms:
            mine = {s: v for s, v in tre[t].items() if s.split("_")[0] == source}
            if not mine:
                continue
            if t == "none" or "none" not in tre:
                versus = "-"
            else:
                both = [s for s in mine if s in tre["none"]]
                versus = f"{sum(mine[s] < tre['none'][s] for s in both)}/{len(both)}"
            values = list(mine.values())
            print(f"| {source} | {t} | {len(values)} | {statistics.median(values):.4f} | "
                  f"{statistics.mean(values):.4f} | {versus} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
