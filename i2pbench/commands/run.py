"""`i2pbench run`: run combinations of stages over a dataset split and write the leaderboard."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

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
    p.add_argument("--grid", help="YAML grid file: base: {kind: name}, grid: {kind: [names]}, confs: {kind: {k: v}}")
    p.add_argument("--conf", action="append", default=[], metavar="KIND.KEY=VALUE", help="component config override")
    add_data_options(p)
    p.add_argument(
        "--weights", default="auto", help="'auto' (shipped checkpoint fitting the stages), 'untrained', or a path"
    )
    p.add_argument("--device", default="auto", help="where learned stages run: auto (cuda if available), cpu, cuda")
    p.add_argument("--seed", type=int, default=0, help="protocol seed for the random transforms")
    p.add_argument("--runs-dir", default="runs", help="where per-frame results are cached")
    p.add_argument("--out", help="leaderboard file stem (default leaderboards/<dataset>-<split>)")
    p.add_argument("--overwrite", action="store_true", help="recompute frames already in the cache")
    p.add_argument("--threads", type=int, default=None, help="torch and OpenCV threads (default min(4, cores))")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_scale_options(p)


def add_scale_options(p: argparse.ArgumentParser) -> None:
    """Parallel runs (docs/scale-out.md): worker processes here, or actors on a Ray cluster."""
    p.add_argument("--workers", type=int, help="worker processes (local; default 1, serial) or Ray actors (default: "
                   "as many as the cluster's CPUs hold)")  # fmt: skip
    p.add_argument("--executor", choices=("local", "ray"), default="local", help="where workers run")
    p.add_argument("--address", help="Ray cluster address (auto: the one `ray start` began; default: a local Ray)")
    p.add_argument("--threads-per-worker", type=int, default=1, help="torch/OpenCV/BLAS threads in each worker")
    p.add_argument("--chunk-size", type=int, default=8, help="most frames of one combination in one worker task")


def add_data_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dataset", default="synthetic", help="dataset name (kitti, nuscenes, synthetic, ...)")
    p.add_argument("--split", default="test")
    p.add_argument("--data-root", help="dataset root directory (else I2PBENCH_<NAME>_ROOT)")
    p.add_argument(
        "--data-conf",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="dataset config (YAML values; dotted keys nest, e.g. frames.test=3)",
    )
    p.add_argument("--frames", type=int, default=None, help="use only the first N frames of the split")


def parse_data_conf(items: list[str]) -> dict[str, Any]:
    """`["frames.test=3"]` -> {"frames": {"test": 3}}."""
    import yaml

    from ..errors import DataError

    conf: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise DataError(f"--data-conf {item!r}: expected KEY=VALUE")
        *parents, leaf = key.split(".")
        node = conf
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = yaml.safe_load(value)
    return conf


def open_dataset(registry, args: argparse.Namespace):
    conf = parse_data_conf(getattr(args, "data_conf", []))
    if args.data_root:
        conf["root"] = args.data_root
    return registry.dataset(args.dataset)(args.split, conf)


def _combinations(registry, args: argparse.Namespace):
    from ..grid import base_combinations, expand, load_grid_file, parse_conf_overrides

    choices = {kind: getattr(args, kind) for kind in STAGE_OPTIONS if getattr(args, kind)}
    bases = base_combinations(registry, args.preset, stages_named=bool(choices or args.grid))
    confs = parse_conf_overrides(args.conf)
    if args.grid:
        grid = load_grid_file(args.grid)
        choices = {**{k: [v] for k, v in grid.base.items()}, **grid.grid, **choices}
        confs = {k: {**grid.confs.get(k, {}), **confs.get(k, {})} for k in {*grid.confs, *confs}}
    return expand(bases, choices, confs, registry)


def run(args: argparse.Namespace) -> int:
    from .. import leaderboard
    from ..errors import DataError
    from ..plugins import default_registry
    from ..protocol import Protocol
    from ..runs.environment import fix_threads
    from ..runs.invocation import Invocation
    from ..runs.store import ResultsStore
    from ..training import pick_device

    threads = fix_threads(args.threads)
    args.device = str(pick_device(args.device))  # resolved once: "auto" would read differently in the record
    registry = default_registry()
    combinations = _combinations(registry, args)
    dataset = open_dataset(registry, args)
    frame_ids = dataset.frame_ids()[: args.frames]
    if not frame_ids:
        raise DataError(f"dataset {dataset.name!r} split {dataset.split!r} has no frames to run")
    protocol = Protocol(seed=args.seed)
    store = ResultsStore(Path(args.runs_dir) / f"{dataset.name}-{dataset.split}")
    invocation = Invocation(store.root, _meta(args, threads, protocol, dataset, frame_ids, combinations))
    start = time.perf_counter()
    records = _run_grid(registry, combinations, dataset, frame_ids, protocol, store, invocation.id, args)
    board = leaderboard.build(records, protocol)
    invocation.finish(**_summary(records, board, invocation.id, time.perf_counter() - start))
    paths = leaderboard.write(board, args.out or f"leaderboards/{dataset.name}-{dataset.split}")
    print(leaderboard.to_markdown(board))
    print(f"\nwritten: {', '.join(str(p) for p in paths)}; per-frame results in {store.root}", file=sys.stderr)
    return 0


def _meta(args, threads: int, protocol, dataset, frame_ids: list[str], combinations) -> dict[str, Any]:
    """What this invocation depends on, recorded before any frame runs (a killed run keeps it too)."""
    from ..runs.environment import environment

    return {
        "argv": sys.argv,
        "threads": threads,
        "device": args.device,
        "executor": {k: getattr(args, k) for k in ("executor", "workers", "threads_per_worker", "address")},
        "protocol": protocol.card(),
        "dataset": dataset.identity(),
        "frames": frame_ids,
        "environment": environment(),
        "combinations": [c.describe() for c in combinations],
    }


def _summary(records, board, invocation: str, wall_s: float) -> dict[str, Any]:
    from .. import leaderboard

    computed = int((records["invocation"] == invocation).sum())
    return {
        "wall_s": wall_s,
        "computed": computed,
        "reused": len(records) - computed,
        "rows": board[leaderboard.GROUP].to_dict("records"),
    }


def _run_grid(registry, combinations, dataset, frame_ids, protocol, store, invocation: str, args):
    """run_grid with a progress bar (ETA) over every frame of every combination, cached ones included."""
    from tqdm import tqdm

    from ..runs import executors
    from ..runs.runner import run_grid

    total = len(frame_ids) * len(combinations)
    executor = executors.make_executor(args.executor, args.workers, args.threads_per_worker, args.address, args.device)
    with tqdm(total=total, disable=args.quiet, unit="frame", file=sys.stderr, dynamic_ncols=True) as bar:
        if executor is not None:
            return executors.run_grid(
                registry, combinations, dataset, protocol, store, executor, weights=args.weights, frame_ids=frame_ids,
                overwrite=args.overwrite, progress=bar.update, invocation=invocation, chunk_size=args.chunk_size,
            )  # fmt: skip
        return run_grid(
            registry,
            combinations,
            dataset,
            protocol,
            store,
            weights=args.weights,
            device=args.device,
            frame_ids=frame_ids,
            overwrite=args.overwrite,
            progress=bar.update,
            invocation=invocation,
        )
