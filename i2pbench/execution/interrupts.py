"""Telling the user's Ctrl-C from a KeyboardInterrupt that plugin code raised itself.

Both arrive as KeyboardInterrupt, but only the first should stop a run: a plugin raising it (or calling sys.exit) is
a broken stage. So SIGINTs are counted by a handler that otherwise does what Python's default one does (raise
KeyboardInterrupt), and a frame compares the count before and after. Where SIGINT cannot raise KeyboardInterrupt
(outside the main thread, or with SIGINT ignored) every KeyboardInterrupt is the plugin's. Where the application
installed a SIGINT handler of its own, it is left alone and a KeyboardInterrupt stops the run, as it always did.

A run stopped by Ctrl-C prints no traceback: its workers are stopped (the executors terminate their processes and
raise `Interrupted`), every finished frame stays in the store, and `run` says what was kept
(`i2pbench.commands.run_notes.stopped`); the same command then resumes from the store. Worker processes start with
SIGINT held (`sigint_held`, `ignore_held_sigint`), so a Ctrl-C while they import is not a traceback of theirs.
The program takes SIGTERM sent to it as it takes Ctrl-C (`stop_on_sigterm`), exiting with 143 instead of 130.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType
from typing import Any

_count = 0
_last = signal.SIGINT  # the signal that stopped the command last: SIGINT (Ctrl-C) or SIGTERM
NAMES = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM"}


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
    global _count, _last
    _count += 1
    _last = signal.SIGINT
    signal.default_int_handler(signum, frame)


def stop_on_sigterm() -> None:
    """SIGTERM (`kill PID`, a scheduler ending a job) stops the command as Ctrl-C does: raised as KeyboardInterrupt
    in the main thread and counted as the user's, so a run stops its workers, keeps every finished frame and marks
    its invocation, instead of dying mid-write with its invocation "running" and its semaphores leaked. Only where
    SIGTERM still has its default action (the program's, not an application's that embeds i2pbench)."""
    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _on_sigterm)


def _on_sigterm(signum: int, frame: FrameType | None) -> None:
    global _count, _last
    _count += 1
    _last = signal.SIGTERM
    raise KeyboardInterrupt


def stopped_by() -> tuple[str, int]:
    """(what stopped the command, its exit status): ("Ctrl-C", 130) or ("SIGTERM", 143), 128 + the signal's number as
    a shell reports a process the signal ended."""
    return NAMES[_last], 128 + int(_last)


class Interrupted(KeyboardInterrupt):
    """The user's Ctrl-C during a grid, carrying the grid's records finished by then (stored ones included)."""

    def __init__(self, records: list[dict[str, Any]]) -> None:
        super().__init__()
        self.records = records


@contextlib.contextmanager
def sigint_held() -> Iterator[None]:
    """SIGINT blocked in this thread while it starts worker processes. A child inherits the blocked mask (across
    fork and exec), so a Ctrl-C that reaches it while it starts up (the terminal signals the whole process group)
    stays pending until its initializer ignores SIGINT (`ignore_held_sigint`), instead of raising
    KeyboardInterrupt in the middle of its imports with a traceback. Here, a SIGINT handed to this thread meanwhile
    is taken on leaving; one the kernel hands to another thread of this process is raised at once, as before (the
    executor then stops the workers it has started)."""
    if not hasattr(signal, "pthread_sigmask"):  # not on Windows: there a worker takes Ctrl-C as before
        yield
        return
    # multiprocessing's resource tracker, started with the first spawned process, unblocks SIGINT in the starting
    # thread once it runs (CPython's resource_tracker.ensure_running): started first, it leaves the hold alone
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    before = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def ignore_held_sigint() -> None:
    """In a worker started under `sigint_held`: Ctrl-C is the driver's (it stops the run and ends its workers), so
    ignore SIGINT, then unblock it; one that came during start-up is dropped."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
