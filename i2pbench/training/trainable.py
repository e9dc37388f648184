"""What a training run changes: the combination's learned stages, less the frozen ones, as one module whose forward
is the batch loss, and the optimiser over the parameters left to train."""

from __future__ import annotations

from typing import Any

import torch

from ..errors import I2PBenchError, PluginError
from ..stages.components import TrainableMatcher
from ..stages.learned import BatchedStage
from ..stages.pipeline import Pipeline
from .batching import BatchForward


def check_trainable(pipeline: Pipeline) -> TrainableMatcher:
    matcher = pipeline.stages["matcher"]
    # a batched matcher inherits `loss`, which trains only through its own `batch_loss`
    untrained_batched = isinstance(matcher, BatchedStage) and type(matcher).batch_loss is BatchedStage.batch_loss
    if not isinstance(matcher, TrainableMatcher) or untrained_batched:
        raise PluginError(f"{matcher.label} has no training loss; choose a trainable matcher")
    if not pipeline.learned_modules():
        raise PluginError(f"combination {pipeline.combination.label!r} has no learned stage to train")
    return matcher


def frozen_stages(pipeline: Pipeline, freeze: str) -> tuple[str, ...]:
    """the learned stage kinds `freeze` names ("none": none), each checked to be one of the pipeline's learned stages:
    fine-tuning on few frames can keep most of a pretrained model as it is and adapt the rest."""
    kinds = tuple(k.strip() for k in (freeze or "none").split(",") if k.strip() and k.strip() != "none")
    learned = pipeline.learned_modules()
    unknown = [k for k in kinds if k not in learned]
    if unknown:
        raise I2PBenchError(
            f"--freeze {unknown[0]!r}: not a learned stage of {pipeline.combination.label}; "
            f"choose from {', '.join(learned) or 'none (no learned stage)'}"
        )
    if learned and set(kinds) == set(learned):
        raise I2PBenchError(f"--freeze {freeze!r}: every learned stage frozen leaves nothing to train")
    return kinds


def trained_parameters(pipeline: Pipeline, frozen: tuple[str, ...]) -> list[torch.nn.Parameter]:
    """the parameters of the learned stages not in `frozen`; the frozen ones stop taking gradients."""
    for kind in frozen:
        pipeline.stages[kind].requires_grad_(False)
    return [p for kind, m in pipeline.learned_modules().items() if kind not in frozen for p in m.parameters()]


def optimizer(params: list[torch.nn.Parameter], lr: float, device: torch.device) -> torch.optim.Optimizer:
    # fused on CUDA: one kernel for all parameters, and no per-parameter step counter read back by the host
    return torch.optim.Adam(params, lr=lr, fused=device.type == "cuda")


class TrainModel(torch.nn.Module):
    """the learned stages as one module whose forward is the batch loss: what DDP wraps."""

    def __init__(self, pipeline: Pipeline) -> None:
        super().__init__()
        self.stages = torch.nn.ModuleDict(pipeline.learned_modules())
        self.batch_forward = BatchForward(pipeline.stages)

    def forward(self, batch: dict[str, Any]) -> tuple[torch.Tensor, dict[str, float]]:
        return self.batch_forward(batch)
