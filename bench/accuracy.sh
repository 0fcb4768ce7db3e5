#!/usr/bin/env bash
# Accuracy benchmark: registers N seeded simulated sequences per source,
# protocol and mask kind with dsr_compare and writes one table of success rates (mean TRE
# below 0.1 mm), median and max TRE and median time.
#
#   bash bench/accuracy.sh [--seeds=20] [--sources=phantom,mni,ct] [--protocols=paper,wide,walk]
#                          [--masks=fov,none] [--init=auto] [--methods=dsr]
#                          [--uncertainty] [--photometric=auto|none|affine]
#                          [--intensity_transform=none|sqrt] [--panorama_sampling=half_voxel|all_phases]
#                          [--gauge=mean|frame0] [--mask_rule=hull|nonzero] [--detect_dropouts]
#                          [--no_checks_off]
#                          [--out=bench/results/accuracy]
#
# Sources: the built-in phantom, the MNI152 T1 template and a chest CT with the heart in view
# (scripts/fetch_anatomy.sh mni|ct: real anatomy the project did not make; the CT's frames
# are cut at 1 mm, its lungs are dark tissue inside the fields of view). Protocols: bench/protocols.sh (paper,
# wide, walk, the ultrasound-like us and us_flat, and echo and echo_flat, which also map every
# source to an echo-like look with black blood pools, lungs and CSF). Masks: fov = the exact field of view
# (dsr_simulate --mask_erosion=0), none = each frame's field of view by --mask_rule eroded
# by one voxel (what dsr_register uses without --masks). Sequences are cached under
# OUT/sequences (simulated again when their protocol's flags change).
# Every run the checks refuse is registered again with them off (--max_structure_fraction=0
# --max_pose_error_voxels=0 --max_misfit_ratio=0 --max_pair_mismatch_ratio=0; the overlap
# guard stays, so that recovery still runs where a
# frame slides out; runs in RUN-checks_off), and the summary lists each refusal
# with the TRE it would have had: a refusal of a run that ends below 0.05 mm with the checks
# off is a clear false refusal, an accepted run above 0.5 mm a clear miss
# (bench/accuracy_summary.py). --no_checks_off skips the second pass.
# --uncertainty: also the pose covariance (dsr_compare --uncertainty) and a table of the
# predicted against the measured error (runs go to OUT/runs/INIT-uncertainty).
# --photometric=affine: per-frame gain and offset estimated with the poses (dsr_compare
# --photometric; runs go to OUT/runs/INIT-affine, the table to OUT/accuracy_INIT_affine.md).
# --intensity_transform=sqrt: register sqrt(c I) (dsr_compare --intensity_transform; runs
# go to OUT/runs/INIT[-affine]-sqrt, the table to OUT/accuracy_INIT[_affine]_sqrt.md).
# --panorama_sampling=all_phases: frame 0 sampled at every sub-voxel phase (dsr_compare
# --panorama_sampling; the suffix -all_phases after the others).
# --gauge=frame0: DSR's and DBA's solves with frame 0 constant rather than in the default mean
# gauge (dsr_compare --gauge; the suffix -frame0_gauge last).
# --mask_rule=nonzero: the none rows' masks by the non-zero rule rather than the default
# convex hull of the non-zero voxels (dsr_compare --mask_rule; the suffix -nonzero_masks last).
# --detect_dropouts: each view's beams without signal left out of its mask (dsr_compare
# --detect_dropouts, as --preset=echo does; the suffix -dropouts last).
# Long: about 2-4 s per run on 2 cores (20 seeds x 2 sources x 3 protocols x 2 mask kinds =
# 240 runs per initialiser); not part of the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
seeds=20 sources=phantom,mni,ct protocols=paper,wide,walk masks=fov,none init=auto methods=dsr
uncertainty="" checks_off="" photometric=auto transform=none sampling=half_voxel gauge=mean
mask_rule=hull dropouts=false
out=bench/results/accuracy
for arg in "$@"; do
  case "$arg" in
    --seeds=*) seeds=${arg#*=} ;;
    --sources=*) sources=${arg#*=} ;;
    --protocols=*) protocols=${arg#*=} ;;
    --masks=*) masks=${arg#*=} ;;
    --init=*) init=${arg#*=} ;;
    --methods=*) methods=${arg#*=} ;;
    --out=*) out=${arg#*=} ;;
    --uncertainty) uncertainty=--uncertainty ;;
    --no_checks_off) checks_off=skip ;;
    --photometric=*) photometric=${arg#*=} ;;
    --intensity_transform=*) transform=${arg#*=} ;;
    --panorama_sampling=*) sampling=${arg#*=} ;;
    --gauge=*) gauge=${arg#*=} ;;
    --mask_rule=*) mask_rule=${arg#*=} ;;
    --detect_dropouts) dropouts=true ;;
    *) echo "accuracy.sh: unknown argument '$arg' (see the header of bench/accuracy.sh)" >&2; exit 2 ;;
  esac
done
[[ "$seeds" =~ ^[0-9]+$ && "$seeds" -ge 1 ]] || { echo "accuracy.sh: --seeds=$seeds: must be >= 1" >&2; exit 2; }
[[ "$photometric" == auto || "$photometric" == none || "$photometric" == affine ]] || {
  echo "accuracy.sh: --photometric=$photometric: must be auto, none or affine" >&2; exit 2; }
[[ "$transform" == none || "$transform" == sqrt ]] || {
  echo "accuracy.sh: --intensity_transform=$transform: must be none or sqrt" >&2; exit 2; }
