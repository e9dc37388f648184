"""A Ctrl-C while worker processes start up: held until the worker ignores it, not a traceback of the worker's."""

import multiprocessing
import os
import signal
import threading
import time

import pytest

from i2pbench.execution.interrupts import ignore_held_sigint, sigint_held

pytestmark = pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="POSIX signal masks")


@pytest.fixture(autouse=True)
def sigint_as_at_a_terminal():
    """Python's own SIGINT handler, as at a terminal: a suite started as a background job inherits SIGINT ignored,
    and an ignored signal stays ignored in the processes it starts, which would hide what these tests look at."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


def _start_and_interrupt(held: bool) -> int:
    """the exit code of a spawned process whose entry point is `ignore_held_sigint`, sent SIGINT at once, while its
    interpreter is still starting (a spawn takes tens of milliseconds before any of our code runs there)."""
    process = multiprocessing.get_context("spawn").Process(target=ignore_held_sigint)
    if held:
        with sigint_held():
            process.start()
    else:
        process.start()
    os.kill(process.pid, signal.SIGINT)
    process.join(60)
    return process.exitcode


def test_a_worker_started_with_sigint_held_survives_a_ctrl_c_during_its_start_up():
    assert _start_and_interrupt(held=True) == 0


def test_without_it_the_same_ctrl_c_kills_the_starting_worker():
    # the failure the hold prevents: KeyboardInterrupt inside the worker's imports (exit 1, with a traceback), or the
    # default action before Python's handler is installed (killed by SIGINT, -2)
    assert _start_and_interrupt(held=False) in (1, -signal.SIGINT)


def test_a_ctrl_c_to_the_starting_thread_itself_is_taken_when_the_hold_ends():
    # directed at this thread: the hold is this thread's signal mask, and a SIGINT sent to the process may be handed
    # to another of its threads (the suite's process has several), which Python then raises here at once
    reached = False
    with pytest.raises(KeyboardInterrupt):
        with sigint_held():
            signal.pthread_kill(threading.get_ident(), signal.SIGINT)
            time.sleep(0.05)  # blocked: nothing is raised here
            reached = True
    assert reached
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, set())  # the mask is as before
