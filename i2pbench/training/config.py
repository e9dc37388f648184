"""A training run's settings, without torch: `i2pbench train`'s options take their defaults from here, so the
library's defaults and the command line's are one set."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TrainConfig:
    steps: int = 20000
    batch_size: int = 1  # frames per rank per forward pass
    accumulate: int = 1  # forward passes per optimiser step (gradient accumulation)
    lr: float = 1e-4  # Adam; the reference code uses 1e-5
    warmup_steps: int = 0  # linear warm-up from 0 to lr
    schedule: str = "constant"  # "constant" or "cosine" (to 0 at `steps`) after the warm-up
    grad_clip: float = 1.0
    checkpoint_every: int = 250
    validate_every: int = 1000
    val_frames: int = 20
    seed: int = 0
    device: str = "auto"  # "auto": cuda when available
    workers: int = 0  # DataLoader worker processes (0: in the main process)
    amp: str = "off"  # "bf16": autocast the learned stages in bfloat16 (losses stay fp32)
    cache_dir: str | None = None  # on-disk cache of extractor outputs and grouping per frame (None: in memory)
    epochs: bool = False  # samples pass through the split in seeded permutations (else a random frame each)
    augment: str = "none"  # "photometric": per-sample exposure, contrast, noise and blur of the image (augment.py)
    deterministic: bool = False  # torch's deterministic kernels only (an op without one raises, naming itself)
    compile: str = "off"  # a torch.compile backend ("inductor", "aot_eager") for the stages' `compile_targets`
    freeze: str = "none"  # learned stages kept as loaded (comma list of kinds, e.g. "encoder3d,exchanger,matcher")
