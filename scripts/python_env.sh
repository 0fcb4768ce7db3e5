#!/usr/bin/env bash
# Creates (once) the Python virtual environment for the plotting scripts and
# scripts/fetch_anatomy.sh in .venv, with matplotlib and nibabel from PyPI, and prints the
# path of its python. Python is only used around the C++ (plots, preparing data), never in
# the solver path. nibabel is pinned: fetch_anatomy.sh checks the bytes of the NIfTI file it
# writes, header included.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! python3 -m venv --help >/dev/null 2>&1 || ! python3 -c "import ensurepip" >/dev/null 2>&1; then
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq python3-venv >/dev/null
fi
if [ ! -x .venv/bin/python ] ||
  ! .venv/bin/python -c "import matplotlib, nibabel; assert nibabel.__version__ == '5.4.2'" \
    >/dev/null 2>&1; then
  python3 -m venv .venv >&2
  .venv/bin/pip install -q --disable-pip-version-check "matplotlib>=3.6" "nibabel==5.4.2" >&2
fi
echo "$PWD/.venv/bin/python"
