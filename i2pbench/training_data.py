"""Training samples as a torch Dataset keyed by a global sample index, and a per-frame cache on disk.

Sample i's frame and protocol transform are a pure function of (seed, i), so a resumed run, another worker count or
another number of DDP ranks sees the same sequence. Everything heavy for one sample (loading, extraction, each learned
stage's `prepare`) runs inside `__getitem__`, i.e. in DataLoader workers, never in the training loop.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .augment import augmenter
from .batching import LEARNED_KINDS, collate, length_mask, prepare_stage
from .components import Component
from .data.base import Dataset
from .pipeline import extract
from .protocol import Protocol
from .types import Frame, Keypoints2D, Keypoints3D

EXTRACTOR_KINDS = ("extractor2d", "extractor3d")


def signature(stage: Component) -> dict[str, Any]:
    return {"name": stage.name, "conf": json.loads(json.dumps(stage.conf, default=str))}


def digest(value: Any) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()[:16]


class FrameCache:
    """Per-frame dicts of tensors under root/key/, written atomically (temp + rename) so concurrent workers and
    processes share them safely; with no root, a dict in this process (tests, one-off runs)."""

    def __init__(self, root: str | Path | None, key: str) -> None:
        self.folder = Path(root) / key if root else None
        self.memory: dict[str, dict] = {}

    def _path(self, frame_id: str) -> Path:
        assert self.folder is not None
        return self.folder / (hashlib.sha256(frame_id.encode()).hexdigest()[:24] + ".pt")

    def get(self, frame_id: str) -> dict | None:
        if self.folder is None:
            return self.memory.get(frame_id)
        path = self._path(frame_id)
        if not path.is_file():
            return None
        try:
            return torch.load(path, map_location="cpu", weights_only=True)
        except Exception:  # a torn or foreign file is recomputed, never trusted
            return None

    def put(self, frame_id: str, entry: dict) -> None:
        if self.folder is None:
            self.memory[frame_id] = entry
            return
        self.folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self.folder, suffix=".tmp")
        os.close(fd)
        try:
            torch.save(entry, tmp)
            os.replace(tmp, self._path(frame_id))
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)


class TrainingSamples(torch.utils.data.Dataset):
    """Item i: one training frame under a fresh protocol transform, extracted and prepared for every learned stage."""

    def __init__(
        self,
        stages: Mapping[str, Component],
        dataset: Dataset,
        seed: int,
        cache_root: str | Path | None = None,
        stage_cache: bool = True,
        epochs: bool = False,
        augment: str = "none",
    ) -> None:
        """`stage_cache` False recomputes the stages' transform-free inputs (grouping) every time: the old loop.
        `epochs`: samples go through the split in passes, each a permutation seeded by (seed, epoch), instead of
        drawing a frame at random for every sample. `augment`: see augment.py, drawn per sample index."""
        self.stage_cache, self.epochs, self.augment = stage_cache, epochs, augmenter(augment)
        self.stages = {k: stages[k] for k in (*EXTRACTOR_KINDS, *LEARNED_KINDS) if k in stages}
        self.dataset, self.seed = dataset, seed
        self.frame_ids = dataset.frame_ids()
        base = {"data": dataset.identity(), **{k: signature(stages[k]) for k in EXTRACTOR_KINDS}}
        self.keypoint_cache = FrameCache(cache_root, "keypoints-" + digest(base))
        self.stage_caches = {
            k: FrameCache(cache_root, f"{k}-" + digest({**base, k: signature(self.stages[k])}))
            for k in LEARNED_KINDS
            if k in self.stages
        }

    def __len__(self) -> int:
        return 2**62  # items are a function of the index; samplers choose the range

    def frame(self, index: int) -> Frame:
        """sample index's frame and transform: a pure function of (seed, index)."""
        n = len(self.frame_ids)
        if self.epochs:
            epoch, position = divmod(index, n)
            frame_id = self.frame_ids[int(np.random.default_rng([self.seed, epoch, n]).permutation(n)[position])]
        else:
            frame_id = self.frame_ids[int(np.random.default_rng([self.seed, index]).integers(n))]
        return Protocol(seed=self.seed * 1_000_003 + index).apply(self.dataset.load(frame_id))

    def keypoints(self, frame: Frame) -> tuple[Keypoints2D, Keypoints3D]:
        """extractor outputs depend on the image and the scan order only, never on the transform: cached per frame.
        They come through the pipeline's path (`pipeline.extract`), contract checks included."""
        entry = self.keypoint_cache.get(frame.frame_id)
        if entry is None:
            kp2d, kp3d = extract(self.stages, frame)
            uv = np.asarray(kp2d.uv, np.float32)
            index = np.asarray(kp3d.index, np.int64)
            entry = {"uv": torch.from_numpy(uv), "index3d": torch.from_numpy(index)}
            self.keypoint_cache.put(frame.frame_id, entry)
        return Keypoints2D(entry["uv"].numpy()), Keypoints3D.from_index(frame, entry["index3d"].numpy())

    def __getitem__(self, index: int) -> dict[str, Any]:
        """the prepared sample, or {"error": ...} for a broken frame (skipped by `collate_samples`, never fatal)."""
        try:
            frame = self.frame(index)
            kp2d, kp3d = self.keypoints(frame)
            if self.augment is not None:  # after extraction: the edges stay where the clean image has them
                rng = np.random.default_rng([self.seed, index, 7])
                frame = dataclasses.replace(frame, image=self.augment(frame.image, rng))
            inputs = {kind: self._prepare(kind, frame, kp2d, kp3d) for kind in self.stage_caches}
        except Exception as exc:  # noqa: BLE001 - one broken frame must not stop a training run
            return {"index": index, "error": f"{type(exc).__name__}: {exc}"[:300]}
        return {"index": index, "inputs": inputs, "n2d": len(kp2d), "n3d": len(kp3d)}

    def _prepare(self, kind: str, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D) -> dict[str, Any]:
        if not self.stage_cache:
            return prepare_stage(kind, self.stages[kind], frame, kp2d, kp3d, None)
        cache = self.stage_caches[kind]
        stored = cache.get(frame.frame_id)
        entry = dict(stored or {})
        inputs = prepare_stage(kind, self.stages[kind], frame, kp2d, kp3d, entry)
        if entry and entry.keys() != (stored or {}).keys():
            cache.put(frame.frame_id, entry)
        return inputs


def collate_samples(items: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """samples -> one padded batch with keypoint masks; broken samples are dropped and their errors kept."""
    good = [item for item in items if "error" not in item]
    errors = [item["error"] for item in items if "error" in item]
    if not good:
        return {"size": 0, "errors": errors}
    n2 = torch.tensor([item["n2d"] for item in good])
    n3 = torch.tensor([item["n3d"] for item in good])
    inputs = {kind: collate([item["inputs"][kind] for item in good]) for kind in good[0]["inputs"]}
    masks = (length_mask(n2, int(n2.max())), length_mask(n3, int(n3.max())))
    return {"size": len(good), "errors": errors, "inputs": inputs, "masks": masks}
