#!/usr/bin/env bash
# Times every linear solver of --mode=dba (and the dense solvers of --mode=dsr) on the
# small sequence of configs/dba_small_simulate.flags, one after another in one run, and
# prints a markdown table (wall time of the registration, iterations, peak memory, errors
# against ground truth). Usage: bash scripts/linear_solver_table.sh [build_dir]
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir="${1:-${DSR_BUILD_DIR:-build}}"
"$build_dir/tools/dsr_simulate" --flagfile=configs/dba_small_simulate.flags >/dev/null 2>&1
echo "| mode | linear solver | time (s) | iterations | peak memory (MiB) | MAE translation (voxels) | MAE rotation (rad) |"
echo "|---|---|---|---|---|---|---|"
for run in dba:DENSE_SCHUR dba:SPARSE_SCHUR dba:ITERATIVE_SCHUR dba:SPARSE_NORMAL_CHOLESKY dba:DENSE_QR \
           dsr:DENSE_QR dsr:DENSE_NORMAL_CHOLESKY; do
  mode="${run%%:*}"; solver="${run#*:}"
  if output=$("$build_dir/tools/dsr_register" --flagfile=configs/dba_small.flags --mode="$mode" \
      --linear_solver="$solver" --out_poses="out/dba_small/poses_${mode}_${solver}.json" \
      --out_panorama= --progress=false 2>&1); then
    time_s=$(sed -n 's/.*: time \([0-9.]*\) s (load [0-9.]* s, pyramid [0-9.]* s, solves \([0-9.]*\) s, checks [0-9.]* s).*/\2/p' <<<"$output")
    iterations=$(sed -n 's/.*, \([0-9]*\) iterations,.*/\1/p' <<<"$output")
    memory=$(sed -n 's/.*peak memory \([0-9]*\) MiB.*/\1/p' <<<"$output")
    mae_t=$(sed -n 's/^MAE: translation \([0-9.e+-]*\) voxels.*/\1/p' <<<"$output")
    mae_r=$(sed -n 's/.*rotation \([0-9.e+-]*\) rad;.*/\1/p' <<<"$output")
    echo "| $mode | $solver | $time_s | $iterations | $memory | $mae_t | $mae_r |"
  else
    reason=$(grep -m1 'error' <<<"$output" | sed 's/^dsr_register: error: //' | cut -c1-120)
    echo "| $mode | $solver | refused: $reason | | | | |"
  fi
done
