"""What machine and software produced a result (as pytest-benchmark's machine_info and lm-eval's results JSON).

Latency depends on the thread count, so runs fix it (torch, OpenCV and numpy's BLAS alike) rather than inherit
whatever the machine's default is, and record it. BLAS matters as much as torch: on a busy machine numpy's default
threads made the protocol's point transform of one KITTI scan 8-60x slower than on one thread.
"""

from __future__ import annotations

import importlib.metadata
import os
import platform

import cv2
import torch

from ..provenance import git_commit, git_dirty

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


def default_threads() -> int:
    return max(1, min(MAX_DEFAULT_THREADS, os.cpu_count() or 1))


def fix_threads(n: int | None = None) -> int:
    """Set torch's, OpenCV's and BLAS's thread counts to `n` (default `default_threads()`); returns it."""
    n = n or default_threads()
    torch.set_num_threads(n)
    cv2.setNumThreads(n)
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # BLAS keeps its default; environment() records what it is
        return n
    threadpool_limits(limits=n, user_api="blas")
    return n


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
        "torch_threads": torch.get_num_threads(),
        "opencv_threads": cv2.getNumThreads(),
        "blas_threads": blas_threads(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "node": platform.node(),
    }
