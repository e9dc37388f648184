"""DeepI2P's image side before any network: the centre of every cell of its coarse grid, as image keypoints.

The classifier names a cell for each point, and grid + PnP pairs the point with that cell's centre (Li & Lee, CVPR
2021, Sec. 4.1), so the 2D keypoints are the cells themselves: row-major, partial cells at the right and bottom
borders included (a point projecting there has a cell too, labels.py). The classic `grid` extractor at stride
`cell_px` gives the same pixels for the whole cells but leaves the partial ones out: on a 1241 x 376 KITTI image with
64 px cells, 95 whole cells of 120, so points in the last column and row would have no keypoint to match.
"""

from __future__ import annotations

from typing import Any

from i2pbench.api import Extractor2D, Frame, Keypoints2D

from .grid_matches import cell_keypoints


class CellCentresExtractor(Extractor2D):
    """Every grid cell's centre, row-major (keypoint i is cell i of labels.grid_shape); deterministic."""

    name = "deepi2p-cell-centres"
    default_conf: dict[str, Any] = {
        # cell side in pixels of the frame's image: the paper's 32 px of its half-size input, 64 px of a full image
        "cell_px": 64,
    }

    def __call__(self, frame: Frame) -> Keypoints2D:
        cell = int(self.conf["cell_px"])
        if cell < 1:
            raise ValueError(f"{self.label}: cell_px must be a positive number of pixels, got {cell}")
        return cell_keypoints(frame.image_size, cell)
