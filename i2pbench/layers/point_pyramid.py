"""A KPConv point pyramid built as CoFiI2P's data preparation builds it (model/kpconv/preprocess_data.py): each level a
random half of the one before, drawn with repeats, and every level's k nearest neighbours in itself, in the level
above (subsampling) and below (upsampling).

The authors' loader finds the neighbours with open3d.ml's `KNNSearch` (a compiled op tied to one torch build); their
file's pure-torch `knn` stands in for it, and this module computes that function exactly: squared distances
expanded as -2 q.d + |q|^2 + |d|^2 in float32, clamped at 1e-12, the k smallest by `torch.topk`. The queries are
taken a block of rows at a time (each row's distances and order are its own), so a 20,480-point level needs ~170 MB
instead of the 1.7 GB a whole distance matrix takes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)

NEIGHBOURS = 128  # preprocess_data.py `radius_num`: every level's neighbour count
STAGES = 5  # data/kitti.py `num_stages`
QUERY_BLOCK = 2048  # query rows per distance block


def halvings(count: int, stages: int, rng: np.random.RandomState) -> list[np.ndarray]:
    """the rows of level 0 each level keeps: level i + 1 is `len(level i) // 2` rows of level i drawn with repeats
    (preprocess_data.py:55-59's `np.random.choice`, here from `rng`) -> `stages` index arrays into level 0."""
    picks = [np.arange(count)]
    for _ in range(1, stages):
        previous = picks[-1]
        picks.append(previous[rng.choice(np.arange(len(previous)), size=len(previous) // 2)])
    return picks


def square_distance(queries: torch.Tensor, database: torch.Tensor) -> torch.Tensor:
    """[Q x D] squared distances of queries [Q x 3] to database points [D x 3], in the authors' float arithmetic."""
    dist = -2.0 * torch.matmul(queries, database.t().contiguous())
    dist += torch.sum(queries**2, dim=-1).unsqueeze(-1)
    dist += torch.sum(database**2, dim=-1).unsqueeze(-2)
    return torch.clamp(dist, min=1e-12)


def knn(database: torch.Tensor, queries: torch.Tensor, k: int = NEIGHBOURS) -> torch.Tensor:
    """the k nearest database points [D x 3] of each query [Q x 3], nearest first -> [Q x k] int64 rows of database
    (the authors' `knn(nodes=database, points=queries, k)`)."""
    blocks = [
        square_distance(queries[start : start + QUERY_BLOCK], database).topk(k=k, dim=-1, largest=False)[1]
        for start in range(0, len(queries), QUERY_BLOCK)
    ]
    return torch.cat(blocks) if blocks else torch.zeros((0, k), dtype=torch.int64)


@dataclass(frozen=True)
class PointPyramid:
    """The network's `pc_data_dict` (`as_inputs`) and which level-0 row each level's point is (`picks`)."""

    points: list[torch.Tensor]  # per level [N_i x 3] float32
    neighbors: list[torch.Tensor]  # per level [N_i x k] int64 rows of the same level
    subsampling: list[torch.Tensor]  # per level i < last [N_i+1 x k] int64 rows of level i
    upsampling: list[torch.Tensor]  # per level i < last [N_i x k] int64 rows of level i + 1
    picks: list[np.ndarray]  # per level [N_i] int64 rows of level 0

    @property
    def lengths(self) -> list[int]:
        return [len(p) for p in self.points]

    def as_inputs(self, feats: torch.Tensor) -> dict[str, object]:
        """the authors' `pc_data_dict` with feats [N_0 x C] (data/kitti.py:292-303)."""
        return {
            "points": list(self.points),
            "lengths": self.lengths,
            "neighbors": list(self.neighbors),
            "subsampling": list(self.subsampling),
            "upsampling": list(self.upsampling),
            "feats": feats,
        }


def point_pyramid(
    points: np.ndarray, rng: np.random.RandomState, stages: int = STAGES, k: int = NEIGHBOURS
) -> PointPyramid:
    """points [N x 3] float32 -> the pyramid (module docstring); `rng` draws the halvings."""
    picks = halvings(len(points), stages, rng)
    levels = [torch.from_numpy(np.ascontiguousarray(points[p], dtype=np.float32)) for p in picks]
    neighbors = [knn(level, level, k) for level in levels]
    subsampling = [knn(levels[i], levels[i + 1], k) for i in range(stages - 1)]
    upsampling = [knn(levels[i + 1], levels[i], k) for i in range(stages - 1)]
    return PointPyramid(levels, neighbors, subsampling, upsampling, picks)
