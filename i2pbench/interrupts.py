"""Telling the user's Ctrl-C from a KeyboardInterrupt that plugin code raised itself.

Both arrive as KeyboardInterrupt, but only the first should stop a run: a plugin raising it (or calling sys.exit) is
a broken stage. So SIGINTs are counted by a handler that otherwise does what Python's default one does (raise
KeyboardInterrupt), and a frame compares the count before and after. Where SIGINT cannot raise KeyboardInterrupt
(outside the main thread, or with SIGINT ignored) every KeyboardInterrupt is the plugin's. Where the application
installed a SIGINT handler of its own, it is left alone and a KeyboardInterrupt stops the run, as it always did.

A run stopped by Ctrl-C (`stopped`) prints no traceback: its workers are stopped (the executors terminate their
processes), every finished frame stays in the store, the invocation is marked, and the board of what finished is
printed with one line saying how much was kept; the same command then resumes from the store.
"""

from __future__ import annotations

import signal
import threading
from types import FrameType
from typing import Any

_count = 0


def watch() -> int | None:
    """Count SIGINTs from now on; returns the count so far, or None when SIGINT is another handler's to count."""
    if threading.current_thread() is not threading.main_thread():
        return _count  # signals raise in the main thread only: the count is never the question here
    current = signal.getsignal(signal.SIGINT)
    if current is signal.default_int_handler:
        signal.signal(signal.SIGINT, _on_sigint)
    elif current is not _on_sigint and callable(current):
        return None
    return _count


def stops_run(exc: BaseException, mark: int | None) -> bool:
    """Whether `exc`, raised during a frame watched from `mark`, is the user's Ctrl-C (or came with one)."""
    return isinstance(exc, KeyboardInterrupt) if mark is None else _count != mark


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    global _count
    _count += 1
    signal.default_int_handler(signum, frame)


class Interrupted(KeyboardInterrupt):
    """The user's Ctrl-C during a grid, carrying the grid's records finished by then (stored ones included)."""

    def __init__(self, records: list[dict[str, Any]]) -> None:
        super().__init__()
        self.records = records


EXIT_STATUS = 130  # 128 + SIGINT, what a shell reports for a process stopped by Ctrl-C


def stopped(exc: KeyboardInterrupt, store: Any, invocation: Any, protocol: Any) -> int:
    """After Ctrl-C in `run`: mark the invocation failed, print the board of the frames that finished (this
    invocation's, and the stored ones the grid in progress reused) and one line saying what was kept."""
    import sys

    import pandas as pd

    from . import leaderboard

    records = _finished(getattr(exc, "records", []), store, invocation.id)
    meta = invocation.meta
    total = len(meta.get("frames", [])) * len(meta.get("combinations", [])) * len(meta.get("protocols", [0]))
    invocation.fail(f"interrupted by Ctrl-C after {len(records)} of {total} frames")
    if len(records):
        print(leaderboard.to_markdown(leaderboard.build(pd.DataFrame(records), protocol)))
    mine = int((records["invocation"] == invocation.id).sum()) if "invocation" in records else 0
    print(
        f"i2pbench: interrupted (Ctrl-C): workers stopped; {len(records)} of {total} frames finished ({mine} computed "
        f"by this run), all kept in {store.frames_dir}; the board above is of those; the same command resumes",
        file=sys.stderr,
    )
    return EXIT_STATUS


def _finished(records: list[dict[str, Any]], store: Any, invocation: str):
    """The grid's finished records, with those this invocation stored that never reached the driver (a worker's
    last frames, an earlier protocol's grid), each (frame, row, protocol) once."""
    import pandas as pd

    from .runs.store import ResultsStore

    stored = ResultsStore(store.root).load()  # opening it sweeps the temp file of a frame a worker was writing
    stored = stored[stored["invocation"] == invocation] if "invocation" in stored else stored.iloc[:0]
    both = pd.concat([pd.DataFrame(records), stored], ignore_index=True)
    if both.empty:
        return both
    keys = [c for c in ("frame_id", "combination", "weights", "protocol") if c in both]
    return both.drop_duplicates(subset=keys).reset_index(drop=True)
