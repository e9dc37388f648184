"""`i2pbench run`: run combinations of stages over a dataset split and write the leaderboard."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

STAGE_OPTIONS = {
    "extractor2d": ("--extractor", "--extractor2d"),
    "extractor3d": ("--extractor3d",),
    "encoder2d": ("--encoder2d",),
    "encoder3d": ("--encoder3d",),
    "exchanger": ("--exchanger",),
    "matcher": ("--matcher",),
    "solver": ("--solver",),
}


def _split_list(value: str) -> list[str]:
    return [v.strip() for v in value.split(",") if v.strip()]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run combinations of stages over a dataset split and print the leaderboard")
    for kind, flags in STAGE_OPTIONS.items():
        p.add_argument(*flags, dest=kind, type=_split_list, help=f"{kind} name(s), comma-separated; 'none' skips")
    p.add_argument("--preset", help="a registered list of combinations (e.g. edge-ablation)")
    p.add_argument("--grid", help="YAML grid file: base: {kind: name}, grid: {kind: [names]}")
    p.add_argument("--conf", action="append", default=[], metavar="KIND.KEY=VALUE", help="component config override")
    add_data_options(p)
    p.add_argument(
        "--weights", default="auto", help="'auto' (shipped checkpoint fitting the stages), 'untrained', or a path"
    )
    p.add_argument("--seed", type=int, default=0, help="protocol seed for the random transforms")
    p.add_argument("--runs-dir", default="runs", help="where per-frame results are cached")
    p.add_argument("--out", help="leaderboard file stem (default leaderboards/<dataset>-<split>)")
    p.add_argument("--overwrite", action="store_true", help="recompute frames already in the cache")
    p.add_argument("--threads", type=int, default=None, help="torch threads (recorded with the results)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def add_data_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dataset", default="synthetic", help="dataset name (kitti, nuscenes, synthetic, ...)")
    p.add_argument("--split", default="test")
    p.add_argument("--data-root", help="dataset root directory (else I2PBENCH_<NAME>_ROOT)")
    p.add_argument("--frames", type=int, default=None, help="use only the first N frames of the split")


def open_dataset(registry, args: argparse.Namespace):
    conf = {"root": args.data_root} if args.data_root else {}
    return registry.dataset(args.dataset)(args.split, conf)


def _combinations(registry, args: argparse.Namespace):
    from ..grid import base_combinations, expand, load_grid_file, parse_conf_overrides

    choices = {kind: getattr(args, kind) for kind in STAGE_OPTIONS if getattr(args, kind)}
    bases = base_combinations(registry, args.preset)
    if args.grid:
        grid_bases, grid = load_grid_file(args.grid)
        bases = [{**b, **g} for b in bases for g in grid_bases]
        choices = {**grid, **choices}
    return expand(bases, choices, parse_conf_overrides(args.conf))


def run(args: argparse.Namespace) -> int:
    import torch
    from tqdm import tqdm

    from .. import leaderboard
    from ..plugins import default_registry
    from ..protocol import Protocol
    from ..runs.environment import environment
    from ..runs.runner import run_grid
    from ..runs.store import ResultsStore

    if args.threads:
        torch.set_num_threads(args.threads)
    registry = default_registry()
    combinations = _combinations(registry, args)
    dataset = open_dataset(registry, args)
    frame_ids = dataset.frame_ids()[: args.frames]
    protocol = Protocol(seed=args.seed)
    store = ResultsStore(Path(args.runs_dir) / f"{dataset.name}-{dataset.split}")
    store.write_meta(
        {
            "protocol": protocol.card(),
            "dataset": dataset.identity(),
            "environment": environment(),
            "combinations": [c.describe() for c in combinations],
        }
    )
    bar = tqdm(total=len(frame_ids) * len(combinations), disable=args.quiet, unit="frame", file=sys.stderr)
    records = run_grid(
        registry,
        combinations,
        dataset,
        protocol,
        store,
        weights=args.weights,
        frame_ids=frame_ids,
        overwrite=args.overwrite,
        progress=bar.update,
    )
    bar.close()
    board = leaderboard.build(records, protocol)
    out = args.out or f"leaderboards/{dataset.name}-{dataset.split}"
    paths = leaderboard.write(board, out)
    print(leaderboard.to_markdown(board))
    print(f"\nwritten: {', '.join(str(p) for p in paths)}; per-frame results in {store.root}", file=sys.stderr)
    return 0
