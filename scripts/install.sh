#!/usr/bin/env bash
# Installs i2pbench and everything it needs into .venv, from the project's own files.
# torch==2.13.0 goes first so pip keeps the CPU wheel (a bare `torch` would pull a multi-GB CUDA build).
set -euo pipefail
cd "$(dirname "$0")/.."

if ! ldconfig -p 2>/dev/null | grep -q libusb-1.0.so.0; then  # open3d imports only with libusb present
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
fi

if ! command -v chromium >/dev/null 2>&1; then  # headless, renders `i2pbench report` pages in the tests (else skipped)
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    { $SUDO apt-get update -qq \
        && $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } \
        || echo "install.sh: chromium not installed; the HTML report rendering tests will be skipped" >&2
fi

PYTHON=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q "torch==2.13.0"
.venv/bin/python -m pip install -q -e ".[dev,ray,train]"  # ray: --executor ray and its tests; train: TensorBoard
# nuscenes-devkit pins numpy<2 and opencv-python-headless, which would clash with numpy 2 and the contrib OpenCV:
# install it without its pins, plus the runtime dependencies it really uses. pip would then end with "ERROR: ...
# nuscenes-devkit requires numpy<2" (and Shapely~=2.0.3): those are the pins skipped on purpose, so the step does not
# warn; `pip check` still lists them, harmlessly.
.venv/bin/python -m pip install -q --no-deps "nuscenes-devkit==1.2.0"
.venv/bin/python -m pip install -q --no-warn-conflicts -r requirements-nuscenes.txt
echo "install.sh: done; nuscenes-devkit's numpy<2 and Shapely pins are skipped on purpose (see docs/datasets.md)"
