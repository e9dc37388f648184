"""The simulated HDL-64E scan, written point by point in the order KITTI's velodyne files use."""

from __future__ import annotations

import numpy as np

from .raycast import Caster, surface
from .rig import LIDAR_HEIGHT, Lidar


def scan(caster: Caster, lidar: Lidar, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Points [N x 4] float32 (x, y, z in the LiDAR frame, reflectance) and their ring [N] int16.

    Rows are ring by ring (top beam first), each ring in azimuth order; misses, returns beyond max range and a few
    random drop-outs are removed without reordering, as in a real sweep.
    """
    dirs = lidar.directions().reshape(-1, 3)
    ring = np.repeat(np.arange(len(lidar.elevations_deg), dtype=np.int16), lidar.steps)
    origin = np.array([0.0, 0.0, LIDAR_HEIGHT])
    hits = caster.cast(origin, dirs)
    keep = np.flatnonzero((hits.t < lidar.max_range) & (rng.random(len(hits.t)) > 0.01))
    rows = hits.rows[keep]
    _, refl = surface(caster.scene, hits, keep)
    cos_inc = -np.einsum("ij,ij->i", hits.normals[keep], dirs[rows])
    refl = refl * (0.6 + 0.4 * cos_inc) + rng.normal(0, 0.015, len(rows))
    noise = np.clip(rng.normal(0, lidar.range_noise, len(rows)), -3 * lidar.range_noise, 3 * lidar.range_noise)
    xyz = dirs[rows] * (hits.t[keep] + noise)[:, None]
    points = np.concatenate([xyz, np.round(np.clip(refl, 0, 1), 2)[:, None]], axis=1).astype(np.float32)
    return points, ring[rows]
