"""`i2pbench compare NEW BASELINE`: the regression gate; exits 1 when a baseline row regresses or disappears, 2 when
it cannot judge (a table that is missing, empty, header-only or malformed), so CI tells a broken gate from a regression.
It warns on stderr, without failing, when the boards' records (`<stem>.env.json`) name other package or synthetic
generator versions, or are missing or malformed (a record is never read as a regression).
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .results import CompareResult

EXIT_CODES = "exit status: 0 no regression; 1 a baseline row regressed or is missing; 2 the gate could not run (a "
EXIT_CODES += "table missing, empty, header-only, binary, ragged or not a leaderboard; a bad --tolerance)"


def add_parser(sub: argparse._SubParsersAction) -> None:
    from ..boards.regression_gate import DEFAULT_TOLERANCE, METRICS

    p = sub.add_parser(
        "compare",
        help="compare a new leaderboard with a baseline under per-metric tolerances (exit 1 on a regression)",
        epilog=EXIT_CODES,
    )
    p.add_argument("new", help="the new leaderboard (.csv or .parquet)")
    p.add_argument("baseline", help="the baseline leaderboard (.csv or .parquet)")
    p.add_argument(
        "--tolerance",
        default=DEFAULT_TOLERANCE,
        help=f"comma-separated METRIC=VALUE: +d/-d absolute slack in the worse direction, xR a ratio (required for "
        f"latency); metrics: {', '.join(METRICS)} (default {DEFAULT_TOLERANCE})",
    )
    p.add_argument(
        "--alpha",
        type=float,
        help="fail a move beyond tolerance only when a paired test on the same frames (McNemar for acc, a paired "
        "bootstrap for rte/rre) finds it significant at this level, e.g. 0.05; without it every move beyond "
        "tolerance fails (the golden gate: deterministic pipelines on 6 frames; docs/leaderboards.md)",
    )


def run(args: argparse.Namespace) -> int:
    """Errors are I2PBenchErrors, which the CLI prints on one line and turns into exit status 2."""
    return 0 if execute(args).ok else 1


def execute(args: argparse.Namespace) -> CompareResult:
    """The verdict (the CLI's and `i2pbench.compare`'s one path); the report goes to stdout only for the CLI."""
    from ..boards.regression_gate import compare, format_report, parse_tolerances, read_board
    from ..errors import I2PBenchError
    from ..runs.board_env import warnings
    from .results import CompareResult

    tolerances = parse_tolerances(args.tolerance)
    new, base = read_board(args.new, "new leaderboard"), read_board(args.baseline, "baseline")
    if args.alpha is not None and not 0 < args.alpha < 1:
        raise I2PBenchError(f"--alpha {args.alpha:g}: a significance level between 0 and 1, such as 0.05")
    names = (f"new leaderboard {args.new}", f"baseline {args.baseline}")
    report = compare(new, base, tolerances, names=names, alpha=args.alpha)
    for line in warnings((args.new, new), (args.baseline, base)):  # once both are judged leaderboards
        print(f"i2pbench: warning: {line}", file=sys.stderr)
    text = format_report(report)
    if getattr(args, "echo", True):
        print(text)
    return CompareResult(report.ok, text, list(report.findings))
