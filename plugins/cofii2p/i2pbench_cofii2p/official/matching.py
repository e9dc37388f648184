"""CoFiI2P's fine matching after the network (evaluation/eval_all.py:99-105) and the bookkeeping that turns its
answer into i2pbench matches: fine-map cells to the extractor's pixels, coarse points to the extractor's points.

The network's test mode returns, per confident coarse point, the 4 x 4 patch of fine image features around the
pixel it was matched to (centre `fine_center_xy`, the patch's rows from y - 2, columns from x - 2), and the point's
fine feature. eval_all.py takes the patch cell of highest cosine similarity, index i = 4 row + column, and adds
i // 4 (the row) to x and i % 4 (the column) to y: the patch's axes swapped. That is the authors' inference, so it is
the default (`swap_patch_axes`); False adds the row to y and the column to x.
"""

from __future__ import annotations

import numpy as np
import torch


def fine_pixels(
    patch_features: torch.Tensor, point_features: torch.Tensor, centres: torch.Tensor, swap_patch_axes: bool = True
) -> tuple[torch.Tensor, torch.Tensor]:
    """patches [n x C x 16], point features [n x C], patch centres [2 x n] (x, y on the fine map) -> each point's
    fine-map pixel [2 x n] (x, y) and the cosine similarity it won with [n]."""
    similarity = torch.cosine_similarity(patch_features, point_features[:, :, None], dim=1)  # [n x 16]
    best = similarity.argmax(dim=1)  # the first at a tie
    rows, cols = best // 4, best % 4
    dx, dy = (rows, cols) if swap_patch_axes else (cols, rows)
    xy = centres - 2
    return torch.stack([xy[0] + dx, xy[1] + dy]), similarity.gather(1, best[:, None])[:, 0]


def node_rows(nodes: torch.Tensor, chosen: torch.Tensor) -> torch.Tensor:
    """the row of nodes [M x 3] each chosen point [n x 3] (copied from them) is: the first row equal to it -> [n]."""
    equal = (chosen[:, None, :] == nodes[None, :, :]).all(-1)
    if not bool(equal.any(1).all()):
        raise ValueError("a point the network chose is not one of the coarsest level's points")
    return equal.int().argmax(1)


def cell_rows(cells: np.ndarray, count: int) -> np.ndarray:
    """for each of `count` fine-map cells, the first keypoint row [K] falling in it (`cells`, -1 outside) -> [count]
    int64, -1 for a cell no keypoint falls in."""
    rows = np.full(count, -1, np.int64)
    held, first = np.unique(cells, return_index=True)
    rows[held[held >= 0]] = first[held >= 0]
    return rows