suffix="${uncertainty:+-uncertainty}"
[[ "$photometric" == affine ]] && suffix="$suffix-affine"
[[ "$photometric" == none ]] && suffix="$suffix-no_photometric"
[[ "$transform" == sqrt ]] && suffix="$suffix-sqrt"
[[ "$sampling" == half_voxel || "$sampling" == all_phases ]] || {
  echo "accuracy.sh: --panorama_sampling=$sampling: must be half_voxel or all_phases" >&2; exit 2; }
[[ "$sampling" == all_phases ]] && suffix="$suffix-all_phases"
[[ "$gauge" == frame0 || "$gauge" == mean ]] || {
  echo "accuracy.sh: --gauge=$gauge: must be frame0 or mean" >&2; exit 2; }
[[ "$gauge" == frame0 ]] && suffix="$suffix-frame0_gauge"
[[ "$mask_rule" == hull || "$mask_rule" == nonzero ]] || {
  echo "accuracy.sh: --mask_rule=$mask_rule: must be hull or nonzero" >&2; exit 2; }
[[ "$mask_rule" == nonzero ]] && suffix="$suffix-nonzero_masks"
[[ "$dropouts" == true ]] && suffix="$suffix-dropouts"
tools=${DSR_TOOLS:-build/tools}
if [[ ! -x "$tools/dsr_compare" ]]; then bash scripts/build.sh; fi
mni="" ct=""
if [[ ",$sources," == *",mni,"* ]]; then mni=$(bash scripts/fetch_anatomy.sh mni | tail -n 1); fi
if [[ ",$sources," == *",ct,"* ]]; then ct=$(bash scripts/fetch_anatomy.sh ct | tail -n 1); fi

# shellcheck source=bench/protocols.sh
source bench/protocols.sh

mkdir -p "$out"
csvs=()
IFS=, read -ra source_list <<< "$sources"
IFS=, read -ra protocol_list <<< "$protocols"
IFS=, read -ra mask_list <<< "$masks"
for source in "${source_list[@]}"; do
  case "$source" in
    phantom) source_flag="" ;;
    mni) source_flag="--source=$mni" ;;
    ct) source_flag="--source=$ct --frame_spacing=1" ;;
    *) echo "accuracy.sh: unknown source '$source' (phantom, mni, ct)" >&2; exit 2 ;;
  esac
  for protocol in "${protocol_list[@]}"; do
    flags=$(protocol_flags "$protocol") || {
      echo "accuracy.sh: unknown protocol '$protocol' ($protocol_names)" >&2; exit 2; }
    folders=()
    for ((seed = 1; seed <= seeds; ++seed)); do
      dir="$out/sequences/$source/$protocol/seed$seed"
      # shellcheck disable=SC2086
      simulate_sequence "$tools" "$dir" "$seed" $source_flag $flags || {
        echo "accuracy.sh: dsr_simulate failed for $dir: $(tail -n 1 "$dir.log")" >&2; exit 1; }
      folders+=("$dir")
    done
    list=$(IFS=,; echo "${folders[*]}")
    for mask in "${mask_list[@]}"; do
      case "$mask" in fov) use=true ;; none) use=false ;;
        *) echo "accuracy.sh: unknown mask kind '$mask' (fov, none)" >&2; exit 2 ;; esac
      run="$out/runs/$init$suffix/$source-$protocol-$mask"
      mkdir -p "$run"
      echo "accuracy.sh: $source $protocol masks=$mask init=$init ($seeds sequences)" >&2
      "$tools/dsr_compare" --out_dir="$run" --methods="$methods" --sequences="$list" \
        --sequence_masks="$use" --init="$init" --photometric="$photometric" \
        --intensity_transform="$transform" --panorama_sampling="$sampling" --gauge="$gauge" \
        --mask_rule="$mask_rule" --detect_dropouts="$dropouts" \
        $uncertainty \
        2>"$run.log" >/dev/null || {
        echo "accuracy.sh: dsr_compare failed, see $run.log" >&2; exit 1; }
      # Every refused run again with the checks off (and so without recovery, which they
      # drive): is the refusal right? Its TRE then says (docs/design.md section 8).
      refused=$(awk -F, -v dir="$out/sequences/$source/$protocol" \
        'NR > 1 && $3 != "1" { printf "%s%s/%s", (n++ ? "," : ""), dir, $2 }' "$run/results.csv")
      off_csv=""
      if [[ -n "$refused" && -z "$checks_off" ]]; then
        "$tools/dsr_compare" --out_dir="$run-checks_off" --methods="$methods" \
          --sequences="$refused" --sequence_masks="$use" --init="$init" \
          --photometric="$photometric" --intensity_transform="$transform" \
          --panorama_sampling="$sampling" --gauge="$gauge" --mask_rule="$mask_rule" \
          --detect_dropouts="$dropouts" --max_structure_fraction=0 --max_pose_error_voxels=0 \
          --max_misfit_ratio=0 --max_pair_mismatch_ratio=0 \
          --min_kept_overlap=0.25 \
          2>"$run-checks_off.log" >/dev/null || {
          echo "accuracy.sh: dsr_compare failed, see $run-checks_off.log" >&2; exit 1; }
        off_csv=",$run-checks_off/results.csv"
      fi
      csvs+=("$source,$protocol,$mask,$run/results.csv$off_csv")
    done
  done
done
summary="$out/accuracy_$init${suffix//-/_}.md"
python3 bench/accuracy_summary.py --init="$init" "${csvs[@]}" > "$summary"
cat "$summary"
echo "accuracy.sh: wrote $summary" >&2
