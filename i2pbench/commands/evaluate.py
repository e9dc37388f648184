"""`i2pbench evaluate RUN_DIR`: recompute metrics and the leaderboard from stored results, other thresholds allowed."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .results import EvaluateResult

THRESHOLDS = {  # option -> (protocol card field, metavar, what it sets)
    "--acc-rre": ("acc_rre_deg", "DEG", "success needs RRE below this"),
    "--acc-rte": ("acc_rte_m", "M", "success needs RTE below this"),
    "--filter-rre": ("filter_rre_deg", "DEG", "mean and std use frames with RRE below this"),
    "--filter-rte": ("filter_rte_m", "M", "mean and std use frames with RTE below this"),
}


def positive_float(value: str) -> float:
    try:
        number = float(value)
    except ValueError:
        number = float("nan")
    if not number > 0:
        raise argparse.ArgumentTypeError(f"{value!r} is not a positive number")
    return number


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate", help="recompute metrics and the leaderboard from a runs directory, no stage run")
    p.add_argument("run_dir", metavar="RUN_DIR", help="per-frame results of `i2pbench run` (runs/<dataset>-<split>)")
    p.add_argument("--invocation", default="last", help="whose grid: an invocation id (or its start, see "
                   "RUN_DIR/invocations), 'last' (default), or 'all' the records in the store")  # fmt: skip
    for option, (field, metavar, what) in THRESHOLDS.items():
        p.add_argument(option, dest=field, type=positive_float, metavar=metavar, help=f"{what} (default: the run's)")
    p.add_argument("--rules", metavar="NAMES", help="score the run under these protocol cards' rules instead, one "
                   "table (comma-separated names, or all; docs/protocol.md)")  # fmt: skip
    p.add_argument("--rules-only", action="store_true", help="with --rules: score cards whose inputs differ from "
                   "the run's by their rules alone instead of listing them as needing a rerun")  # fmt: skip
    p.add_argument("--by-sequence", action="store_true", help="also print each row's Acc. and error percentiles "
                   "per sequence (KITTI sequence or drive, nuScenes scene)")  # fmt: skip
    p.add_argument("--out", help="also write the leaderboard to STEM.csv, STEM.md and STEM.parquet (with --rules: "
                   "the table to STEM.csv and STEM.md)")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    execute(args)
    return 0


def execute(args: argparse.Namespace) -> EvaluateResult:
    """The evaluation `args` describe (the CLI's and `i2pbench.evaluate`'s one path); tables go to stdout only for
    the CLI (`echo`)."""
    from ..boards import leaderboard
    from ..boards.out_stem import board_stem
    from ..errors import I2PBenchError
    from ..runs import board_env
    from ..runs.evaluate import evaluate
    from .results import EvaluateResult

    echo = getattr(args, "echo", True)
    args.out = board_stem(args.out)  # as run's: a device or folder refused, board.csv read as the stem board
    thresholds = {field: getattr(args, field) for field, *_ in THRESHOLDS.values()}
    if args.rules or args.rules_only:
        from .evaluate_rules import run_rules

        return run_rules(args, thresholds, echo)
    result = evaluate(args.run_dir, args.invocation, **thresholds)
    if echo:
        print(leaderboard.to_markdown(result.board))
    table = None
    if args.by_sequence:
        from ..scoring.installed import rescored
        from ..scoring.recall import by_sequence

        table = by_sequence(rescored(result.records, result.protocol), result.protocol)
        if echo:
            print("\n" + leaderboard.to_markdown(table, list(table.columns)))
    p = result.protocol
    grid = "" if result.expected is None else f" of the grid's {result.expected}"
    note = (
        f"{len(result.records)} per-frame records{grid}; success: RRE < {p.acc_rre_deg:g}° and RTE < "
        f"{p.acc_rte_m:g} m; mean ± std over RRE < {p.filter_rre_deg:g}° and RTE < {p.filter_rte_m:g} m"
    )
    if echo:
        print(f"\n{note}", file=sys.stderr)
    paths = []
    if args.out:
        try:
            paths = leaderboard.write(result.board, Path(args.out))
            paths.append(board_env.write(Path(args.out), args.run_dir, result.records))
        except OSError as exc:
            raise I2PBenchError(f"--out {args.out}: could not write the leaderboard ({exc.strerror or exc})") from None
        if echo:
            print(f"written: {', '.join(str(path) for path in paths)}", file=sys.stderr)
    return EvaluateResult(result.board, result.records, Path(args.run_dir), paths, [note], table)
