"""Triangle soup with a texture frame per triangle, so any hit point can be turned into 2D texture coordinates.

Every triangle carries a material id and a frame (origin, u axis, v axis): the texture coordinates of a hit point p
are ((p - origin) . u_axis, (p - origin) . v_axis) in metres. Faces of one box side share a frame, so textures run
continuously across the two triangles of a quad and painted edges land at the same world place for camera and LiDAR.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Mesh:
    """A finished scene mesh: arrays indexed by triangle id (the ray caster's primitive id)."""

    vertices: np.ndarray  # [V x 3] float32 world metres
    triangles: np.ndarray  # [T x 3] uint32
    material: np.ndarray  # [T] int32 index into the scene's material list
    origin: np.ndarray  # [T x 3] float64 texture frame origin
    u_axis: np.ndarray  # [T x 3] float64 unit vector
    v_axis: np.ndarray  # [T x 3] float64 unit vector
    normal: np.ndarray  # [T x 3] float64 unit geometric normal (sign arbitrary; shading faces it to the ray)


class MeshBuilder:
    """Accumulates quads, boxes and prisms; `build()` returns one Mesh for a single ray-casting geometry.

    Quads are stored as rows of numbers and turned into triangles in one vectorised step, because a scene has
    thousands of them and per-quad numpy calls dominated the scene-building time.
    """

    def __init__(self) -> None:
        self._quads: list[tuple] = []  # (p0, a, b, origin, u_axis, v_axis, material)
        self._soups: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []  # (verts, tris, frames, mats)

    def quad(self, p0, a, b, material: int, origin=None, u_axis=None, v_axis=None) -> None:
        """Parallelogram p0, p0+a, p0+a+b, p0+b; texture frame defaults to (p0, a/|a|, b/|b|)."""
        self._quads.append(
            (
                p0,
                a,
                b,
                p0 if origin is None else origin,
                a if u_axis is None else u_axis,
                b if v_axis is None else v_axis,
                material,
            )
        )

    def box(
        self, center, size, yaw: float, z0: float, side: int, top: int | None = None, bottom_ref: float = 0.0
    ) -> None:
        """Upright box; side faces get v = height above `bottom_ref` (world z) and u = metres along the face."""
        cx, cy = center
        lx, ly, lz = size
        ex = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        ey = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
        up = np.array([0.0, 0.0, lz])
        c0 = np.array([cx, cy, z0]) - ex * lx / 2 - ey * ly / 2
        corners = [c0, c0 + ex * lx, c0 + ex * lx + ey * ly, c0 + ey * ly]
        edges = [ex * lx, ey * ly, -ex * lx, -ey * ly]
        for corner, edge in zip(corners, edges, strict=True):
            origin = np.array([corner[0], corner[1], bottom_ref])
            self.quad(corner, edge, up, side, origin=origin, v_axis=[0.0, 0.0, 1.0])
        top_mat = side if top is None else top
        self.quad(c0 + up, ex * lx, ey * ly, top_mat)

    def prism(self, center, radius: float, z0: float, height: float, material: int, sides: int = 8) -> None:
        """Upright regular prism (poles, trunks); u runs around the circumference, v is world height."""
        angles = np.linspace(0, 2 * np.pi, sides + 1)
        ring = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], 1) * radius
        base = np.array([center[0], center[1], z0])
        chord = 2 * radius * np.sin(np.pi / sides)
        for i in range(sides):
            edge = ring[i + 1] - ring[i]
            origin = base + ring[i] - _units(edge) * chord * i
            origin[2] = 0.0
            self.quad(base + ring[i], edge, [0, 0, height], material, origin=origin, v_axis=[0.0, 0.0, 1.0])
        self.quad(base + [0, 0, height] - [radius, radius, 0], [2 * radius, 0, 0], [0, 2 * radius, 0], material)

    def triangles(self, vertices: np.ndarray, triangles: np.ndarray, material: int, u_axis) -> None:
        """Arbitrary triangles textured by a shared planar projection (u = u_axis, v = world z)."""
        v = np.asarray(vertices, dtype=np.float64)
        t = np.asarray(triangles, dtype=np.int64)
        frame = np.zeros((len(t), 4, 3))
        frame[:, 1] = u_axis
        frame[:, 2] = [0.0, 0.0, 1.0]
        frame[:, 3] = _units(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]))
        self._soups.append((v, t, frame, np.full(len(t), material, np.int32)))

    def _quad_soup(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        rows = [np.asarray(x, dtype=np.float64) for x in zip(*(q[:6] for q in self._quads), strict=True)]
        p0, a, b, origin, u_axis, v_axis = (np.broadcast_to(r, (len(self._quads), 3)) for r in rows)
        verts = np.stack([p0, p0 + a, p0 + a + b, p0 + b], axis=1).reshape(-1, 3)
        base = 4 * np.arange(len(p0))[:, None, None]
        tris = (np.array([[0, 1, 2], [0, 2, 3]])[None] + base).reshape(-1, 3)
        frame = np.stack([origin, _units(u_axis), _units(v_axis), _units(np.cross(a, b))], axis=1)
        mats = np.array([q[6] for q in self._quads], np.int32)
        return verts, tris, np.repeat(frame, 2, axis=0), np.repeat(mats, 2)

    def build(self) -> Mesh:
        soups = ([self._quad_soup()] if self._quads else []) + self._soups
        offsets = np.cumsum([0] + [len(s[0]) for s in soups[:-1]])
        frames = np.concatenate([s[2] for s in soups])
        return Mesh(
            vertices=np.concatenate([s[0] for s in soups]).astype(np.float32),
            triangles=np.concatenate([s[1] + o for s, o in zip(soups, offsets, strict=True)]).astype(np.uint32),
            material=np.concatenate([s[3] for s in soups]),
            origin=frames[:, 0],
            u_axis=frames[:, 1],
            v_axis=frames[:, 2],
            normal=frames[:, 3],
        )


def _units(x: np.ndarray) -> np.ndarray:
    return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)
