#!/usr/bin/env bash
# Cardiac loops at clinical size: time and memory per phase. dsr_simulate writes 11 views of
# 176x176x200 voxels at 0.6 mm (the paper's clinical volumes, ~6.2M voxels each) with T
# phases of the beating phantom (each view a 4D NIfTI); dsr_register registers them with
# phase 0 alone and with every phase, --runs times each in turn, and the table gives each
# run's time (load, pyramid, solves) and peak memory, and per added phase the growth of
# both (the slope between the one-phase and the T-phase medians).
#
#   bash bench/phases_clinical.sh [--phases=4] [--runs=2] [--out=bench/results/phases_clinical]
#
# Long: ~10 minutes on 2 cores and ~9 GB of memory at T = 4; not part of the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
phases=4 runs=2 out=bench/results/phases_clinical
for arg in "$@"; do
  case "$arg" in
    --phases=*) phases=${arg#*=} ;;
    --runs=*) runs=${arg#*=} ;;
    --out=*) out=${arg#*=} ;;
    *) echo "phases_clinical.sh: error: unknown argument $arg" >&2; exit 2 ;;
  esac
done
tools=${DSR_TOOLS:-build/tools}
seq="$out/sequence-$phases"
mkdir -p "$out"
if [ ! -f "$seq/gt_poses.json" ]; then
  "$tools/dsr_simulate" --out_dir="$seq" --frame_size=176,176,200 --frame_spacing=0.6 \
    --num_phases="$phases" --seed=1 >/dev/null 2>"$out/simulate.log"
fi
images=$(ls "$seq"/frame_*.nii.gz | paste -sd, -)
masks=$(ls "$seq"/mask_*.nii.gz | paste -sd, -)
table="$out/phases_clinical.md"
{
  echo "| phases | run | time (s) | load (s) | pyramid (s) | solves (s) | peak memory (MiB) | mean TRE (mm) |"
  echo "|---|---|---|---|---|---|---|---|"
} > "$table"
for run in $(seq 1 "$runs"); do
  for which in 0 all; do
    log="$out/register_${which}_$run.txt"
    "$tools/dsr_register" --images="$images" --masks="$masks" --phases="$which" \
      --out_poses="$out/poses_$which.json" --gt_poses="$seq/gt_poses.json" --progress=false \
      >"$log" 2>&1
    line=$(grep -o "time [0-9.]* s (load [0-9.]* s, pyramid [0-9.]* s, solves [0-9.]* s, checks [0-9.]* s), peak memory [0-9]* MiB" "$log")
    tre=$(grep -o "TRE mean [0-9.e+-]* mm" "$log" | awk '{print $3}')
    read -r t l p s m <<<"$(echo "$line" | sed -E 's/time ([0-9.]*) s \(load ([0-9.]*) s, pyramid ([0-9.]*) s, solves ([0-9.]*) s, checks [0-9.]* s\), peak memory ([0-9]*) MiB/\1 \2 \3 \4 \5/')"
    n=$([ "$which" = all ] && echo "$phases" || echo 1)
    echo "| $n | $run | $t | $l | $p | $s | $m | $tre |" >> "$table"
    echo "phases $n run $run: $line, TRE mean $tre mm"
  done
done
python3 - "$table" "$phases" <<'PY'
import statistics, sys
rows = [line.split("|")[1:-1] for line in open(sys.argv[1]) if line.startswith("| ") and
        line[2].isdigit()]
t = int(sys.argv[2])
def median(n, column):
    return statistics.median(float(r[column]) for r in rows if int(r[0]) == n)
lines = ["", f"Per added phase (medians, {t} phases against 1): "
         f"time +{(median(t, 2) - median(1, 2)) / (t - 1):.1f} s "
         f"(solves +{(median(t, 5) - median(1, 5)) / (t - 1):.1f} s, "
         f"load +{(median(t, 3) - median(1, 3)) / (t - 1):.1f} s), "
         f"peak memory +{(median(t, 6) - median(1, 6)) / (t - 1):.0f} MiB; "
         f"{t} phases take {median(t, 2) / median(1, 2):.2f}x the time of one and "
         f"{median(t, 6) / median(1, 6):.2f}x its memory."]
with open(sys.argv[1], "a") as f:
    f.write("\n".join(lines) + "\n")
print(open(sys.argv[1]).read())
PY
