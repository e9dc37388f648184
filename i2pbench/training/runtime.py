"""Where and how the training loop runs: the device, this process's rank under torchrun, deterministic kernels,
TF32 and `torch.compile`; set once before the first step."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass

import torch

from ..stages.learned import LearnedComponent
from .config import TrainConfig


@dataclass(frozen=True)
class Distributed:
    """this process's place under torchrun (rank 0 of 1 without it)."""

    rank: int = 0
    world: int = 1

    @classmethod
    def from_env(cls) -> Distributed:
        return cls(int(os.environ.get("RANK", 0)), int(os.environ.get("WORLD_SIZE", 1)))

    @property
    def main(self) -> bool:
        return self.rank == 0


def pick_device(choice: str) -> torch.device:
    if choice == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(choice)


def make_deterministic() -> None:
    """Deterministic kernels everywhere (cuBLAS needs its workspace pinned before CUDA starts), no cuDNN autotuning:
    reruns on one machine then match bit for bit on GPU too; on CPU the kernels already do."""
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    torch.use_deterministic_algorithms(True)
    torch.backends.cudnn.benchmark = False
    torch.backends.cudnn.deterministic = True


def training_device(config: TrainConfig, dist: Distributed) -> torch.device:
    """this rank's device, with the kernels `config` asks for: deterministic ones, or TF32 on CUDA otherwise."""
    device = pick_device(config.device)
    if dist.world > 1 and device.type == "cuda":
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", 0)))
    if device.type == "cuda" and not config.deterministic:  # TF32: ~free accuracy-wise for this training
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
    if config.deterministic:
        make_deterministic()
    return device


def compile_stages(stages: Mapping[str, LearnedComponent], backend: str) -> list[str]:
    """`torch.compile` each learned stage's fixed-shape blocks in place (state dicts keep their keys); returns what
    was compiled, as `kind.Module` names."""
    compiled = []
    for kind, stage in stages.items():
        for block in stage.compile_targets():
            block.compile(backend=backend)
            compiled.append(f"{kind}.{type(block).__name__}")
    return compiled


def wrapped(model: torch.nn.Module, dist: Distributed, device: torch.device) -> torch.nn.Module:
    """`model` itself on one rank; under torchrun, in DistributedDataParallel (the process group started once)."""
    if dist.world == 1:
        return model
    import torch.distributed as torch_dist

    if not torch_dist.is_initialized():
        torch_dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
    ids = [device.index] if device.type == "cuda" else None
    return torch.nn.parallel.DistributedDataParallel(model, device_ids=ids)
