"""What machine and software produced a result (as pytest-benchmark's machine_info and lm-eval's results JSON).

Latency depends on the thread count, so runs fix it (torch, OpenCV and numpy's BLAS alike) rather than inherit
whatever the machine's default is, and record it. BLAS matters as much as torch: on a busy machine numpy's default
threads made the protocol's point transform of one KITTI scan 8-60x slower than on one thread.

torch is set and asked only when something has loaded it (a learned stage): a classic run never imports it. One
loaded after `fix_threads` (building a learned stage imports it) gets the same count from `sync_torch_threads`.
"""

from __future__ import annotations

import importlib.metadata
import os
import platform
import sys

import cv2

from ..execution.devices import torch_gpu_build
from .provenance import git_commit, git_dirty

PACKAGES = (
    "i2pbench",
    "torch",
    "numpy",
    "opencv-contrib-python-headless",
    "open3d",
    "pandas",
    "pyarrow",
    "pluggy",
    "poselib",
)
MAX_DEFAULT_THREADS = 4  # the default thread count: this, or fewer on smaller machines
_fixed: int | None = None  # the count `fix_threads` last set
_pending: int | None = None  # that count, while torch (not loaded then) has yet to be given it


def default_threads() -> int:
    return max(1, min(MAX_DEFAULT_THREADS, os.cpu_count() or 1))


def fix_threads(n: int | None = None) -> int:
    """Set torch's (now, or when it loads: `sync_torch_threads`), OpenCV's and BLAS's thread counts to `n` (default
    `default_threads()`); returns it."""
    global _fixed, _pending
    n = _fixed = n or default_threads()
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(n)
    _pending = None if torch is not None else n
    cv2.setNumThreads(n)
    _limit_blas(n)
    return n


def _limit_blas(n: int) -> None:
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # BLAS keeps its default; environment() records what it is
        return
    threadpool_limits(limits=n, user_api="blas")


def sync_torch_threads() -> None:
    """Give torch the count `fix_threads` set, once, if it was loaded since: called when a run's stages are built,
    since a learned stage's module is what imports torch."""
    global _pending
    torch = sys.modules.get("torch")
    if _pending is not None and torch is not None:
        torch.set_num_threads(_pending)
        _limit_blas(_pending)  # and any BLAS library torch brought
        _pending = None


def threads() -> int:
    """The thread count torch runs (or would run) stages with: its own when loaded, else the one `fix_threads` set."""
    if "torch" in sys.modules or _fixed is None:  # nothing set yet: torch's default, which only torch knows
        import torch

        return torch.get_num_threads()
    return _fixed


def _cuda_name() -> str | None:
    """The first GPU's name, or None; a torch built without GPU support has none, known without importing it."""
    if not torch_gpu_build():
        return None
    import torch

    return torch.cuda.get_device_name(0) if torch.cuda.is_available() else None


def blas_threads() -> dict[str, int]:
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return {}
    return {i["filepath"].rsplit("/", 1)[-1]: i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}


def _version(package: str) -> str:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def environment() -> dict:
    return {
        "git_commit": git_commit(),
        "git_dirty": git_dirty(),
        "packages": {p: _version(p) for p in PACKAGES},
        "python": platform.python_version(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "torch_threads": threads(),
        "opencv_threads": cv2.getNumThreads(),
        "blas_threads": blas_threads(),
        "cuda": _cuda_name(),
        "node": platform.node(),
    }
