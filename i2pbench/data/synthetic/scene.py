"""Procedural street scenes: a road with lanes and paint, kerbed pavements, building rows or gardens, parked and
moving cars, lamp posts, signs and trees, lit by a random sun.

World frame: x forward along the ego car's heading, y left, z up, ground at z = 0, the ego LiDAR above the origin.
The road runs at a small angle `yaw` to the ego heading; street furniture is placed in road coordinates
(s along the road, t to its left) and turned into the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import props
from .mesh import Mesh, MeshBuilder
from .palette import Palette
from .style import DEFAULT, Style
from .textures import Material

EXTENT = 150.0  # metres of road modelled each way; the LiDAR sees 100 m at most


@dataclass(frozen=True)
class Lighting:
    sun: np.ndarray  # [3] unit vector towards the sun
    sun_rgb: np.ndarray  # [3]
    ambient_rgb: np.ndarray  # [3]
    sky_horizon: np.ndarray  # [3]
    sky_zenith: np.ndarray  # [3]
    cloud_seed: int
    cloud_level: float  # noise level above which the sky is cloud (0.4 overcast .. 1 clear)


@dataclass(frozen=True)
class Scene:
    mesh: Mesh
    materials: list[Material]
    lighting: Lighting


@dataclass(frozen=True)
class Road:
    """Cross-section and course of the street in road coordinates (s, t)."""

    yaw: float
    t_left: float  # left kerb line
    t_right: float  # right kerb line (negative)
    kerb: float  # kerb height
    parking: tuple[float, float]  # width of the parking strip outside the outer lane line (left, right)
    walk: tuple[float, float]  # pavement widths (left, right)
    crossing: tuple[float, float] | None  # (s, width) of a side street, if any

    def world(self, s: float, t: float) -> tuple[float, float]:
        c, n = np.cos(self.yaw), np.sin(self.yaw)
        return c * s - n * t, n * s + c * t

    def edge(self, side: int) -> float:
        return self.t_left if side > 0 else self.t_right

    def blocked(self, s: float, margin: float = 0.0) -> bool:
        """Whether s falls inside the side street's opening."""
        if self.crossing is None:
            return False
        return abs(s - self.crossing[0]) < self.crossing[1] / 2 + margin


def build_scene(
    rng: np.random.Generator, style: Style = DEFAULT, style_rng: np.random.Generator | None = None
) -> Scene:
    """One random street scene; every draw comes from rng, so a seed fixes the scene.

    A style with `props` above 1 adds clutter drawn from `style_rng` (default: a generator spawned from rng, which
    draws nothing from it), so the street under the extra objects, its lighting and every later draw from rng are
    the default style's.
    """
    b, pal = MeshBuilder(), Palette(rng)
    road, lanes = _road(rng)
    _ground(b, pal, road, lanes)
    for side in (1, -1):
        _pavement(b, pal, road, side)
        _roadside(b, pal, road, side)
        _parked_cars(b, pal, road, side)
    _traffic(b, pal, road, lanes)
    if style.props > 1:
        extra = Palette(style_rng if style_rng is not None else rng.spawn(1)[0])
        extra.materials = pal.materials  # one material list: ids stored on triangles index it
        for side in (1, -1):
            _more_props(b, extra, road, side, style.props - 1)
    return Scene(b.build(), pal.materials, _lighting(rng))


def _road(rng: np.random.Generator) -> tuple[Road, list[float]]:
    """Lane boundaries (t of each line) with the ego car in one of the lanes."""
    lane_w = rng.uniform(2.9, 3.7)
    n_lanes = int(rng.integers(1, 5))
    ego_lane = int(rng.integers(n_lanes))
    parking = [rng.uniform(2.0, 2.5) if rng.random() < 0.5 else 0.3 for _ in range(2)]
    lines = [(k - ego_lane - 0.5) * lane_w + rng.normal(0, 0.3) * (k == 0) for k in range(n_lanes + 1)]
    lines = sorted(lines)
    crossing = (float(rng.uniform(12, 60)), float(rng.uniform(8, 14))) if rng.random() < 0.35 else None
    road = Road(
        yaw=float(rng.normal(0, 0.06)),
        t_left=lines[-1] + parking[0],
        t_right=lines[0] - parking[1],
        kerb=float(rng.uniform(0.08, 0.18)),
        parking=(float(parking[0]), float(parking[1])),
        walk=(float(rng.uniform(1.8, 5)), float(rng.uniform(1.8, 5))),
        crossing=crossing,
    )
    return road, lines


