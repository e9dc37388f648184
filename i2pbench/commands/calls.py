"""The commands as Python calls: `i2pbench.run(frames=3, matcher="oracle")` is `i2pbench run --frames 3 --matcher
oracle`, through the same option parser and the same code (docs/python.md).

Keyword arguments are the command's option names with `_` for `-` (stage options by kind: `extractor2d`, `matcher`,
...); a list stands for a comma-separated value, True for a flag. Errors are the CLI's exceptions with the CLI's
messages; a malformed option is an `OptionError` carrying argparse's message, never a SystemExit.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import importlib
import os
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, NoReturn

from ..errors import I2PBenchError
from .results import CompareResult, EvaluateResult, RunResult, ScoreResult


class OptionError(I2PBenchError, ValueError):
    """An option value the command line would refuse (its usage error), with the same message."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise OptionError(message)


def run(**options: Any) -> RunResult:
    """`i2pbench run` with `options`: runs the grid (frames already stored are reused) and returns its board and
    records; the board is not printed (progress still shows unless quiet=True)."""
    from ..execution.timeout import check_env

    args = namespace("run", {}, options)
    check_env()
    with _quiet(args.quiet):
        outcome = _module("run").execute(args)
    if isinstance(outcome, int):  # Ctrl-C: the finished frames' board was printed and the invocation marked
        raise KeyboardInterrupt
    return outcome


def evaluate(run_dir: str | Path, **options: Any) -> EvaluateResult:
    """`i2pbench evaluate RUN_DIR`: the leaderboard again from the store (rules="all": under every card's rules)."""
    return _module("evaluate").execute(namespace("evaluate", {"run_dir": run_dir}, options))


def compare(new: str | Path, baseline: str | Path, **options: Any) -> CompareResult:
    """`i2pbench compare NEW BASELINE`: the regression gate's verdict (`.ok`), without raising on a regression."""
    return _module("compare").execute(namespace("compare", {"new": new, "baseline": baseline}, options))


def score(predictions: Any, **options: Any) -> ScoreResult:
    """`i2pbench score PREDICTIONS`: a DataFrame or file of another code base's poses under cards' rules."""
    frame = predictions if not isinstance(predictions, (str, Path)) else None
    args = namespace("score", {"predictions": "-" if frame is not None else predictions}, options)
    return _module("score").execute(args, frame)


def namespace(command: str, positional: Mapping[str, Any], options: Mapping[str, Any]) -> argparse.Namespace:
    """The argparse namespace the command line would give for these arguments, its defaults included; not printed
    to stdout (`echo` False)."""
    parser = _Parser(prog="i2pbench")
    sub = parser.add_subparsers(dest="command", required=True)
    _module(command).add_parser(sub)
    actions = {a.dest: a for a in sub.choices[command]._actions if a.dest != "help"}
    argv = [command, *_positional(actions, positional)]
    for name, value in options.items():
        argv += _option(actions, name, value)
    args = parser.parse_args(argv)
    args.echo = False
    return args


@contextlib.contextmanager
def _quiet(quiet: bool) -> Iterator[None]:
    """quiet=True silences progress for this call only (the CLI's --quiet sets it for the whole process)."""
    from ..execution.progress import ENV_VAR

    before = os.environ.get(ENV_VAR)
    if quiet:
        os.environ[ENV_VAR] = "1"
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(ENV_VAR, None)
        else:
            os.environ[ENV_VAR] = before


def _module(command: str):
    return importlib.import_module(f"i2pbench.commands.{command.replace('-', '_')}")


def _positional(actions: dict[str, argparse.Action], values: Mapping[str, Any]) -> list[str]:
    """Positional arguments in the parser's order ("--" first would not let one start with a dash)."""
    return [str(values[dest]) for dest, action in actions.items() if not action.option_strings and dest in values]


def _option(actions: dict[str, argparse.Action], name: str, value: Any) -> list[str]:
    """One keyword argument as the command line's words (nargs="+" options are not among the commands' options)."""
    action = actions.get(name)
    if action is None or not action.option_strings:
        known = [dest for dest, a in actions.items() if a.option_strings]
        close = difflib.get_close_matches(name, known, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else f"; known: {', '.join(sorted(known))}"
        raise TypeError(f"unexpected keyword argument {name!r}{hint}")
    flag = action.option_strings[-1]
    if value is None or value is False:
        return []
    if action.nargs == 0:
        return [flag]
    if isinstance(action, argparse._AppendAction):
        items = [f"{k}={v}" for k, v in value.items()] if isinstance(value, Mapping) else _items(value)
        return [f"{flag}={item}" for item in items]
    if isinstance(value, (list, tuple)):
        return [f"{flag}={','.join(map(str, value))}"]
    return [f"{flag}={value}"]  # one word: a value starting with a dash stays a value


def _items(value: Any) -> list[Any]:
    return list(value) if isinstance(value, (list, tuple)) else [value]
