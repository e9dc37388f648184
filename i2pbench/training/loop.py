"""The generic training loop for any combination with learned stages; the loss comes from the matcher plugin.

A step takes `batch_size` frames per rank, `accumulate` times (effective batch = ranks x accumulate x batch_size);
each frame has its own protocol transform, drawn from its global sample index, so a resumed run, another worker count
or another number of ranks sees the same sequence (`samples.py`). Data work runs in DataLoader workers; the
loop only moves padded batches to the device and runs the learned stages (`batching.py`). Under `torchrun` each rank
takes its share of every step and DistributedDataParallel averages the gradients (`runtime.py`); rank 0 validates and
checkpoints every N steps, keeping the `best` checkpoint beside the `last` one (`checkpoints.py`).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from ..data.base import Dataset
from ..errors import I2PBenchError
from ..scoring import installed as installed_metrics
from ..scoring.pose import kept
from ..scoring.protocol import Protocol
from ..stages.pipeline import Pipeline
from ..types import Frame
from ..weights.checkpoints import save_checkpoint
from . import checkpoints, lineage, trainable
from .batching import to_device
from .config import TrainConfig
from .mix import MixedSource
from .runtime import Distributed, compile_stages, training_device, wrapped
from .samples import TrainingSamples, collate_samples
from .steplog import StepLog

Report = Callable[[int, dict[str, Any]], None]


def steps_for_epochs(epochs: float, frames: int, config: TrainConfig, world: int = 1) -> int:
    """optimiser steps that pass `epochs` times through `frames` at the effective batch."""
    return max(1, math.ceil(epochs * frames / (world * config.accumulate * config.batch_size)))


def learning_rate(config: TrainConfig, step: int) -> float:
    """the schedule as a pure function of the step, so resuming needs no scheduler state."""
    if step < config.warmup_steps:
        return config.lr * (step + 1) / config.warmup_steps
    if config.schedule == "cosine":
        span = max(config.steps - config.warmup_steps, 1)
        return config.lr * 0.5 * (1 + math.cos(math.pi * min(step - config.warmup_steps, span) / span))
    return config.lr


def check_rates(config: TrainConfig) -> None:
    for name, value in (("lr", config.lr), ("grad_clip", config.grad_clip)):
        if not (math.isfinite(value) and value > 0):
            raise I2PBenchError(f"training {name} {value}: give a finite positive number")


class Trainer:
    def __init__(
        self,
        pipeline: Pipeline,
        train_set: Dataset,
        val_set: Dataset | None,
        out: Path,
        config: TrainConfig,
        mix: Sequence[MixedSource] = (),
    ) -> None:
        """`mix`: datasets mixed into `train_set`, each with its share of the samples (mix.py)."""
        self.pipeline, self.train_set, self.val_set, self.out, self.config = pipeline, train_set, val_set, out, config
        self.mix = tuple(mix)
        check_rates(config)
        self.matcher = trainable.check_trainable(pipeline)
        self.dist = Distributed.from_env()
        self.device = training_device(config, self.dist)
        pipeline.to(self.device)
        self.compiled = compile_stages(pipeline.learned_modules(), config.compile) if config.compile != "off" else []
        self.model = trainable.TrainModel(pipeline)
        self.frozen = trainable.frozen_stages(pipeline, config.freeze)
        self.params = trainable.trained_parameters(pipeline, self.frozen)
        self.optimizer = trainable.optimizer(self.params, config.lr, self.device)
        self.samples = TrainingSamples(
            pipeline.stages,
            train_set,
            config.seed,
            config.cache_dir,
            epochs=config.epochs,
            augment=config.augment,
            mix=self.mix,
        )
        self.step, self.seconds, self.validation = 0, 0.0, {}
        self.best: float | None = None
        self.lineage: list[dict[str, Any]] = []  # earlier phases on other data (see Checkpoint.lineage)
        self.notes: list[str] = []
        self.saved_step: int | None = None  # the step of the checkpoint on disk, None while there is none

    def sample(self, index: int) -> Frame:
        """sample index's frame and transform (a pure function of (seed, index))."""
        return self.samples.frame(index)

    def resume(self) -> str | None:
        """Continue from the last checkpoint (`checkpoints.restore`). With its resume file (when it belongs to this
        very checkpoint) the optimiser continues exactly; else from the weights and step with a fresh optimiser,
        said in the returned note. None: nothing to resume."""
        restored = checkpoints.restore(self.out, self.pipeline)
        if restored is None:
            return None
        self.step = self.saved_step = restored.step
        self.seconds, self.validation, self.best = restored.seconds, restored.validation, restored.best
        now = lineage.data_identity(self.train_set, self.mix)
        self.lineage, new_phase = lineage.continued(restored.lineage, restored.trained_on, now, self.step)
        if new_phase:
            self.best = None  # a validation of the new phase is not comparable with the old one's
        note = checkpoints.load_optimizer(self.out, self.optimizer, self.step, self.device)
        if self.lineage and self.lineage[-1]["steps"] == self.step:
            note += f"; fine-tuning what was trained on {restored.trained_on_label}"
        self.notes.append(note)
        return note

    def loader(self) -> Iterator[dict[str, Any]]:
        """micro-batches from the current step on: this rank's share of each step's samples, in order."""
        c, d = self.config, self.dist
        indices = [
            ((step * c.accumulate + m) * d.world + d.rank) * c.batch_size + j
            for step in range(self.step, c.steps)
            for m in range(c.accumulate)
            for j in range(c.batch_size)
        ]
        loader = torch.utils.data.DataLoader(
            self.samples,
            batch_size=c.batch_size,
            sampler=indices,
            collate_fn=collate_samples,
            num_workers=c.workers,
            pin_memory=self.device.type == "cuda",
            prefetch_factor=4 if c.workers else None,
            persistent_workers=False,
            worker_init_fn=_one_thread if c.workers else None,
        )
        return iter(loader)

    def _autocast(self) -> contextlib.AbstractContextManager:
        if self.config.amp == "bf16":
            return torch.autocast(self.device.type, dtype=torch.bfloat16)
        if self.config.amp not in ("off", "", None):
            raise I2PBenchError(f"--amp {self.config.amp!r}: choose 'bf16' or 'off'")
        return contextlib.nullcontext()

    def train_step(self, model: torch.nn.Module, batches: list[dict[str, Any]]) -> dict[str, Any]:
        """one optimiser step over `accumulate` micro-batches; a micro-batch whose frames all broke is skipped."""
        for kind, module in self.pipeline.learned_modules().items():
            module.train(kind not in self.frozen)  # a frozen stage keeps its BatchNorm statistics and no dropout
        for group in self.optimizer.param_groups:
            group["lr"] = learning_rate(self.config, self.step)
        self.optimizer.zero_grad(set_to_none=True)
        terms: dict[str, Any] = {}
        errors = [e for b in batches for e in b["errors"]]
        used = [b for b in batches if b["size"]]
        for i, batch in enumerate(used):
            sync = contextlib.nullcontext() if i == len(used) - 1 or not hasattr(model, "no_sync") else model.no_sync()
            with sync:
                with self._autocast():
                    loss, t = model(to_device(batch, self.device, non_blocking=True))
                loss = loss.float()
                if torch.isfinite(loss) and loss.requires_grad:
                    (loss / len(used)).backward()
            for k, v in {"loss": float(loss.detach()), **t}.items():
                terms[k] = terms.get(k, 0.0) + float(v) / len(used)
        if used:  # under DDP every rank must have a frame: one rank with none would leave the others waiting
            torch.nn.utils.clip_grad_norm_(self.params, self.config.grad_clip)
            self.optimizer.step()
        if errors:
            terms.update(skipped=float(len(errors)), error=errors[0][:200])
        return terms

    def validate(self) -> dict[str, float]:
        """Every registered metric's aggregate on `val_frames` frames spread evenly over the val split (so over its
        sequences, not the first one's first frames), protocol seed 0: each frame takes `run`'s path
        (`runs.frames.run_frame`, a failed load a failed frame) and the records are aggregated as a board row is.
        Keys are metric names (acc_pct, skill_acc_pct, ...)."""
        if self.val_set is None:
            return {}
        from ..runs.frames import run_frame
        from ..runs.jobs import Job

        self.pipeline.eval()
        protocol, job = Protocol(), Job(self.pipeline.combination, self.pipeline, str(self.device))
        ids = spread(self.val_set.frame_ids(), self.config.val_frames)
        records = pd.DataFrame([run_frame(job, self.val_set, frame_id, protocol) for frame_id in ids])
        stats = installed_metrics.aggregates(records, protocol) if len(records) else {}
        if len(records):
            stats["kept"] = int(kept(records["rte_m"], records["rre_deg"], protocol).sum())
        numbers = {k: float(v) for k, v in stats.items() if isinstance(v, int | float) and not math.isnan(v)}
        return {"step": self.step, "frames": len(records), **numbers}

    def save(self, meta: dict[str, Any]) -> None:
        """checkpoint, then the resume file that names the checkpoint's bytes."""
        full = {"best_acc": self.best, **self._progress(), **meta}
        checkpoints.save(self.out, self.pipeline, self.optimizer, self.step, self.seconds, full)
        self.saved_step = self.step

    def check_finite(self, terms: dict[str, Any]) -> None:
        """stop on a non-finite loss or weights (a too-large learning rate): nothing more is saved, so the
        checkpoint on disk stays the last good one."""
        loss = terms.get("loss", 0.0)
        weights = torch.stack([p.detach().double().sum() for p in self.params]).sum() if self.params else None
        if math.isfinite(loss) and (weights is None or bool(torch.isfinite(weights))):
            return
        what = f"the loss is {loss}" if not math.isfinite(loss) else "the weights are no longer finite"
        kept = "nothing was saved" if self.saved_step is None else f"{self.out} keeps step {self.saved_step}"
        raise I2PBenchError(
            f"training stopped at step {self.step}: {what} (lr {self.config.lr:g}); {kept}. Lower --lr or --grad-clip"
        )

    def _progress(self) -> dict[str, Any]:
        return {
            "steps": self.step,
            "train_seconds": round(self.seconds, 1),
            "validation": self.validation,
            "lineage": self.lineage,
        }

    def _validate_and_keep_best(self, meta: dict[str, Any], report: Report | None) -> None:
        self.validation = self.validate()
        if report and self.validation:
            report(self.step, {f"val_{k}": v for k, v in self.validation.items()})
        acc = self.validation.get("skill_acc_pct")  # chance successes never make a checkpoint the best
        if acc is not None and (self.best is None or acc > self.best):
            self.best = acc
            save_checkpoint(checkpoints.best_path(self.out), self.pipeline, best_acc=acc, **self._progress(), **meta)

    def run(
        self,
        meta: dict[str, Any],
        report: Report | None = None,
        log: Path | None = None,
        tensorboard: Path | None = None,
    ) -> None:
        """Train to `config.steps`; `log`: the JSONL step log; `tensorboard`: a TensorBoard log directory too."""
        c = self.config
        if self.dist.main:
            checkpoints.check_writable(self.out)
        model = wrapped(self.model, self.dist, self.device)
        batches = self.loader()
        logger = StepLog(log, tensorboard) if (log or tensorboard) and self.dist.main else None
        while self.step < c.steps:
            start = time.perf_counter()
            micro = [next(batches) for _ in range(c.accumulate)]
            waited = time.perf_counter() - start
            terms = self.train_step(model, micro)
            self.step += 1
            self.check_finite(terms)
            elapsed = time.perf_counter() - start
            self.seconds += elapsed
            terms.update(lr=learning_rate(c, self.step - 1), data_wait=waited / max(elapsed, 1e-9))
            if report and self.dist.main:
                report(self.step, terms)
            if logger:
                logger.write(self.step, terms, elapsed)
            if not self.dist.main:
                continue
            if self.step % c.validate_every == 0 or self.step == c.steps:
                self._validate_and_keep_best(meta, report)
                if logger and self.validation:
                    logger.validation(self.step, self.validation)
            if self.step % c.checkpoint_every == 0 or self.step == c.steps:
                self.save(meta)
        if logger:
            logger.close()


def spread(ids: list[str], count: int) -> list[str]:
    """`count` of `ids` at even spacing, first and last included (all of them when there are no more)."""
    if count >= len(ids):
        return list(ids)
    return [ids[i] for i in np.linspace(0, len(ids) - 1, count).round().astype(int)]


def _one_thread(_: int) -> None:
    """data workers run one torch thread each: the main process owns the cores for the network."""
    torch.set_num_threads(1)
