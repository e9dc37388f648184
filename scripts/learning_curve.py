"""Learning curve of EdgeRegNet (CPU size, the default preset) on real KITTI drives: validation against the number
of training drives, with and without synthetic pretraining (issue 27, item 2).

Why: one real drive is memorised, not generalised from (docs/edgeregnet.md#sim-to-real-what-the-real-kitti-frames-say).
The curve says whether more drives help, and by how much, at a fixed training budget.

What it runs, all deterministic (seed 0):
- drives: the first K scenes of the `kitti-real-drives` split file's train list, in the file's order (largest
  first), for each K in --drives; K = all uses the committed file itself, a smaller K a copy of it whose train list
  is cut to K scenes (and whose other train scenes are left out), so val and test stay the file's;
- arms: `synthetic` continues a copy of the shipped synthetic weights (`train --force`) for --steps more steps;
  `scratch` trains from random weights for the same --steps; same learning rate, one frame per step;
- levers (--levers): each on all training drives for the same steps (LEVERS below);
- measure: `i2pbench run --split val` on the committed file's val drives (5 scenes, 8 frames, protocol seed 0) with
  each final checkpoint, through the harness (the table takes the board's columns, plus the true matches summed
  over the frames); with --val-loss also the matcher's loss on those frames, and the training loss from the step log.

What ran for docs/edgeregnet.md (a 2-core CPU shared with other jobs): the curve and two levers at 50 steps, then
copies of the 1- and 13-drive checkpoints continued to 100 steps (train resumes them exactly), then the table:

    python scripts/learning_curve.py --work /tmp/lc --steps 50 --jobs 4 --levers aliked,mix
    mkdir -p /tmp/lc100/runs && cp /tmp/lc/runs/{synthetic,scratch}-{1,13}.pt* /tmp/lc100/runs/
    python scripts/learning_curve.py --work /tmp/lc100 --steps 100 --jobs 2 --drives 13,1
    # the 13-drive pair again, copied from /tmp/lc100 to /tmp/lc200, to 200 steps:
    python scripts/learning_curve.py --work /tmp/lc200 --steps 200 --jobs 1 --drives 13
    python scripts/learning_curve.py --work /tmp/lc --also /tmp/lc100 /tmp/lc200 --table-only --val-loss --jobs 3 \
        --csv docs/results/learning-curve.csv --md docs/results/learning-curve.md --png docs/img/learning-curve.png

A rerun skips what is done: `train` resumes from its checkpoint and stops at --steps; `run` reuses its cache.
Every training output stays under --work; only the table and the plot are written where asked.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
from argparse import Namespace
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path

import pandas as pd
import yaml

from i2pbench.boards.leaderboard import to_markdown
from i2pbench.data.kitti_drives import DEFAULT_SPLIT_FILE, load_split_file
from i2pbench.runs.store import ResultsStore
from i2pbench.weights.checkpoints import file_digest

ARMS = ("synthetic", "scratch")
SHIPPED = (
    Path(__file__).resolve().parents[1] / "plugins/edgeregnet/i2pbench_edgeregnet/weights/edgeregnet-cpu-synthetic.pt"
)
SHIPPED_STEPS = 8500  # the shipped synthetic checkpoint's step count: `train --steps` counts from 0
ALL_DRIVES = 13  # the train list's length
CURVE_DRIVES = (1, 3, 10, 13)
COLUMNS = {
    "Acc. (%) ↑": "acc_pct",
    "chance successes": "chance",
    "Acc. with true matches (%) ↑": "acc_true_pct",
    "true matches median ↑": "true_matches_median",
    "inlier ratio (%) ↑": "inlier_pct",
    "weights": "weights",
    "weights_trained_on": "trained_on",
}


def cli() -> Path:
    """the `i2pbench` command of the running interpreter's environment."""
    return Path(sys.executable).parent / "i2pbench"


