"""Checking `--device` before any work starts, so a typo or a missing GPU is one clear line, not a torch traceback."""

from __future__ import annotations

import ast
import contextlib
import importlib.util
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import I2PBenchError

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


def resolve_device_name(choice: str) -> str:
    """`resolve_device(choice)` as a name, without importing torch where the answer is known without it ("cpu", and
    "auto" on a torch built without GPU support), so a run of classic stages never imports torch."""
    name = choice.strip().lower()
    if name == "cpu" or (name == "auto" and not torch_gpu_build()):
        return "cpu"
    return str(resolve_device(choice))


def torch_gpu_build() -> bool:
    """Whether the installed torch is built for CUDA or ROCm (if not, `torch.cuda.is_available()` is always False),
    read from its version.py without importing torch; True when that cannot be read, so that torch is asked."""
    if "torch" in sys.modules:
        version = sys.modules["torch"].version
        return bool(version.cuda or version.hip)
    built = _torch_version_constants()
    return "cuda" not in built or bool(built["cuda"] or built.get("hip"))


def _torch_version_constants() -> dict[str, Any]:
    """The literals torch/version.py assigns (`cuda: Optional[str] = '12.4'`...), {} when it cannot be read."""
    spec = importlib.util.find_spec("torch")
    if spec is None or not spec.submodule_search_locations:
        return {}
    try:
        tree = ast.parse((Path(next(iter(spec.submodule_search_locations))) / "version.py").read_text())
    except (OSError, SyntaxError):
        return {}
    constants = {}
    for node in tree.body:
        target = node.target if isinstance(node, ast.AnnAssign) else getattr(node, "targets", [None])[0]
        if isinstance(target, ast.Name) and getattr(node, "value", None) is not None:
            with contextlib.suppress(ValueError, TypeError):
                constants[target.id] = ast.literal_eval(node.value)
    return constants


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
