"""The `i2pbench` command line: each subcommand lives in its own module under `i2pbench.commands`."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from .errors import I2PBenchError
from .progress import set_quiet

COMMANDS = ("plugins", "run", "train", "diagnose", "data", "compare", "viz", "report")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="i2pbench", description="Benchmark image-to-LiDAR registration.")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        importlib.import_module(f"i2pbench.commands.{name}").add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    set_quiet(getattr(args, "quiet", False))  # reaches progress bars deep in library code and worker processes
    try:
        return importlib.import_module(f"i2pbench.commands.{args.command}").run(args)
    except I2PBenchError as exc:
        print(f"i2pbench: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
