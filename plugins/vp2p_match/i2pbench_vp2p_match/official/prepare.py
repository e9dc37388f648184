"""The authors' data preparation for KITTI (models/kitti_dataset.py:151-183, 296-323 at be76104), as
`i2pbench.layers.peer_inputs` computes it for the three official peers: the whole image halved and centre-cropped
(no top rows cut: VP2P-Match's crop conf has no `top_rows`), the network's stride-4 cells as full-resolution pixels,
and the scan as 0.1 m voxels with normals.

Geometry of a cell: the loader halves the whole image (OpenCV linear, `int(round(side * 0.5))`), crops 160 x 512 at
offsets `int((side - crop) / 2)`, and run_kitti.py reads cell (x, y) of the stride-4 map with K at 1/4 of the crop's.
A point whose projection under that K is (x, y) projects under the frame's K to (x / scale * 4 + dx / scale, ...), so
cell (x, y) is the frame's pixel (8x + 2 dx, 8y + 2 dy) at the authors' scale, and 1 px there is 8 px here.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from i2pbench.layers import peer_inputs

STRIDE = 4  # the image branch's output stride


def grid_pixels(width: int, height: int, crop: Mapping[str, Any]) -> np.ndarray:
    """the frame's pixel of each stride-4 cell of the crop, raster order -> [cells x 2]; none for a frame too small."""
    return peer_inputs.cell_corners(width, height, crop, STRIDE)


def pixel_cells(uv: np.ndarray, width: int, height: int, crop: Mapping[str, Any]) -> np.ndarray:
    """the raster index of the stride-4 cell each pixel uv [M x 2] falls in -> [M] int64; -1 outside the crop."""
    return peer_inputs.pixel_cells(uv, width, height, crop, STRIDE)
