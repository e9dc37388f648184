"""`i2pbench table --preset P DATASET=BOARD ...`: one preset's rows across several datasets' leaderboards, laid out
as a paper's comparison table (methods down, a column group per dataset), e.g. the seed's Table I from a KITTI and
a nuScenes leaderboard of `--preset paper-table-1`."""

from __future__ import annotations

import argparse
import sys


def _board_spec(value: str) -> tuple[str, str]:
    name, sep, path = value.partition("=")
    if not sep or not name or not path:
        raise argparse.ArgumentTypeError(f"{value!r}: expected DATASET=PATH (e.g. KITTI=leaderboards/kitti.csv)")
    return name, path


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("table", help="a preset's rows across several datasets' leaderboards, as a paper's table")
    p.add_argument(
        "boards",
        nargs="+",
        type=_board_spec,
        metavar="DATASET=BOARD",
        help="a column group's name and its leaderboard (.csv or .parquet), in column order",
    )
    p.add_argument("--preset", required=True, help="the preset whose rows the table shows, in its order")
    p.add_argument("--out", help="write OUT.csv and OUT.md as well")


def run(args: argparse.Namespace) -> int:
    from ..boards import paper_table
    from ..boards.out_stem import board_stem
    from ..boards.regression_gate import read_board
    from ..errors import I2PBenchError, os_problem
    from ..registry.build import default_registry
    from ..runs.board_env import board_warnings

    args.out = board_stem(args.out, (".csv", ".md"))  # a device, pipe or folder refused before any board is read
    names = [name for name, _ in args.boards]
    if len(set(names)) != len(names):
        raise I2PBenchError(f"table: a column group's name is given twice ({', '.join(names)})")
    boards = {name: read_board(path, f"leaderboard of {name}") for name, path in args.boards}
    for line in board_warnings({name: (path, boards[name]) for name, path in args.boards}):  # as compare warns
        print(f"i2pbench: warning: {line}", file=sys.stderr)
    rows = paper_table.preset_rows(default_registry(), args.preset)
    table = paper_table.build(rows, boards)
    text = paper_table.to_text(table, rows, dict(args.boards))
    print(text)
    if args.out:
        try:
            written = paper_table.write(table, text, args.out)
        except OSError as exc:
            raise I2PBenchError(
                f"--out {args.out}: could not write the table, printed above: {os_problem(exc)}"
            ) from None
        print("written: " + ", ".join(map(str, written)))
    return 0
