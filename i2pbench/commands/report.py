"""`i2pbench report`: one self-contained HTML page for a runs directory (leaderboard, error curves, overlays)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="write a self-contained HTML report of a runs directory (e.g. runs/kitti-all)")
    p.add_argument("run", help="a runs directory: runs/<dataset>-<split>")
    p.add_argument("--out", help="HTML path (default RUN/report.html)")
    p.add_argument(
        "--overlays",
        type=int,
        default=4,
        help="best and worst frame overlays for this many combinations, top of the leaderboard (0: none)",
    )
    p.add_argument("--data-root", help="where the dataset lies now, if not where the run recorded it")
    p.add_argument("--quiet", action="store_true", help="no progress bar, no `written:` line (errors still show)")


def run(args: argparse.Namespace) -> int:
    from ..errors import I2PBenchError
    from ..execution import progress
    from ..report.html import write_report

    out = Path(args.out or Path(args.run) / "report.html")
    try:
        notes = write_report(Path(args.run), out, overlays=args.overlays, data_root=args.data_root, quiet=args.quiet)
    except OSError as exc:  # most often an unwritable --out folder; the path at fault is named either way
        where = f"report of {args.run} into --out {out}"
        raise I2PBenchError(f"{exc.filename or out}: {exc.strerror or exc} ({where})") from None
    for note in notes:
        print(f"i2pbench: note: {note}", file=sys.stderr)
    progress.note(f"written: {out}")
    return 0
