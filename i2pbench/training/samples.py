"""Training samples as a torch Dataset keyed by a global sample index, and a per-frame cache on disk.

Sample i's source (with `--mix`, mix.py), frame and protocol transform are a pure function of (seed, i), so
a resumed run, another worker count or another number of DDP ranks sees the same sequence. Everything heavy for one
sample (loading, extraction, each learned stage's `prepare`) runs inside `__getitem__`, i.e. in DataLoader workers,
never in the training loop.

Each source has caches of its own, keyed by its dataset identity and the stages' configs, so frame ids can never
collide between sources (synthetic "00/000000" and KITTI "00/000000" live under different keys), and the main
dataset's entries are the very ones a run without a mix computes and reuses.
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

from .. import layers
from ..data.base import Dataset
from ..scoring.protocol import Protocol
from ..stages.components import Component
from ..stages.pipeline import extract
from ..types import Frame, Keypoints2D, Keypoints3D
from .augment import augmentations
from .batching import LEARNED_KINDS, collate, length_mask, prepare_stage
from .mix import MixedSource, choose_source

EXTRACTOR_KINDS = ("extractor2d", "extractor3d")


def signature(stage: Component) -> dict[str, Any]:
    described = {"name": stage.name, "conf": json.loads(json.dumps(stage.conf, default=str))}
    used = layers.revisions(stage)  # a bumped shared layer (the grouping, say) refills the cache
    return {**described, "layers": used} if used else described


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


class Source:
    """one dataset split samples are drawn from, with its per-frame caches."""

    def __init__(self, stages: Mapping[str, Component], dataset: Dataset, cache_root: str | Path | None) -> None:
        self.dataset, self.frame_ids = dataset, dataset.frame_ids()
        base = {"data": dataset.identity(), **{k: signature(stages[k]) for k in EXTRACTOR_KINDS}}
        self.keypoint_cache = FrameCache(cache_root, "keypoints-" + digest(base))
        self.stage_caches = {
            k: FrameCache(cache_root, f"{k}-" + digest({**base, k: signature(stages[k])}))
            for k in LEARNED_KINDS
            if k in stages
        }


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
        mix: Sequence[MixedSource] = (),
    ) -> None:
        """`stage_cache` False recomputes the stages' transform-free inputs (grouping) every time: the old loop.
        `epochs`: samples go through the split in passes, each a permutation seeded by (seed, epoch), instead of
        drawing a frame at random for every sample. `augment`: see augment.py, drawn per sample index. `mix`: other
        datasets, each supplying its share of the samples (mix.py); not with `epochs`, whose passes are
        over one split."""
        if epochs and mix:
            raise ValueError("epochs pass over one split; with mixed-in datasets give a number of steps")
        self.stage_cache, self.epochs, self.augment = stage_cache, epochs, augmentations(augment)
        self.stages = {k: stages[k] for k in (*EXTRACTOR_KINDS, *LEARNED_KINDS) if k in stages}
        self.dataset, self.seed = dataset, seed
        self.sources = [Source(self.stages, d, cache_root) for d in (dataset, *(m.dataset for m in mix))]
        self.shares = [m.share for m in mix]

    def __len__(self) -> int:
        return 2**62  # items are a function of the index; samplers choose the range

    def source(self, index: int) -> int:
        """sample index's source: 0 the main dataset, k the k-th mixed-in one; a pure function of (seed, index)."""
        return choose_source(self.shares, self.seed, index)

    def frame(self, index: int) -> Frame:
        """sample index's frame and transform: a pure function of (seed, index)."""
        source = self.sources[self.source(index)]
        frame_id = self._frame_id(source.frame_ids, index)
        return Protocol(seed=self.seed * 1_000_003 + index).apply(source.dataset.load(frame_id))

    def _frame_id(self, ids: list[str], index: int) -> str:
        n = len(ids)
        if self.epochs:
            epoch, position = divmod(index, n)
            return ids[int(np.random.default_rng([self.seed, epoch, n]).permutation(n)[position])]
        return ids[int(np.random.default_rng([self.seed, index]).integers(n))]

    def keypoints(self, frame: Frame, source: int = 0) -> tuple[Keypoints2D, Keypoints3D]:
        """extractor outputs depend on the image and the scan order only, never on the transform: cached per frame
        of each source. They come through the pipeline's path (`pipeline.extract`), contract checks included."""
        cache = self.sources[source].keypoint_cache
        entry = cache.get(frame.frame_id)
        if entry is None:
            kp2d, kp3d = extract(self.stages, frame)
            uv = np.asarray(kp2d.uv, np.float32)
            index = np.asarray(kp3d.index, np.int64)
            entry = {"uv": torch.from_numpy(uv), "index3d": torch.from_numpy(index)}
            cache.put(frame.frame_id, entry)
        return Keypoints2D(entry["uv"].numpy()), Keypoints3D.from_index(frame, entry["index3d"].numpy())

    def __getitem__(self, index: int) -> dict[str, Any]:
        """the prepared sample, or {"error": ...} for a broken frame (skipped by `collate_samples`, never fatal)."""
        try:
            source = self.source(index)
            frame = self.frame(index)
            kp2d, kp3d = self.keypoints(frame, source)
            frame, kp3d = self._augmented(index, frame, kp3d)
            # a thinned scan is not the one the stages' per-frame cache (grouping) was computed on
            caches = None if self.augment.lidar is not None else self.sources[source].stage_caches
            inputs = {kind: self._prepare(kind, frame, kp2d, kp3d, caches) for kind in self.sources[0].stage_caches}
        except Exception as exc:  # noqa: BLE001 - one broken frame must not stop a training run
            return {"index": index, "error": f"{type(exc).__name__}: {exc}"[:300]}
        return {"index": index, "inputs": inputs, "n2d": len(kp2d), "n3d": len(kp3d)}

    def _augmented(self, index: int, frame: Frame, kp3d: Keypoints3D) -> tuple[Frame, Keypoints3D]:
        """after extraction: the edges stay where the clean frame has them; each augmentation its own generator."""
        if self.augment.image is not None:
            rng = np.random.default_rng([self.seed, index, 7])
            frame = dataclasses.replace(frame, image=self.augment.image(frame.image, rng))
        if self.augment.lidar is not None:
            frame, kp3d = self.augment.lidar(frame, kp3d, np.random.default_rng([self.seed, index, 11]))
        return frame, kp3d

    def _prepare(
        self, kind: str, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, caches: Mapping[str, FrameCache] | None
    ) -> dict[str, Any]:
        if not self.stage_cache or caches is None:
            return prepare_stage(kind, self.stages[kind], frame, kp2d, kp3d, None)
        cache = caches[kind]
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
