#!/usr/bin/env bash
# The main job on the built-in default, no files needed: installs what is missing, builds,
# simulates an 11-frame TEE-like sequence from the built-in phantom with the paper's
# protocol (+/-12 degrees, +/-15 voxels, noise sigma 25) into out/demo, registers it with
# DSR from identity initial poses, prints the per-frame errors against ground truth, and
# writes a report (pictures, poses, ITK transforms, index.md) to out/demo/report.
set -euo pipefail
cd "$(dirname "$0")/.."
# Only the tools it runs (the test suite's build is scripts/test.sh's).
DSR_BUILD_TARGETS="dsr_simulate dsr_register" bash scripts/build.sh
build_dir="${DSR_BUILD_DIR:-build}"
out="${DSR_DEMO_DIR:-out/demo}"
"$build_dir/tools/dsr_simulate" --out_dir="$out/sequence" --seed=1
images=$(ls "$out"/sequence/frame_*.nii.gz | paste -sd, -)
masks=$(ls "$out"/sequence/mask_*.nii.gz | paste -sd, -)
"$build_dir/tools/dsr_register" --images="$images" --masks="$masks" --mode=dsr \
  --out_poses="$out/poses.json" --out_panorama="$out/panorama.nii.gz" \
  --gt_poses="$out/sequence/gt_poses.json" --progress=false --blend=feather \
  --report_dir="$out/report" --out_tfm_dir="$out/transforms"
echo "demo: sequence in $out/sequence, poses in $out/poses.json, panorama in $out/panorama.nii.gz"
echo "demo: report (pictures, poses, transforms) in $out/report/index.md"
