"""The step log: one JSON line per step (loss terms, lr, steps/s, data-wait share, peak memory) and, given a
directory, the same scalars as TensorBoard events (`train/...`, validation under `val/...`)."""

from __future__ import annotations

import json
import math
import resource
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from ..errors import I2PBenchError


class StepLog:
    """the JSONL step log at `path` and the TensorBoard events in `tensorboard`, either one optional."""

    def __init__(self, path: Path | None, tensorboard: Path | None = None) -> None:
        self.path = path
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
        self.board = _summary_writer(tensorboard) if tensorboard is not None else None

    def write(self, step: int, terms: dict[str, Any], seconds: float) -> None:
        record = {"step": step, "seconds": round(seconds, 4), "steps_per_s": round(1 / max(seconds, 1e-9), 3)}
        record.update({k: v for k, v in terms.items() if isinstance(v, int | float | str)})
        record.update(peak_memory_mb())
        if self.path is not None:
            with self.path.open("a") as f:
                f.write(json.dumps(record) + "\n")
        if self.board is not None:
            self._scalars("train", step, record)

    def validation(self, step: int, stats: Mapping[str, Any]) -> None:
        if self.board is not None:
            self._scalars("val", step, stats)

    def _scalars(self, prefix: str, step: int, values: Mapping[str, Any]) -> None:
        for key, value in values.items():
            if key != "step" and isinstance(value, int | float) and math.isfinite(value):
                self.board.add_scalar(f"{prefix}/{key}", value, step)

    def close(self) -> None:
        if self.board is not None:
            self.board.close()


def peak_memory_mb() -> dict[str, float]:
    """the process's peak resident memory, and the GPU's peak allocation when there is one."""
    out = {"max_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**10, 1)}  # KiB on Linux
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        out["max_memory_mb"] = round(torch.cuda.max_memory_allocated() / 2**20, 1)
    return out


def _summary_writer(directory: Path) -> Any:
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError as exc:  # tensorboard is the `train` extra
        raise I2PBenchError(
            f"--tensorboard {directory}: the tensorboard package is not installed (pip install 'i2pbench[train]')"
        ) from exc
    return SummaryWriter(log_dir=str(directory))
