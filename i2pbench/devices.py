"""Checking `--device` before any work starts, so a typo or a missing GPU is one clear line, not a torch traceback."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from .errors import I2PBenchError

if TYPE_CHECKING:
    import torch

CHOICES = ("auto", "cpu", "cuda", "cuda:N", "mps")
_DEVICE = re.compile(r"auto|cpu|mps|cuda(?::(\d+))?")


class DeviceError(I2PBenchError):
    """--device names no device i2pbench knows, or one this machine does not have."""


def resolve_device(choice: str) -> torch.device:
    """The torch device for `choice`; "auto" is cuda when torch sees a GPU, else cpu. torch is imported only here,
    so parsing options stays fast."""
    import torch

    name = choice.strip().lower()
    match = _DEVICE.fullmatch(name)
    if match is None:
        raise DeviceError(f"--device {choice!r}: unknown device; choose one of {', '.join(CHOICES)}")
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda"):
        _check_cuda(choice, match.group(1))
    if name == "mps" and not torch.backends.mps.is_available():
        raise DeviceError(f"--device {choice!r}: MPS (Apple GPU) is not available on this machine; use cpu or auto")
    return torch.device(name)


def _check_cuda(choice: str, index: str | None) -> None:
    import torch

    if not torch.cuda.is_available():
        build = f"CUDA {torch.version.cuda} build, no GPU visible" if torch.version.cuda else "a CPU-only build"
        raise DeviceError(f"--device {choice!r}: CUDA is not available (torch {torch.__version__}, {build}); use cpu")
    count = torch.cuda.device_count()
    if index is not None and int(index) >= count:
        raise DeviceError(
            f"--device {choice!r}: this machine has {count} CUDA device(s); the index must be below {count}"
        )
