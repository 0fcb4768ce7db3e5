#!/usr/bin/env bash
# Installs the Debian packages dsr needs, only those missing, and any packages given as
# arguments (scripts/python_test.sh: chromium, the browser the cohort page is opened in).
# Idempotent; quiet when all are present. Runs apt-get directly as root, or through sudo
# when available.
set -euo pipefail
packages=(
  build-essential cmake ninja-build pkg-config
  libceres-dev libeigen3-dev libgoogle-glog-dev libgflags-dev
  libopencv-core-dev libopencv-imgproc-dev libpng-dev
  libinsighttoolkit5-dev nlohmann-json3-dev libfftw3-dev libqhull-dev zlib1g-dev
  libdeflate-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  python3 python3-dev python3-venv pybind11-dev
  "$@"
)
missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
[ ${#missing[@]} -eq 0 ] && exit 0
echo "install_deps: installing ${missing[*]}" >&2
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    echo "install_deps: not root and no sudo; install: ${missing[*]}" >&2; exit 1; fi
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq >/dev/null
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
