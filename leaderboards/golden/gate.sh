#!/usr/bin/env bash
# The CI regression gate: rerun the golden grid on the real KITTI frames and on a tiny synthetic split, then compare
# with the committed leaderboards. Latency is checked only for a gross (10x) slowdown, as it depends on the machine.
#   bash leaderboards/golden/gate.sh            compare (exit 1 on a regression or a missing row)
#   bash leaderboards/golden/gate.sh --update   rewrite the golden leaderboards from this run (review the diff)
set -euo pipefail
cd "$(dirname "$0")/../.."
GOLDEN=leaderboards/golden
TOLERANCE=acc=-2,rte=+0.05,rre=+0.2,latency=x10
KITTI_ROOT=${I2PBENCH_KITTI_ROOT:-../shared/data/kitti_odometry}
SYNTHETIC_ROOT=${XDG_CACHE_HOME:-$HOME/.cache}/i2pbench/gate-synthetic  # 3 frames, made once, kept across runs
MODE=${1:-compare}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

run() {  # NAME, then the dataset options
    local name=$1
    shift
    .venv/bin/i2pbench run --grid "$GOLDEN/classic.yaml" --runs-dir "$work/runs" --out "$work/$name" \
        --threads 1 --quiet "$@" >/dev/null
    if [ "$MODE" = --update ]; then
        cp "$work/$name.csv" "$work/$name.md" "$GOLDEN/"
    else
        echo "== $name"
        .venv/bin/i2pbench compare "$work/$name.csv" "$GOLDEN/$name.csv" --tolerance "$TOLERANCE"
    fi
}

run kitti-classic --dataset kitti --split all --data-root "$KITTI_ROOT"
run synthetic-classic --dataset synthetic --split test --data-root "$SYNTHETIC_ROOT" --data-conf frames.test=3
