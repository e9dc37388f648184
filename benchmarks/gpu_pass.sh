#!/usr/bin/env bash
# The GPU figure (docs/performance.md): install, then time the official EdgeRegNet frame and the default grid on a
# CUDA device and write OUT_DIR/gpu_pass.json (per-stage seconds and peak memory; benchmarks/gpu_pass.py).
#   bash benchmarks/gpu_pass.sh OUT_DIR                      install (scripts/install.sh), then run on cuda
#   bash benchmarks/gpu_pass.sh OUT_DIR --no-install --device cpu --frames 1 --keypoints 64 --repeat 1
#                                                            the same pass on the CPU, as tests/test_gpu_pass.py runs it
# On a GPU machine, TORCH=torch==X picks the CUDA build scripts/install.sh installs (default: constraints.txt's pin).
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -ge 1 ] || { echo "usage: bash benchmarks/gpu_pass.sh OUT_DIR [--no-install] [gpu_pass.py options]" >&2; exit 2; }
out=$1
shift
if [ "${1:-}" = --no-install ]; then
    shift
else
    bash scripts/install.sh
fi
.venv/bin/python benchmarks/gpu_pass.py --out "$out" "$@"
