"""Summary of bench/phases.sh's runs: per source and protocol, every phase against phase 0.

Usage: python3 bench/phases_summary.py OUT/phases.csv   (plain Python 3, no numpy)
"""
import csv
import statistics
import sys
from collections import defaultdict

SUCCESS_MM = 0.1  # bench/accuracy.sh's rule: exit 0 and mean TRE below 0.1 mm


def main(path):
    runs = defaultdict(dict)  # (source, protocol) -> {(seed, phases): row}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            runs[(row["source"], row["protocol"])][(row["seed"], row["phases"])] = row
    print("| source | protocol | sequences | success every phase | success phase 0 | "
          "median TRE every phase (mm) | median TRE phase 0 (mm) | median ratio | "
          "max TRE every phase / phase 0 (mm) | median time every phase / phase 0 (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for (source, protocol), cases in sorted(runs.items()):
        seeds = sorted({seed for seed, _ in cases}, key=int)
        both = [s for s in seeds if (s, "all") in cases and (s, "0") in cases]

        def ok(row):
            return row["exit"] == "0" and row["tre_mean_mm"] and \
                float(row["tre_mean_mm"]) < SUCCESS_MM

        def tre(s, which):
            row = cases[(s, which)]
            return float(row["tre_mean_mm"]) if row["exit"] == "0" and row["tre_mean_mm"] \
                else float("inf")

        good = [s for s in both if ok(cases[(s, "all")]) and ok(cases[(s, "0")])]
        ratios = [tre(s, "all") / tre(s, "0") for s in good]
        cells = [source, protocol, str(len(both)),
                 f"{sum(ok(cases[(s, 'all')]) for s in both)}/{len(both)}",
                 f"{sum(ok(cases[(s, '0')]) for s in both)}/{len(both)}",
                 f"{statistics.median(tre(s, 'all') for s in both):.4f}",
                 f"{statistics.median(tre(s, '0') for s in both):.4f}",
                 f"{statistics.median(ratios):.3f}" if ratios else "-",
                 f"{max(tre(s, 'all') for s in both):.4f} / {max(tre(s, '0') for s in both):.4f}",
                 f"{statistics.median(float(cases[(s, 'all')]['seconds']) for s in both):.1f} / "
                 f"{statistics.median(float(cases[(s, '0')]['seconds']) for s in both):.1f}"]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main(sys.argv[1])
