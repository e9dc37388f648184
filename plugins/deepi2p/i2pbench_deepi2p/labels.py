"""DeepI2P's per-point classification targets (Li & Lee, CVPR 2021, Sec. 3): frustum and coarse-grid labels.

Pixel convention: pixel centres at integer coordinates (OpenCV's, which K follows), so a W x H image covers
u in [-0.5, W - 0.5) and v in [-0.5, H - 0.5), the union of its pixel squares. A grid cell of `cell` pixels is the
same kind of half-open square (the last row or column may be partial), so with no margin a point is in the frustum
exactly when it has a cell. (`i2pbench.geometry.transforms.in_image` takes [0, W) instead: the two differ by half a
pixel.)
"""

from __future__ import annotations

import numpy as np

from i2pbench.api import project


def inside_image(uv: np.ndarray, size: tuple[int, int], margin_px: float = 0.0) -> np.ndarray:
    """[N] bool: pixels [N x 2] at least `margin_px` inside a (width, height) image (a negative margin widens it)."""
    w, h = size
    lo = -0.5 + margin_px
    return (uv[:, 0] >= lo) & (uv[:, 0] < w - 0.5 - margin_px) & (uv[:, 1] >= lo) & (uv[:, 1] < h - 0.5 - margin_px)


def frustum_labels(
    xyz: np.ndarray,
    K: np.ndarray,
    T: np.ndarray,
    size: tuple[int, int],
    margin_px: float = 0.0,
    min_depth: float = 0.1,
) -> np.ndarray:
    """[N] bool: LiDAR points [N x 3] in front of the camera T (camera <- LiDAR) whose projection lies in the image.

    The paper's frustum label l^c (Sec. 3): 1 when the point projects inside the image, with positive depth.
    """
    uv, front = project(K, T, np.asarray(xyz, dtype=np.float64), min_depth)
    return front & inside_image(uv, size, margin_px)


def grid_shape(size: tuple[int, int], cell: int) -> tuple[int, int]:
    """(rows, columns) of a grid of `cell`-pixel squares covering a (width, height) image; edge cells may be partial."""
    w, h = size
    return -(-h // cell), -(-w // cell)


def cell_of_pixels(uv: np.ndarray, size: tuple[int, int], cell: int) -> np.ndarray:
    """[N] int64 row-major cell index of each pixel [N x 2]; -1 for pixels outside the image."""
    _, cols = grid_shape(size, cell)
    ok = inside_image(uv, size)
    col = np.floor((uv[:, 0] + 0.5) / cell)
    row = np.floor((uv[:, 1] + 0.5) / cell)
    return np.where(ok, row * cols + col, -1).astype(np.int64)


def grid_labels(
    xyz: np.ndarray, K: np.ndarray, T: np.ndarray, size: tuple[int, int], cell: int, min_depth: float = 0.1
) -> np.ndarray:
    """[N] int64 cell of each point's projection (the paper's grid label, Sec. 3); -1 outside the frustum."""
    uv, front = project(K, T, np.asarray(xyz, dtype=np.float64), min_depth)
    return np.where(front, cell_of_pixels(uv, size, cell), -1)


def cell_centres(index: np.ndarray, size: tuple[int, int], cell: int) -> np.ndarray:
    """[K x 2] float64 pixel at the centre of each cell (of its part inside the image, for a partial edge cell).

    Cell (row, col) holds pixel columns col*cell ... min((col+1)*cell, W) - 1, so its centre is their midpoint.
    """
    w, h = size
    rows, cols = grid_shape(size, cell)
    index = np.asarray(index, dtype=np.int64)
    if index.size and (index.min() < 0 or index.max() >= rows * cols):
        raise ValueError(f"cell index out of range for a {rows} x {cols} grid")
    row, col = np.divmod(index, cols)
    u = (col * cell + np.minimum((col + 1) * cell, w) - 1) / 2
    v = (row * cell + np.minimum((row + 1) * cell, h) - 1) / 2
    return np.column_stack([u, v]).astype(np.float64)
