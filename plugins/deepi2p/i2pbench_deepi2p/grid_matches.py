"""Grid classification + PnP (Li & Lee, CVPR 2021, Sec. 4.1) through the contracts as they are: every cell centre is
an image keypoint (an extractor2d's output), and a LiDAR keypoint classified into a cell is matched with that cell's
centre (a matcher's output), so the classic EPnP-RANSAC solver needs nothing new."""

from __future__ import annotations

import numpy as np

from i2pbench.api import Keypoints2D, Matches, cell_half_diagonal

from .labels import cell_centres, grid_shape


def cell_keypoints(size: tuple[int, int], cell: int) -> Keypoints2D:
    """Every cell's centre as an image keypoint, row-major: keypoint i is cell i."""
    rows, cols = grid_shape(size, cell)
    return Keypoints2D(cell_centres(np.arange(rows * cols), size, cell).astype(np.float32))


def cell_matches(cells: np.ndarray, scores: np.ndarray, cell: int) -> Matches:
    """Matches pairing LiDAR keypoint j with cell_keypoints' keypoint cells[j]; cells[j] = -1 (predicted outside the
    frustum) gives no match. `scores` [M3] is each keypoint's confidence (e.g. its frustum times cell probability);
    the pairs are judged true within the cell's half diagonal (`cell_half_diagonal`)."""
    cells = np.asarray(cells, dtype=np.int64)
    kept = np.flatnonzero(cells >= 0)
    return Matches(cells[kept], kept, np.asarray(scores, dtype=np.float32)[kept], radius_px=cell_half_diagonal(cell))
