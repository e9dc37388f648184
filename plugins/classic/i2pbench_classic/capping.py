"""The seeded rule that caps how many keypoints an extractor returns, shared by the 2D and 3D extractors.

Rule: when there are more than `max_keypoints` candidates, keep a uniform random subset without replacement drawn from
a generator seeded by sha256(seed, dataset, frame id), then sort the kept positions so the output keeps the
candidates' order (raster order for pixels, point order for LiDAR points). Seeding per frame, not per run, makes every
frame's keypoints independent of run order and of which other frames run.
"""

from __future__ import annotations

import hashlib

import numpy as np

from i2pbench.api import Frame

# numpy's Generator.choice(n, k, replace=False) draws by Floyd's algorithm unless n > 10,000 and k > n // 50 (a
# shuffle of the tail of arange(n)); on Floyd's branch `shuffle=False` keeps the same set and skips a shuffle of the k
# drawn values, which the sort undoes anyway. tests/test_extractor_kernels.py holds this to the plain call.
FLOYD_MAX_POPULATION = 10_000
FLOYD_MAX_FRACTION = 50

# below this many candidates per kept one, sorting by marking a [candidates] mask beats a comparison sort
MASK_SORT_MAX_RATIO = 32


def frame_seed(seed: int, frame: Frame) -> np.ndarray:
    """[8] uint32: the words of sha256(seed, dataset, frame id)."""
    digest = hashlib.sha256(f"{seed}\x00{frame.dataset}\x00{frame.frame_id}".encode()).digest()
    return np.frombuffer(digest, dtype=np.uint32)


def frame_rng(seed: int, frame: Frame) -> np.random.Generator:
    """A generator that depends only on (seed, dataset, frame id). SeedSequence takes the words as a uint32 array 4x
    faster than as a list of ints, to the same state."""
    return np.random.default_rng(frame_seed(seed, frame))


def sorted_positions(keep: np.ndarray, candidates: int) -> np.ndarray:
    """The distinct positions `keep` (each < candidates) in increasing order, int64."""
    if candidates <= MASK_SORT_MAX_RATIO * keep.size:
        mask = np.zeros(candidates, dtype=bool)
        mask[keep] = True
        return np.flatnonzero(mask).astype(np.int64, copy=False)
    if candidates <= np.iinfo(np.int32).max:  # int32 keys sort about 2x faster than int64
        return np.sort(keep.astype(np.int32)).astype(np.int64)
    return np.sort(keep).astype(np.int64, copy=False)


def cap(candidates: int, max_keypoints: int | None, seed: int, frame: Frame) -> np.ndarray:
    """Sorted positions (into the candidate list) of the candidates kept; all of them when under the cap."""
    if max_keypoints is None or candidates <= max_keypoints:
        return np.arange(candidates, dtype=np.int64)
    size = int(max_keypoints)
    floyd = candidates <= FLOYD_MAX_POPULATION or size <= candidates // FLOYD_MAX_FRACTION
    keep = frame_rng(seed, frame).choice(candidates, size=size, replace=False, shuffle=not floyd)
    return sorted_positions(keep, candidates)
