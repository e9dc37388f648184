"""CorrI2P's feature exchange (the first half of its "symmetric overlapping region detector"): each
modality's keypoints attend over the other modality's coarse nodes, with attention weights that depend on the
keypoint's own feature and the other modality's global feature, and fuse what they gather into their descriptors.

As in the paper, a pixel attends over the point cloud's 128 nodes, each node the max of the features of the points
it gathers, and a point attends over the image's coarse cells (the paper's stride-32 map of the half-size image:
64 x 64 pixels of the original); each side is then updated from [its local feature, the gathered message, both
global features]. Descriptors arrive as [local (D - G) | global (G)] from CorrI2P's encoders (image.py, points.py).

What differs, and why:
- the paper predicts the attention weights with an MLP whose outputs are the node (or cell) slots themselves, which
  ties the network to one image size and node count; here the query is computed from the same inputs ([local
  feature, other global feature]) and scored against keys computed from the nodes (scaled dot-product, 4 heads), so
  any image size and node count works;
- the exchange runs on the per-keypoint features the encoders return (the stage boundary), not inside the image
  decoder at strides 32 and 16 as in the paper: the fused features are not convolved again;
- the 3D nodes are farthest-point samples of the 3D keypoints (the paper samples the whole cloud), each keypoint
  belonging to its nearest node; the 2D cells pool the keypoints they contain;
- the update MLPs are normalised over each frame's keypoints (layers/frame_norm.py), as the paper's BatchNorm.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from i2pbench.api import (
    BatchedStage,
    Component,
    Device,
    Exchanger,
    Frame,
    Keypoints2D,
    Keypoints3D,
    width_mismatch,
)
from i2pbench.layers.attention import key_mask
from i2pbench.layers.frame_norm import FrameMLP
from i2pbench.layers.nodes import expand, masked_mean, pool_nodes
from i2pbench.layers.pointnet2 import farthest_point_sampling


def point_nodes(xyz: np.ndarray, count: int) -> np.ndarray:
    """[M] int64: each of the [M x 3] points' nearest among `count` farthest-point samples of them (the first point
    starts the sampling, so the assignment depends only on distances between the points)."""
    if len(xyz) == 0:
        return np.zeros(0, np.int64)
    points = torch.from_numpy(np.ascontiguousarray(xyz, np.float32))
    centres = points[farthest_point_sampling(points[None], min(count, len(points)))[0]]
    return torch.cdist(points, centres).argmin(1).numpy().astype(np.int64)


def pixel_cells(uv: np.ndarray, size: tuple[int, int], cell_px: float) -> tuple[np.ndarray, int]:
    """([M] int64 raster index of the cell_px x cell_px cell holding each pixel, the image's number of cells)."""
    width, height = size
    cols, rows = math.ceil(width / cell_px), math.ceil(height / cell_px)
    cell = np.clip(np.floor(np.asarray(uv, np.float64).reshape(-1, 2) / cell_px), 0, [cols - 1, rows - 1])
    return (cell[:, 1] * cols + cell[:, 0]).astype(np.int64), cols * rows


class NodeAttention(nn.Module):
    """keypoints attend over nodes: query from [keypoint feature, other modality's global feature], keys and values
    from the node features; scaled dot-product, `heads` heads -> messages [B x M x A]."""

    def __init__(self, query_dim: int, node_dim: int, dim: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.q, self.kv, self.out = nn.Linear(query_dim, dim), nn.Linear(node_dim, 2 * dim), nn.Linear(dim, dim)

    def forward(self, query: torch.Tensor, nodes: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        q = self.q(query).unflatten(-1, (self.heads, -1)).transpose(1, 2)  # [B x H x M x A/H]
        k, v = self.kv(nodes).unflatten(-1, (2, self.heads, -1)).permute(2, 0, 3, 1, 4)  # 2 x [B x H x K x A/H]
        message = F.scaled_dot_product_attention(q, k, v, attn_mask=key_mask(valid))
        return self.out(message.transpose(1, 2).flatten(2))


class CorrI2PExchanger(BatchedStage, Exchanger):
    """Pixels attend over point nodes, points over image cells; both descriptor sets updated, shapes kept."""

    name = "corri2p-exchange"
    default_conf: dict[str, Any] = {
        "descriptor_dim": 640,  # D, must equal the encoders'
        "global_dim": 512,  # G: the last G channels of each input descriptor are its modality's global feature
        "attention_dim": 128,  # width of queries, keys, values and messages
        "num_heads": 4,
        "point_nodes": 128,  # 3D nodes the pixels attend over (the paper's 128)
        "cell_px": 64,  # side of the image cells the points attend over, in pixels (the paper's stride-32 cells)
        "fusion_mlp": (512,),  # hidden widths of the update MLP on [local, message, own global, other global]
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        d, g, a = self.conf["descriptor_dim"], self.conf["global_dim"], self.conf["attention_dim"]
        if d <= g or a % self.conf["num_heads"]:
            raise ValueError(f"{self.label}: needs descriptor_dim > global_dim and attention_dim divisible by heads")
        local, heads, hidden = d - g, self.conf["num_heads"], tuple(self.conf["fusion_mlp"])
        self.attend2d, self.attend3d = NodeAttention(d, local, a, heads), NodeAttention(d, local, a, heads)
        self.fuse2d = FrameMLP((local + a + 2 * g, *hidden, d))
        self.fuse3d = FrameMLP((local + a + 2 * g, *hidden, d))

    def check_compatible(self, upstream: Mapping[str, Component]) -> str | None:
        return width_mismatch(self, upstream, ("descriptor_dim", "global_dim"))

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, device: Device = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's node membership: the cell of each pixel [M2] and the point node of each 3D keypoint [M3],
        with the image's cell count; neither depends on the protocol's transform."""
        cells, count = pixel_cells(kp2d.uv, frame.image_size, self.conf["cell_px"])
        nodes = point_nodes(kp3d.xyz, self.conf["point_nodes"])
        arrays = {"cell2d": cells, "node3d": nodes, "num_cells": np.int64(count)}
        return {k: torch.from_numpy(np.asarray(v)).to(device) for k, v in arrays.items()}

    def forward(
        self,
        inputs: dict[str, torch.Tensor],
        d2: torch.Tensor,
        d3: torch.Tensor,
        mask2d: torch.Tensor | None = None,
        mask3d: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """`prepare`d memberships (cell2d [B x M2], node3d [B x M3], num_cells [B]), d2 [B x M2 x D], d3 [B x M3 x D],
        keypoint masks [B x M2], [B x M3] (None: no padding) -> updated d2, d3."""
        d2, d3 = d2.float(), d3.float()
        mask2d = torch.ones(d2.shape[:2], dtype=torch.bool, device=d2.device) if mask2d is None else mask2d
        mask3d = torch.ones(d3.shape[:2], dtype=torch.bool, device=d3.device) if mask3d is None else mask3d
        local = d2.shape[-1] - self.conf["global_dim"]
        (l2, g2), (l3, g3) = (
            d2.split([local, self.conf["global_dim"]], -1),
            d3.split([local, self.conf["global_dim"]], -1),
        )
        g2, g3 = masked_mean(g2, mask2d), masked_mean(g3, mask3d)  # [B x G]: the same on every real keypoint
        cells, cell_valid = pool_nodes(l2, inputs["cell2d"], mask2d, int(inputs["num_cells"].max()))
        nodes, node_valid = pool_nodes(l3, inputs["node3d"], mask3d, self.conf["point_nodes"])
        m2 = self.attend2d(torch.cat([l2, expand(g3, l2)], -1), nodes, node_valid)
        m3 = self.attend3d(torch.cat([l3, expand(g2, l3)], -1), cells, cell_valid)
        d2 = d2 + self.fuse2d(torch.cat([l2, m2, expand(g2, l2), expand(g3, l2)], -1), mask2d)
        d3 = d3 + self.fuse3d(torch.cat([l3, m3, expand(g3, l3), expand(g2, l3)], -1), mask3d)
        return d2, d3
