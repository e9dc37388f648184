"""Ray casting against the scene mesh and evaluation of the surface each ray hits.

Both sensors go through `surface()`, so the camera's albedo and the LiDAR's reflectance at a world point come from
the same texture call on the same triangle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from .scene import Scene
from .textures import evaluate


@dataclass(frozen=True)
class Hits:
    """The rays that hit something; every field is indexed by hit, `rows` says which input ray it was."""

    rows: np.ndarray  # [M] int64 indices of the rays that hit
    t: np.ndarray  # [M] float64 distance along the unit direction
    tri: np.ndarray  # [M] int64 triangle id
    points: np.ndarray  # [M x 3] float64 world hit points
    normals: np.ndarray  # [M x 3] float64 unit normals turned towards the ray origin


class Caster:
    """One RaycastingScene per scene; `nthreads=1` keeps worker processes from oversubscribing the cores."""

    def __init__(self, scene: Scene, nthreads: int = 0) -> None:
        self.scene = scene
        self.nthreads = nthreads
        self._rc = o3d.t.geometry.RaycastingScene()
        self._rc.add_triangles(o3d.core.Tensor(scene.mesh.vertices), o3d.core.Tensor(scene.mesh.triangles))

    def cast(self, origin: np.ndarray, directions: np.ndarray) -> Hits:
        """One origin [3] and unit directions [N x 3]."""
        rays = np.empty((len(directions), 6), np.float32)
        rays[:, :3] = origin
        rays[:, 3:] = directions
        out = self._rc.cast_rays(o3d.core.Tensor(rays), nthreads=self.nthreads)
        t = out["t_hit"].numpy()
        rows = np.flatnonzero(np.isfinite(t))
        t = t[rows].astype(np.float64)
        tri = out["primitive_ids"].numpy()[rows].astype(np.int64)
        dirs = directions[rows]
        normals = self.scene.mesh.normal[tri]
        flip = np.einsum("ij,ij->i", normals, dirs) > 0
        normals[flip] *= -1
        return Hits(rows=rows, t=t, tri=tri, points=origin + dirs * t[:, None], normals=normals)

    def occluded(self, origins: np.ndarray, direction: np.ndarray, t_far: float = 500.0) -> np.ndarray:
        """[N] bool: whether something lies between each origin and t_far along one direction (sun shadows)."""
        rays = np.empty((len(origins), 6), np.float32)
        rays[:, :3] = origins
        rays[:, 3:] = direction
        out = self._rc.test_occlusions(o3d.core.Tensor(rays), tnear=0.02, tfar=t_far, nthreads=self.nthreads)
        return out.numpy().astype(bool)


def surface(scene: Scene, hits: Hits, keep: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Albedo [K x 3] and reflectance [K] at the hits selected by `keep` (indices into the hits; default all)."""
    sel = slice(None) if keep is None else keep
    tri, points = hits.tri[sel], hits.points[sel]
    mesh = scene.mesh
    rel = points - mesh.origin[tri]
    u = np.einsum("ij,ij->i", rel, mesh.u_axis[tri])
    v = np.einsum("ij,ij->i", rel, mesh.v_axis[tri])
    mat = mesh.material[tri]
    order = np.argsort(mat, kind="stable")
    bounds = np.flatnonzero(np.diff(mat[order])) + 1
    albedo, refl = np.zeros((len(tri), 3)), np.zeros(len(tri))
    for group in np.split(order, bounds):
        if len(group):
            albedo[group], refl[group] = evaluate(scene.materials[mat[group[0]]], u[group], v[group])
    return albedo, refl