def split_file_for(drives: int, work: Path) -> str:
    """the committed split file for all its train drives, else a copy whose train list is its first `drives` scenes."""
    split_file = load_split_file(DEFAULT_SPLIT_FILE)
    train = list(split_file.splits["train"])
    if drives >= len(train):
        return DEFAULT_SPLIT_FILE
    keep = train[:drives] + list(split_file.splits["val"]) + list(split_file.splits["test"])
    data = {
        "name": f"{DEFAULT_SPLIT_FILE}-train{drives}",
        "scenes": {scene: list(split_file.scenes[scene]) for scene in split_file.scenes if scene in keep},
        "train": train[:drives],
        "val": list(split_file.splits["val"]),
        "test": list(split_file.splits["test"]),
    }
    path = work / "splits" / f"train{drives}.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return str(path)


# levers (issue 27, item 4), each on all training drives for the same steps, measured on the same val drives:
# name -> (arm it starts from, preset, extra train options)
# aliked: frozen pretrained ALIKED image features at half resolution (a quarter of its full-resolution cost, which
# this CPU could not afford), the other stages from scratch: no checkpoint fits them; mix: half the samples from the
# synthetic train split; augment: image and scan randomisation per sample; image-only: only the image branch
# (encoder2d) is fine-tuned, the 3D encoder, exchanger and matcher stay the synthetic weights' (`--freeze`).
# keep-image: the converse, the image branch kept as the synthetic weights have it; low-lr: a third of the recipe's
# learning rate.
LEVERS = {
    "aliked": ("scratch", "edgeregnet-aliked", ["--conf", "encoder2d.image_scale=0.5"]),
    "mix": ("synthetic", "default", ["--mix", "synthetic:train=0.5"]),
    "augment": ("synthetic", "default", ["--augment", "photometric,lidar-dropout"]),
    "image-only": ("synthetic", "default", ["--freeze", "encoder3d,exchanger,matcher"]),
    "keep-image": ("synthetic", "default", ["--freeze", "encoder2d"]),
    "low-lr": ("synthetic", "default", ["--lr", "3e-5"]),  # after the recipe's --lr: the last one counts
}


def checkpoint(name: str, work: Path) -> Path:
    return work / "runs" / f"{name}.pt"


def train_argv(name: str, arm: str, drives: int, args: Namespace, preset: str = "default", extra=()) -> list[str]:
    """`i2pbench train` on the first `drives` train scenes, from the shipped synthetic weights or from scratch."""
    out = checkpoint(name, args.work)
    out.parent.mkdir(parents=True, exist_ok=True)
    if arm == "synthetic":
        if not out.exists():
            shutil.copyfile(SHIPPED, out)  # train never writes into the package: it continues a copy
        steps = ["--force", "--steps", str(SHIPPED_STEPS + args.steps)]
    else:
        steps = ["--steps", str(args.steps)]
    split_file = split_file_for(drives, args.work)
    files = [] if split_file == DEFAULT_SPLIT_FILE else ["--split-file", split_file]
    return [
        str(cli()), "train", "--preset", preset, "--dataset", "kitti-drives", "--data-root", args.data_root,
        *files, "--split", "train", "--out", str(out), *steps, "--lr", str(args.lr), "--seed", "0",
        "--threads", "1", "--cache-dir", str(args.work / "cache"), "--checkpoint-every", "25",
        "--val-split", "none", "--quiet", *extra,
    ]  # fmt: skip


def board(name: str, work: Path) -> Path:
    return work / "boards" / f"{name}-val"


def eval_argv(weights: Path, stem: Path, args: Namespace, preset: str = "default", confs=()) -> list[str]:
    """`i2pbench run` of the preset's row with `weights` on the committed file's val drives."""
    return [
        str(cli()), "run", "--preset", preset, "--dataset", "kitti-drives", "--data-root", args.data_root,
        "--split", "val", "--weights", str(weights), "--runs-dir", str(args.work / "rundir"), "--out", str(stem),
        "--threads", "1", "--quiet", *confs,
    ]  # fmt: skip


