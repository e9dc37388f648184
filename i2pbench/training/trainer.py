"""The generic training loop for any combination with learned stages; the loss comes from the matcher plugin.

A step takes `batch_size` frames per rank, `accumulate` times (effective batch = ranks x accumulate x batch_size);
each frame has its own protocol transform, drawn from its global sample index, so a resumed run, another worker count
or another number of ranks sees the same sequence (`samples.py`). Data work runs in DataLoader workers; the
loop only moves padded batches to the device and runs the learned stages (`batching.py`). Under `torchrun` each rank
takes its share of every step and DistributedDataParallel averages the gradients; rank 0 validates and checkpoints.

Checkpoints (weights with identity) and a resume file (optimiser state and the checkpoint's sha256, so a resume file
left from another save is recognised and not applied) are written atomically every N steps, and the `best`
checkpoint is kept beside the `last` one.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from ..components import TrainableMatcher
from ..data.base import Dataset
from ..errors import I2PBenchError, PluginError, WeightsError
from ..learned import BatchedStage, LearnedComponent
from ..metrics import installed as installed_metrics
from ..metrics.pose import summarize
from ..pipeline import Pipeline
from ..protocol import Protocol
from ..types import Frame
from ..weights import file_digest, load_checkpoint, mismatch, save_checkpoint
from .batching import BatchForward, to_device
from .config import TrainConfig
from .mix import MixedSource
from .samples import TrainingSamples, collate_samples

Report = Callable[[int, dict[str, Any]], None]


def pick_device(choice: str) -> torch.device:
    if choice == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(choice)


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


def make_deterministic() -> None:
    """Deterministic kernels everywhere (cuBLAS needs its workspace pinned before CUDA starts), no cuDNN autotuning:
    reruns on one machine then match bit for bit on GPU too; on CPU the kernels already do."""
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    torch.use_deterministic_algorithms(True)
    torch.backends.cudnn.benchmark = False
    torch.backends.cudnn.deterministic = True


def compile_stages(stages: Mapping[str, LearnedComponent], backend: str) -> list[str]:
    """`torch.compile` each learned stage's fixed-shape blocks in place (state dicts keep their keys); returns what
    was compiled, as `kind.Module` names."""
    compiled = []
    for kind, stage in stages.items():
        for block in stage.compile_targets():
            block.compile(backend=backend)
            compiled.append(f"{kind}.{type(block).__name__}")
    return compiled


def _resume_path(out: Path) -> Path:
    return out.with_name(out.name + ".resume")


def best_path(out: Path) -> Path:
    return out.with_name(f"{out.stem}.best{out.suffix}")


def check_trainable(pipeline: Pipeline) -> TrainableMatcher:
    matcher = pipeline.stages["matcher"]
    # a batched matcher inherits `loss`, which trains only through its own `batch_loss`
    untrained_batched = isinstance(matcher, BatchedStage) and type(matcher).batch_loss is BatchedStage.batch_loss
    if not isinstance(matcher, TrainableMatcher) or untrained_batched:
        raise PluginError(f"{matcher.label} has no training loss; choose a trainable matcher")
    if not pipeline.learned_modules():
        raise PluginError(f"combination {pipeline.combination.label!r} has no learned stage to train")
    return matcher


def check_writable(out: Path) -> None:
    """fail before step 1, not at the first checkpoint, when the output folder cannot take files."""
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out.parent, prefix=f".{out.name}.", suffix=".probe"):
            pass
    except OSError as exc:
        raise WeightsError(f"cannot write checkpoints to {out.parent}: {exc.strerror or exc}") from exc


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


class TrainModel(torch.nn.Module):
    """the learned stages as one module whose forward is the batch loss: what DDP wraps."""

    def __init__(self, pipeline: Pipeline) -> None:
        super().__init__()
        self.stages = torch.nn.ModuleDict(pipeline.learned_modules())
        self.batch_forward = BatchForward(pipeline.stages)

    def forward(self, batch: dict[str, Any]) -> tuple[torch.Tensor, dict[str, float]]:
        return self.batch_forward(batch)


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
        for name, value in (("lr", config.lr), ("grad_clip", config.grad_clip)):
            if not (math.isfinite(value) and value > 0):
                raise I2PBenchError(f"training {name} {value}: give a finite positive number")
        self.matcher = check_trainable(pipeline)
        self.dist = Distributed.from_env()
        self.device = pick_device(config.device)
        if self.dist.world > 1 and self.device.type == "cuda":
            self.device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", 0)))
        if self.device.type == "cuda" and not config.deterministic:  # TF32: ~free accuracy-wise for this training
            torch.backends.cuda.matmul.allow_tf32 = True
            torch.backends.cudnn.allow_tf32 = True
        if config.deterministic:
            make_deterministic()
        pipeline.to(self.device)
        self.compiled = compile_stages(pipeline.learned_modules(), config.compile) if config.compile != "off" else []
        self.model = TrainModel(pipeline)
        self.frozen = frozen_stages(pipeline, config.freeze)
        self.params = [
            p for kind, m in pipeline.learned_modules().items() if kind not in self.frozen for p in m.parameters()
        ]
        for kind in self.frozen:
            pipeline.stages[kind].requires_grad_(False)
        # fused on CUDA: one kernel for all parameters, and no per-parameter step counter read back by the host
        self.optimizer = torch.optim.Adam(self.params, lr=config.lr, fused=self.device.type == "cuda")
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
        """Continue from the last checkpoint, refusing one of other stages or extractors. With its resume file (when
        it belongs to this very checkpoint) the optimiser continues exactly; else from the weights and step with a
        fresh optimiser, said in the returned note. None: nothing to resume."""
        if not self.out.is_file():
            return None
        checkpoint = load_checkpoint(self.out)
        reason = mismatch(checkpoint, self.pipeline, strict_extractors=True)
        if reason:
            raise WeightsError(f"cannot resume {self.out}: {reason}; choose another --out or delete it")
        for kind, module in self.pipeline.learned_modules().items():
            module.load_state_dict(checkpoint.state[kind])
        self.step = self.saved_step = int(checkpoint.meta.get("steps", 0))
        self.seconds = float(checkpoint.meta.get("train_seconds", 0.0))
        self.validation = checkpoint.meta.get("validation", {})
        self.best = checkpoint.meta.get("best_acc")
        self.lineage = checkpoint.lineage
        before = checkpoint.meta.get("trained_on", {})
        if before and _data_of(before) != _data_of(data_identity(self.train_set, self.mix)):  # on other data
            self.lineage.append({**_data_of(before), "steps": self.step})
            self.best = None  # a validation of the new phase is not comparable with the old one's
        note = self._load_optimizer()
        if self.lineage and self.lineage[-1]["steps"] == self.step:
            note += f"; fine-tuning what was trained on {checkpoint.trained_on}"
        self.notes.append(note)
        return note

    def _load_optimizer(self) -> str:
        state_path = _resume_path(self.out)
        if not state_path.is_file():
            return f"resumed at step {self.step} with a fresh optimiser (no {state_path.name})"
        try:
            state = torch.load(state_path, map_location=self.device, weights_only=True)
        except Exception as exc:  # noqa: BLE001 - a torn resume file only costs the optimiser's moments
            return f"resumed at step {self.step} with a fresh optimiser ({state_path.name} unreadable: {exc})"
        if state.get("checkpoint_sha256") != file_digest(self.out) or int(state["step"]) != self.step:
            return (
                f"resumed at step {self.step} with a fresh optimiser ({state_path.name} belongs to another save of "
                f"{self.out.name}: step {state.get('step')}, an interrupted checkpoint)"
            )
        try:
            self.optimizer.load_state_dict(state["optimizer"])
        except ValueError as exc:  # other parameters trained (another --freeze): the moments belong to those
            held = f"{state_path.name} holds other parameters: {exc}"
            return f"resumed at step {self.step} with a fresh optimiser ({held})"
        return f"resumed exactly at step {self.step}"

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
            stats["kept"] = summarize(records["rte_m"], records["rre_deg"], protocol)["kept"]
        numbers = {k: float(v) for k, v in stats.items() if isinstance(v, int | float) and not math.isnan(v)}
        return {"step": self.step, "frames": len(records), **numbers}

    def save(self, meta: dict[str, Any]) -> None:
        """checkpoint, then the resume file that names the checkpoint's bytes."""
        save_checkpoint(self.out, self.pipeline, best_acc=self.best, **self._progress(), **meta)
        state = {
            "optimizer": self.optimizer.state_dict(),
            "step": self.step,
            "seconds": self.seconds,
            "checkpoint_sha256": file_digest(self.out),
        }
        tmp = _resume_path(self.out).with_suffix(".tmp")
        torch.save(state, tmp)
        os.replace(tmp, _resume_path(self.out))
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
            save_checkpoint(best_path(self.out), self.pipeline, best_acc=acc, **self._progress(), **meta)

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
            check_writable(self.out)
        model = self._wrapped()
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

    def _wrapped(self) -> torch.nn.Module:
        if self.dist.world == 1:
            return self.model
        import torch.distributed as dist

        if not dist.is_initialized():
            dist.init_process_group("nccl" if self.device.type == "cuda" else "gloo")
        ids = [self.device.index] if self.device.type == "cuda" else None
        return torch.nn.parallel.DistributedDataParallel(self.model, device_ids=ids)


