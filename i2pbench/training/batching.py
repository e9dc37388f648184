"""Batched training: how the learned stages of a combination take several frames at once.

A stage that subclasses `i2pbench.stages.learned.BatchedStage` (its contract: `prepare` one frame, `forward` a padded
batch, `batch_loss` for a trainable matcher) is prepared per frame here and run on the collated batch. A stage
without it still trains: it runs frame by frame inside the batch (slower, same result), each call through
`i2pbench.stages.calling.call_stage` as in a run (declared view, contract check), with autograd on.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
import torch.nn.functional as F

from ..stages.calling import StageInputs, call_stage
from ..stages.components import LEARNABLE_KINDS, Component
from ..stages.learned import BatchedStage
from ..types import Features, Frame, Keypoints2D, Keypoints3D

LEARNED_KINDS = LEARNABLE_KINDS  # the stages a batch runs through, in data-flow order
PER_FRAME = "_per_frame"  # the prepared entry of a stage without `prepare`: (frame, kp2d, kp3d), collated as a list


def pad_stack(tensors: Sequence[torch.Tensor], value: float = 0) -> torch.Tensor:
    """tensors of one rank, each padded at the end of every dim to the largest, stacked -> [B x ...]."""
    shape = [max(sizes) for sizes in zip(*(t.shape for t in tensors), strict=True)]
    padded = []
    for t in tensors:
        pad = [p for dim in reversed(range(t.dim())) for p in (0, shape[dim] - t.shape[dim])]
        padded.append(F.pad(t, pad, value=value) if any(pad) else t)
    return torch.stack(padded)


def collate(items: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """prepared dicts of the frames of a batch -> one dict: tensors padded and stacked, anything else listed."""
    out: dict[str, Any] = {}
    for key in items[0]:
        values = [item[key] for item in items]
        if isinstance(values[0], torch.Tensor):
            out[key] = pad_stack(values)
        elif isinstance(values[0], Mapping):
            out[key] = collate(values)
        else:
            out[key] = values
    return out


def length_mask(lengths: torch.Tensor, size: int) -> torch.Tensor:
    """[B] lengths -> [B x size] bool, True for the first lengths[b] entries."""
    return torch.arange(size, device=lengths.device)[None] < lengths[:, None]


def to_device(batch: Any, device: torch.device, non_blocking: bool = False) -> Any:
    """tensors of a (nested) batch moved to device; lists of frames stay where they are."""
    if isinstance(batch, torch.Tensor):
        return batch.to(device, non_blocking=non_blocking)
    if isinstance(batch, Mapping):
        return {k: to_device(v, device, non_blocking) for k, v in batch.items()}
    return batch


def prepare_stage(
    kind: str, stage: Component, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, cache: dict | None
) -> dict[str, Any]:
    """one frame's inputs for the stage of this kind (the frame itself for a stage without `prepare`); only the
    matcher, whose loss is the supervision, sees the ground truth."""
    if kind != "matcher":
        frame = frame.without_ground_truth()
    if not isinstance(stage, BatchedStage):
        return {PER_FRAME: (frame, kp2d, kp3d)}
    return stage.prepare(frame, *stage.keypoints_of(kp2d, kp3d), cache=cache)


class BatchForward:
    """The learned stages of a pipeline applied to a collated batch: features, then the matcher's mean loss."""

    def __init__(self, stages: Mapping[str, Component]) -> None:
        self.stages = {k: stages[k] for k in LEARNED_KINDS if k in stages}

    def __call__(self, batch: Mapping[str, Any]) -> tuple[torch.Tensor, dict[str, float]]:
        inputs, (m2, m3) = batch["inputs"], batch["masks"]
        d2 = self._encode("encoder2d", inputs)
        d3 = self._encode("encoder3d", inputs)
        exchanger = self.stages.get("exchanger")
        if isinstance(exchanger, BatchedStage):
            d2, d3 = exchanger.batched(inputs["exchanger"], d2, d3, m2, m3)
        elif exchanger is not None:
            d2, d3 = _per_frame_exchange(exchanger, inputs["exchanger"][PER_FRAME], d2, d3, m2, m3)
        matcher, features = self.stages["matcher"], Features(d2, d3)
        if isinstance(matcher, BatchedStage):
            return matcher.batch_loss(inputs["matcher"], features, m2, m3)
        return _per_frame_loss(matcher, inputs["matcher"][PER_FRAME], features, m2, m3)

    def _encode(self, kind: str, inputs: Mapping[str, Any]) -> torch.Tensor | None:
        stage = self.stages.get(kind)
        if stage is None:
            return None
        if isinstance(stage, BatchedStage):
            return stage.batched(inputs[kind])
        frames = inputs[kind][PER_FRAME]
        return pad_stack([call_stage(stage, f, StageInputs(kp2d, kp3d)).output for f, kp2d, kp3d in frames])


def _unpad(features: torch.Tensor | None, mask: torch.Tensor, b: int) -> torch.Tensor | None:
    return None if features is None else features[b, : int(mask[b].sum())]


def _per_frame_exchange(stage, frames, d2, d3, m2, m3) -> tuple[torch.Tensor, torch.Tensor]:
    out = [
        call_stage(stage, frame, StageInputs(kp2d, kp3d, Features(_unpad(d2, m2, b), _unpad(d3, m3, b)))).output
        for b, (frame, kp2d, kp3d) in enumerate(frames)
    ]
    return pad_stack([o.desc2d for o in out]), pad_stack([o.desc3d for o in out])


def _per_frame_loss(matcher, frames, features: Features, m2, m3) -> tuple[torch.Tensor, dict[str, float]]:
    losses, terms = [], []
    for b, (frame, kp2d, kp3d) in enumerate(frames):
        unpadded = Features(_unpad(features.desc2d, m2, b), _unpad(features.desc3d, m3, b))
        loss, t = matcher.loss(frame, kp2d, kp3d, unpadded)
        losses.append(loss)
        terms.append(t)
    mean = {k: sum(float(t[k]) for t in terms) / len(terms) for k in terms[0]}
    return torch.stack(losses).mean(), mean