def train_and_measure(name: str, arm: str, drives: int, args: Namespace, preset: str = "default", extra=()) -> None:
    subprocess.run(train_argv(name, arm, drives, args, preset, extra), check=True)
    confs = [a for pair in zip(extra[::2], extra[1::2], strict=True) if pair[0] == "--conf" for a in pair]
    subprocess.run(eval_argv(checkpoint(name, args.work), board(name, args.work), args, preset, confs), check=True)


def tasks(args: Namespace) -> list[tuple]:
    """(name, arm, drives, preset, extra) of every run, in the order they start: each drive count's two arms side
    by side, then the levers."""
    curve = [(f"{arm}-{d}", arm, d, "default", []) for d in args.drives for arm in ARMS]
    return curve + [(f"lever-{lever}", LEVERS[lever][0], ALL_DRIVES, *LEVERS[lever][1:]) for lever in args.levers]


def read_board(stem: Path, work: Path) -> dict[str, object]:
    """the board's columns, plus the true matches summed over the val frames: a finer signal than the median while
    most frames have none."""
    row = pd.read_csv(stem.with_suffix(".csv")).iloc[0]
    out = {short: row[long] for long, short in COLUMNS.items()}
    frames = ResultsStore(work / "rundir" / "kitti-drives-val", read_only=True).load()
    mine = frames[(frames["weights"] == row["weights"]) & (frames["combination"] == row["combination"])]
    return {**out, "true_matches_total": int(mine.drop_duplicates("frame_id")["n_true_matches"].fillna(0).sum())}


def step_log(name: str, work: Path) -> dict[str, float]:
    """median seconds per optimiser step, and the matching loss L_P on the training drives over the last 10 steps."""
    log = pd.read_json(f"{checkpoint(name, work)}.log.jsonl", lines=True)
    return {
        "steps": len(log),  # one line per step on real drives (a synthetic-arm run counts from 8,500)
        "s_per_step": round(float(log["seconds"].median()), 1),
        "train_P": round(float(log["P"].tail(10).mean()), 2),
    }


def row(name: str, arm: str, drives: int, work: Path, args: Namespace, lever: str = "") -> dict[str, object]:
    split_file = load_split_file(DEFAULT_SPLIT_FILE)
    scenes = split_file.splits["train"][:drives]
    frames = sum(_frames(seq, args.data_root) for seq in split_file.sequences(scenes))
    out = {"arm": arm, "lever": lever, "drives": len(scenes), "frames": frames}
    return {**out, **step_log(name, work), **read_board(board(name, work), work)}


def measured(work: Path) -> list[tuple[str, str, int, str]]:
    """(name, arm, drives, lever) of every run whose board is there."""
    runs = [(f"{arm}-{d}", arm, d, "") for arm in ARMS for d in CURVE_DRIVES]
    runs += [(f"lever-{lever}", LEVERS[lever][0], ALL_DRIVES, lever) for lever in LEVERS]
    return [r for r in runs if board(r[0], work).with_suffix(".csv").exists()]


def table(work: Path, args: Namespace) -> pd.DataFrame:
    """the shipped weights' row as the reference, one row per (arm, drives), one per lever measured; with
    --val-loss, each checkpoint's loss terms on the val frames (one process per checkpoint, --jobs at a time)."""
    shipped = {"arm": "shipped (synthetic only)", "lever": "", "drives": 0, "frames": 0, "steps": 0}
    runs = measured(work)
    rows = [{**shipped, **read_board(board("shipped", work), work)}]
    rows += [row(name, arm, drives, work, args, lever) for name, arm, drives, lever in runs]
    if args.val_loss:
        jobs = [(SHIPPED, "default", {})] + [(checkpoint(r[0], work), *lever_confs(r[3])) for r in runs]
        rows = [{**r, **loss} for r, loss in zip(rows, val_losses(jobs, work, args), strict=True)]
    return pd.DataFrame(rows)


