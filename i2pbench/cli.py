"""The `i2pbench` command line: each subcommand lives in its own module under `i2pbench.commands`."""

from __future__ import annotations

import argparse
import importlib
import math
import sys
from collections.abc import Sequence
from typing import NoReturn

from .errors import I2PBenchError
from .progress import set_quiet

COMMANDS = ("plugins", "run", "train", "diagnose", "domain-gap", "data", "compare", "evaluate", "viz", "report")
PIPELINE_COMMANDS = ("run", "train", "viz")  # those that build pipelines, which read the stage time limit


def command_module(name: str) -> str:
    """A command's module: `domain-gap` lives in i2pbench.commands.domain_gap (a module name has no hyphen)."""
    return f"i2pbench.commands.{name.replace('-', '_')}"


class ArgumentParser(argparse.ArgumentParser):
    """Usage errors end in the same `i2pbench: error:` line as every other error (subcommands inherit the class)."""

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        self.exit(2, f"i2pbench: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="i2pbench", description="Benchmark image-to-LiDAR registration.")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        importlib.import_module(command_module(name)).add_parser(sub)
    return parser


def check_stage_timeout() -> None:
    """Read I2PBENCH_STAGE_TIMEOUT_S once, up front: a bad value found deep in a pipeline would be a traceback."""
    from .timeout import ENV_VAR, timeout_from_env

    try:
        limit = timeout_from_env()
    except ValueError as exc:
        raise I2PBenchError(str(exc)) from None
    if limit is not None and not 0 < limit < math.inf:
        raise I2PBenchError(f"{ENV_VAR}={limit:g}: expected a positive number of seconds, or 'none'")


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    set_quiet(getattr(args, "quiet", False))  # reaches progress bars deep in library code and worker processes
    try:
        if args.command in PIPELINE_COMMANDS:
            check_stage_timeout()
        return importlib.import_module(command_module(args.command)).run(args)
    except I2PBenchError as exc:
        print(f"i2pbench: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
