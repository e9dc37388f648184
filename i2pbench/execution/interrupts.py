"""Telling the user's Ctrl-C from a KeyboardInterrupt that plugin code raised itself.

Both arrive as KeyboardInterrupt, but only the first should stop a run: a plugin raising it (or calling sys.exit) is
a broken stage. So SIGINTs are counted by a handler that otherwise does what Python's default one does (raise
KeyboardInterrupt), and a frame compares the count before and after. Where SIGINT cannot raise KeyboardInterrupt
(outside the main thread, or with SIGINT ignored) every KeyboardInterrupt is the plugin's. Where the application
installed a SIGINT handler of its own, it is left alone and a KeyboardInterrupt stops the run, as it always did.

A run stopped by Ctrl-C prints no traceback: its workers are stopped (the executors terminate their processes and
raise `Interrupted`), every finished frame stays in the store, and `run` says what was kept
(`i2pbench.commands.run_notes.stopped`); the same command then resumes from the store.
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
