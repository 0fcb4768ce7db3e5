#!/usr/bin/env bash
# Whether the cost keeps the views together where they belong: registers each simulated
# sequence starting at its ground-truth poses with every guard and check off (no structure,
# determination or overlap check, no recovery), and reports per source, protocol and mask
# kind how many sequences end with a frame more than 0.5 mm (mean TRE) from the truth (a
# view that slid away; "inf" where a frame ended overlapping no other, which even then ends
# the run), and the median and largest of each sequence's worst frame.
#
#   bash bench/from_truth.sh [--sequences=bench/results/accuracy/sequences]
#                            [--sources=phantom,mni,ct] [--protocols=echo_real]
#                            [--masks=fov,none] [--seeds=20] [--out=bench/results/from_truth]
#                            [-- dsr_register flags, e.g. --preset=echo]
#
# The sequences are bench/accuracy.sh's (run it first with the same protocols and seeds);
# fov uses their exact masks, none each frame's field of view by the default mask rule.
set -euo pipefail
cd "$(dirname "$0")/.."
sequences=bench/results/accuracy/sequences sources=phantom,mni,ct protocols=echo_real
masks=fov,none seeds=20 out=bench/results/from_truth
extra=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --sequences=*) sequences=${1#*=} ;;
    --sources=*) sources=${1#*=} ;;
    --protocols=*) protocols=${1#*=} ;;
    --masks=*) masks=${1#*=} ;;
    --seeds=*) seeds=${1#*=} ;;
    --out=*) out=${1#*=} ;;
    --) shift; extra=("$@"); break ;;
    *) echo "from_truth.sh: unknown argument '$1' (see its header)" >&2; exit 2 ;;
  esac
  shift
done
[[ "$seeds" =~ ^[0-9]+$ && "$seeds" -ge 1 ]] || {
  echo "from_truth.sh: --seeds=$seeds: must be >= 1" >&2; exit 2; }
tools=${DSR_TOOLS:-build/tools}
if [[ ! -x "$tools/dsr_register" ]]; then bash scripts/build.sh; fi
mkdir -p "$out"
guards_off=(--max_structure_fraction=0 --max_pose_error_voxels=0 --min_kept_overlap=0
            --max_recoveries=0 --max_misfit_ratio=0 --max_pair_mismatch_ratio=0)
echo "| source | protocol | masks | sequences | a frame > 0.5 mm | worst frame, median (mm) | worst frame, max (mm) |"
echo "|---|---|---|---|---|---|---|"
IFS=, read -ra source_list <<< "$sources"
IFS=, read -ra protocol_list <<< "$protocols"
IFS=, read -ra mask_list <<< "$masks"
for source in "${source_list[@]}"; do
  for protocol in "${protocol_list[@]}"; do
    for mask in "${mask_list[@]}"; do
      worst=()
      for ((seed = 1; seed <= seeds; ++seed)); do
        dir="$sequences/$source/$protocol/seed$seed"
        [[ -f "$dir/gt_poses.json" ]] || {
          echo "from_truth.sh: no sequence $dir (run bench/accuracy.sh first)" >&2; exit 1; }
        args=(--images="$(ls "$dir"/frame_*.nii.gz | paste -sd,)")
        [[ "$mask" == fov ]] && args+=(--masks="$(ls "$dir"/mask_*.nii.gz | paste -sd,)")
        log="$out/$source-$protocol-$mask-seed$seed.log"
        rc=0
        "$tools/dsr_register" "${args[@]}" --init="$dir/gt_poses.json" \
          --gt_poses="$dir/gt_poses.json" --out_poses="$out/poses.json" --progress=false \
          "${guards_off[@]}" "${extra[@]}" > "$log" 2>&1 || rc=$?
        if [[ $rc -eq 1 ]]; then
          # Refused even with the guards off: a frame that overlaps nothing any more.
          worst+=(inf)
          continue
        fi
        [[ $rc -eq 0 ]] || { echo "from_truth.sh: dsr_register failed, see $log" >&2; exit 1; }
        # The per-frame table: the largest of the frames' mean TREs (column 8, "0.0164mm").
        worst+=("$(sed -n '/^frame /,/^MAE/p' "$log" | awk 'NR > 1 && $8 ~ /mm$/ {
          v = $8 + 0; if (v > w) w = v } END { printf "%.4f", w }')")
      done
      printf '%s\n' "${worst[@]}" | sort -g | awk -v s="$source" -v p="$protocol" -v m="$mask" '
        function show(x) { return x >= 1e9 ? "inf" : sprintf("%.4f", x) }
        { v[NR] = ($1 == "inf") ? 1e9 : $1 + 0; if (v[NR] > 0.5) far++ }
        END { med = NR % 2 ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2
              printf "| %s | %s | %s | %d | %d | %s | %s |\n", s, p, m, NR, far, show(med),
                     show(v[NR]) }'
    done
  done
done