def spread(ids: list[str], count: int) -> list[str]:
    """`count` of `ids` at even spacing, first and last included (all of them when there are no more)."""
    if count >= len(ids):
        return list(ids)
    return [ids[i] for i in np.linspace(0, len(ids) - 1, count).round().astype(int)]


def _data_of(identity: dict[str, Any]) -> dict[str, Any]:
    """what names the training data (dataset, split, root, a non-default style; each mixed-in source's and its
    share), without counts or configs; an unmixed run's is what it was before mixes existed, so its checkpoints
    resume as one phase."""
    named = {k: identity.get(k) for k in ("dataset", "split", "root")}
    if identity.get("style"):  # a synthetic set in another style is other data (absent for the default style)
        named["style"] = identity["style"]
    if identity.get("mix"):
        named["mix"] = [{**_data_of(m), "share": m.get("share")} for m in identity["mix"]]
    return named


def data_identity(train_set: Dataset, mix: Sequence[MixedSource] = ()) -> dict[str, Any]:
    """the training data's identity: the main dataset's, and under "mix" each mixed-in source's with its share."""
    identity = {**train_set.identity(), "frames": len(train_set.frame_ids())}
    return {**identity, "mix": [m.identity() for m in mix]} if mix else identity


def _one_thread(_: int) -> None:
    """data workers run one torch thread each: the main process owns the cores for the network."""
    torch.set_num_threads(1)


class StepLog:
    """One JSON line per step (loss terms, lr, steps/s, data-wait share, peak memory) and, given a directory, the
    same scalars as TensorBoard events (`train/...`, validation under `val/...`)."""

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
    import resource

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


def training_meta(
    train_set: Dataset, config: TrainConfig, world: int = 1, mix: Sequence[MixedSource] = ()
) -> dict[str, Any]:
    trained_on = data_identity(train_set, mix)
    effective = world * config.accumulate * config.batch_size
    return {"trained_on": trained_on, "train_config": {**asdict(config), "ranks": world, "effective_batch": effective}}
