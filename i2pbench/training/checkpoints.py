"""A training run's files: the checkpoint (weights with identity), the `best` checkpoint beside it, and the resume
file (optimiser state and the checkpoint's sha256, so a resume file left from another save is recognised and not
applied), each written atomically; and restoring a run from them."""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from ..errors import WeightsError
from ..stages.pipeline import Pipeline
from ..weights.checkpoints import file_digest, load_checkpoint, mismatch, save_checkpoint


def resume_path(out: Path) -> Path:
    return out.with_name(out.name + ".resume")


def best_path(out: Path) -> Path:
    return out.with_name(f"{out.stem}.best{out.suffix}")


def check_writable(out: Path) -> None:
    """fail before step 1, not at the first checkpoint, when the output folder cannot take files."""
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out.parent, prefix=f".{out.name}.", suffix=".probe"):
            pass
    except OSError as exc:
        raise WeightsError(f"cannot write checkpoints to {out.parent}: {exc.strerror or exc}") from exc


@dataclass(frozen=True)
class Restored:
    """where the checkpoint on disk left its run; the weights are already back in the pipeline."""

    step: int
    seconds: float
    validation: dict[str, Any]
    best: float | None
    lineage: list[dict[str, Any]]
    trained_on: dict[str, Any]  # the data identity it recorded
    trained_on_label: str  # the same, in words, with its lineage


def restore(out: Path, pipeline: Pipeline) -> Restored | None:
    """Load the checkpoint at `out` into `pipeline`'s learned stages, refusing one of other stages or extractors.
    None: nothing to resume."""
    if not out.is_file():
        return None
    checkpoint = load_checkpoint(out)
    reason = mismatch(checkpoint, pipeline, strict_extractors=True)
    if reason:
        raise WeightsError(f"cannot resume {out}: {reason}; choose another --out or delete it")
    for kind, module in pipeline.learned_modules().items():
        module.load_state_dict(checkpoint.state[kind])
    meta = checkpoint.meta
    return Restored(
        step=int(meta.get("steps", 0)),
        seconds=float(meta.get("train_seconds", 0.0)),
        validation=meta.get("validation", {}),
        best=meta.get("best_acc"),
        lineage=checkpoint.lineage,
        trained_on=meta.get("trained_on", {}),
        trained_on_label=checkpoint.trained_on,
    )


def load_optimizer(out: Path, optimizer: torch.optim.Optimizer, step: int, device: torch.device) -> str:
    """Load the resume file of the checkpoint at `out` into `optimizer` when it belongs to this very checkpoint (same
    bytes, same step), so the run continues exactly; else the optimiser stays fresh. Returns the note saying which."""
    state_path = resume_path(out)
    fresh = f"resumed at step {step} with a fresh optimiser"
    if not state_path.is_file():
        return f"{fresh} (no {state_path.name})"
    try:
        state = torch.load(state_path, map_location=device, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - a torn resume file only costs the optimiser's moments
        return f"{fresh} ({state_path.name} unreadable: {exc})"
    if state.get("checkpoint_sha256") != file_digest(out) or int(state["step"]) != step:
        return (
            f"{fresh} ({state_path.name} belongs to another save of "
            f"{out.name}: step {state.get('step')}, an interrupted checkpoint)"
        )
    try:
        optimizer.load_state_dict(state["optimizer"])
    except ValueError as exc:  # other parameters trained (another --freeze): the moments belong to those
        return f"{fresh} ({state_path.name} holds other parameters: {exc})"
    return f"resumed exactly at step {step}"


def save(
    out: Path, pipeline: Pipeline, optimizer: torch.optim.Optimizer, step: int, seconds: float, meta: dict[str, Any]
) -> None:
    """the checkpoint with `meta`, then the resume file that names the checkpoint's bytes."""
    save_checkpoint(out, pipeline, **meta)
    state = {
        "optimizer": optimizer.state_dict(),
        "step": step,
        "seconds": seconds,
        "checkpoint_sha256": file_digest(out),
    }
    tmp = resume_path(out).with_suffix(".tmp")
    torch.save(state, tmp)
    os.replace(tmp, resume_path(out))