def val_losses(jobs: list[tuple], work: Path, args: Namespace) -> list[dict[str, float]]:
    """val_loss of each (weights, preset, confs), kept in work/val-loss/<stem>@<sha8>.json: a checkpoint's bytes
    fix its loss, so a rerun computes only new ones."""
    paths = [work / "val-loss" / f"{w.stem}@{file_digest(w)[:8]}.json" for w, *_ in jobs]
    todo = [(job, path) for job, path in zip(jobs, paths, strict=True) if not path.exists()]
    with ProcessPoolExecutor(args.jobs) as pool:
        found = pool.map(val_loss, *zip(*[job for job, _ in todo], strict=True), [args.data_root] * len(todo))
        for (_, path), loss in zip(todo, found, strict=True):
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(loss), encoding="utf-8")
    return [json.loads(path.read_text(encoding="utf-8")) for path in paths]


def lever_confs(lever: str) -> tuple[str, dict[str, dict]]:
    """the preset and `--conf` overrides a lever's row runs with (the default row's for none)."""
    if not lever:
        return "default", {}
    _, preset, extra = LEVERS[lever]
    confs: dict[str, dict] = {}
    for option, value in zip(extra[::2], extra[1::2], strict=True):
        if option == "--conf":
            key, text = value.split("=", 1)
            kind, name = key.split(".", 1)
            confs.setdefault(kind, {})[name] = yaml.safe_load(text)
    return preset, confs


def _frames(sequence: str, data_root: str) -> int:
    folder, seq = sequence.split("/")
    return len(list((Path(data_root) / folder / "sequences" / seq / "velodyne").glob("*.bin")))


def val_loss(weights: Path, preset: str, confs: dict[str, dict], data_root: str) -> dict[str, float]:
    """the matcher's loss terms (L_P, the matching loss; chance is 2 ln 2048 = 15.2) of `weights` averaged over the
    val frames at protocol seed 0: a continuous signal where Acc. and the true-matches median are 0."""
    terms = [t for _, t in frame_losses(weights, preset, confs, data_root)]
    return {f"val_{k}": round(sum(t[k] for t in terms) / len(terms), 2) for k in ("P", "fov")}


def frame_losses(
    weights: Path,
    preset: str,
    confs: dict[str, dict],
    data_root: str,
    split: str = "val",
    fold: str | None = None,
    split_file: str | None = None,
) -> list[tuple[str, dict[str, float]]]:
    """(frame id, the matcher's loss terms) of `weights` on each frame of a kitti-drives split (of fold K/N when
    `fold` is given), protocol seed 0, through the pipeline as `run` takes it."""
    import torch

    from i2pbench.data.kitti_drives import KittiDrives
    from i2pbench.registry.build import default_registry
    from i2pbench.runs.jobs import prepare
    from i2pbench.scoring.protocol import Protocol
    from i2pbench.stages.pipeline import Combination

    torch.set_num_threads(1)  # one process per checkpoint, side by side
    registry = default_registry()
    (row,) = registry.preset_rows(preset)
    names = {k: v for k, v in row.items() if k not in ("confs", "variant")}
    merged = {kind: {**row["confs"].get(kind, {}), **confs.get(kind, {})} for kind in {*row["confs"], *confs}}
    (job,) = prepare(registry, [Combination(names, merged, row["variant"])], str(weights))
    conf = {"root": data_root, **({"fold": fold} if fold else {}), **({"split_file": split_file} if split_file else {})}
    dataset = KittiDrives(split, conf)
    protocol, out = Protocol(), []
    with torch.no_grad():
        for frame_id in dataset.frame_ids():
            frame = protocol.apply(dataset.load(frame_id))
            stages = {r.kind: r.output for r in job.pipeline.run(frame).records}
            matcher = job.pipeline.stages["matcher"]
            out.append(
                (frame_id, matcher.loss(frame, stages["extractor2d"], stages["extractor3d"], stages["exchanger"])[1])
            )
    return out


PANELS = (  # column, axis label, the target or a reference line, its name
    ("acc_true_pct", "Acc. with >= 4 true matches (%)", 30, "target"),
    ("true_matches_median", "true matches median", 10, "target"),
    ("val_P", "matching loss L_P on the val drives", 2 * math.log(2048), "chance, 2 ln 2048"),
)


