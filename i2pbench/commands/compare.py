"""`i2pbench compare NEW BASELINE`: the regression gate; exits 1 when a baseline row regresses or disappears."""

from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction) -> None:
    from ..compare import DEFAULT_TOLERANCE, METRICS

    p = sub.add_parser(
        "compare",
        help="compare a new leaderboard with a baseline under per-metric tolerances (exit 1 on a regression)",
    )
    p.add_argument("new", help="the new leaderboard (.csv or .parquet)")
    p.add_argument("baseline", help="the baseline leaderboard (.csv or .parquet)")
    p.add_argument(
        "--tolerance",
        default=DEFAULT_TOLERANCE,
        help=f"comma-separated METRIC=VALUE: +d/-d absolute slack in the worse direction, xR a ratio (required for "
        f"latency); metrics: {', '.join(METRICS)} (default {DEFAULT_TOLERANCE})",
    )


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .. import leaderboard
    from ..compare import compare, format_report, parse_tolerances
    from ..errors import I2PBenchError

    tolerances = parse_tolerances(args.tolerance)
    boards = []
    for path in (args.new, args.baseline):
        if not Path(path).is_file():
            raise I2PBenchError(f"{path}: no such leaderboard file")
        boards.append(leaderboard.read(path))
    report = compare(boards[0], boards[1], tolerances)
    print(format_report(report))
    return 0 if report.ok else 1
