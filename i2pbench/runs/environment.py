"""What machine and software produced a result (as pytest-benchmark's machine_info and lm-eval's results JSON)."""

from __future__ import annotations

import importlib.metadata
import os
import platform

import torch

from ..weights import git_commit

PACKAGES = ("i2pbench", "torch", "numpy", "opencv-contrib-python-headless", "open3d", "pandas", "pluggy", "poselib")


def _version(package: str) -> str:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def environment() -> dict:
    return {
        "git_commit": git_commit(),
        "packages": {p: _version(p) for p in PACKAGES},
        "python": platform.python_version(),
        "machine": platform.machine(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "node": platform.node(),
    }
