#!/usr/bin/env bash
# Regenerates every committed leaderboard under leaderboards/ (the CI golden ones have gate.sh --update) from the
# shipped weights, on the embedded synthetic test split and the real frames in ../shared/data. Review the diff.
#   bash leaderboards/make.sh              all of them (about two hours on 2 busy cores)
#   bash leaderboards/make.sh kitti-real   only the boards whose name contains this word
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${I2PBENCH_SHARED_DATA:-../shared/data}
RUNS=${I2PBENCH_MAKE_RUNS:-runs/make-leaderboards}  # per-frame results: a rerun only computes what changed
ONLY=${1:-}
PRESETS=baselines,edge-ablation,exchange-ablation  # every row of the paper's tables and the baselines, once each

selected() {  # NAME: whether this invocation makes that board
    case "$1" in *"$ONLY"*) return 0 ;; esac
    return 1
}

board() {  # NAME, then the run options
    local name=$1
    shift
    selected "$name" || return 0
    echo "== $name" >&2
    .venv/bin/i2pbench run --runs-dir "$RUNS" --threads 1 --quiet --out "leaderboards/$name" "$@" >/dev/null
}

board synthetic-test-edgeregnet --preset baselines --dataset synthetic --split test
board kitti-sample-classic --grid leaderboards/kitti-sample-classic.yaml --dataset kitti --split all \
    --data-root "$DATA/kitti_odometry"
board kitti-sample-edgeregnet --preset "$PRESETS" --dataset kitti --split all --data-root "$DATA/kitti_odometry"
# kitti_real by whole sequence: train = 04 (a highway, KITTI Odometry), val = 26 (city traffic, a raw drive)
board kitti-real-04 --preset "$PRESETS" --dataset kitti --split train --data-root "$DATA/kitti_real"
board kitti-real-26 --preset "$PRESETS" --dataset kitti --split val --data-root "$DATA/kitti_real"
# nuScenes: ten keyframes of scene-0916 (devkit val split), all six cameras
root="$RUNS/nuscenes-real-dataroot"
if selected nuscenes-real || selected paper-table-1-nuscenes; then  # the devkit dataroot both nuScenes boards read
    [ -d "$root/v1.0-trainval" ] || .venv/bin/i2pbench data nuscenes-dataroot --records "$DATA/nuscenes_real" --out "$root"
fi
NUSCENES=(--dataset nuscenes --split val --data-root "$root"
    --data-conf 'cameras=[CAM_FRONT, CAM_FRONT_LEFT, CAM_FRONT_RIGHT, CAM_BACK, CAM_BACK_LEFT, CAM_BACK_RIGHT]')
board nuscenes-real --preset baselines "${NUSCENES[@]}"
# The seed paper's Table I (plugins/tables): every method on the same frames and transforms of each dataset, then
# one table with a column group per dataset (held-out real KITTI 26, the nuScenes keyframes, the synthetic test split)
board paper-table-1-synthetic --preset paper-table-1 --dataset synthetic --split test
board paper-table-1-kitti --preset paper-table-1 --dataset kitti --split val --data-root "$DATA/kitti_real"
board paper-table-1-nuscenes --preset paper-table-1 "${NUSCENES[@]}"
case "paper-table-1" in *"$ONLY"*)
    .venv/bin/i2pbench table --preset paper-table-1 --out leaderboards/paper-table-1 >/dev/null \
        KITTI=leaderboards/paper-table-1-kitti.csv nuScenes=leaderboards/paper-table-1-nuscenes.csv \
        synthetic=leaderboards/paper-table-1-synthetic.csv
    ;;
esac
# Robustness (docs/robustness.md): clean, then all twelve corruptions at severities 1, 3, 5, on the first 10 frames
ROBUST=(--robustness --severities 1,3,5 --frames 10)
CLASSIC=(--matcher oracle --extractor lsd,canny --extractor3d depth+reflectance --solver epnp-ransac,poselib)
board robustness-synthetic-test-classic "${CLASSIC[@]}" --dataset synthetic --split test "${ROBUST[@]}"
board robustness-synthetic-test-edgeregnet --preset default --dataset synthetic --split test "${ROBUST[@]}"
board robustness-kitti-real-classic "${CLASSIC[@]}" --dataset kitti --split all --data-root "$DATA/kitti_real" \
    "${ROBUST[@]}"
# the held-out sequence 26 (val), the shipped EdgeRegNet beside the classic rows on the same 10 frames
board robustness-kitti-real-26-classic "${CLASSIC[@]}" --dataset kitti --split val --data-root "$DATA/kitti_real" \
    "${ROBUST[@]}"
board robustness-kitti-real-26-edgeregnet --preset default --dataset kitti --split val \
    --data-root "$DATA/kitti_real" "${ROBUST[@]}"
