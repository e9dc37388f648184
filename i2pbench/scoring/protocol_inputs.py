"""What a protocol card's stages are given, made from a dataset's frame: the peers' image resize and crop, their
voxel grid and point sampling (i2pbench.scoring.cards.Inputs says which card asks for what).

As the peers' loaders do it (CorrI2P's kitti_pc_img_dataloader.py:269-287): rows cut off the top, then the image
resized by `scale` with bilinear interpolation to (round(W s), round(H s)), K scaled (its last row kept), then a
centre crop of (H, W) at (int((W' - W) / 2), int((H' - H) / 2)), K's principal point moved by it. Points: one point
per occupied voxel of a grid anchored half a voxel below the cloud's minimum, the mean of its points' coordinates and
reflectance (Open3D's voxel_down_sample), kept in scan order with the ring of the voxel's first point; then
`count` of them drawn without replacement (sorted, so scan order holds), or, when fewer, every point repeated and
the rest drawn, as their downsample_np does. The draw has its own generator per (seed, dataset, frame).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import DataError
from ..types import SensorFrame


def transform_K(K: np.ndarray, top: int, scale: float, offset: tuple[int, int]) -> np.ndarray:
    """K after cutting `top` rows, resizing by `scale` and cropping at offset (dx, dy)."""
    K = np.array(K, dtype=np.float64)
    K[1, 2] -= top
    K = scale * K
    K[2, 2] = 1.0
    K[0, 2] -= offset[0]
    K[1, 2] -= offset[1]
    return K


def image_geometry(shape: tuple[int, ...], top: int, scale: float, crop: tuple[int, int] | None) -> tuple:
    """(resized (W, H), crop offset (dx, dy)) for an image of `shape`; refused when the crop does not fit."""
    h, w = shape[0] - top, shape[1]
    size = (int(round(w * scale)), int(round(h * scale)))
    if crop is None:
        return size, (0, 0)
    if crop[0] > size[1] or crop[1] > size[0]:
        raise DataError(f"a {shape[1]} x {shape[0]} image resized to {size[0]} x {size[1]} is smaller than the "
                        f"protocol's {crop[1]} x {crop[0]} crop")  # fmt: skip
    return size, (int((size[0] - crop[1]) / 2), int((size[1] - crop[0]) / 2))


def resample_image(image: np.ndarray, top: int, scale: float, crop: tuple[int, int] | None) -> np.ndarray:
    import cv2

    size, (dx, dy) = image_geometry(image.shape, top, scale, crop)
    image = image[top:]
    if scale != 1.0:
        image = cv2.resize(image, size, interpolation=cv2.INTER_LINEAR)
    if crop is not None:
        image = image[dy : dy + crop[0], dx : dx + crop[1]]
    return np.ascontiguousarray(image)


def voxel_means(points: np.ndarray, ring: np.ndarray, voxel_m: float) -> tuple[np.ndarray, np.ndarray]:
    """[V x 4] the mean of each occupied voxel's points, [V] the ring of its first point; voxels in the order of
    their first point."""
    xyz = points[:, :3].astype(np.float64)
    origin = xyz.min(axis=0) - voxel_m / 2  # where Open3D anchors its grid
    cells = np.floor((xyz - origin) / voxel_m).astype(np.int64)
    _, first, inverse = np.unique(cells, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(first), points.shape[1]), np.float64)
    np.add.at(sums, inverse, points.astype(np.float64))
    means = sums / np.bincount(inverse, minlength=len(first))[:, None]
    order = np.argsort(first, kind="stable")
    return means[order].astype(np.float32), ring[first[order]]


def sample(n: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """`count` indices into n points: drawn without replacement, or every point repeated and the rest drawn."""
    if n >= count:
        return np.sort(rng.choice(n, count, replace=False))
    if n == 0:
        raise DataError("the scan has no points to sample")
    repeated = np.tile(np.arange(n), count // n)
    return np.sort(np.concatenate([repeated, rng.choice(n, count % n, replace=False)]))


def resample(
    sensor: SensorFrame,
    top: int,
    scale: float,
    crop: tuple[int, int] | None,
    voxel_m: float,
    count: int,
    rng: np.random.Generator,
) -> SensorFrame:
    """The frame as the card's stages see it (K transformed with the image); voxel_m 0 or count 0: none."""
    _, offset = image_geometry(sensor.image.shape, top, scale, crop)
    points, ring = sensor.points, sensor.ring
    if voxel_m:
        points, ring = voxel_means(points, ring, voxel_m)
    if count:
        chosen = sample(len(points), count, rng)
        points, ring = points[chosen], ring[chosen]
    return dataclasses.replace(
        sensor,
        image=resample_image(sensor.image, top, scale, crop),
        K=transform_K(sensor.K, top, scale, offset),
        points=points,
        ring=ring,
    )
