#!/usr/bin/env bash
# Builds the Python package (python/) against the Release build's libraries and runs its
# pytest suite (python/tests). The libraries are installed into BUILD/python-prefix
# (cmake --install: static, position-independent) and the extension module links them, so
# only python/src/*.cc are compiled here. The package goes
# into .venv (scripts/python_env.sh); scikit-build-core comes from PyPI (Debian has none),
# pybind11 from Debian; SimpleITK and tqdm (and nibabel, python_env.sh) for the tests that
# pass their images and show a bar, Dask distributed for the cohort runner (dsr.cohort). Called by scripts/test.sh after the Release ctest.
set -euo pipefail
cd "$(dirname "$0")/.."
build="$PWD/${DSR_BUILD_DIR:-build}"
bash scripts/install_deps.sh chromium  # the cohort page is opened in headless Chromium
python=$(bash scripts/python_env.sh)
"$python" -m pip install -q --disable-pip-version-check "pytest>=7" "numpy>=1.21" "SimpleITK==2.5.7" tqdm \
  "dask[distributed]==2024.8.2"
cmake --install "$build" --prefix "$build/python-prefix" >/dev/null
"$python" -m pip install -q --disable-pip-version-check ./python \
  -Ccmake.define.dsr_DIR="$build/python-prefix/lib/cmake/dsr" -Cbuild-dir="$build/python"
DSR_TOOLS="$build/tools" "$python" -m pytest -q python/tests
