#!/usr/bin/env python3
"""Summarises bench/accuracy.sh runs: one Markdown row per (method, source, protocol, masks).

Usage: accuracy_summary.py --init=NAME SOURCE,PROTOCOL,MASKS,results.csv[,checks_off.csv] [...]
A run succeeds when dsr_compare reports it ok and its mean TRE is below 0.1 mm; on the
ultrasound-like protocols with brightness changes (us, us_gain, echo) also when it is within
1.5 times the TRE of the same sequence without them (us_flat, echo_flat: the same poses, noise
and speckle), and on those references below 1 mm (the right basin, a wrong minimum being
millimetres off). TRE and
time medians are over the successful runs, the max TRE over every run that returned poses;
the max times are over every run, split by whether it needed a recovery round (with the
run counts; dsr_compare's recoveries column).
With us (or us_gain) and us_flat, or echo and echo_flat, for the same source, masks and
method, a brightness table
compares them sequence by sequence (the same poses, noise and speckle, with and without the gains,
offsets and attenuation): runs refused or unsuccessful on each, the median TREs and their
ratio, and the median error of the estimated gains and offsets where the poses files have
them (mae_gain, mae_offset).
With dsr_compare --uncertainty (bench/accuracy.sh --uncertainty) a second table compares the
predicted with the measured error over the successful runs: the mean predicted and measured
TRE, their ratio, and the mean normalised squared pose error e^T C^-1 e over 6 (1 when the
covariance is calibrated; docs/design.md section 8.6), and the spread of the per-sequence
ratio measured / predicted TRE (its range, and how many sequences exceed 1.2).
With a checks_off.csv (bench/accuracy.sh: the refused runs registered again with the misfit
and pair checks off), a table lists every refusal with the TRE it would have had, and counts
per row the clear false refusals (refused, below CLEAR_FALSE_REFUSAL_MM with the checks off),
the refusals in between, the right refusals (above CLEAR_MISS_MM with the checks off, or still
failing), the clear misses (accepted above CLEAR_MISS_MM) and the accepted runs in between
(from the success threshold to CLEAR_MISS_MM).
With several methods on the same sequences a head-to-head table compares the first method
with each other one on the sequences where both succeed: on how many the first is more
accurate, and the median and largest per-sequence TRE ratio first / other. Arguments with the
same SOURCE,PROTOCOL,MASKS add their methods to one group, so that runs of other tools on the
same sequences compare too (e.g. dsr's results.csv, then bench/elastix.sh's).
"""
import csv
import math
import statistics
import sys

SUCCESS_TRE_MM = 0.1
SUCCESS_TRE_MM_BY_PROTOCOL = {"us_flat": 1.0, "echo_flat": 1.0}
# The protocol each brightness-changing protocol is compared with: the same sequences
# without the gains, offsets and attenuation. A run of one of these succeeds when it is
# accepted and within FLAT_RATIO of the same sequence's flat run (accepted or not: its TRE
# as dsr_compare recorded it), or below SUCCESS_TRE_MM.
FLAT_PROTOCOL = {"us": "us_flat", "us_gain": "us_flat", "echo": "echo_flat"}
FLAT_RATIO = 1.5
# The brightness table compares runs in the right basin (a wrong minimum is millimetres off).
BASIN_MM = 1.0
# A refusal is clearly false when the run ends below this with the checks off; an accepted
# run is a clear miss above CLEAR_MISS_MM.
CLEAR_FALSE_REFUSAL_MM = 0.05
CLEAR_MISS_MM = 0.5


def success_mm(protocol):
    return SUCCESS_TRE_MM_BY_PROTOCOL.get(protocol, SUCCESS_TRE_MM)


# (source, FLAT protocol, masks) -> {(method, sequence): row}, filled by main before judging.
FLAT_ROWS = {}


