"""The `i2pbench` command line: each subcommand lives in its own module under `i2pbench.commands`.

Start-up time matters for a command line: only the invoked command's module is imported and its options built; the
others appear in `--help` by their summary (pip keeps its commands the same way), so `i2pbench plugins` never pays
for the pandas that `compare` imports to describe its options. See docs/performance.md.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import sys
from collections.abc import Collection, Sequence
from typing import NoReturn

from . import __version__
from .errors import I2PBenchError, os_problem

COMMANDS = (
    "plugins",
    "run",
    "train",
    "diagnose",
    "domain-gap",
    "data",
    "compare",
    "table",
    "evaluate",
    "score",
    "viz",
    "report",
    "weights",
)
PIPELINE_COMMANDS = ("run", "train", "viz")  # those that build pipelines, which read the stage time limit
# each command's one-line help, shown without importing its module (a command left out is imported to build --help);
# tests/test_cli_startup.py checks they equal the modules' own
SUMMARIES = {
    "plugins": "list installed plugins and the components they register",
    "run": "run combinations of stages over a dataset split and print the leaderboard",
    "train": "train a combination's learned stages on a dataset split",
    "diagnose": "share of 3D edge points within eps_c of a 2D edge pixel, per extractor pair",
    "domain-gap": "edge, LiDAR and image statistics of two datasets side by side",
    "data": "dataset utilities",
    "compare": "compare a new leaderboard with a baseline under per-metric tolerances (exit 1 on a regression)",
    "table": "a preset's rows across several datasets' leaderboards, as a paper's table",
    "evaluate": "recompute metrics and the leaderboard from a runs directory, no stage run",
    "score": "score another code base's per-frame predictions under protocol cards' rules",
    "viz": "draw one frame's LiDAR points under the initial, ground-truth and predicted poses",
    "report": "write a self-contained HTML report of a runs directory (e.g. runs/kitti-all)",
    "weights": "import another code base's checkpoint as an i2pbench checkpoint",
}


def command_module(name: str) -> str:
    """A command's module: `domain-gap` lives in i2pbench.commands.domain_gap (a module name has no hyphen)."""
    return f"i2pbench.commands.{name.replace('-', '_')}"


class ArgumentParser(argparse.ArgumentParser):
    """Usage errors end in the same `i2pbench: error:` line as every other error (subcommands inherit the class)."""

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        self.exit(2, f"i2pbench: error: {message}\n")


def build_parser(full: Collection[str] = COMMANDS) -> argparse.ArgumentParser:
    """The command line; commands outside `full` get only their name and summary (their options are not built)."""
    parser = ArgumentParser(prog="i2pbench", description="Benchmark image-to-LiDAR registration.")
    parser.add_argument("--version", action="version", version=f"i2pbench {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        if name in full or name not in SUMMARIES:
            importlib.import_module(command_module(name)).add_parser(sub)
        else:
            sub.add_parser(name, help=SUMMARIES[name])
    return parser


def invoked(argv: Sequence[str]) -> tuple[str, ...]:
    """The command `argv` names (the top level takes no option with a value), or none for `--help` and typos."""
    first = next((arg for arg in argv if not arg.startswith("-")), None)
    return (first,) if first in COMMANDS else ()


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command. As the program (`argv` None: read sys.argv), freeze the garbage collector when done: the
    collections during interpreter shutdown then skip the objects torch and pandas made, which took 0.5-1 s here only
    to free memory the process hands back anyway. atexit handlers and refcount finalizers still run; only garbage in
    reference cycles goes unfinalized, and commands close their files with `with`. In-process callers (tests) pass
    `argv` and keep a normal collector."""
    if argv is None:  # the program, not a caller that owns its process's signals
        from .execution.interrupts import stop_on_sigterm

        stop_on_sigterm()
    try:
        return _run(sys.argv[1:] if argv is None else argv)
    finally:
        if argv is None:
            gc.freeze()


def _run(argv: Sequence[str]) -> int:
    args = build_parser(full=invoked(argv)).parse_args(argv)
    if getattr(args, "quiet", False):  # reaches progress bars deep in library code and worker processes
        from .execution.progress import set_quiet

        set_quiet(True)
    try:
        if args.command in PIPELINE_COMMANDS:
            from .execution.timeout import check_env

            check_env()
        return importlib.import_module(command_module(args.command)).run(args)
    except I2PBenchError as exc:
        print(f"i2pbench: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # the machine's, not a bug (an unwritable HOME or folder, a full disk): the path at fault
        print(f"i2pbench: error: {os_problem(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM outside a run's frames (`run` reports what finished): no traceback
        from .execution.interrupts import stopped_by

        what, status = stopped_by()
        print(f"i2pbench: interrupted ({what})", file=sys.stderr)
        return status


if __name__ == "__main__":
    sys.exit(main())
