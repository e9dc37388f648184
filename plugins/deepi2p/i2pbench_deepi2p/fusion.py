"""DeepI2P's attention fusion (Li & Lee, CVPR 2021, Sec. 3.1, "image-point cloud fusion"): the image's features
flow into the point cloud's nodes, weighted by attention that the nodes and the image's global feature decide, and
from the nodes back to every classified point. Only the points change; the image descriptors pass through.

For each node: attention scores over the image cells from [node feature, image global feature]; the message is the
mean over the cells of score x cell feature (the paper's weighted mean, without a softmax); the node's update is an
MLP of [node feature, cloud global feature, message, image global feature] (the paper's node_b PointNet); each 3D
keypoint reads its nearest nodes' updates (inverse-distance weights) and adds an MLP of [its own local feature,
that] to its descriptor. Descriptors arrive as [local (D - G) | global (G)] from DeepI2P's encoders (image.py,
points.py); the image side's keypoints are the grid cells (extract.py).

What differs, and why:
- the paper's attention MLP outputs one score per stride-32 pixel of its fixed 160 x 512 input; here the score of
  cell c is the dot product of a query from the same inputs with a key computed from c's position alone
  (positions.py), the paper's per-slot weight vector made a function of where the slot is, so any image size works;
- one level of fusion over the cells, not two (the paper fuses stride-32 features into its 128 coarse nodes, then
  stride-16 features into its 128 fine ones); the nodes are farthest-point samples of the 3D keypoints, each
  keypoint pooled (max) into its nearest, as CorrI2P's exchanger does (the paper's nodes are the encoder's own);
- the fused features are added to the point descriptors (a residual) rather than concatenated for the head, so the
  stage keeps the descriptors' width, as an exchanger must.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from scipy.spatial import cKDTree

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
from i2pbench.layers.mlp import linear_mlp
from i2pbench.layers.nodes import expand, masked_mean, pool_nodes
from i2pbench.layers.pointnet2 import farthest_point_sampling, gather

from .positions import feature_width, fourier_features, normalised_pixels


def node_graph(xyz: np.ndarray, count: int, k: int) -> dict[str, np.ndarray]:
    """Nodes of the [M x 3] points: `count` farthest-point samples (the first point starts), each point's nearest
    node (`node` [M]) and its `k` nearest (`neighbours` [M x k]) with normalised inverse-distance `weights`; only
    distances between the points matter, so the protocol's transform leaves all of it unchanged."""
    if len(xyz) == 0:
        return {"node": np.zeros(0, np.int64), "neighbours": np.zeros((0, 1), np.int64), "weights": np.zeros((0, 1))}
    points = np.ascontiguousarray(xyz, np.float32)
    picked = farthest_point_sampling(torch.from_numpy(points)[None], min(count, len(points)))[0].numpy()
    k = min(k, len(picked))
    dist, neighbours = cKDTree(points[picked].astype(np.float64)).query(points.astype(np.float64), k=k)
    dist, neighbours = dist.reshape(len(points), k), neighbours.reshape(len(points), k)
    weights = 1.0 / np.maximum(dist, 1e-8)
    return {"node": neighbours[:, 0], "neighbours": neighbours, "weights": weights / weights.sum(1, keepdims=True)}


class DeepI2PFusion(BatchedStage, Exchanger):
    """Image features fused into the 3D keypoints through attention-weighted point nodes; image side unchanged."""

    name = "deepi2p-fusion"
    default_conf: dict[str, Any] = {
        "descriptor_dim": 768,  # D, the encoders' (both sides)
        "global_dim": 512,  # G: the last G channels of each input descriptor are its modality's global feature
        "attention_dim": 256,  # width of the queries and the cell keys (the paper's attention MLP: 256 hidden)
        "point_nodes": 128,  # nodes the image is fused into (the paper's 128)
        "interpolation_k": 3,  # nearest nodes each 3D keypoint reads (the paper's k_interp_point_b)
        "frequencies": 6,  # Fourier frequencies of a cell's position (positions.py)
        "node_mlp": (1024, 512),  # the node update on [node, cloud global, message, image global] (the paper's)
        "point_mlp": (512,),  # hidden widths of the keypoint update on [local, interpolated node update]
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        c = self.conf
        local, g, a = c["descriptor_dim"] - c["global_dim"], c["global_dim"], c["attention_dim"]
        if local < 1 or not c["node_mlp"]:
            raise ValueError(f"{self.label}: needs descriptor_dim > global_dim and a node_mlp")
        self.query = linear_mlp((local + g, a, a))
        self.key = linear_mlp((feature_width(c["frequencies"]), a, a))
        node = tuple(c["node_mlp"])
        self.node_update = linear_mlp((2 * local + 2 * g, *node))
        self.point_update = linear_mlp((local + node[-1], *c["point_mlp"], c["descriptor_dim"]))

    def check_compatible(self, upstream: Mapping[str, Component]) -> str | None:
        return width_mismatch(self, upstream, ("descriptor_dim", "global_dim"))

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, device: Device = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's cell positions [M2 x 2] in [0, 1] and the 3D keypoints' node graph (node_graph)."""
        graph = node_graph(kp3d.xyz, self.conf["point_nodes"], self.conf["interpolation_k"])
        arrays = {"cell_xy": normalised_pixels(kp2d.uv, frame.image_size), **graph}
        arrays["weights"] = arrays["weights"].astype(np.float32)
        return {k: torch.from_numpy(np.ascontiguousarray(v)).to(device) for k, v in arrays.items()}

    def forward(
        self,
        inputs: dict[str, torch.Tensor],
        d2: torch.Tensor,
        d3: torch.Tensor,
        mask2d: torch.Tensor | None = None,
        mask3d: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """`prepare`d inputs (cell_xy [B x M2 x 2], node [B x M3], neighbours and weights [B x M3 x k]), d2
        [B x M2 x D], d3 [B x M3 x D], keypoint masks [B x M2], [B x M3] (None: no padding) -> d2, fused d3."""
        d2, d3 = d2.float(), d3.float()
        mask2d = torch.ones(d2.shape[:2], dtype=torch.bool, device=d2.device) if mask2d is None else mask2d
        mask3d = torch.ones(d3.shape[:2], dtype=torch.bool, device=d3.device) if mask3d is None else mask3d
        g = self.conf["global_dim"]
        (l2, g2), (l3, g3) = d2.split([d2.shape[-1] - g, g], -1), d3.split([d3.shape[-1] - g, g], -1)
        g2, g3 = masked_mean(g2, mask2d), masked_mean(g3, mask3d)  # [B x G]: the same on every real keypoint
        nodes, _ = pool_nodes(l3, inputs["node"], mask3d, self.conf["point_nodes"])  # [B x S x L]
        query = self.query(torch.cat([nodes, expand(g2, nodes)], -1))  # [B x S x A]
        key = self.key(fourier_features(inputs["cell_xy"], self.conf["frequencies"]))  # [B x M2 x A]
        score = query @ key.transpose(1, 2) / math.sqrt(query.shape[-1]) * mask2d[:, None]  # [B x S x M2]
        message = score @ l2 / mask2d.sum(1).clamp(min=1)[:, None, None]  # the mean over the frame's cells
        update = self.node_update(torch.cat([nodes, expand(g3, nodes), message, expand(g2, nodes)], -1))
        at_points = (gather(update, inputs["neighbours"]) * inputs["weights"][..., None]).sum(-2)  # [B x M3 x U]
        return d2, d3 + self.point_update(torch.cat([l3, at_points], -1))
