#!/usr/bin/env bash
# Box plots of a dsr_compare CSV (scripts/plot_compare.py), with matplotlib set up first.
# Usage: bash scripts/plot_compare.sh out/paper_simulated/results.csv [out.png]
set -euo pipefail
python="$(bash "$(dirname "$0")/python_env.sh")"
exec "$python" "$(dirname "$0")/plot_compare.py" "$@"
