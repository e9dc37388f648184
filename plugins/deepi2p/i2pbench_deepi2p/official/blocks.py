"""The authors' shared-MLP building blocks (DeepI2P `models/layers_pc.py`): 1x1 convolutions with BatchNorm and ReLU.

Module names follow the authors' state dict (`layers.L.conv`, `layers.L.norm`), the interface their checkpoints
share with this size, so an import only strips prefixes.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn


class Unit(nn.Module):
    """1x1 convolution, then (unless last) BatchNorm and ReLU, then dropout when its rate is in (0, 1)."""

    def __init__(self, cin: int, cout: int, dims: int = 1, plain: bool = False, dropout: float = 0.0) -> None:
        super().__init__()
        conv, norm = (nn.Conv1d, nn.BatchNorm1d) if dims == 1 else (nn.Conv2d, nn.BatchNorm2d)
        self.conv = conv(cin, cout, 1)
        self.norm = None if plain else norm(cout)
        self.act = None if plain else nn.ReLU()
        self.dropout = nn.Dropout(dropout) if 0 < dropout < 1 else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.conv(x)
        if self.norm is not None:
            x = self.act(self.norm(x))
        return x if self.dropout is None else self.dropout(x)


class PointMLP(nn.Module):
    """a chain of `Unit`s over [B x C x N] (dims=1) or [B x C x M x K] (dims=2); `plain_last`: the last unit is a
    bare convolution (the authors' `norm_act_at_last=False`, used for every head)."""

    def __init__(
        self, cin: int, widths: Sequence[int], plain_last: bool = False, dims: int = 1,
        dropout: Sequence[float] | None = None,
    ) -> None:  # fmt: skip
        super().__init__()
        rates = dropout or [0.0] * len(widths)
        ins = [cin, *widths[:-1]]
        last = len(widths) - 1
        self.layers = nn.ModuleList(
            Unit(i, o, dims, plain_last and n == last, rates[n])
            for n, (i, o) in enumerate(zip(ins, widths, strict=True))
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for layer in self.layers:
            x = layer(x)
        return x


def nearest(queries: torch.Tensor, points: torch.Tensor, k: int) -> torch.Tensor:
    """[B x 3 x N] queries, [B x 3 x M] points -> [B x N x k] indices of the k nearest points, nearest first.

    Distances as the authors take them (the norm of the broadcast difference), so ties break as theirs do."""
    distance = torch.norm(queries[:, :, :, None] - points[:, :, None, :], dim=1)
    return torch.topk(distance, k, dim=2, largest=False, sorted=True)[1]


def gather_columns(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """[B x C x M] values, [B x N x k] column indices -> [B x C x N x k]."""
    b, n, k = index.shape
    flat = index.reshape(b, 1, n * k).expand(b, values.shape[1], n * k)
    return torch.gather(values, 2, flat).view(b, values.shape[1], n, k)


def interpolate(
    index: torch.Tensor, queries: torch.Tensor, nodes: torch.Tensor, features: torch.Tensor
) -> torch.Tensor:
    """features of the k nearest nodes summed with weights 1 - d / sum(d) (they sum to k - 1, as the authors')."""
    distance = torch.norm(queries[:, :, :, None] - gather_columns(nodes, index), dim=1)
    weight = 1 - distance / distance.sum(dim=2, keepdim=True)
    return (weight[:, None] * gather_columns(features, index)).sum(dim=3)
