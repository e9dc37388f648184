"""Long fine-tuning runs on the real drives, scored as they go (issue 27, item 4: longer training, and levers over
more steps than the learning curve's).

Why: the learning curve (scripts/learning_curve.py) scores each run once, at its end. Whether more steps help, or a
lever only pays off late, needs the same run scored at many points. This trains one run of the curve's recipe (the
default row, CPU size, on all 13 train drives of `kitti-real-drives`, Adam at a constant lr 1e-4, one frame per
step, seed 0, one thread) in chunks of --every steps, resuming exactly between chunks, and after each chunk scores a
snapshot of the checkpoint as the curve does: the matching loss L_P on the 5 val drives (8 frames) and an
`i2pbench run --split val` row. Stopped and restarted, it carries on from the last chunk (across sessions too, with
the checkpoint and its resume file kept).

    python scripts/long_run.py --work /tmp/long --name augment --lever augment --until 9500
    python scripts/long_run.py --work /tmp/long --name plain --start /tmp/lc200/runs/synthetic-13.pt --until 9000
    python scripts/long_run.py --table /tmp/long --curve docs/results/learning-curve.csv \
        --csv docs/results/long-runs.csv --md docs/results/long-runs.md --png docs/img/long-runs.png

--start copies a checkpoint (with its resume file and step log) to continue; without it a synthetic-arm run starts
from a copy of the shipped synthetic weights. Every output stays under --work; the table is written where asked.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import time
from argparse import Namespace
from pathlib import Path

import learning_curve as lc  # its recipe, scoring and levers: scripts/ is on the path of a script
import pandas as pd

PROGRESS = "progress.jsonl"
LABELS = {  # the plot's names of the runs in docs/edgeregnet.md
    "plain": "no augmentation",
    "augment": "photometric + LiDAR dropout",
    "image-only": "image branch only (--freeze)",
    "keep-image": "image branch kept (--freeze encoder2d)",
    "low-lr": "lr 3e-5",
}


def checkpoint_step(path: Path) -> int:
    """the optimiser steps a checkpoint has (0 when there is none)."""
    from i2pbench.weights.checkpoints import load_checkpoint

    return int(load_checkpoint(path).meta.get("steps", 0)) if path.exists() else 0


def next_stop(step: int, every: int, until: int) -> int:
    """the next multiple of `every` after `step`, never past `until`."""
    return min((step // every + 1) * every, until)


def score(name: str, step: int, args: Namespace, preset: str, confs: dict) -> dict[str, object]:
    """the snapshot at `step`: val L_P (the curve's val_loss) and the harness row on the val drives."""
    snap = args.work / "snapshots" / f"{name}-{step}.pt"
    snap.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(lc.checkpoint(name, args.work), snap)
    loss = lc.val_loss(snap, preset, confs, args.data_root)
    stem = args.work / "boards" / f"{name}-{step}-val"
    subprocess.run(lc.eval_argv(snap, stem, args, preset, _conf_flags(confs)), check=True)
    return {**loss, **lc.read_board(stem, args.work)}


def _conf_flags(confs: dict) -> list[str]:
    return [
        a for kind, conf in confs.items() for key, value in conf.items() for a in ("--conf", f"{kind}.{key}={value}")
    ]


def train_chunks(args: Namespace) -> None:
    """train to --until in chunks of --every, scoring each chunk's snapshot into work/progress.jsonl."""
    arm, preset, extra = lc.LEVERS[args.lever] if args.lever else ("synthetic", "default", [])
    out = lc.checkpoint(args.name, args.work)
    out.parent.mkdir(parents=True, exist_ok=True)
    if args.start and not out.exists():
        for suffix in ("", ".resume", ".log.jsonl"):
            if Path(f"{args.start}{suffix}").exists():
                shutil.copyfile(f"{args.start}{suffix}", f"{out}{suffix}")
    offset = lc.SHIPPED_STEPS if arm == "synthetic" else 0  # train_argv counts a synthetic arm's steps from 8,500
    step = checkpoint_step(out) or offset
    while step < args.until:
        stop = next_stop(step, args.every, args.until)
        started = time.time()
        subprocess.run(
            lc.train_argv(args.name, arm, lc.ALL_DRIVES, _steps(args, stop - offset), preset, extra), check=True
        )
        trained = time.time()
        record = {"name": args.name, "lever": args.lever, "step": stop, "train_s": round(trained - started, 1)}
        record.update(score(args.name, stop, args, *lc.lever_confs(args.lever)))
        record["score_s"] = round(time.time() - trained, 1)
        with open(args.work / PROGRESS, "a", encoding="utf-8") as f:
            f.write(json.dumps(record, default=str) + "\n")
        step = stop


def _steps(args: Namespace, steps: int) -> Namespace:
    return Namespace(**{**vars(args), "steps": steps})


def table(works: list[Path], curve_csv: Path | None) -> pd.DataFrame:
    """one row per (run, step): the long runs' progress, and the curve's 13-drive synthetic-weights points (no
    lever) as the first steps of the run without augmentation, whose chunks went on from the curve's 200 steps."""
    rows = [json.loads(line) for work in works for line in (work / PROGRESS).read_text().splitlines() if line]
    frame = pd.DataFrame(rows)
    if curve_csv:
        curve = pd.read_csv(curve_csv).fillna({"lever": ""})
        first = curve[(curve["arm"] == "synthetic") & (curve["drives"] == lc.ALL_DRIVES) & (curve["lever"] == "")]
        first = first.assign(name="plain", lever="", step=first["steps"] + lc.SHIPPED_STEPS)
        frame = pd.concat([first[[c for c in frame.columns if c in first]], frame], ignore_index=True)
    frame["train_P"] = [train_loss(works, name, step) for name, step in zip(frame["name"], frame["step"], strict=True)]
    keep = ["name", "lever", "step", "real_steps", "val_P", "train_P", "val_fov", "acc_pct", "chance", "acc_true_pct",
            "true_matches_median", "true_matches_total", "inlier_pct", "weights", "train_s"]  # fmt: skip
    frame = frame.assign(real_steps=frame["step"] - lc.SHIPPED_STEPS)
    frame = frame[frame["real_steps"] > 0]  # a run's first record, before any real step, is the shipped row
    return frame[[c for c in keep if c in frame]].sort_values(["name", "step"]).reset_index(drop=True)


def train_loss(works: list[Path], name: str, step: int, last: int = 50) -> float:
    """the matching loss L_P on the training drives over the `last` steps up to `step`, from the run's step log
    (NaN where no work holds it): what the val loss is set against to see fitting."""
    for work in works:
        log = Path(f"{lc.checkpoint(name, work)}.log.jsonl")
        if log.exists():
            steps = pd.read_json(log, lines=True)
            window = steps[(steps["step"] > step - last) & (steps["step"] <= step)]
            return round(float(window["P"].mean()), 2) if len(window) else math.nan
    return math.nan


def plot(frame: pd.DataFrame, png: Path) -> None:
    """val L_P against the real steps, one line per run, chance and the shipped weights' value marked."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9.6, 4.0), dpi=110)
    ax = fig.subplots()
    for (name, rows), colour in zip(frame.groupby("name"), ("C0", "C1", "C2", "C3", "C4", "C5"), strict=False):
        label = LABELS.get(name, name)
        ax.plot(rows["real_steps"], rows["val_P"], marker="o", color=colour, label=f"{label}: val drives")
        train = {"linestyle": ":", "marker": "x", "color": colour, "label": f"{label}: train drives"}
        ax.plot(rows["real_steps"], rows["train_P"], **train)
    ax.axhline(2 * math.log(2048), color="red", linestyle="--", linewidth=0.8, label="chance, 2 ln 2048")
    ax.set_xlabel("optimiser steps on the 13 train drives (from the shipped synthetic weights)")
    ax.set_ylabel("matching loss L_P (train: mean of 50 steps)")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the axes, off the lines
    fig.suptitle("EdgeRegNet CPU size, long runs; shipped weights: L_P 36.9", fontsize=9)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", type=Path, help="checkpoints, snapshots, boards and progress.jsonl: outside the repo")
    p.add_argument("--name", help="the run's name (its checkpoint is work/runs/NAME.pt)")
    p.add_argument("--lever", default="", help=f"one of the curve's levers: {', '.join(lc.LEVERS)} (none: plain)")
    p.add_argument("--start", help="a checkpoint to continue (copied with its resume file and step log)")
    p.add_argument("--until", type=int, help="stop at this step (a synthetic-arm run counts from 8,500)")
    p.add_argument("--every", type=int, default=100, help="steps between scored snapshots")
    p.add_argument("--data-root", default="../shared/data")
    p.add_argument("--lr", type=float, default=1e-4)
    p.add_argument("--table", type=Path, nargs="*", help="only tabulate these works' progress")
    p.add_argument("--curve", type=Path, help="the learning curve's CSV, for the plain run's first points")
    p.add_argument("--csv", type=Path)
    p.add_argument("--md", type=Path)
    p.add_argument("--png", type=Path)
    args = p.parse_args(argv)
    if args.lever and args.lever not in lc.LEVERS:
        p.error(f"--lever {args.lever!r}: choose from {', '.join(lc.LEVERS)}")
    if args.table is None:
        if not (args.work and args.name and args.until):
            p.error("training needs --work, --name and --until")
        train_chunks(args)
        return 0
    lc.write_table(table(args.table, args.curve), args, plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
