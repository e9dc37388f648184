"""The simulated HDL-64E scan, written point by point in the order KITTI's velodyne files use."""

from __future__ import annotations

import numpy as np

from .raycast import Caster, surface
from .rig import Lidar
from .style import DEFAULT, Style


def scan(
    caster: Caster, lidar: Lidar, rng: np.random.Generator, style: Style = DEFAULT
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points [N x 4] float32 (x, y, z in the LiDAR frame, reflectance), their ring [N] int16 and azimuth step [N].

    Rows are ring by ring, each ring in sweep order (KITTI's file order); misses, returns beyond max range and a few
    random drop-outs are removed without reordering, as in a real sweep.
    """
    dirs = lidar.directions.reshape(-1, 3)
    ring = np.repeat(np.arange(len(lidar.elevations_deg), dtype=np.int16), lidar.steps)
    step = np.tile(np.arange(lidar.steps), len(lidar.elevations_deg))
    R, origin = lidar.pose[:3, :3], lidar.pose[:3, 3]
    world = np.einsum("ij,kj->ik", dirs, R)
    hits = caster.cast(origin, world)
    keep = np.flatnonzero((hits.t < lidar.max_range) & (rng.random(len(hits.t)) > 0.01))
    rows = hits.rows[keep]
    _, albedo_ir = surface(caster.scene, hits, keep)
    cos_inc = -np.einsum("ij,ij->i", hits.normals[keep], world[rows])
    t = hits.t[keep]
    noise = np.clip(rng.normal(0, lidar.range_noise, len(rows)), -3 * lidar.range_noise, 3 * lidar.range_noise)
    t = t + noise + _porosity(caster, hits.tri[keep], rng, style.foliage_depth)
    refl = _reflectance(albedo_ir, cos_inc, t, rng, style.reflectance_offset, style.reflectance_floor)
    points = np.concatenate([dirs[rows] * t[:, None], refl[:, None]], axis=1).astype(np.float32)
    return points, ring[rows], step[rows]


def _reflectance(
    albedo_ir: np.ndarray,
    cos_inc: np.ndarray,
    t: np.ndarray,
    rng: np.random.Generator,
    offset: float = 0.0,
    floor: float = 0.0,
) -> np.ndarray:
    """KITTI-like intensity: falls with incidence and range, speckled, floored to 0 on weak far returns, 2 decimals.

    Fitted by eye to KITTI's scans: road ~0.25-0.3 near the car, neighbouring-point differences of a few hundredths
    on uniform surfaces, and a third or more of the returns beyond 30 m reading exactly 0. A style's `offset` lowers
    every return and its `floor` zeroes the ones below it, so more weak returns read 0.
    """
    falloff = 1.0 / (1.0 + (t / 35.0) ** 2)
    speckle = np.exp(rng.normal(0, 0.2, len(t)))
    refl = 1.3 * albedo_ir * (0.6 + 0.4 * np.abs(cos_inc)) * falloff * speckle - 0.04 + rng.normal(0, 0.02, len(t))
    refl = refl - offset
    refl[refl < floor] = 0.0  # below a floor of 0 the clip does the same
    return np.round(np.clip(refl, 0, 1), 2)


def _porosity(caster: Caster, tri: np.ndarray, rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    """Extra range for returns from porous surfaces (foliage): the beam goes some way into the crown (a style's
    `foliage_depth` scales how far)."""
    depth = np.array([m.params.get("porosity", 0.0) for m in caster.scene.materials])[caster.scene.mesh.material[tri]]
    return rng.exponential(1.0, len(tri)) * depth * scale
