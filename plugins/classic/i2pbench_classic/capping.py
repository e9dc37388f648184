"""The seeded rule that caps how many keypoints an extractor returns, shared by the 2D and 3D extractors.

Rule: when there are more than `max_keypoints` candidates, keep a uniform random subset without replacement drawn from
a generator seeded by sha256(seed, dataset, frame id), then sort the kept positions so the output keeps the
candidates' order (raster order for pixels, point order for LiDAR points). Seeding per frame, not per run, makes every
frame's keypoints independent of run order and of which other frames run.
"""

from __future__ import annotations

import hashlib

import numpy as np

from i2pbench.types import Frame


def frame_rng(seed: int, frame: Frame) -> np.random.Generator:
    """A generator that depends only on (seed, dataset, frame id)."""
    digest = hashlib.sha256(f"{seed}\x00{frame.dataset}\x00{frame.frame_id}".encode()).digest()
    return np.random.default_rng(np.frombuffer(digest, dtype=np.uint32).tolist())


def cap(candidates: int, max_keypoints: int | None, seed: int, frame: Frame) -> np.ndarray:
    """Sorted positions (into the candidate list) of the candidates kept; all of them when under the cap."""
    if max_keypoints is None or candidates <= max_keypoints:
        return np.arange(candidates, dtype=np.int64)
    keep = frame_rng(seed, frame).choice(candidates, size=int(max_keypoints), replace=False)
    return np.sort(keep).astype(np.int64)