def succeeded(row, source, protocol, masks):
    """Whether an accepted run counts as a success (see SUCCESS_TRE_MM and FLAT_PROTOCOL)."""
    if row["ok"] != "1":
        return False
    tre = float(row["tre_mean_mm"])
    if protocol in FLAT_PROTOCOL:
        flat = FLAT_ROWS.get((source, FLAT_PROTOCOL[protocol], masks), {}).get(
            (row["method"], row["sequence"]))
        flat_tre = float(flat["tre_mean_mm"]) if flat and flat.get("tre_mean_mm") else math.nan
        return tre < SUCCESS_TRE_MM or tre <= FLAT_RATIO * flat_tre
    return tre < success_mm(protocol)


def refusal_rows(source, protocol, masks, rows, checks_off, out):
    """Appends one line per method to `out` when the row has a refusal or an accepted run
    above the success threshold (see the module's doc)."""
    by_method = {}
    for r in rows:
        by_method.setdefault(r["method"], []).append(r)
    for method, runs in by_method.items():
        refused = [r for r in runs if r["ok"] != "1"]
        above = [r for r in runs if r["ok"] == "1" and not succeeded(r, source, protocol, masks)]
        if not refused and not above:
            continue
        false_refusals = between = right = 0
        notes = []
        for r in refused:
            off = checks_off.get((method, r["sequence"]))
            if off is None:
                notes.append(f"{r['sequence']} (not rerun)")
                continue
            if off["ok"] != "1":
                right += 1
                notes.append(f"{r['sequence']} (fails)")
                continue
            tre = float(off["tre_mean_mm"])
            notes.append(f"{r['sequence']} {tre:.3g}")
            if tre < CLEAR_FALSE_REFUSAL_MM:
                false_refusals += 1
            elif tre > CLEAR_MISS_MM:
                right += 1
            else:
                between += 1
        misses = sum(float(r["tre_mean_mm"]) > CLEAR_MISS_MM for r in above)
        notes += [f"{r['sequence']} accepted at {float(r['tre_mean_mm']):.3g}" for r in above]
        out.append(f"| {method} | {source} | {protocol} | {masks} | {len(refused)} | "
                   f"{false_refusals} | {between} | {right} | {len(above) - misses} | {misses} | "
                   f"{'; '.join(notes)} |")


def median_or_nan(values):
    return statistics.median(values) if values else float("nan")


