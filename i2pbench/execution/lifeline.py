"""Making a child process exit when its parent dies, so a killed run leaves no worker behind.

A process-pool worker waits on a task queue whose write end it holds itself, so the parent's death never wakes it:
a SIGKILLed driver left its workers (hundreds of MB each, model weights included) alive for good. On Linux the
kernel kills the child when the parent dies (prctl PR_SET_PDEATHSIG). There "parent" means the thread that started
the child: the main thread for pool workers; an isolated child (`i2pbench.execution.isolation`) started by a thread that
ends is restarted when next needed. Elsewhere a daemon thread polls os.getppid(), which changes when the child is
re-parented.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time

PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>
POLL_S = 1.0


def exit_with_parent(poll_s: float = POLL_S) -> None:
    """Arm this process to die with its parent (the multiprocessing parent, else the current one)."""
    parent = multiprocessing.parent_process()
    parent_pid = parent.pid if parent is not None and parent.pid else os.getppid()
    if not _arm_pdeathsig():
        threading.Thread(target=_watch, args=(parent_pid, poll_s), name="i2pbench-lifeline", daemon=True).start()
    if os.getppid() != parent_pid:  # the parent died before the signal was armed
        os._exit(1)


def _arm_pdeathsig() -> bool:
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _watch(parent_pid: int, poll_s: float) -> None:
    while os.getppid() == parent_pid:
        time.sleep(poll_s)
    os._exit(1)
