"""The authors' data preparation for KITTI (models/kitti_dataset.py:151-183, 296-323 at be76104): the image halved and
centre-cropped, the network's stride-4 cells as full-resolution pixels, and the scan as 0.1 m voxels with normals.

Geometry of a cell: the loader halves the whole image (OpenCV linear, `int(round(side * 0.5))`), crops 160 x 512 at
offsets `int((side - crop) / 2)`, and run_kitti.py reads cell (x, y) of the stride-4 map with K at 1/4 of the crop's.
A point whose projection under that K is (x, y) projects under the frame's K to (x / scale * 4 + dx / scale, ...), so
cell (x, y) is the frame's pixel (8x + 2 dx, 8y + 2 dy) at the authors' scale, and 1 px there is 8 px here.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np

from i2pbench.api import Frame

STRIDE = 4  # the image branch's output stride
VOXEL_M = 0.1  # the preprocessed clouds' grid and the loader's downsampling (voxel_grid_downsample_size)
# LiDAR axes (x forward, y left, z up) -> camera axes (x right, y down, z forward): a fixed permutation, no extrinsic
LIDAR_TO_CAMERA_AXES = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], np.float32)


def crop_offsets(width: int, height: int, crop: Mapping[str, Any]) -> tuple[int, int] | None:
    """(dx, dy) of the centre crop in the scaled image, as the loader's test mode; None for a frame too small."""
    scaled_w, scaled_h = round(width * crop["scale"]), round(height * crop["scale"])
    crop_w, crop_h = crop["crop"]
    if scaled_w < crop_w or scaled_h < crop_h:
        return None
    return (scaled_w - crop_w) // 2, (scaled_h - crop_h) // 2


def network_image(image: np.ndarray, crop: Mapping[str, Any]) -> np.ndarray:
    """the frame's RGB image -> the authors' crop (H x W x 3 uint8); the frame must hold it (crop_offsets)."""
    height, width = image.shape[:2]
    scaled = cv2.resize(
        image, (round(width * crop["scale"]), round(height * crop["scale"])), interpolation=cv2.INTER_LINEAR
    )
    dx, dy = crop_offsets(width, height, crop)
    crop_w, crop_h = crop["crop"]
    return np.ascontiguousarray(scaled[dy : dy + crop_h, dx : dx + crop_w])


def grid_pixels(width: int, height: int, crop: Mapping[str, Any]) -> np.ndarray:
    """the frame's pixel of each stride-4 cell of the crop, raster order -> [cells x 2]; none for a frame too small."""
    offsets = crop_offsets(width, height, crop)
    if offsets is None:
        return np.zeros((0, 2), np.float32)
    (dx, dy), (crop_w, crop_h) = offsets, crop["crop"]
    rows, cols = np.divmod(np.arange((crop_h // STRIDE) * (crop_w // STRIDE)), crop_w // STRIDE)
    step = STRIDE / crop["scale"]
    return np.stack([step * cols + dx / crop["scale"], step * rows + dy / crop["scale"]], 1).astype(np.float32)


def pixel_cells(uv: np.ndarray, width: int, height: int, crop: Mapping[str, Any]) -> np.ndarray:
    """the raster index of the stride-4 cell each pixel uv [M x 2] falls in (grid_pixels gives cells' corners)
    -> [M] int64; -1 outside the crop."""
    offsets = crop_offsets(width, height, crop)
    if offsets is None:
        return np.full(len(uv), -1, np.int64)
    (dx, dy), (crop_w, crop_h) = offsets, crop["crop"]
    step = STRIDE / crop["scale"]
    col = np.floor((uv[:, 0] - dx / crop["scale"]) / step).astype(np.int64)
    row = np.floor((uv[:, 1] - dy / crop["scale"]) / step).astype(np.int64)
    inside = (col >= 0) & (col < crop_w // STRIDE) & (row >= 0) & (row < crop_h // STRIDE)
    return np.where(inside, row * (crop_w // STRIDE) + col, -1)


def voxel_cloud(frame: Frame) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """the scan's 0.1 m voxel centroids [V x 3], normals [V x 3] (open3d, 0.6 m / 30 neighbours, towards +z),
    nearest-return intensity [V] and that return's row [V]: the preprocessed cloud the loader reads."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    rows = np.flatnonzero(np.isfinite(frame.points).all(1))
    scan = frame.points[rows]
    if len(scan) == 0:
        none = np.zeros((0, 3), np.float32)
        return none, none, np.zeros(0, np.float32), np.zeros(0, np.int64)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scan[:, :3].astype(np.float64))).voxel_down_sample(
        VOXEL_M
    )
    cloud.estimate_normals(search_param=o3d.geometry.KDTreeSearchParamHybrid(radius=0.6, max_nn=30))
    cloud.orient_normals_to_align_with_direction([0, 0, 1])
    xyz = np.asarray(cloud.points, np.float32)
    _, nearest = cKDTree(scan[:, :3]).query(xyz, k=1)
    return xyz, np.asarray(cloud.normals, np.float32), scan[nearest, 3].astype(np.float32), rows[nearest]
