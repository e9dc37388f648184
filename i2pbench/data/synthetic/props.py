"""Street furniture built from boxes and prisms: buildings, cars, trees, poles, signs, hedges, walls.

Each builder takes a world position (x, y) and a heading, adds triangles to a MeshBuilder and its materials to the
Palette. Sizes follow real objects so the LiDAR samples them as densely as it samples real ones.
"""

from __future__ import annotations

import functools

import numpy as np
import open3d as o3d

from .mesh import MeshBuilder
from .palette import Palette


def _offset(xy, yaw: float, along: float, across: float) -> tuple[float, float]:
    """A point `along` metres ahead and `across` metres to the left of xy in a frame turned by yaw."""
    c, s = np.cos(yaw), np.sin(yaw)
    return xy[0] + c * along - s * across, xy[1] + s * along + c * across


def building(b: MeshBuilder, pal: Palette, xy, yaw: float, width: float, depth: float, height: float) -> None:
    """Box house; its facade texture spans the faces so window rows run at the same heights all round."""
    wall = pal.facade(max(width, depth), height)
    roof = pal.plain(pal.grey(0.15, 0.45), float(pal.rng.uniform(0.1, 0.3)), 0.3)
    b.box(xy, (width, depth, height), yaw, -0.3, wall, roof)


def car(b: MeshBuilder, pal: Palette, xy, yaw: float) -> None:
    """Passenger car or van: body, glazed cabin, wheels, number plates and rear reflectors."""
    r = pal.rng
    van = r.random() < 0.15
    length, width = r.uniform(3.9, 4.9) + 0.6 * van, r.uniform(1.7, 1.95)
    body_h = r.uniform(0.65, 0.8) + 0.9 * van
    paint, rgb, ir = pal.car_paint()
    b.box(xy, (length, width, body_h), yaw, 0.3, paint)
    cab_len = (length - 0.3) if van else r.uniform(0.5, 0.6) * length
    cab_z, cab_h = 0.3 + body_h, r.uniform(0.4, 0.55)
    cabin = pal.cabin(rgb, ir, (cab_z + 0.06, cab_z + cab_h - 0.06))
    b.box(_offset(xy, yaw, -0.1 * length * (not van), 0), (cab_len, width - 0.12, cab_h), yaw, cab_z, cabin, paint)
    tyre = pal.plain((0.05, 0.05, 0.05), 0.05, 0.05)
    for along in (0.33 * length, -0.33 * length):
        for across in (width / 2 - 0.15, -width / 2 + 0.15):
            b.box(_offset(xy, yaw, along, across), (0.65, 0.24, 0.65), yaw, 0.0, tyre)
    plate = pal.plain((0.92, 0.92, 0.9), float(r.uniform(0.8, 1.0)), 0.02)
    lamp = pal.plain((0.7, 0.05, 0.05), float(r.uniform(0.6, 0.9)), 0.02)
    for sign in (1, -1):
        b.box(_offset(xy, yaw, sign * (length / 2 + 0.01), 0), (0.04, 0.52, 0.12), yaw, 0.45, plate)
        b.box(
            _offset(xy, yaw, -length / 2 - 0.01, sign * (width / 2 - 0.2)),
            (0.04, 0.25, 0.12),
            yaw,
            0.25 + body_h * 0.75,
            lamp,
        )


def street_light(b: MeshBuilder, pal: Palette, xy, yaw: float) -> None:
    """Lamp post with an arm reaching over the road (yaw points at the road)."""
    r = pal.rng
    height = r.uniform(5.5, 8.5)
    metal = _pole_material(pal)
    b.prism(xy, r.uniform(0.07, 0.13), 0.0, height, metal)
    arm = r.uniform(0.8, 2.5)
    b.box(_offset(xy, yaw, arm / 2, 0), (arm, 0.1, 0.1), yaw, height - 0.2, metal)
    lamp = pal.plain((0.85, 0.85, 0.8), 0.5, 0.02)
    b.box(_offset(xy, yaw, arm, 0), (0.6, 0.3, 0.15), yaw, height - 0.35, lamp)


def _pole_material(pal: Palette) -> int:
    """Grey metal, some with a retro-reflective band pattern near the bottom."""
    grey = pal.grey(0.3, 0.7)
    if pal.rng.random() < 0.3:
        return pal.striped(grey, 0.35, (0.95, 0.95, 0.95), 0.9, (0.6, 1.6), 0.2)
    return pal.plain(grey, float(pal.rng.uniform(0.25, 0.45)), 0.1)


def traffic_sign(b: MeshBuilder, pal: Palette, xy, yaw: float) -> None:
    """Sign panel on a thin pole; the panel faces along yaw (towards oncoming traffic)."""
    r = pal.rng
    size, bottom = r.uniform(0.55, 0.9), r.uniform(1.8, 2.4)
    b.prism(xy, 0.035, 0.0, bottom + size, _pole_material(pal), sides=6)
    face = pal.sign(size)
    b.box(_offset(xy, yaw, 0.05, 0), (0.03, size, size), yaw, bottom, face, face, bottom_ref=bottom)


