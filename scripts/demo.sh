#!/usr/bin/env bash
# The main job on the built-in default, no files needed: installs what is missing, builds,
# simulates an 11-frame TEE-like sequence from the built-in phantom (the paper's protocol)
# into out/demo, and prints where it is. Registration of the sequence joins this script
# with `dsr_register --mode=dsr` (see the README's status).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
build_dir="${DSR_BUILD_DIR:-build}"
out="${DSR_DEMO_DIR:-out/demo}"
"$build_dir/tools/dsr_simulate" --out_dir="$out" --seed=1
echo "demo sequence written to $out (frames, masks, gt_poses.json)"
