"""Per-call time limits for pipeline stages, so a hanging third-party component fails one frame, not the whole run.

A Python thread cannot be killed, so a stage that overruns is *abandoned*: the caller stops waiting, the stage is
recorded as failed, and its thread is left to finish (or hang) in the background as a daemon, which never keeps the
process alive at exit. The next call gets a fresh worker thread. An abandoned call may still hold the component
(and CPU) until it returns; that is the price of staying in-process, and a hang is rare enough to pay it.

The limit comes from `Pipeline(timeout_s=...)`, else the environment variable I2PBENCH_STAGE_TIMEOUT_S (seconds, or
"none" to disable), else DEFAULT_TIMEOUT_S. With no limit a stage runs in the caller's thread, exactly as without
this module.

A stage that holds the GIL (a long C call that does not release it) keeps the waiting caller asleep until it returns, so
this limit cannot fire on it; `i2pbench.execution.isolation` runs stages in a child process that can be killed instead.
"""

from __future__ import annotations

import os
import queue
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

DEFAULT_TIMEOUT_S = 300.0
ENV_VAR = "I2PBENCH_STAGE_TIMEOUT_S"
WAKE_S = 0.2  # how often the caller wakes while a stage runs, to take a Ctrl-C (see _wait)


class StageTimeout(Exception):
    """A stage ran past its time limit and was abandoned (or, isolated in a process, killed)."""

    def __init__(self, seconds: float, fate: str = "abandoned; its thread may still run in the background") -> None:
        super().__init__(f"timed out after {seconds:g} s ({fate})")
        self.seconds = seconds


def check_env() -> None:
    """Read I2PBENCH_STAGE_TIMEOUT_S once, up front (the CLI and `i2pbench.run`): a bad value found deep in a
    pipeline would be a traceback."""
    import math

    from ..errors import I2PBenchError

    try:
        limit = timeout_from_env()
    except ValueError as exc:
        raise I2PBenchError(str(exc)) from None
    if limit is not None and not 0 < limit < math.inf:
        raise I2PBenchError(f"{ENV_VAR}={limit:g}: expected a positive number of seconds, or 'none'")


def timeout_from_env(default: float | None = DEFAULT_TIMEOUT_S) -> float | None:
    """The limit set by I2PBENCH_STAGE_TIMEOUT_S ("none", "off" or "0" disable it), else `default`."""
    value = os.environ.get(ENV_VAR, "").strip().lower()
    if not value:
        return default
    if value in ("none", "off", "0"):
        return None
    try:
        return float(value)
    except ValueError as exc:
        raise ValueError(f"{ENV_VAR}={value!r}: expected seconds or 'none'") from exc


class _Task:
    """One call handed to the worker, and its outcome."""

    def __init__(self, fn: Callable[[], Any]) -> None:
        self.fn = fn
        self.done = threading.Event()
        self.value: Any = None
        self.error: BaseException | None = None
        # torch's grad and inference modes are thread-local: the worker must run under the caller's. Without torch
        # loaded no stage has set a mode (a pipeline of classic stages never imports it), so there is none to share.
        torch = sys.modules.get("torch")
        self.modes = None if torch is None else (torch.is_inference_mode_enabled(), torch.is_grad_enabled())

    def run(self) -> None:
        try:
            self.value = self._call()
        except BaseException as exc:  # handed back to the caller, who decides what it means
            self.error = exc
        finally:
            self.done.set()

    def _call(self) -> Any:
        if self.modes is None:
            return self.fn()
        torch = sys.modules["torch"]
        inference, grad = self.modes
        with torch.inference_mode(inference), torch.set_grad_enabled(grad):
            return self.fn()


class TimeLimiter:
    """Runs calls in one reusable daemon worker thread and waits at most `timeout_s` for each.

    The worker belongs to the process that started it: a forked or unpickled copy (a pipeline sent to a process
    pool) starts its own on first use rather than queueing work for a thread that does not exist there.
    """

    def __init__(self, timeout_s: float | None) -> None:
        if timeout_s is not None and timeout_s <= 0:
            raise ValueError(f"timeout_s must be positive or None, got {timeout_s}")
        self.timeout_s = timeout_s
        self._tasks: queue.SimpleQueue[_Task | None] | None = None
        self._pid = 0  # the process the worker runs in

    def __getstate__(self) -> dict[str, Any]:
        return {"timeout_s": self.timeout_s, "_tasks": None, "_pid": 0}

    def call(self, fn: Callable[[], Any]) -> Any:
        """fn() within the limit; raises StageTimeout when it overruns, or whatever fn raised."""
        if self.timeout_s is None:
            return fn()
        task = _Task(fn)
        self._worker().put(task)
        try:
            finished = _wait(task.done, self.timeout_s)
        except BaseException:  # a Ctrl-C while waiting: the worker is still busy with fn, so no later call may queue
            self._retire()
            raise
        if not finished:
            self._retire()
            raise StageTimeout(self.timeout_s)
        if task.error is not None:
            raise task.error
        return task.value

    def _retire(self) -> None:
        """Leave the busy worker behind; it exits once the abandoned call returns, and the next call starts another."""
        if self._tasks is not None:
            self._tasks.put(None)
        self._tasks = None

    def _worker(self) -> queue.SimpleQueue[_Task | None]:
        if self._tasks is None or self._pid != os.getpid():
            tasks: queue.SimpleQueue[_Task | None] = queue.SimpleQueue()
            threading.Thread(target=_serve, args=(tasks,), name="i2pbench-stage", daemon=True).start()
            self._tasks, self._pid = tasks, os.getpid()
        return self._tasks


def _wait(done: threading.Event, timeout_s: float) -> bool:
    """done.wait(timeout_s) in short slices: a SIGINT the kernel hands to the stage's thread only sets Python's flag,
    and the main thread runs the handler (KeyboardInterrupt) when it next wakes, so one long wait held Ctrl-C until the
    stage's time limit."""
    deadline = time.monotonic() + timeout_s
    while (remaining := deadline - time.monotonic()) > 0:
        if done.wait(min(remaining, WAKE_S)):
            return True
    return done.is_set()


def _serve(tasks: queue.SimpleQueue[_Task | None]) -> None:
    while (task := tasks.get()) is not None:
        task.run()