def plot(frame: pd.DataFrame, png: Path) -> None:
    """each panel's column against training drives, one line per (arm, steps); the shipped weights dotted."""
    from matplotlib.figure import Figure

    panels = [p for p in PANELS if p[0] in frame]
    fig = Figure(figsize=(4.2 * len(panels), 3.8), dpi=110)
    shipped = frame[frame["drives"] == 0].iloc[0]
    low = frame.loc[frame["drives"] > 0, "steps"].min()
    curve = frame[frame["arm"].isin(ARMS) & (frame["lever"] == "")]
    ticks = sorted(curve["drives"].unique())
    for ax, (key, label, line, line_name) in zip(fig.subplots(1, len(panels)), panels, strict=True):
        for arm, colour, marker in zip(ARMS, ("C0", "C1"), "os", strict=True):
            for steps, rows in curve[curve["arm"] == arm].groupby("steps"):
                name = f"{'synthetic pretraining' if arm == 'synthetic' else 'from scratch'}, {steps} steps"
                style = {"color": colour, "marker": marker, "linestyle": "-" if steps == low else "--"}
                ax.plot(rows["drives"], rows[key], label=name, **style)
        ax.axhline(float(shipped[key]), color="grey", linestyle=":", label="shipped (synthetic only)")
        ax.axhline(line, color="red", linestyle="--", linewidth=0.8)
        ax.annotate(line_name, (ticks[0], line), fontsize=7, color="red", va="bottom")
        ax.set_xscale("log")
        ax.set_xticks(ticks, [str(d) for d in ticks])
        ax.set_xlabel("training drives (train list, in order)")
        ax.set_ylabel(label)
    fig.axes[0].legend(fontsize=7, loc="center left")
    fig.suptitle("EdgeRegNet CPU size, validated on 5 held-out drives (8 frames), protocol seed 0", fontsize=9)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png)


def drive_counts(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", type=Path, required=True, help="checkpoints, logs, caches, boards: outside the repo")
    p.add_argument("--data-root", default="../shared/data")
    p.add_argument("--drives", type=drive_counts, default=[13, 1, 3, 10], help="drive counts to train ('' for none)")
    p.add_argument("--levers", type=lambda s: [x for x in s.split(",") if x], default=[], help=", ".join(LEVERS))
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--lr", type=float, default=1e-4)
    p.add_argument("--jobs", type=int, default=2, help="runs trained side by side, one thread each")
    p.add_argument("--table-only", action="store_true", help="only collect the boards already made under --work")
    p.add_argument("--val-loss", action="store_true", help="also each checkpoint's loss terms on the val frames")
    p.add_argument("--also", type=Path, nargs="*", default=[], help="other --work folders to tabulate (more steps)")
    p.add_argument("--csv", type=Path)
    p.add_argument("--md", type=Path)
    p.add_argument("--png", type=Path)
    args = p.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    if not args.table_only:
        subprocess.run(eval_argv(SHIPPED, board("shipped", args.work), args), check=True)
        with ThreadPoolExecutor(args.jobs) as pool:
            list(pool.map(lambda task: train_and_measure(*task[:3], args, *task[3:]), tasks(args)))
    result = pd.concat([table(work, args) for work in [args.work, *args.also]], ignore_index=True)
    result = result.drop_duplicates(["arm", "lever", "drives", "steps"])  # the shipped row once
    write_table(result, args, plot)
    return 0


def write_table(result: pd.DataFrame, args: Namespace, draw: Callable[[pd.DataFrame, Path], None]) -> None:
    """print the table as Markdown, and write it where --csv, --md and --png ask (the plot by `draw`)."""
    text = to_markdown(result, list(result.columns))
    print(text)
    for path in (args.csv, args.md, args.png):
        if path:
            path.parent.mkdir(parents=True, exist_ok=True)
    if args.csv:
        result.to_csv(args.csv, index=False)
    if args.md:
        args.md.write_text(text + "\n", encoding="utf-8")
    if args.png:
        draw(result, args.png)


if __name__ == "__main__":
    sys.exit(main())
