"""The generic training loop for any combination with learned stages; the loss comes from the matcher plugin.

Each step draws a training frame and a fresh protocol transform (keyed by the step, so a resumed run sees the same
sequence), runs the extractors, then the learned stages with gradients, and minimises `matcher.loss`. Checkpoints
(weights with identity) and a resume file (optimiser state, step) are written atomically every N steps.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .components import TrainableMatcher
from .data.base import Dataset
from .errors import I2PBenchError, PluginError
from .metrics import pose_errors, summarize
from .pipeline import Pipeline
from .protocol import Protocol
from .types import Features, Frame, Keypoints3D
from .weights import load_checkpoint, save_checkpoint

Report = Callable[[int, dict[str, float]], None]


@dataclass(frozen=True)
class TrainConfig:
    steps: int = 20000
    lr: float = 1e-4  # Adam; the reference code uses 1e-5
    grad_clip: float = 1.0
    checkpoint_every: int = 250
    validate_every: int = 1000
    val_frames: int = 20
    seed: int = 0
    device: str = "auto"  # "auto": cuda when available


def pick_device(choice: str) -> torch.device:
    if choice == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(choice)


def _resume_path(out: Path) -> Path:
    return out.with_name(out.name + ".resume")


def check_trainable(pipeline: Pipeline) -> TrainableMatcher:
    matcher = pipeline.stages["matcher"]
    if not isinstance(matcher, TrainableMatcher):
        raise PluginError(f"{matcher.label} has no training loss; choose a trainable matcher")
    if not pipeline.learned_modules():
        raise PluginError(f"combination {pipeline.combination.label!r} has no learned stage to train")
    return matcher


def forward_features(pipeline: Pipeline, frame: Frame, kp2d, kp3d) -> Features:
    """The learned part of the pipeline, with gradients; stages see no ground truth."""
    hidden, s = frame.without_ground_truth(), pipeline.stages
    d2 = s["encoder2d"](hidden, kp2d) if "encoder2d" in s else None
    d3 = s["encoder3d"](hidden, kp3d) if "encoder3d" in s else None
    features = Features(d2, d3)
    return s["exchanger"](hidden, kp2d, kp3d, features) if "exchanger" in s else features


class Trainer:
    def __init__(
        self, pipeline: Pipeline, train_set: Dataset, val_set: Dataset | None, out: Path, config: TrainConfig
    ) -> None:
        self.pipeline, self.train_set, self.val_set, self.out, self.config = pipeline, train_set, val_set, out, config
        self.matcher = check_trainable(pipeline)
        self.device = pick_device(config.device)
        pipeline.to(self.device)
        self.params = [p for m in pipeline.learned_modules().values() for p in m.parameters()]
        self.optimizer = torch.optim.Adam(self.params, lr=config.lr)
        self.train_ids = train_set.frame_ids()
        self.step, self.seconds, self.validation = 0, 0.0, {}
        self._keypoints: dict[str, tuple] = {}

    def resume(self) -> bool:
        """Continue from the last checkpoint: exactly with its resume file (optimiser state), or from its weights and
        step with a fresh optimiser when only the checkpoint travelled (resume files are not committed)."""
        if not self.out.is_file():
            return False
        checkpoint = load_checkpoint(self.out)
        for kind, module in self.pipeline.learned_modules().items():
            module.load_state_dict(checkpoint.state[kind])
        self.step = int(checkpoint.meta.get("steps", 0))
        self.seconds = float(checkpoint.meta.get("train_seconds", 0.0))
        self.validation = checkpoint.meta.get("validation", {})
        state_path = _resume_path(self.out)
        if state_path.is_file():
            state = torch.load(state_path, map_location=self.device, weights_only=True)
            if int(state["step"]) == self.step:
                self.optimizer.load_state_dict(state["optimizer"])
        return True

    def sample(self, step: int) -> Frame:
        """The step's frame and transform: a pure function of (seed, step), so resuming is exact."""
        rng = np.random.default_rng([self.config.seed, step])
        frame_id = self.train_ids[int(rng.integers(len(self.train_ids)))]
        protocol = Protocol(seed=self.config.seed * 1_000_003 + step)
        return protocol.apply(self.train_set.load(frame_id))

    def keypoints(self, frame: Frame):
        """Extractor outputs depend on the image and the scan order only, never on the transform: cache indices."""
        s = self.pipeline.stages
        if frame.frame_id not in self._keypoints:
            hidden = frame.without_ground_truth()
            self._keypoints[frame.frame_id] = (s["extractor2d"](hidden), s["extractor3d"](hidden).index)
        kp2d, index3d = self._keypoints[frame.frame_id]
        return kp2d, Keypoints3D.from_index(frame, index3d)

    def train_step(self, step: int) -> dict[str, float]:
        frame = self.sample(step)
        kp2d, kp3d = self.keypoints(frame)
        for module in self.pipeline.learned_modules().values():
            module.train()
        features = forward_features(self.pipeline, frame, kp2d, kp3d)
        loss, terms = self.matcher.loss(frame, kp2d, kp3d, features)
        self.optimizer.zero_grad(set_to_none=True)
        if torch.isfinite(loss) and loss.requires_grad:
            loss.backward()
            torch.nn.utils.clip_grad_norm_(self.params, self.config.grad_clip)
            self.optimizer.step()
        return {"loss": float(loss.detach()), **{k: float(v) for k, v in terms.items()}}

    def validate(self) -> dict[str, float]:
        """Acc./RTE/RRE of the full pipeline (solver included) on the first val frames, protocol seed 0."""
        if self.val_set is None:
            return {}
        self.pipeline.eval()
        protocol, rte, rre = Protocol(), [], []
        for frame_id in self.val_set.frame_ids()[: self.config.val_frames]:
            frame = protocol.apply(self.val_set.load(frame_id))
            errors = pose_errors(self.pipeline.run(frame).estimate.T, frame.T_gt)
            rte.append(errors.rte_m)
            rre.append(errors.rre_deg)
        stats = summarize(rte, rre, protocol)
        return {"step": self.step, "frames": len(rte), **{k: v for k, v in stats.items() if not math.isnan(v)}}

    def save(self, meta: dict[str, Any]) -> None:
        save_checkpoint(
            self.out,
            self.pipeline,
            steps=self.step,
            train_seconds=round(self.seconds, 1),
            validation=self.validation,
            **meta,
        )
        tmp = _resume_path(self.out).with_suffix(".tmp")
        torch.save({"optimizer": self.optimizer.state_dict(), "step": self.step, "seconds": self.seconds}, tmp)
        os.replace(tmp, _resume_path(self.out))

    def run(self, meta: dict[str, Any], report: Report | None = None) -> None:
        c = self.config
        while self.step < c.steps:
            start = time.perf_counter()
            try:
                terms = self.train_step(self.step)
            except I2PBenchError as exc:  # a broken training frame is skipped, not fatal
                terms = {"skipped": 1.0, "error": str(exc)[:200]}  # type: ignore[dict-item]
            self.step += 1
            self.seconds += time.perf_counter() - start
            if report:
                report(self.step, terms)
            if self.step % c.validate_every == 0 or self.step == c.steps:
                self.validation = self.validate()
                if report and self.validation:
                    report(self.step, {f"val_{k}": v for k, v in self.validation.items()})
            if self.step % c.checkpoint_every == 0 or self.step == c.steps:
                self.save(meta)


def training_meta(train_set: Dataset, config: TrainConfig) -> dict[str, Any]:
    trained_on = {**train_set.identity(), "frames": len(train_set.frame_ids())}
    return {"trained_on": trained_on, "train_config": asdict(config)}
