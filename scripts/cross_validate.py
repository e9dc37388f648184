"""Pool the test folds of a k-fold run by scene and print Acc. with true matches and the true-matches median, each
with a 95% interval from resampling whole scenes (i2pbench.boards.crossval).

    for k in 1 2 3 4 5; do i2pbench run --dataset kitti-drives --data-root ../shared/data --split test --fold $k/5 \
        --preset default --weights weights/fold$k.pt; done
    python scripts/cross_validate.py --folds 5 --data-root ../shared/data

Reads the results store runs/kitti-drives-test-fold{K}of{N}/ (the per-frame records each fold's run wrote); every fold
must be there, since a missing fold would leave its scenes out of the estimate.

`--loss WEIGHTS` (a path in which `{k}` stands for the fold, e.g. weights/fold{k}.pt; without it the same weights
for every fold) adds the matcher's loss L_P on each fold's test frames, pooled the same way (its mean, with a
scene-bootstrap interval): the signal that still moves where no frame is registered (chance: 2 ln 2048 = 15.2).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from i2pbench.boards.crossval import cross_validated, scene_bootstrap
from i2pbench.boards.leaderboard import to_markdown
from i2pbench.data.kitti_drives import DEFAULT_SPLIT_FILE, KittiDrives
from i2pbench.runs.store import ResultsStore


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--folds", type=int, required=True, help="N of the K/N folds that were run")
    p.add_argument("--runs-dir", default="runs")
    p.add_argument("--data-root", required=True, help="the kitti-drives root the folds were run on")
    p.add_argument("--split-file", default=DEFAULT_SPLIT_FILE)
    p.add_argument("--out", help="also write the table to this .md file")
    p.add_argument("--loss", metavar="WEIGHTS", help="also pool L_P of these weights ({k}: the fold) on the test folds")
    p.add_argument("--preset", default="default", help="the preset whose row --loss runs")
    args = p.parse_args(argv)
    suffix = "" if args.split_file == DEFAULT_SPLIT_FILE else f"-{Path(args.split_file).stem}"
    parts = []
    for k in range(1, args.folds + 1):
        fold = ResultsStore(Path(args.runs_dir) / f"kitti-drives-test{suffix}-fold{k}of{args.folds}", read_only=True)
        parts.append(fold.load())
        if parts[-1].empty:
            print(f"cross_validate: no results for fold {k}/{args.folds} under {args.runs_dir}", file=sys.stderr)
            return 1
    records = pd.concat(parts, ignore_index=True).drop_duplicates(["frame_id", "combination"], keep="last")
    dataset = KittiDrives("all", {"root": args.data_root, "split_file": args.split_file})
    table = cross_validated(records, dataset.scene_of)
    if args.loss:
        mean, low, high = pooled_loss(args, dataset.scene_of)
        table = table.assign(**{"L_P ↓": round(mean, 2), "L_P 95% interval": f"[{low:.2f}, {high:.2f}]"})
    text = to_markdown(table, list(table.columns))
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n", encoding="utf-8")
    return 0


def pooled_loss(args: argparse.Namespace, scene_of) -> tuple[float, float, float]:
    """the mean L_P over every fold's test frames, each fold's from its own weights, and its scene-bootstrap
    interval (scripts/learning_curve.py computes each frame's loss terms)."""
    import learning_curve as curve  # scripts/ is on the path of a script

    frames, losses = [], []
    for k in range(1, args.folds + 1):
        weights = Path(args.loss.format(k=k))
        fold = f"{k}/{args.folds}"
        for frame_id, terms in curve.frame_losses(
            weights, args.preset, {}, args.data_root, "test", fold, args.split_file
        ):
            frames.append(frame_id)
            losses.append(terms["P"])
    return scene_bootstrap(np.array(losses), [scene_of(f) for f in frames], np.mean)


if __name__ == "__main__":
    sys.exit(main())
