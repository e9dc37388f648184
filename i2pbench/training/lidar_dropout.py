"""LiDAR dropout for training: a random share of the scan's points and of its whole rings removed per sample.

Domain randomisation against the gap between a clean simulated scan and a real one (returns lost on dark or shiny
surfaces, dead or masked lasers of an HDL-64). Applied after extraction, like the photometric augmentation, and this
is the design that is correct with the caches: the 3D extractor's output is cached per frame as rows of the full scan
(`Keypoints3D.from_index`). Dropping points before extraction would need the cache keyed by the draw, i.e. no cache
(a frame is almost never drawn twice with one dropout), and a fixed extractor's response to sparse scans is nothing
training can change anyway. So the cached keypoints are computed on the full scan, then the dropped rows are removed
from the scan and from the keypoints, and the kept keypoints are re-indexed into the thinned scan: each still points
at the same 3D coordinates. What the learned stages see, the context cloud and the keypoints, is thinned; the ground
truth is untouched (no point moves). What it does not model: the edges an extractor would find on a sparse scan.
A sample with dropout must not use the per-frame cache of the stages' `prepare` (e.g. point grouping), which belongs
to the full scan; `TrainingSamples` prepares such samples afresh.

Rings are `Frame.ring`, the laser index each dataset gives (KITTI and the synthetic set recover it from the scan
order, data/scanlines.py; nuScenes stores it), not elevation angles: the protocol has already moved the scan off
the sensor's origin, so an elevation measured now would not be the laser's.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..types import Frame, Keypoints3D


@dataclass(frozen=True)
class LidarDropout:
    """ranges the shares are drawn from, uniformly, per sample."""

    point_share: tuple[float, float] = (0.0, 0.3)  # of the points, each dropped independently
    ring_share: tuple[float, float] = (0.0, 0.25)  # of the rings, dropped whole (at least one ring always stays)

    def keep(self, ring: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """[N] ring index -> [N] bool, True for the points that stay."""
        rings = np.unique(ring)
        count = min(int(rng.uniform(*self.ring_share) * len(rings)), len(rings) - 1)
        dropped = rng.choice(rings, count, replace=False)
        share = rng.uniform(*self.point_share)
        return ~np.isin(ring, dropped) & (rng.random(len(ring)) >= share)

    def __call__(self, frame: Frame, kp3d: Keypoints3D, rng: np.random.Generator) -> tuple[Frame, Keypoints3D]:
        """the frame with a drawn share of its scan removed, and its 3D keypoints on what stays."""
        return thin(frame, kp3d, self.keep(frame.ring, rng))


def thin(frame: Frame, kp3d: Keypoints3D, keep: np.ndarray) -> tuple[Frame, Keypoints3D]:
    """Keep the scan rows where `keep` [N] is True; keypoints on dropped rows go, the others are re-indexed into the
    thinned scan (same coordinates and reflectance). T_gt, K and the image stay as they are."""
    row = np.cumsum(keep) - 1  # a kept row's place in the thinned scan
    thinned = dataclasses.replace(frame, points=frame.points[keep], ring=frame.ring[keep], ranges=frame.ranges[keep])
    return thinned, Keypoints3D.from_index(thinned, row[kp3d.index[keep[kp3d.index]]])
