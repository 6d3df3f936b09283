#!/usr/bin/env bash
# Set up everything bimcap needs on a Debian machine; safe to run again (idempotent).
#   1. Debian packages (--no-install-recommends; sudo only when not root; skipped if present)
#   2. a virtual environment in .venv
#   3. pip install of bimcap (builds the C++ core: bimcap._core and bimcap_solve) with test extras
set -euo pipefail
cd "$(dirname "$0")/.."

DEB_PACKAGES=(build-essential cmake ninja-build python3-venv python3-dev
              libceres-dev libeigen3-dev libgoogle-glog-dev libsuitesparse-dev libdeflate-dev
              libgtest-dev libgmock-dev libusb-1.0-0 clang-format)

missing=()
for p in "${DEB_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "==> installing Debian packages: ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "==> creating .venv"
  "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
echo "==> pip install bimcap (this compiles the C++ core the first time)"
.venv/bin/python -m pip install -q ".[test]"
echo "==> setup done: $(.venv/bin/python -c 'import bimcap; print("bimcap", bimcap.__version__)')"