def _ground(b: MeshBuilder, pal: Palette, road: Road, lanes: list[float]) -> None:
    """Terrain plane, road surface with its markings, and the side street if there is one."""
    up = np.array([0.0, 0.0, 0.0])
    ex, ey = np.array([*road.world(1, 0), 0.0]), np.array([*road.world(0, 1), 0.0])
    b.quad(up - ex * 400 - ey * 400 + [0, 0, -0.03], ex * 800, ey * 800, pal.terrain())
    lines = [
        (t, 0.15, 0.0 if i in (0, len(lanes) - 1) else 3.0, 0.0 if i in (0, len(lanes) - 1) else 6.0)
        for i, t in enumerate(lanes)
    ]
    extra: dict = {}
    if road.crossing is not None:
        s0, w = road.crossing
        extra["no_lines"] = [(s0 - w / 2, s0 + w / 2)]
        extra["zebras"] = [(s0 - w / 2 - 4.0, s0 - w / 2 - 1.0, lanes[0], lanes[-1])] if pal.rng.random() < 0.6 else []
    mat = pal.asphalt(lines, **extra)
    corner = np.array([*road.world(-EXTENT, road.t_right), 0.0])
    b.quad(corner, ex * 2 * EXTENT, ey * (road.t_left - road.t_right), mat, origin=up, u_axis=ex, v_axis=ey)
    if road.crossing is not None:
        _side_street(b, pal, road, ex, ey)


def _side_street(b: MeshBuilder, pal: Palette, road: Road, ex: np.ndarray, ey: np.ndarray) -> None:
    s0, w = road.crossing
    mat = pal.asphalt([(0.0, 0.15, 3.0, 6.0)])
    for side in (1, -1):
        t0 = road.edge(side)
        start = np.array([*road.world(s0 - w / 2, t0), 0.0])
        origin = np.array([*road.world(s0, 0), 0.0])
        b.quad(start, ex * w, ey * side * 120, mat, origin=origin, u_axis=ey, v_axis=-ex)


def _segments(road: Road, margin: float) -> list[tuple[float, float]]:
    """Stretches of s along the road not interrupted by the side street."""
    if road.crossing is None:
        return [(-EXTENT, EXTENT)]
    s0, w = road.crossing
    return [(-EXTENT, s0 - w / 2 - margin), (s0 + w / 2 + margin, EXTENT)]


def _pavement(b: MeshBuilder, pal: Palette, road: Road, side: int) -> None:
    """Raised pavement slab: its kerb is a small depth step the LiDAR sees next to a paint-free asphalt edge."""
    mat = pal.paving()
    width = road.walk[0 if side > 0 else 1]
    t_mid = road.edge(side) + side * width / 2
    for s0, s1 in _segments(road, 0.0):
        xy = road.world((s0 + s1) / 2, t_mid)
        b.box(xy, (s1 - s0, width, road.kerb + 0.1), road.yaw, -0.1, mat)


def _roadside(b: MeshBuilder, pal: Palette, road: Road, side: int) -> None:
    """Whatever lines the street behind the pavement: a building row, gardens with houses, or open land."""
    style = pal.rng.choice(["urban", "urban", "residential", "open"])
    back = road.edge(side) + side * road.walk[0 if side > 0 else 1]
    _furniture(b, pal, road, side)
    if style == "urban":
        _buildings(b, pal, road, side, back + side * pal.rng.uniform(0, 1.0), (7, 26), (0, 5))
    elif style == "residential":
        _fences(b, pal, road, side, back + side * 0.5)
        _buildings(b, pal, road, side, back + side * pal.rng.uniform(4, 10), (4, 10), (3, 12))
    else:
        _trees(b, pal, road, side, back + side * pal.rng.uniform(1, 6), (6, 20))
        _buildings(b, pal, road, side, back + side * pal.rng.uniform(25, 60), (4, 15), (5, 30))


def _buildings(b, pal: Palette, road: Road, side: int, front: float, heights, gaps) -> None:
    """A row of boxes whose facades start at t = front, with random widths, depths, heights and gaps."""
    r = pal.rng
    for s0, s1 in _segments(road, 2.0):
        s = s0 + r.uniform(0, 5)
        while s < s1 - 4:
            width = min(r.uniform(6, 25), s1 - s)
            depth = r.uniform(8, 16)
            xy = road.world(s + width / 2, front + side * depth / 2)
            yaw = road.yaw + (0.0 if side > 0 else np.pi) + r.normal(0, 0.02)
            props.building(b, pal, xy, yaw, width, depth, r.uniform(*heights))
            s += width + (r.uniform(*gaps) if r.random() < 0.6 else 0.0)


def _fences(b, pal: Palette, road: Road, side: int, t: float) -> None:
    r = pal.rng
    for s0, s1 in _segments(road, 1.0):
        s = s0
        while s < s1 - 3:
            length = min(r.uniform(6, 20), s1 - s)
            build = props.hedge if r.random() < 0.5 else props.wall
            build(b, pal, road.world(s + length / 2, t), road.yaw, length)
            s += length + r.uniform(1, 4)
        _trees(b, pal, road, side, t + side * r.uniform(2, 4), (8, 25))


def _trees(b, pal: Palette, road: Road, side: int, t: float, spacing) -> None:
    r = pal.rng
    s = -100 + r.uniform(0, spacing[1])
    while s < 110:
        if not road.blocked(s, 3.0):
            props.tree(b, pal, road.world(s, t + r.normal(0, 0.5)))
        s += r.uniform(*spacing)


