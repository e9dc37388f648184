"""Sample frames for the conformance kit: a small synthetic scene built in milliseconds, so authors need no dataset.

The scene is analytic: around the sensor, twelve azimuth sectors each hold a wall at its own distance, height and
albedo (striped, so reflectance changes along a scan line), over a flat road; what lies beyond is sky. The LiDAR
(16 rings, -15 to +3 degrees, 0.5 degree steps, points in ring then scan order) and a pinhole camera at the same
centre sample the same surfaces, so image edges and depth/reflectance discontinuities line up as in a real frame.
The protocol's random transform is applied as for any dataset, so the frame has T_gt and moved points.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..scoring.protocol import Protocol
from ..types import Frame, SensorFrame

SENSOR_HEIGHT = 1.7  # metres above the road
SECTORS = 12
# camera <- LiDAR rotation: camera x right = -LiDAR y, camera y down = -LiDAR z, camera z forward = LiDAR x
R_CAM_LIDAR = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


@dataclasses.dataclass(frozen=True)
class Scene:
    distance: np.ndarray  # [SECTORS] horizontal distance of each sector's wall (m)
    top: np.ndarray  # [SECTORS] height of each wall's top above the sensor (m)
    albedo: np.ndarray  # [SECTORS] wall reflectance in [0, 1]

    @classmethod
    def random(cls, seed: int) -> Scene:
        rng = np.random.default_rng(seed)
        return cls(rng.uniform(4, 20, SECTORS), rng.uniform(0.5, 4, SECTORS), rng.uniform(0.2, 0.9, SECTORS))

    def hit(self, azimuth: np.ndarray, elevation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(range in m, inf for sky; reflectance) of rays from the sensor centre, vectorised."""
        sector = np.floor((azimuth + np.pi) / (2 * np.pi) * SECTORS).astype(int) % SECTORS
        d = self.distance[sector]
        z_wall = d * np.tan(elevation)
        wall = (z_wall >= -SENSOR_HEIGHT) & (z_wall <= self.top[sector])
        stripes = np.where(np.floor(np.degrees(azimuth) / 4) % 2 == 0, 1.0, 0.5)  # reflectance edges on walls
        ground = ~wall & (z_wall < -SENSOR_HEIGHT)
        rng = np.full(azimuth.shape, np.inf)
        rng[wall] = (d / np.cos(elevation))[wall]
        rng[ground] = SENSOR_HEIGHT / np.sin(-elevation[ground])
        albedo = np.where(wall, self.albedo[sector] * stripes, 0.3)
        return rng, albedo


def _lidar(scene: Scene, rings: int, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """([N x 4] float32 points, [N] int16 ring) of one sweep, ring by ring, in scan order; sky returns dropped."""
    elevation = np.radians(np.linspace(-15.0, 3.0, rings))[:, None].repeat(steps, 1)
    azimuth = np.linspace(-np.pi, np.pi, steps, endpoint=False)[None, :].repeat(rings, 0)
    rng, albedo = scene.hit(azimuth.ravel(), elevation.ravel())
    keep = np.isfinite(rng)
    az, el, r = azimuth.ravel()[keep], elevation.ravel()[keep], rng[keep]
    xyz = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], axis=1)
    points = np.concatenate([xyz, albedo[keep, None]], axis=1).astype(np.float32)
    ring = np.repeat(np.arange(rings), steps)[keep].astype(np.int16)
    return points, ring


def _image(scene: Scene, K: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """[H x W x 3] uint8 RGB: each pixel shows the albedo its ray hits (sky bright), tinted by sector."""
    width, height = size
    u, v = np.meshgrid(np.arange(width) + 0.0, np.arange(height) + 0.0)
    rays_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    rays = rays_cam.reshape(-1, 3) @ R_CAM_LIDAR  # rows: R^T @ ray, into the LiDAR frame
    azimuth = np.arctan2(rays[:, 1], rays[:, 0])
    elevation = np.arctan2(rays[:, 2], np.hypot(rays[:, 0], rays[:, 1]))
    rng, albedo = scene.hit(azimuth, elevation)
    grey = np.where(np.isfinite(rng), albedo, 0.95)
    tint = np.array([1.0, 0.9, 0.8])
    return (255 * grey[:, None] * tint).reshape(height, width, 3).astype(np.uint8)


def synthetic_frame(seed: int = 0, size: tuple[int, int] = (160, 96), rings: int = 16, steps: int = 720) -> Frame:
    """A complete registration problem (image, ~10k points with rings and ranges, K, T_gt) made from `seed` alone."""
    scene = Scene.random(seed)
    width, height = size
    K = np.array([[width / 2, 0.0, width / 2], [0.0, width / 2, height / 2], [0.0, 0.0, 1.0]])
    T_cam_lidar = np.eye(4)
    T_cam_lidar[:3, :3] = R_CAM_LIDAR
    points, ring = _lidar(scene, rings, steps)
    sensor = SensorFrame("conformance", f"synthetic-{seed}", _image(scene, K, size), points, ring, K, T_cam_lidar)
    return Protocol(seed=seed).apply(sensor)


def kitti_frame(root: str, frame_id: str = "00/000000", seed: int = 0) -> Frame:
    """A real KITTI Odometry frame (root holds sequences/), moved by the protocol's transform for `seed`."""
    from ..data.kitti import KittiOdometry

    return Protocol(seed=seed).apply(KittiOdometry("all", {"root": root}).load(frame_id))


def with_image(frame: Frame, image: np.ndarray) -> Frame:
    return dataclasses.replace(frame, image=image)


def blank_image(frame: Frame) -> Frame:
    """The same problem with a uniform grey image: no edge anywhere."""
    return with_image(frame, np.full_like(frame.image, 128))


def tiny_image(frame: Frame, size: int = 8) -> Frame:
    """An image a few pixels wide (a crop of the original)."""
    return with_image(frame, np.ascontiguousarray(frame.image[:size, :size]))


def flipped_image(frame: Frame) -> Frame:
    """The image as a mirrored numpy view (negative stride): valid pixels, awkward memory layout."""
    return with_image(frame, frame.image[:, ::-1])


def with_points(frame: Frame, rows: np.ndarray | int) -> Frame:
    """The frame keeping only some LiDAR rows (the first `rows` when an int; 0 gives an empty scan)."""
    rows = np.arange(min(rows, len(frame.points))) if isinstance(rows, int) else np.asarray(rows)
    return dataclasses.replace(frame, points=frame.points[rows], ring=frame.ring[rows], ranges=frame.ranges[rows])


def with_nan_points(frame: Frame, rows: np.ndarray) -> Frame:
    """The frame with NaN in x, y, z and range of the given rows (a corrupt scan that slipped past its reader)."""
    points, ranges = frame.points.copy(), frame.ranges.copy()
    points[rows, :3] = np.nan
    ranges[rows] = np.nan
    return dataclasses.replace(frame, points=points, ranges=ranges)