def main(argv):
    init = "?"
    groups = []
    for arg in argv[1:]:
        if arg.startswith("--init="):
            init = arg.split("=", 1)[1]
            continue
        source, protocol, masks, path = arg.split(",", 3)
        path, _, off_path = path.partition(",")
        groups.append((source, protocol, masks, path, off_path))
    for source, protocol, masks, path, _ in groups:
        if protocol in FLAT_PROTOCOL.values():
            with open(path, newline="") as f:
                FLAT_ROWS[(source, protocol, masks)] = {
                    (r["method"], r["sequence"]): r for r in csv.DictReader(f)}
    print(f"Initialiser: `--init={init}`. Success: accepted and mean TRE < {SUCCESS_TRE_MM} mm "
          f"(< 1 mm on {', '.join(SUCCESS_TRE_MM_BY_PROTOCOL)}; on "
          f"{', '.join(FLAT_PROTOCOL)}: below {SUCCESS_TRE_MM} mm or within {FLAT_RATIO}x the "
          f"same sequence's run without brightness changes).\n")
    print("| method | source | protocol | masks | success | median TRE (mm) | max TRE (mm) "
          "| median time (s) | max time (s), runs without / with a recovery | failures |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    calibration = []
    refusals = []
    shared = []
    head_to_head = []
    by_group = {}  # (source, protocol, masks) -> {method: [rows]}
    for source, protocol, masks, path, off_path in groups:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        checks_off = {}
        if off_path:
            with open(off_path, newline="") as f:
                checks_off = {(r["method"], r["sequence"]): r for r in csv.DictReader(f)}
        refusal_rows(source, protocol, masks, rows, checks_off, refusals)
        by_method = {}
        for r in rows:
            by_method.setdefault(r["method"], []).append(r)
        for method, runs in by_method.items():
            by_group.setdefault((source, protocol, masks), {}).setdefault(method, []).extend(runs)
        for method, runs in by_method.items():
            ok = [r for r in runs if succeeded(r, source, protocol, masks)]
            tre_ok = [float(r["tre_mean_mm"]) for r in ok]
            tre_all = [float(r["tre_mean_mm"]) for r in runs if r["ok"] == "1"]
            times = [float(r["seconds"]) for r in ok if r.get("seconds")]  # empty: not timed
            failed = sorted(r["sequence"] for r in runs if r not in ok)
            # Every run's time, split by whether it needed a recovery round (columns of
            # dsr_compare; other tools' rows have none).
            plain = [float(r["seconds"]) for r in runs if r.get("recoveries", "") == "0"]
            recovered = [float(r["seconds"]) for r in runs
                         if r.get("recoveries", "") not in ("", "0")]
            def longest(seconds):  # "-" where no run falls in the group
                return f"{max(seconds):.2f}" if seconds else "-"
            split = (f"{longest(plain)} ({len(plain)}) / {longest(recovered)} ({len(recovered)})"
                     if plain or recovered else "-")
            print(f"| {method} | {source} | {protocol} | {masks} | {len(ok)}/{len(runs)} | "
                  f"{statistics.median(tre_ok) if tre_ok else float('nan'):.4f} | "
                  f"{max(tre_all) if tre_all else float('nan'):.3g} | "
                  f"{statistics.median(times) if times else float('nan'):.2f} | {split} | "
                  f"{' '.join(failed) if failed else '-'} |")
            offsets = [[float(r[f"shared_offset_{a}_mm"]) for a in "xyz"] for r in ok
                       if r.get("shared_offset_x_mm")]
            if offsets and len(offsets) == len(ok):
                n = len(offsets)
                mean = [sum(o[a] for o in offsets) / n for a in range(3)]
                along = sum(sum(o[a] * mean[a] for a in range(3)) > 0.0 for o in offsets)
                shared.append(
                    f"| {method} | {source} | {protocol} | {masks} | {n} | "
                    f"{statistics.median(math.hypot(*o) for o in offsets):.4f} | "
                    f"{mean[0]:.4f} {mean[1]:.4f} {mean[2]:.4f} | {along}/{n} | "
                    f"{statistics.median(float(r['frame_spread_mm']) for r in ok):.4f} |")
            predicted = [float(r["predicted_tre_mm"]) for r in ok if r.get("predicted_tre_mm")]
            nees = [float(r["nees"]) for r in ok if r.get("nees")]
            if predicted and len(predicted) == len(ok):
                measured = statistics.mean(tre_ok)
                ratios = [t / p for t, p in zip(tre_ok, predicted)]
                calibration.append(
                    f"| {method} | {source} | {protocol} | {masks} | {len(ok)} | "
                    f"{statistics.mean(predicted):.4f} | {measured:.4f} | "
                    f"{measured / statistics.mean(predicted):.2f} | "
                    f"{statistics.mean(nees) / 6.0:.2f} | "
                    f"{min(ratios):.2f}-{max(ratios):.2f} | "
                    f"{sum(r > 1.2 for r in ratios)}/{len(ratios)} |")
    for (source, protocol, masks), by_method in by_group.items():
        methods = list(by_method)
        good = {m: {r["sequence"]: float(r["tre_mean_mm"]) for r in by_method[m]
                    if succeeded(r, source, protocol, masks)}
                for m in methods}
        for other in methods[1:]:
            first = methods[0]
            both = sorted(set(good[first]) & set(good[other]))
            if not both:
                continue
            ratio = [good[first][q] / good[other][q] for q in both]
            wins = sum(r < 1.0 for r in ratio)
            head_to_head.append(
                f"| {first} vs {other} | {source} | {protocol} | {masks} | {wins}/{len(both)} | "
                f"{statistics.median(ratio):.2f} | {max(ratio):.2f} |")
    brightness = []
    for (source, protocol, masks), by_method in by_group.items():
        flat = (by_group.get((source, FLAT_PROTOCOL[protocol], masks))
                if protocol in FLAT_PROTOCOL else None)
        if not flat:
            continue
        for method, runs in by_method.items():
            if method not in flat:
                continue
            def good(rows):  # accepted, in the right basin
                return {r["sequence"]: float(r["tre_mean_mm"]) for r in rows
                        if r["ok"] == "1" and float(r["tre_mean_mm"]) < BASIN_MM}

            us, us_flat = good(runs), good(flat[method])
            refused = sum(r["ok"] != "1" for r in runs)
            refused_flat = sum(r["ok"] != "1" for r in flat[method])
            both = sorted(set(us) & set(us_flat))
            ratio = [us[q] / us_flat[q] for q in both]
            gains = [float(r["mae_gain"]) for r in runs if r["ok"] == "1" and r.get("mae_gain")]
            offsets = [float(r["mae_offset"]) for r in runs
                       if r["ok"] == "1" and r.get("mae_offset")]
            m_us, m_flat = median_or_nan(list(us.values())), median_or_nan(list(us_flat.values()))
            brightness.append(
                f"| {method} | {source} | {protocol} | {masks} "
                f"| {refused} / {len(runs) - refused - len(us)} | "
                f"{refused_flat} / {len(flat[method]) - refused_flat - len(us_flat)} | "
                f"{m_us:.4f} | {m_flat:.4f} | {m_us / m_flat:.2f} | "
                f"{median_or_nan(ratio):.2f} ({min(ratio) if ratio else float('nan'):.2f}-"
                f"{max(ratio) if ratio else float('nan'):.2f}) | "
                f"{median_or_nan(gains):.4f} | {median_or_nan(offsets):.2f} |")
    if brightness:
        print("\nBrightness changes: us (and us_gain) against us_flat, echo against echo_flat, "
              "the same sequences without "
              "the gains, offsets and attenuation (refused: the checks refused the run; missed: "
              f"usable but TRE >= {success_mm('us')} mm).\n")
        print("| method | source | protocol | masks | refused / missed | flat refused / missed "
              "| median TRE (mm) | flat median TRE (mm) | ratio of medians "
              "| per-sequence ratio, median (range) | gain MAE | offset MAE |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for line in brightness:
            print(line)
    if refusals:
        print(f"\nRefusals and misses: each refused run with its TRE when registered again "
              f"with the checks off (clear false refusal: below {CLEAR_FALSE_REFUSAL_MM} mm; "
              f"right: above {CLEAR_MISS_MM} mm or still failing), and the accepted runs above "
              f"the success threshold (clear miss: above {CLEAR_MISS_MM} mm).\n")
        print("| method | source | protocol | masks | refused | clear false refusals "
              "| refusals in between | right refusals | accepted above the threshold "
              "| clear misses | runs (TRE with the checks off, mm) |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for line in refusals:
            print(line)
    if calibration:
        print("\nPredicted against measured error (calibrated: both ratios within [0.7, 1.5]).\n")
        print("| method | source | protocol | masks | runs | predicted TRE (mm) "
              "| measured TRE (mm) | measured / predicted | mean e^T C^-1 e / 6 "
              "| per-sequence ratio | sequences above 1.2 |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for line in calibration:
            print(line)
    if shared:
        print("\nThe frames' errors at their fields of view's centres, split into the offset they "
              "share (frame 0 off against the rest) and their spread about it (successful runs; "
              "mm, frame 0's axes).\n")
        print("| method | source | protocol | masks | runs | median shared offset | mean shared "
              "offset (x y z) | sequences along the mean | median spread |")
        print("|---|---|---|---|---|---|---|---|---|")
        for line in shared:
            print(line)
    if head_to_head:
        print("\nHead to head on the sequences where both succeed (TRE ratio < 1: the first "
              "method is more accurate).\n")
        print("| methods | source | protocol | masks | first more accurate | median TRE ratio "
              "| max TRE ratio |")
        print("|---|---|---|---|---|---|---|")
        for line in head_to_head:
            print(line)


if __name__ == "__main__":
    main(sys.argv)
