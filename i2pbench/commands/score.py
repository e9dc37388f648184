"""`i2pbench score PREDICTIONS`: another code base's per-frame poses (or the peers' own error files) scored under
protocol cards' rules, written as a board (docs/python.md, "Scoring predictions")."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pandas as pd

    from .results import ScoreResult


def add_parser(sub: argparse._SubParsersAction) -> None:
    from ..scoring.peer_outputs import FORMATS

    p = sub.add_parser("score", help="score another code base's per-frame predictions under protocol cards' rules")
    p.add_argument("predictions", metavar="PREDICTIONS", help="a .csv/.parquet in the documented schema, EdgeRegNet's "
                   "KITTI.xlsx, a CorrI2P result_error_* or CoFiI2P eval folder, or a <name>_t_error.npy")  # fmt: skip
    p.add_argument("--rules", default="all", metavar="NAMES", help="protocol cards to score under (comma-separated "
                   "names, or all; docs/protocol.md)")  # fmt: skip
    p.add_argument("--format", dest="fmt", choices=FORMATS, default="auto", help="how to read PREDICTIONS")
    p.add_argument("--out", help="also write the board to STEM.csv, STEM.md and STEM.parquet")


def run(args: argparse.Namespace) -> int:
    execute(args)
    return 0


def execute(args: argparse.Namespace, frame: pd.DataFrame | None = None) -> ScoreResult:
    """The board (the CLI's and `i2pbench.score`'s one path); `frame`: a table given in Python instead of a file."""
    from ..boards.out_stem import board_stem
    from ..scoring import foreign, peer_outputs, predictions
    from ..scoring.table import chosen, to_markdown
    from .results import ScoreResult

    args.out = board_stem(args.out)
    if frame is not None:
        table = predictions.check(frame, "predictions")
    else:
        table = peer_outputs.read(args.predictions, args.fmt)
    board = foreign.board(table, chosen(args.rules))
    markdown = to_markdown(board)
    if getattr(args, "echo", True):
        print(markdown)
    paths = _write(board, markdown, Path(args.out)) if args.out else []
    if paths and getattr(args, "echo", True):
        print(f"written: {', '.join(map(str, paths))}", file=sys.stderr)
    return ScoreResult(board, table, paths)


def _write(board: pd.DataFrame, markdown: str, stem: Path) -> list[Path]:
    from ..errors import I2PBenchError

    paths = [stem.with_name(f"{stem.name}.{ext}") for ext in ("csv", "md", "parquet")]
    try:
        stem.parent.mkdir(parents=True, exist_ok=True)
        board.to_csv(paths[0], index=False)
        paths[1].write_text(markdown + "\n")
        board.to_parquet(paths[2], index=False)
    except OSError as exc:
        raise I2PBenchError(f"--out {stem}: could not write the board ({exc.strerror or exc})") from None
    return paths
