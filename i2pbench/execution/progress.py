"""Progress bars for long operations (data synthesis, runs, training), silenced by `--quiet` or I2PBENCH_QUIET=1.

Library code that may run deep inside a command (e.g. a dataset generating itself on first use) cannot see the
command's flags, so `--quiet` is passed down through the environment, which worker processes inherit too.

On a terminal the bar redraws in place; written to a file or a CI log, where every redraw would stay as text, it
becomes a plain line at most every LOG_INTERVAL seconds and one at the end.
"""

from __future__ import annotations

import os
import sys
from typing import IO, Any

from tqdm import tqdm

ENV_VAR = "I2PBENCH_QUIET"
LOG_INTERVAL = 10.0  # seconds between progress lines in a log


def quiet() -> bool:
    return os.environ.get(ENV_VAR, "") not in ("", "0")


def set_quiet(value: bool) -> None:
    if value:
        os.environ[ENV_VAR] = "1"


def note(text: str) -> None:
    """a line about what was done (`written: ...`) on stderr, left out under --quiet."""
    if not quiet():
        print(text, file=sys.stderr)


class LogLines:
    """A stream for tqdm that writes each redraw as its own line (no carriage returns, no padding)."""

    def __init__(self, stream: IO[str]) -> None:
        self.stream = stream

    def write(self, text: str) -> None:
        line = text.replace("\r", "").rstrip()
        if line:
            self.stream.write(line + "\n")

    def flush(self) -> None:
        self.stream.flush()


def bar(
    total: int,
    desc: str = "",
    unit: str = "frame",
    initial: int = 0,
    disable: bool | None = None,
    stream: IO[str] | None = None,
) -> tqdm:
    """A bar on `stream` (stderr): redrawn in place on a terminal, a line per LOG_INTERVAL elsewhere; off when quiet."""
    stream = stream or sys.stderr
    options: dict[str, Any] = {"dynamic_ncols": True}
    if not _is_terminal(stream):
        options = {"mininterval": LOG_INTERVAL}
        stream = LogLines(stream)
    off = quiet() if disable is None else disable
    return tqdm(total=total, desc=desc, unit=unit, initial=initial, disable=off, file=stream, **options)


def _is_terminal(stream: IO[str]) -> bool:
    isatty = getattr(stream, "isatty", None)
    return bool(isatty and isatty())
