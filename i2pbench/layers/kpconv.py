"""Kernel point convolution (Thomas et al., ICCV 2019, rigid kernels) on a stacked cloud with fixed-size neighbour
lists, as GeoTransformer's KPConv-FPN computes it (CoFiI2P's point branch): every neighbour list indexes a support
cloud plus one "shadow" row (index = number of support points) that pads a short list; the shadow point lies far
away (no kernel influence) and its feature is zero.

- `KPConv`: the convolution. Parameters `weights` [K x C_in x C_out], `bias` [C_out]; buffer `kernel_points`
  [K x 3] (saved in a state dict, so a trained checkpoint carries the disposition it was trained with);
- `kernel_disposition`: a seeded, deterministic kernel disposition for networks built without a checkpoint;
- `gather_rows`, `nearest_upsample`, `neighbour_maxpool`: the shadow-row gathers the blocks around it use.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)

SHADOW_DISTANCE = 1e6  # where the shadow support point sits: beyond every kernel point's reach


def gather_rows(rows: torch.Tensor, index: torch.Tensor, fill: float = 0.0) -> torch.Tensor:
    """rows [N x C] with a shadow row of `fill` appended, gathered by `index` [...] -> [... x C] (one flat
    index_select: on the CPU faster than advanced indexing with a 2-D index)."""
    padded = torch.cat([rows, rows.new_full((1, rows.shape[1]), fill)])
    return padded.index_select(0, index.reshape(-1)).view(*index.shape, rows.shape[1])


def nearest_upsample(feats: torch.Tensor, upsampling: torch.Tensor) -> torch.Tensor:
    """the coarse feature [N x C] of each fine point's nearest coarse point (column 0 of its sorted list)."""
    return gather_rows(feats, upsampling[:, 0])


def neighbour_maxpool(feats: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
    """the channel-wise largest feature over each query's neighbour list (the shadow row counts as zeros)."""
    return gather_rows(feats, neighbours).max(1).values


class KPConv(nn.Module):
    """feats [N x C_in] on support points [N x 3] -> [M x C_out] at query points [M x 3], through neighbour lists
    [M x H]: each neighbour's feature is weighted by its linear influence max(0, 1 - |offset - kernel point| / sigma)
    on each kernel point, multiplied by that kernel point's matrix, summed, and divided by the number of neighbours
    whose features sum to more than zero (at least 1), as GeoTransformer's normalisation does."""

    def __init__(self, cin: int, cout: int, kernel_size: int, radius: float, sigma: float, seed: int = 0) -> None:
        super().__init__()
        self.radius, self.sigma = radius, sigma
        self.weights = nn.Parameter(torch.empty(kernel_size, cin, cout))
        self.bias = nn.Parameter(torch.zeros(cout))
        nn.init.kaiming_uniform_(self.weights, a=math.sqrt(5))
        disposition = kernel_disposition(kernel_size, radius, seed)
        self.register_buffer("kernel_points", torch.from_numpy(disposition))

    def forward(
        self, feats: torch.Tensor, queries: torch.Tensor, support: torch.Tensor, neighbours: torch.Tensor
    ) -> torch.Tensor:
        offsets = gather_rows(support, neighbours, SHADOW_DISTANCE) - queries[:, None]  # M x H x 3
        distance = (offsets[:, :, None] - self.kernel_points).pow(2).sum(-1).sqrt()  # M x H x K
        influence = (1 - distance / self.sigma).clamp(min=0).transpose(1, 2)  # M x K x H
        gathered = gather_rows(feats, neighbours)  # M x H x C_in
        per_kernel = torch.matmul(influence, gathered).transpose(0, 1)  # K x M x C_in
        out = torch.matmul(per_kernel, self.weights).sum(0)
        counted = (gathered.sum(-1) > 0).sum(-1).clamp(min=1)
        return out / counted[:, None] + self.bias


def kernel_disposition(count: int, radius: float, seed: int = 0, steps: int = 400) -> np.ndarray:
    """[count x 3] float32 kernel points of a ball of `radius`: one at the centre, the others spread by gradient
    descent on Thomas et al.'s energy (pairwise repulsion sum 1/d plus an attraction 5 |x|^2 to the centre), from a
    start drawn inside the unit ball by `seed`; then scaled to a mean distance of 0.66 from the centre, turned by a
    seeded angle about z and jittered by 1% of the radius, as a KPConv disposition file is used. Deterministic in
    (count, radius, seed); a network loading a checkpoint replaces it with the checkpoint's buffer."""
    rng = np.random.default_rng(seed)
    direction = rng.standard_normal((count, 3))
    points = direction / np.linalg.norm(direction, axis=1, keepdims=True) * rng.uniform(0.3, 1.0, (count, 1))
    points[0] = 0
    step = 0.01
    for _ in range(steps):
        move = step * _energy_gradient(points)[1:]
        length = np.linalg.norm(move, axis=1, keepdims=True)
        points[1:] -= move * np.minimum(1.0, 0.05 / np.maximum(length, 1e-12))  # at most 0.05 a step
        step *= 0.995
    points *= 0.66 / np.linalg.norm(points[1:], axis=1).mean()
    angle = rng.uniform(0, 2 * np.pi)
    turn = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    points = (points + rng.normal(scale=0.01, size=points.shape)) @ turn
    return (radius * points).astype(np.float32)


def _energy_gradient(points: np.ndarray) -> np.ndarray:
    """d/dx of sum_{i<j} 1/|x_i - x_j| + 5 sum_i |x_i|^2 at each point."""
    diff = points[:, None] - points[None]
    dist = np.linalg.norm(diff, axis=-1) + np.eye(len(points))
    repulsion = -(diff / dist[..., None] ** 3).sum(1)
    return repulsion + 10 * points