def _furniture(b, pal: Palette, road: Road, side: int) -> None:
    """Lamp posts, signs and kerbside trees on the pavement near the kerb."""
    r = pal.rng
    t_kerb = road.edge(side) + side * 0.5
    facing = road.yaw + (np.pi / 2 if side < 0 else -np.pi / 2)
    s = -90 + r.uniform(0, 30)
    while s < 110:
        if not road.blocked(s, 1.0):
            props.street_light(b, pal, road.world(s, t_kerb), facing)
        s += r.uniform(20, 40)
    for _ in range(int(r.integers(0, 4))):
        s = r.uniform(-30, 70)
        if not road.blocked(s, 1.0):
            props.traffic_sign(b, pal, road.world(s, t_kerb + side * 0.2), road.yaw + np.pi * (side < 0))
    if r.random() < 0.4:
        _trees(b, pal, road, side, road.edge(side) + side * 1.2, (7, 15))
    _clutter(b, pal, road, side)


def _clutter(b, pal: Palette, road: Road, side: int, count: int | None = None) -> None:
    """People, bins, bollards and shrubs on the pavement: small objects with depth edges of their own."""
    r = pal.rng
    width = road.walk[0 if side > 0 else 1]
    builders = [props.pedestrian, props.pedestrian, props.bin_, props.bollard, props.bush]
    for _ in range(int(r.integers(0, 12)) if count is None else count):
        s = r.uniform(-40, 80)
        if road.blocked(s, 2.0):
            continue
        build = builders[int(r.integers(len(builders)))]
        t = road.edge(side) + side * r.uniform(0.4, width - 0.4)
        build(b, pal, road.world(s, t), road.yaw + r.uniform(0, 2 * np.pi))


def _more_props(b, pal: Palette, road: Road, side: int, amount: float) -> None:
    """More depth edges along the pavement for a style's `props` (amount = props - 1): `amount` times the default's
    pavement clutter, lamp posts and kerbside trees again, and bushes at the back of the pavement."""
    r = pal.rng
    _clutter(b, pal, road, side, int(r.poisson(5.5 * amount)))
    t_kerb = road.edge(side) + side * 0.5
    s = -90 + r.uniform(0, 30)
    while s < 110:  # poles: the default's lamp-post spacing, shortened
        if not road.blocked(s, 1.0):
            props.street_light(b, pal, road.world(s, t_kerb + side * r.uniform(0, 0.3)), road.yaw - side * np.pi / 2)
        s += r.uniform(20, 40) / amount
    if r.random() < min(0.4 * amount, 1.0):
        _trees(b, pal, road, side, road.edge(side) + side * 1.2, (7 / amount, 15 / amount))
    for _ in range(int(r.poisson(4 * amount))):  # bushes at the back of the pavement
        s = r.uniform(-40, 80)
        if not road.blocked(s, 2.0):
            props.bush(b, pal, road.world(s, road.edge(side) + side * (road.walk[0 if side > 0 else 1] - 0.3)))


def _parked_cars(b, pal: Palette, road: Road, side: int) -> None:
    r = pal.rng
    if road.parking[0 if side > 0 else 1] < 1.0 or r.random() < 0.2:
        return
    t = road.edge(side) - side * 1.1
    s = -70 + r.uniform(0, 8)
    while s < 90:
        if not road.blocked(s, 3.0) and r.random() < 0.7:
            yaw = road.yaw + r.normal(0, 0.03) + np.pi * (r.random() < 0.5)
            props.car(b, pal, road.world(s, t + r.normal(0, 0.1)), yaw)
        s += r.uniform(5.0, 8.0)


def _traffic(b, pal: Palette, road: Road, lanes: list[float]) -> None:
    """A few cars in the lanes, kept clear of the ego car."""
    r = pal.rng
    for _ in range(int(r.integers(0, 6))):
        k = int(r.integers(len(lanes) - 1))
        t = (lanes[k] + lanes[k + 1]) / 2
        s = r.uniform(-50, 70)
        if abs(t) < 2.0 and abs(s) < 9:
            continue
        props.car(b, pal, road.world(s, t + r.normal(0, 0.2)), road.yaw + r.normal(0, 0.02) + np.pi * (t > 0))


def _lighting(rng: np.random.Generator) -> Lighting:
    """Sun height and strength vary from low evening light to overcast, as across KITTI's drives."""
    elevation, azimuth = rng.uniform(np.radians(15), np.radians(65)), rng.uniform(0, 2 * np.pi)
    sun = np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    strength = rng.uniform(0.3, 1.0)
    return Lighting(
        sun=sun,
        sun_rgb=np.array([1.0, 0.96, 0.88]) * strength * 1.1,
        ambient_rgb=np.array([0.5, 0.55, 0.65]) * rng.uniform(0.35, 0.6),
        sky_horizon=np.array([0.85, 0.88, 0.92]) * rng.uniform(0.85, 1.0),
        sky_zenith=np.array([0.35, 0.55, 0.85]) * rng.uniform(0.7, 1.0),
        cloud_seed=int(rng.integers(2**31)),
        cloud_level=float(rng.uniform(0.4, 1.0)),
    )