def tree(b: MeshBuilder, pal: Palette, xy, _yaw: float = 0.0) -> None:
    """Trunk and a lumpy crown; the crown is a perturbed sphere so its silhouette is irregular like foliage."""
    r = pal.rng
    trunk_h, crown_r = r.uniform(1.8, 3.5), r.uniform(1.2, 3.2)
    bark = pal.plain(pal.jitter((0.3, 0.22, 0.15), 0.2), float(r.uniform(0.25, 0.4)), 0.3)
    b.prism(xy, r.uniform(0.1, 0.3), 0.0, trunk_h + crown_r * 0.5, bark, sides=7)
    verts, tris = _sphere()
    lump = 1 + 0.18 * r.standard_normal(len(verts))
    scale = np.array([crown_r, crown_r * r.uniform(0.8, 1.2), crown_r * r.uniform(0.8, 1.4)])
    centre = np.array([xy[0], xy[1], trunk_h + scale[2]])
    angle = r.uniform(0, np.pi)
    b.triangles(verts * lump[:, None] * scale + centre, tris, pal.foliage(), [np.cos(angle), np.sin(angle), 0.0])


@functools.cache
def _sphere() -> tuple[np.ndarray, np.ndarray]:
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=8)
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)


def hedge(b: MeshBuilder, pal: Palette, xy, yaw: float, length: float) -> None:
    r = pal.rng
    b.box(xy, (length, r.uniform(0.5, 1.2), r.uniform(0.7, 1.8)), yaw, -0.1, pal.foliage())


def wall(b: MeshBuilder, pal: Palette, xy, yaw: float, length: float) -> None:
    r = pal.rng
    b.box(xy, (length, r.uniform(0.2, 0.4), r.uniform(0.6, 2.0)), yaw, -0.1, pal.brick())


def pedestrian(b: MeshBuilder, pal: Palette, xy, yaw: float) -> None:
    """Standing person: two legs, torso, arms and head as boxes, in random clothing colours."""
    r = pal.rng
    height = r.uniform(1.55, 1.95)
    legs = pal.plain(pal.pick([(0.15, 0.15, 0.2), (0.25, 0.3, 0.45), (0.4, 0.35, 0.3)]), float(r.uniform(0.1, 0.4)))
    top = pal.plain(
        pal.pick([(0.8, 0.1, 0.1), (0.9, 0.9, 0.9), (0.1, 0.1, 0.1), (0.2, 0.4, 0.7), (0.8, 0.7, 0.2)]),
        float(r.uniform(0.1, 0.6)),
    )
    skin = pal.plain(pal.pick([(0.85, 0.65, 0.5), (0.55, 0.4, 0.3), (0.35, 0.25, 0.2)]), 0.35)
    leg_h, torso_h = 0.47 * height, 0.33 * height
    for across in (-0.1, 0.1):
        b.box(_offset(xy, yaw, 0, across), (0.18, 0.14, leg_h), yaw, 0.0, legs)
        b.box(_offset(xy, yaw, 0, 2.6 * across), (0.12, 0.09, torso_h * 0.95), yaw, leg_h + 0.05, top)
    b.box(xy, (0.26, 0.42, torso_h), yaw, leg_h, top)
    b.box(xy, (0.2, 0.18, height - leg_h - torso_h), yaw, leg_h + torso_h, skin)


def bush(b: MeshBuilder, pal: Palette, xy, _yaw: float = 0.0) -> None:
    """Low lumpy shrub (same perturbed sphere as tree crowns, squashed onto the ground)."""
    r = pal.rng
    verts, tris = _sphere()
    size = r.uniform(0.4, 1.3)
    scale = np.array([size * r.uniform(0.8, 1.5), size * r.uniform(0.8, 1.5), size * r.uniform(0.5, 0.9)])
    lump = 1 + 0.2 * r.standard_normal(len(verts))
    angle = r.uniform(0, np.pi)
    b.triangles(
        verts * lump[:, None] * scale + [xy[0], xy[1], scale[2] * 0.6],
        tris,
        pal.foliage(),
        [np.cos(angle), np.sin(angle), 0.0],
    )


def bollard(b: MeshBuilder, pal: Palette, xy, _yaw: float = 0.0) -> None:
    """Short post with a retro-reflective band: a strong reflectance edge on a small depth edge."""
    r = pal.rng
    height = r.uniform(0.8, 1.1)
    mat = pal.striped(pal.grey(0.2, 0.6), 0.3, (0.95, 0.95, 0.95), 0.95, (height - 0.25, height - 0.1), 0.15)
    b.prism(xy, r.uniform(0.06, 0.1), 0.0, height, mat, sides=6)


def bin_(b: MeshBuilder, pal: Palette, xy, yaw: float) -> None:
    """Wheelie bin or litter bin."""
    r = pal.rng
    colour = pal.pick([(0.1, 0.3, 0.15), (0.2, 0.2, 0.22), (0.15, 0.3, 0.6), (0.6, 0.5, 0.1)])
    b.box(
        xy,
        (r.uniform(0.5, 0.8), r.uniform(0.5, 0.8), r.uniform(0.9, 1.2)),
        yaw,
        0.0,
        pal.plain(colour, float(r.uniform(0.1, 0.35)), 0.1),
    )
