"""The generator's numerical kernels, pinned, so the embedded dataset is the same bytes on every x86-64 machine.

NumPy, OpenBLAS and OpenCV each pick kernels for the CPU they run on, and those kernels round differently: with
NumPy's AVX-512 loops (`power`, `exp`, ...) 39 of the 40 synthetic test images differed from the ones made without
them, OpenCV's AVX2 Gaussian blur moved pixels, and OpenBLAS's SkylakeX LAPACK moved calib.txt's 13th digit. So every
frame is made in a child process started with
- `NPY_DISABLE_CPU_FEATURES` naming every feature NumPy dispatches on (its baseline loops, x86-64-v2, run everywhere);
- `OPENBLAS_CORETYPE=Nehalem` (kernels that any x86-64-v2 CPU runs) on one thread;
- OpenCV's optimised code paths switched off (`cv2.setUseOptimized(False)`: its SSE3 baseline, no IPP).
Children check that NumPy took the setting before making anything. What stays machine-dependent is Open3D's ray
caster (Embree picks its AVX2 kernels on every AVX2 machine; an AVX2-less CPU would take another path).

A child reads `(function, calls, result file)` pickled on stdin, prints `done <position>` on stdout as each call
finishes (the parent's progress bar), and pickles the results to the file. Call `run` from the parent.
"""

from __future__ import annotations

import os
import pickle
import platform
import queue
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ...errors import DataError

OPENBLAS_CORE = "Nehalem"  # x86-64-v2, NumPy's own baseline: a core every machine of this kind runs


def pinned_env() -> dict[str, str]:
    """This process's environment with the kernel choices pinned (what the children start with)."""
    from numpy._core import _multiarray_umath as umath

    env = dict(os.environ)
    env.pop("NPY_ENABLE_CPU_FEATURES", None)
    env["NPY_DISABLE_CPU_FEATURES"] = " ".join(umath.__cpu_dispatch__)
    if platform.machine().lower() in ("x86_64", "amd64"):
        env["OPENBLAS_CORETYPE"] = OPENBLAS_CORE
    env.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    return env


def run(
    function: Callable[..., Any],
    calls: Sequence[tuple],
    workers: int = 1,
    done: Callable[[], None] | None = None,
) -> list[Any]:
    """`function(*args)` for each args in `calls`, made in `workers` pinned children; the results in call order.

    `function` must be importable by name (a module-level function). `done()` is called once per finished call.
    A failing call raises DataError with the child's error.
    """
    workers = max(1, min(workers, len(calls)))
    shares = [list(range(k, len(calls), workers)) for k in range(workers)]
    with tempfile.TemporaryDirectory(prefix="i2pbench-pinned-") as tmp:
        children = [
            _start(function, [(i, calls[i]) for i in share], Path(tmp) / f"{k}.pkl") for k, share in enumerate(shares)
        ]
        try:
            _follow(children, len(calls), done)
        finally:
            for child, _, _ in children:
                if child.poll() is None:
                    child.kill()
                child.wait()
        results: dict[int, Any] = {}
        for child, out, err in children:
            if child.returncode != 0:
                raise DataError(f"synthetic generator: a pinned worker failed (exit {child.returncode}):\n{_tail(err)}")
            results.update(pickle.loads(out.read_bytes()))
    return [results[i] for i in range(len(calls))]


def _start(function: Callable[..., Any], share: list[tuple[int, tuple]], out: Path):
    err = out.with_suffix(".err")
    child = subprocess.Popen(
        [sys.executable, "-m", __name__],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=err.open("wb"),
        env=pinned_env(),
    )
    child.stdin.write(pickle.dumps((function, share, str(out))))
    child.stdin.close()
    return child, out, err


def _follow(children: list, total: int, done: Callable[[], None] | None) -> None:
    """Count finished calls as the children report them, until every child has closed its output."""
    lines: queue.Queue = queue.Queue()

    def read(stream) -> None:
        for line in stream:
            if line.startswith(b"done "):
                lines.put(True)
        lines.put(False)

    for child, _, _ in children:
        threading.Thread(target=read, args=(child.stdout,), daemon=True).start()
    open_streams = len(children)
    while open_streams:
        if lines.get():
            if done is not None:
                done()
        else:
            open_streams -= 1


def _tail(err: Path, lines: int = 25) -> str:
    text = err.read_text(errors="replace") if err.is_file() else ""
    return "\n".join(text.splitlines()[-lines:]) or "(no error output)"


def _check_pinned() -> None:
    """Refuse to make frames with NumPy's CPU-specific loops on (the environment did not reach this process)."""
    from numpy._core import _multiarray_umath as umath

    live = [name for name in umath.__cpu_dispatch__ if umath.__cpu_features__.get(name)]
    if live:
        raise RuntimeError(f"pinned generator: NumPy still dispatches on {live}; NPY_DISABLE_CPU_FEATURES not applied")


def _serve() -> None:
    _check_pinned()
    import cv2

    cv2.setUseOptimized(False)
    function, share, out = pickle.loads(sys.stdin.buffer.read())
    results = {}
    for i, args in share:
        try:
            results[i] = function(*args)
        except Exception as error:
            raise RuntimeError(f"{function.__name__}{args!r} failed: {error}") from error
        print("done", i, flush=True)
    Path(out).write_bytes(pickle.dumps(results, protocol=pickle.HIGHEST_PROTOCOL))


if __name__ == "__main__":
    _serve()
